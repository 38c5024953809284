//! `conformance watch`: its CSV and JSON lines parsed back, planted faults counted as
//! their kinds, reads only on the wire, SIGTERM ending with the summary, the table
//! redrawn in place on a terminal (tmux), the HTML trend report, a value changed by
//! another master marked, and pymodbus's serial server watched.
#![cfg(unix)]

mod common;

use std::io::{BufRead, BufReader};

use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use common::{
    bin, line, need, run_bounded, runs, tool_or_skip, words, GatewaySim, Kill, Peer, Run, Scratch,
};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

const LIMIT: Duration = Duration::from_secs(120);

/// `conformance watch ARGS`: exit code, stdout, stderr.
fn watch(args: &[&str]) -> (Option<i32>, String, String) {
    let mut all = vec!["watch"];
    all.extend_from_slice(args);
    run_bounded(&all, LIMIT)
}

/// The JSON lines of a watch's stdout.
fn json_lines(stdout: &str) -> Vec<serde_json::Value> {
    stdout
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect()
}

/// A CSV text (no quoted commas in these rows) as header and rows of fields.
fn csv(stdout: &str) -> (Vec<String>, Vec<Vec<String>>) {
    let mut lines = stdout.split("\r\n").filter(|l| !l.is_empty());
    let header: Vec<String> = lines
        .next()
        .expect("no header")
        .split(',')
        .map(String::from)
        .collect();
    let rows = lines
        .map(|l| l.split(',').map(String::from).collect())
        .collect();
    (header, rows)
}

#[test]
fn csv_rows_parse_back_in_rtu_and_ascii() {
    for mode in ["rtu", "ascii"] {
        let (code, out, err) = watch(&line(&[
            "--sim f510 --mode",
            mode,
            "-c 3 --interval 50ms --format csv 2502H status 252FH",
        ]));
        assert_eq!(code, Some(0), "{mode}: {err}");
        let (header, rows) = csv(&out);
        assert_eq!(
            header,
            [
                "time",
                "elapsed_s",
                "node",
                "poll",
                "outcome",
                "rtt_ms",
                "exceptions",
                "observations",
                "2502H",
                "2502H_value",
                "2520H",
                "2520H_value",
                "252FH",
                "252FH_value"
            ]
        );
        assert_eq!(rows.len(), 3, "{mode}: {out}");
        for (i, row) in rows.iter().enumerate() {
            assert_eq!(row.len(), header.len(), "{row:?}");
            assert!(humantime::parse_rfc3339(&row[0]).is_ok(), "{}", row[0]);
            assert!(row[1].parse::<f64>().is_ok());
            assert_eq!(row[2], "01");
            assert_eq!(row[3], (i + 1).to_string());
            assert_eq!(row[4], "ok", "{row:?}");
            assert!(row[5].parse::<f64>().unwrap() > 0.0);
            assert_eq!((row[8].as_str(), row[9].as_str()), ("0000", "0.00"));
            // The simulated F510 is ready (bit 2) and identifies as 0510H.
            assert_eq!((row[10].as_str(), row[11].as_str()), ("0004", "4"));
            assert_eq!(row[12], "0510");
        }
        // Two reads: the command block and the monitor block are two groups.
        assert!(err.contains("3 registers in 2 reads per poll"), "{err}");
    }
}

#[test]
fn json_lines_parse_back_with_units_and_bits() {
    let (code, out, err) = watch(&words("--sim f510 -c 2 --interval 50ms --format jsonl"));
    assert_eq!(code, Some(0), "{err}");
    let rows = json_lines(&out);
    assert_eq!(rows.len(), 2, "{out}");
    for (i, r) in rows.iter().enumerate() {
        assert_eq!(r["poll"], i as u64 + 1);
        assert_eq!(r["node"], "01");
        assert_eq!(r["outcome"], "ok");
        assert!(humantime::parse_rfc3339(r["time"].as_str().unwrap()).is_ok());
        assert!(r["rtt_ms"].as_f64().unwrap() > 0.0);
        let v = &r["values"];
        // The default: the monitor block without its reserved registers, status first.
        assert_eq!(v.as_object().unwrap().len(), 14, "{v}");
        assert!(v.get("2525H").is_none());
        assert_eq!(v["2520H"]["raw"], "0004");
        assert_eq!(v["2520H"]["bits"][0], "Inverter ready (1: ready)");
        assert_eq!(v["2524H"]["unit"], "Hz");
        assert_eq!(v["2524H"]["text"], "0.00 Hz");
        assert_eq!(v["252FH"]["value"], 0x0510);
        assert_eq!(r["observations"].as_array().unwrap().len(), 0);
    }
}

#[test]
fn planted_faults_are_counted_as_their_kinds() {
    // An out-of-range frequency command (one over 400.00 Hz) and an exception on the
    // output frequency's read: exit 1, each counted apart.
    let (code, out, err) = watch(&[
        "--sim",
        "f510",
        "--quirk",
        "stuck-at=2502H:9C41H",
        "--quirk",
        "exception-at=2524H",
        "-c",
        "3",
        "--interval",
        "50ms",
        "--format",
        "jsonl",
        "2502H",
        "output frequency",
        "2501H",
    ]);
    assert_eq!(code, Some(1), "{err}");
    for r in json_lines(&out) {
        assert_eq!(r["outcome"], "exception", "{r}");
        assert_eq!(r["exceptions"], serde_json::json!(["04"]));
        let kinds: Vec<&str> = common::strings(&r["observations"], "kind");
        assert_eq!(kinds, ["out-of-range"], "{r}");
        assert_eq!(r["values"]["2502H"]["text"], "400.01 Hz");
        assert!(r["values"]["2524H"].is_null());
    }
    assert!(
        err.contains("exceptions 3 (04H x3), out of range 3, reserved bits 0"),
        "{err}"
    );

    // A reserved bit of the operation signal (bit 15) is an observation of its own kind,
    // not a reason for exit 1.
    let (code, out, err) = watch(&words(
        "--sim f510 --quirk stuck-at=2501H:8001H -c 2 --interval 50ms --format jsonl 2501H",
    ));
    assert_eq!(code, Some(0), "{err}");
    for r in json_lines(&out) {
        assert_eq!(r["observations"][0]["kind"], "reserved-bit", "{r}");
        assert_eq!(r["outcome"], "ok");
    }
    assert!(err.contains("out of range 0, reserved bits 2"), "{err}");

    // CRC errors and timeouts are counted apart, and are no reason for exit 1.
    for (quirk, outcome, counts) in [
        (
            "crc-swap",
            "bad-checksum",
            "timeouts 0, CRC errors 2, exceptions 0",
        ),
        (
            "dead --timeout 200",
            "timeout",
            "timeouts 2, CRC errors 0, exceptions 0",
        ),
    ] {
        let args = format!("--sim f510 --quirk {quirk} -c 2 --interval 50ms --format csv 2520H");
        let (code, out, err) = watch(&words(&args));
        assert_eq!(code, Some(0), "{quirk}: {err}");
        let (_, rows) = csv(&out);
        assert!(rows.iter().all(|r| r[4] == outcome), "{quirk}: {out}");
        assert!(err.contains(counts), "{quirk}: {err}");
    }
}

#[test]
fn only_reads_go_out() {
    let d = Scratch::new("reads-only");
    let log = d.join("sim.jsonl");
    let (code, _, err) = watch(&line(&[
        "--sim f510 -a 1,2 --sim-log",
        log.to_str().unwrap(),
        "-c 3 --interval 50ms --format csv command monitor",
    ]));
    assert_eq!(code, Some(0), "{err}");
    let text = std::fs::read_to_string(&log).unwrap();
    let requests: Vec<serde_json::Value> = text
        .lines()
        .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
        .filter(|r| r["dir"] == "in" && r["event"] == "frame")
        .collect();
    // Two nodes, three polls, two reads (command block, monitor block) each.
    assert_eq!(requests.len(), 12, "{text}");
    for r in &requests {
        let hex = r["hex"].as_str().unwrap();
        let function = hex.split(' ').nth(1).unwrap();
        assert_eq!(function, "03", "a request that is no read: {hex}");
    }
}

/// The watch `args` build, running in the background: its guard (its stderr kept for when
/// it has ended) and its stdout's lines as they come.
fn watching(args: Run) -> (Kill, std::io::Lines<BufReader<std::process::ChildStdout>>) {
    let mut cmd = args.command();
    let mut child = Kill::spawn(cmd.stdout(Stdio::piped()).stderr(Stdio::piped()));
    let lines = BufReader::new(child.0.stdout.take().unwrap()).lines();
    (child, lines)
}

#[test]
fn sigterm_ends_with_the_summary_and_exit_0() {
    let (mut child, mut lines) =
        watching(Run::words("watch --sim f510 --format csv --interval 50ms"));
    // The header, then a first row: the watch is polling.
    lines.next().unwrap().unwrap();
    lines.next().unwrap().unwrap();
    kill(Pid::from_raw(child.0.id() as i32), Signal::SIGTERM).unwrap();
    let status = child.wait_within(LIMIT, "watch after SIGTERM");
    let err = child.stderr_text();
    assert_eq!(status.code(), Some(0), "{err}");
    common::assert_contains_all(&err, &["watch ended (interrupted)", "node 01: "]);
}

#[test]
fn a_link_that_fails_ends_the_watch_with_its_summary_and_exit_2() {
    let (mut sim, port) = common::sim_pty(&["--model", "f510"]);
    let (mut child, mut lines) = watching(
        Run::words("watch --model f510 --port")
            .arg(&port)
            .args(words("-P even --format csv --interval 50ms 2520H")),
    );
    lines.next().unwrap().unwrap();
    let row = lines.next().unwrap().unwrap();
    assert!(row.contains(",ok,"), "{row}");
    // The simulator goes, and its pseudo-terminal with it.
    sim.0.kill().unwrap();
    let status = child.wait_within(LIMIT, "watch after its link went");
    let err = child.stderr_text();
    assert_eq!(status.code(), Some(2), "{err}");
    common::assert_contains_all(
        &err,
        &[
            "watch ended (the link failed)",
            "result: the link failed (exit 2)",
        ],
    );
    // A link that cannot be opened: exit 2 too.
    let (code, _, err) = watch(&words("--model f510 --port /dev/nonexistent-watch -c 1"));
    assert_eq!(code, Some(2), "{err}");
}

#[test]
fn a_value_another_master_writes_is_marked_changed() {
    // The simulated drive behind a Modbus TCP gateway serves several masters at once:
    // the watch reads, `send` writes 2502H <- 1194H meanwhile.
    let sim = GatewaySim::start("f510", 1, &[]);
    let (mut child, mut lines) = watching(
        Run::words("watch --model f510 --tcp")
            .arg(&sim.addr)
            .args(words("--framing mbap --format jsonl --interval 50ms 2502H")),
    );
    let first: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    assert_eq!(first["values"]["2502H"]["raw"], "0000");
    let (code, out, err) = run_bounded(
        &line(&[
            "send --model f510 --tcp",
            &sim.addr,
            "--framing mbap 0106250211942EF9",
        ]),
        LIMIT,
    );
    assert_eq!(code, Some(0), "{out}{err}");
    let t0 = Instant::now();
    let changed = loop {
        let line = lines.next().expect("the watch ended").unwrap();
        let r: serde_json::Value = serde_json::from_str(&line).unwrap();
        if r["values"]["2502H"]["raw"] == "1194" {
            break r;
        }
        assert!(t0.elapsed() < LIMIT, "the write was never seen");
    };
    assert_eq!(changed["changed"], serde_json::json!(["2502H"]));
    assert_eq!(changed["values"]["2502H"]["text"], "45.00 Hz");
    // The next poll reads the same value: no change.
    let next: serde_json::Value = serde_json::from_str(&lines.next().unwrap().unwrap()).unwrap();
    assert_eq!(next["changed"], serde_json::json!([]));
    kill(Pid::from_raw(child.0.id() as i32), Signal::SIGTERM).unwrap();
    let status = child.wait_within(LIMIT, "watch after SIGTERM");
    assert_eq!(status.code(), Some(0), "{}", child.stderr_text());
}

/// `tmux capture-pane -p` of `session`.
fn pane(session: &str) -> String {
    let o = Command::new("tmux")
        .args(["capture-pane", "-p", "-t", session])
        .output()
        .unwrap();
    String::from_utf8_lossy(&o.stdout).into_owned()
}

#[test]
fn the_table_redraws_in_place_on_a_terminal() {
    if !tool_or_skip(runs("tmux", &["-V"]), "tmux (Debian package tmux)") {
        return;
    }
    let session = format!("watch-test-{}", std::process::id());
    let command = format!(
        "{} watch --sim f510 --quirk stuck-at=2502H:9C41H -c 6 --interval 100ms 2502H monitor; sleep 600",
        bin()
    );
    assert!(runs(
        "tmux",
        &[
            "new-session",
            "-d",
            "-s",
            &session,
            "-x",
            "160",
            "-y",
            "50",
            &command
        ]
    ));
    struct Session(String);
    impl Drop for Session {
        fn drop(&mut self) {
            let _ = Command::new("tmux")
                .args(["kill-session", "-t", &self.0])
                .status();
        }
    }
    let _guard = Session(session.clone());
    let t0 = Instant::now();
    let shown = loop {
        let p = pane(&session);
        if p.contains("watch ended") {
            break p;
        }
        assert!(t0.elapsed() < LIMIT, "the watch did not end: {p}");
        std::thread::sleep(Duration::from_millis(100));
    };
    // Six polls, one table: each redraw went home and cleared the screen.
    common::assert_count(&shown, "watch f510 (", 1);
    assert!(shown.contains("node 01: 6 polls"), "{shown}");
    let row = shown
        .lines()
        .find(|l| l.contains("2502H Frequency command"))
        .unwrap_or_else(|| panic!("{shown}"));
    assert!(row.contains("9C41H") && row.contains("400.01 Hz"), "{row}");
    assert!(row.starts_with(" !"), "out-of-range mark: {row:?}");
    assert!(row.contains("[out of range: 9C40H or less]"), "{row}");
    let status = shown
        .lines()
        .find(|l| l.contains("2520H State signal"))
        .unwrap();
    assert!(status.contains("Inverter ready (1: ready)"), "{status}");
}

#[test]
fn the_html_report_has_a_trend_per_register_and_no_script() {
    let d = Scratch::new("html");
    let page = d.join("watch.html");
    let (code, _, err) = watch(&[
        "--sim",
        "f510",
        "--quirk",
        "stuck-at=2502H:9C41H",
        "-c",
        "4",
        "--interval",
        "50ms",
        "-o",
        page.to_str().unwrap(),
        "2502H",
        "status",
        "output frequency",
    ]);
    assert_eq!(code, Some(1), "{err}");
    let html = std::fs::read_to_string(&page).unwrap();
    for id in ["trend-01-2502", "trend-01-2520", "trend-01-2524"] {
        assert!(html.contains(id), "no chart {id}");
    }
    assert!(!html.contains("<script"), "a script in the page");
    assert!(!html.contains("src="), "something fetched");
    // The out-of-range points are drawn red, with their value.
    assert!(html.contains("9C41H at"), "no out-of-range point");
    if !need(Peer::Chromium) {
        return;
    }
    let png = d.join("watch.png");
    let ok = Command::new(common::chromium().unwrap())
        .args(["--headless", "--no-sandbox", "--disable-gpu"])
        .arg(format!("--screenshot={}", png.display()))
        .args(["--window-size=1300,900"])
        .arg(format!("file://{}", page.display()))
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .unwrap();
    assert!(ok.success());
    assert!(std::fs::metadata(&png).unwrap().len() > 10_000);
}

#[test]
fn pymodbus_serial_server_is_watched_and_its_exceptions_counted() {
    for mode in ["rtu", "ascii"] {
        let d = Scratch::new(&format!("pymodbus-{mode}"));
        // pymodbus serves the command block only: the monitor block's reads get 02H.
        let Some(peer) = common::pymodbus_serial_blocks(&d, mode, "2500-251F") else {
            return;
        };
        let port = peer.port.to_str().unwrap();
        let on_port = |rest: &str| {
            watch(&line(&[
                "--model f510 --port",
                port,
                "-P none -m",
                mode,
                rest,
            ]))
        };
        let (code, out, err) = on_port("-c 3 --interval 50ms --format csv 2502H");
        assert_eq!(code, Some(0), "{mode}: {err}");
        let (_, rows) = csv(&out);
        assert_eq!(rows.len(), 3);
        assert!(rows.iter().all(|r| r[4] == "ok"), "{mode}: {out}");
        let (code, out, err) = on_port("-c 2 --interval 50ms --format csv monitor");
        assert_eq!(code, Some(1), "{mode}: {err}");
        let (_, rows) = csv(&out);
        assert!(
            rows.iter().all(|r| r[4] == "exception" && r[6] == "02"),
            "{mode}: {out}"
        );
        assert!(err.contains("exceptions 2 (02H x2)"), "{mode}: {err}");
    }
}
