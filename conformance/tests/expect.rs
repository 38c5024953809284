//! Expectations (`--expect FILE`, `conformance expect --from`): a file written from a run
//! with a planted fault gates that run (exit 0), reports the fault's checks as UNEXPECTED
//! PASS on a clean drive (exit 1 with --strict-expect), and fails a run with one more
//! fault naming only the new deviations. Expired and unmatched entries are reported;
//! an invalid file is refused with its line and field.

mod common;
use common::{line, Ran, Run, Scratch};

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::time::Duration;

/// Short runs: the map checks of groups 1 and 10..18 (wrong-exception makes their
/// past-end reads deviate) and the broadcast checks (reply-to-broadcast makes them
/// deviate). The simulator is not paced (`--no-pace`): what is compared is which checks
/// deviate, and a paced pseudo-terminal on a loaded host can stall a request (an ERROR,
/// exit 2) that has nothing to do with expectations.
const ONLY: [&str; 4] = ["--only", "rtu.map.group-1*", "--only", "rtu.broadcast.*"];

/// `conformance check --sim f510 ONLY ARGS --format json -o DIR/check.json`: exit code
/// and report (checked against the schema).
fn check(dir: &Path, args: &[&str]) -> (Option<i32>, serde_json::Value) {
    let mut all = vec!["--sim", "f510", "--no-pace"];
    all.extend(ONLY);
    all.extend(args);
    common::check_device(dir, &all, Duration::from_secs(120))
}

/// Runs the binary to completion (for the quick commands: expect, report, refusals).
fn conformance(args: &[&str]) -> Ran {
    let out = Run::new(args).run();
    let stderr = out.stderr.as_str();
    assert!(!stderr.contains("panicked"), "{stderr}");
    out
}

fn ids_with(v: &serde_json::Value, status: &str) -> BTreeSet<String> {
    v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["status"] == status)
        .map(|c| c["id"].as_str().unwrap().to_string())
        .collect()
}

fn ids_marked(v: &serde_json::Value, outcome: &str) -> BTreeSet<String> {
    v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["expectation"]["outcome"] == outcome)
        .map(|c| c["id"].as_str().unwrap().to_string())
        .collect()
}

/// The ids listed under a heading of the text report (up to the next heading).
fn listed_under(text: &str, heading: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut inside = false;
    for line in text.lines() {
        if line.starts_with(heading) {
            inside = true;
            continue;
        }
        if inside && !line.is_empty() && !line.starts_with(' ') {
            break;
        }
        if inside {
            if let Some(id) = line
                .trim_start()
                .strip_prefix('[')
                .and_then(|l| l.split(']').next())
            {
                out.insert(id.to_string());
            }
        }
    }
    out
}

/// Writes the starting file from a wrong-exception run; returns it with the run's
/// deviations.
fn starting_file(d: &Path) -> (PathBuf, BTreeSet<String>) {
    let (exit, v) = check(d, &["--quirk", "wrong-exception"]);
    assert_eq!(exit, Some(1), "{}", v["summary"]);
    let deviating = ids_with(&v, "deviation");
    assert!(deviating.len() >= 5, "{deviating:?}");
    let run = d.join("wrong-exception.json");
    std::fs::rename(d.join("check.json"), &run).unwrap();
    let file = d.join("expect.toml");
    let out = conformance(&[
        "expect",
        "--from",
        run.to_str().unwrap(),
        "--reason",
        "firmware answers code+1, ticket 28",
        "-o",
        file.to_str().unwrap(),
    ]);
    assert_eq!(out.code, Some(0), "{}", out.stderr);
    let text = std::fs::read_to_string(&file).unwrap();
    assert_eq!(
        text.matches("[[expect]]").count(),
        deviating.len(),
        "{text}"
    );
    for id in &deviating {
        assert!(text.contains(&format!("check = \"{id}\"")), "{id}: {text}");
    }
    assert!(text.contains("reason = \"firmware answers code+1, ticket 28\""));
    (file, deviating)
}

#[test]
fn an_expectations_file_gates_runs_by_what_changed() {
    let d = Scratch::new("gate");
    let (file, deviating) = starting_file(&d);
    let expect = ["--expect", file.to_str().unwrap()];

    // The run it was written from: every deviation expected, exit 0.
    let (exit, v) = check(&d, &[&["--quirk", "wrong-exception"][..], &expect].concat());
    assert_eq!(exit, Some(0), "{}", v["expectations"]["counts"]);
    assert_eq!(v["exit_code"], 0);
    assert_eq!(ids_marked(&v, "expected"), deviating);
    assert_eq!(v["expectations"]["counts"]["unexpected"], 0);
    assert_eq!(
        v["summary"]["deviation"],
        deviating.len(),
        "still reported as deviations"
    );
    // `report` reads the outcome back: the deviations are listed as expected.
    let saved = d.join("expected.json");
    std::fs::rename(d.join("check.json"), &saved).unwrap();
    let out = conformance(&["report", saved.to_str().unwrap()]);
    let text = out.stdout.as_str();
    assert_eq!(listed_under(text, "EXPECTED ("), deviating, "{text}");
    assert!(listed_under(text, "NEW DEVIATIONS").is_empty(), "{text}");

    // The clean drive: each expected deviation is an UNEXPECTED PASS; exit 0, and 1 with
    // --strict-expect.
    let (exit, v) = check(&d, &expect);
    assert_eq!(exit, Some(0), "{}", v["expectations"]["counts"]);
    assert_eq!(ids_marked(&v, "unexpected-pass"), deviating);
    let (exit, v) = check(&d, &[&expect[..], &["--strict-expect"]].concat());
    assert_eq!(exit, Some(1), "{}", v["expectations"]["counts"]);
    assert_eq!(v["expectations"]["strict"], true);
    assert_eq!(ids_marked(&v, "unexpected-pass"), deviating);
    let out = conformance(&["report", d.join("check.json").to_str().unwrap()]);
    let text = out.stdout.as_str();
    assert_eq!(listed_under(text, "UNEXPECTED PASSES"), deviating, "{text}");
    assert!(
        text.contains("UNEXPECTED PASS: expected deviation"),
        "{text}"
    );

    // One more fault: exit 1, and only its deviations are new.
    let (exit, v) = check(
        &d,
        &[
            &[
                "--quirk",
                "wrong-exception",
                "--quirk",
                "reply-to-broadcast",
            ][..],
            &expect,
        ]
        .concat(),
    );
    assert_eq!(exit, Some(1), "{}", v["expectations"]["counts"]);
    let now: BTreeSet<String> = ids_with(&v, "deviation");
    let new: BTreeSet<String> = now.difference(&deviating).cloned().collect();
    assert!(
        !new.is_empty() && new.iter().all(|id| id.contains("broadcast")),
        "{new:?}"
    );
    assert_eq!(v["expectations"]["counts"]["unexpected"], new.len());
    assert_eq!(ids_marked(&v, "expected"), deviating);
    let out = conformance(&["report", d.join("check.json").to_str().unwrap()]);
    let text = out.stdout.as_str();
    assert_eq!(listed_under(text, "NEW DEVIATIONS"), new, "{text}");
    // The diff from the expected run to this one names the new deviations, and sees that
    // the expected ones are still as expected.
    let out = conformance(&[
        "diff",
        saved.to_str().unwrap(),
        d.join("check.json").to_str().unwrap(),
    ]);
    assert_eq!(out.code, Some(1));
    let text = out.stdout.as_str();
    for id in &new {
        assert!(text.contains(id.as_str()), "{id}: {text}");
    }
    assert!(text.contains("expected"), "{text}");
}

#[test]
fn expired_and_unmatched_entries_are_reported_and_do_not_apply() {
    let d = Scratch::new("stale");
    let (file, deviating) = starting_file(&d);
    // The first entry expired long ago; one more names a check that does not exist.
    let first = deviating.iter().next().unwrap().clone();
    let text = std::fs::read_to_string(&file).unwrap();
    let at = format!("check = \"{first}\"\n");
    let text = text.replacen(&at, &format!("{at}expires = 2020-01-31\n"), 1)
        + "\n[[expect]]\ncheck = \"rtu.no-such-check\"\nstatus = \"deviation\"\nreason = \"stale\"\n";
    std::fs::write(&file, &text).unwrap();
    let (exit, v) = check(
        &d,
        &[
            "--quirk",
            "wrong-exception",
            "--expect",
            file.to_str().unwrap(),
        ],
    );
    assert_eq!(
        exit,
        Some(1),
        "the deviation of the expired entry is new again"
    );
    let entries = v["expectations"]["entries"].as_array().unwrap();
    let state_of = |check: &str| {
        entries
            .iter()
            .find(|e| e["check"] == check)
            .map(|e| e["state"].as_str().unwrap().to_string())
    };
    assert_eq!(state_of(&first).as_deref(), Some("expired"));
    assert_eq!(state_of("rtu.no-such-check").as_deref(), Some("unmatched"));
    assert_eq!(v["expectations"]["counts"]["expired"], 1);
    assert_eq!(v["expectations"]["counts"]["unmatched"], 1);
    assert_eq!(v["expectations"]["counts"]["unexpected"], 1);
    let out = conformance(&["report", d.join("check.json").to_str().unwrap()]);
    let report = out.stdout.as_str();
    assert_eq!(
        listed_under(report, "NEW DEVIATIONS"),
        BTreeSet::from([first.clone()])
    );
    let stale: Vec<&str> = report
        .lines()
        .skip_while(|l| !l.starts_with("EXPECTATIONS NOT APPLIED (2)"))
        .skip(1)
        .take(2)
        .collect();
    assert!(
        stale[0].contains(&first) && stale[0].contains("EXPIRED on 2020-01-31"),
        "{report}"
    );
    assert!(
        stale[1].contains("rtu.no-such-check") && stale[1].contains("matched nothing"),
        "{report}"
    );
}

#[test]
fn an_invalid_file_is_refused_with_its_line_and_field_before_the_run() {
    let d = Scratch::new("invalid");
    let file = d.join("bad.toml");
    std::fs::write(
        &file,
        "# known\n[[expect]]\ncheck = \"rtu.map.group-1.past-end\"\nstatus = \"deviates\"\nreason = \"r\"\n",
    )
    .unwrap();
    let f = file.to_str().unwrap();
    let sim = ["--sim", "f510", "--only", "rtu.map.group-1.past-end"];
    for args in [
        [&["check"][..], &sim, &["--expect", f]].concat(),
        [&["fuzz"][..], &sim[..2], &["--expect", f]].concat(),
        vec!["gate", "--codec", "conformance adapter", "--expect", f],
        vec![
            "monitor",
            "--model",
            "f510",
            "--port",
            "/dev/null",
            "--expect",
            f,
        ],
    ] {
        let out = conformance(&args);
        let stderr = out.stderr.as_str();
        assert_eq!(out.code, Some(2), "{args:?}: {stderr}");
        assert!(
            stderr.contains(&format!("{f}:4: status: \"deviates\" is not")),
            "{args:?}: {stderr}"
        );
    }
    // Another field on another line, and a file that is not TOML: each refused, naming
    // its line (and the field, where there is one).
    for (text, says) in [
        (
            "[[expect]]\ncheck = \"x\"\nstatus = \"deviation\"\nreason = \"r\"\nexpires = \"soon\"\n",
            format!("{f}:5: expires: "),
        ),
        (
            "[[expect]]\ncheck = \"x\"\nreason = \"r\nstatus = 1\n",
            format!("{f}:3: "),
        ),
    ] {
        std::fs::write(&file, text).unwrap();
        let out = conformance(&[&["check"][..], &sim, &["--expect", f]].concat());
        assert_eq!(out.code, Some(2), "{says}");
        let stderr = out.stderr.as_str();
        assert!(stderr.contains(&says), "{stderr}");
    }
    // --strict-expect means nothing without a file.
    let out = conformance(&[&["check"][..], &sim, &["--strict-expect"]].concat());
    assert_eq!(out.code, Some(2));
}

/// A fuzz run: `expect --from` a campaign against wrong-exception writes one entry per
/// finding signature; the same campaign with the file exits 0; a campaign against the
/// clean drive does not find them again, which is an UNEXPECTED PASS (exit 1 with
/// --strict-expect).
/// `expect --from run -o file`, which must exit 0.
fn expect_from(run: &Path, file: &Path) {
    let out = conformance(&line(&[
        "expect --from",
        run.to_str().unwrap(),
        "-o",
        file.to_str().unwrap(),
    ]));
    assert_eq!(out.code, Some(0), "{out}");
}

#[test]
fn fuzz_findings_are_expected_by_their_signature() {
    let d = Scratch::new("fuzz");
    let fuzz = |quirk: &[&str], more: &[&str]| {
        let mut args = vec![
            "--sim",
            "f510",
            "--no-pace",
            "--mode",
            "rtu",
            "--cases",
            "60",
            "--no-minimize",
        ];
        args.extend(quirk);
        args.extend(more);
        common::report_of("fuzz", &d, &args, Duration::from_secs(120))
    };
    let (exit, v) = fuzz(&["--quirk", "wrong-exception"], &[]);
    assert_eq!(exit, Some(1), "{}", v["summary"]);
    let run = d.join("fuzz-first.json");
    std::fs::rename(d.join("fuzz.json"), &run).unwrap();
    let findings: BTreeSet<String> = v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["status"] == "deviation" || c["status"] == "observation")
        .map(|c| c["id"].as_str().unwrap().to_string())
        .collect();
    assert!(!findings.is_empty());
    let file = d.join("fuzz.toml");
    expect_from(&run, &file);
    let text = std::fs::read_to_string(&file).unwrap();
    for id in &findings {
        let sig = id.strip_prefix("fuzz.").unwrap();
        assert!(
            text.contains(&format!("signature = \"{sig}\"")),
            "{sig}: {text}"
        );
    }
    let f = file.to_str().unwrap();
    let (exit, v) = fuzz(&["--quirk", "wrong-exception"], &["--expect", f]);
    assert_eq!(exit, Some(0), "{}", v["expectations"]["counts"]);
    assert_eq!(ids_marked(&v, "expected"), findings);
    let (exit, v) = fuzz(&[], &["--expect", f, "--strict-expect"]);
    assert_eq!(exit, Some(1), "{}", v["expectations"]["counts"]);
    assert_eq!(
        v["expectations"]["counts"]["unexpected_pass"],
        findings.len()
    );
    assert!(v["expectations"]["entries"]
        .as_array()
        .unwrap()
        .iter()
        .all(|e| e["state"] == "not-found"));
    let (exit, _) = fuzz(&[], &["--expect", f]);
    assert_eq!(exit, Some(0), "not strict");
}

/// `monitor` judges a capture: `expect --from` its report accepts what it heard, and the
/// same capture judged with the file exits 0 with each of its results expected.
#[test]
fn a_monitor_run_is_gated_by_the_same_file() {
    let d = Scratch::new("monitor");
    let cap = d.join("run.pcapng");
    let (exit, _) = check(
        &d,
        &line(&[
            "--quirk wrong-exception --mode rtu --capture",
            cap.to_str().unwrap(),
        ]),
    );
    assert_eq!(exit, Some(1));
    let monitor = |more: &[&str]| {
        let mut args = vec![
            "--capture-in",
            cap.to_str().unwrap(),
            "--model",
            "f510",
            "-a",
            "1",
        ];
        args.extend(more);
        common::report_of("monitor", &d, &args, Duration::from_secs(60))
    };
    let (exit, v) = monitor(&[]);
    assert_eq!(exit, Some(1), "{}", v["summary"]);
    let deviating = ids_with(&v, "deviation");
    assert!(
        deviating
            .iter()
            .any(|id| id.ends_with(".drive.wrong-exception")),
        "{deviating:?}"
    );
    let run = d.join("monitor-first.json");
    std::fs::rename(d.join("monitor.json"), &run).unwrap();
    let file = d.join("monitor.toml");
    expect_from(&run, &file);
    let (exit, v) = monitor(&["--expect", file.to_str().unwrap()]);
    assert_eq!(exit, Some(0), "{}", v["expectations"]["counts"]);
    assert_eq!(ids_marked(&v, "expected"), deviating);
}
