//! Field-level checks of a model file: hex numbers and ranges, a fact's basis and
//! citation, the fields a version 1 file requires, and the Modbus specification's facts
//! that stand in for what a version 2 description leaves out. [`super::load`] builds the
//! model from them.

use std::ops::RangeInclusive;

use super::*;

pub(super) fn hex16(model: &str, what: &str, s: &str) -> Result<u16, ModelError> {
    let v = upper_hex(model, what, s, 4, "four")?;
    Ok(v as u16)
}

pub(super) fn hex8(model: &str, what: &str, s: &str) -> Result<u8, ModelError> {
    let v = upper_hex(model, what, s, 2, "two")?;
    Ok(v as u8)
}

/// `s` as exactly `digits` upper-case hex digits (`spelt` is the count in words, for the
/// error), so the value fits the `digits * 4` bits its caller narrows it to.
fn upper_hex(
    model: &str,
    what: &str,
    s: &str,
    digits: usize,
    spelt: &str,
) -> Result<u32, ModelError> {
    if s.len() == digits
        && s.bytes()
            .all(|c| c.is_ascii_digit() || (b'A'..=b'F').contains(&c))
    {
        if let Ok(v) = u32::from_str_radix(s, 16) {
            return Ok(v);
        }
    }
    Err(ModelError::Invalid {
        model: model.to_string(),
        path: what.to_string(),
        problem: format!("{s:?} is not {spelt} upper-case hex digits"),
    })
}

pub(super) fn hex_range(
    model: &str,
    what: &str,
    s: &str,
) -> Result<RangeInclusive<u16>, ModelError> {
    let (a, b) = match s.split_once('-') {
        Some((a, b)) => (hex16(model, what, a)?, hex16(model, what, b)?),
        None => {
            let a = hex16(model, what, s)?;
            (a, a)
        }
    };
    if a > b {
        return Err(ModelError::Invalid {
            model: model.to_string(),
            path: what.to_string(),
            problem: format!("range {s} runs backwards"),
        });
    }
    Ok(a..=b)
}

/// The paths of the fields a version 1 file must have (v2 makes each optional).
pub(super) fn v1_required(f: &ModelFile) -> Vec<&'static str> {
    let mut out = Vec::new();
    let mut need = |present: bool, path: &'static str| {
        if !present {
            out.push(path);
        }
    };
    need(f.manual.is_some(), "manual");
    need(f.notes.is_some(), "notes");
    need(f.addresses.is_some(), "addresses");
    need(f.loop_back.is_some(), "loop_back");
    need(f.exception_codes.is_some(), "exception_codes");
    need(f.exception_codes_source.is_some(), "exception_codes_source");
    need(f.exceptions.is_some(), "exceptions");
    need(f.silence.is_some(), "silence");
    need(f.groups.is_some(), "groups");
    need(f.registers.is_some(), "registers");
    need(f.identification.is_some(), "identification");
    need(f.parameter_groups.is_some(), "parameter_groups");
    need(f.parameter_access.is_some(), "parameter_access");
    need(f.example_registers.is_some(), "example_registers");
    need(f.initial_values.is_some(), "initial_values");
    need(f.aliases.is_some(), "aliases");
    match &f.limits {
        None => need(false, "limits"),
        Some(l) => {
            need(l.max_frame_bytes.is_some(), "limits.max_frame_bytes");
            need(l.read_registers.is_some(), "limits.read_registers");
            need(l.write_registers.is_some(), "limits.write_registers");
            if let Some(p) = &l.read_registers {
                need(p.rtu.is_some(), "limits.read_registers.rtu");
                need(p.ascii.is_some(), "limits.read_registers.ascii");
            }
            if let Some(p) = &l.write_registers {
                need(p.rtu.is_some(), "limits.write_registers.rtu");
                need(p.ascii.is_some(), "limits.write_registers.ascii");
            }
            need(l.same_group.is_some(), "limits.same_group");
            need(l.response_time_ms.is_some(), "limits.response_time_ms");
        }
    }
    out
}

/// A fact of the Modbus specification that a v2 description leaves to it.
pub(super) fn spec(rule: &str) -> Fact {
    Fact {
        basis: Basis::Derived,
        source: None,
        rule: Some(rule.to_string()),
        why: None,
    }
}

/// The Modbus application protocol's counts, which a v2 description may leave out.
pub(super) const SPEC_COUNTS: &str =
    "Modbus application protocol V1.1b3, 6.3 and 6.12: 1..125 registers per 03H, 1..123 per 10H";

/// "12-16" as (group, number).
pub(super) fn parameter_number(s: &str) -> Option<(u8, u8)> {
    let (g, n) = s.split_once('-')?;
    let ok = |t: &str| !t.is_empty() && t.len() <= 2 && t.bytes().all(|c| c.is_ascii_digit());
    if !ok(g) || !ok(n) {
        return None;
    }
    Some((g.parse().ok()?, n.parse().ok()?))
}

pub(super) fn check_fact(model: &str, what: &str, f: &file::FactFile) -> Result<(), ModelError> {
    let problem = match f.basis {
        Basis::Documented if f.source.as_deref().unwrap_or("").is_empty() => {
            Some("a documented fact needs a source")
        }
        Basis::Derived if f.rule.as_deref().unwrap_or("").is_empty() => {
            Some("a derived fact needs a rule")
        }
        Basis::Decision if f.why.as_deref().unwrap_or("").is_empty() => {
            Some("a decision needs a why")
        }
        _ => None,
    };
    let problem = problem.or(match (f.basis, &f.request) {
        (Basis::Observed, None) => Some("an observed fact needs the request that showed it"),
        (Basis::Observed, Some(r)) if !is_hex_frame(r) => {
            Some("request: not a frame in hex (pairs of hex digits, spaces between)")
        }
        (_, Some(_)) if f.basis != Basis::Observed => {
            Some("request and reply belong to observed facts")
        }
        _ => None,
    });
    let problem = problem.or(match &f.reply {
        Some(r) if !is_hex_frame(r) => {
            Some("reply: not a frame in hex (pairs of hex digits, spaces between)")
        }
        _ => None,
    });
    match problem {
        Some(p) => Err(ModelError::Invalid {
            model: model.to_string(),
            path: what.to_string(),
            problem: p.to_string(),
        }),
        None => Ok(()),
    }
}

/// "01 03 00 00 00 7D 85 EB" (or without spaces): a frame as hex.
pub(super) fn is_hex_frame(s: &str) -> bool {
    crate::codec::hex::parse_hex(s).is_ok_and(|b| !b.is_empty())
}
