//! Expectations: a hand-written file of known, accepted results ("this deviation, ticket
//! 123, until 2027-01-01"), so that a run gated in CI fails only on what changed.
//!
//! The file is TOML (`--expect FILE`): people write it by hand and keep it next to the
//! code, so it needs comments (why an entry is there) and errors that point at a line;
//! the `toml` crate gives every value's span, so an invalid file is refused with the line
//! and the field ([`ExpectError::Invalid`]). JSON has no comments; YAML's indentation
//! rules are a trap in a file people edit under pressure.
//!
//! ```toml
//! [[expect]]
//! check = "rtu.exceptions.*"        # a check id, '*' and '?' match anything
//! status = "deviation"              # deviation or observation
//! reason = "answers 03H where the manual says 02H"
//! ticket = "https://tracker.example/123"
//! expires = 2027-01-01              # optional: after this day the entry no longer applies
//! identification = "0510"           # optional: only for a device that reads this value
//! node = 1                          # optional, in a run of several nodes
//! mode = "rtu"                      # optional
//!
//! [[expect]]
//! signature = "rtu.mismatch.03H.exception-code"   # a fuzz finding's signature
//! reason = "..."
//! ```
//!
//! [`crate::report::apply_expectations`] marks a report's results against the entries;
//! [`crate::report::starting_expectations`] writes a
//! file from a report (`conformance expect --from REPORT.json`).

pub mod fuzzing;
mod outcome;

pub use outcome::{EntryReport, EntryState, Mark, MarkKind, Outcome};

use std::fmt;
use std::path::Path;

use serde::Deserialize;
use toml::Spanned;

use crate::codec::Mode;

/// Why an expectations file cannot be used.
#[derive(Debug, thiserror::Error)]
pub enum ExpectError {
    /// The file cannot be read.
    #[error("{path}: cannot read: {source}")]
    Read {
        /// The file.
        path: String,
        /// Why.
        source: std::io::Error,
    },
    /// The file is not a valid expectations file.
    #[error("{path}:{line}: {field}: {problem}")]
    Invalid {
        /// The file.
        path: String,
        /// The line (1-based) of the offending value, or of its entry where a field is
        /// missing.
        line: usize,
        /// The field, e.g. `status` (or `expect` for the entry as a whole).
        field: String,
        /// What is wrong, and what was expected.
        problem: String,
    },
}

/// The status an entry expects.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Expected {
    /// DEVIATION.
    Deviation,
    /// OBSERVATION.
    Observation,
    /// A fuzz finding, whichever of the two it is reported as.
    Finding,
}

impl Expected {
    /// Its word in the file and in reports.
    pub fn key(self) -> &'static str {
        match self {
            Expected::Deviation => "deviation",
            Expected::Observation => "observation",
            Expected::Finding => "finding",
        }
    }

    /// Reads [`Expected::key`] back.
    pub fn from_key(s: &str) -> Option<Expected> {
        Some(match s {
            "deviation" => Expected::Deviation,
            "observation" => Expected::Observation,
            "finding" => Expected::Finding,
            _ => return None,
        })
    }
}

/// A calendar day (UTC), as `expires` holds it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub struct Day {
    /// Year.
    pub year: u16,
    /// Month, 1..=12.
    pub month: u8,
    /// Day of the month, 1..=31.
    pub day: u8,
}

impl Day {
    /// Today in UTC.
    pub fn today() -> Day {
        let now = humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string();
        Day::parse(now.get(..10).unwrap_or("")).unwrap_or(Day {
            year: 1970,
            month: 1,
            day: 1,
        })
    }

    /// Parses `YYYY-MM-DD`.
    pub fn parse(s: &str) -> Option<Day> {
        let mut it = s.split('-');
        let (y, m, d) = (it.next()?, it.next()?, it.next()?);
        if it.next().is_some() || y.len() != 4 || m.len() != 2 || d.len() != 2 {
            return None;
        }
        let day = Day {
            year: y.parse().ok()?,
            month: m.parse().ok()?,
            day: d.parse().ok()?,
        };
        ((1..=12).contains(&day.month) && (1..=31).contains(&day.day)).then_some(day)
    }
}

impl fmt::Display for Day {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:04}-{:02}-{:02}", self.year, self.month, self.day)
    }
}

/// What an entry is about: a check (id or glob) or a fuzz finding's signature.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Target {
    /// A check id, or a glob of ids (`*`, `?`).
    Check(String),
    /// A fuzz finding's signature (its result's id without `fuzz.`), or a glob of them.
    Signature(String),
}

impl Target {
    /// The result id pattern it stands for.
    pub fn id_pattern(&self) -> String {
        match self {
            Target::Check(p) => p.clone(),
            Target::Signature(s) => format!("fuzz.{s}"),
        }
    }

    /// Whether it names more than one id.
    pub fn is_glob(&self) -> bool {
        let p = match self {
            Target::Check(p) | Target::Signature(p) => p,
        };
        p.contains(['*', '?'])
    }
}

impl fmt::Display for Target {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Target::Check(p) => write!(f, "check {p}"),
            Target::Signature(s) => write!(f, "signature {s}"),
        }
    }
}

/// One known result.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    /// The line of its `[[expect]]` header.
    pub line: usize,
    /// The check or finding.
    pub target: Target,
    /// Only this node (the node's address), if given.
    pub node: Option<u8>,
    /// Only this mode, if given.
    pub mode: Option<Mode>,
    /// The status it expects.
    pub status: Expected,
    /// Why it is accepted.
    pub reason: String,
    /// A ticket or URL.
    pub ticket: Option<String>,
    /// The last day it applies.
    pub expires: Option<Day>,
    /// Only for a device whose identification register reads this.
    pub identification: Option<u16>,
}

/// A whole expectations file.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Expectations {
    /// Where it was read from (for reports).
    pub path: String,
    /// Its entries in file order.
    pub entries: Vec<Entry>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawFile {
    #[serde(default)]
    expect: Vec<Spanned<RawEntry>>,
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct RawEntry {
    check: Option<Spanned<String>>,
    signature: Option<Spanned<String>>,
    node: Option<Spanned<i64>>,
    mode: Option<Spanned<String>>,
    status: Option<Spanned<String>>,
    reason: Option<Spanned<String>>,
    ticket: Option<Spanned<String>>,
    expires: Option<Spanned<toml::value::Datetime>>,
    identification: Option<Spanned<String>>,
}

/// The 1-based line of byte `offset` of `text`.
fn line_of(text: &str, offset: usize) -> usize {
    let end = offset.min(text.len());
    text.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// The field a parser error is about: named in its message (unknown or missing field),
/// else the key before `=` on the line it points at, else the table (`expect`). A key
/// that is empty once its quotes are gone (`"" = 1`, `'' = 1`) names no field, nor does
/// a message that names the empty key.
fn field_of_parse_error(message: &str, line_text: &str) -> String {
    for lead in ["unknown field `", "missing field `", "duplicate key `"] {
        if let Some(rest) = message.split(lead).nth(1) {
            if let Some(name) = rest.split('`').next().filter(|n| !n.trim().is_empty()) {
                return name.to_string();
            }
        }
    }
    let unquoted = |key: &str| key.trim().trim_matches(['"', '\'']).trim().to_string();
    match line_text.split_once('=') {
        Some((key, _)) if !unquoted(key).is_empty() && !key.trim().starts_with('[') => {
            unquoted(key)
        }
        _ => "expect".to_string(),
    }
}

impl Expectations {
    /// Reads and parses a file.
    pub fn load(path: &Path) -> Result<Expectations, ExpectError> {
        let name = path.display().to_string();
        let text = std::fs::read_to_string(path).map_err(|source| ExpectError::Read {
            path: name.clone(),
            source,
        })?;
        Expectations::parse(&text, &name)
    }

    /// Parses the text of a file; `path` names it in errors.
    pub fn parse(text: &str, path: &str) -> Result<Expectations, ExpectError> {
        let invalid = |offset: usize, field: &str, problem: String| ExpectError::Invalid {
            path: path.to_string(),
            line: line_of(text, offset),
            field: field.to_string(),
            problem,
        };
        let raw: RawFile = toml::from_str(text).map_err(|e| {
            let at = e.span().map_or(0, |s| s.start);
            let line_text = text
                .lines()
                .nth(line_of(text, at).saturating_sub(1))
                .unwrap_or("");
            let message = e.message().trim().to_string();
            invalid(at, &field_of_parse_error(&message, line_text), message)
        })?;
        let mut entries = Vec::with_capacity(raw.expect.len());
        for spanned in raw.expect {
            let at = spanned.span().start;
            let e = spanned.into_inner();
            let target = match (e.check, e.signature) {
                (Some(c), None) => {
                    check_pattern(&c).map_err(|p| invalid(c.span().start, "check", p))?;
                    Target::Check(c.into_inner())
                }
                (None, Some(s)) => {
                    check_pattern(&s).map_err(|p| invalid(s.span().start, "signature", p))?;
                    Target::Signature(s.into_inner())
                }
                (Some(_), Some(s)) => {
                    return Err(invalid(
                        s.span().start,
                        "signature",
                        "an entry names a check or a fuzz signature, not both".into(),
                    ))
                }
                (None, None) => return Err(invalid(
                    at,
                    "check",
                    "missing: each entry names a check id (or glob), or a fuzz finding's signature"
                        .into(),
                )),
            };
            let status = match (&e.status, &target) {
                (None, Target::Signature(_)) => Expected::Finding,
                (None, Target::Check(_)) => {
                    return Err(invalid(
                        at,
                        "status",
                        "missing: \"deviation\" or \"observation\"".into(),
                    ))
                }
                (Some(s), _) => match Expected::from_key(s.get_ref()) {
                    Some(x) => x,
                    None => {
                        let why = match s.get_ref().as_str() {
                            "error" => "an ERROR is the bench failing to tell, never an accepted result of a device; expect \"deviation\" or \"observation\"".to_string(),
                            "pass" | "skip" => format!("{:?} needs no entry; expect \"deviation\" or \"observation\"", s.get_ref()),
                            other => format!("{other:?} is not \"deviation\", \"observation\" or \"finding\""),
                        };
                        return Err(invalid(s.span().start, "status", why));
                    }
                },
            };
            let reason = match e.reason {
                Some(r) if !r.get_ref().trim().is_empty() => r.into_inner(),
                Some(r) => {
                    return Err(invalid(
                        r.span().start,
                        "reason",
                        "empty: say why this result is accepted".into(),
                    ))
                }
                None => {
                    return Err(invalid(
                        at,
                        "reason",
                        "missing: say why this result is accepted".into(),
                    ))
                }
            };
            let node = optional(e.node, "node", &invalid, |n| {
                u8::try_from(*n).map_err(|_| format!("{n} is not a node address (0..=255)"))
            })?;
            let mode = optional(e.mode, "mode", &invalid, |m| {
                Mode::from_key(m).ok_or_else(|| format!("{m:?} is not \"rtu\" or \"ascii\""))
            })?;
            let expires = optional(e.expires, "expires", &invalid, |v| {
                match (v.date, v.time, v.offset) {
                    (Some(x), None, None) => Ok(Day {
                        year: x.year,
                        month: x.month,
                        day: x.day,
                    }),
                    _ => Err(format!(
                        "{v} is not a day: write it as 2027-01-31 (no quotes, no time)"
                    )),
                }
            })?;
            let identification = optional(e.identification, "identification", &invalid, |i| {
                let s = i.trim();
                let digits = s
                    .strip_prefix("0x")
                    .or_else(|| s.strip_suffix('H'))
                    .unwrap_or(s);
                u16::from_str_radix(digits, 16).map_err(|_| {
                    format!(
                        "{s:?} is not a 16-bit hex value (the identification register, e.g. \"0510\")"
                    )
                })
            })?;
            let ticket = e.ticket.map(Spanned::into_inner).filter(|t| !t.is_empty());
            entries.push(Entry {
                line: line_of(text, at),
                target,
                node,
                mode,
                status,
                reason,
                ticket,
                expires,
                identification,
            });
        }
        Ok(Expectations {
            path: path.to_string(),
            entries,
        })
    }
}

/// An entry's optional `field`, read by `read`; a value it refuses is an error at the
/// value's place, in `read`'s words.
fn optional<T, U>(
    value: Option<Spanned<T>>,
    field: &str,
    invalid: &impl Fn(usize, &str, String) -> ExpectError,
    read: impl FnOnce(&T) -> Result<U, String>,
) -> Result<Option<U>, ExpectError> {
    value
        .map(|v| read(v.get_ref()).map_err(|problem| invalid(v.span().start, field, problem)))
        .transpose()
}

/// Refuses an empty pattern and characters no check id has.
fn check_pattern(p: &Spanned<String>) -> Result<(), String> {
    let s = p.get_ref();
    if s.is_empty() {
        return Err("empty".into());
    }
    match s
        .chars()
        .find(|c| c.is_whitespace() || c.is_control() || matches!(c, '[' | ']' | '{' | '}'))
    {
        Some(c) => Err(format!(
            "{s:?} has {c:?}: ids are letters, digits, '.', '-' and '@'; '*' and '?' match anything"
        )),
        None => Ok(()),
    }
}

/// Whether `id` matches the whole of `pattern` (`*` any run of characters, `?` one).
pub fn glob_match(pattern: &str, id: &str) -> bool {
    let (p, s): (Vec<char>, Vec<char>) = (pattern.chars().collect(), id.chars().collect());
    let (mut pi, mut si) = (0usize, 0usize);
    let mut star: Option<(usize, usize)> = None;
    while si < s.len() {
        match p.get(pi) {
            Some('*') => {
                star = Some((pi, si));
                pi += 1;
            }
            Some(&c) if c == '?' || c == s[si] => {
                pi += 1;
                si += 1;
            }
            _ => match star {
                Some((sp, ss)) => {
                    pi = sp + 1;
                    si = ss + 1;
                    star = Some((sp, ss + 1));
                }
                None => return false,
            },
        }
    }
    p[pi.min(p.len())..].iter().all(|&c| c == '*')
}

#[cfg(test)]
mod tests;
