//! The description's JSON Schema (`vectors/schema/model.schema.json`), applied by a small
//! interpreter of the keywords that schema uses, so that `model lint` and the published
//! schema cannot disagree about which fields exist (tests/model_schema.rs holds the same
//! files to the schema with a full validator).

use std::sync::OnceLock;

use serde_json::Value;

use super::span::JsonPath;

/// The schema as built into the binary.
pub const MODEL_SCHEMA: &str = include_str!("../../../../vectors/schema/model.schema.json");

/// How deep `$ref`s may nest: the schema has no cycles, so this only stops a broken one.
const MAX_DEPTH: usize = 64;

/// What the schema says is wrong at a path.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SchemaError {
    /// The field.
    pub path: JsonPath,
    /// What was expected and what was found.
    pub message: String,
}

fn schema() -> &'static Value {
    static S: OnceLock<Value> = OnceLock::new();
    // The text is the crate's own file; tests/model_schema.rs compiles it, so a broken
    // one fails there. Null (which accepts anything) is the fallback, not a panic.
    S.get_or_init(|| serde_json::from_str(MODEL_SCHEMA).unwrap_or(Value::Null))
}

/// Every way `value` breaks the description schema.
pub fn check(value: &Value) -> Vec<SchemaError> {
    let root = schema();
    let mut out = Vec::new();
    walk(root, root, value, &JsonPath::default(), 0, &mut out);
    out
}

/// The members the schema allows in the object at `path` of `value` (for "did you mean").
fn known_members(s: &Value) -> Vec<&str> {
    s.get("properties")
        .and_then(Value::as_object)
        .map(|p| p.keys().map(String::as_str).collect())
        .unwrap_or_default()
}

fn resolve<'a>(root: &'a Value, s: &'a Value) -> Option<&'a Value> {
    match s.get("$ref").and_then(Value::as_str) {
        Some(r) => root.pointer(r.strip_prefix('#')?),
        None => Some(s),
    }
}

fn describe(v: &Value) -> String {
    let s = v.to_string();
    match s.char_indices().nth(40) {
        Some((i, _)) => format!("{}...", &s[..i]),
        None => s,
    }
}

fn type_name(v: &Value) -> &'static str {
    match v {
        Value::Null => "null",
        Value::Bool(_) => "a boolean",
        Value::Number(n) if n.is_u64() || n.is_i64() => "an integer",
        Value::Number(_) => "a number",
        Value::String(_) => "a string",
        Value::Array(_) => "an array",
        Value::Object(_) => "an object",
    }
}

fn has_type(v: &Value, t: &str) -> bool {
    match t {
        "null" => v.is_null(),
        "boolean" => v.is_boolean(),
        "integer" => v.is_u64() || v.is_i64(),
        "number" => v.is_number(),
        "string" => v.is_string(),
        "array" => v.is_array(),
        "object" => v.is_object(),
        _ => true,
    }
}

/// The patterns the schema uses, as predicates and as words; a pattern not listed here is
/// left to the loader.
fn pattern(p: &str, s: &str) -> Option<(bool, &'static str)> {
    let hex = |s: &str, n: usize| {
        s.len() == n && s.bytes().all(|c| matches!(c, b'0'..=b'9' | b'A'..=b'F'))
    };
    Some(match p {
        "^[0-9A-F]{2}$" => (hex(s, 2), "two upper-case hex digits"),
        "^[0-9A-F]{4}$" => (hex(s, 4), "four upper-case hex digits"),
        "^[0-9A-F]{4}(-[0-9A-F]{4})?$" => (
            match s.split_once('-') {
                Some((a, b)) => hex(a, 4) && hex(b, 4),
                None => hex(s, 4),
            },
            "XXXX or XXXX-YYYY in upper-case hex",
        ),
        "^[a-z0-9][a-z0-9._-]{0,63}$" => {
            (crate::model::valid_model_id(s), crate::model::MODEL_ID_RULE)
        }
        _ => return None,
    })
}

/// Edit distance, for "did you mean".
pub(crate) fn distance(a: &str, b: &str) -> usize {
    let b: Vec<char> = b.chars().collect();
    let mut row: Vec<usize> = (0..=b.len()).collect();
    for (i, ca) in a.chars().enumerate() {
        let mut prev = row[0];
        row[0] = i + 1;
        for (j, cb) in b.iter().enumerate() {
            let cur = row[j + 1];
            row[j + 1] = (prev + usize::from(ca != *cb)).min(row[j] + 1).min(cur + 1);
            prev = cur;
        }
    }
    row[b.len()]
}

/// The known name closest to `name`, if it is close enough to be a slip.
pub(crate) fn did_you_mean<'a>(name: &str, known: &[&'a str]) -> Option<&'a str> {
    let lower = name.to_ascii_lowercase().replace('-', "_");
    known
        .iter()
        .map(|k| (distance(&lower, k), *k))
        .filter(|(d, k)| *d <= (k.chars().count() / 3).max(1))
        .min_by_key(|(d, _)| *d)
        .map(|(_, k)| k)
}

fn walk(
    root: &Value,
    s: &Value,
    v: &Value,
    path: &JsonPath,
    depth: usize,
    out: &mut Vec<SchemaError>,
) {
    if depth > MAX_DEPTH {
        return;
    }
    let Some(s) = resolve(root, s) else { return };
    let err = |out: &mut Vec<SchemaError>, message: String| {
        out.push(SchemaError {
            path: path.clone(),
            message,
        })
    };
    if s.get("$ref").is_some() {
        walk(root, s, v, path, depth + 1, out);
    }
    if let Some(t) = s.get("type").and_then(Value::as_str) {
        if !has_type(v, t) {
            let want = match t {
                "integer" => "an integer",
                "number" => "a number",
                "string" => "a string",
                "boolean" => "true or false",
                "array" => "an array",
                "object" => "an object",
                _ => t,
            };
            err(
                out,
                format!("expected {want}, found {} {}", type_name(v), describe(v)),
            );
            // The other keywords of this schema are about that type: nothing more to say.
            return;
        }
    }
    if let Some(c) = s.get("const") {
        if c != v {
            err(out, format!("expected {c}, found {}", describe(v)));
        }
    }
    if let Some(e) = s.get("enum").and_then(Value::as_array) {
        if !e.contains(v) {
            let list = e
                .iter()
                .map(Value::to_string)
                .collect::<Vec<_>>()
                .join(", ");
            let hint = match v.as_str() {
                Some(found) => {
                    let names: Vec<&str> = e.iter().filter_map(Value::as_str).collect();
                    did_you_mean(found, &names)
                        .map(|m| format!("; did you mean \"{m}\"?"))
                        .unwrap_or_default()
                }
                None => String::new(),
            };
            err(
                out,
                format!("expected one of {list}, found {}{hint}", describe(v)),
            );
        }
    }
    if let (Some(p), Some(text)) = (s.get("pattern").and_then(Value::as_str), v.as_str()) {
        if let Some((false, words)) = pattern(p, text) {
            err(out, format!("expected {words}, found {}", describe(v)));
        }
    }
    if let Some(n) = v.as_f64() {
        if let Some(min) = s.get("minimum").and_then(Value::as_f64) {
            if n < min {
                err(
                    out,
                    format!("expected at least {min}, found {}", describe(v)),
                );
            }
        }
        if let Some(max) = s.get("maximum").and_then(Value::as_f64) {
            if n > max {
                err(
                    out,
                    format!("expected at most {max}, found {}", describe(v)),
                );
            }
        }
    }
    if let Some(a) = v.as_array() {
        if let Some(min) = s.get("minItems").and_then(Value::as_u64) {
            if (a.len() as u64) < min {
                err(
                    out,
                    format!("expected at least {min} entries, found {}", a.len()),
                );
            }
        }
        if let Some(max) = s.get("maxItems").and_then(Value::as_u64) {
            if (a.len() as u64) > max {
                err(
                    out,
                    format!("expected at most {max} entries, found {}", a.len()),
                );
            }
        }
        if s.get("uniqueItems") == Some(&Value::Bool(true)) {
            for (i, x) in a.iter().enumerate() {
                if let Some(j) = a[..i].iter().position(|y| y == x) {
                    out.push(SchemaError {
                        path: path.index(i),
                        message: format!("{} repeats entry [{j}]", describe(x)),
                    });
                }
            }
        }
        if let Some(items) = s.get("items") {
            for (i, x) in a.iter().enumerate() {
                walk(root, items, x, &path.index(i), depth + 1, out);
            }
        }
    }
    if let Some(o) = v.as_object() {
        let props = s.get("properties").and_then(Value::as_object);
        if let Some(req) = s.get("required").and_then(Value::as_array) {
            for r in req.iter().filter_map(Value::as_str) {
                if !o.contains_key(r) {
                    err(out, format!("missing field `{r}`"));
                }
            }
        }
        for (k, x) in o {
            match props.and_then(|p| p.get(k)) {
                Some(ps) => walk(root, ps, x, &path.key(k), depth + 1, out),
                None => match s.get("additionalProperties") {
                    Some(Value::Bool(false)) => {
                        let known = known_members(s);
                        let hint = match did_you_mean(k, &known) {
                            Some(m) => format!("did you mean `{m}`?"),
                            None => format!("expected one of: {}", known.join(", ")),
                        };
                        out.push(SchemaError {
                            path: path.key(k),
                            message: format!("unknown field `{k}`; {hint}"),
                        });
                    }
                    Some(extra @ Value::Object(_)) => {
                        walk(root, extra, x, &path.key(k), depth + 1, out)
                    }
                    _ => {}
                },
            }
        }
    }
    if let Some(any) = s.get("anyOf").and_then(Value::as_array) {
        let branches: Vec<Vec<SchemaError>> = any
            .iter()
            .map(|b| {
                let mut e = Vec::new();
                walk(root, b, v, path, depth + 1, &mut e);
                e
            })
            .collect();
        if !branches.iter().any(Vec::is_empty) {
            // The branch that got furthest (fewest complaints) says best what was meant.
            if let Some(best) = branches.into_iter().min_by_key(Vec::len) {
                out.extend(best);
            }
        }
    }
    if let Some(all) = s.get("allOf").and_then(Value::as_array) {
        for b in all {
            walk(root, b, v, path, depth + 1, out);
        }
    }
    if let Some(cond) = s.get("if") {
        let mut e = Vec::new();
        walk(root, cond, v, path, depth + 1, &mut e);
        let branch = if e.is_empty() {
            s.get("then")
        } else {
            s.get("else")
        };
        if let Some(b) = branch {
            walk(root, b, v, path, depth + 1, out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slips_are_caught_and_strangers_are_not_matched() {
        let known = ["blocks", "limits", "read_registers", "modes"];
        assert_eq!(did_you_mean("blcoks", &known), Some("blocks"));
        assert_eq!(
            did_you_mean("read-registers", &known),
            Some("read_registers")
        );
        assert_eq!(did_you_mean("Modes", &known), Some("modes"));
        assert_eq!(did_you_mean("colour", &known), None);
        assert_eq!(distance("", "abc"), 3);
        assert_eq!(distance("kitten", "sitting"), 3);
    }

    #[test]
    fn the_schema_is_built_in_and_has_the_top_level_fields() {
        let s = schema();
        let known = known_members(s);
        for f in ["schema_version", "blocks", "limits", "identification"] {
            assert!(known.contains(&f), "{f}");
        }
    }
}
