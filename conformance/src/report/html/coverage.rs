//! The requirements coverage of a `check` run: which requirements of the model's manual
//! this run verified, which it found deviating, and which it skipped (read-only, no motion,
//! no restart, `--only`), with the reason.

use std::fmt::Write;

use crate::report::markup::esc;
use crate::report::Report;
use crate::requirements::trace::{self, Coverage, RunCoverage};

macro_rules! w {
    ($out:expr, $($arg:tt)*) => {{
        // Writing to a String cannot fail.
        let _ = write!($out, $($arg)*);
    }};
}

/// The anchor of a requirement's row.
pub(super) fn anchor(id: &str) -> String {
    format!("req-{id}")
}

/// The requirement ids a check verifies, as links to their rows; empty if none.
pub(super) fn links(report: &Report, check_id: &str) -> String {
    let ids = crate::requirements::for_check(&report.device.model, check_id);
    if ids.is_empty() {
        return String::new();
    }
    let links: Vec<String> = ids
        .iter()
        .map(|id| format!("<a href=\"#{}\">{}</a>", esc(&anchor(id)), esc(id)))
        .collect();
    format!(
        "<div class=\"muted reqs\">verifies {}</div>",
        links.join(" ")
    )
}

/// The section, or nothing when the model has no catalogue.
pub(super) fn section(report: &Report) -> String {
    let Some(cat) = crate::requirements::of_model(&report.device.model) else {
        return String::new();
    };
    let results: Vec<(&str, String, &str)> = report
        .results
        .iter()
        .map(|r| {
            (
                r.id.as_str(),
                format!("{:?}", r.status).to_lowercase(),
                r.summary.as_str(),
            )
        })
        .collect();
    let results: Vec<(&str, &str, &str)> = results
        .iter()
        .map(|(a, b, c)| (*a, b.as_str(), *c))
        .collect();
    let rows = trace::of_run(cat, &report.options.modes, &results);
    let count = |k: &str| rows.iter().filter(|(_, c)| c.key() == k).count();
    let counts = trace::counts(cat);
    let mut out = String::new();
    w!(
        out,
        "<h2 id=\"coverage\">Requirements coverage</h2><p>Of the {total} requirements of the {doc} manual (<code>conformance requirements --doc {doc}</code>), {checked} are verified by a check. This run: <b>{v}</b> verified, <b>{d}</b> deviating, <b>{s}</b> skipped, <b>{e}</b> could not tell, <b>{n}</b> not selected, <b>{m}</b> of a mode this run did not speak. The other {rest} are covered by the vectors, the model or the fuzz oracle ({o}), only passively ({p}), not on the wire ({nw}), or not at all ({u}).</p>",
        total = counts.values().sum::<usize>(),
        doc = esc(&cat.document),
        checked = counts[&Coverage::Check],
        v = count("verified"),
        d = count("deviated"),
        s = count("skipped"),
        e = count("error"),
        n = count("not-run"),
        m = count("other-mode"),
        rest = counts.values().sum::<usize>() - counts[&Coverage::Check],
        o = counts[&Coverage::Otherwise],
        p = counts[&Coverage::Passive],
        nw = counts[&Coverage::NotOnWire],
        u = counts[&Coverage::Uncovered],
    );
    out.push_str("<table id=\"coverage-t\"><thead><tr><th>requirement</th><th>this run</th><th>statement</th><th>checks</th></tr></thead><tbody>");
    for (r, got) in &rows {
        let (class, label) = match got {
            RunCoverage::Verified => ("pass", "verified"),
            RunCoverage::Deviated => ("deviation", "deviating"),
            RunCoverage::Skipped(_) => ("skip", "skipped"),
            RunCoverage::Error(_) => ("error", "could not tell"),
            RunCoverage::NotRun => ("skip", "not selected"),
            RunCoverage::OtherMode(_) => ("skip", "other mode"),
        };
        let why = match got {
            RunCoverage::Skipped(w) | RunCoverage::Error(w) => {
                format!("<div class=\"muted\">{}</div>", esc(w))
            }
            RunCoverage::OtherMode(m) => {
                let m = m.to_string().to_uppercase();
                format!("<div class=\"muted\">its checks are {m}'s; this run did not speak {m} (--mode)</div>")
            }
            _ => String::new(),
        };
        w!(
            out,
            "<tr id=\"{a}\"><td class=\"id\">{id}</td><td><span class=\"badge {class}\">{label}</span>{why}</td><td>{st}<div class=\"muted\">line {line}: “{q}”</div></td><td class=\"id\">{c}</td></tr>",
            a = esc(&anchor(&r.id)),
            id = esc(&r.id),
            st = esc(&r.statement),
            line = r.line,
            q = esc(&r.quote),
            c = esc(&r.verified_by.checks.join(" ")),
        );
    }
    out.push_str("</tbody></table>");
    out
}
