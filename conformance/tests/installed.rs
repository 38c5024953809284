//! The binary as a user who installed a package has it: a copy outside the build tree, run
//! from a folder outside the checkout. Everything it needs at run time (the models, the
//! vectors, the requirements, the description schema) must be inside it.

mod common;

use common::installed::Installed;

#[test]
fn check_against_the_simulator_runs_from_outside_the_checkout() {
    let i = Installed::new("check");
    let (code, out, err) = i.run(&["check", "--sim", "f510", "--mode", "rtu", "--no-pace"]);
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(out.contains("PASSED ("), "{out}");
    // Nothing was written beside the user's working folder but what was asked for.
    assert_eq!(std::fs::read_dir(&i.cwd).unwrap().count(), 0);
}

#[test]
fn vectors_requirements_and_models_come_from_inside_the_binary() {
    let i = Installed::new("data");
    let (code, out, err) = i.run(&["vectors", "verify"]);
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(out.contains(" 0 do not; 0 required items missing"), "{out}");

    let (code, out, err) = i.run(&["requirements"]);
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(out.contains("f510"), "{out}");

    for model in ["f510", "a510", "l510", "e510", "l510-legacy"] {
        let (code, out, err) = i.run(&["model", "show", model]);
        assert_eq!(code, Some(0), "{model}: {out}{err}");
        assert!(out.starts_with(model), "{model}: {out}");
    }
}

#[test]
fn model_lint_holds_a_description_to_the_schema_inside_the_binary() {
    let i = Installed::new("lint");
    std::fs::write(
        i.cwd.join("good.json"),
        include_str!("../../vectors/models/examples/acme-x100.json"),
    )
    .unwrap();
    let (code, out, err) = i.run(&["model", "lint", "good.json"]);
    assert_eq!(code, Some(0), "{out}{err}");
    // A field the schema does not know is an error that only the schema can give.
    std::fs::write(
        i.cwd.join("bad.json"),
        "{\"schema_version\": 2, \"nonsense\": 1}",
    )
    .unwrap();
    let (code, out, err) = i.run(&["model", "lint", "bad.json"]);
    assert_eq!(code, Some(1), "{out}{err}");
    assert!(out.contains("bad.json:1:"), "{out}");
}

#[test]
fn version_says_the_commit_and_the_crc_path_the_dispatcher_chose() {
    let i = Installed::new("version");
    let (code, out, err) = i.run(&["--version"]);
    assert_eq!(code, Some(0), "{out}{err}");
    let lines: Vec<&str> = out.lines().collect();
    assert_eq!(
        lines.first().copied(),
        Some(concat!("conformance ", env!("CARGO_PKG_VERSION"))),
        "{out}"
    );
    let commit = lines
        .iter()
        .find_map(|l| l.strip_prefix("commit: "))
        .unwrap_or_else(|| panic!("no commit line: {out}"));
    // Built from this checkout, it is the checkout's HEAD (and not a blank).
    match std::process::Command::new("git")
        .args(["rev-parse", "HEAD"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
    {
        Ok(o) if o.status.success() && std::env::var_os("CONFORMANCE_BUILD_COMMIT").is_none() => {
            assert_eq!(commit, String::from_utf8_lossy(&o.stdout).trim(), "{out}")
        }
        _ => assert!(commit.len() > 6, "{out}"),
    }
    // The path the codec's dispatcher takes in this process is the one the binary names.
    let tier = conformance::codec::crc::crc16_tier().name();
    assert!(
        out.contains(&format!(
            "\ncrc: {tier} path for long inputs (this CPU runs: table"
        )),
        "{out}"
    );
    // Capped to the table, it says so.
    let o = Installed::output(
        i.command(&["--version"])
            .env("CONFORMANCE_CRC_PATH", "table"),
    );
    let out = String::from_utf8_lossy(&o.stdout);
    common::assert_contains_all(
        &out,
        &[
            "\ncrc: table path for long inputs",
            "capped by CONFORMANCE_CRC_PATH=table",
        ],
    );
    // -V is the one line a script reads.
    let (_, short, _) = i.run(&["-V"]);
    assert_eq!(short.trim(), lines[0]);
}
