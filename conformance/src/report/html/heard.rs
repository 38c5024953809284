//! The monitor's section of the HTML report: per node, what was heard, and a histogram
//! of response times drawn as SVG.

use std::fmt::Write as _;

use super::svg;
use crate::monitor::stats::Histogram;
use crate::monitor::{MonitorSummary, NodeStats};
use crate::report::markup::esc;

/// The section: a table of the nodes, then one histogram per node with replies, against
/// `limits`.
pub(super) fn section(m: &MonitorSummary, limits: Limits) -> String {
    let mut out = String::new();
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
        let cells: String = s
            .figures()
            .iter()
            .map(|f| format!("<td class=\"num\">{f}</td>"))
            .collect();
        let _ = write!(
            out,
            "<tr><td>{a:02X}</td>{cells}<td>{}</td></tr>",
            esc(&s.findings_text())
        );
    }
    out.push_str("</tbody></table>");
    for (a, s) in &m.nodes {
        if s.response.count() > 0 {
            let _ = write!(out, "<h3>Node {a:02X}: response times</h3>");
            out.push_str(&histogram(*a, s, limits));
        }
    }
    out
}

/// The manual's response time and the time beyond which a reply counts as late, in ms,
/// from the report's options (the limits the monitor judged by).
pub(super) type Limits = (Option<f64>, Option<f64>);

/// A node's response times: a bar per non-empty bucket on a time axis in ms from 0, the
/// count of replies up the side, and the manual's response time and the late limit as
/// lines, so that a reader sees where the replies fall against what the manual allows.
fn histogram(a: u8, s: &NodeStats, (manual, late): Limits) -> String {
    let buckets = s.response.buckets();
    let peak = buckets.iter().map(|b| b.1).max().unwrap_or(1).max(1);
    let longest = buckets
        .last()
        .map_or(0.0, |(lo, _)| lo + Histogram::bucket_width_ms(*lo));
    let top = longest.max(late.unwrap_or(0.0)).max(1.0) * 1.08;
    let tick = svg::step(top, 8.0);
    let x_max = (top / tick).ceil() * tick;
    let (left, right, top_y, plot_h) = (60.0_f64, 20.0_f64, 24.0_f64, 110.0_f64);
    let (width, height) = (900.0_f64, top_y + plot_h + 40.0);
    let plot_w = width - left - right;
    let base = top_y + plot_h;
    let x = |v: f64| left + v / x_max * plot_w;
    let mut out = format!(
        "<svg id=\"hist-{a:02X}\" class=\"plot\" viewBox=\"0 0 {width} {height}\" role=\"img\" aria-label=\"Response times of node {a:02X}, ms\" xmlns=\"http://www.w3.org/2000/svg\">"
    );
    for (lo, c) in &buckets {
        let w = Histogram::bucket_width_ms(*lo);
        let h = plot_h * f64::from(*c) / f64::from(peak);
        let _ = write!(
            out,
            "<rect class=\"bar{}\" x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{h:.1}\"><title>{lo:.1}–{:.1} ms: {c} repl{}</title></rect>",
            if late.is_some_and(|l| *lo >= l) { " late" } else { "" },
            x(*lo),
            base - h,
            (x(lo + w) - x(*lo)).max(1.5),
            lo + w,
            if *c == 1 { "y" } else { "ies" }
        );
    }
    // The axes: time along the bottom, replies up the side.
    let _ = write!(
        out,
        "<line class=\"axis\" x1=\"{left}\" y1=\"{base}\" x2=\"{}\" y2=\"{base}\"/><line class=\"axis\" x1=\"{left}\" y1=\"{top_y}\" x2=\"{left}\" y2=\"{base}\"/>",
        left + plot_w
    );
    let mut t = 0.0;
    while t <= x_max + 1e-9 {
        let _ = write!(
            out,
            "<line class=\"tick\" x1=\"{0:.1}\" y1=\"{base}\" x2=\"{0:.1}\" y2=\"{1}\"/><text class=\"small\" x=\"{0:.1}\" y=\"{2}\" text-anchor=\"middle\">{3}</text>",
            x(t),
            base + 4.0,
            base + 16.0,
            svg::trim(t)
        );
        t += tick;
    }
    for (v, y) in [(0, base), (peak, top_y)] {
        let _ = write!(
            out,
            "<line class=\"tick\" x1=\"{}\" y1=\"{y}\" x2=\"{left}\" y2=\"{y}\"/><text class=\"small\" x=\"{}\" y=\"{}\" text-anchor=\"end\">{v}</text>",
            left - 4.0,
            left - 6.0,
            y + 4.0
        );
    }
    let _ = write!(
        out,
        "<text class=\"small\" x=\"14\" y=\"{0}\" text-anchor=\"middle\" transform=\"rotate(-90 14 {0})\">replies</text>",
        top_y + plot_h / 2.0
    );
    for (class, label, at) in [
        ("limit", "manual", manual),
        ("limit late", "late beyond", late),
    ] {
        if let Some(v) = at {
            let _ = write!(
                out,
                "<line class=\"{class}\" x1=\"{0:.1}\" y1=\"{1}\" x2=\"{0:.1}\" y2=\"{base}\"/><text class=\"small {2}\" x=\"{3:.1}\" y=\"{4}\">{label} {5} ms</text>",
                x(v),
                top_y - 10.0,
                if class == "limit" { "limit-t" } else { "late-t" },
                x(v) + 3.0,
                top_y - 2.0 - if class == "limit" { 0.0 } else { 10.0 },
                svg::trim(v)
            );
        }
    }
    let _ = write!(
        out,
        "<text class=\"small\" x=\"{}\" y=\"{}\" text-anchor=\"middle\">from the request's last byte to the reply's first (ms); {} replies</text></svg>",
        left + plot_w / 2.0,
        height - 6.0,
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
        ]), (None, None));
        let list = html.find("<ul class=\"notices\">").expect(&html);
        assert!(list < html.find("<table").unwrap(), "{html}");
        assert!(html.contains("<li>notice: 19200 8O1 rtu found by listening (two valid frames in a row, after 4 other settings)</li>"), "{html}");
        assert!(
            html.contains("<li>notice: the first 3 bytes &lt;01 03 25&gt; were not judged</li>"),
            "{html}"
        );
        assert_eq!(html.matches("<li>notice: ").count(), 2);
        // None: no empty list.
        assert!(!section(&summary(&[]), (None, None)).contains("notices"));
    }
}
