use super::*;

fn f510() -> &'static str {
    DriveModel::builtin_files()
        .iter()
        .find(|(m, _)| *m == "f510")
        .map(|(_, t)| *t)
        .unwrap()
}

/// The F510 file with `edit` applied to its parsed value, pretty-printed again.
fn edited(edit: impl FnOnce(&mut Value)) -> String {
    let mut v: Value = serde_json::from_str(f510()).unwrap();
    edit(&mut v);
    serde_json::to_string_pretty(&v).unwrap()
}

/// A small schema_version 2 description: the semantic lints run on it whatever the
/// loader of this branch says about version 2.
fn v2(extra: &str) -> String {
    format!(
        r#"{{
  "schema_version": 2,
  "model": "t",
  "title": "test",
  "modes": ["rtu"],
  "functions": {{"codes": ["03"], "basis": "documented", "source": "s"}},
  "exception_codes": [{{"code": "02", "meaning": "Illegal data address"}}]{extra}
}}"#
    )
}

/// Each `(path, message)`: the finding at the path says the message.
fn assert_messages(f: &[Finding], expected: &[(&str, &str)]) {
    for (path, message) in expected {
        assert_eq!(find(f, path).message, *message, "at {path}");
    }
}

fn find<'a>(f: &'a [Finding], path: &str) -> &'a Finding {
    f.iter()
        .find(|x| x.path == path)
        .unwrap_or_else(|| panic!("no finding at {path}: {f:#?}"))
}

#[test]
fn the_built_in_models_lint_clean() {
    for (m, text) in DriveModel::builtin_files() {
        let f = lint(m, text);
        assert!(f.is_empty(), "{m}: {f:#?}");
    }
}

#[test]
fn a_syntax_error_gives_serde_jsons_line_and_column() {
    let f = lint("x.json", "{\n  \"model\": \"a\",\n  \"title\" \"b\"\n}");
    assert_eq!(f.len(), 1, "{f:#?}");
    assert_eq!((f[0].line, f[0].column), (3, 11));
    assert!(
        f[0].message.starts_with("not JSON: expected `:`"),
        "{}",
        f[0].message
    );
    assert!(f[0]
        .to_string()
        .starts_with("x.json:3:11: error: (top level): not JSON"));
}

#[test]
fn an_unknown_field_is_placed_and_gets_a_did_you_mean() {
    let text = f510().replacen("\"exception_codes_source\"", "\"exception_code_source\"", 1);
    let f = lint("f510.json", &text);
    let x = find(&f, "exception_code_source");
    assert_eq!(
        x.message,
        "unknown field `exception_code_source`; did you mean `exception_codes_source`?"
    );
    let offset = text.find("\"exception_code_source\"").unwrap();
    assert_eq!((x.line, x.column), span::line_col(&text, offset));
    // The real one is now missing, and says so at the top level.
    assert!(f
        .iter()
        .any(|x| x.path == "(top level)" && x.message == "missing field `exception_codes_source`"));
}

#[test]
fn unknown_fields_inside_flattened_facts_are_found_too() {
    // serde's flatten cannot deny unknown fields: only the schema pass sees this one.
    let text = edited(|v| v["limits"]["read_registers"]["sorce"] = "x".into());
    let f = lint("f", &text);
    assert_eq!(
        find(&f, "limits.read_registers.sorce").message,
        "unknown field `sorce`; did you mean `source`?"
    );
}

#[test]
fn wrong_types_and_spellings_say_what_was_expected() {
    let text = edited(|v| {
        v["limits"]["response_time_ms"]["value"] = "10".into();
        v["groups"][1]["first"] = "2520h".into();
        v["modes"] = serde_json::json!(["rtu", "RTU"]);
    });
    let f = lint("f", &text);
    assert_messages(
        &f,
        &[
            (
                "limits.response_time_ms.value",
                "expected an integer, found a string \"10\"",
            ),
            (
                "groups[1].first",
                "expected four upper-case hex digits, found \"2520h\"",
            ),
            (
                "modes[1]",
                "expected one of \"rtu\", \"ascii\", found \"RTU\"; did you mean \"rtu\"?",
            ),
        ],
    );
    assert!(f.iter().all(|x| x.severity == Severity::Error));
}

#[test]
fn the_loaders_error_is_placed_by_its_path() {
    let text = edited(|v| v["addresses"]["first"] = "00".into());
    let f = lint("f", &text);
    assert_eq!(f.len(), 1, "{f:#?}");
    assert_eq!(f[0].path, "addresses");
    assert!(
        f[0].message.contains("01 <= first <= last"),
        "{}",
        f[0].message
    );
    let offset = text.find("\"addresses\"").unwrap();
    assert_eq!((f[0].line, f[0].column), span::line_col(&text, offset));
}

#[test]
fn a_loader_error_about_a_register_points_at_its_entry() {
    let (p, m) = loader_path(f510(), "register 2501: unknown role \"x\"");
    assert_eq!(p.to_string(), "registers[1]");
    assert_eq!(m, "register 2501: unknown role \"x\"");
    let (p, _) = loader_path(f510(), "no colon here");
    assert_eq!(p, JsonPath::default());
}

#[test]
fn limits_beyond_the_specification_are_errors() {
    let text = edited(|v| {
        v["limits"]["read_registers"]["rtu"] = 126.into();
        v["limits"]["write_registers"]["ascii"] = 124.into();
        v["limits"]["max_frame_bytes"]["value"] = 257.into();
    });
    let f = lint("f", &text);
    assert!(find(&f, "limits.read_registers.rtu")
        .message
        .starts_with("126 is beyond the specification's 125"));
    assert!(find(&f, "limits.write_registers.ascii")
        .message
        .starts_with("124 is beyond the specification's 123"));
    assert!(find(&f, "limits.max_frame_bytes.value")
        .message
        .contains("256-byte RTU frame"));
    // At the limits themselves, nothing of this kind.
    let text = edited(|v| {
        v["limits"]["read_registers"]["rtu"] = 125.into();
        v["limits"]["max_frame_bytes"]["value"] = 256.into();
    });
    assert!(lint("f", &text)
        .iter()
        .all(|x| !x.message.contains("specification")));
}

#[test]
fn an_exception_code_not_in_the_table_is_named() {
    let text = edited(|v| v["exceptions"]["illegal-count"]["code"] = "0B".into());
    let f = lint("f", &text);
    assert_eq!(f.len(), 1, "{f:#?}");
    assert_eq!(f[0].path, "exceptions.illegal-count.code");
    assert_eq!(
        f[0].message,
        "code 0B is not in the exception-code table (exception_codes has 01, 02, 03, 04)"
    );
}

#[test]
fn overlapping_blocks_are_errors() {
    let text = v2(r#",
  "blocks": [
    {"first": "0000", "last": "0FFF", "basis": "documented", "source": "s"},
    {"first": "0F00", "last": "10FF", "basis": "documented", "source": "s"}
  ]"#);
    let f = lint("t.json", &text);
    let x = find(&f, "blocks[1]");
    assert_eq!(
        x.message,
        "0F00H..10FFH overlaps blocks[0] (0000H..0FFFH); a register belongs to one block"
    );
    assert_eq!((x.line, x.column), (10, 5));
}

#[test]
fn an_identification_register_outside_the_map_is_an_error() {
    let text = v2(r#",
  "blocks": [{"first": "0000", "last": "0FFF", "basis": "documented", "source": "s"}],
  "identification": {"register": "2000", "value": "1234", "basis": "documented", "source": "s"}"#);
    let f = lint("t", &text);
    assert_eq!(
        find(&f, "identification.register").message,
        "2000H is outside the map: no block, group or register declares it"
    );
    let inside = text.replace("\"2000\"", "\"0FFF\"");
    assert!(lint("t", &inside)
        .iter()
        .all(|x| x.path != "identification.register"));
}

#[test]
fn the_f510_example_register_inside_a_block_is_a_warning_unless_access_differs() {
    let example = |access: &str| {
        v2(&format!(
            r#",
  "blocks": [{{"first": "0000", "last": "0FFF", "basis": "documented", "source": "s"}}],
  "example_registers": [{{"register": "0123", "initial": "1770", "access": "{access}", "basis": "decision", "why": "w"}}]"#
        ))
    };
    let f = lint("t", &example("read-write"));
    let x = find(&f, "example_registers[0]");
    assert_eq!(x.severity, Severity::Warning);
    assert!(f.iter().all(|x| !x.message.contains("overlaps")), "{f:#?}");
    let f = lint("t", &example("read-only"));
    let x = find(&f, "example_registers[0].access");
    assert_eq!(x.severity, Severity::Error);
    assert_eq!(
        x.message,
        "example register 0123H is read-only but blocks[0] (0000H..0FFFH) is read-write"
    );
}

#[test]
fn an_exception_without_a_table_and_a_backward_block_are_errors() {
    let text = v2(r#",
  "blocks": [{"first": "0FFF", "last": "0000", "basis": "documented", "source": "s"}],
  "exceptions": {"illegal-count": {"code": "03", "basis": "documented", "source": "s"}}"#);
    let f = lint("t", &text);
    assert_messages(
        &f,
        &[
            (
                "blocks[0].last",
                "block runs backwards: first 0FFFH, last 0000H",
            ),
            (
                "exceptions.illegal-count.code",
                "code 03 is not in the exception-code table (exception_codes has 02)",
            ),
        ],
    );
}

#[test]
fn summary_counts_errors_and_warnings() {
    let f = lint("t", "[]");
    assert_eq!(summary(&f), "1 error, 0 warnings");
    assert_eq!(f[0].message, "expected an object, found an array []");
}

#[test]
fn lint_is_total_over_damaged_files() {
    // Cuts and byte flips through a real description: whatever comes out, the fuzz
    // target's laws hold (no panic, places inside the text, clean means it loads).
    let text = f510();
    let b = text.as_bytes();
    let step = (b.len() / 150).max(1);
    for cut in (0..b.len()).step_by(step) {
        if let Some(t) = text.get(..cut) {
            crate::oracle::model_lint(t.as_bytes());
        }
        let mut flipped = b.to_vec();
        flipped[cut] = match flipped[cut] {
            b'"' => b'{',
            b'{' => b'[',
            b':' => b',',
            c if c.is_ascii_digit() => b'x',
            _ => b'"',
        };
        if let Ok(t) = std::str::from_utf8(&flipped) {
            crate::oracle::model_lint(t.as_bytes());
        }
    }
}
