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

/// The first consistent frame vector of the first document, to be spoilt.
fn a_consistent_frame(set: &mut VectorSet) -> &mut vectors::model::Vector {
    let frames = set.files[0].vectors.iter_mut();
    frames
        .filter(|v| matches!(v.body, Body::Frame(_)))
        .find(|v| v.verdict == Verdict::Consistent)
        .expect("a consistent frame")
}

#[test]
fn a_wrong_flag_is_caught() {
    // Declaring a fault the frame does not have must fail verification.
    let mut set = set();
    let v = a_consistent_frame(&mut set);
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
    let v = a_consistent_frame(&mut set);
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
        out.push_str(&vectors::render_in(&set, v));
    }
    insta::assert_snapshot!("all_vectors", out);
}

fn verify_one(set: &VectorSet, id: &str) -> vectors::VectorReport {
    let v = set.get(id).unwrap().clone();
    vectors::verify_vector(set, &v)
}

fn body_mut<'a>(set: &'a mut VectorSet, id: &str) -> &'a mut Body {
    &mut set
        .files
        .iter_mut()
        .flat_map(|f| f.vectors.iter_mut())
        .find(|v| v.id == id)
        .unwrap()
        .body
}

/// The report of vector `id` in the vector set changed by `edit`.
fn verified_after(id: &str, edit: impl FnOnce(&mut VectorSet)) -> vectors::VectorReport {
    let mut s = set();
    edit(&mut s);
    verify_one(&s, id)
}

/// Whether one of the report's problems says `text`.
fn says(r: &vectors::VectorReport, text: &str) -> bool {
    r.problems.iter().any(|p| p.contains(text))
}

fn listing<'a>(set: &'a mut VectorSet, id: &str) -> &'a mut vectors::model::CListing {
    let Body::CListing(l) = body_mut(set, id) else {
        panic!("{id} is no C listing")
    };
    l
}

fn rule<'a>(set: &'a mut VectorSet, id: &str) -> &'a mut vectors::model::ExceptionRule {
    let Body::ExceptionRule(r) = body_mut(set, id) else {
        panic!("{id} is no exception rule")
    };
    r
}

#[test]
fn a_listing_corrected_beyond_its_repairs_is_caught() {
    for id in ["f510.crc-listing", "e510.crc-listing"] {
        assert!(verify_one(&set(), id).passed(), "{id}");
        // One more change in `corrected` than the repairs record.
        let r = verified_after(id, |s| {
            let l = listing(s, id);
            l.corrected = l.corrected.replace("0xa001", "0xA001");
        });
        assert!(says(&r, "recorded repairs"), "{id}: {:?}", r.problems);
        // A repair whose count is wrong.
        let r = verified_after(id, |s| listing(s, id).repairs[0].count = 1);
        assert!(!r.passed(), "{id}");
        // The printed text corrected in place: the repairs no longer apply.
        let r = verified_after(id, |s| {
            let l = listing(s, id);
            l.printed = l.printed.replace("rxdbuff++", "*rxdbuff++");
        });
        assert!(!r.passed(), "{id}");
    }
    // The E510's OCR repairs need their flag.
    let id = "e510.crc-listing";
    let r = verified_after(id, |s| {
        let v = s.files[3].vectors.iter_mut().find(|v| v.id == id).unwrap();
        v.flags.retain(|f| f != "ocr-repair");
    });
    assert!(!r.passed());
}

#[test]
fn the_exception_rule_is_checked_against_its_frames() {
    let id = "f510.exception-rule";
    let r = verify_one(&set(), id);
    assert!(r.passed(), "{:?}", r.problems);
    assert_eq!(r.observed, ["prose-contradicts-examples"]);
    // Were the sentence an OR, it would not contradict the examples: the flag is then wrong.
    let r = verified_after(id, |s| {
        rule(s, id).stated_operation = conformance::vectors::model::BitOperation::Or;
    });
    let flag = "declares prose-contradicts-examples";
    assert!(says(&r, flag), "{:?}", r.problems);
    // An evidence frame that carries what the AND reading gives (00H) is caught.
    let frame = "f510.06.rtu.exception";
    let r = verified_after(id, |s| {
        let Body::Frame(f) = body_mut(s, frame) else {
            panic!("{frame} is no frame")
        };
        f.printed = "01 06 52 C3 9D".into();
    });
    assert!(says(&r, frame), "{:?}", r.problems);
    // Evidence must be complete and must exist.
    let r = verified_after(id, |s| {
        let evidence = &mut rule(s, id).evidence;
        evidence.pop();
        evidence.push("f510.03.rtu.response".into());
    });
    assert!(r.problems.len() >= 2, "{:?}", r.problems);
}

#[test]
fn the_new_vectors_are_found_by_flag() {
    let set = set();
    for flag in ["code-does-not-compile", "prose-contradicts-examples"] {
        assert!(set.flags.flags.contains_key(flag), "{flag} is explained");
        let n = set
            .iter()
            .filter(|(_, v)| v.flags.iter().any(|f| f == flag))
            .count();
        assert_eq!(n, DOCUMENTS.len(), "{flag}");
    }
}
