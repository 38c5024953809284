//! The master adapters of masters nobody here wrote (adapters/*-master) complete
//! `conformance gate --master` on a few cases each, every case is judged, and the known
//! findings of each library (adapters/MASTER-FINDINGS.md) appear as the kinds the gate
//! names. Each test checks its peer first and skips with the reason when it is missing
//! (tests/common/skip.rs). No timing is asserted: the cases chosen are decided by what the
//! library does with the bytes, not by how fast it does it.
//!
//! One gate run serves each library, so its cases share one adapter process and one
//! library state, as in an application: where a fault leaves the library in a bad state
//! (libmodbus after a stale reply, jsmodbus after stray bytes), only the cases before it are
//! asserted to pass.

mod common;
use common::gate::{assert_statuses, status_of};
use common::{python, words, Peer, Scratch};

use std::path::Path;
use std::time::Duration;

const LIMIT: Duration = Duration::from_secs(90);

fn adapter(path: &str) -> String {
    Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../adapters")
        .join(path)
        .display()
        .to_string()
}

/// `conformance gate --master CMD --model MODEL --only ID ...`, bounded, its report checked
/// against the schema; asserts the run completed, ran every case named and judged every
/// case it ran.
fn gate(name: &str, cmd: &str, model: &str, only: &[&str]) -> (Option<i32>, serde_json::Value) {
    let mut args = vec!["--master", cmd, "--model", model];
    for p in only {
        args.extend(["--only", p]);
    }
    let (code, v) = common::gate::again_while_unscheduled(|| {
        common::report_of("gate", &Scratch::new(name), &args, LIMIT)
    });
    assert_eq!(v["kind"], "gate");
    assert_eq!(v["complete"], true, "the run did not complete: {v:#}");
    assert_eq!(v["summary"]["error"], 0, "{:#}", v["checks"]);
    let checks = v["checks"].as_array().unwrap();
    // Each pattern is a case id (a pattern matches ids that contain it, so a later case
    // whose id extends one of these may run too: it is judged like the others).
    for id in only {
        assert!(
            checks.iter().any(|c| c["id"] == *id),
            "no case {id} in the run"
        );
    }
    for c in checks {
        let status = c["status"].as_str().unwrap();
        assert!(
            ["pass", "deviation", "observation", "skip"].contains(&status),
            "{} was not judged: {c:#}",
            c["id"]
        );
    }
    (code, v)
}

/// The command that runs the master adapter at `path` (under adapters/) with `program`,
/// when `peer` is here; None (after SKIPPED) when it is not.
fn master_cmd(peer: Peer, program: &str, path: &str) -> Option<String> {
    common::need(peer).then(|| format!("{program} {}", adapter(path)))
}

/// Asserts that the master `cmd` takes the late reply of one case as the next one's, in a
/// gate run of its own (scratch folder `name`) on the F510.
fn takes_the_stale_reply(name: &str, cmd: &str) {
    let (_, v) = gate(name, cmd, "f510", &["rtu.read.stale-reply"]);
    finding(&v, "stale-reply-taken", "rtu.read.stale-reply");
}

/// [`gate`] of the library `lib`'s master adapter (`cmd`) against the legacy L510 on
/// `cases` (the ids, apart by white space), which must name its implementation `lib`.
fn legacy_gate(lib: &str, cmd: &str, cases: &str) -> (Option<i32>, serde_json::Value) {
    let (code, v) = gate(lib, cmd, "l510-legacy", &words(cases));
    assert_eq!(v["codec"]["implementation"], lib);
    (code, v)
}

/// Asserts that the gate names the finding `kind` for case `id`.
fn finding(v: &serde_json::Value, kind: &str, id: &str) {
    let kinds = v["master"]["kinds"].as_array().expect("master.kinds");
    let hit = kinds
        .iter()
        .any(|k| k["kind"] == kind && k["cases"].as_array().unwrap().iter().any(|c| c == id));
    assert!(
        hit,
        "expected the finding {kind} in {id}; the gate found: {}",
        kinds
            .iter()
            .map(|k| format!("{} {}", k["kind"], k["cases"]))
            .collect::<Vec<_>>()
            .join("; ")
    );
}

/// `-P even` on the gate's pseudo-terminal: pymodbus cannot open it (Linux clears PARENB
/// on a pty, glibc's tcsetattr then fails with EINVAL), and every case's error says so,
/// with pyserial's own error and what to run instead; the report's master line says which
/// line it was given. `-P none -s 2`, which the error proposes, opens, and the report says
/// so too.
#[test]
fn pymodbus_master_with_a_parity_on_a_pty_is_told_why_it_cannot_open() {
    let Some(cmd) = master_cmd(Peer::Pymodbus, &python(), "pymodbus-master/adapter.py") else {
        return;
    };
    let dir = Scratch::new("pymodbus-parity");
    let only = [
        "--only",
        "rtu.read.normal",
        "--only",
        "rtu.read.exception-02",
    ];
    let mut args = vec!["--master", cmd.as_str(), "--mode", "rtu", "-P", "even"];
    args.extend(only);
    let (code, v) = common::report_of("gate", &dir, &args, LIMIT);
    assert_eq!(code, Some(2), "{v:#}");
    let checks = v["checks"].as_array().unwrap();
    assert_eq!(checks.len(), 2, "{v:#}");
    for c in checks {
        assert_eq!(c["status"], "error", "{c:#}");
        let why = c["summary"].as_str().unwrap();
        for part in [
            "pymodbus could not open pty /dev/",
            "Invalid argument",
            "a pseudo-terminal has no parity bit",
            "-P none",
            "-s 2",
        ] {
            assert!(why.contains(part), "{part:?} not in {why}");
        }
    }
    let serial = &v["master"]["serial"];
    assert_eq!(serial["baud"], 9600, "{:#}", v["master"]);
    assert_eq!(serial["parity"], "even");
    let page = common::rendered(&dir.join("gate.json"), &dir.join("gate.html"));
    assert!(
        page.contains("a pty line, 9600 baud 8E1, which it did not open"),
        "{page}"
    );

    let mut args = vec![
        "--master",
        cmd.as_str(),
        "--mode",
        "rtu",
        "-P",
        "none",
        "-s",
        "2",
    ];
    args.extend(only);
    let (code, v) = common::report_of("gate", &dir, &args, LIMIT);
    assert_eq!(v["summary"]["error"], 0, "{:#}", v["checks"]);
    assert_eq!(code, Some(0), "{:#}", v["checks"]);
    assert_eq!(v["master"]["serial"]["parity"], "none");
    assert_eq!(v["master"]["serial"]["stop_bits"], 2);
    let page = common::rendered(&dir.join("gate.json"), &dir.join("gate.html"));
    assert!(
        page.contains("rtu on a pty line, 9600 baud 8N2: its timeout 300 ms, 0 retries"),
        "{page}"
    );
}

#[test]
fn pymodbus_master_completes_and_loses_a_reply_behind_a_stray_byte() {
    let Some(cmd) = master_cmd(Peer::Pymodbus, &python(), "pymodbus-master/adapter.py") else {
        return;
    };
    let cases = "rtu.read.normal \
        rtu.read.exception-51 rtu.read.stale-reply rtu.read.stale-in-flight \
        rtu.read.wrong-function rtu.read.zero-before rtu.loop-back.normal \
        rtu.broadcast-single.normal ascii.read.normal ascii.read.zero-before";
    let (code, v) = legacy_gate("pymodbus", &cmd, cases);
    // The headline (pymodbus #2636): a reply that comes while its next request waits is
    // taken as that request's, even with another register count.
    finding(&v, "stale-reply-taken", "rtu.read.stale-in-flight");
    // A 06H echo in place of a read's reply: its value is reported as the register's.
    finding(&v, "accepted-wrong-function", "rtu.read.wrong-function");
    assert_eq!(status_of(&v, "rtu.read.normal"), "pass");
    // pymodbus reports any exception code, the legacy L510's 51H..55H included.
    assert_ne!(status_of(&v, "rtu.read.exception-51"), "deviation");
    // It drops a reply that comes after its timeout and before its next request (it
    // empties its input before sending).
    assert_statuses(
        &v,
        "pass",
        &words("rtu.read.stale-reply rtu.loop-back.normal ascii.read.normal"),
    );
    // RTU: a lone 00H before the reply makes its framer drop the good reply behind it.
    finding(&v, "garbage-breaks-reply", "rtu.read.zero-before");
    // (Its next request follows a broadcast at once, which the gate notes as the
    // observation broadcast-turnaround: a matter of timing, so not asserted here.)
    // ASCII: bytes before ':' are skipped.
    assert_eq!(status_of(&v, "ascii.read.zero-before"), "pass");
    assert_eq!(code, Some(1));
}

#[test]
fn minimalmodbus_master_completes_skips_loop_back_and_loses_a_reply_behind_a_stray_byte() {
    let Some(cmd) = master_cmd(
        Peer::Minimalmodbus,
        &python(),
        "minimalmodbus-master/adapter.py",
    ) else {
        return;
    };
    let cases = "rtu.read.normal \
        rtu.read.exception-53 rtu.read.stale-reply rtu.read.zero-before rtu.loop-back.normal \
        ascii.read.normal ascii.read.garbage-before";
    let (code, v) = legacy_gate("minimalmodbus", &cmd, cases);
    assert_eq!(status_of(&v, "rtu.read.normal"), "pass");
    // "Slave reported error code 83" carries the legacy code. (It comes back only when its
    // read timeout ends, which the gate may note as an observation, never a deviation.)
    assert_ne!(status_of(&v, "rtu.read.exception-53"), "deviation");
    // It clears its input before each request.
    assert_eq!(status_of(&v, "rtu.read.stale-reply"), "pass");
    // It reads a fixed number of bytes from the first one that comes.
    finding(&v, "garbage-breaks-reply", "rtu.read.zero-before");
    finding(&v, "garbage-breaks-reply", "ascii.read.garbage-before");
    // minimalmodbus has no 08H call.
    assert_eq!(status_of(&v, "rtu.loop-back.normal"), "skip");
    assert_eq!(status_of(&v, "ascii.read.normal"), "pass");
    assert_eq!(code, Some(1));
}

#[test]
fn libmodbus_master_takes_the_stale_reply_and_waits_after_a_broadcast() {
    let Some(cmd) = master_cmd(Peer::Libmodbus, &python(), "libmodbus-master/adapter.py") else {
        return;
    };
    let cases = "rtu.read.normal \
        rtu.read.exception-52 rtu.write-single.normal rtu.write-multiple.normal \
        rtu.broadcast-single.normal ascii.read.normal";
    let (code, v) = legacy_gate("libmodbus", &cmd, cases);
    assert_statuses(
        &v,
        "pass",
        &words("rtu.read.normal rtu.write-single.normal rtu.write-multiple.normal"),
    );
    // EMBBADEXC: a code at or above MODBUS_EXCEPTION_MAX is "Invalid exception code".
    finding(&v, "exception-not-recognised", "rtu.read.exception-52");
    // libmodbus 3.1.6 waits for a confirmation after a write to unit 0.
    finding(&v, "waits-after-broadcast", "rtu.broadcast-single.normal");
    // libmodbus has no ASCII.
    assert_eq!(status_of(&v, "ascii.read.normal"), "skip");
    assert_eq!(code, Some(1));
    // The headline, in a run of its own (after it every answer is one request late): a
    // reply after the timeout answers the next request.
    takes_the_stale_reply("libmodbus-stale", &cmd);
}

/// Builds the rmodbus master adapter (its own workspace, its own target folder) and
/// returns its path, or None (skipped, with why) when it cannot be built here.
fn rmodbus_master() -> Option<String> {
    let manifest = adapter("rmodbus-master/Cargo.toml");
    let target = adapter("rmodbus-master/target");
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let why = match std::process::Command::new(&cargo)
        .args(["build", "--locked", "--quiet", "--manifest-path", &manifest])
        .args(["--target-dir", &target])
        .env_remove("CARGO_TARGET_DIR")
        .output()
    {
        Ok(o) if o.status.success() => {
            return Some(adapter(
                "rmodbus-master/target/debug/rmodbus-master-adapter",
            ))
        }
        Ok(o) => {
            let err = String::from_utf8_lossy(&o.stderr).into_owned();
            let last = err
                .lines()
                .rev()
                .find(|l| !l.trim().is_empty())
                .unwrap_or("");
            format!(
                "cargo build --manifest-path {manifest} failed: {}",
                last.trim()
            )
        }
        Err(e) => format!("cannot run {cargo}: {e}"),
    };
    common::missing(&format!("the rmodbus master adapter ({why})"));
    None
}

#[test]
fn rmodbus_master_takes_the_stale_reply_and_knows_no_legacy_exception() {
    if common::peers_hidden() {
        common::missing(
            "the rmodbus master adapter, built with cargo (hidden by CONFORMANCE_PEERS=none)",
        );
        return;
    }
    let Some(cmd) = rmodbus_master() else { return };
    let cases = "rtu.read.normal \
        rtu.read.exception-54 rtu.write-single.normal rtu.loop-back.normal ascii.read.normal";
    let (code, v) = legacy_gate("rmodbus", &cmd, cases);
    assert_statuses(
        &v,
        "pass",
        &words("rtu.read.normal rtu.write-single.normal ascii.read.normal"),
    );
    // ErrorKind::from_modbus_error knows 01H..09H and 10H only: 54H is UnknownError.
    finding(&v, "exception-not-recognised", "rtu.read.exception-54");
    // rmodbus's client has no 08H request.
    assert_eq!(status_of(&v, "rtu.loop-back.normal"), "skip");
    assert_eq!(code, Some(1));
    // The loop of rmodbus's RTU example clears nothing before a request: the late reply
    // answers the next one.
    takes_the_stale_reply("rmodbus-stale", &cmd);
}

#[test]
fn jsmodbus_master_throws_on_a_legacy_exception_and_is_stuck_after_stray_bytes() {
    let Some(cmd) = master_cmd(Peer::Jsmodbus, "node", "jsmodbus-master/adapter.js") else {
        return;
    };
    let cases = "rtu.read.normal \
        rtu.read.exception-55 rtu.read.stale-reply rtu.read.stale-in-flight \
        rtu.broadcast-single.normal rtu.read.garbage-after ascii.read.normal";
    let (code, v) = legacy_gate("jsmodbus", &cmd, cases);
    assert_eq!(status_of(&v, "rtu.read.normal"), "pass");
    // errorCodeToMessage throws inside the socket's data handler.
    finding(&v, "raised", "rtu.read.exception-55");
    // A reply with no request waiting for it is dropped; one that comes while the next
    // request waits is given to that request.
    assert_eq!(status_of(&v, "rtu.read.stale-reply"), "pass");
    finding(&v, "stale-reply-taken", "rtu.read.stale-in-flight");
    // No broadcast notion: the write to unit 0 waits for a reply.
    finding(&v, "waits-after-broadcast", "rtu.broadcast-single.normal");
    // Bytes that parse as no response stay at the head of its receive buffer.
    finding(&v, "no-recovery", "rtu.read.garbage-after");
    assert_eq!(status_of(&v, "ascii.read.normal"), "skip");
    assert_eq!(code, Some(1));
}

#[test]
fn mbpoll_master_runs_once_per_operation_and_takes_the_stale_reply() {
    let Some(cmd) = master_cmd(Peer::Mbpoll, &python(), "mbpoll-master/adapter.py") else {
        return;
    };
    let cases = "rtu.read.normal \
        rtu.read.exception-51 rtu.write-single.normal rtu.write-multiple.normal \
        rtu.broadcast-single.normal";
    let (code, v) = legacy_gate("mbpoll", &cmd, cases);
    assert_statuses(
        &v,
        "pass",
        &words("rtu.read.normal rtu.write-single.normal rtu.write-multiple.normal"),
    );
    finding(&v, "exception-not-recognised", "rtu.read.exception-51");
    // mbpoll refuses address 0 in RTU: no broadcast.
    assert_eq!(status_of(&v, "rtu.broadcast-single.normal"), "skip");
    assert_eq!(code, Some(1));
    // The next run opens the port and reads the previous run's late reply.
    takes_the_stale_reply("mbpoll-stale", &cmd);
}

/// `--reopen-each-case`: libmodbus, after a stale reply, answers every later read one
/// request late (its queue is never flushed). In one run without the option, the case
/// after the stale reply inherits it and deviates; with the option each case gets a new
/// line, and only the stale-reply case deviates.
#[test]
fn libmodbus_state_after_a_stale_reply_stays_in_its_case_with_reopen_each_case() {
    let Some(cmd) = master_cmd(Peer::Libmodbus, &python(), "libmodbus-master/adapter.py") else {
        return;
    };
    let only = ["rtu.read.normal", "rtu.read.stale-reply", "rtu.read.late"];
    let run = |name: &str, reopen: bool| {
        let mut args = vec!["--master", cmd.as_str(), "--mode", "rtu"];
        if reopen {
            args.push("--reopen-each-case");
        }
        for p in &only {
            args.extend(["--only", p]);
        }
        let (_, v) = common::report_of("gate", &Scratch::new(name), &args, LIMIT);
        assert_eq!(v["complete"], true, "{v:#}");
        v
    };
    let kept = run("libmodbus-kept", false);
    assert_eq!(status_of(&kept, "rtu.read.normal"), "pass");
    finding(&kept, "stale-reply-taken", "rtu.read.stale-reply");
    // The late case runs after the stale reply: its read gets the reply of the one before.
    assert_eq!(status_of(&kept, "rtu.read.late"), "deviation");
    let fresh = run("libmodbus-reopened", true);
    assert_eq!(status_of(&fresh, "rtu.read.normal"), "pass");
    finding(&fresh, "stale-reply-taken", "rtu.read.stale-reply");
    assert_eq!(
        status_of(&fresh, "rtu.read.late"),
        "pass",
        "{:#}",
        fresh["checks"]
    );
}

/// `--line mbap`: the gate plays a Modbus TCP gateway. pymodbus's TCP client checks the
/// transaction id, so the stale reply (the old id) is never taken; it still takes a 06H
/// echo as a read's values. libmodbus's TCP client takes another unit's reply, and never a
/// stale one's values (a stale reply read ahead of the right one makes it report "Invalid
/// data" for the read that follows, libmodbus #255; how often depends on the host's
/// timing, so that is not asserted). The faults of a serial line's bytes are skipped.
#[test]
fn over_modbus_tcp_pymodbus_checks_the_transaction_and_libmodbus_not_the_unit() {
    if !common::need(Peer::Pymodbus) || !common::need(Peer::Libmodbus) {
        return;
    }
    let only = [
        "rtu.read.normal",
        "rtu.read.stale-reply",
        "rtu.read.other-node",
        "rtu.read.wrong-function",
        "rtu.read.bad-checksum",
    ];
    let run = |name: &str, cmd: &str| {
        let mut args = vec!["--master", cmd, "--line", "mbap", "--mode", "rtu"];
        args.push("--reopen-each-case");
        for p in &only {
            args.extend(["--only", p]);
        }
        let (_, v) = common::report_of("gate", &Scratch::new(name), &args, LIMIT);
        assert_eq!(v["complete"], true, "{v:#}");
        assert_eq!(
            status_of(&v, "rtu.read.normal"),
            "pass",
            "{:#}",
            v["checks"]
        );
        assert_eq!(status_of(&v, "rtu.read.bad-checksum"), "skip");
        v
    };
    let py = run(
        "pymodbus-mbap",
        &format!("{} {}", python(), adapter("pymodbus-master/adapter.py")),
    );
    assert_eq!(status_of(&py, "rtu.read.stale-reply"), "pass");
    assert_eq!(status_of(&py, "rtu.read.other-node"), "pass");
    finding(&py, "accepted-wrong-function", "rtu.read.wrong-function");
    let lm = run(
        "libmodbus-mbap",
        &format!("{} {}", python(), adapter("libmodbus-master/adapter.py")),
    );
    finding(&lm, "accepted-other-node", "rtu.read.other-node");
    // The stale frame (its old transaction id) is never taken as values. Where it is
    // read ahead of the right reply, the read after it fails ("Invalid data",
    // no-recovery); where the host's timing lets it be read apart, nothing is found.
    let kinds: Vec<&str> = lm["master"]["kinds"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|k| {
            k["cases"]
                .as_array()
                .unwrap()
                .iter()
                .any(|c| c == "rtu.read.stale-reply")
        })
        .map(|k| k["kind"].as_str().unwrap())
        .collect();
    assert!(
        kinds.iter().all(|k| *k == "no-recovery"),
        "libmodbus over MBAP: {kinds:?}"
    );
}
