//! `conformance ports` against a fake sysfs and /dev tree (the hidden `--root`): an FTDI
//! adapter at the default latency timer of 16 ms, beside the ttys a real machine also has
//! that are not serial ports (a virtual console, an empty legacy 8250 slot).

#![cfg(target_os = "linux")]

mod common;

use std::os::unix::fs::symlink;
use std::path::{Path, PathBuf};
use std::process::Command;

/// The folder of the fake tree; removed when the guard goes.
struct Tree(PathBuf);

impl Drop for Tree {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

fn write(p: &Path, text: &str) {
    std::fs::create_dir_all(p.parent().unwrap()).unwrap();
    std::fs::write(p, text).unwrap();
}

fn link(target: &str, at: &Path) {
    std::fs::create_dir_all(at.parent().unwrap()).unwrap();
    symlink(target, at).unwrap();
}

/// A tree laid out as Linux lays out an FTDI FT232R on USB port 1-2, with its latency
/// timer at `latency_ms`, and a lock on it held by this test's process.
fn tree(name: &str, latency_ms: u32) -> Tree {
    let root = std::env::temp_dir().join(format!("ports-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&root);
    let sys = root.join("sys");
    let usb = sys.join("devices/pci0000:00/0000:00:14.0/usb1/1-2");
    for (f, v) in [
        ("idVendor", "0403"),
        ("idProduct", "6001"),
        ("manufacturer", "FTDI"),
        ("product", "FT232R USB UART"),
        ("serial", "A10K5XYZ"),
    ] {
        write(&usb.join(f), &format!("{v}\n"));
    }
    // The usb-serial port device, its tty below it, and the names sysfs gives them.
    let port = usb.join("1-2:1.0/ttyUSB0");
    write(&port.join("latency_timer"), &format!("{latency_ms}\n"));
    std::fs::create_dir_all(sys.join("bus/usb-serial/drivers/ftdi_sio")).unwrap();
    link(
        "../../../bus/usb-serial/drivers/ftdi_sio",
        &port.join("driver"),
    );
    std::fs::create_dir_all(port.join("tty/ttyUSB0")).unwrap();
    link("../../../ttyUSB0", &port.join("tty/ttyUSB0/device"));
    link(
        "../../devices/pci0000:00/0000:00:14.0/usb1/1-2/1-2:1.0/ttyUSB0/tty/ttyUSB0",
        &sys.join("class/tty/ttyUSB0"),
    );
    link(
        "../../../devices/pci0000:00/0000:00:14.0/usb1/1-2/1-2:1.0/ttyUSB0",
        &sys.join("bus/usb-serial/devices/ttyUSB0"),
    );
    // A virtual console (no device) and an empty 8250 slot (type 0): not serial ports.
    std::fs::create_dir_all(sys.join("devices/virtual/tty/tty0")).unwrap();
    link(
        "../../devices/virtual/tty/tty0",
        &sys.join("class/tty/tty0"),
    );
    let slot = sys.join("devices/platform/serial8250/tty/ttyS1");
    write(&slot.join("type"), "0\n");
    link("../../../serial8250", &slot.join("device"));
    link(
        "../../devices/platform/serial8250/tty/ttyS1",
        &sys.join("class/tty/ttyS1"),
    );
    // /dev: the node, its stable name, the pseudo-terminals every machine has.
    write(&root.join("dev/ttyUSB0"), "");
    link(
        "../../ttyUSB0",
        &root.join("dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A10K5XYZ-if00-port0"),
    );
    std::fs::create_dir_all(root.join("dev/pts")).unwrap();
    write(
        &root.join("run/lock/LCK..ttyUSB0"),
        &format!("{:>10}\n", std::process::id()),
    );
    Tree(root)
}

fn ports(root: &Path, args: &[&str]) -> (Option<i32>, String) {
    let o = Command::new(common::bin())
        .arg("ports")
        .args(args)
        .arg("--root")
        .arg(root)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(!err.contains("panicked"), "{err}");
    (
        o.status.code(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
    )
}

#[test]
fn an_ftdi_at_16_ms_is_listed_with_its_timer_finding_and_the_command() {
    let t = tree("text", 16);
    let (code, out) = ports(&t.0, &[]);
    assert_eq!(code, Some(0), "{out}");
    let r = t.0.display();
    assert!(
        out.starts_with(&format!(
            "{r}/dev/ttyUSB0  FTDI FT232R USB UART (USB 0403:6001, serial A10K5XYZ), driver ftdi_sio\n"
        )),
        "{out}"
    );
    assert!(
        out.contains(&format!(
            "  by-id: {r}/dev/serial/by-id/usb-FTDI_FT232R_USB_UART_A10K5XYZ-if00-port0\n"
        )),
        "{out}"
    );
    assert!(
        out.contains(&format!(
            "  latency timer: 16 ms ({r}/sys/bus/usb-serial/devices/ttyUSB0/latency_timer)\n"
        )),
        "{out}"
    );
    for line in [
        "    9600 baud: t3.5 is 4.01 ms; 16 ms is 4.0x t3.5: replies reach this computer in bursts",
        "   19200 baud: t3.5 is 2.01 ms; 16 ms is 8.0x t3.5",
        "   38400 baud: t3.5 is 1.75 ms; 16 ms is 9.1x t3.5",
        "  115200 baud: t3.5 is 1.75 ms; 16 ms is 9.1x t3.5",
    ] {
        assert!(out.contains(line), "{line:?} missing from\n{out}");
    }
    assert!(
        out.contains(&format!(
            ": echo 1 | sudo tee {r}/sys/bus/usb-serial/devices/ttyUSB0/latency_timer\n"
        )),
        "{out}"
    );
    assert!(out.contains("  access: you may"), "{out}");
    assert!(
        out.contains(&format!(
            "  lock: {r}/run/lock/LCK..ttyUSB0 held by pid {}",
            std::process::id()
        )),
        "{out}"
    );
    // The console and the empty slot are not ports.
    assert!(!out.contains("tty0") && !out.contains("ttyS1"), "{out}");
    assert!(out.ends_with("\n1 serial port\n"), "{out}");
}

#[test]
fn the_json_listing_holds_the_same_finding_for_scripts() {
    let t = tree("json", 16);
    let (code, out) = ports(&t.0, &["--format", "json"]);
    assert_eq!(code, Some(0), "{out}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["count"], 1);
    let p = &v["ports"][0];
    assert_eq!(p["path"], format!("{}/dev/ttyUSB0", t.0.display()));
    assert_eq!(p["kind"], "usb");
    assert_eq!(p["driver"], "ftdi_sio");
    assert_eq!(p["usb"]["vid"], "0403");
    assert_eq!(p["usb"]["pid"], "6001");
    assert_eq!(p["usb"]["serial"], "A10K5XYZ");
    assert_eq!(p["latency_timer"]["ms"], 16);
    let effects = p["latency_timer"]["effects"].as_array().unwrap();
    assert_eq!(effects.len(), 4);
    assert!(effects.iter().all(|e| e["breaks_framing"] == true), "{p}");
    assert_eq!(effects[0]["baud"], 9600);
    assert_eq!(effects[0]["t3_5_us"], 4011);
    assert_eq!(
        p["latency_timer"]["set_command"],
        format!(
            "echo 1 | sudo tee {}/sys/bus/usb-serial/devices/ttyUSB0/latency_timer",
            t.0.display()
        )
    );
    assert_eq!(p["lock"]["pid"], std::process::id());
    assert_eq!(p["lock"]["alive"], true);
    assert_eq!(p["access"]["may_open"], true);
}

#[test]
fn at_1_ms_the_timer_is_below_t3_5_and_no_command_is_given() {
    let t = tree("one-ms", 1);
    let (code, out) = ports(&t.0, &[]);
    assert_eq!(code, Some(0), "{out}");
    assert!(out.contains("  latency timer: 1 ms"), "{out}");
    common::assert_count(&out, "below t3.5, framing by silence holds", 4);
    assert!(!out.contains("sudo tee"), "{out}");
}

#[test]
fn a_machine_with_pseudo_terminals_only_lists_none_and_says_so() {
    let t = tree("none", 16);
    // Unplugged: the adapter's tty and its node are gone; the console and the ptys stay.
    std::fs::remove_file(t.0.join("sys/class/tty/ttyUSB0")).unwrap();
    std::fs::remove_file(t.0.join("dev/ttyUSB0")).unwrap();
    let (code, out) = ports(&t.0, &[]);
    assert_eq!(code, Some(1), "{out}");
    assert!(
        out.starts_with("no serial ports found\nhint: this machine has pseudo-terminals only"),
        "{out}"
    );
    assert!(out.contains("conformance check --sim f510"), "{out}");
    let (code, out) = ports(&t.0, &["--format", "json"]);
    assert_eq!(code, Some(1), "{out}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert_eq!(v["count"], 0);
    assert!(
        v["hint"]
            .as_str()
            .unwrap()
            .contains("pseudo-terminals only"),
        "{v}"
    );
}
