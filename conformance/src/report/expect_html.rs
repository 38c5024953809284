//! The HTML report's part of a run with `--expect`: what the file accepts, the unexpected
//! passes, and the entries that did not apply; and a tag for each marked check.

use std::fmt::Write as _;

use super::markup::esc;
use super::Report;
use crate::expect::{EntryState, Mark, MarkKind, Outcome};
use crate::runner::CheckResult;

/// "expect.toml:12".
fn at(e: &Outcome, m: &Mark) -> String {
    format!("{}:{}", e.path, m.line)
}

/// Why a result is expected, escaped: the entry's place, its reason and its ticket.
fn because(e: &Outcome, m: &Mark) -> String {
    format!(
        "({}): {}{}",
        esc(&at(e, m)),
        esc(&m.reason),
        m.ticket
            .as_deref()
            .map(|t| format!(" [{}]", esc(t)))
            .unwrap_or_default()
    )
}

/// The tag after a check's status badge in the table of every check.
pub fn tag(report: &Report, r: &CheckResult) -> String {
    match report.expectation(r) {
        Some(m) if m.kind == MarkKind::Expected => {
            format!(
                " <span class=\"badge skip\" title=\"{}\">expected</span>",
                esc(&m.reason)
            )
        }
        Some(m) if m.kind == MarkKind::UnexpectedPass => format!(
            " <span class=\"badge deviation\" title=\"{}\">UNEXPECTED PASS</span>",
            esc(&m.reason)
        ),
        _ => String::new(),
    }
}

/// The expectations section: counts, unexpected passes, expected results (each folded
/// with its frames by `block`), entries not applied.
pub fn section(
    out: &mut String,
    report: &Report,
    e: &Outcome,
    mut block: impl FnMut(&mut String, &CheckResult),
) {
    let marked = |k: MarkKind| -> Vec<(&CheckResult, &Mark)> {
        report
            .results
            .iter()
            .filter_map(|r| {
                report
                    .expectation(r)
                    .filter(|m| m.kind == k)
                    .map(|m| (r, m))
            })
            .collect()
    };
    let (expected, passes) = (marked(MarkKind::Expected), marked(MarkKind::UnexpectedPass));
    let stale: Vec<_> = e.stale().collect();
    let _ = write!(
        out,
        "<h2 id=\"expected\">Expected results ({})</h2><p class=\"muted\">Against {}: {} new deviation(s), {} unexpected pass(es){}, {} entr{} not applied.</p>",
        expected.len(),
        esc(&e.path),
        report.unexpected_findings().len(),
        report.unexpected_passes(),
        if e.strict { " (strict: they fail the run)" } else { "" },
        stale.len(),
        if stale.len() == 1 { "y" } else { "ies" },
    );
    if !passes.is_empty() {
        out.push_str("<h3>Unexpected passes</h3><ul>");
        for (r, m) in &passes {
            let _ = write!(
                out,
                "<li><code>{}</code> UNEXPECTED PASS: expected {} {}</li>",
                esc(&r.key()),
                m.expected.key(),
                because(e, m)
            );
        }
        out.push_str("</ul>");
    }
    for (r, m) in &expected {
        let _ = write!(out, "<p class=\"muted\">expected {}</p>", because(e, m));
        block(out, r);
    }
    if !stale.is_empty() {
        out.push_str("<h3>Entries not applied</h3><ul>");
        for x in stale {
            let why = match x.state {
                EntryState::Expired => format!(
                    "expired on {}",
                    x.entry.expires.map(|d| d.to_string()).unwrap_or_default()
                ),
                EntryState::Unmatched => "matched nothing in this run".into(),
                EntryState::OtherDevice => "for another identification".into(),
                EntryState::NotFound => {
                    "UNEXPECTED PASS: a complete campaign did not find it again".into()
                }
                EntryState::Applied => String::new(),
            };
            let _ = write!(
                out,
                "<li>{}:{} {}: {} ({})</li>",
                esc(&e.path),
                x.entry.line,
                esc(&x.entry.target.to_string()),
                esc(&why),
                esc(&x.entry.reason)
            );
        }
        out.push_str("</ul>");
    }
}
