//! The description schema (`vectors/schema/model.schema.json`), held by a full JSON Schema
//! validator to the five built-in models, the example descriptions, and every description
//! and fragment of one in the guide and the READMEs; and `model lint`'s own reading of the
//! schema agrees with the validator on broken files.

use std::path::{Path, PathBuf};

use conformance::model::lint::{self, Severity};
use conformance::model::DriveModel;
use serde_json::Value;

fn repo() -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join("..")
}

fn schema() -> Value {
    serde_json::from_str(lint::MODEL_SCHEMA).unwrap()
}

fn errors(validator: &jsonschema::Validator, v: &Value) -> Vec<String> {
    validator
        .iter_errors(v)
        .map(|e| format!("{}: {e}", e.instance_path))
        .collect()
}

/// The built-in schema is the file in vectors/schema.
#[test]
fn the_built_in_schema_is_the_published_file() {
    let file = std::fs::read_to_string(repo().join("vectors/schema/model.schema.json")).unwrap();
    assert_eq!(file, lint::MODEL_SCHEMA);
}

#[test]
fn the_built_in_models_and_the_examples_match_the_schema() {
    let v = jsonschema::validator_for(&schema()).expect("the schema compiles");
    for (m, text) in DriveModel::builtin_files() {
        let e = errors(&v, &serde_json::from_str(text).unwrap());
        assert!(e.is_empty(), "{m}: {e:#?}");
    }
    let mut examples = 0;
    for f in std::fs::read_dir(repo().join("vectors/models/examples")).unwrap() {
        let p = f.unwrap().path();
        if p.extension().is_some_and(|x| x == "json") {
            let e = errors(
                &v,
                &serde_json::from_str(&std::fs::read_to_string(&p).unwrap()).unwrap(),
            );
            assert!(e.is_empty(), "{}: {e:#?}", p.display());
            examples += 1;
        }
    }
    assert!(examples >= 1);
}

/// Markdown files that may show descriptions: the guide and the READMEs under vectors/.
fn pages() -> Vec<PathBuf> {
    let mut out = vec![repo().join("README.md")];
    for d in ["docs/src", "vectors", "vectors/models"] {
        for f in std::fs::read_dir(repo().join(d)).unwrap() {
            let p = f.unwrap().path();
            if p.extension().is_some_and(|x| x == "md") {
                out.push(p);
            }
        }
    }
    out
}

/// The `json` blocks of a Markdown text, with the line of their fence.
fn json_blocks(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut open: Option<(usize, String)> = None;
    for (i, line) in text.lines().enumerate() {
        let t = line.trim_start();
        match &mut open {
            Some(_) if t.starts_with("```") => out.extend(open.take()),
            Some((_, body)) => {
                body.push_str(line);
                body.push('\n');
            }
            None if t.starts_with("```json") => open = Some((i + 1, String::new())),
            None if t.starts_with("```") => open = Some((usize::MAX, String::new())),
            None => {}
        }
    }
    out.retain(|(l, _)| *l != usize::MAX);
    out
}

#[test]
fn every_description_and_fragment_in_the_docs_matches_the_schema() {
    let s = schema();
    let whole = jsonschema::validator_for(&s).unwrap();
    // A fragment (`"limits": {...}` in a page that builds a description up) is held to
    // the same fields with nothing required.
    let mut loose = s.clone();
    let obj = loose.as_object_mut().unwrap();
    obj.remove("required");
    obj.remove("allOf");
    let fragment = jsonschema::validator_for(&loose).unwrap();
    let (mut descriptions, mut fragments) = (0, 0);
    for page in pages() {
        let text = std::fs::read_to_string(&page).unwrap();
        for (line, body) in json_blocks(&text) {
            let here = format!("{}:{line}", page.display());
            let v: Value = match serde_json::from_str(&body) {
                Ok(v) => v,
                Err(_) => match serde_json::from_str(&format!("{{{body}}}")) {
                    Ok(v) => v,
                    Err(_) => continue,
                },
            };
            let is_description = v.get("schema_version").is_some() && v.get("modes").is_some();
            let looks_like_part = v.as_object().is_some_and(|o| {
                !o.is_empty() && o.keys().all(|k| s["properties"].get(k).is_some())
            });
            if is_description {
                let e = errors(&whole, &v);
                assert!(e.is_empty(), "{here}: {e:#?}");
                descriptions += 1;
            } else if looks_like_part {
                let e = errors(&fragment, &v);
                assert!(e.is_empty(), "{here}: {e:#?}");
                fragments += 1;
            }
        }
    }
    // The guide page alone has the complete example and its fields one by one.
    assert!(
        descriptions >= 1 && fragments >= 8,
        "{descriptions} descriptions, {fragments} fragments"
    );
}

/// Damaged copies of the F510 description: the validator and lint's schema pass find
/// each damage at the same path.
#[test]
fn lint_and_the_validator_agree_on_what_breaks_the_schema() {
    let v = jsonschema::validator_for(&schema()).unwrap();
    let f510: Value = serde_json::from_str(
        &std::fs::read_to_string(repo().join("vectors/models/f510.json")).unwrap(),
    )
    .unwrap();
    type Edit = fn(&mut Value);
    let cases: [(&str, Edit); 7] = [
        ("/limits/read_registers", |v| {
            v["limits"]["read_registers"]["rtu_max"] = 1.into()
        }),
        ("/modes/0", |v| v["modes"][0] = "RTU".into()),
        ("/groups/0/first", |v| {
            v["groups"][0]["first"] = "25000".into()
        }),
        ("/limits/response_time_ms/value", |v| {
            v["limits"]["response_time_ms"]["value"] = (-1).into()
        }),
        ("", |v| {
            v.as_object_mut().unwrap().remove("silence");
        }),
        ("/exceptions", |v| {
            v["exceptions"]["illegal-counts"] = v["exceptions"]["illegal-count"].clone()
        }),
        ("/registers/1/bits/0/role", |v| {
            v["registers"][1]["bits"][0]["role"] = "runs".into()
        }),
    ];
    for (path, edit) in cases {
        let mut broken = f510.clone();
        edit(&mut broken);
        let by_validator: Vec<String> = v
            .iter_errors(&broken)
            .map(|e| e.instance_path.to_string())
            .collect();
        assert!(
            by_validator.contains(&path.to_string()),
            "{path}: {by_validator:?}"
        );
        let findings = lint::lint("f", &serde_json::to_string_pretty(&broken).unwrap());
        assert!(findings.iter().all(|f| f.severity == Severity::Error));
        // Lint names a member it refuses, the validator the object that has it.
        let lint_paths: Vec<String> = findings
            .iter()
            .map(|f| {
                let p = lint::JsonPath::parse(&f.path).unwrap_or_default();
                let mut ptr = String::new();
                for s in &p.0 {
                    match s {
                        lint::Segment::Key(k) => ptr.push_str(&format!("/{k}")),
                        lint::Segment::Index(i) => ptr.push_str(&format!("/{i}")),
                    }
                }
                ptr
            })
            .collect();
        assert!(
            lint_paths
                .iter()
                .any(|p| p == path || p.rsplit_once('/').map(|(a, _)| a) == Some(path)),
            "{path}: lint says {findings:#?}"
        );
    }
}
