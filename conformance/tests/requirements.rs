//! The requirements catalogue (vectors/requirements/): every quote is in its manual at its
//! line, every link names something that exists, every check verifies a requirement, and
//! the reports name the requirements each check verifies.

mod common;
use common::{Run, Scratch};

use std::collections::BTreeSet;
use std::path::PathBuf;

use std::time::Duration;

use conformance::requirements::trace::{self, Coverage, Universe};
use conformance::requirements::{quote_is_at, Catalogue};

fn catalogues() -> Vec<Catalogue> {
    Catalogue::builtin().expect("the built-in requirements files load")
}

fn seeds() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../shared/seeds")
}

#[test]
fn every_file_matches_its_schema_and_names_its_document() {
    let schema = jsonschema::validator_for(
        &serde_json::from_str(include_str!(
            "../../vectors/schema/requirements.schema.json"
        ))
        .unwrap(),
    )
    .unwrap();
    for (doc, text) in Catalogue::builtin_texts() {
        let v: serde_json::Value = serde_json::from_str(text).unwrap();
        let errors: Vec<String> = schema.iter_errors(&v).map(|e| e.to_string()).collect();
        assert!(errors.is_empty(), "{doc}: {errors:?}");
        assert_eq!(v["document"], *doc);
    }
}

#[test]
fn every_manual_has_its_requirements() {
    let cats = catalogues();
    assert_eq!(
        cats.iter().map(|c| c.document.as_str()).collect::<Vec<_>>(),
        conformance::model::MODELS
    );
    for c in &cats {
        let n = c.current().count();
        assert!(n >= 40, "{}: only {n} requirements", c.document);
        // Each kind of statement the issue lists is there.
        let kinds: BTreeSet<&str> = c.current().map(|r| r.kind.as_str()).collect();
        for k in [
            "framing",
            "function",
            "exception",
            "register-map",
            "loop-back",
        ] {
            assert!(
                kinds.contains(k),
                "{}: no requirement of kind {k}",
                c.document
            );
        }
        // Ids in the manual's order of lines are numbered in order (stable ids are
        // appended, never renumbered, so only a strictly increasing sequence is asked).
        let ids: Vec<&str> = c.requirements.iter().map(|r| r.id.as_str()).collect();
        let mut sorted = ids.clone();
        sorted.sort();
        assert_eq!(ids, sorted, "{}: ids out of order", c.document);
    }
}

#[test]
fn every_quote_is_in_its_manual_at_its_line() {
    let dir = seeds();
    if !common::tool_or_skip(
        dir.is_dir(),
        &format!(
            "the manuals in {} (../shared/seeds beside the project)",
            dir.display()
        ),
    ) {
        return;
    }
    let mut wrong = Vec::new();
    let mut checked = 0;
    for c in catalogues() {
        let text = std::fs::read(dir.join(&c.source))
            .unwrap_or_else(|e| panic!("{}: cannot read {}: {e}", c.document, c.source));
        let text = String::from_utf8_lossy(&text);
        for r in &c.requirements {
            checked += 1;
            if let Err(e) = quote_is_at(&text, r.line, &r.quote) {
                wrong.push(format!("{}: {e}", r.id));
            }
        }
    }
    assert!(checked > 200, "{checked}");
    assert!(
        wrong.is_empty(),
        "{} quotes wrong:\n{}",
        wrong.len(),
        wrong.join("\n")
    );
}

#[test]
fn every_link_names_something_and_every_check_verifies_a_requirement() {
    let cats = catalogues();
    let mut problems = Vec::new();
    for c in &cats {
        let u = Universe::of(c, &cats).unwrap();
        for p in trace::problems(c, &u) {
            problems.push(format!("{}: {}: {}", c.document, p.id, p.text));
        }
    }
    assert!(problems.is_empty(), "{}", problems.join("\n"));
}

#[test]
fn contradictions_link_both_ways() {
    let cats = catalogues();
    let mut links = BTreeSet::new();
    for c in &cats {
        for r in c.current() {
            for x in &r.conflicts {
                links.insert((r.id.clone(), x.with.clone()));
            }
        }
    }
    let one_way: Vec<_> = links
        .iter()
        .filter(|(a, b)| !links.contains(&(b.clone(), a.clone())))
        .collect();
    assert!(one_way.is_empty(), "{one_way:?}");
}

#[test]
fn a_requirement_without_a_check_says_why() {
    for c in catalogues() {
        for r in c.current() {
            if trace::coverage(r) != Coverage::Check {
                let why = r.reason.as_deref().unwrap_or("");
                assert!(
                    why.len() > 10,
                    "{}: no reason worth the name: {why:?}",
                    r.id
                );
            }
        }
    }
}

fn conformance(args: &[&str]) -> (i32, String, String) {
    let o = Run::new(args).run();
    (o.code.unwrap_or(-1), o.stdout.clone(), o.stderr.clone())
}

#[test]
fn the_command_prints_the_coverage_of_all_five_manuals() {
    let (code, out, err) = conformance(&["requirements", "--verify"]);
    assert_eq!(code, 0, "{out}{err}");
    for doc in conformance::model::MODELS {
        let line = out
            .lines()
            .find(|l| l.starts_with(&format!("{doc}: ")))
            .unwrap_or_else(|| panic!("no coverage line for {doc}:\n{out}"));
        assert!(line.contains("verified by a check"), "{line}");
    }
    assert!(out.contains("every check verifies a requirement"), "{out}");

    let (code, json, _) = conformance(&["requirements", "--format", "json"]);
    assert_eq!(code, 0);
    let v: serde_json::Value = serde_json::from_str(&json).unwrap();
    let docs = v["documents"].as_array().unwrap();
    assert_eq!(docs.len(), 5);
    let mut total = 0;
    for d in docs {
        let n = d["total"].as_u64().unwrap();
        let sum = common::total(&d["coverage"]);
        assert_eq!(n, sum, "{}", d["document"]);
        assert_eq!(d["requirements"].as_array().unwrap().len() as u64, n);
        total += n;
    }
    let (_, csv, _) = conformance(&["requirements", "--format", "csv"]);
    assert_eq!(
        csv.lines().count() as u64,
        total + 1,
        "one row per requirement"
    );

    let (code, _, err) = conformance(&["requirements", "--doc", "f999"]);
    assert_eq!(code, 2);
    assert!(err.contains("no document 'f999'"), "{err}");

    let (code, matrix, _) = conformance(&["requirements", "--doc", "f510", "--matrix"]);
    assert_eq!(code, 0);
    assert!(matrix.contains("f510.REQ-001"), "{matrix}");
    assert!(!matrix.contains("a510.REQ-001"), "{matrix}");
}

#[test]
fn reports_name_the_requirements_each_check_verifies() {
    let args = "--sim f510 --only rtu.map.monitor.* --read-only";
    let (dir, code, v) = common::check_in("names", args, Duration::from_secs(120));
    assert_eq!(code, Some(0));
    let checks = v["checks"].as_array().unwrap();
    assert!(!checks.is_empty());
    // The preflight is the run's, not a check of the model's plan.
    let checks: Vec<&serde_json::Value> = checks
        .iter()
        .filter(|c| !c["id"].as_str().unwrap().ends_with(".preflight"))
        .collect();
    for c in &checks {
        let reqs = c["requirements"]
            .as_array()
            .unwrap_or_else(|| panic!("{} names no requirement", c["id"]));
        assert!(reqs
            .iter()
            .all(|r| r.as_str().unwrap().starts_with("f510.REQ-")));
    }
    let json = dir.join("check.json");
    let html = common::rendered(&json, &dir.join("check.html"));
    let xml = common::rendered(&json, &dir.join("check.xml"));
    let first = checks[0]["requirements"][0].as_str().unwrap();
    assert!(
        xml.contains(&format!(
            "<property name=\"requirement\" value=\"{first}\"/>"
        )),
        "{xml}"
    );
    assert!(html.contains(&format!("href=\"#req-{first}\"")));
    assert!(html.contains(&format!("<tr id=\"req-{first}\">")));
    assert!(html.contains("id=\"coverage\""));
}

/// The requirements coverage section of the HTML report (`conformance report`) of a
/// `check` run with `args`, which must exit 0.
fn coverage_section(tag: &str, args: &[&str]) -> String {
    let dir = Scratch::new(tag);
    let (code, report) = common::check_device(&dir, args, Duration::from_secs(120));
    assert_eq!(code, Some(0), "{:#}", report["summary"]);
    let html = common::rendered(&dir.join("check.json"), &dir.join("check.html"));
    let at = html.find("id=\"coverage\"").unwrap();
    let end = html[at..].find("id=\"all\"").unwrap() + at;
    html[at..end].to_string()
}

#[test]
fn the_coverage_section_says_what_a_read_only_run_skipped() {
    let section = coverage_section(
        "read-only",
        &["--sim", "f510", "--only", "rtu.write.*", "--read-only"],
    );
    common::assert_contains_all(
        &section,
        &[">skipped</span>", "read-only", ">not selected</span>"],
    );
    assert!(!section.contains(">verified</span>"), "{section}");
}

/// A run of one mode says of the other mode's requirements that this run did not speak
/// it, not that they were not selected.
#[test]
fn the_coverage_section_names_the_mode_a_run_did_not_speak() {
    let section = coverage_section(
        "rtu-only",
        &[
            "--sim",
            "f510",
            "--mode",
            "rtu",
            "--only",
            "rtu.map.group-0.*",
        ],
    );
    common::assert_contains_all(
        &section,
        &[
            ">other mode</span>",
            "its checks are ASCII's; this run did not speak ASCII",
        ],
    );
    assert!(!section.contains("this run did not speak RTU"), "{section}");
    assert!(section.contains(">verified</span>"), "{section}");
    // The count in the sentence is the rows'.
    let rows = section.matches(">other mode</span>").count();
    assert!(
        section.contains(&format!("<b>{rows}</b> of a mode this run did not speak")),
        "{section}"
    );
}
