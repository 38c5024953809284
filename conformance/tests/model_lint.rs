//! `conformance model lint`: every error of a description with FILE:LINE:COL and the
//! field's path, the exit codes, JSON output, and the same findings from every command
//! that loads a description (`--model-file`).

mod common;
use common::{Ran, Run, Scratch};

use std::path::{Path, PathBuf};

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn run(args: &[&str]) -> Ran {
    Run::new(args).run()
}

/// The F510 description with a misspelt top-level field and a misspelt citation inside a
/// limit (a flattened fact, which serde alone lets through): three errors in all.
fn broken(d: &Path) -> PathBuf {
    let f510 = std::fs::read_to_string(repo().join("vectors/models/f510.json")).unwrap();
    let t = f510
        .replacen("\"exception_codes_source\"", "\"exception_code_source\"", 1)
        .replacen(
            "\"read_registers\": {",
            "\"read_registers\": {\"sorce\": \"x\", ",
            1,
        );
    assert_ne!(t, f510);
    let p = d.join("broken.json");
    std::fs::write(&p, t).unwrap();
    p
}

/// The line and column of the first `needle` in `file`, as lint counts them.
fn place(file: &Path, needle: &str) -> String {
    let t = std::fs::read_to_string(file).unwrap();
    let at = t.find(needle).unwrap();
    let before = &t[..at];
    let line = before.matches('\n').count() + 1;
    let col = before.rsplit('\n').next().unwrap().chars().count() + 1;
    format!("{}:{line}:{col}", file.display())
}

#[test]
fn lint_prints_every_error_with_its_place_and_path_and_exits_1() {
    let d = Scratch::new("every");
    let f = broken(&d);
    let o = run(&["model", "lint", f.to_str().unwrap()]);
    assert_eq!(o.code, Some(1), "{}", o.stderr);
    let out = o.stdout.clone();
    let want = [
        format!(
            "{}:1:1: error: (top level): missing field `exception_codes_source`",
            f.display()
        ),
        format!(
            "{}: error: exception_code_source: unknown field `exception_code_source`; did you mean `exception_codes_source`?",
            place(&f, "\"exception_code_source\"")
        ),
        format!(
            "{}: error: limits.read_registers.sorce: unknown field `sorce`; did you mean `source`?",
            place(&f, "\"sorce\"")
        ),
        "failed: 3 errors, 0 warnings in 1 file".to_string(),
    ];
    assert_eq!(out.lines().collect::<Vec<_>>(), want, "{out}");
}

#[test]
fn the_built_in_models_lint_clean_and_an_unreadable_file_exits_2() {
    let mut args = vec!["model".to_string(), "lint".to_string()];
    for m in ["f510", "a510", "l510", "e510", "l510-legacy"] {
        args.push(
            repo()
                .join(format!("vectors/models/{m}.json"))
                .display()
                .to_string(),
        );
    }
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let o = run(&args);
    assert_eq!(o.code, Some(0), "{}", o.stdout);
    assert_eq!(o.stdout.clone(), "ok: 0 errors, 0 warnings in 5 files\n");

    let d = Scratch::new("unreadable");
    let missing = d.join("missing.json");
    let f = broken(&d);
    let o = run(&[
        "model",
        "lint",
        missing.to_str().unwrap(),
        f.to_str().unwrap(),
    ]);
    assert_eq!(o.code, Some(2));
    let out = o.stdout.clone();
    assert!(
        out.starts_with(&format!("{}: error: cannot read: ", missing.display())),
        "{out}"
    );
    // The readable file is still linted.
    assert!(
        out.ends_with("failed: 3 errors, 0 warnings in 2 files\n"),
        "{out}"
    );
}

#[test]
fn json_output_has_every_finding() {
    let d = Scratch::new("json");
    let f = broken(&d);
    let o = run(&["model", "lint", "--format", "json", f.to_str().unwrap()]);
    assert_eq!(o.code, Some(1));
    let v: serde_json::Value = serde_json::from_slice(&o.bytes).unwrap();
    assert_eq!(v["errors"], 3);
    assert_eq!(v["warnings"], 0);
    let findings = v["files"][0]["findings"].as_array().unwrap();
    let paths: Vec<&str> = findings
        .iter()
        .map(|f| f["path"].as_str().unwrap())
        .collect();
    assert_eq!(
        paths,
        [
            "(top level)",
            "exception_code_source",
            "limits.read_registers.sorce"
        ]
    );
    assert!(findings
        .iter()
        .all(|f| f["severity"] == "error" && f["line"].as_u64().unwrap() >= 1));
}

#[test]
fn every_command_that_loads_a_description_lints_it_first() {
    let d = Scratch::new("load");
    let f = broken(&d);
    let fs = f.to_str().unwrap();
    let lint = run(&["model", "lint", fs]).stdout;
    let findings: Vec<&str> = lint.lines().filter(|l| l.contains(": error: ")).collect();
    assert_eq!(findings.len(), 3);
    let on_no_port = |command: &'static str| {
        vec![
            command,
            "--model",
            "f510",
            "--model-file",
            fs,
            "--port",
            "/dev/null",
        ]
    };
    for args in [
        vec!["model", "show", "--model-file", fs],
        vec!["model", "--model-file", fs],
        on_no_port("check"),
        on_no_port("fuzz"),
        on_no_port("monitor"),
    ] {
        let o = run(&args);
        let err = o.stderr.clone();
        assert_eq!(o.code, Some(2), "{args:?}: {err}");
        assert!(
            err.starts_with(&format!(
                "error: {fs}: 3 errors, 0 warnings in the description\n"
            )),
            "{args:?}: {err}"
        );
        for l in &findings {
            assert!(err.contains(l), "{args:?} does not say {l}: {err}");
        }
    }
}

#[test]
fn model_show_is_what_model_printed_before() {
    let old = run(&["model", "e510", "--decisions"]);
    let new = run(&["model", "show", "e510", "--decisions"]);
    assert!(old.code == Some(0) && new.code == Some(0));
    assert_eq!(old.stdout.clone(), new.stdout.clone());
    assert!(old.stdout.clone().starts_with("e510 — "));
}

/// The F510 example register left in a copied description (issue 34, item 3): inside a
/// block of the same access it is a warning, which fails only with --deny-warnings.
#[test]
fn a_warning_fails_only_with_deny_warnings() {
    let d = Scratch::new("warn");
    let acme =
        std::fs::read_to_string(repo().join("vectors/models/examples/acme-x100.json")).unwrap();
    let with_example = acme.replacen(
        "\"blocks\": [",
        "\"example_registers\": [{\"register\": \"0123\", \"initial\": \"1770\", \"access\": \"read-write\", \"basis\": \"decision\", \"why\": \"copied\"}],\n  \"blocks\": [",
        1,
    );
    assert_ne!(with_example, acme);
    let f = d.join("x.json");
    std::fs::write(&f, with_example).unwrap();
    let fs = f.to_str().unwrap();
    let o = run(&["model", "lint", fs]);
    let out = o.stdout.clone();
    assert_eq!(o.code, Some(0), "{out}");
    assert!(
        out.contains(": warning: example_registers[0]: example register 0123H is inside blocks[0]"),
        "{out}"
    );
    assert!(
        out.ends_with("ok: 0 errors, 1 warning in 1 file\n"),
        "{out}"
    );
    let o = run(&["model", "lint", "--deny-warnings", fs]);
    assert_eq!(o.code, Some(1));
}
