//! The runner against a device that nobody here wrote: pymodbus's serial server, set up as
//! a generic holding-register device (no TECO registers, no TECO exception rules), on a
//! pseudo-terminal pair made by socat, checked as an F510. The run must complete, report
//! the deviations a generic device has from the F510 manual, and neither panic nor hang.

mod common;
use common::{tool_or_skip, Kill};

use std::process::{Command, Stdio};
use std::time::Duration;

/// pymodbus's generic server on one end of a socat pair: the guards and the runner's end
/// (None after SKIPPED when a tool is missing).
fn start(mode: &str, dir: &std::path::Path) -> Option<(Kill, Kill, std::path::PathBuf)> {
    let socat = Command::new("socat")
        .arg("-V")
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !tool_or_skip(socat, "socat not installed (apt-get install socat)") {
        return None;
    }
    let pymodbus = Command::new("python3")
        .args(["-c", "import pymodbus, serial"])
        .status()
        .is_ok_and(|s| s.success());
    if !tool_or_skip(
        pymodbus,
        "pymodbus not installed (pip install 'pymodbus[serial]==3.16.1')",
    ) {
        return None;
    }
    let (socat, a, b) = common::socat_pair(dir);
    let server = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/interop/pymodbus_server.py"
    );
    let server = Kill(
        Command::new("python3")
            .args([server, a.to_str().unwrap(), mode])
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    common::wait_until_answers(&b, mode, &["-P", "none"]);
    Some((socat, server, b))
}

fn run(mode: &str) {
    let dir = std::env::temp_dir().join(format!("teco-generic-{mode}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let Some((_socat, _server, b)) = start(mode, &dir) else {
        return;
    };
    let t0 = std::time::Instant::now();
    let (exit, v) = common::check_device(
        &dir,
        &[
            "--model",
            "f510",
            "--port",
            b.to_str().unwrap(),
            "--mode",
            mode,
            "-P",
            "none",
            "--timeout",
            "300",
        ],
        Duration::from_secs(180),
    );
    assert_eq!(v["complete"], true, "{}", v["stopped"]);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    let deviations = v["summary"]["deviation"].as_u64().unwrap();
    assert!(
        deviations > 10,
        "a generic device cannot behave like a TECO drive: {}",
        v["summary"]
    );
    assert_eq!(exit, Some(1));
    // The device answers plain reads: the runner talked to it.
    assert!(
        v["summary"]["pass"].as_u64().unwrap() > 10,
        "{}",
        v["summary"]
    );
    eprintln!("{mode}: {} in {:?}", v["summary"], t0.elapsed());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_generic_pymodbus_device_checked_as_f510_rtu() {
    run("rtu");
}

#[test]
fn a_generic_pymodbus_device_checked_as_f510_ascii() {
    run("ascii");
}
