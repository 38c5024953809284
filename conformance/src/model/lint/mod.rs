//! `model lint`: everything wrong with a device description, each with its file, line,
//! column and field path, before anything is sent to a device.
//!
//! Three passes, each only if the one before found no error, because an error of an early
//! pass makes the later ones guess: the JSON syntax (serde_json), the schema
//! (`vectors/schema/model.schema.json`: unknown fields with "did you mean", types, hex
//! spellings, required fields), then the rules a schema cannot say (overlapping blocks, an
//! identification register outside the map, limits beyond the Modbus specification,
//! exception codes not in the table) followed by the loader's own checks
//! ([`DriveModel::from_file`]), which stop at their first error.

mod schema;
pub mod span;

use std::fmt;
use std::ops::RangeInclusive;

use serde_json::Value;

pub use schema::MODEL_SCHEMA;
pub use span::{JsonPath, Segment};

use super::{DriveModel, ModelError};

/// How bad a finding is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, serde::Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum Severity {
    /// The description cannot be used: every command refuses it.
    Error,
    /// The description loads, but something in it is probably not what was meant.
    Warning,
}

impl fmt::Display for Severity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Severity::Error => "error",
            Severity::Warning => "warning",
        })
    }
}

/// One thing wrong with a description.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct Finding {
    /// Error or warning.
    pub severity: Severity,
    /// The file (or the name the text was given).
    pub file: String,
    /// Line, from 1.
    pub line: usize,
    /// Column, from 1, in characters.
    pub column: usize,
    /// The field's JSON path (`blocks[2].last`; `(top level)`).
    pub path: String,
    /// What was expected and what was found.
    pub message: String,
}

impl fmt::Display for Finding {
    /// `FILE:LINE:COL: error: PATH: message`, as rustc and gcc print theirs, so editors
    /// and CI logs link to the place.
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}:{}:{}: {}: {}: {}",
            self.file, self.line, self.column, self.severity, self.path, self.message
        )
    }
}

/// True if any finding is an error.
pub fn has_errors(findings: &[Finding]) -> bool {
    findings.iter().any(|f| f.severity == Severity::Error)
}

/// "2 errors, 1 warning".
pub fn summary(findings: &[Finding]) -> String {
    let n = |s: Severity| findings.iter().filter(|f| f.severity == s).count();
    let plural = |n: usize, w: &str| format!("{n} {w}{}", if n == 1 { "" } else { "s" });
    format!(
        "{}, {}",
        plural(n(Severity::Error), "error"),
        plural(n(Severity::Warning), "warning")
    )
}

/// Every finding in the description `text`; `name` names it in the findings (a file's
/// path). Never panics, whatever the text.
pub fn lint(name: &str, text: &str) -> Vec<Finding> {
    let mut out = Lints {
        name,
        text,
        findings: Vec::new(),
    };
    let value: Value = match serde_json::from_str(text) {
        Ok(v) => v,
        Err(e) => {
            out.findings.push(Finding {
                severity: Severity::Error,
                file: name.to_string(),
                line: e.line().max(1),
                column: e.column().max(1),
                path: JsonPath::default().to_string(),
                message: format!("not JSON: {e}"),
            });
            return out.findings;
        }
    };
    for e in schema::check(&value) {
        out.push(Severity::Error, &e.path, e.message);
    }
    if has_errors(&out.findings) {
        out.findings.sort_by_key(|f| (f.line, f.column));
        return out.findings;
    }
    semantic(&value, &mut out);
    if !has_errors(&out.findings) {
        loader(&mut out);
    }
    // In the file's order, as a compiler lists its errors.
    out.findings.sort_by_key(|f| (f.line, f.column));
    out.findings
}

struct Lints<'a> {
    name: &'a str,
    text: &'a str,
    findings: Vec<Finding>,
}

impl Lints<'_> {
    fn push(&mut self, severity: Severity, path: &JsonPath, message: String) {
        let (line, column) = span::line_col(self.text, span::locate(self.text, path));
        self.findings.push(Finding {
            severity,
            file: self.name.to_string(),
            line,
            column,
            path: path.to_string(),
            message,
        });
    }
}

/// The loader's checks: its first error, placed by the path its message starts with.
fn loader(out: &mut Lints<'_>) {
    let err = match DriveModel::from_json_unlinted(out.name, out.text) {
        Ok(_) => return,
        Err(e) => e,
    };
    match err {
        ModelError::Json { source, .. } => {
            // The schema passed, so this is a rule of the serde types it does not carry.
            // serde says where it stopped: the field is the one holding that place.
            let (line, column) = (source.line().max(1), source.column().max(1));
            let at = span::offset_of(out.text, line, column);
            let message = source.to_string();
            let message = match message.rfind(" at line ") {
                Some(i) => message[..i].to_string(),
                None => message,
            };
            out.findings.push(Finding {
                severity: Severity::Error,
                file: out.name.to_string(),
                line,
                column,
                path: span::path_at(out.text, at.saturating_sub(1)).to_string(),
                message,
            });
        }
        // The loader names the field where it can; else its message may say it.
        ModelError::Invalid { path, problem, .. } => {
            let (path, message) = match JsonPath::parse(&path) {
                Some(p) if !path.is_empty() => (p, problem),
                _ => loader_path(out.text, &problem),
            };
            out.push(Severity::Error, &path, message);
        }
        other => out.push(Severity::Error, &JsonPath::default(), other.to_string()),
    }
}

/// The field a loader message is about: its `what:` prefix where that is a path
/// (`limits.read_registers.rtu: ...`), the entry of `registers` where it names a register
/// (`register 2501: ...`), else the top level with the whole message.
fn loader_path(text: &str, problem: &str) -> (JsonPath, String) {
    if let Some((what, rest)) = problem.split_once(": ") {
        if let Some(p) = JsonPath::parse(what) {
            return (p, rest.to_string());
        }
        if let Some(reg) = what.strip_prefix("register ").and_then(|r| r.get(..4)) {
            let registers = serde_json::from_str::<Value>(text)
                .ok()
                .and_then(|v| v.get("registers").and_then(Value::as_array).cloned())
                .unwrap_or_default();
            if let Some(i) = registers
                .iter()
                .position(|r| r.get("register").and_then(Value::as_str) == Some(reg))
            {
                return (
                    JsonPath::default().key("registers").index(i),
                    problem.to_string(),
                );
            }
        }
    }
    (JsonPath::default(), problem.to_string())
}

fn hex(v: Option<&Value>) -> Option<u16> {
    let s = v?.as_str()?;
    u16::from_str_radix(s, 16).ok()
}

fn hex_range(s: &str) -> Option<RangeInclusive<u16>> {
    match s.split_once('-') {
        Some((a, b)) => Some(u16::from_str_radix(a, 16).ok()?..=u16::from_str_radix(b, 16).ok()?),
        None => {
            let a = u16::from_str_radix(s, 16).ok()?;
            Some(a..=a)
        }
    }
}

fn span_text(r: &RangeInclusive<u16>) -> String {
    if r.start() == r.end() {
        format!("{:04X}H", r.start())
    } else {
        format!("{:04X}H..{:04X}H", r.start(), r.end())
    }
}

fn overlaps(a: &RangeInclusive<u16>, b: &RangeInclusive<u16>) -> bool {
    a.start() <= b.end() && b.start() <= a.end()
}

/// The Modbus specification's limits (Modbus Application Protocol V1.1b3 6.3 and 6.12;
/// Modbus over Serial Line V1.02 2.5.1 and 2.5.2).
const SPEC_READ: u64 = 125;
const SPEC_WRITE: u64 = 123;
const SPEC_RTU_FRAME: u64 = 256;
const SPEC_ASCII_FRAME: u64 = 513;

/// The rules a schema cannot say. Runs on a value the schema accepted, so fields have
/// their types, but it still reads every one through `Option`.
fn semantic(v: &Value, out: &mut Lints<'_>) {
    let root = JsonPath::default();
    let arr = |k: &str| {
        v.get(k)
            .and_then(Value::as_array)
            .map(Vec::as_slice)
            .unwrap_or_default()
    };

    // Every span of the map with the path that declares it.
    let mut spans: Vec<(RangeInclusive<u16>, JsonPath, &'static str)> = Vec::new();
    // Two hex fields of one entry ("first" and "last"), where both are there and read.
    let both = |x: &Value, lo: &str, hi: &str| hex(x.get(lo)).zip(hex(x.get(hi)));
    for (i, b) in arr("blocks").iter().enumerate() {
        let p = root.key("blocks").index(i);
        if let Some((a, z)) = both(b, "first", "last") {
            if a > z {
                let problem = format!("block runs backwards: first {a:04X}H, last {z:04X}H");
                out.push(Severity::Error, &p.key("last"), problem);
                continue;
            }
            if let Some((lo, hi)) = both(b, "min", "max").filter(|(lo, hi)| lo > hi) {
                let problem = format!("max {hi:04X}H is below min {lo:04X}H");
                out.push(Severity::Error, &p.key("max"), problem);
            }
            spans.push((a..=z, p, "block"));
        }
    }
    for (i, g) in arr("groups").iter().enumerate() {
        if let Some((a, z)) = both(g, "first", "last") {
            if a <= z {
                spans.push((a..=z, root.key("groups").index(i), "group"));
            }
        }
    }
    for (i, g) in arr("parameter_groups").iter().enumerate() {
        let p = root.key("parameter_groups").index(i).key("registers");
        for (j, r) in g
            .get("registers")
            .and_then(Value::as_array)
            .map(Vec::as_slice)
            .unwrap_or_default()
            .iter()
            .enumerate()
        {
            if let Some(r) = r.as_str().and_then(hex_range) {
                spans.push((r, p.index(j), "parameter group"));
            }
        }
    }
    // Overlaps that involve a block: the v1 loader checks the TECO spans among themselves.
    for i in 0..spans.len() {
        for j in 0..i {
            let ((a, pa, ka), (b, pb, kb)) = (&spans[i], &spans[j]);
            if (*ka == "block" || *kb == "block") && overlaps(a, b) {
                let (a, pa, b, pb) = (a.clone(), pa.clone(), b.clone(), pb.clone());
                out.push(
                    Severity::Error,
                    &pa,
                    format!(
                        "{} overlaps {pb} ({}); a register belongs to one block",
                        span_text(&a),
                        span_text(&b)
                    ),
                );
            }
        }
    }
    // Example registers inside a block: the F510's example left in a copied file.
    for (i, e) in arr("example_registers").iter().enumerate() {
        let Some(r) = hex(e.get("register")) else {
            continue;
        };
        let p = root.key("example_registers").index(i);
        for (span, sp, kind) in &spans {
            if *kind != "block" || !span.contains(&r) {
                continue;
            }
            let block_access = v
                .pointer(&format!("/blocks/{}/access", block_index(sp)))
                .and_then(Value::as_str)
                .unwrap_or("read-write");
            let access = e
                .get("access")
                .and_then(Value::as_str)
                .unwrap_or("read-write");
            if access == block_access {
                out.push(
                    Severity::Warning,
                    &p,
                    format!(
                        "example register {r:04X}H is inside {sp} ({}) and adds nothing; remove it",
                        span_text(span)
                    ),
                );
            } else {
                out.push(
                    Severity::Error,
                    &p.key("access"),
                    format!(
                        "example register {r:04X}H is {access} but {sp} ({}) is {block_access}",
                        span_text(span)
                    ),
                );
            }
        }
    }
    // The identification register must be one the device serves.
    if let Some(id) = hex(v.pointer("/identification/register")) {
        let in_map = spans.iter().any(|(s, ..)| s.contains(&id))
            || arr("example_registers")
                .iter()
                .any(|e| hex(e.get("register")) == Some(id))
            || arr("registers")
                .iter()
                .any(|e| hex(e.get("register")) == Some(id));
        if !in_map {
            out.push(
                Severity::Error,
                &root.key("identification").key("register"),
                format!("{id:04X}H is outside the map: no block, group or register declares it"),
            );
        }
    }
    // Limits beyond the Modbus specification.
    let modes: Vec<&str> = arr("modes").iter().filter_map(Value::as_str).collect();
    let limits = root.key("limits");
    for (field, spec, what) in [
        (
            "read_registers",
            SPEC_READ,
            "registers per 03H read (Modbus Application Protocol 6.3: 1..125)",
        ),
        (
            "write_registers",
            SPEC_WRITE,
            "registers per 10H write (Modbus Application Protocol 6.12: 1..123)",
        ),
    ] {
        for mode in ["rtu", "ascii"] {
            let p = limits.key(field).key(mode);
            if let Some(n) = v
                .pointer(&format!("/limits/{field}/{mode}"))
                .and_then(Value::as_u64)
            {
                if n > spec {
                    out.push(
                        Severity::Error,
                        &p,
                        format!("{n} is beyond the specification's {spec} {what}"),
                    );
                }
            }
        }
    }
    if let Some(n) = v
        .pointer("/limits/max_frame_bytes/value")
        .and_then(Value::as_u64)
    {
        let p = limits.key("max_frame_bytes").key("value");
        if modes.contains(&"rtu") && n > SPEC_RTU_FRAME {
            out.push(Severity::Error, &p, format!("{n} bytes is beyond the specification's {SPEC_RTU_FRAME}-byte RTU frame (Modbus over Serial Line 2.5.1)"));
        } else if n > SPEC_ASCII_FRAME {
            out.push(Severity::Error, &p, format!("{n} characters is beyond the specification's {SPEC_ASCII_FRAME}-character ASCII frame (Modbus over Serial Line 2.5.2)"));
        }
    }
    // Exception codes used but not in the table.
    let table: Vec<&str> = arr("exception_codes")
        .iter()
        .filter_map(|e| e.get("code").and_then(Value::as_str))
        .collect();
    if let Some(rules) = v.get("exceptions").and_then(Value::as_object) {
        for (fault, rule) in rules {
            if let Some(code) = rule.get("code").and_then(Value::as_str) {
                if !table.contains(&code) {
                    out.push(
                        Severity::Error,
                        &root.key("exceptions").key(fault).key("code"),
                        format!(
                            "code {code} is not in the exception-code table (exception_codes has {})",
                            if table.is_empty() {
                                "none".to_string()
                            } else {
                                table.join(", ")
                            }
                        ),
                    );
                }
            }
        }
    }
}

/// The index of `blocks[i]` in a path that starts with it.
fn block_index(p: &JsonPath) -> usize {
    match p.0.get(1) {
        Some(Segment::Index(i)) => *i,
        _ => 0,
    }
}

#[cfg(test)]
mod tests;
