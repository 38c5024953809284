//! The monitor's section of the HTML report: per node, what was heard, and a histogram
//! of response times drawn as SVG.

use std::fmt::Write as _;

use super::esc;
use crate::monitor::{MonitorSummary, NodeStats};

/// The section: a table of the nodes, then one histogram per node with replies.
pub(super) fn section(m: &MonitorSummary) -> String {
    let mut out = String::new();
    let ms = |d: Option<std::time::Duration>| {
        d.map_or("-".to_string(), |d| {
            format!("{:.1}", d.as_secs_f64() * 1000.0)
        })
    };
    let _ = write!(
        out,
        "<h2 id=\"heard\">Heard on the bus</h2><p class=\"muted\">{}</p>{}<table class=\"budget\"><thead><tr><th>node</th><th class=\"num\">requests</th><th class=\"num\">exchanges</th><th class=\"num\">replies</th><th class=\"num\">timeouts</th><th class=\"num\">CRC errors</th><th class=\"num\">retries</th><th class=\"num\">p50 ms</th><th class=\"num\">p95 ms</th><th class=\"num\">p99 ms</th><th class=\"num\">max ms</th><th>findings</th></tr></thead><tbody>",
        esc(&m.text_lines()[0]),
        if m.notices.is_empty() {
            String::new()
        } else {
            let items: Vec<String> = m
                .notices
                .iter()
                .map(|n| format!("<li>notice: {}</li>", esc(n)))
                .collect();
            format!("<ul class=\"notices\">{}</ul>", items.concat())
        }
    );
    for (a, s) in &m.nodes {
        let h = &s.response;
        let findings: Vec<String> = s.errors.iter().map(|(k, n)| format!("{k} {n}")).collect();
        let _ = write!(
            out,
            "<tr><td>{a:02X}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{}</td></tr>",
            s.requests,
            s.exchanges,
            s.replies,
            s.timeouts,
            s.crc_errors,
            s.retries,
            ms(h.percentile(50)),
            ms(h.percentile(95)),
            ms(h.percentile(99)),
            ms(h.max()),
            esc(&findings.join(", "))
        );
    }
    out.push_str("</tbody></table>");
    for (a, s) in &m.nodes {
        if s.response.count() > 0 {
            let _ = write!(out, "<h3>Node {a:02X}: response times</h3>");
            out.push_str(&histogram(s));
        }
    }
    out
}

/// Bars of the non-empty buckets, in order, with their lower edge in ms.
fn histogram(s: &NodeStats) -> String {
    let buckets = s.response.buckets();
    let top = buckets.iter().map(|b| b.1).max().unwrap_or(1).max(1);
    let (w, h, pad) = (640.0_f64, 160.0_f64, 30.0_f64);
    let bw = ((w - 2.0 * pad) / buckets.len().max(1) as f64).min(24.0);
    let mut out = format!(
        "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"{w}\" height=\"{h}\" role=\"img\"><title>response times, ms</title>"
    );
    for (i, (lo, c)) in buckets.iter().enumerate() {
        let bh = (h - 2.0 * pad) * f64::from(*c) / f64::from(top);
        let x = pad + i as f64 * bw;
        let _ = write!(
            out,
            "<rect x=\"{x:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{bh:.1}\" fill=\"#4a7\"><title>{lo:.1} ms: {c}</title></rect>",
            h - pad - bh,
            (bw - 1.0).max(1.0)
        );
        if i == 0 || i + 1 == buckets.len() {
            let _ = write!(
                out,
                "<text x=\"{x:.1}\" y=\"{:.1}\" font-size=\"10\">{lo:.1}</text>",
                h - pad + 12.0
            );
        }
    }
    let _ = write!(
        out,
        "<text x=\"{pad}\" y=\"14\" font-size=\"10\">{} replies; most in one bucket {top}</text></svg>",
        s.response.count()
    );
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn summary(notices: &[&str]) -> MonitorSummary {
        MonitorSummary {
            mode: "rtu".into(),
            port: "pty /dev/pts/9".into(),
            line: "19200 8O1".into(),
            window_ms: 1000,
            frames: 0,
            bytes: 0,
            listened: std::time::Duration::from_secs(2),
            searched: None,
            ended: "end of input".into(),
            nodes: Vec::new(),
            notices: notices.iter().map(|n| n.to_string()).collect(),
        }
    }

    /// What the report can be trusted for (the settings found by listening, a latency
    /// timer, bytes not judged at the start) is in the HTML as in the text and JSON:
    /// each notice once, escaped, before the table.
    #[test]
    fn the_notices_are_listed_before_the_table_escaped() {
        let html = section(&summary(&[
            "19200 8O1 rtu found by listening (two valid frames in a row, after 4 other settings)",
            "the first 3 bytes <01 03 25> were not judged",
        ]));
        let list = html.find("<ul class=\"notices\">").expect(&html);
        assert!(list < html.find("<table").unwrap(), "{html}");
        assert!(html.contains("<li>notice: 19200 8O1 rtu found by listening (two valid frames in a row, after 4 other settings)</li>"), "{html}");
        assert!(
            html.contains("<li>notice: the first 3 bytes &lt;01 03 25&gt; were not judged</li>"),
            "{html}"
        );
        assert_eq!(html.matches("<li>notice: ").count(), 2);
        // None: no empty list.
        assert!(!section(&summary(&[])).contains("notices"));
    }
}
