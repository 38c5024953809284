//! `conformance monitor` on a pseudo-terminal the test holds: the test plays the bus
//! (a master's requests and the drives' replies, recorded frames written with gaps), the
//! monitor listens on the other end and must never write a byte to it.
//!
//! Gaps are large against every threshold (100 ms between exchanges, where t3.5 at 9600
//! baud is 4 ms; a late reply 2.5 s late where the limit is 1 s), and a request and its
//! prompt reply are written in one piece, whose inner silence the monitor cannot see and
//! does not judge: nothing here depends on how busy the machine is. The timing rules
//! themselves (t3.5 before a request, early replies, gaps inside a reply) are tested with
//! exact synthetic times in the library (monitor::tests).
#![cfg(unix)]

mod common;
use common::rtu::{exception, read, values, write};
use common::{monitor_node as node, Run};

use std::time::{Duration, Instant};

use conformance::codec::pdu::{Message, Pdu, Registers};
use conformance::codec::Mode;
use conformance::transport::pty::PtyMaster;
use conformance::transport::Transport;
use serde_json::Value;

/// One step of the recorded bus: wait, then write these bytes in one piece.
struct Step {
    after_ms: u64,
    bytes: Vec<u8>,
}

fn step(after_ms: u64, parts: &[&[u8]]) -> Step {
    Step {
        after_ms,
        bytes: parts.concat(),
    }
}

struct Heard {
    code: i32,
    report: Value,
    stderr: Vec<String>,
    /// Bytes the monitor wrote to the port (must be none).
    written: Vec<u8>,
}

impl Heard {
    /// Asserts that the monitor wrote nothing on the line (it only listens).
    #[track_caller]
    fn assert_wrote_nothing(&self) {
        assert!(
            self.written.is_empty(),
            "the monitor wrote {:02X?}",
            self.written
        );
    }
}

/// Starts the monitor on a fresh pty with `args`, plays `steps` on the other end,
/// checking after each that nothing came back, then closes the line (the end of the
/// input) and returns what the monitor reported.
fn listen(args: &[&str], steps: &[Step]) -> Heard {
    listen_paused(args, steps, false)
}

/// As [`listen`]; with `paused`, the monitor is stopped (SIGSTOP) from its announcement
/// until every step is played, so that its next read gets all of them at once: a monitor
/// that the host did not schedule while the traffic began.
fn listen_paused(args: &[&str], steps: &[Step], paused: bool) -> Heard {
    // One folder a run: the tests of this file listen at once, some more than once.
    static RUNS: std::sync::atomic::AtomicUsize = std::sync::atomic::AtomicUsize::new(0);
    let run = RUNS.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let dir = common::Scratch::new(&format!("listen-{run}"));
    let out = dir.join("monitor.json");
    let mut bus = PtyMaster::open(None).unwrap();
    let port = bus.slave_path().to_str().unwrap().to_string();
    let probe = std::fs::File::open(&port).unwrap();
    let cflag = || {
        use std::os::fd::AsRawFd;
        // SAFETY: termios is plain integers (all zeroes is a value); tcgetattr gets an
        // open descriptor and a pointer to it, and fills it or fails.
        let mut t: libc::termios = unsafe { std::mem::zeroed() };
        (unsafe { libc::tcgetattr(probe.as_raw_fd(), &mut t) } == 0).then_some(t.c_cflag)
    };
    // The monitor's serial port sets the line (CLOCAL and the baud rate among others).
    let before = cflag();
    let set_up = || cflag() != before;
    let mut monitor = common::Monitor::spawn(
        Run::words("monitor --port")
            .arg(&port)
            .args(["--model", "f510", "--format", "json", "-o"])
            .arg(&out)
            // The line is given: the search without -b has its own test.
            .args(if args.contains(&"-b") {
                &[][..]
            } else {
                &["-b", "9600"][..]
            })
            .args(args)
            .command(),
    );
    if args.contains(&"--quiet") {
        // Nothing is announced: the port is open and set when its termios changed, and
        // serialport sets the line before it returns the port; give the monitor the
        // moment from there to its first read.
        let deadline = Instant::now() + Duration::from_secs(30);
        while !set_up() {
            assert!(
                Instant::now() < deadline,
                "the monitor never set the port up"
            );
            std::thread::sleep(Duration::from_millis(10));
        }
        std::thread::sleep(Duration::from_millis(200));
    } else {
        monitor.until_listening();
    }
    if paused {
        monitor.signal(nix::sys::signal::Signal::SIGSTOP);
    }
    let mut written = Vec::new();
    let mut buf = [0u8; 256];
    for s in steps {
        std::thread::sleep(Duration::from_millis(s.after_ms));
        bus.send(&s.bytes).unwrap();
        let n = bus.recv(&mut buf, Duration::from_millis(1)).unwrap();
        written.extend_from_slice(&buf[..n]);
    }
    if paused {
        monitor.signal(nix::sys::signal::Signal::SIGCONT);
    }
    // The monitor has read every byte (a busy host may make it late: wait for it, as
    // the end of the input drops what is still queued), then a last look for anything
    // written.
    let unread = || {
        use std::os::fd::AsRawFd;
        let mut n: libc::c_int = 0;
        // SAFETY: FIONREAD writes one int through the pointer it is given.
        let rc = unsafe { libc::ioctl(probe.as_raw_fd(), libc::FIONREAD, &mut n) };
        if rc == 0 {
            n
        } else {
            0
        }
    };
    let deadline = Instant::now() + Duration::from_secs(30);
    while unread() > 0 {
        assert!(
            Instant::now() < deadline,
            "the monitor never read what was sent"
        );
        std::thread::sleep(Duration::from_millis(10));
    }
    std::thread::sleep(Duration::from_millis(300));
    let n = bus.recv(&mut buf, Duration::from_millis(300)).unwrap();
    written.extend_from_slice(&buf[..n]);
    drop(probe);
    drop(bus);
    let (status, stderr) = monitor.finish(
        Duration::from_secs(30),
        "the monitor, at the end of its input,",
    );
    let report = common::report_file(&out)
        .unwrap_or_else(|e| panic!("no report ({e}); stderr: {stderr:#?}"));
    Heard {
        code: status.code().unwrap_or(-1),
        report,
        stderr,
        written,
    }
}

fn errors(r: &Value, address: &str) -> Vec<String> {
    node(r, address)["errors"]
        .as_object()
        .unwrap()
        .keys()
        .cloned()
        .collect()
}

#[test]
fn the_drive_answering_as_the_manual_says_passes_and_nothing_is_written() {
    let w = write(1, 0x2502, 4500);
    let b = write(0, 0x2502, 1000);
    let heard = listen(
        &["-a", "1", "--window", "3000", "--allowance", "1000"],
        &[
            step(100, &[&read(1, 0x2520, 2), &values(1, &[0, 1])]),
            step(100, &[&w, &w]),
            step(100, &[&read(1, 0x2530, 1)]),
            step(100, &[&exception(1, 3, 2)]),
            step(100, &[&b]),
            step(300, &[&read(1, 0x2520, 1)]),
            step(100, &[&values(1, &[3])]),
        ],
    );
    heard.assert_wrote_nothing();
    let r = &heard.report;
    assert_eq!(r["kind"], "monitor");
    // The read past the end of the map is the master's finding (a deviation of the
    // master), not the drive's, which answered it as the manual says.
    let n1 = errors(r, "01");
    assert_eq!(n1, ["master.register-not-in-map"], "{:#}", r["monitor"]);
    assert!(!n1.iter().any(|k| k.starts_with("drive.")));
    let s = node(r, "01");
    assert_eq!(s["exchanges"], 4, "{s:#}");
    assert_eq!(s["replies"], 4);
    assert_eq!(s["timeouts"], 0);
    assert_eq!(s["crc_errors"], 0);
    // (Response times are seen only where a reply came in a piece of its own, which a
    // busy host may merge: their statistics are tested with exact times in the library.)
    assert_eq!(errors(r, "00"), Vec::<String>::new());
    assert_eq!(node(r, "00")["exchanges"], 1);
    // The drive's side passes on node 01.
    let drive = common::check_of(r, "rtu.node01.drive");
    assert_eq!(drive["status"], "pass");
    assert_eq!(
        heard.code, 1,
        "the master's read past the map is a deviation"
    );
    // Live lines: one per exchange, with the register's name from the model.
    let live: Vec<&String> = heard
        .stderr
        .iter()
        .filter(|l| l.contains("node 01"))
        .collect();
    assert_eq!(live.len(), 4, "{:#?}", heard.stderr);
    assert!(
        live.iter()
            .any(|l| l.contains("45.00 Hz") && l.contains("copy of the request")),
        "{live:#?}"
    );
    assert!(live.iter().all(|l| l.contains("CRC ok")), "{live:#?}");
}

/// Traffic that begins right after the monitor says it is listening is heard whole,
/// even when the host gives the monitor no time until the whole exchange is queued (the
/// monitor is stopped meanwhile): its first read came before the announcement, so what
/// comes after it is never taken for the tail of a frame already under way. (In CI the
/// announcement came before the first read once, and a busy host dropped a request as
/// the tail of a frame.)
#[test]
fn traffic_right_after_the_announcement_is_heard_whole() {
    let heard = listen_paused(
        &["-a", "1"],
        &[step(0, &[&read(1, 0x2520, 2), &values(1, &[0, 1])])],
        true,
    );
    heard.assert_wrote_nothing();
    let notices = heard.report["monitor"]["notices"].as_array().unwrap();
    assert!(
        notices.iter().all(|n| {
            let n = n.as_str().unwrap();
            !n.contains("middle of the traffic") && !n.contains("first frame heard was a reply")
        }),
        "{notices:#?}"
    );
    assert_eq!(
        node(&heard.report, "01")["exchanges"],
        1,
        "{:#}",
        heard.report["monitor"]
    );
    assert_eq!(heard.code, 0, "{:#}", heard.report["checks"]);
}

#[test]
fn an_installation_that_only_polls_gives_exit_0() {
    let heard = listen(
        &[
            "-a",
            "1",
            "--window",
            "3000",
            "--allowance",
            "1000",
            "--quiet",
        ],
        &[
            step(100, &[&read(1, 0x2520, 2), &values(1, &[0, 1])]),
            step(100, &[&read(1, 0x2521, 1)]),
            step(100, &[&values(1, &[7])]),
        ],
    );
    heard.assert_wrote_nothing();
    assert_eq!(heard.code, 0, "{:#}", heard.report["checks"]);
    assert_eq!(heard.report["summary"]["deviation"], 0);
    assert_eq!(node(&heard.report, "01")["exchanges"], 2);
    assert!(
        heard.stderr.iter().all(|l| !l.contains("node 01")),
        "--quiet: {:#?}",
        heard.stderr
    );
}

#[test]
fn each_fault_is_found_as_its_kind_on_its_node() {
    let mut bad = values(1, &[7]);
    let n = bad.len();
    bad.swap(n - 1, n - 2);
    let b = write(0, 0x2502, 1000);
    let heard = listen(
        &["-a", "1,2", "--window", "5000", "--allowance", "1000"],
        &[
            // Node 01: a wrong exception code (03H where the manual gives 02H).
            step(100, &[&read(1, 0x2530, 1), &exception(1, 3, 3)]),
            // Node 01: a reply whose CRC bytes are swapped.
            step(200, &[&read(1, 0x2520, 1), &bad]),
            // Node 01: a reply 2.5 s after its request (the limit is about 1 s here).
            step(200, &[&read(1, 0x2520, 1)]),
            step(2500, &[&values(1, &[7])]),
            // A broadcast write, and a reply to it.
            step(200, &[&b]),
            step(100, &[&b]),
            // Node 02 asked, and a reply carrying node 01's address.
            step(200, &[&read(2, 0x2520, 1), &values(1, &[7])]),
        ],
    );
    heard.assert_wrote_nothing();
    assert_eq!(heard.code, 1);
    let r = &heard.report;
    let n1 = errors(r, "01");
    for want in [
        "drive.wrong-exception",
        "drive.bad-checksum",
        "drive.late-reply",
        "master.register-not-in-map",
    ] {
        assert!(
            n1.contains(&want.to_string()),
            "{want} not on node 01: {n1:?}"
        );
    }
    assert_eq!(node(r, "01")["crc_errors"], 1);
    assert!(
        errors(r, "00").contains(&"drive.unexpected-reply".to_string()),
        "{:?}",
        errors(r, "00")
    );
    assert!(
        errors(r, "02").contains(&"drive.wrong-address".to_string()),
        "{:?}",
        errors(r, "02")
    );
    // Each finding is a result of its own, with the frames and the manual's citation.
    let c = common::check_of(r, "rtu.node01.drive.wrong-exception");
    assert_eq!(c["status"], "deviation");
    assert_eq!(c["node"], "01");
    assert_eq!(c["exchanges"][0]["expected"], "01 83 02 C0 F1");
    assert_eq!(c["exchanges"][0]["reply"], "01 83 03 01 31");
    assert_eq!(
        c["exchanges"][0]["differs_at"],
        serde_json::json!([2, 3, 4])
    );
    assert!(
        c["source"].as_str().unwrap().contains("exception code"),
        "{}",
        c["source"]
    );
}

/// The simulator's drive, quirk by quirk, heard by the monitor: each planted fault is
/// found as its kind on its node, and the drive without a quirk gives none. The drive's
/// transmissions are played into the monitor at the times the drive gives them (after
/// the end of each request), so the times are exact.
#[test]
fn each_simulator_quirk_is_found_as_its_kind_on_its_node() {
    use std::sync::Arc;

    use conformance::codec::timing::{LineSettings, Parity};
    use conformance::model::DriveModel;
    use conformance::monitor::{Monitor, MonitorConfig};
    use conformance::sim::{Drive, Quirk};

    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let model = Arc::new(DriveModel::builtin("f510").unwrap());
    let script = [
        read(1, 0x2520, 1),
        read(1, 0x2530, 1),
        write(0, 0x2502, 1000),
        read(2, 0x2520, 1),
        read(1, 0x2521, 1),
    ];
    let heard = |quirks: &[Quirk]| {
        let mut drive =
            Drive::new(model.clone(), 1, model.response_delay(&line)).with_quirks(quirks);
        let mut m = Monitor::new(
            (*model).clone(),
            MonitorConfig {
                mode: Mode::Rtu,
                line,
                nodes: vec![1],
                window: Duration::from_millis(1000),
                response_allowance: Duration::from_millis(20),
                gap_allowance: Duration::from_millis(5),
            },
        )
        .unwrap();
        let base = Instant::now();
        for (i, req) in script.iter().enumerate() {
            let t = Duration::from_millis(300 * i as u64 + 100);
            m.idle(t);
            m.feed(t, req);
            let outcome = drive.handle(Mode::Rtu, req, base + t);
            for tx in outcome.sends {
                m.idle(t + tx.after);
                m.feed(t + tx.after, &tx.bytes);
            }
        }
        m.idle(Duration::from_secs(10));
        m.finish();
        let mut found: Vec<(u8, String)> = m
            .nodes()
            .iter()
            .flat_map(|(n, s)| s.errors.keys().map(move |k| (*n, k.clone())))
            .filter(|(_, k)| k.starts_with("drive."))
            .collect();
        found.sort();
        found
    };
    assert_eq!(
        heard(&[]),
        Vec::<(u8, String)>::new(),
        "the drive without a quirk"
    );
    let cases: [(Quirk, u8, &str); 8] = [
        (Quirk::WrongException, 1, "drive.wrong-exception"),
        (Quirk::LateReply(40), 1, "drive.late-reply"),
        (Quirk::ReplyToBroadcast, 0, "drive.unexpected-reply"),
        (Quirk::CrcSwap, 1, "drive.bad-checksum"),
        (Quirk::GarbageBeforeReply, 1, "drive.extra-bytes"),
        (Quirk::AnswerEveryAddress, 2, "drive.unexpected-reply"),
        (Quirk::TruncatedReply, 1, "drive.truncated"),
        (Quirk::DropEvery(2), 1, "drive.no-reply"),
    ];
    for (quirk, node, kind) in cases {
        // That kind on that node, and nothing else on the drive's side.
        assert_eq!(heard(&[quirk]), [(node, kind.to_string())], "{quirk:?}");
    }
}

/// `--mode auto` tells the mode from two valid frames, says which, and judges the
/// exchanges it heard while telling (they are replayed, not lost).
#[test]
fn mode_auto_tells_rtu_from_ascii_and_judges_what_it_heard_meanwhile() {
    for mode in [Mode::Rtu, Mode::Ascii] {
        let frame =
            |address: u8, pdu: Pdu<'_>| Message { address, pdu }.to_frame_vec(mode).unwrap();
        let req = frame(
            1,
            Pdu::ReadRequest {
                start: 0x2520,
                count: 1,
            },
        );
        let rep = frame(
            1,
            Pdu::ReadResponse {
                values: Registers::new(&[0, 7]).unwrap(),
            },
        );
        let heard = listen(
            &[
                "-a",
                "1",
                "--mode",
                "auto",
                "--window",
                "3000",
                "--allowance",
                "1000",
            ],
            &[
                step(100, &[&req]),
                step(30, &[&rep]),
                step(100, &[&req]),
                step(30, &[&rep]),
            ],
        );
        let r = &heard.report;
        assert_eq!(r["monitor"]["mode"], mode.to_string(), "{:#}", r["monitor"]);
        assert_eq!(node(r, "01")["exchanges"], 2, "{:#}", r["monitor"]);
        assert!(errors(r, "01").is_empty(), "{:#}", r["monitor"]);
        assert_eq!(heard.code, 0);
        assert!(
            heard
                .stderr
                .iter()
                .any(|l| l.starts_with(&format!("--mode auto: {mode}"))),
            "{:#?}",
            heard.stderr
        );
        heard.assert_wrote_nothing();
    }
}
