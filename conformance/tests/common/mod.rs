//! Helpers shared by the integration tests that start the `conformance` binary or other
//! programs.
#![allow(dead_code)]

pub mod agree;
pub mod gate;
pub mod installed;
mod peers;
mod skip;
pub use peers::*;
pub use skip::*;

/// The `conformance` binary built for these tests.
pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_conformance")
}

/// Writes straight to the process's stderr, past the test harness's output capture, so
/// that a SKIPPED line is seen in a normal `cargo test` run.
pub fn note(line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// Prints `SKIPPED: ...` and returns false when `ok` is false (a failure under CI): for a
/// need that is not one of the [`Peer`]s.
pub fn tool_or_skip(ok: bool, what: &str) -> bool {
    ok || missing(what)
}

/// Runs `conformance check ARGS --format json -o dir/check.json` with a bound on its
/// time (a hang is a failure, not a stalled CI job), asserts it did not panic and that
/// the report matches its schema; returns the exit code and the report.
pub fn check_device(
    dir: &std::path::Path,
    args: &[&str],
    limit: std::time::Duration,
) -> (Option<i32>, serde_json::Value) {
    report_of("check", dir, args, limit)
}

/// Runs `conformance COMMAND ARGS --format json -o DIR/COMMAND.json` (check or fuzz),
/// bounded by `limit`, and returns its exit code and the report, checked against the
/// report schema.
pub fn report_of(
    command: &str,
    dir: &std::path::Path,
    args: &[&str],
    limit: std::time::Duration,
) -> (Option<i32>, serde_json::Value) {
    let report = dir.join(format!("{command}.json"));
    let mut run = Kill::spawn(
        std::process::Command::new(bin())
            .arg(command)
            .args(args)
            .args(["--format", "json", "--quiet", "-o"])
            .arg(&report)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped()),
    );
    let exit = run.wait_within(limit, &format!("conformance {command}"));
    let stderr = run.stderr_text();
    assert!(!stderr.contains("panicked"), "{stderr}");
    let out = std::fs::read(&report).unwrap();
    let v: serde_json::Value =
        serde_json::from_slice(&out).unwrap_or_else(|e| panic!("{e}: {stderr}"));
    let schema = jsonschema::validator_for(
        &serde_json::from_str(include_str!("../../../vectors/schema/report.schema.json")).unwrap(),
    )
    .unwrap();
    assert!(schema.is_valid(&v), "the report does not match its schema");
    (exit.code(), v)
}

/// Waits (at most 30 s) until a device on `port` answers the runner's preflight in `mode`
/// (a slow-starting server, such as pymodbus on a busy machine, is not a dead device).
pub fn wait_until_answers(port: &std::path::Path, mode: &str, line: &[&str]) {
    let t0 = std::time::Instant::now();
    loop {
        let o = std::process::Command::new(bin())
            .args(["check", "--model", "f510", "--mode", mode, "--port"])
            .arg(port)
            .args(line)
            .args(["--only", "identification", "--timeout", "300", "--quiet"])
            .output()
            .unwrap();
        if o.status.code() != Some(2) {
            return;
        }
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(30),
            "the device on {} does not answer: {}",
            port.display(),
            String::from_utf8_lossy(&o.stdout)
        );
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
}

/// The findings of every mode of a fuzz report that are not unconfirmed: a finding that
/// was replayed and not seen again is an observation (a host stall under load can make
/// one), not one of the device's bugs.
pub fn confirmed_findings(v: &serde_json::Value) -> Vec<serde_json::Value> {
    findings(v)
        .into_iter()
        .filter(|f| f["reproduced"] == true || f["replays"].as_u64().unwrap_or(0) == 0)
        .collect()
}

/// The findings of every mode of a fuzz report.
pub fn findings(v: &serde_json::Value) -> Vec<serde_json::Value> {
    v["fuzz"]["modes"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|m| m["findings"].as_array().unwrap().clone())
        .collect()
}

/// The monitor's kinds of finding that rest on when bytes were read: a silence, a gap, a
/// response time. On an emulated bus these measure the host as well as the line.
pub const TIMING_KINDS: &[&str] = &[
    "master.no-t3.5",
    "master.request-before-reply",
    "master.broadcast-turnaround",
    "drive.late-reply",
    "drive.gap-in-reply",
];

/// Of a node's findings (`errors`: kind to count, from a monitor report), those a busy
/// host does not explain, as "kind xN": a timing finding ([`TIMING_KINDS`]) is explained
/// where the bus's log (`bus_log`, its records) has a `late` record of at least t3.5 of
/// its line (a silence misjudged on that scale needs lateness on that scale); every
/// other finding is unexplained. Explained ones are noted with that record.
pub fn unexplained(errors: &serde_json::Value, bus_log: &[serde_json::Value]) -> Vec<String> {
    // As the codec's rule: 3.5 characters, 1750 us above 19200 baud.
    let t3_5_us = bus_log
        .iter()
        .find(|r| r["event"] == "start")
        .and_then(|r| {
            let baud: u32 = r["line"].as_str()?.split(' ').next()?.parse().ok()?;
            let char_us = r["char_us"].as_u64()?;
            Some(if baud > 19_200 {
                1_750
            } else {
                char_us * 7 / 2
            })
        })
        .expect("the bus log has no start record with its line");
    let late = bus_log
        .iter()
        .filter(|r| r["event"] == "late")
        .find(|r| r["by_us"].as_u64().is_some_and(|b| b >= t3_5_us));
    let mut out = Vec::new();
    for (k, n) in errors.as_object().into_iter().flatten() {
        match late {
            Some(l) if TIMING_KINDS.contains(&k.as_str()) => note(&format!(
                "{k} x{n}: the bus ran late by t3.5 ({t3_5_us} us) or more ({l}), so the listener's timing was the host's"
            )),
            _ => out.push(format!("{k} x{n}")),
        }
    }
    out
}

/// `conformance report JSON -o OUT` (the format from OUT's extension), which must exit 0:
/// what it wrote.
pub fn rendered(json: &std::path::Path, out: &std::path::Path) -> String {
    let o = std::process::Command::new(bin())
        .arg("report")
        .arg(json)
        .arg("-o")
        .arg(out)
        .output()
        .unwrap();
    assert_eq!(
        o.status.code(),
        Some(0),
        "report {}: {}",
        json.display(),
        String::from_utf8_lossy(&o.stderr)
    );
    std::fs::read_to_string(out).unwrap()
}
