//! The conformance runner against the simulator: no deviations from a clean simulator of
//! any model; at least one deviation naming each quirk's effect; an interrupted or
//! disconnected run leaves a whole, valid report marked incomplete and restores what it
//! changed; reports validate against their schema; the command line's exit codes.

mod common;
use common::{bin, free_port, wait_listening, Kill};

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread;
use std::time::{Duration, Instant};

use conformance::codec::timing::{LineSettings, Parity};
use conformance::codec::Mode;
use conformance::model::{DriveModel, MODELS};
use conformance::report::Report;
use conformance::runner::{MasterTiming, Options, Status};
use conformance::session::{self, SessionConfig, Target};
use conformance::sim::Quirk;

fn options(only: &[&str]) -> Options {
    Options {
        address: 1,
        other_address: 0x7F,
        bus: vec![1],
        read_only: false,
        allow_motion: false,
        only: only.iter().map(|s| s.to_string()).collect(),
        timing: MasterTiming {
            timeout: Duration::from_millis(500),
            silence: Duration::from_millis(250),
            derive_silence: false,
            quiet: Duration::from_millis(30),
            gap: Duration::from_millis(5),
            retries: 0,
        },
        // Generous: the tests run many sessions at once on a small machine. The
        // late-reply quirk (200 ms) is still far over it.
        response_allowance: Duration::from_millis(100),
        // The host's scheduler puts gaps of several ms into a paced pseudo-terminal when
        // the machine is busy (the tests run in parallel).
        gap_allowance: Duration::from_millis(20),
        seed: 1,
        echo: conformance::runner::EchoMode::Auto,
        allow_restart: false,
        line: None,
    }
}

fn config(
    model: &str,
    modes: &[Mode],
    quirks: &[Quirk],
    pace: bool,
    opts: Options,
) -> SessionConfig {
    SessionConfig {
        model: Arc::new(DriveModel::builtin(model).unwrap()),
        target: Target::Sim {
            quirks: quirks.iter().map(|&q| q.into()).collect(),
            pace,
            delay: None,
            log: None,
        },
        modes: modes.to_vec(),
        line: LineSettings::new(9600, 8, Parity::Even, 1),
        options: opts,
    }
}

fn run(c: &SessionConfig) -> Report {
    let stop = AtomicBool::new(false);
    session::run(c, &stop, &mut |_, _| {}, &mut |_| {}).unwrap()
}

fn deviations(r: &Report) -> Vec<String> {
    r.results
        .iter()
        .filter(|c| c.status == Status::Deviation)
        .map(|c| format!("{}: {}", c.id, c.summary))
        .collect()
}

fn schema() -> jsonschema::Validator {
    let text = include_str!("../../vectors/schema/report.schema.json");
    jsonschema::validator_for(&serde_json::from_str(text).unwrap()).unwrap()
}

fn assert_valid(r: &Report) {
    let v = r.to_json();
    let errors: Vec<String> = schema()
        .iter_errors(&v)
        .map(|e| format!("{e} at {}", e.instance_path))
        .collect();
    assert!(
        errors.is_empty(),
        "report does not match its schema: {errors:#?}"
    );
}

#[test]
fn a_clean_simulator_of_every_model_has_no_deviations() {
    // F510 paced, both modes, on its own (the line-timing check measures real gaps).
    let r = run(&config(
        "f510",
        &[Mode::Rtu, Mode::Ascii],
        &[],
        true,
        options(&[]),
    ));
    assert!(r.complete, "{:?}", r.stopped);
    assert_eq!(deviations(&r), Vec::<String>::new());
    let s = r.summary();
    assert_eq!(s.error, 0);
    assert!(s.pass > 200, "{s:?}");
    assert_eq!(r.exit_code(), 0);
    assert!(r.unrestored().is_empty());
    let timing = r
        .results
        .iter()
        .find(|c| c.id == "rtu.line-timing")
        .unwrap();
    assert_eq!(timing.status, Status::Pass, "{}", timing.summary);
    assert_valid(&r);

    // The other models at once, without pacing.
    let handles: Vec<_> = MODELS
        .iter()
        .filter(|m| **m != "f510")
        .map(|m| {
            let m = m.to_string();
            thread::spawn(move || {
                (
                    m.clone(),
                    run(&config(
                        &m,
                        &[Mode::Rtu, Mode::Ascii],
                        &[],
                        false,
                        options(&[]),
                    )),
                )
            })
        })
        .collect();
    for h in handles {
        let (m, r) = h.join().unwrap();
        assert!(r.complete, "{m}: {:?}", r.stopped);
        assert_eq!(deviations(&r), Vec::<String>::new(), "{m}");
        assert_eq!(r.summary().error, 0, "{m}");
        assert_eq!(r.exit_code(), 0, "{m}");
        // Decisions of the model show as observations, never as deviations.
        assert!(r.summary().observation > 0, "{m}");
    }
}

/// Checks that every quirk's run covers: a fixed subset, the same for every quirk.
const SUBSET: [&str; 7] = [
    "rtu.map.monitor*",
    "rtu.function.*",
    "rtu.broadcast*",
    "rtu.other-address",
    "rtu.response-time",
    "rtu.loop-back*",
    "rtu.bad-crc",
];

#[test]
fn each_quirk_is_named_by_a_deviation() {
    let cases: Vec<(Quirk, &str)> = vec![
        (Quirk::CrcSwap, "the two CRC bytes are swapped"),
        (Quirk::ReplyToBroadcast, "manual: no reply (broadcast)"),
        (Quirk::WrongException, "in the manual's table"),
        (Quirk::LateReply(200), "replies are late"),
        (Quirk::DropEvery(3), "device: no reply within"),
        (Quirk::GarbageBeforeReply, "bytes before the reply"),
        (Quirk::TruncatedReply, "a truncated reply"),
        (
            Quirk::AnswerEveryAddress,
            "manual: no reply (other-address)",
        ),
    ];
    let handles: Vec<_> = cases
        .into_iter()
        .map(|(q, phrase)| {
            thread::spawn(move || {
                let r = run(&config("f510", &[Mode::Rtu], &[q], false, options(&SUBSET)));
                (q, phrase, r)
            })
        })
        .collect();
    for h in handles {
        let (q, phrase, r) = h.join().unwrap();
        let devs = deviations(&r);
        assert!(
            r.results.iter().any(|c| c.status == Status::Deviation
                && c.findings.iter().any(|f| f.text.contains(phrase))),
            "quirk {q}: no deviation says {phrase:?}; deviations: {devs:#?}"
        );
        assert_ne!(r.exit_code(), 0, "quirk {q}");
        assert_valid(&r);
    }
    // In ASCII the crc-swap quirk swaps the LRC characters.
    let r = run(&config(
        "l510",
        &[Mode::Ascii],
        &[Quirk::CrcSwap],
        false,
        options(&["ascii.map.monitor.first"]),
    ));
    assert!(
        deviations(&r)
            .iter()
            .any(|d| d.contains("LRC characters are swapped")),
        "{:#?}",
        deviations(&r)
    );
}

#[test]
fn an_interrupted_run_is_reported_incomplete_and_restores_what_it_changed() {
    let c = config("a510", &[Mode::Rtu], &[], false, options(&["rtu.write.*"]));
    let stop = AtomicBool::new(false);
    let mut snapshots = Vec::new();
    let r = session::run(&c, &stop, &mut |_, _| {}, &mut |rep| {
        snapshots.push(rep.to_json());
        if rep.results.len() == 4 {
            stop.store(true, Ordering::Relaxed);
        }
    })
    .unwrap();
    assert!(!r.complete);
    assert_eq!(r.stopped.as_deref(), Some("interrupted"));
    assert_eq!(r.results.len(), 4);
    assert_eq!(r.exit_code(), 2);
    assert!(
        !r.restore.is_empty() && r.unrestored().is_empty(),
        "{:#?}",
        r.restore
    );
    assert_valid(&r);
    // Every intermediate report is whole and valid, marked incomplete.
    let v = schema();
    for s in &snapshots[..snapshots.len() - 1] {
        assert!(v.is_valid(s));
        assert_eq!(s["complete"], false);
    }
}

#[test]
fn a_lost_link_ends_the_run_with_an_error_and_a_whole_report() {
    let addr = format!("127.0.0.1:{}", free_port());
    let child = Arc::new(std::sync::Mutex::new(Kill::spawn(
        std::process::Command::new(bin())
            .args(["simulate", "--model", "l510", "--tcp", &addr, "-q"]),
    )));
    wait_listening(&addr, Duration::from_secs(10));
    thread::sleep(Duration::from_millis(100));
    let c = SessionConfig {
        model: Arc::new(DriveModel::builtin("l510").unwrap()),
        target: Target::Tcp { addr },
        modes: vec![Mode::Rtu],
        line: LineSettings::new(9600, 8, Parity::Even, 1),
        options: options(&[]),
    };
    let stop = AtomicBool::new(false);
    let killer = child.clone();
    let t0 = Instant::now();
    let r = session::run(&c, &stop, &mut |_, _| {}, &mut |rep| {
        if rep.results.len() == 10 {
            let mut ch = killer.lock().unwrap();
            let _ = ch.0.kill();
            let _ = ch.0.wait();
        }
    })
    .unwrap();
    assert!(
        t0.elapsed() < Duration::from_secs(30),
        "the run hung: {:?}",
        t0.elapsed()
    );
    assert!(!r.complete);
    assert!(
        r.stopped.as_deref().unwrap_or("").contains("closed"),
        "{:?}",
        r.stopped
    );
    assert_eq!(r.results.last().unwrap().status, Status::Error);
    assert_eq!(r.exit_code(), 2);
    assert_valid(&r);
}

#[test]
fn the_command_line_gives_exit_codes_and_every_format() {
    let dir = std::env::temp_dir().join(format!("teco-runner-cli-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let out = |args: &[&str]| {
        std::process::Command::new(bin())
            .args(args)
            .output()
            .unwrap()
    };
    // Clean: exit 0; JUnit parses with one test case per check.
    let xml = dir.join("r.xml");
    let o = out(&[
        "check",
        "--sim",
        "f510",
        "--mode",
        "rtu",
        "--only",
        "rtu.map.monitor",
        "--format",
        "junit",
        "-o",
        xml.to_str().unwrap(),
    ]);
    assert_eq!(
        o.status.code(),
        Some(0),
        "{}",
        String::from_utf8_lossy(&o.stderr)
    );
    let text = std::fs::read_to_string(&xml).unwrap();
    let doc = roxmltree::Document::parse(&text).unwrap();
    let cases = doc
        .descendants()
        .filter(|n| n.has_tag_name("testcase"))
        .count();
    // Three monitor checks and the preflight, which runs whatever --only selects.
    assert_eq!(cases, 4 + 1, "{text}");
    // A quirk: exit 1; the deviation is a JUnit failure and leads the text report.
    let o = out(&[
        "check",
        "--sim",
        "f510",
        "--mode",
        "rtu",
        "--quirk",
        "wrong-exception",
        "--only",
        "rtu.function.04",
        "--format",
        "junit",
    ]);
    assert_eq!(o.status.code(), Some(1));
    let text = String::from_utf8(o.stdout).unwrap();
    let doc = roxmltree::Document::parse(&text).unwrap();
    assert_eq!(
        doc.descendants()
            .filter(|n| n.has_tag_name("failure"))
            .count(),
        1
    );
    let o = out(&[
        "check",
        "--sim",
        "f510",
        "--mode",
        "rtu",
        "--quirk",
        "wrong-exception",
        "--only",
        "rtu.function.04",
    ]);
    let text = String::from_utf8(o.stdout).unwrap();
    assert!(
        text.lines()
            .nth(1)
            .unwrap()
            .starts_with("RESULT: 2 checks: 1 pass, 1 deviation,"),
        "{text}"
    );
    assert!(
        text.contains("DEVIATIONS (1)")
            && text.contains("expected 01 84 01 ")
            && text.contains("received 01 84 02 "),
        "{text}"
    );
    assert!(
        text.contains("^^ ^^ ^^"),
        "the differing bytes are marked: {text}"
    );
    // JSON validates.
    let o = out(&[
        "check",
        "--sim",
        "e510",
        "--mode",
        "ascii",
        "--only",
        "ascii.write.read-only",
        "--format",
        "json",
    ]);
    let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert!(schema().is_valid(&v));
    assert_eq!(v["checks"][0]["id"], "ascii.preflight");
    assert_eq!(v["checks"][1]["status"], "observation");
    // Bad arguments: exit 2 with a message.
    let o = out(&["check", "--sim", "f999"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("unknown model"));
    // A pattern that selects nothing is an error, not an empty pass.
    let o = out(&["check", "--sim", "f510", "--only", "no-such-check"]);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("no check matches"));
    // --list runs nothing and names every check.
    let o = out(&["check", "--sim", "l510", "--list"]);
    assert_eq!(o.status.code(), Some(0));
    assert!(String::from_utf8_lossy(&o.stdout).contains("rtu.identification"));
    let _ = std::fs::remove_dir_all(&dir);
}
