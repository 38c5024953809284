//! The golden vectors, checked by the codec: every vector behaves as its verdict says, no
//! document lacks an item, the export validates against its schema, and the rendering of
//! every vector is held in a snapshot.

use conformance::vectors::{self, export::export_json, Body, VectorSet, Verdict, DOCUMENTS};

fn set() -> VectorSet {
    VectorSet::builtin().expect("built-in vectors load")
}

#[test]
fn every_vector_behaves_as_its_verdict_says() {
    let set = set();
    let failures: Vec<String> = vectors::verify_all(&set)
        .into_iter()
        .filter(|r| !r.passed())
        .map(|r| format!("{}: {}", r.id, r.problems.join("; ")))
        .collect();
    assert!(
        failures.is_empty(),
        "{} vectors fail:\n{}",
        failures.len(),
        failures.join("\n")
    );
}

#[test]
fn every_document_is_complete() {
    let set = set();
    let missing = vectors::missing(&set);
    assert!(missing.is_empty(), "missing items: {missing:?}");
    for d in DOCUMENTS {
        let file = set.file(d).unwrap();
        let frames = file
            .vectors
            .iter()
            .filter(|v| matches!(v.body, Body::Frame(_)))
            .count();
        assert!(frames >= 26, "{d}: {frames} frame vectors");
        assert!(
            file.vectors.len() >= 31,
            "{d}: {} vectors",
            file.vectors.len()
        );
    }
}

#[test]
fn directory_and_builtin_copies_agree() {
    let dir = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("../vectors");
    let from_dir = VectorSet::load_dir(&dir).unwrap();
    assert_eq!(from_dir.files, set().files);
}

#[test]
fn errata_are_flagged_and_corrected() {
    for (_, v) in set().iter() {
        match v.verdict {
            Verdict::Consistent => {
                assert!(v.flags.is_empty() || v.flags == ["ocr-repair"], "{}", v.id)
            }
            Verdict::Erratum | Verdict::Incomplete => {
                assert!(!v.flags.is_empty(), "{} has no flags", v.id);
                if let Body::Frame(f) = &v.body {
                    assert!(f.corrected.is_some(), "{} has no corrected frame", v.id);
                }
            }
        }
    }
}

#[test]
fn a_wrong_flag_is_caught() {
    // Declaring a fault the frame does not have must fail verification.
    let mut set = set();
    let v = set.files[0]
        .vectors
        .iter_mut()
        .find(|v| v.verdict == Verdict::Consistent && matches!(v.body, Body::Frame(_)))
        .unwrap();
    v.verdict = Verdict::Erratum;
    v.flags = vec!["crc-mismatch".into()];
    v.notes = "deliberately wrong".into();
    let id = v.id.clone();
    let v = set.get(&id).unwrap().clone();
    let report = vectors::verify_vector(&set, &v);
    assert!(!report.passed());
}

#[test]
fn a_changed_byte_is_caught() {
    let mut set = set();
    let v = set.files[0]
        .vectors
        .iter_mut()
        .find(|v| v.verdict == Verdict::Consistent && matches!(v.body, Body::Frame(_)))
        .unwrap();
    if let Body::Frame(f) = &mut v.body {
        let last = f.printed.len() - 1;
        let flipped = if &f.printed[last..] == "0" { "1" } else { "0" };
        f.printed.replace_range(last.., flipped);
        if let Some(t) = &mut f.text {
            // Keep the text in step so only the checksum check can catch it.
            *t = f
                .printed
                .split(' ')
                .map(|h| u8::from_str_radix(h, 16).unwrap() as char)
                .collect();
        }
    }
    let id = v.id.clone();
    let v = set.get(&id).unwrap().clone();
    assert!(!vectors::verify_vector(&set, &v).passed(), "{id}");
}

#[test]
fn export_validates_against_schema() {
    let schema_path = std::path::Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("../vectors/schema/export.schema.json");
    let schema: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(schema_path).unwrap()).unwrap();
    let validator = jsonschema::validator_for(&schema).expect("schema compiles");
    let doc = export_json(&set());
    let errors: Vec<String> = validator
        .iter_errors(&doc)
        .map(|e| format!("{} at {}", e, e.instance_path))
        .collect();
    assert!(
        errors.is_empty(),
        "export does not validate:\n{}",
        errors.join("\n")
    );
    // And the schema is not vacuous: a broken document fails.
    let mut broken = doc.clone();
    broken["documents"][0]["vectors"][0]["verdict"] = "fine".into();
    assert!(!validator.is_valid(&broken));
}

#[test]
fn rendering_snapshot() {
    let set = set();
    let mut out = String::new();
    for (_, v) in set.iter() {
        out.push_str(&vectors::render(v));
    }
    insta::assert_snapshot!("all_vectors", out);
}
