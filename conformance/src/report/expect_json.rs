//! The expectations part of the JSON report (`--expect`): written by [`outcome`] and
//! [`mark`], read back by [`read_outcome`] so that `report` and `diff` see which results
//! were expected.

use std::collections::BTreeMap;

use serde_json::{json, Value};

use super::error::{field, ReportError};
use super::Report;
use crate::codec::Mode;
use crate::expect::{
    Day, Entry, EntryReport, EntryState, Expected, Mark, MarkKind, Outcome, Target,
};
use crate::runner::CheckResult;

/// The report's `expectations` object.
pub fn outcome(report: &Report, o: &Outcome) -> Value {
    let count = |k: MarkKind| o.marks.values().filter(|m| m.kind == k).count();
    let entries: Vec<Value> = o
        .entries
        .iter()
        .map(|e| {
            let x = &e.entry;
            let (check, signature) = match &x.target {
                Target::Check(c) => (Some(c.clone()), None),
                Target::Signature(s) => (None, Some(s.clone())),
            };
            json!({
                "line": x.line,
                "check": check,
                "signature": signature,
                "node": x.node,
                "mode": x.mode.map(|m| m.to_string()),
                "status": x.status.key(),
                "reason": x.reason,
                "ticket": x.ticket,
                "expires": x.expires.map(|d| d.to_string()),
                "identification": x.identification.map(|v| format!("{v:04X}")),
                "state": e.state.key(),
                "matched": e.matched,
            })
        })
        .collect();
    json!({
        "file": o.path,
        "strict": o.strict,
        "today": o.today.to_string(),
        "counts": {
            "expected": count(MarkKind::Expected),
            "unexpected": report.unexpected_findings().len(),
            "unexpected_pass": count(MarkKind::UnexpectedPass) + o.not_found(),
            "changed": count(MarkKind::Changed),
            "expired": o.entries.iter().filter(|e| e.state == EntryState::Expired).count(),
            "unmatched": o.entries.iter().filter(|e| matches!(e.state, EntryState::Unmatched | EntryState::OtherDevice)).count(),
        },
        "entries": entries,
    })
}

/// A check's `expectation` object.
pub fn mark(m: &Mark) -> Value {
    json!({
        "outcome": m.kind.key(),
        "line": m.line,
        "status": m.expected.key(),
        "reason": m.reason,
        "ticket": m.ticket,
    })
}

fn s<'a>(v: &'a Value, key: &str, path: &str) -> Result<&'a str, ReportError> {
    v.get(key)
        .and_then(Value::as_str)
        .ok_or_else(|| field(&format!("{path}.{key}"), "missing or not a string"))
}

fn opt_s(v: &Value, key: &str) -> Option<String> {
    v.get(key).and_then(Value::as_str).map(str::to_string)
}

fn line(v: &Value, path: &str) -> Result<usize, ReportError> {
    v.get("line")
        .and_then(Value::as_u64)
        .and_then(|n| usize::try_from(n).ok())
        .ok_or_else(|| field(&format!("{path}.line"), "missing or not a whole number"))
}

fn expected(v: &Value, path: &str) -> Result<Expected, ReportError> {
    let k = s(v, "status", path)?;
    Expected::from_key(k).ok_or_else(|| {
        field(
            &format!("{path}.status"),
            format!("{k:?} is not deviation, observation or finding"),
        )
    })
}

/// A check's mark read back (`checks[i].expectation`).
fn read_mark(v: &Value, path: &str) -> Result<Mark, ReportError> {
    let k = s(v, "outcome", path)?;
    Ok(Mark {
        kind: MarkKind::from_key(k).ok_or_else(|| {
            field(
                &format!("{path}.outcome"),
                format!("{k:?} is not expected, unexpected-pass or changed"),
            )
        })?,
        line: line(v, path)?,
        expected: expected(v, path)?,
        reason: s(v, "reason", path)?.to_string(),
        ticket: opt_s(v, "ticket"),
    })
}

/// The outcome read back from a report's `expectations` and its checks' `expectation`
/// (None for a report of a run without `--expect`).
pub fn read_outcome(v: &Value, results: &[CheckResult]) -> Result<Option<Outcome>, ReportError> {
    let o = match v.get("expectations") {
        None | Some(Value::Null) => return Ok(None),
        Some(o) => o,
    };
    let p = ".expectations";
    let entries = o
        .get("entries")
        .and_then(Value::as_array)
        .ok_or_else(|| field(&format!("{p}.entries"), "missing or not an array"))?
        .iter()
        .enumerate()
        .map(|(i, e)| {
            let p = format!("{p}.entries[{i}]");
            let target = match (opt_s(e, "check"), opt_s(e, "signature")) {
                (Some(c), _) => Target::Check(c),
                (None, Some(sig)) => Target::Signature(sig),
                (None, None) => return Err(field(&p, "neither check nor signature")),
            };
            let state = s(e, "state", &p)?;
            Ok(EntryReport {
                entry: Entry {
                    line: line(e, &p)?,
                    target,
                    node: e
                        .get("node")
                        .and_then(Value::as_u64)
                        .and_then(|n| u8::try_from(n).ok()),
                    mode: match opt_s(e, "mode").as_deref() {
                        Some("rtu") => Some(Mode::Rtu),
                        Some("ascii") => Some(Mode::Ascii),
                        _ => None,
                    },
                    status: expected(e, &p)?,
                    reason: s(e, "reason", &p)?.to_string(),
                    ticket: opt_s(e, "ticket"),
                    expires: opt_s(e, "expires").and_then(|d| Day::parse(&d)),
                    identification: opt_s(e, "identification")
                        .and_then(|x| u16::from_str_radix(&x, 16).ok()),
                },
                state: EntryState::from_key(state).ok_or_else(|| {
                    field(&format!("{p}.state"), format!("{state:?} is not a state"))
                })?,
                matched: e
                    .get("matched")
                    .and_then(Value::as_u64)
                    .and_then(|n| usize::try_from(n).ok())
                    .unwrap_or(0),
            })
        })
        .collect::<Result<Vec<_>, ReportError>>()?;
    let mut marks = BTreeMap::new();
    if let Some(checks) = v.get("checks").and_then(Value::as_array) {
        for (i, (c, r)) in checks.iter().zip(results).enumerate() {
            if let Some(m) = c.get("expectation").filter(|m| !m.is_null()) {
                marks.insert(r.key(), read_mark(m, &format!(".checks[{i}].expectation"))?);
            }
        }
    }
    Ok(Some(Outcome {
        path: s(o, "file", p)?.to_string(),
        strict: o.get("strict").and_then(Value::as_bool).unwrap_or(false),
        today: opt_s(o, "today")
            .and_then(|d| Day::parse(&d))
            .unwrap_or(Day {
                year: 1970,
                month: 1,
                day: 1,
            }),
        entries,
        marks,
    }))
}
