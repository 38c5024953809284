//! The storm test and the timing damage cases, against the simulator on its paced
//! pseudo-terminal (the only local link with line timing):
//!
//! - `fuzz --storm`: the clean simulator answers every own request, loses none, answers
//!   nothing else; with `busy-after=2` (a request that follows another node's frame
//!   within t3.5 + 2 characters is lost) the storm reports lost requests and fails its
//!   test case; with `answer-every-address` it reports answers to other traffic. A few
//!   hundred frames at 19200 baud; STORM_FRAMES for more (the full storm).
//! - timing damage: the clean simulator gives no finding over the timing classes; the
//!   planted `ignore-t15` (a frame with a silence over t1.5 inside it is taken whole) is
//!   found as an unexpected reply in `timing.gap-in-frame` within 300 cases (seed 1) and
//!   minimized to the shortest request with its cut and silence; `conformance send
//!   --split --gap` replays it. On an unpaced link the timing classes are not sent, and
//!   the report says why.

mod common;
use common::{check_of, confirmed_findings, report_in, Run};

use std::time::Duration;

use serde_json::Value;

fn frames() -> String {
    std::env::var("STORM_FRAMES").unwrap_or_else(|_| "300".into())
}

/// The storm (seed 1, 19200 baud) in a scratch folder `name`, with `quirks` planted.
fn storm(name: &str, quirks: &[&str]) -> (Option<i32>, Value) {
    let n = frames();
    let args = format!(
        "--sim f510 --mode rtu -b 19200 --storm --storm-frames {n} --storm-idle 20 --seed 1 {}",
        planted(quirks)
    );
    report_in("fuzz", name, &args, Duration::from_secs(600))
}

/// `--quirk Q` for each of `quirks`.
fn planted(quirks: &[&str]) -> String {
    quirks.iter().map(|q| format!("--quirk {q} ")).collect()
}

fn storm_of(v: &Value) -> &Value {
    &v["fuzz"]["modes"][0]["storm"]
}

#[test]
fn the_clean_simulator_weathers_the_storm() {
    let (code, v) = storm("clean", &[]);
    let s = storm_of(&v);
    assert_eq!(s["lost"], 0, "{s:#}");
    assert_eq!(s["unexpected"], 0, "{s:#}");
    assert_eq!(s["wrong"], 0, "{s:#}");
    assert_eq!(s["line_timing"], true);
    let sent = &s["sent"];
    for kind in [
        "own-request",
        "other-request",
        "other-reply",
        "broadcast-read",
    ] {
        assert!(sent[kind].as_u64().unwrap() > 0, "no {kind}: {sent}");
    }
    // With --writes preserving, nothing for other nodes is written.
    assert!(sent.get("broadcast-write").is_none() && sent.get("other-write").is_none());
    // An own request this host could not send whole (every send broken by a stall of a
    // busy machine) is given up, neither lost nor answered.
    assert_eq!(
        s["own_requests"].as_u64().unwrap() + s["own_unsent"].as_u64().unwrap(),
        sent["own-request"].as_u64().unwrap(),
        "{s:#}"
    );
    assert_eq!(s["load"]["count"], s["own_requests"]);
    // The idle reference: 20 requests; one not answered in time there is counted in
    // idle_problems (seen once under a load of 7, not explained yet: see the report).
    let idle = s["idle"]["count"].as_u64().unwrap() + s["idle_problems"].as_u64().unwrap();
    assert!(idle >= 20, "{s:#}");
    let total: u64 = sent
        .as_object()
        .unwrap()
        .values()
        .map(|x| x.as_u64().unwrap())
        .sum();
    assert_eq!(total.to_string(), frames());
    // Whether a reply was late is the host's timing as much as the simulator's (timing
    // assertions do not belong in tests): only that the verdict follows the counts.
    let on_time = s["late"] == 0;
    assert_eq!(s["passed"], on_time);
    let status = &check_of(&v, "fuzz.rtu.storm")["status"];
    assert_eq!(*status, if on_time { "pass" } else { "deviation" });
    assert_eq!(code, Some(if on_time { 0 } else { 1 }), "{s:#}");
}

#[test]
fn a_request_lost_after_other_traffic_fails_the_storm() {
    let (code, v) = storm("busy", &["busy-after=2"]);
    let s = storm_of(&v);
    assert!(s["lost"].as_u64().unwrap() > 0, "{s:#}");
    assert_eq!(s["passed"], false);
    assert_eq!(code, Some(1));
    assert_eq!(check_of(&v, "fuzz.rtu.storm")["status"], "deviation");
    let problems = s["problems"].as_array().unwrap();
    assert!(
        problems
            .iter()
            .any(|p| p.as_str().unwrap().starts_with("lost: ")),
        "{problems:#?}"
    );
}

#[test]
fn answers_to_other_nodes_fail_the_storm() {
    let (code, v) = storm("every", &["answer-every-address"]);
    let s = storm_of(&v);
    assert!(s["unexpected"].as_u64().unwrap() > 0, "{s:#}");
    assert_eq!(code, Some(1));
    let problems = s["problems"].as_array().unwrap();
    assert!(
        problems.iter().any(|p| p
            .as_str()
            .unwrap()
            .contains("answers none of its own requests")),
        "{problems:#?}"
    );
}

/// The timing classes (seed 1, 19200 baud) in a scratch folder `name`, with `quirks`
/// planted.
fn timing_run(name: &str, quirks: &[&str], cases: &str) -> (Option<i32>, Value) {
    let args = format!(
        "--sim f510 --mode rtu -b 19200 --cases {cases} --seed 1 {}",
        planted(quirks)
    );
    report_in("fuzz", name, &args, Duration::from_secs(900))
}

#[test]
fn a_frame_with_a_gap_over_t15_taken_whole_is_found_and_minimized() {
    let (code, v) = timing_run("t15", &["ignore-t15"], "300");
    assert_eq!(code, Some(1), "{:#}", v["fuzz"]);
    let f = confirmed_findings(&v);
    let g = f
        .iter()
        .find(|x| x["field_class"] == "timing.gap-in-frame")
        .unwrap_or_else(|| panic!("no timing.gap-in-frame finding in {f:#?}"));
    assert_eq!(g["kind"], "unexpected-reply", "{g:#}");
    assert_eq!(g["reproduced"], true, "{g:#}");
    // Minimized to the shortest request (a one-register read), with its cut and silence.
    let min = g["minimized"].as_array().unwrap();
    assert_eq!(min.len(), 1);
    let frame: Vec<u8> = conformance::codec::hex::parse_hex(min[0].as_str().unwrap()).unwrap();
    assert_eq!((frame.len(), frame[1]), (8, 0x03), "{g:#}");
    let replay = g["replay"].as_str().unwrap();
    assert!(
        replay.contains("--split ") && replay.contains("--gap "),
        "{replay}"
    );
    // Only the gap inside a frame shows the bug: no other signature.
    assert!(
        f.iter().all(|x| x["field_class"] == "timing.gap-in-frame"),
        "{f:#?}"
    );
    // The replay command reproduces it (exit 1: the device answered).
    let out = Run::new(replay.split_whitespace().skip(1)).run();
    let text = &out.stdout;
    assert_eq!(out.code, Some(1), "{text}");
    assert!(text.contains("timing.gap-in-frame"), "{text}");
}

#[test]
fn the_clean_simulator_passes_the_timing_classes() {
    let cases = std::env::var("FUZZ_CASES").unwrap_or_else(|_| "300".into());
    let (code, v) = timing_run("t-clean", &[], &cases);
    let f = confirmed_findings(&v);
    assert!(f.is_empty(), "{f:#?}");
    assert_eq!(code, Some(0));
    let t = &v["fuzz"]["modes"][0]["timing"];
    assert!(t["not_sent"].is_null(), "{t}");
    for class in [
        "timing.gap-in-frame",
        "timing.split-under-t15",
        "timing.split-over-t35",
        "timing.no-t35",
    ] {
        assert!(
            t["sent"][class].as_u64().unwrap_or(0) > 0,
            "no {class}: {t}"
        );
    }
}

#[test]
fn timing_damage_is_not_sent_without_line_timing() {
    let args = "--sim f510 --mode rtu --no-pace --cases 100 --quirk ignore-t15";
    let (code, v) = report_in("fuzz", "t-unpaced", args, Duration::from_secs(300));
    assert_eq!(code, Some(0));
    let t = &v["fuzz"]["modes"][0]["timing"];
    assert!(
        t["not_sent"].as_str().unwrap().contains("no line timing"),
        "{t}"
    );
    assert!(t["sent"].as_object().unwrap().is_empty());
}

#[test]
fn send_splits_a_frame_with_the_silence_asked_for() {
    // Under t1.5 (19200 baud 8E1: 860 us; t3.5 2006 us): one frame, answered.
    let run = |gap: &str| {
        let out = Run::words("send --sim f510 --mode rtu -b 19200 --split 3 --gap")
            .args([gap, "010325200001", "8ECC"])
            .run();
        (out.code, out.stdout)
    };
    let (code, text) = run("300us");
    assert_eq!(code, Some(0), "{text}");
    assert!(
        text.contains("timing.split-under-t15")
            && text.contains("device: node 01 03 read response"),
        "{text}"
    );
    // Between t1.5 and t3.5: discarded, silence as predicted.
    let (code, text) = run("1250us");
    assert_eq!(code, Some(0), "{text}");
    assert!(
        text.contains("timing.gap-in-frame") && text.contains("no reply"),
        "{text}"
    );
    // Without line timing: refused, exit 2.
    Run::words("send --sim f510 --mode rtu --no-pace --split 3 --gap 1ms 010325200001 8ECC")
        .run()
        .expect(2);
}
