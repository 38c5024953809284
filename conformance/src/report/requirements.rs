//! The traceability matrix and the coverage of the manuals (`conformance requirements`):
//! text, JSON, CSV and HTML.

use std::fmt::Write;

use serde_json::{json, Value};

use super::csv::field;
use super::markup::{esc, CSS};
use crate::requirements::trace::{self, Coverage};
use crate::requirements::{Catalogue, Requirement};

macro_rules! w {
    ($out:expr, $($arg:tt)*) => {{
        // Writing to a String cannot fail.
        let _ = write!($out, $($arg)*);
    }};
}

/// Every link of `r`, as "checks: a, b; vectors: c".
fn links(r: &Requirement) -> String {
    let v = &r.verified_by;
    let mut parts = Vec::new();
    for (name, list) in [
        ("checks", &v.checks),
        ("vectors", &v.vectors),
        ("model", &v.model),
        ("monitor", &v.monitor),
        ("fuzz", &v.fuzz),
    ] {
        if !list.is_empty() {
            parts.push(format!("{name}: {}", list.join(", ")));
        }
    }
    parts.join("; ")
}

/// The coverage line of one catalogue: "f510: 120 requirements: 80 verified by a check, ...".
pub fn coverage_line(cat: &Catalogue) -> String {
    let counts = trace::counts(cat);
    let total: usize = counts.values().sum();
    let parts: Vec<String> = Coverage::ALL
        .iter()
        .map(|c| format!("{} {}", counts[c], c.words()))
        .collect();
    format!(
        "{}: {total} requirements: {}",
        cat.document,
        parts.join(", ")
    )
}

/// Text: per document, the coverage, the matrix (with `matrix`), and the uncovered
/// requirements with their quotes and reasons.
pub fn text(cats: &[&Catalogue], matrix: bool) -> String {
    let mut out = String::new();
    for cat in cats {
        w!(out, "{}\n  {}\n", coverage_line(cat), cat.title);
        if matrix {
            for r in cat.current() {
                w!(
                    out,
                    "  {:<18} {:<16} {:<16} {}\n  {:<18} {}\n",
                    r.id,
                    trace::coverage(r).key(),
                    r.kind,
                    r.statement,
                    "",
                    if links(r).is_empty() {
                        format!("(no link) {}", r.reason.as_deref().unwrap_or(""))
                    } else {
                        links(r)
                    }
                );
            }
        }
        let uncovered: Vec<&Requirement> = cat
            .current()
            .filter(|r| trace::coverage(r) == Coverage::Uncovered)
            .collect();
        if !uncovered.is_empty() {
            w!(out, "  not covered ({}):\n", uncovered.len());
            for r in uncovered {
                w!(
                    out,
                    "    {} (line {}): \"{}\"\n      why: {}\n",
                    r.id,
                    r.line,
                    r.quote,
                    r.reason.as_deref().unwrap_or("(no reason)")
                );
            }
        }
        out.push('\n');
    }
    out
}

/// JSON: per document, the counts and every requirement with its coverage.
pub fn json(cats: &[&Catalogue]) -> Value {
    let docs: Vec<Value> = cats
        .iter()
        .map(|cat| {
            let counts = trace::counts(cat);
            let reqs: Vec<Value> = cat
                .current()
                .map(|r| {
                    let mut v = serde_json::to_value(r).unwrap_or(Value::Null);
                    v["coverage"] = json!(trace::coverage(r).key());
                    v
                })
                .collect();
            json!({
                "document": cat.document,
                "model": cat.model,
                "title": cat.title,
                "source": cat.source,
                "total": counts.values().sum::<usize>(),
                "coverage": Coverage::ALL.iter().map(|c| (c.key().to_string(), json!(counts[c]))).collect::<serde_json::Map<String, Value>>(),
                "requirements": reqs,
            })
        })
        .collect();
    json!({
        "schema": "teco-modbus-conformance/requirements",
        "schema_version": 1,
        "documents": docs,
    })
}

/// CSV: one row per requirement.
pub fn csv(cats: &[&Catalogue]) -> String {
    let mut out = String::from(
        "id,document,line,section,kind,verification,coverage,statement,quote,checks,vectors,model,monitor,fuzz,reason\r\n",
    );
    for cat in cats {
        for r in cat.current() {
            let v = &r.verified_by;
            let row = [
                r.id.clone(),
                cat.document.clone(),
                r.line.to_string(),
                r.section.clone(),
                r.kind.clone(),
                r.verification.key().to_string(),
                trace::coverage(r).key().to_string(),
                r.statement.clone(),
                r.quote.clone(),
                v.checks.join(" "),
                v.vectors.join(" "),
                v.model.join(" "),
                v.monitor.join(" "),
                v.fuzz.join(" "),
                r.reason.clone().unwrap_or_default(),
            ];
            let row: Vec<String> = row.iter().map(|s| field(s)).collect();
            out.push_str(&row.join(","));
            out.push_str("\r\n");
        }
    }
    out
}

/// HTML: a page with the coverage per document and the matrix.
pub fn html(cats: &[&Catalogue]) -> String {
    let mut out = String::with_capacity(256 * 1024);
    w!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>Requirements of the manuals</title><style>{CSS}.cov-check{{background:var(--pass)}}.cov-vectors-or-model{{background:#5b8cc9}}.cov-passive-only{{background:var(--obs);color:#222}}.cov-not-on-wire{{background:var(--skip);color:#222}}.cov-uncovered{{background:var(--dev)}}</style></head><body><main><h1>Requirements of the manuals</h1><p class=\"muted\">Every wire-testable statement of each manual's Modbus chapter, with its quote and line, and what in this suite verifies it.</p>"
    );
    out.push_str("<table><thead><tr><th>document</th><th class=\"num\">total</th>");
    for c in Coverage::ALL {
        w!(out, "<th class=\"num\">{}</th>", esc(c.words()));
    }
    out.push_str("</tr></thead><tbody>");
    for cat in cats {
        let counts = trace::counts(cat);
        w!(
            out,
            "<tr><td><a href=\"#{0}\">{0}</a></td><td class=\"num\">{1}</td>",
            esc(&cat.document),
            counts.values().sum::<usize>()
        );
        for c in Coverage::ALL {
            w!(out, "<td class=\"num\">{}</td>", counts[&c]);
        }
        out.push_str("</tr>");
    }
    out.push_str("</tbody></table>");
    for cat in cats {
        w!(
            out,
            "<h2 id=\"{}\">{}</h2><p class=\"muted\">{}</p><table><thead><tr><th>id</th><th>coverage</th><th>requirement</th><th>verified by</th></tr></thead><tbody>",
            esc(&cat.document),
            esc(&cat.title),
            esc(&cat.scope)
        );
        for r in cat.current() {
            let cov = trace::coverage(r);
            w!(
                out,
                "<tr id=\"{id}\"><td class=\"id\">{id}</td><td><span class=\"badge cov-{k}\">{k}</span></td><td>{st}<div class=\"muted\">line {line}: “{q}”</div></td><td>{l}{why}</td></tr>",
                id = esc(&r.id),
                k = cov.key(),
                st = esc(&r.statement),
                line = r.line,
                q = esc(&r.quote),
                l = esc(&links(r)),
                why = r
                    .reason
                    .as_deref()
                    .map(|s| format!("<div class=\"muted\">{}</div>", esc(s)))
                    .unwrap_or_default()
            );
        }
        out.push_str("</tbody></table>");
    }
    w!(
        out,
        "<footer>Generated by {} {} from vectors/requirements/.</footer></main></body></html>\n",
        env!("CARGO_PKG_NAME"),
        env!("CARGO_PKG_VERSION")
    );
    out
}
