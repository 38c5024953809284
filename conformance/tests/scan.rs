//! `conformance scan` against simulators whose pseudo-terminal behaves like a drive's
//! line (`simulate --pty --emulate-line`), an empty line, and a line whose device talks
//! at another setting; RS-485 direction control on a pseudo-terminal; mbpoll against the
//! emulated line.
#![cfg(unix)]

mod common;

use std::process::Command;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use common::{need, pty_pair, sim_pty, words, Kill, Peer, Ran, Run, Scratch};
use conformance::codec::timing::{LineSettings, Parity};
use conformance::codec::{frame_of_body, Mode};
use conformance::scan::link::SerialLink;
use conformance::scan::probe::Answer;
use conformance::scan::settings::Setting;
use conformance::scan::{scan, ScanConfig, Verdict};
use conformance::transport::pty::PtyMaster;
use conformance::transport::serial::SerialTransport;
use conformance::transport::{LinkKind, Transport};

/// `conformance scan --port PORT ARGS` (the words of `args`) bounded by `secs`, which
/// must exit `exit`.
fn scan_on(port: &str, args: &str, secs: u64, exit: i32) -> Ran {
    Run::words("scan --port")
        .arg(port)
        .args(words(args))
        .timeout(Duration::from_secs(secs))
        .run()
        .expect(exit)
}

/// The E510 simulator at node 17 on an emulated ASCII 19200 8O1 line, paced: the guard
/// and its port.
fn e510_at_node_17() -> (Kill, String) {
    sim_pty(&words(
        "--model e510 --emulate-line --pace -b 19200 -P odd -m ascii -a 17",
    ))
}

#[test]
fn scan_finds_a_simulator_at_an_unusual_setting() {
    let (_sim, path) = e510_at_node_17();
    // The whole default search: every speed, parity and mode, addresses 1..247.
    let out = scan_on(&path, "--quiet", 300, 0).stdout;
    let row = out
        .lines()
        .find(|l| l.starts_with("11H (17)"))
        .unwrap_or_else(|| panic!("no row for node 17:\n{out}"));
    common::assert_contains_all(row, &["ascii", "19200 8O1"]);
    // The e510 simulator's identification value, and the reply's bytes in hex.
    common::assert_contains_all(row, &["252FH = 0E51H: e510", "3A 31 31 30 33 30 32"]);
    assert_eq!(
        out.lines().filter(|l| l.contains("H (")).count(),
        1,
        "one device:\n{out}"
    );

    // Narrowed, as JSON: the same device.
    let v = scan_on(
        &path,
        "-b 19200 -m ascii --addresses 10-20 --format json --quiet",
        60,
        0,
    )
    .json();
    let found = v["found"].as_array().unwrap();
    assert_eq!(found.len(), 1, "{v}");
    assert_eq!(found[0]["address"], 17);
    assert_eq!(found[0]["line"]["parity"], "O");
    assert_eq!(found[0]["line"]["baud"], 19200);
    assert_eq!(found[0]["identification"], "0E51");
    // Only 19200 ASCII settings were tried (three parities).
    assert_eq!(v["settings"].as_array().unwrap().len(), 3);
}

#[test]
fn an_empty_line_finds_nothing_with_exit_1() {
    let dir = Scratch::new("empty");
    let (_line, a, _b) = pty_pair(&dir);
    let a = a.to_string_lossy().into_owned();
    let out = scan_on(&a, "-b 19200,9600 -P even --addresses 1-20 --quiet", 60, 1).stdout;
    common::assert_contains_all(&out, &["no device found", "4 silent"]);

    // A simulator at the right setting but outside the address range: nothing either.
    let (_sim, path) = sim_pty(&words("--emulate-line -b 9600 -P even -a 30"));
    let v = scan_on(
        &path,
        "-b 9600 -P even -m rtu --addresses 1-29 --format json --quiet",
        60,
        1,
    )
    .json();
    assert_eq!(v["found"].as_array().unwrap().len(), 0);
    assert_eq!(v["tries"], 29);
}

/// A device on an emulated 19200 8O1 line that talks on its own every 8 ms (a reply
/// from node 01, as a bus with another master polling carries): at any other setting the
/// scanner hears garbage. (A device that only answers requests is silent at a wrong
/// setting, since it cannot read them: garbage needs a talker.)
#[test]
fn a_wrong_setting_yields_garbage_and_is_skipped_early() {
    let device_line = LineSettings::new(19_200, 8, Parity::Odd, 1);
    let mut device = PtyMaster::open(None)
        .unwrap()
        .with_line_emulation(device_line)
        .unwrap();
    let path = device.slave_path().to_string_lossy().into_owned();
    let reply = frame_of_body(Mode::Rtu, &[0x01, 0x03, 0x02, 0x05, 0x10]).unwrap();
    let stop = Arc::new(AtomicBool::new(false));
    let s = stop.clone();
    let r = reply.clone();
    let talker = std::thread::spawn(move || {
        let mut buf = [0u8; 256];
        while !s.load(Ordering::Relaxed) {
            device.send(&r).unwrap();
            // Whatever the scanner sends is read (and dropped) meanwhile.
            let t = Instant::now();
            while t.elapsed() < Duration::from_millis(8) {
                device.recv(&mut buf, Duration::from_millis(2)).unwrap();
            }
        }
    });
    let wrong = Setting {
        line: LineSettings::new(9600, 8, Parity::Even, 1),
        mode: Mode::Rtu,
    };
    let right = Setting {
        line: device_line,
        mode: Mode::Rtu,
    };
    let port = SerialTransport::open(&path, wrong.line, LinkKind::Pty).unwrap();
    let mut link = SerialLink::new(port, &path);
    let config = ScanConfig {
        settings: vec![wrong, right],
        addresses: (1..=10).collect(),
        first: vec![1],
        response: Duration::from_millis(10),
        reply_window: None,
        // Every address answers here (the talker's frames): nothing to ask again.
        retries: 1,
    };
    let report = scan(&mut link, &config, &AtomicBool::new(false), &mut |_| {}).unwrap();
    stop.store(true, Ordering::Relaxed);
    talker.join().unwrap();

    // The wrong setting was dropped after its first try, on garbage.
    let w = &report.settings[0];
    assert_eq!(w.tries, 1, "{:?}", report.settings);
    match &w.verdict {
        Verdict::Garbage { address, bytes } => {
            assert_eq!(*address, 1);
            assert!(!bytes.is_empty());
            assert_ne!(bytes[..], reply[..]);
        }
        v => panic!("9600 8E1 should be garbage, is {v:?}"),
    }
    // The right one answered, and the range was swept there.
    assert_eq!(report.settings[1].verdict, Verdict::Answered);
    assert_eq!(report.settings[1].tries, 10);
    assert_eq!(report.found.len(), 1);
    assert_eq!(report.found[0].setting, right);
    assert_eq!(report.found[0].answer, Answer::Value(0x0510));
    assert_eq!(report.tries, 11);
}

#[test]
fn rts_needs_a_port_with_an_rts_line() {
    let (_sim, path) = sim_pty(&[]);
    // A pseudo-terminal has no modem lines: --rts is refused with the reason, exit 2.
    let (code, out, err) =
        Run::words("check --model f510 --rts --rts-delay 200 --quiet --only identification")
            .args(["--port", &path])
            .timeout(Duration::from_secs(30))
            .run()
            .parts();
    assert_eq!(code, Some(2), "{out}\n{err}");
    assert!(err.contains("RTS"), "{err}");
    let err = scan_on(&path, "-b 9600 -P even -m rtu --rts --quiet", 30, 2).stderr;
    assert!(err.contains("no RTS line"), "{err}");
    // --rts without a serial port is an argument error.
    let err = Run::words("check --sim f510 --rts --quiet")
        .timeout(Duration::from_secs(30))
        .run()
        .expect(2)
        .stderr;
    assert!(
        err.contains("--rts drives the RTS line of a serial port"),
        "{err}"
    );
}

/// mbpoll at the simulator's setting reads it; at another baud rate it gets nothing,
/// as from a real drive.
#[test]
fn mbpoll_against_the_emulated_line() {
    if !need(Peer::Mbpoll) {
        return;
    }
    let (_sim, path) = sim_pty(&words("--model l510 --emulate-line -b 19200 -P odd -a 17"));
    let mbpoll = |baud: &str| {
        Command::new("mbpoll")
            .args([
                "-m", "rtu", "-a", "17", "-b", baud, "-P", "odd", "-t", "4:hex", "-r", "9520",
                "-c", "1", "-1", "-o", "0.5", &path,
            ])
            .output()
            .unwrap()
    };
    // 252FH is register 9519 counted from 0; mbpoll counts from 1 (-r 9520).
    let o = mbpoll("19200");
    let out = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "{out}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(out.contains("[9520]: \t0x0110"), "{out}");
    let o = mbpoll("9600");
    let text = format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    );
    assert!(!o.status.success(), "{text}");
    assert!(!text.contains("0x0110"), "{text}");
}

/// `scan --capture`: every try is recorded, each setting on an interface of its own whose
/// description names the mode and the line, under the mode's link type (147 RTU, 148
/// ASCII), and the reply that found the device is on the setting it answered.
#[test]
fn a_scan_capture_records_each_setting_on_its_own_interface() {
    let (_sim, path) = e510_at_node_17();
    let dir = Scratch::new("scan-capture");
    let cap = dir.join("scan.pcapng");
    let err = Run::words("scan -b 19200 -P odd,even --addresses 16-17 --reply-window 150 --quiet")
        .args(["--port", &path, "--capture"])
        .arg(&cap)
        .timeout(Duration::from_secs(120))
        .run()
        .ok()
        .stderr;
    assert!(err.contains("capture: "), "{err}");
    let data = std::fs::read(&cap).unwrap();
    let packets: Vec<conformance::capture::Packet<'_>> = conformance::capture::Reader::new(&data)
        .unwrap()
        .map(|p| p.unwrap())
        .collect();
    // Every request of every try: 2 parities x 2 modes x 2 addresses at most, at least
    // the 3 settings before the one that answers, and node 17's read in ASCII 8O1.
    let requests: Vec<&conformance::capture::Packet<'_>> = packets
        .iter()
        .filter(|p| p.direction == Some(conformance::capture::Direction::Outbound))
        .collect();
    assert!(requests.len() >= 4, "{}", requests.len());
    for p in &packets {
        let want = match p.data.first() {
            Some(b':') => conformance::capture::LINKTYPE_USER1,
            _ => conformance::capture::LINKTYPE_USER0,
        };
        assert_eq!(p.link_type, want, "{:02X?}", p.data);
    }
    // The reply: inbound, ASCII, from node 17 ("11"), on an interface other than the
    // first setting's.
    let reply = packets
        .iter()
        .find(|p| p.direction == Some(conformance::capture::Direction::Inbound))
        .unwrap_or_else(|| panic!("no reply in the capture"));
    assert!(reply.data.starts_with(b":1103"), "{:?}", reply.data);
    assert_ne!(reply.interface, packets[0].interface);
    // The interfaces are described by their settings, and tshark (where present) shows
    // the answered one as ASCII 19200 8O1.
    if !need(Peer::Tshark) {
        return;
    }
    let o = Command::new("tshark")
        .arg("-r")
        .arg(&cap)
        .args(["-T", "fields", "-e", "frame.interface_description"])
        .output()
        .unwrap();
    let descriptions = String::from_utf8_lossy(&o.stdout).into_owned();
    let of_reply = descriptions
        .lines()
        .nth(packets.iter().position(|p| std::ptr::eq(p, reply)).unwrap())
        .unwrap();
    assert!(of_reply.starts_with("ascii 19200 8O1"), "{of_reply}");
    assert!(
        descriptions.lines().any(|l| l.starts_with("rtu 19200 8E1")),
        "{descriptions}"
    );
}
