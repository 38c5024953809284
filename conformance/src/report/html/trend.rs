//! `watch -o x.html`: one self-contained page (the report's CSS, no script at all) with
//! the per-node statistics and a trend chart per register, drawn as inline SVG with the
//! report's axis helpers; the model's range is drawn on the chart where it has one, and
//! values outside it are red.

use std::fmt::Write as _;

use super::svg::{step, trim};
use crate::report::markup::{esc, CSS};
use crate::report::watch::stats_line;
use crate::watch::{Cell, Watcher};

macro_rules! w {
    ($out:expr, $($arg:tt)*) => {{
        // Writing to a String cannot fail.
        let _ = write!($out, $($arg)*);
    }};
}

/// The page for `w`, ended as `ended` says ("interrupted", "--duration 10s").
pub fn watch_html(w: &Watcher, ended: &str) -> String {
    let mut out = String::new();
    w!(
        out,
        "<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>watch {} {}</title><style>{CSS}</style></head><body><main>",
        esc(&w.model.id),
        esc(&humantime::format_rfc3339_seconds(w.started_at).to_string())
    );
    w!(
        out,
        "<h1>Watch of {} ({})</h1><p class=\"muted\">Started {}, {:.1} s, ended: {}. {} mode, reads per poll: {}. Only 03H reads were sent.</p>",
        esc(&w.model.id),
        esc(&w.model.manual),
        esc(&humantime::format_rfc3339_seconds(w.started_at).to_string()),
        w.elapsed().as_secs_f64(),
        esc(ended),
        w.mode,
        esc(&w
            .plan
            .reads
            .iter()
            .map(|r| format!("{:04X}H x{}", r.start, r.count))
            .collect::<Vec<_>>()
            .join(", "))
    );
    let verdict = if w.found() {
        "<div class=\"verdict bad\">an exception or a value out of the model's range was seen</div>"
    } else {
        "<div class=\"verdict ok\">no exception, no value out of the model's range</div>"
    };
    out.push_str(verdict);
    out.push_str("<h2>Nodes</h2><ul>");
    for n in &w.nodes {
        w!(
            out,
            "<li><code>{}</code></li>",
            esc(&stats_line(n.node, &n.stats))
        );
    }
    out.push_str("</ul>");
    for n in &w.nodes {
        w!(out, "<h2 id=\"node{0:02X}\">Node {0:02X}</h2>", n.node);
        for c in &n.cells {
            w!(
                out,
                "<h3>{}</h3><p class=\"muted\">{}</p>{}",
                esc(&w.model.describe(c.register)),
                esc(&cell_facts(w, c)),
                chart(w, n.node, c)
            );
        }
    }
    out.push_str("<footer>conformance watch: drawn by the suite, nothing fetched from the network.</footer></main></body></html>\n");
    out
}

/// The line under a register's title: last value, changes, what was observed, range.
fn cell_facts(w: &Watcher, c: &Cell) -> String {
    let last = c.value.map_or("no value read".to_string(), |v| {
        format!(
            "last {v:04X}H{}",
            w.model
                .value_text(c.register, v)
                .map_or(String::new(), |t| format!(" = {t}"))
        )
    });
    let range = w
        .model
        .range_of(c.register)
        .map_or(String::new(), |r| format!("; range {}", r.bounds()));
    format!(
        "{last}; {} changes; out of range {}, reserved bits set {}{range}",
        c.changes, c.out_of_range_count, c.reserved_count
    )
}

/// A trend chart: time across, the value (in its unit) up; the range's bound as a
/// dashed line; a point outside the range red.
fn chart(w: &Watcher, node: u8, c: &Cell) -> String {
    let pts = &c.trend.points;
    if pts.is_empty() {
        return "<p class=\"muted\">No value was read.</p>".into();
    }
    let unit = w.model.unit_of(c.register);
    let val = |raw: u16| unit.as_ref().map_or(f64::from(raw), |u| u.value(raw));
    let range = w.model.range_of(c.register);
    let bounds: Vec<f64> = range
        .iter()
        .flat_map(|r| [r.min, r.max])
        .flatten()
        .map(val)
        .collect();
    let values_min = pts
        .iter()
        .map(|p| val(p.1))
        .chain(bounds.iter().copied())
        .fold(f64::INFINITY, f64::min);
    let lo = pts
        .iter()
        .map(|p| val(p.1))
        .chain(bounds.iter().copied())
        .fold(f64::INFINITY, f64::min);
    let hi = pts
        .iter()
        .map(|p| val(p.1))
        .chain(bounds.iter().copied())
        .fold(f64::NEG_INFINITY, f64::max);
    // No tick finer than one step of the register (0.01 Hz; 1 for a raw value): a
    // finer one would label the same value twice.
    let resolution = unit.as_ref().map_or(1.0, |u| u.scale);
    let decimals = unit.as_ref().map_or(0, |u| u.decimals);
    // A flat trend gets one step of room either side.
    let (lo, hi) = if hi - lo < resolution / 2.0 {
        (lo - resolution, hi + resolution)
    } else {
        (lo, hi)
    };
    let tick = step(hi - lo, 4.0).max(resolution);
    // One tick of room below and above, so that a bound or a value on the edge is not
    // drawn on the axis (never below 0 for values that are not).
    let y0 = (lo / tick).floor() * tick - tick;
    let y0 = if values_min >= 0.0 { y0.max(0.0) } else { y0 };
    let y1 = (hi / tick).ceil() * tick + tick;
    let t_end = pts
        .last()
        .map_or(1.0, |p| p.0)
        .max(w.elapsed().as_secs_f64());
    let t_end = if t_end <= 0.0 { 1.0 } else { t_end };
    let t_tick = step(t_end, 8.0);
    let (width, height, left, right, top, bottom) = (900.0, 170.0, 80.0, 20.0, 10.0, 30.0);
    let pw = width - left - right;
    let ph = height - top - bottom;
    let x = |t: f64| left + t / t_end * pw;
    let y = |v: f64| top + ph - (v - y0) / (y1 - y0) * ph;
    let mut s = String::new();
    w!(
        s,
        "<svg id=\"trend-{node:02X}-{:04X}\" class=\"plot\" viewBox=\"0 0 {width} {height}\" role=\"img\" aria-label=\"{} over time\" xmlns=\"http://www.w3.org/2000/svg\">",
        c.register,
        esc(&w.model.describe(c.register))
    );
    let mut v = y0;
    while v <= y1 + tick / 2.0 {
        w!(
            s,
            "<line class=\"grid\" x1=\"{left}\" x2=\"{xr}\" y1=\"{yv:.1}\" y2=\"{yv:.1}\"/><text x=\"{xl}\" y=\"{yt:.1}\" class=\"small\" text-anchor=\"end\">{label}</text>",
            xr = width - right,
            yv = y(v),
            xl = left - 6.0,
            yt = y(v) + 4.0,
            label = format!("{v:.decimals$}")
        );
        v += tick;
    }
    let mut t = 0.0;
    while t <= t_end + t_tick / 2.0 {
        w!(
            s,
            "<text x=\"{:.1}\" y=\"{}\" class=\"small\" text-anchor=\"middle\">{}</text>",
            x(t),
            height - 12.0,
            trim(t)
        );
        t += t_tick;
    }
    w!(
        s,
        "<line class=\"axis\" x1=\"{left}\" x2=\"{left}\" y1=\"{top}\" y2=\"{}\"/><line class=\"axis\" x1=\"{left}\" x2=\"{}\" y1=\"{0}\" y2=\"{0}\"/>",
        top + ph,
        width - right
    );
    w!(
        s,
        "<text x=\"{}\" y=\"{}\" class=\"small\" text-anchor=\"end\">s</text><text x=\"6\" y=\"{}\" class=\"small\">{}</text>",
        width - right,
        height - 2.0,
        top + 10.0,
        esc(unit
            .as_ref()
            .map_or("raw", |u| if u.unit.is_empty() { "value" } else { u.unit.as_str() }))
    );
    for b in &bounds {
        w!(
            s,
            "<line class=\"limit late\" x1=\"{left}\" x2=\"{}\" y1=\"{1:.1}\" y2=\"{1:.1}\"><title>the model's bound {2}</title></line>",
            width - right,
            y(*b),
            trim(*b)
        );
    }
    // A step line: a register holds its value until the next poll.
    let mut path = String::new();
    for (i, (t, raw)) in pts.iter().enumerate() {
        let (px, py) = (x(*t), y(val(*raw)));
        if i == 0 {
            w!(path, "M{px:.1},{py:.1}");
        } else {
            w!(path, "H{px:.1}V{py:.1}");
        }
    }
    w!(
        s,
        "<path d=\"{path}\" fill=\"none\" stroke=\"#5b8cc9\" stroke-width=\"1.5\"/>"
    );
    for (t, raw) in pts {
        if range.as_ref().is_some_and(|r| !r.admits(*raw)) {
            w!(
                s,
                "<circle class=\"dot\" cx=\"{:.1}\" cy=\"{:.1}\" r=\"3.5\" fill=\"#d32f2f\"><title>{raw:04X}H at {:.3} s: out of range</title></circle>",
                x(*t),
                y(val(*raw)),
                t
            );
        }
    }
    s.push_str("</svg>");
    s
}

#[cfg(test)]
mod tests {
    use std::sync::Arc;

    use crate::codec::Mode;
    use crate::model::DriveModel;
    use crate::watch::{plan, Watcher};

    /// The y labels of the chart of `register` (the `text-anchor="end"` texts).
    fn y_labels(page: &str, register: &str) -> Vec<String> {
        let at = page.find(&format!("trend-01-{register}")).unwrap();
        let svg = &page[at..at + page[at..].find("</svg>").unwrap()];
        svg.split("text-anchor=\"end\">")
            .skip(1)
            .filter_map(|s| s.split('<').next())
            .filter(|s| *s != "s")
            .map(String::from)
            .collect()
    }

    #[test]
    fn a_chart_labels_each_tick_once_and_no_value_below_zero() {
        let m = Arc::new(DriveModel::builtin("f510").unwrap());
        let p = plan(&m, 1, Mode::Rtu, &[0x2502, 0x2524]).unwrap();
        let mut w = Watcher::new(m, Mode::Rtu, p, &[1]).unwrap();
        for t in [0.0, 0.5, 1.0].iter() {
            w.nodes[0].cells[0].trend.push(*t, 0x9C41);
            w.nodes[0].cells[1].trend.push(*t, 0);
        }
        let page = super::watch_html(&w, "test");
        // 400.01 Hz against the bound 400.00: steps of 0.01, each labelled once.
        let labels = y_labels(&page, "2502");
        let mut unique = labels.clone();
        unique.dedup();
        assert_eq!(labels, unique, "{labels:?}");
        assert!(labels.contains(&"400.01".to_string()), "{labels:?}");
        // A flat 0.00 Hz: no negative frequency on the axis.
        let labels = y_labels(&page, "2524");
        assert!(labels.iter().all(|l| !l.starts_with('-')), "{labels:?}");
        assert!(!page.contains("<script"));
    }
}
