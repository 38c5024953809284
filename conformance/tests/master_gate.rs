//! The master gate (`conformance gate --master`): this suite's own master, the test
//! double (`conformance adapter --master`), gives no finding in RTU and in ASCII; each of
//! its planted bugs (`--master-quirk`) is caught as the right kind of finding and as no
//! other kind; an adapter that is not a master stops the gate with exit code 2.
//!
//! No test here asserts a time: the gate's timing judgements are bounds that a loaded
//! host can only make more lenient, and the quirk that needs timing (no-t35) runs in RTU
//! at 300 baud (its reads only), where t3.5 less one character is 84 ms: a host that
//! stalls the gate's drive long enough to hide the quirk makes the gate run the case
//! again instead. In ASCII the same quirk is caught by the drive's frame under way, which
//! no timing blurs.

mod common;
use common::gate::{gate_json, schema_valid, status_of};
use common::{Ran, Run, Scratch};

use std::collections::BTreeSet;

fn gate_master(master: &str, extra: &[&str]) -> (Ran, serde_json::Value) {
    gate_json("--master", master, extra)
}

/// The kinds of deviation the report groups, with their cases.
fn deviation_kinds(v: &serde_json::Value) -> BTreeSet<String> {
    v["master"]["kinds"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|k| k["severity"] == "deviation")
        .map(|k| k["kind"].as_str().unwrap().to_string())
        .collect()
}

/// The cases that ended in ERROR, with why (for a failing assertion's message).
fn errors(v: &serde_json::Value) -> Vec<String> {
    common::with_status(v, &["error"])
}

fn master(quirk: Option<&str>) -> String {
    match quirk {
        None => "conformance adapter --master".to_string(),
        Some(q) => format!("conformance adapter --master --master-quirk {q}"),
    }
}

#[test]
fn the_clean_master_gives_no_finding_in_rtu_and_ascii() {
    let (o, v) = gate_master(&master(None), &["--mode", "both"]);
    schema_valid(&v);
    let kinds = deviation_kinds(&v);
    assert!(kinds.is_empty(), "{kinds:?}: {:#}", v["master"]["kinds"]);
    assert_eq!(o.code, Some(0), "{:?} {}", errors(&v), o.stderr);
    assert_eq!(v["summary"]["deviation"], 0);
    assert_eq!(v["summary"]["error"], 0);
    assert_eq!(v["summary"]["skip"], 0);
    // Every fault ran in both modes, against every operation.
    for id in [
        "rtu.read.normal",
        "rtu.read.stale-reply",
        "rtu.read.stale-in-flight",
        "rtu.read.wrong-function",
        "rtu.read.exception-02",
        "rtu.read.bad-checksum",
        "rtu.read.other-node",
        "rtu.read.zero-before",
        "rtu.write-single.no-reply",
        "rtu.write-multiple.twice",
        "rtu.loop-back.exception-01",
        "rtu.broadcast-single.reply-to-broadcast",
        "ascii.read.stale-reply",
        "ascii.read.exception-no-checksum",
        "ascii.broadcast-multiple.normal",
    ] {
        let s = status_of(&v, id);
        assert!(s == "pass" || s == "observation", "{id}: {s}");
    }
    assert_eq!(v["master"]["settings"]["rtu"]["timeout_ms"], 300);
    assert_eq!(v["master"]["settings"]["ascii"]["retries"], 0);
}

#[test]
fn a_clean_master_that_retries_as_its_setting_says_gives_no_finding() {
    let (o, v) = gate_master(&master(None), &["--mode", "rtu", "--retries", "1"]);
    schema_valid(&v);
    let kinds = deviation_kinds(&v);
    assert!(kinds.is_empty(), "{kinds:?}: {:#}", v["master"]["kinds"]);
    assert_eq!(o.code, Some(0), "{:?}", errors(&v));
    assert_eq!(v["master"]["settings"]["rtu"]["retries"], 1);
    // A second try after a reply split by a silence over t1.5 is right, not a storm (a
    // loaded host may hand the master both parts at once: then it is an observation).
    assert_ne!(status_of(&v, "rtu.read.split"), "deviation");
}

/// A fault case first on its line, with retries, once made the gate panic (the silence
/// before the master's first request is unbounded, and t3.5's check added a character to
/// it): each such case, alone and reopened, ends with a report.
#[test]
fn a_fault_case_first_on_its_line_with_retries_gives_a_report() {
    for (only, extra) in [
        (&["rtu.read.no-reply"][..], &[][..]),
        (&["rtu.read.garbage-before"][..], &["-b", "19200"][..]),
        (
            &["rtu.read.bad-checksum", "rtu.read.no-reply"][..],
            &["--reopen-each-case"][..],
        ),
    ] {
        let mut args = vec!["--mode", "rtu", "--retries", "1"];
        for id in only {
            args.extend(["--only", id]);
        }
        args.extend_from_slice(extra);
        let (o, v) = gate_master(&master(None), &args);
        schema_valid(&v);
        assert_eq!(o.code, Some(0), "{only:?}: {:?} {}", errors(&v), o.stderr);
        for id in only {
            let s = status_of(&v, id);
            assert!(s == "pass" || s == "observation", "{id}: {s}");
        }
    }
}

/// Runs the whole schedule of `mode` against the master with `quirk`; asserts that the
/// gate found deviations of `kind` and of no other kind, and returns the report.
fn caught_as(quirk: &str, mode: &str, kind: &str, extra: &[&str]) -> serde_json::Value {
    let mut args = vec!["--mode", mode];
    args.extend_from_slice(extra);
    let (o, v) = gate_master(&master(Some(quirk)), &args);
    schema_valid(&v);
    let kinds = deviation_kinds(&v);
    let want: BTreeSet<String> = [kind.to_string()].into();
    assert_eq!(kinds, want, "{quirk} in {mode}: {:#}", v["master"]["kinds"]);
    assert_eq!(o.code, Some(1), "{quirk} in {mode}: {:?}", errors(&v));
    let k = v["master"]["kinds"]
        .as_array()
        .unwrap()
        .iter()
        .find(|k| k["kind"] == kind)
        .unwrap();
    let repro = k["reproduce"].as_str().unwrap();
    assert!(
        repro.starts_with("conformance gate --master ") && repro.contains("--only "),
        "{repro}"
    );
    assert!(repro.contains(quirk), "{repro}");
    v
}

#[test]
fn a_master_that_takes_a_stale_reply_is_caught() {
    for mode in ["rtu", "ascii"] {
        let v = caught_as("takes-stale-reply", mode, "stale-reply-taken", &[]);
        // The headline case: the reply that came after the master's timeout, taken as
        // the answer to its next read.
        assert_eq!(
            status_of(&v, &format!("{mode}.read.stale-reply")),
            "deviation"
        );
        if mode == "rtu" {
            html_lists_the_kinds(&v, "stale-reply-taken", "rtu.read.stale-reply");
        }
    }
}

/// The saved report rendered as HTML (`conformance report`): a row for `kind` in the
/// section of what was found on the master, its case `case` linked to its finding, and
/// every link of the page landing on an element of the page.
fn html_lists_the_kinds(v: &serde_json::Value, kind: &str, case: &str) {
    let d = Scratch::new("master-gate-html");
    let json = d.join("r.json");
    std::fs::write(&json, v.to_string()).unwrap();
    let page = common::rendered(&json, &d.join("r.html"));
    let at = page
        .find("<h2 id=\"found\">")
        .expect("no section of what was found");
    let section = &page[at..at + page[at..].find("</table>").unwrap()];
    assert!(
        section.contains(&format!("<td class=\"id\">{kind}</td>")),
        "{section}"
    );
    assert!(
        section.contains(&format!("<a href=\"#f-{case}\"><code>{case}</code></a>")),
        "{section}"
    );
    assert_eq!(
        conformance::report::unresolved_links(&page),
        Vec::<String>::new()
    );
    // The master's timeout is in its settings; the gate's is an allowance.
    assert!(page.contains("allowance "), "{page}");
    // A master gate's words: cases, deviations in the master, sources that are no manual,
    // and the stale reply shown as what came, not as no reply found.
    assert!(page.contains("deviation in the master") || page.contains("deviations in the master"));
    for wrong in [
        "from the manual",
        "Manual:",
        "</b>checks</div>",
        "no reply frame found",
    ] {
        assert!(!page.contains(wrong), "{wrong:?} in {page}");
    }
    assert!(page.contains("</b>cases</div>"), "{page}");
    assert!(page.contains("none: what came (below) is no valid reply to this request"));
}

#[test]
fn a_master_that_does_not_keep_t35_is_caught() {
    let v = caught_as(
        "no-t35",
        "rtu",
        "no-t3.5",
        &[
            "-b",
            "300",
            "--master-timeout",
            "1000",
            "--only",
            "rtu.read.*",
        ],
    );
    assert_eq!(status_of(&v, "rtu.read.line-busy"), "deviation");
    // ASCII has no t3.5: the same master is caught sending while the drive sends.
    let v = caught_as("no-t35", "ascii", "talks-over-drive", &[]);
    assert_eq!(status_of(&v, "ascii.read.line-busy"), "deviation");
}

/// [`caught_as`] in RTU and then in ASCII, where the case `<mode>.<case>` must deviate:
/// each mode with its report.
fn caught_in_both_modes(
    quirk: &str,
    kind: &str,
    case: &str,
) -> [(&'static str, serde_json::Value); 2] {
    ["rtu", "ascii"].map(|mode| {
        let v = caught_as(quirk, mode, kind, &[]);
        let id = format!("{mode}.{case}");
        assert_eq!(status_of(&v, &id), "deviation", "{id}");
        (mode, v)
    })
}

#[test]
fn a_master_that_accepts_a_bad_checksum_is_caught() {
    let kind = "accepted-bad-checksum";
    for (mode, v) in caught_in_both_modes("accepts-bad-crc", kind, "read.bad-checksum") {
        assert_eq!(status_of(&v, &format!("{mode}.read.normal")), "pass");
    }
}

#[test]
fn a_master_that_retries_without_pause_is_caught() {
    caught_in_both_modes("retry-storm", "retry-storm", "read.no-reply");
}

#[test]
fn a_master_that_ignores_exceptions_is_caught() {
    let case = "write-single.exception-03";
    caught_in_both_modes("ignores-exception", "exception-ignored", case);
    // The legacy L510's own codes, 51H..55H, and a code of another device (0BH).
    let v = caught_as(
        "ignores-exception",
        "rtu",
        "exception-ignored",
        &["--model", "l510-legacy", "--exception-code", "0B"],
    );
    assert_eq!(status_of(&v, "rtu.read.exception-52"), "deviation");
    assert_eq!(status_of(&v, "rtu.read.exception-0b"), "deviation");
}

#[test]
fn a_master_that_reads_over_the_limit_is_caught() {
    caught_in_both_modes("reads-over-limit", "request-over-limit", "read.normal");
}

#[test]
fn over_tcp_the_same_master_is_judged_without_line_timing() {
    let (o, v) = gate_master(&master(None), &["--mode", "rtu", "--line", "tcp-rtu"]);
    schema_valid(&v);
    assert_eq!(o.code, Some(0), "{:?}", errors(&v));
    assert!(deviation_kinds(&v).is_empty(), "{:#}", v["master"]["kinds"]);
    assert_eq!(v["master"]["line"], "tcp-rtu");
    assert_eq!(status_of(&v, "rtu.read.stale-reply"), "pass");
    // No t1.5 or t3.5 over TCP: the cases that need them are skipped, with the reason.
    for id in ["rtu.read.split", "rtu.read.line-busy"] {
        assert_eq!(status_of(&v, id), "skip", "{id}");
    }
    let v = caught_as(
        "accepts-bad-crc",
        "rtu",
        "accepted-bad-checksum",
        &["--line", "tcp-rtu"],
    );
    assert!(v["master"]["kinds"][0]["reproduce"]
        .as_str()
        .unwrap()
        .contains("--line tcp-rtu"));
}

#[test]
fn an_adapter_that_is_not_a_master_stops_the_gate() {
    let o = Run::words("gate --master")
        .arg("conformance adapter")
        .args(["--only", "rtu.read.normal"])
        .run();
    assert_eq!(o.code, Some(2));
    let err = o.stderr.as_str();
    assert!(err.contains("role"), "{err}");
}

#[test]
fn the_cases_list_without_an_adapter() {
    let o = Run::words("gate --master /nonexistent/master --list --model l510-legacy").run();
    assert_eq!(o.code, Some(0));
    let out = o.stdout.as_str();
    for id in [
        "rtu.read.exception-51",
        "rtu.read.exception-55",
        "ascii.read.stale-reply",
    ] {
        assert!(out.contains(id), "{id}: {out}");
    }
}
