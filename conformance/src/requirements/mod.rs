//! The requirements catalogue: every statement of the five manuals' Modbus chapters that a
//! tester could observe on the wire, with its exact quote and line, and what in this suite
//! verifies it (data under `vectors/requirements/`, schema
//! `vectors/schema/requirements.schema.json`).
//!
//! This module is data, beside [`crate::vectors`] and [`crate::model`]: it loads and checks
//! the files' shape. [`trace`] resolves the links against the checks, vectors, model facts,
//! monitor kinds and oracle classes that exist, and computes the coverage.

pub mod fuzzing;
pub mod trace;

use std::collections::BTreeSet;
use std::sync::OnceLock;

use serde::{Deserialize, Serialize};

/// The catalogues as built into the binary, as (document, JSON).
const BUILTIN: [(&str, &str); 5] = [
    (
        "f510",
        include_str!("../../../vectors/requirements/f510.json"),
    ),
    (
        "a510",
        include_str!("../../../vectors/requirements/a510.json"),
    ),
    (
        "l510",
        include_str!("../../../vectors/requirements/l510.json"),
    ),
    (
        "e510",
        include_str!("../../../vectors/requirements/e510.json"),
    ),
    (
        "l510-legacy",
        include_str!("../../../vectors/requirements/l510-legacy.json"),
    ),
];

/// A catalogue file that cannot be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RequirementsError {
    /// Not JSON, or not the schema's shape.
    #[error("{file}: line {line}, column {column}: {message}")]
    Parse {
        /// The file.
        file: String,
        /// 1-based line.
        line: usize,
        /// 1-based column.
        column: usize,
        /// What serde said.
        message: String,
    },
    /// A requirement that breaks a rule of the schema.
    #[error("{file}: {id}: field '{field}': {message}")]
    Invalid {
        /// The file.
        file: String,
        /// The requirement's id (or "document").
        id: String,
        /// The field.
        field: &'static str,
        /// What is wrong.
        message: String,
    },
}

/// How a statement can be verified on the wire.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verification {
    /// By sending requests (`check`, `fuzz`).
    Active,
    /// Only by listening (`monitor`).
    Passive,
    /// Not on the wire (wiring, keypad, what the motor does).
    NotOnWire,
}

impl Verification {
    /// As the files spell it.
    pub fn key(self) -> &'static str {
        match self {
            Verification::Active => "active",
            Verification::Passive => "passive",
            Verification::NotOnWire => "not-on-wire",
        }
    }
}

/// The kinds of requirement.
pub const KINDS: [&str; 16] = [
    "line-settings",
    "framing",
    "addressing",
    "function",
    "limit",
    "timing",
    "exception",
    "register-map",
    "access",
    "command-bit",
    "status-bit",
    "monitor-register",
    "parameter",
    "loop-back",
    "error-handling",
    "identification",
];

/// What verifies a requirement.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct VerifiedBy {
    /// Check id patterns ('*' matches anything; without one, the whole id).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub checks: Vec<String>,
    /// Golden vector ids.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub vectors: Vec<String>,
    /// JSON pointers into the model file.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub model: Vec<String>,
    /// Monitor kinds.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub monitor: Vec<String>,
    /// The fuzz oracle's classes (a fault or a silence reason of the model).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub fuzz: Vec<String>,
}

/// A statement that contradicts a requirement, and what settles it.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Conflict {
    /// The other requirement's id.
    pub with: String,
    /// A vector id, a flag, a model pointer ("a510:/exception_codes") or "unsettled: why".
    pub settled_by: String,
    /// More words.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
}

/// One requirement.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Requirement {
    /// `<document>.REQ-NNN`.
    pub id: String,
    /// The manual's words, whitespace folded.
    pub quote: String,
    /// The line of the source file where the quote starts (1-based).
    pub line: usize,
    /// The manual's section.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub section: String,
    /// One sentence a tester can check.
    pub statement: String,
    /// One of [`KINDS`].
    pub kind: String,
    /// How it can be verified.
    pub verification: Verification,
    /// What verifies it.
    #[serde(default)]
    pub verified_by: VerifiedBy,
    /// Why no check verifies it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reason: Option<String>,
    /// Contradicting statements.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub conflicts: Vec<Conflict>,
    /// Why it no longer applies (its id is kept).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub withdrawn: Option<String>,
}

/// Checks of the model that verify no statement of this document, and why (a rule of the
/// Modbus specification only, or a decision of the model where the manual is silent).
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Unlinked {
    /// A check id pattern, as in [`VerifiedBy::checks`].
    pub checks: String,
    /// Why no requirement of this document is verified by them.
    pub reason: String,
}

/// The requirements of one document.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Catalogue {
    /// 1.
    pub schema_version: u32,
    /// The document (f510, ..., l510-legacy).
    pub document: String,
    /// The drive model whose checks verify it.
    pub model: String,
    /// The source text file, relative to `shared/seeds/`.
    pub source: String,
    /// The document's title.
    pub title: String,
    /// Which lines are the Modbus chapter, and how parameters were sampled.
    #[serde(default, skip_serializing_if = "String::is_empty")]
    pub scope: String,
    /// The requirements, in the manual's order.
    pub requirements: Vec<Requirement>,
    /// The model's checks that verify no requirement of this document, with the reason.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub checks_without_requirement: Vec<Unlinked>,
}

impl Catalogue {
    /// Parses and checks one catalogue (`file` names it in errors).
    pub fn parse(file: &str, text: &str) -> Result<Catalogue, RequirementsError> {
        let cat: Catalogue = serde_json::from_str(text).map_err(|e| RequirementsError::Parse {
            file: file.to_string(),
            line: e.line(),
            column: e.column(),
            message: e.to_string(),
        })?;
        cat.check_shape(file)?;
        Ok(cat)
    }

    fn check_shape(&self, file: &str) -> Result<(), RequirementsError> {
        let bad = |id: &str, field: &'static str, message: String| RequirementsError::Invalid {
            file: file.to_string(),
            id: id.to_string(),
            field,
            message,
        };
        if self.schema_version != 1 {
            return Err(bad(
                "document",
                "schema_version",
                format!("{} (this suite reads version 1)", self.schema_version),
            ));
        }
        if !crate::model::MODELS.contains(&self.document.as_str()) {
            return Err(bad(
                "document",
                "document",
                format!("'{}' is none of {:?}", self.document, crate::model::MODELS),
            ));
        }
        let mut seen = BTreeSet::new();
        let prefix = format!("{}.REQ-", self.document);
        for r in &self.requirements {
            let digits = r.id.strip_prefix(&prefix).unwrap_or("");
            if digits.len() != 3 || !digits.bytes().all(|b| b.is_ascii_digit()) {
                return Err(bad(&r.id, "id", format!("not of the form {prefix}NNN")));
            }
            if !seen.insert(r.id.as_str()) {
                return Err(bad(&r.id, "id", "used twice".into()));
            }
            if r.line == 0 {
                return Err(bad(&r.id, "line", "lines count from 1".into()));
            }
            if fold(&r.quote).len() < 3 {
                return Err(bad(&r.id, "quote", "empty or too short".into()));
            }
            if r.statement.trim().is_empty() {
                return Err(bad(&r.id, "statement", "empty".into()));
            }
            if !KINDS.contains(&r.kind.as_str()) {
                return Err(bad(
                    &r.id,
                    "kind",
                    format!("'{}' is none of {KINDS:?}", r.kind),
                ));
            }
            let has_reason = r.reason.as_deref().is_some_and(|s| !s.trim().is_empty());
            if r.verified_by.checks.is_empty() && !has_reason && r.withdrawn.is_none() {
                return Err(bad(
                    &r.id,
                    "reason",
                    "no check verifies it and no reason says why".into(),
                ));
            }
        }
        for u in &self.checks_without_requirement {
            if u.reason.trim().len() < 10 {
                return Err(bad(
                    &u.checks,
                    "checks_without_requirement",
                    "the reason is missing or too short".into(),
                ));
            }
        }
        Ok(())
    }

    /// The catalogues built into the binary, in the order of [`crate::model::MODELS`].
    pub fn builtin() -> Result<Vec<Catalogue>, RequirementsError> {
        BUILTIN
            .iter()
            .map(|(doc, text)| Catalogue::parse(&format!("vectors/requirements/{doc}.json"), text))
            .collect()
    }

    /// The built-in files as (document, JSON).
    pub fn builtin_texts() -> &'static [(&'static str, &'static str)] {
        &BUILTIN
    }

    /// The requirements in force (not withdrawn).
    pub fn current(&self) -> impl Iterator<Item = &Requirement> {
        self.requirements.iter().filter(|r| r.withdrawn.is_none())
    }
}

/// The built-in catalogues, loaded once; empty if a built-in file is broken (a test
/// catches that: `tests/requirements.rs`).
pub fn builtin() -> &'static [Catalogue] {
    static CATALOGUES: OnceLock<Vec<Catalogue>> = OnceLock::new();
    CATALOGUES.get_or_init(|| Catalogue::builtin().unwrap_or_default())
}

/// The catalogue whose checks are `model`'s.
pub fn of_model(model: &str) -> Option<&'static Catalogue> {
    builtin().iter().find(|c| c.model == model)
}

/// The ids of the requirements that the check `check_id` of `model` verifies.
pub fn for_check(model: &str, check_id: &str) -> Vec<&'static str> {
    let Some(cat) = of_model(model) else {
        return Vec::new();
    };
    cat.current()
        .filter(|r| r.verified_by.checks.iter().any(|p| matches(p, check_id)))
        .map(|r| r.id.as_str())
        .collect()
}

/// Whether a link pattern names `id`: '*' matches any run of characters; a pattern
/// without one names exactly that id ([`crate::runner::id_matches`] with whole ids).
pub fn matches(pattern: &str, id: &str) -> bool {
    crate::runner::id_matches(pattern, id, crate::runner::Plain::WholeId)
}

/// Whitespace runs (line breaks included) folded to one space, ends trimmed.
pub fn fold(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

/// How many lines after its first a quote may run over.
pub const QUOTE_SPAN_LINES: usize = 30;

/// Checks that `quote` is in `text` starting on `line` (1-based): the quote, folded, is
/// found in the folded text of `line` and the lines after it, and starts within `line`.
pub fn quote_is_at(text: &str, line: usize, quote: &str) -> Result<(), String> {
    let lines: Vec<&str> = text.lines().collect();
    if line == 0 || line > lines.len() {
        return Err(format!(
            "line {line} is outside the file ({} lines)",
            lines.len()
        ));
    }
    let first = fold(lines[line - 1]);
    let end = (line - 1 + QUOTE_SPAN_LINES).min(lines.len());
    let window = fold(&lines[line - 1..end].join(" "));
    let q = fold(quote);
    match window.find(&q) {
        Some(at) if at <= first.len() => Ok(()),
        Some(_) => Err(format!(
            "the quote is in the text, but does not start on line {line} ('{first}')"
        )),
        None => Err(match text_find_line(&lines, &q) {
            Some(n) => format!("the quote is not at line {line}; it starts on line {n}"),
            None => format!(
                "the quote is not in the text (line {line} reads '{}')",
                first
            ),
        }),
    }
}

fn text_find_line(lines: &[&str], q: &str) -> Option<usize> {
    (0..lines.len()).find_map(|i| {
        let end = (i + QUOTE_SPAN_LINES).min(lines.len());
        let first = fold(lines[i]);
        let window = fold(&lines[i..end].join(" "));
        window
            .find(q)
            .filter(|&at| at <= first.len())
            .map(|_| i + 1)
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn patterns_match_whole_ids() {
        assert!(matches("rtu.map.monitor.first", "rtu.map.monitor.first"));
        assert!(!matches("rtu.map.monitor", "rtu.map.monitor.first"));
        assert!(matches("*.map.monitor.*", "ascii.map.monitor.last"));
        assert!(!matches("*.map.monitor.*", "ascii.map.command.last"));
        assert!(matches("*", "anything"));
        assert!(matches("a*a", "aa"));
        assert!(!matches("ab*ba", "aba"));
    }

    #[test]
    fn quotes_are_found_where_they_start() {
        let text = "first line\nThe maximum frame\n   length is 80 bytes.\nend";
        assert!(quote_is_at(text, 2, "The maximum frame length is 80 bytes.").is_ok());
        assert!(quote_is_at(text, 2, "frame length").is_ok());
        let e = quote_is_at(text, 1, "length is 80").unwrap_err();
        assert!(e.contains("does not start on line 1"), "{e}");
        let e = quote_is_at(text, 4, "The maximum").unwrap_err();
        assert!(e.contains("starts on line 2"), "{e}");
        assert!(quote_is_at(text, 9, "end").is_err());
        assert!(quote_is_at(text, 1, "not there").is_err());
    }

    #[test]
    fn a_broken_file_names_the_line_and_the_field() {
        let e =
            Catalogue::parse("x.json", "{\n\"schema_version\": 1,\n\"document\": 3}").unwrap_err();
        assert!(matches!(e, RequirementsError::Parse { line: 3, .. }), "{e}");
        let base = r#"{"schema_version": 1, "document": "f510", "model": "f510", "source": "s", "title": "t", "requirements": [
            {"id": "f510.REQ-001", "quote": "abc def", "line": 1, "statement": "s", "kind": "KIND", "verification": "active", "verified_by": {"checks": ["x"]}}]}"#;
        let e = Catalogue::parse("x.json", &base.replace("KIND", "colour")).unwrap_err();
        assert_eq!(
            e.to_string().split(": ").nth(2),
            Some("field 'kind'"),
            "{e}"
        );
        assert!(Catalogue::parse("x.json", &base.replace("KIND", "framing")).is_ok());
        let no_reason = base.replace("KIND", "framing").replace(
            r#""verified_by": {"checks": ["x"]}"#,
            r#""verified_by": {}"#,
        );
        let e = Catalogue::parse("x.json", &no_reason).unwrap_err();
        assert!(e.to_string().contains("field 'reason'"), "{e}");
        let twice = base.replace("KIND", "framing").replace(
            "}]}",
            r#"}, {"id": "f510.REQ-001", "quote": "abc", "line": 1, "statement": "s", "kind": "framing", "verification": "active", "reason": "r"}]}"#,
        );
        let e = Catalogue::parse("x.json", &twice).unwrap_err();
        assert!(e.to_string().contains("used twice"), "{e}");
    }
}
