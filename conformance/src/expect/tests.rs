use super::*;
use crate::report::{
    apply_expectations as apply, starting_expectations as starting_file, Device, Report, ReportKind,
};
use crate::runner::{CheckResult, Status};

const GOOD: &str = r#"# accepted deviations
[[expect]]
check = "rtu.map.group-0.past-end"
status = "deviation"
reason = "answers 03H, ticket 123"
ticket = "https://tracker.example/123"
expires = 2027-01-31
identification = "0510"

[[expect]]
check = "ascii.map.*.past-end"
status = "deviation"
reason = "the same in ASCII"
mode = "ascii"
node = 1

[[expect]]
signature = "rtu.mismatch.03H.exception-code"
reason = "fuzz finding, known"
"#;

fn day(s: &str) -> Day {
    Day::parse(s).unwrap()
}

#[test]
fn a_file_reads_with_its_lines() {
    let e = Expectations::parse(GOOD, "e.toml").unwrap();
    assert_eq!(e.entries.len(), 3);
    let a = &e.entries[0];
    assert_eq!(a.line, 2);
    assert_eq!(a.target, Target::Check("rtu.map.group-0.past-end".into()));
    assert_eq!(a.status, Expected::Deviation);
    assert_eq!(a.expires, Some(day("2027-01-31")));
    assert_eq!(a.identification, Some(0x0510));
    assert_eq!(a.ticket.as_deref(), Some("https://tracker.example/123"));
    let b = &e.entries[1];
    assert_eq!(b.line, 10);
    assert_eq!((b.mode, b.node), (Some(Mode::Ascii), Some(1)));
    let c = &e.entries[2];
    assert_eq!(c.line, 17);
    assert_eq!(
        c.status,
        Expected::Finding,
        "a signature expects any finding"
    );
    assert_eq!(
        c.target.id_pattern(),
        "fuzz.rtu.mismatch.03H.exception-code"
    );
    // An empty file expects nothing.
    assert!(Expectations::parse("# nothing yet\n", "e.toml")
        .unwrap()
        .entries
        .is_empty());
}

/// The line and field an invalid file is refused with.
fn refused(text: &str) -> (usize, String, String) {
    match Expectations::parse(text, "e.toml") {
        Err(ExpectError::Invalid {
            line,
            field,
            problem,
            path,
        }) => {
            assert_eq!(path, "e.toml");
            (line, field, problem)
        }
        other => panic!("not refused: {other:?}"),
    }
}

#[test]
fn an_invalid_file_names_the_line_and_the_field() {
    let entry = "[[expect]]\ncheck = \"rtu.x\"\nreason = \"r\"\n";
    let (line, field, problem) = refused(&format!("{entry}status = \"fine\"\n"));
    assert_eq!((line, field.as_str()), (4, "status"));
    assert!(problem.contains("\"fine\""), "{problem}");
    let (line, field, problem) = refused(&format!("{entry}status = \"error\"\n"));
    assert_eq!((line, field.as_str()), (4, "status"));
    assert!(problem.contains("ERROR"), "{problem}");
    let (line, field, _) = refused(&format!(
        "\n\n{entry}status = \"deviation\"\nexpires = 2027-13-01\n"
    ));
    assert_eq!(field, "expires");
    assert_eq!(line, 7);
    let (line, field, _) = refused(&format!(
        "{entry}status = \"deviation\"\nexpires = 2027-01-01T10:00:00\n"
    ));
    assert_eq!((line, field.as_str()), (5, "expires"));
    let (line, field, problem) = refused(&format!("{entry}status = \"deviation\"\nnode = 300\n"));
    assert_eq!((line, field.as_str()), (5, "node"));
    assert!(problem.contains("300"), "{problem}");
    let (line, field, _) = refused(&format!("{entry}status = \"deviation\"\nnode = \"one\"\n"));
    assert_eq!((line, field.as_str()), (5, "node"));
    let (line, field, _) = refused(&format!("{entry}status = \"deviation\"\nmode = \"tcp\"\n"));
    assert_eq!((line, field.as_str()), (5, "mode"));
    let (line, field, _) = refused(&format!(
        "{entry}status = \"deviation\"\nidentification = \"F5xx\"\n"
    ));
    assert_eq!((line, field.as_str()), (5, "identification"));
    let (line, field, problem) = refused(&format!("{entry}status = \"deviation\"\ncolour = 1\n"));
    assert_eq!(field, "colour");
    assert!(problem.contains("colour"), "{problem}");
    assert_eq!(line, 5);
    // A missing field names the entry's header line.
    let (line, field, _) = refused("# c\n[[expect]]\ncheck = \"rtu.x\"\nstatus = \"deviation\"\n");
    assert_eq!((line, field.as_str()), (2, "reason"));
    let (line, field, _) = refused("[[expect]]\nstatus = \"deviation\"\nreason = \"r\"\n");
    assert_eq!((line, field.as_str()), (1, "check"));
    let (line, field, _) = refused("[[expect]]\ncheck = \"rtu.x\"\nreason = \"r\"\n");
    assert_eq!((line, field.as_str()), (1, "status"));
    let (line, field, _) = refused(&format!(
        "{entry}status = \"deviation\"\nsignature = \"s\"\n"
    ));
    assert_eq!((line, field.as_str()), (5, "signature"));
    let (line, field, _) =
        refused("[[expect]]\ncheck = \"rtu x\"\nreason = \"r\"\nstatus = \"deviation\"\n");
    assert_eq!((line, field.as_str()), (2, "check"));
    let (line, field, _) =
        refused("[[expect]]\ncheck = \"rtu.x\"\nreason = \"  \"\nstatus = \"deviation\"\n");
    assert_eq!((line, field.as_str()), (3, "reason"));
    // A key that is empty once unquoted names no field: the entry is named instead
    // (a campaign found `'' = ' '` refused as "unknown field ``", naming nothing).
    for text in ["'' = ' '", "\"\" = 1", "[[expect]]\n'' = 1\n"] {
        let (_, field, problem) = refused(text);
        assert_eq!(field, "expect", "{text:?}: {problem}");
    }
    // Not TOML at all: the line of the syntax error.
    let (line, _, _) = refused("[[expect]]\ncheck = \"rtu.x\"\nreason = \"unterminated\n");
    assert_eq!(line, 3);
    // The message a person reads names the file, the line and the field.
    let e = Expectations::parse(&format!("{entry}status = \"fine\"\n"), "e.toml").unwrap_err();
    assert!(e.to_string().starts_with("e.toml:4: status: "), "{e}");
}

#[test]
fn globs_match_whole_ids() {
    assert!(glob_match("rtu.map.*.past-end", "rtu.map.group-0.past-end"));
    assert!(!glob_match(
        "rtu.map.*.past-end",
        "rtu.map.group-0.past-end.x"
    ));
    assert!(!glob_match("rtu.map", "rtu.map.group-0"));
    assert!(glob_match("rtu.map", "rtu.map"));
    assert!(glob_match("*", "anything"));
    assert!(glob_match("rtu.?ap.*", "rtu.map.x"));
    assert!(!glob_match("rtu.?ap.*", "rtu.ap.x"));
    assert!(glob_match("a*b*c", "aXXbYYc"));
    assert!(!glob_match("a*b*c", "aXXbYY"));
    assert!(glob_match(
        "fuzz.rtu.*",
        "fuzz.rtu.mismatch.03H.exception-code"
    ));
}

fn result(id: &str, status: Status) -> CheckResult {
    CheckResult {
        id: id.into(),
        title: id.into(),
        mode: Some(if id.starts_with("ascii") {
            Mode::Ascii
        } else {
            Mode::Rtu
        }),
        source: String::new(),
        status,
        summary: format!("{id} {status}"),
        findings: Vec::new(),
        exchanges: Vec::new(),
        duration: std::time::Duration::ZERO,
        node: None,
    }
}

fn report(results: Vec<CheckResult>) -> Report {
    Report {
        complete: true,
        device: Device {
            model: "f510".into(),
            address: 1,
            identification: Some(0x0510),
            ..Device::default()
        },
        results,
        ..Report::default()
    }
}

/// A report of checks with these ids and statuses.
fn report_of(results: &[(&str, Status)]) -> Report {
    report(results.iter().map(|&(id, s)| result(id, s)).collect())
}

fn entry(line: usize, check: &str, status: Expected) -> Entry {
    Entry {
        line,
        target: Target::Check(check.into()),
        node: None,
        mode: None,
        status,
        reason: format!("reason {line}"),
        ticket: None,
        expires: None,
        identification: None,
    }
}

fn file(entries: Vec<Entry>) -> Expectations {
    Expectations {
        path: "e.toml".into(),
        entries,
    }
}

#[test]
fn expected_deviations_leave_the_exit_code_to_new_ones() {
    let mut r = report_of(&[
        ("rtu.a", Status::Deviation),
        ("rtu.b", Status::Deviation),
        ("rtu.c", Status::Pass),
    ]);
    assert_eq!(r.exit_code(), 1);
    let f = file(vec![entry(1, "rtu.a", Expected::Deviation)]);
    apply(&mut r, &f, false, day("2026-06-01"));
    assert_eq!(r.exit_code(), 1, "rtu.b is new");
    let new: Vec<&str> = r
        .unexpected_findings()
        .iter()
        .map(|c| c.id.as_str())
        .collect();
    assert_eq!(new, ["rtu.b"]);
    let f = file(vec![
        entry(1, "rtu.a", Expected::Deviation),
        entry(5, "rtu.b", Expected::Deviation),
    ]);
    apply(&mut r, &f, false, day("2026-06-01"));
    assert_eq!(r.exit_code(), 0);
    assert!(r.is_expected(&r.results[0]) && r.is_expected(&r.results[1]));
    assert!(!r.is_expected(&r.results[2]));
    // An ERROR is never expected away: the bench could not tell.
    r.results.push(result("rtu.d", Status::Error));
    assert_eq!(r.exit_code(), 2);
}

#[test]
fn a_deviation_that_passes_is_an_unexpected_pass() {
    let mut r = report_of(&[("rtu.a", Status::Pass)]);
    let f = file(vec![entry(3, "rtu.a", Expected::Deviation)]);
    apply(&mut r, &f, false, day("2026-06-01"));
    let m = r.expectation(&r.results[0]).unwrap();
    assert_eq!((m.kind, m.line), (MarkKind::UnexpectedPass, 3));
    assert_eq!(r.unexpected_passes(), 1);
    assert_eq!(r.exit_code(), 0, "not strict");
    apply(&mut r, &f, true, day("2026-06-01"));
    assert_eq!(r.exit_code(), 1, "strict");
}

#[test]
fn a_glob_marks_passes_only_when_none_of_its_checks_deviates() {
    let mut r = report_of(&[
        ("rtu.map.a.past-end", Status::Deviation),
        ("rtu.map.b.past-end", Status::Pass),
    ]);
    let f = file(vec![entry(1, "rtu.map.*.past-end", Expected::Deviation)]);
    apply(&mut r, &f, true, day("2026-06-01"));
    assert!(r.is_expected(&r.results[0]));
    assert!(r.expectation(&r.results[1]).is_none());
    assert_eq!(r.exit_code(), 0);
    r.results[0].status = Status::Pass;
    apply(&mut r, &f, true, day("2026-06-01"));
    assert_eq!(r.unexpected_passes(), 2);
    assert_eq!(r.exit_code(), 1);
}

#[test]
fn expired_unmatched_and_other_device_entries_do_not_apply() {
    let mut r = report_of(&[
        ("rtu.a", Status::Deviation),
        ("rtu.b", Status::Deviation),
        ("rtu.s", Status::Skip),
    ]);
    let mut expired = entry(1, "rtu.a", Expected::Deviation);
    expired.expires = Some(day("2026-05-31"));
    let mut other = entry(2, "rtu.b", Expected::Deviation);
    other.identification = Some(0x0A51);
    let f = file(vec![
        expired,
        other,
        entry(3, "rtu.gone", Expected::Deviation),
        entry(4, "rtu.s", Expected::Deviation),
    ]);
    apply(&mut r, &f, false, day("2026-06-01"));
    let o = r.expect.as_ref().unwrap();
    let states: Vec<EntryState> = o.entries.iter().map(|e| e.state).collect();
    assert_eq!(
        states,
        [
            EntryState::Expired,
            EntryState::OtherDevice,
            EntryState::Unmatched,
            EntryState::Unmatched
        ]
    );
    assert_eq!(o.stale().count(), 4);
    assert_eq!(r.exit_code(), 1, "both deviations are new again");
    // The last day of an entry still applies; the identification that matches applies.
    let mut last_day = entry(1, "rtu.a", Expected::Deviation);
    last_day.expires = Some(day("2026-06-01"));
    let mut this_device = entry(2, "rtu.b", Expected::Deviation);
    this_device.identification = Some(0x0510);
    apply(
        &mut r,
        &file(vec![last_day, this_device]),
        false,
        day("2026-06-01"),
    );
    assert_eq!(r.exit_code(), 0);
}

/// `f` applied to `r` on 2026-06-01, and the state of its first entry.
fn first_state_after(r: &mut Report, f: &Expectations, strict: bool) -> EntryState {
    apply(r, f, strict, day("2026-06-01"));
    r.expect.as_ref().unwrap().entries[0].state
}

#[test]
fn node_and_mode_narrow_an_entry() {
    let mut a = result("rtu.a", Status::Deviation);
    a.node = Some(2);
    let mut b = result("rtu.a", Status::Deviation);
    b.node = Some(5);
    let mut r = report(vec![a, b]);
    r.device.nodes = vec![
        crate::report::NodeInfo {
            address: 2,
            ..Default::default()
        },
        crate::report::NodeInfo {
            address: 5,
            ..Default::default()
        },
    ];
    let mut e = entry(1, "rtu.a", Expected::Deviation);
    e.node = Some(5);
    apply(&mut r, &file(vec![e.clone()]), false, day("2026-06-01"));
    assert!(!r.is_expected(&r.results[0]));
    assert!(r.is_expected(&r.results[1]));
    e.node = None;
    e.mode = Some(Mode::Ascii);
    let state = first_state_after(&mut r, &file(vec![e]), false);
    assert_eq!(state, EntryState::Unmatched);
}

#[test]
fn a_fuzz_finding_is_expected_by_its_signature() {
    let mut r = report_of(&[
        ("fuzz.rtu.campaign", Status::Pass),
        ("fuzz.rtu.mismatch.03H.exception-code", Status::Observation),
    ]);
    r.kind = ReportKind::Fuzz;
    assert_eq!(r.exit_code(), 1, "a fuzz finding fails the run");
    let f = Expectations::parse(
        "[[expect]]\nsignature = \"rtu.mismatch.03H.*\"\nreason = \"known\"\n",
        "e.toml",
    )
    .unwrap();
    apply(&mut r, &f, true, day("2026-06-01"));
    assert_eq!(r.exit_code(), 0);
    // The clean drive: the campaign ran to its end and did not find it again.
    r.results.truncate(1);
    assert_eq!(first_state_after(&mut r, &f, false), EntryState::NotFound);
    assert_eq!((r.unexpected_passes(), r.exit_code()), (1, 0));
    apply(&mut r, &f, true, day("2026-06-01"));
    assert_eq!(r.exit_code(), 1, "strict");
    // A campaign that did not end (ERROR) says nothing: the entry matched nothing.
    r.results[0].status = Status::Error;
    assert_eq!(first_state_after(&mut r, &f, true), EntryState::Unmatched);
}

#[test]
fn a_starting_file_expects_the_run_it_came_from() {
    let mut r = report_of(&[
        ("rtu.a", Status::Deviation),
        ("rtu.b", Status::Pass),
        ("rtu.c", Status::Observation),
    ]);
    r.results[0].summary = "manual: \"02\"\\ device: 03\nnext line".into();
    let text = starting_file(&r, "run.json", Some("known \"bug\""));
    let f = Expectations::parse(&text, "e.toml").unwrap();
    assert_eq!(f.entries.len(), 1, "{text}");
    assert_eq!(f.entries[0].target, Target::Check("rtu.a".into()));
    assert_eq!(f.entries[0].reason, "known \"bug\"");
    assert_eq!(f.entries[0].identification, None, "written as a comment");
    assert!(text.contains("# identification = \"0510\""), "{text}");
    apply(&mut r, &f, true, Day::today());
    assert_eq!(r.exit_code(), 0);
    // Without --reason, a placeholder that says what to do.
    assert!(starting_file(&r, "run.json", None).contains("TODO"));
}

#[test]
fn the_outcome_reads_back_from_the_json_report() {
    let mut r = report_of(&[("rtu.a", Status::Deviation), ("rtu.b", Status::Pass)]);
    let mut gone = entry(9, "rtu.gone", Expected::Observation);
    gone.ticket = Some("T-1".into());
    gone.expires = Some(day("2030-02-03"));
    let f = file(vec![
        entry(1, "rtu.a", Expected::Deviation),
        entry(5, "rtu.b", Expected::Deviation),
        gone,
    ]);
    apply(&mut r, &f, true, day("2026-06-01"));
    let json = r.to_json();
    assert_eq!(json["exit_code"], 1);
    assert_eq!(json["expectations"]["counts"]["expected"], 1);
    assert_eq!(json["expectations"]["counts"]["unexpected_pass"], 1);
    assert_eq!(json["expectations"]["counts"]["unmatched"], 1);
    assert_eq!(json["checks"][0]["expectation"]["outcome"], "expected");
    assert_eq!(
        json["checks"][1]["expectation"]["outcome"],
        "unexpected-pass"
    );
    let back = Report::from_json(&json).unwrap();
    assert_eq!(back.expect, r.expect);
    assert_eq!(back.to_json(), json);
    assert_eq!(back.exit_code(), 1);
}

#[test]
fn days_parse_and_order() {
    assert!(day("2026-12-31") < day("2027-01-01"));
    assert_eq!(day("2027-01-31").to_string(), "2027-01-31");
    assert!(Day::parse("2027-1-31").is_none());
    assert!(Day::parse("2027-00-31").is_none());
    assert!(Day::parse("x").is_none());
    assert!(Day::today() > day("2020-01-01"));
}

#[test]
fn every_format_shows_expected_results_apart() {
    let mut r = report_of(&[
        ("rtu.a", Status::Deviation),
        ("rtu.b", Status::Deviation),
        ("rtu.c", Status::Pass),
    ]);
    let mut a = entry(2, "rtu.a", Expected::Deviation);
    a.ticket = Some("T-7".into());
    let f = file(vec![a, entry(8, "rtu.c", Expected::Deviation)]);
    apply(&mut r, &f, true, day("2026-06-01"));

    let text = crate::report::text(&r, false);
    assert!(
        text.contains("EXPECT:  e.toml: 1 expected, 1 new, 1 unexpected pass (strict"),
        "{text}"
    );
    let new_at = text.find("NEW DEVIATIONS (1)").expect("new section");
    let exp_at = text.find("EXPECTED (1)").expect("expected section");
    assert!(
        text[new_at..exp_at].contains("[rtu.b]") && !text[new_at..exp_at].contains("[rtu.a]"),
        "{text}"
    );
    assert!(
        text.contains("[rtu.a] DEVIATION: reason 2 (e.toml:2, T-7)"),
        "{text}"
    );
    assert!(
        text.contains("[rtu.c] UNEXPECTED PASS: expected deviation (e.toml:8)"),
        "{text}"
    );

    let junit = crate::report::junit(&r);
    let doc = roxmltree::Document::parse(&junit).unwrap();
    let root = doc.root_element();
    assert_eq!(
        root.attribute("failures"),
        Some("2"),
        "rtu.b, and rtu.c under strict"
    );
    assert_eq!(root.attribute("skipped"), Some("1"), "rtu.a");
    let case = |id: &str| {
        doc.descendants()
            .find(|n| n.has_tag_name("testcase") && n.attribute("name") == Some(id))
            .unwrap()
    };
    assert!(case("rtu.a")
        .children()
        .any(|n| n.has_tag_name("skipped") && n.attribute("type") == Some("expected")));
    assert!(case("rtu.c")
        .children()
        .any(|n| n.has_tag_name("failure") && n.attribute("type") == Some("unexpected-pass")));

    let csv = crate::report::csv(&r);
    let rows: Vec<&str> = csv.lines().collect();
    assert!(rows[0].ends_with(",expectation,expectation_entry"));
    assert!(
        rows[1].starts_with("rtu.a,") && rows[1].ends_with(",expected,e.toml:2: reason 2"),
        "{csv}"
    );
    assert!(
        rows[2].starts_with("rtu.b,") && rows[2].ends_with(",new,"),
        "{csv}"
    );
    assert!(rows[3].contains(",unexpected-pass,"), "{csv}");

    let html = crate::report::html(&r);
    assert!(html.contains("<h2 id=\"deviations\">Errors (0) and new deviations (1)</h2>"));
    assert!(html.contains("<h2 id=\"expected\">Expected results (1)</h2>"));
    assert!(html.contains(">UNEXPECTED PASS</span>"));

    // Without a file, every format is as it was.
    r.expect = None;
    assert!(!crate::report::text(&r, false).contains("EXPECT"));
    assert!(crate::report::csv(&r)
        .lines()
        .next()
        .unwrap()
        .ends_with(",summary"));
    assert!(crate::report::junit(&r).contains("failures=\"2\" errors=\"0\" skipped=\"0\""));
}
