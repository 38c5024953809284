//! A description (`--model-file F`) alone is enough wherever a model is taken: the model
//! id comes from the file, and reports name the description (its file, title and hash).

mod common;

use std::path::{Path, PathBuf};
use std::time::Duration;

use common::{line, run_bounded, words, Run, Scratch};

/// The F510 model under another id and title: a description no built-in model has, so
/// that a command can only know it from the file.
fn acme(dir: &Path) -> PathBuf {
    let mut m: serde_json::Value =
        serde_json::from_str(include_str!("../../vectors/models/f510.json")).unwrap();
    m["model"] = "acme-x100".into();
    m["title"] = "Acme X100 user manual rev C".into();
    let path = dir.join("acme-x100.json");
    std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    path
}

#[test]
fn send_and_fuzz_take_a_description_alone() {
    let d = Scratch::new("send-fuzz");
    let f = acme(&d);
    let f = f.to_str().unwrap();
    let (_sim, port) = common::sim_pty(&["--model", "f510"]);
    let (code, out, err) = Run::words("send --model-file")
        .arg(f)
        .arg("--port")
        .arg(&port)
        .args(["--mode", "rtu", "0103252000018ECC"])
        .timeout(Duration::from_secs(60))
        .run()
        .parts();
    assert_eq!(code, Some(0), "{out}{err}");
    assert!(out.contains("model: "), "{out}");

    let (code, v) = common::report_of(
        "fuzz",
        &d,
        &line(&["--model-file", f, "--port", &port, "--mode rtu --cases 10"]),
        Duration::from_secs(180),
    );
    assert!(matches!(code, Some(0 | 1)), "{v}");
    assert_eq!(v["device"]["model"], "acme-x100", "{}", v["device"]);
    assert_eq!(v["device"]["description"]["file"], f, "{}", v["device"]);
}

#[test]
fn a_second_description_is_refused_where_one_is_taken() {
    let d = Scratch::new("two");
    let f = acme(&d);
    let f = f.to_str().unwrap();
    let (code, out, err) = Run::words("send --model-file")
        .arg(f)
        .arg("--model-file")
        .arg(f)
        .args(["--port", "/dev/null", "0103252000018ECC"])
        .timeout(Duration::from_secs(30))
        .run()
        .parts();
    assert_eq!(code, Some(2), "{out}{err}");
    assert!(
        err.contains("--model-file is given 2 times: this command takes one description"),
        "{err}"
    );
}

#[test]
fn monitor_takes_a_description_alone() {
    let d = Scratch::new("monitor");
    let f = acme(&d);
    let f = f.to_str().unwrap();
    let cap = d.join("check.pcapng");
    let (code, _, err) =
        Run::words("check --sim f510 --mode rtu --only rtu.map.group-0* --quiet --capture")
            .arg(&cap)
            .args(["--format", "json", "-o"])
            .arg(d.join("check.json").to_str().unwrap())
            .timeout(Duration::from_secs(120))
            .run()
            .parts();
    assert_eq!(code, Some(0), "{err}");
    let json = d.join("monitor.json");
    let (code, out, err) = Run::words("monitor --model-file")
        .arg(f)
        .arg("--capture-in")
        .arg(&cap)
        .args([
            "-b", "9600", "-P", "even", "-a", "1", "--format", "json", "-q", "-o",
        ])
        .arg(&json)
        .timeout(Duration::from_secs(60))
        .run()
        .parts();
    assert!(matches!(code, Some(0 | 1)), "{out}{err}");
    let v = common::json_file(&json);
    assert_eq!(v["device"]["model"], "acme-x100", "{}", v["device"]);
    assert_eq!(v["device"]["description"]["file"], f, "{}", v["device"]);
}

/// SHA-256 of `path` by coreutils' sha256sum (a hash this suite did not compute).
fn sha256sum(path: &Path) -> Option<String> {
    let out = std::process::Command::new("sha256sum")
        .arg(path)
        .output()
        .ok()?;
    let text = String::from_utf8(out.stdout).ok()?;
    text.split_whitespace().next().map(str::to_string)
}

#[test]
fn reports_name_the_description_by_file_title_and_hash() {
    let d = Scratch::new("reports");
    let f = acme(&d);
    let Some(hash) = sha256sum(&f) else {
        common::missing("sha256sum (coreutils)");
        return;
    };
    let (_sim, port) = common::sim_pty(&["--model", "f510"]);
    let (code, v) = common::check_device(
        &d,
        &line(&[
            "--model-file",
            f.to_str().unwrap(),
            "--port",
            &port,
            "--mode rtu --only rtu.map.monitor.*",
        ]),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{v}");
    let desc = &v["device"]["description"];
    assert_eq!(desc["file"], f.to_str().unwrap(), "{desc}");
    assert_eq!(desc["title"], "Acme X100 user manual rev C", "{desc}");
    assert_eq!(desc["sha256"], hash.as_str(), "{desc}");
    let json = d.join("check.json");
    let json = json.to_str().unwrap();
    let render = |format: &str| {
        let (code, out, err) = Run::words("report")
            .arg(json)
            .arg("--format")
            .arg(format)
            .timeout(Duration::from_secs(30))
            .run()
            .parts();
        assert_eq!(code, Some(0), "{err}");
        out
    };
    let text = render("text");
    let line = format!(
        "model:   {}, \"Acme X100 user manual rev C\", sha256 {hash}",
        f.display()
    );
    assert!(text.lines().any(|l| l == line), "{line}\n{text}");
    let junit = render("junit");
    assert!(
        junit.contains(&format!(
            "<property name=\"description_sha256\" value=\"{hash}\"/>"
        )),
        "{junit}"
    );
    let html = render("html");
    assert!(
        html.contains(&format!("sha256 {hash}")),
        "no hash in the page"
    );

    // A built-in model: no file, the hash of the model as shipped.
    let builtin = Path::new(env!("CARGO_MANIFEST_DIR")).join("../vectors/models/f510.json");
    let hash = sha256sum(&builtin).unwrap();
    let (code, v) = common::check_device(
        &d,
        &words("--sim f510 --mode rtu --only rtu.map.monitor.*"),
        Duration::from_secs(120),
    );
    assert_eq!(code, Some(0), "{v}");
    let desc = &v["device"]["description"];
    assert!(desc["file"].is_null(), "{desc}");
    assert_eq!(desc["sha256"], hash.as_str(), "{desc}");
    // The text names a built-in model by the suite's version only (the guide's examples).
    assert!(!render("text").contains("\nmodel:   "));
}

/// The built-in model `model`'s file under the id `id`, written to `dir`.
fn renamed(dir: &Path, model: &str, id: &str) -> PathBuf {
    let text = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join(format!("../vectors/models/{model}.json")),
    )
    .unwrap();
    let mut m: serde_json::Value = serde_json::from_str(&text).unwrap();
    m["model"] = id.into();
    let path = dir.join(format!("{id}.json"));
    std::fs::write(&path, serde_json::to_string_pretty(&m).unwrap()).unwrap();
    path
}

/// `identify ARGS --format json -o DIR/identify.json`: exit code, report, stderr.
fn identify(dir: &Path, args: &[&str]) -> (Option<i32>, serde_json::Value, String) {
    let out = dir.join("identify.json");
    let _ = std::fs::remove_file(&out);
    let mut all = vec!["identify", "--format", "json", "--quiet", "-o"];
    all.push(out.to_str().unwrap());
    all.extend(args);
    let (code, _, err) = run_bounded(&all, Duration::from_secs(120));
    let v: serde_json::Value = std::fs::read(&out)
        .ok()
        .and_then(|b| serde_json::from_slice(&b).ok())
        .unwrap_or_default();
    if !v.is_null() {
        let schema = jsonschema::validator_for(
            &serde_json::from_str(include_str!("../../vectors/schema/identify.schema.json"))
                .unwrap(),
        )
        .unwrap();
        if let Err(e) = schema.validate(&v) {
            panic!("the identify report does not match its schema: {e}");
        }
    }
    (code, v, err)
}

#[test]
fn identify_takes_descriptions_as_more_candidates() {
    let d = Scratch::new("identify");
    let a = renamed(&d, "a510", "acme-a");
    let f = renamed(&d, "f510", "acme-f");
    let (a, f) = (a.to_str().unwrap(), f.to_str().unwrap());

    // Beside the five: a description that predicts what a510 predicts ties with it.
    let (code, v, err) = identify(
        &d,
        &line(&["--sim a510 --mode rtu --model-file", a, "--model-file", f]),
    );
    assert_eq!(code, Some(1), "{err}");
    assert_eq!(v["verdict"]["result"], "ambiguous", "{}", v["verdict"]);
    let named: Vec<&str> = v["verdict"]["models"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|m| m.as_str())
        .collect();
    assert_eq!(named, ["a510", "acme-a"], "{}", v["verdict"]);
    let candidates = v["candidates"].as_array().unwrap();
    assert_eq!(candidates.len(), 7, "{candidates:?}");
    assert_eq!(candidates[5]["model"], "acme-a");
    assert_eq!(candidates[5]["file"], a);
    assert!(candidates[0]["file"].is_null());

    // Only the descriptions: the one the device follows is named.
    let (code, v, err) = identify(
        &d,
        &line(&[
            "--sim a510 --mode rtu --model-file",
            a,
            "--model-file",
            f,
            "--only-files",
        ]),
    );
    assert_eq!(code, Some(0), "{err}");
    assert_eq!(v["verdict"]["models"], serde_json::json!(["acme-a"]));
    assert_eq!(v["scores"].as_array().unwrap().len(), 2);

    // A copy that keeps a built-in's id is refused beside the built-in.
    let copy = renamed(&d, "f510", "f510");
    let (code, _, err) = identify(
        &d,
        &line(&["--sim a510 --mode rtu --model-file", copy.to_str().unwrap()]),
    );
    assert_eq!(code, Some(2), "{err}");
    assert!(
        err.contains("describes model \"f510\", as the built-in f510 does"),
        "{err}"
    );
}
