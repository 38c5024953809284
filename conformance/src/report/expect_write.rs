//! A starting expectations file from a report (`conformance expect --from REPORT.json`):
//! one entry per result that makes a run fail, for a person to give reasons and tickets.

use std::fmt::Write as _;

use super::{Report, ReportKind};
use crate::runner::Status;

/// A TOML basic string: quoted, with backslashes, quotes and control characters escaped.
fn quoted(s: &str) -> String {
    let mut o = String::with_capacity(s.len() + 2);
    o.push('"');
    for c in s.chars() {
        match c {
            '"' => o.push_str("\\\""),
            '\\' => o.push_str("\\\\"),
            '\n' => o.push_str("\\n"),
            '\t' => o.push_str("\\t"),
            c if c.is_control() => {
                let _ = write!(o, "\\u{:04X}", c as u32);
            }
            c => o.push(c),
        }
    }
    o.push('"');
    o
}

/// One line for a comment: newlines folded, at most `max` characters.
fn comment(s: &str, max: usize) -> String {
    let one: String = s
        .chars()
        .map(|c| if c.is_control() { ' ' } else { c })
        .collect();
    match one.char_indices().nth(max) {
        Some((i, _)) => format!("{}...", &one[..i]),
        None => one,
    }
}

/// The text of an expectations file that accepts every result of `report` that makes its
/// exit code 1: each deviation (and, for a fuzz run, each finding signature), with
/// `reason` (or a placeholder that says to write one), the report's identification as a
/// commented-out restriction, and the deviation's summary as a comment. `source` names
/// the report in the header.
pub fn starting_file(report: &Report, source: &str, reason: Option<&str>) -> String {
    let mut o = String::new();
    let _ = writeln!(
        o,
        "# Expected results: conformance check|fuzz|gate|monitor --expect THIS_FILE\n\
         # Written by `conformance expect --from {source}` from the run of {} ({}).\n\
         # Each entry: check (id or glob; '*' and '?') or signature (a fuzz finding),\n\
         # status, reason, ticket; optional node, mode, expires = YYYY-MM-DD and\n\
         # identification = \"XXXX\" (the identification register this entry is for).\n\
         # An entry past its expiry, or that names nothing in a run, is reported and ignored.",
        report.started,
        match report.kind {
            ReportKind::Gate => report
                .codec
                .as_ref()
                .map(|c| format!("codec {} {}", c.implementation, c.version))
                .unwrap_or_else(|| "a codec".into()),
            _ => format!("model {}", report.device.model),
        }
    );
    let reason = reason.unwrap_or("TODO: why this result is accepted");
    let mut n = 0usize;
    for r in &report.results {
        let fuzz_finding = report.kind == ReportKind::Fuzz
            && r.id.starts_with("fuzz.")
            && !r.id.ends_with(".campaign")
            && matches!(r.status, Status::Deviation | Status::Observation);
        if r.status != Status::Deviation && !fuzz_finding {
            continue;
        }
        n += 1;
        let _ = writeln!(o, "\n[[expect]]");
        let _ = writeln!(o, "# {}", comment(&r.summary, 160));
        match r.id.strip_prefix("fuzz.").filter(|_| fuzz_finding) {
            Some(sig) => {
                let _ = writeln!(o, "signature = {}", quoted(sig));
            }
            None => {
                let _ = writeln!(o, "check = {}", quoted(&r.id));
                let _ = writeln!(
                    o,
                    "status = {}",
                    quoted(&r.status.to_string().to_lowercase())
                );
            }
        }
        if let Some(node) = r.node {
            let _ = writeln!(o, "node = {node}");
        }
        let _ = writeln!(o, "reason = {}", quoted(reason));
        let _ = writeln!(o, "ticket = \"\"");
        let _ = writeln!(o, "# expires = 2099-12-31");
        let ident = super::expect_apply::identification_of(report, r);
        if let Some(v) = ident {
            let _ = writeln!(o, "# identification = \"{v:04X}\"");
        }
    }
    if n == 0 {
        let _ = writeln!(
            o,
            "\n# The run had no deviations and no findings: nothing to expect."
        );
    }
    o
}
