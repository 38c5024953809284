//! `conformance monitor` judging masters nobody here wrote: mbpoll, pymodbus's serial
//! client, minimalmodbus and a libmodbus client (`tests/libmodbus/client.c`, built here)
//! each poll and write a simulated F510 on `conformance bus`, while the monitor listens
//! on a third endpoint. For each: the monitor hears every request and its reply, finds
//! nothing wrong on the drive's side, never writes a byte (the bus's log names every
//! writer), and says what the master did on the wire (printed as NOTE lines: which
//! masters keep t3.5, which retry and how soon). With a drive that drops every second
//! reply, the monitor finds the missing replies on the drive's side and the retries of
//! the master that makes them. The suite's `send --burst` and a collision of two drives
//! are heard too.
//!
//! Devices nobody here wrote: pymodbus's and libmodbus's servers as the drive on the bus,
//! checked by the suite's own `check` while the monitor listens; for every exchange of
//! check's report the monitor's log (`--log`) agrees on whether the device deviated.
//!
//! What the masters did when this was written (pymodbus 3.16.1, minimalmodbus 2.1.1,
//! Debian mbpoll 1.5 and libmodbus 3.1.6) is in docs/src/monitor.md.
#![cfg(unix)]

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::Duration;

use common::{need, note, python, words, Kill, Peer, Run, Scratch};
use serde_json::Value;

/// A bus with a simulated F510 at node 1 (9600 8E1), an endpoint `master` for the
/// program under test, and the monitor listening on the endpoint `tap`.
struct Listening {
    bus: common::Bus,
    master: PathBuf,
    monitor: common::Monitor,
    report: PathBuf,
    log: PathBuf,
    /// The device nobody here wrote, where there is one (it goes before the bus).
    _device: Option<Kill>,
}

impl Listening {
    /// [`Listening::start`] in a scratch folder `name`, where `peer` (the master under
    /// test) is installed; None (after SKIPPED) where it is not.
    fn for_peer(peer: Peer, name: &str, drive: &[&str]) -> Option<(Scratch, Listening)> {
        if !need(peer) {
            return None;
        }
        let d = Scratch::new(name);
        let l = Listening::start(&d, drive);
        Some((d, l))
    }

    fn start(d: &Path, drive: &[&str]) -> Listening {
        Listening::start_on(d, "1", &[], drive)
    }

    /// [`Listening::start`] with the drives `nodes` ("1,2") and the line settings `line`
    /// (`-b 2400`), which the bus and the monitor share.
    fn start_on(d: &Path, nodes: &str, line: &[&str], drive: &[&str]) -> Listening {
        let mut bus = vec!["--model", "f510", "-a", nodes];
        bus.extend_from_slice(line);
        bus.extend_from_slice(drive);
        let mut monitor = vec!["-a", nodes];
        monitor.extend_from_slice(line);
        Listening::with(d, &bus, &monitor, None)
    }

    /// A bus with `bus` arguments (its drives, its line), the monitor on `tap` with
    /// `monitor` arguments (its nodes and line), and where `device` is given, a program
    /// nobody here wrote as the drive on the endpoint `dev` (its path is the command's
    /// last argument), answering before the monitor starts.
    fn with(
        d: &Path,
        bus: &[&str],
        monitor: &[&str],
        device: Option<(Command, &[&str])>,
    ) -> Listening {
        let (master, tap, dev, log) = (
            d.join("master"),
            d.join("tap"),
            d.join("dev"),
            d.join("line.jsonl"),
        );
        let mut links = vec![
            format!("master={}", master.display()),
            format!("tap={}", tap.display()),
        ];
        if device.is_some() {
            links.push(format!("dev={}", dev.display()));
        }
        let mut args: Vec<&str> = links.iter().flat_map(|l| ["--link", l]).collect();
        args.extend(["--log", log.to_str().unwrap()]);
        args.extend(bus);
        // Each endpoint's line is printed once its link is made.
        let mut bus = common::Bus::start(&args, links.len());
        assert!(bus.guard.0.try_wait().unwrap().is_none(), "the bus ended");
        let device = device.map(|(mut c, line)| {
            common::wait_for(&dev);
            let guard = Kill::spawn(c.arg(&dev).stdin(Stdio::null()).stdout(Stdio::null()));
            common::wait_until_answers(&master, "rtu", line);
            guard
        });
        let report = d.join("monitor.json");
        let monitor = common::Monitor::start(
            Run::words("monitor --model f510")
                // The bus's line is given (the search without -b has its own test).
                .args(if monitor.contains(&"-b") {
                    &[][..]
                } else {
                    &["-b", "9600"][..]
                })
                .args(monitor)
                .arg("--port")
                .arg(&tap)
                .arg("--log")
                .arg(d.join("heard.jsonl"))
                .arg("-o")
                .arg(&report)
                .command(),
        );
        Listening {
            bus,
            master,
            monitor,
            report,
            log,
            _device: device,
        }
    }

    /// Waits until the monitor printed `n` live lines (one per exchange or lone frame),
    /// then stops it with SIGINT and the bus with SIGTERM: the monitor's exit code, its
    /// report, its live lines and the bus's log.
    fn stop(mut self, n: usize) -> (i32, Value, Vec<String>, Vec<Value>) {
        let mut lines = Vec::new();
        while lines.len() < n {
            match self.monitor.stderr.next_line(Duration::from_secs(20)) {
                Some(l) => lines.push(l),
                None => break,
            }
        }
        let signal = |k: &Kill, s| {
            let pid = nix::unistd::Pid::from_raw(i32::try_from(k.0.id()).unwrap());
            nix::sys::signal::kill(pid, s).unwrap();
        };
        self.monitor.signal(nix::sys::signal::Signal::SIGINT);
        let (status, _) = self
            .monitor
            .finish(Duration::from_secs(20), "the monitor after SIGINT");
        lines.extend(self.monitor.stderr.pending());
        // The device first: the bus's endpoints go with the bus.
        self._device = None;
        signal(&self.bus.guard, nix::sys::signal::Signal::SIGTERM);
        self.bus
            .guard
            .wait_within(Duration::from_secs(10), "the bus after SIGTERM");
        let text = std::fs::read_to_string(&self.report)
            .unwrap_or_else(|e| panic!("no report ({e}); monitor said {lines:#?}"));
        let report: Value = serde_json::from_str(&text)
            .unwrap_or_else(|e| panic!("-o monitor.json is not JSON ({e}): {text}"));
        let log = std::fs::read_to_string(&self.log)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
        (status.code().unwrap_or(-1), report, lines, log)
    }
}

/// Node 01's statistics in the monitor's report.
fn node01(r: &Value) -> &Value {
    common::monitor_node(r, "01")
}

/// The kinds of finding on node 01 of one side ("drive" or "master"), with their counts.
fn findings(r: &Value, side: &str) -> Vec<(String, u64)> {
    node01(r)["errors"]
        .as_object()
        .unwrap()
        .iter()
        .filter(|(k, _)| k.starts_with(&format!("{side}.")))
        .map(|(k, v)| (k.clone(), v.as_u64().unwrap()))
        .collect()
}

/// What every clean session shows: `requests` requests to node 01 at least, each
/// answered, nothing wrong on the drive's side, and not one byte from the monitor's
/// endpoint on the line. Prints what the monitor found on the master's side.
fn assert_heard_clean(who: &str, heard: &(i32, Value, Vec<String>, Vec<Value>), requests: u64) {
    let (code, r, lines, log) = heard;
    let n = node01(r);
    assert!(
        n["requests"].as_u64().unwrap() >= requests,
        "{who}: {n:#}\n{lines:#?}"
    );
    assert_eq!(n["replies"], n["requests"], "{who}: {n:#}\n{lines:#?}");
    assert_eq!(n["timeouts"], 0, "{who}: {n:#}");
    assert_eq!(n["crc_errors"], 0, "{who}: {n:#}");
    // On the drive's side nothing, but what a busy host makes of the timing (the bus's
    // log says when it ran late).
    let drive: serde_json::Map<String, Value> = n["errors"]
        .as_object()
        .unwrap()
        .iter()
        .filter(|(k, _)| k.starts_with("drive."))
        .map(|(k, v)| (k.clone(), v.clone()))
        .collect();
    assert_eq!(
        common::unexplained(&Value::Object(drive), log),
        Vec::<String>::new(),
        "{who}: {n:#}\n{lines:#?}"
    );
    let master = findings(r, "master");
    // Exit 1 exactly when the master did something the manual does not allow.
    let deviations = r["summary"]["deviation"].as_u64().unwrap();
    assert_eq!(
        *code,
        i32::from(deviations > 0),
        "{who}: {:#}",
        r["summary"]
    );
    assert!(
        log.iter()
            .filter(|e| e["event"] == "tx")
            .all(|e| e["from"] != "tap"),
        "{who}: the monitor's endpoint wrote to the line"
    );
    note(&format!(
        "{who}: {} requests, all answered; on the master's side: {}; response p50 {} ms",
        n["requests"],
        if master.is_empty() {
            "nothing".to_string()
        } else {
            format!("{master:?}")
        },
        n["response_ms"]["p50"]
    ));
    for l in lines
        .iter()
        .filter(|l| l.contains("DEVIATION") || l.contains("OBSERVATION"))
    {
        note(&format!("{who}: {}", l.trim()));
    }
}

/// Python that opens pymodbus's serial client `c` on `port` with `timeout` (seconds) and
/// `retries`. Parity E on a pseudo-terminal: pymodbus's connect() refuses it (EINVAL) and
/// falls back to N here; the line carries bytes, whatever the program's termios says.
fn pymodbus_connect(port: &Path, timeout: &str, retries: u32) -> String {
    format!(
        "from pymodbus.client import ModbusSerialClient\n\
         for parity in ('E', 'N'):\n\
         \x20   c = ModbusSerialClient(port={port:?}, baudrate=9600, parity=parity, stopbits=1, bytesize=8, timeout={timeout}, retries={retries})\n\
         \x20   if c.connect():\n\
         \x20       break\n\
         else:\n\
         \x20   raise SystemExit('pymodbus cannot open the endpoint')\n"
    )
}

/// The libmodbus client, built into `d`; `None` (after SKIPPED) without libmodbus.
fn libmodbus_client(d: &Path) -> Option<PathBuf> {
    common::libmodbus_program(d, "client")
}

/// Runs `cmd` to its end (60 s at most): its stdout, which must come with exit 0 when
/// `must_succeed`.
fn run(cmd: Run, must_succeed: bool) -> String {
    let o = cmd.timeout(Duration::from_secs(60)).run();
    if must_succeed {
        assert_eq!(o.code, Some(0), "{o}");
    }
    o.stdout
}

#[test]
fn mbpoll_polling_and_writing_is_heard_and_the_drive_passes() {
    let Some((_d, l)) = Listening::for_peer(Peer::Mbpoll, "mbpoll", &[]) else {
        return;
    };
    let mbpoll = |args: &[&str]| {
        Run::program("mbpoll", words("-m rtu -b 9600 -P even -a 1 -o 2")).args(args)
    };
    // mbpoll counts registers from 1: 9520 is 252FH, 9475 is 2502H.
    for _ in 0..3 {
        let out = run(
            mbpoll(&["-t", "4:hex", "-r", "9520", "-1"]).arg(&l.master),
            true,
        );
        assert!(out.contains("[9520]: \t0x0510"), "{out}");
    }
    run(mbpoll(&["-r", "9475"]).arg(&l.master).arg("1234"), true);
    let heard = l.stop(4);
    assert_heard_clean("mbpoll", &heard, 4);
}

#[test]
fn pymodbus_polling_and_writing_is_heard_and_the_drive_passes() {
    let Some((_d, l)) = Listening::for_peer(Peer::Pymodbus, "pymodbus", &[]) else {
        return;
    };
    // Parity E on a pseudo-terminal: pymodbus's connect() refuses it (EINVAL) and falls
    // back to N here; the line carries bytes, whatever the program's termios says.
    let script = format!(
        "{connect}\
         for _ in range(3):\n\
         \x20   print(hex(c.read_holding_registers(0x252F, count=1, device_id=1).registers[0]))\n\
         assert not c.write_register(0x2502, 0x04D2, device_id=1).isError()\n\
         print(hex(c.read_holding_registers(0x2502, count=1, device_id=1).registers[0]))\n\
         c.close()\n",
        connect = pymodbus_connect(&l.master, "2", 0)
    );
    let out = run(Run::program(python(), ["-c", &script]), true);
    assert_eq!(
        out.lines().collect::<Vec<_>>(),
        ["0x510", "0x510", "0x510", "0x4d2"]
    );
    let heard = l.stop(5);
    assert_heard_clean("pymodbus", &heard, 5);
}

#[test]
fn minimalmodbus_polling_and_writing_is_heard_and_the_drive_passes() {
    let Some((_d, l)) = Listening::for_peer(Peer::Minimalmodbus, "minimalmodbus", &[]) else {
        return;
    };
    let script = format!(
        "import minimalmodbus\n\
         i = minimalmodbus.Instrument({port:?}, 1)\n\
         i.serial.baudrate = 9600\n\
         i.serial.timeout = 2\n\
         for _ in range(3):\n\
         \x20   print(hex(i.read_register(0x252F)))\n\
         i.write_register(0x2502, 0x04D2, functioncode=6)\n\
         print(hex(i.read_register(0x2502)))\n",
        port = l.master.to_str().unwrap()
    );
    let out = run(Run::program(python(), ["-c", &script]), true);
    assert_eq!(
        out.lines().collect::<Vec<_>>(),
        ["0x510", "0x510", "0x510", "0x4d2"]
    );
    let heard = l.stop(5);
    assert_heard_clean("minimalmodbus", &heard, 5);
}

#[test]
fn a_libmodbus_client_polling_and_writing_is_heard_and_the_drive_passes() {
    let d = Scratch::new("libmodbus");
    let Some(client) = libmodbus_client(&d) else {
        return;
    };
    let l = Listening::start(&d, &[]);
    let out = run(Run::program(&client, [&l.master]).args(["1", "3"]), true);
    assert_eq!(
        out.lines().collect::<Vec<_>>(),
        [
            "read 252F 0510",
            "read 252F 0510",
            "read 252F 0510",
            "write 2502 ok",
            "read 2502 04D2"
        ]
    );
    let heard = l.stop(5);
    assert_heard_clean("libmodbus", &heard, 5);
}

/// A drive that drops every second reply: the monitor finds the missing replies on the
/// drive's side, and counts the retries of pymodbus (retries=2), which sends the same
/// request again after its timeout. The libmodbus client does not retry: its missing
/// replies are timeouts and nothing more.
#[test]
fn replies_a_drive_drops_are_found_and_the_retries_of_the_master_counted() {
    let Some((_d, l)) =
        Listening::for_peer(Peer::Pymodbus, "retries", &["--quirk", "drop-every=2"])
    else {
        return;
    };
    let script = format!(
        "{connect}\
         for _ in range(4):\n\
         \x20   r = c.read_holding_registers(0x252F, count=1, device_id=1)\n\
         \x20   print('error' if r.isError() else hex(r.registers[0]))\n\
         c.close()\n",
        connect = pymodbus_connect(&l.master, "0.3", 2)
    );
    let out = run(Run::program(python(), ["-c", &script]), false);
    // Every read gets its answer, at the first try or at a retry.
    assert_eq!(
        out.lines().collect::<Vec<_>>(),
        ["0x510", "0x510", "0x510", "0x510"],
        "{out}"
    );
    let (code, r, lines, log) = l.stop(8);
    let n = node01(&r);
    assert_eq!(code, 1, "{:#}", r["summary"]);
    let drive = findings(&r, "drive");
    let master = findings(&r, "master");
    assert!(
        drive.iter().any(|(k, _)| k == "drive.no-reply"),
        "{drive:?}\n{lines:#?}"
    );
    assert!(n["timeouts"].as_u64().unwrap() >= 2, "{n:#}");
    assert!(n["retries"].as_u64().unwrap() >= 2, "{n:#}\n{lines:#?}");
    assert!(
        master.iter().any(|(k, _)| k == "master.retry"),
        "{master:?}\n{lines:#?}"
    );
    assert!(log
        .iter()
        .filter(|e| e["event"] == "tx")
        .all(|e| e["from"] != "tap"));
    for l in lines.iter().filter(|l| l.contains("retry")) {
        note(&format!("pymodbus retries: {}", l.trim()));
    }
}

/// The suite's own `send --burst` puts two requests on the line in one write, with no
/// t3.5 between them: the monitor finds the master's fault. Where its reads prove the
/// silence short, that is `master.no-t3.5`; a busy host that read the second request late
/// proves nothing about the silence (docs/src/monitor.md), and then the fault is the
/// second request sent while the first was still due its reply. (The drive frames the two
/// as one frame with a wrong CRC and stays silent, as the model says.)
#[test]
fn a_master_sending_two_requests_without_t35_is_found() {
    let d = Scratch::new("burst");
    let l = Listening::start(&d, &[]);
    let out = Run::words("send --model f510 --mode rtu --burst --port")
        .arg(&l.master)
        .args(["--timeout", "300", "0103252F0001BECF", "0103252F0001BECF"])
        .run();
    assert!(out.code.is_some_and(|c| c < 2), "send: {out}");
    let (code, r, lines, log) = l.stop(2);
    assert_eq!(code, 1, "{:#}\n{lines:#?}", r["summary"]);
    let master = findings(&r, "master");
    assert!(
        master
            .iter()
            .any(|(k, _)| k == "master.no-t3.5" || k == "master.request-before-reply"),
        "{master:?}\n{lines:#?}"
    );
    assert!(log
        .iter()
        .filter(|e| e["event"] == "tx")
        .all(|e| e["from"] != "tap"));
}

/// Two drives answer one request at once (node 2 answers every address), 2400 baud so
/// that the replies overlap on the line: the bus logs a collision, and the monitor hears
/// its damage as a reply that is not one (a bad checksum, or bytes that are no frame);
/// or, where the two sent the same bytes in step, nothing wrong, as on a real line.
#[test]
fn a_collision_on_the_line_is_heard_as_damage() {
    let d = Scratch::new("collision");
    let l = Listening::start_on(
        &d,
        "1,2",
        &["-b", "2400"],
        &["--quirk", "answer-every-address@2"],
    );
    let out = Run::words("send --model f510 --mode rtu -b 2400 --port")
        .arg(&l.master)
        .args(["--timeout", "500", "0103252F0001BECF"])
        .run();
    assert!(out.code.is_some_and(|c| c < 3), "send: {out}");
    let (code, r, lines, log) = l.stop(1);
    let collision = log
        .iter()
        .find(|e| e["event"] == "collision")
        .expect("the bus logged no collision");
    // Two drives that start the same bytes within one bit of each other drive the pair
    // alike: the wired-AND of two equal waveforms is that waveform, and the listeners
    // read it clean, as on a real line. Then nothing is heard wrong.
    let read = collision["line_hex"].as_str().unwrap();
    let in_step = log
        .iter()
        .filter(|e| e["event"] == "tx" && e["from"] != "master")
        .any(|e| e["hex"].as_str().unwrap().contains(read));
    if in_step {
        assert_eq!(findings(&r, "drive"), [], "{read}\n{lines:#?}");
        note(&format!(
            "collision in step ({read}): heard clean, as on a real line"
        ));
        return;
    }
    assert_eq!(
        code, 1,
        "{:#}\n{:#}\n{lines:#?}",
        r["summary"], r["monitor"]
    );
    let drive = findings(&r, "drive");
    assert!(
        drive.iter().any(|(k, _)| [
            "drive.bad-checksum",
            "drive.malformed",
            "drive.truncated",
            "drive.extra-bytes",
            "drive.gap-in-reply",
            "drive.wrong-reply"
        ]
        .contains(&k.as_str())),
        "{drive:?}\n{lines:#?}"
    );
    note(&format!("collision heard as: {drive:?}"));
}

/// Check ids whose exchanges the monitor cannot judge as `check` does, with the reason.
const JUDGED_APART: &[(&str, &str)] = &[(
    "rtu.write.frequency-command",
    "check reads 2523H expecting the value it wrote to 2502H: the model links the two, the monitor learns values only from writes to the same register",
)];

/// `check` runs against a device nobody here wrote, through the bus, while the monitor
/// listens: every exchange of check's report is found in the monitor's log (`--log`), in
/// order, and for each the two agree on whether the device's answer differs from the
/// manual's (check: differing bytes, an answer where none is due or none where one is,
/// bytes that are no reply;
/// monitor: a finding
/// on the drive's side that is not about timing), except the checks in [`JUDGED_APART`].
fn check_and_monitor_agree(
    who: &str,
    d: &Path,
    device: Command,
    timeout_ms: &str,
    left_out: &[&str],
) {
    let line = ["-P", "none", "-a", "1"];
    // check never sends a request twice, so a copy of a 06H request is always the
    // device's reply; but a copy later than the manual's response time plus the
    // allowance is taken by the monitor as the master's resend (it cannot know better).
    // A device nobody here wrote, run on a busy host (pymodbus at load average 4 echoed
    // a write 88 ms late), must not turn that rule into a disagreement: the allowance
    // here is all of the window but the last 100 ms. Timing itself is not compared.
    let monitor = ["-P", "none", "-a", "1", "--allowance", "900"];
    let l = Listening::with(d, &["-P", "none"], &monitor, Some((device, &line)));
    let master = l.master.to_str().unwrap().to_string();
    let only: Vec<&str> = [
        "rtu.map",
        "rtu.write",
        "rtu.example",
        "rtu.read-count",
        "rtu.function",
        "rtu.broadcast",
        "rtu.identification",
        "rtu.same-group",
        "rtu.exception",
        "rtu.other-address",
        "rtu.bad-crc",
        "rtu.garbage",
        "rtu.partial",
        "rtu.loop-back",
        "rtu.diagnostics",
        "rtu.order",
    ]
    .into_iter()
    .filter(|o| !left_out.contains(o))
    .collect();
    let mut args = vec![
        "--model",
        "f510",
        "--port",
        &master,
        "--mode",
        "rtu",
        "-P",
        "none",
        "--timeout",
        timeout_ms,
    ];
    for o in &only {
        args.extend(["--only", o]);
    }
    let (_, v) = common::check_device(d, &args, Duration::from_secs(300));
    assert_eq!(v["complete"], true, "{who}: {}", v["stopped"]);
    std::thread::sleep(Duration::from_millis(300));
    let (_, r, _, bus_log) = l.stop(0);
    let heard = common::json_lines_file(&d.join("heard.jsonl"));
    let (agree, apart) = common::agree::exchanges_on_bus(who, &v, &heard, JUDGED_APART, &bus_log);
    assert!(agree > 50, "{who}: only {agree} exchanges compared");
    note(&format!(
        "{who}: check and monitor agree on {agree} exchanges, {apart} judged apart ({}); monitor's drive side: {}",
        JUDGED_APART.iter().map(|(i, _)| *i).collect::<Vec<_>>().join(", "),
        node01(&r)["errors"]
    ));
}

#[test]
fn check_and_monitor_judge_pymodbus_s_server_alike() {
    if !need(Peer::Pymodbus) {
        return;
    }
    let d = Scratch::new("pymodbus-server");
    // pymodbus_server.py PORT (RTU, node 1, 9600 8N1): the bus's endpoint comes last.
    let mut c = Command::new(python());
    c.arg(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/interop/pymodbus_server.py"
    ))
    .stderr(Stdio::null());
    // pymodbus's server, its bytes coming at the line's pace, never answers again after
    // a request with a function it does not know (41H), garbage before a frame, or the
    // start of a frame left unfinished (docs/src/monitor.md): those checks, and the
    // ones after them, are left out.
    check_and_monitor_agree(
        "pymodbus server",
        &d,
        c,
        "1000",
        &[
            "rtu.function",
            "rtu.garbage",
            "rtu.partial",
            "rtu.diagnostics",
            "rtu.order",
        ],
    );
}

#[test]
fn check_and_monitor_judge_libmodbus_s_server_alike() {
    let d = Scratch::new("libmodbus-server");
    let Some(exe) = libmodbus_server(&d) else {
        return;
    };
    let mut c = Command::new(exe);
    c.stderr(Stdio::null());
    // libmodbus's server sleeps its response timeout and flushes its input after a
    // request it refuses (as tests/libmodbus_device.rs found): a read sent into that
    // window is lost. 2500 ms gives the runner's probes room.
    check_and_monitor_agree("libmodbus server", &d, c, "2500", &[]);
}

/// tests/libmodbus/server.c, built into `d`; `None` (after SKIPPED) without libmodbus.
fn libmodbus_server(d: &Path) -> Option<PathBuf> {
    common::libmodbus_program(d, "server")
}
