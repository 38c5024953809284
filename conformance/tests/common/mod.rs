//! Helpers shared by the integration tests that start the `conformance` binary or other
//! programs.
#![allow(dead_code)]

pub mod agree;
mod bus;
pub mod gate;
pub mod installed;
mod monitor;
mod peers;
mod report;
pub mod rtu;
mod run;
mod scratch;
mod skip;
mod text;
// A test binary uses some of these and not others.
#[allow(unused_imports)]
pub use {bus::*, monitor::*, peers::*, report::*, run::*, scratch::*, skip::*, text::*};

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

/// Waits (at most 30 s) until a device on `port` answers the runner's preflight in `mode`
/// (a slow-starting server, such as pymodbus on a busy machine, is not a dead device).
pub fn wait_until_answers(port: &std::path::Path, mode: &str, line: &[&str]) {
    let t0 = std::time::Instant::now();
    loop {
        let o = Run::words("check --model f510 --mode")
            .arg(mode)
            .arg("--port")
            .arg(port)
            .args(line)
            .args(["--only", "identification", "--timeout", "300", "--quiet"])
            .timeout(std::time::Duration::from_secs(60))
            .run();
        if o.code != Some(2) {
            return;
        }
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(30),
            "the device on {} does not answer: {}",
            port.display(),
            o.stdout
        );
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
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

/// t1.5 and t3.5 (us) of the line of a bus log (`bus_log`, its records), from its start
/// record, as the codec's rule: 1.5 and 3.5 characters, 750 and 1750 us above 19200 baud.
pub fn bus_silences(bus_log: &[serde_json::Value]) -> Option<(u64, u64)> {
    let start = bus_log.iter().find(|r| r["event"] == "start")?;
    let baud: u32 = start["line"].as_str()?.split(' ').next()?.parse().ok()?;
    let char_us = start["char_us"].as_u64()?;
    Some(if baud > 19_200 {
        (750, 1_750)
    } else {
        (char_us * 3 / 2, char_us * 7 / 2)
    })
}

/// Of a node's findings (`errors`: kind to count, from a monitor report), those a busy
/// host does not explain, as "kind xN": a timing finding ([`TIMING_KINDS`]) is explained
/// where the bus's log (`bus_log`, its records) has a `late` record of at least t3.5 of
/// its line (a silence misjudged on that scale needs lateness on that scale); every
/// other finding is unexplained. Explained ones are noted with that record.
///
/// A reply with no request under way (`drive.unexpected-reply`) is explained once for
/// each `late` record of t3.5 or more inside a master's frame: a request whose bytes the
/// host handed over t3.5 apart reaches the listener as two frames, neither of them the
/// request, and its reply then has no request.
pub fn unexplained(errors: &serde_json::Value, bus_log: &[serde_json::Value]) -> Vec<String> {
    let t3_5_us = bus_silences(bus_log)
        .expect("the bus log has no start record with its line")
        .1;
    let late = late_by_t3_5(bus_log);
    // Late records that fell inside a master's frame: only those can split a request.
    let split: Vec<String> = agree::late_frames(bus_log, t3_5_us)
        .into_iter()
        .filter(|l| l.in_request)
        .map(|l| l.record)
        .collect();
    let mut out = Vec::new();
    for (k, n) in errors.as_object().into_iter().flatten() {
        match late {
            Some(l) if TIMING_KINDS.contains(&k.as_str()) => note(&format!(
                "{k} x{n}: the bus ran late by t3.5 ({t3_5_us} us) or more ({l}), so the listener's timing was the host's"
            )),
            _ if k == "drive.unexpected-reply"
                && n.as_u64().is_some_and(|n| n <= split.len() as u64) =>
            {
                note(&format!(
                    "{k} x{n}: the bus handed a request's bytes over t3.5 ({t3_5_us} us) or more late {} times, each of which can split it (the first: {})",
                    split.len(),
                    split[0]
                ))
            }
            _ => out.push(format!("{k} x{n}")),
        }
    }
    out
}

/// The first `late` record of a bus log (`bus_log`, its records) of at least t3.5 of its
/// line: the host handed bytes over late enough to split a frame the line did not split.
pub fn late_by_t3_5(bus_log: &[serde_json::Value]) -> Option<&serde_json::Value> {
    let t3_5_us = bus_silences(bus_log)?.1;
    bus_log
        .iter()
        .filter(|r| r["event"] == "late")
        .find(|r| r["by_us"].as_u64().is_some_and(|b| b >= t3_5_us))
}
