//! The plots of the HTML report, drawn as inline SVG by the suite: the response-time
//! distribution per mode, a timeline of the exchanges, and the register-map grid.

use std::collections::BTreeMap;
use std::fmt::Write;

use crate::report::markup::esc;
use crate::report::Report;
use crate::runner::{CheckResult, Status};

macro_rules! w {
    ($out:expr, $($arg:tt)*) => {{
        // Writing to a String cannot fail.
        let _ = write!($out, $($arg)*);
    }};
}

/// Fill colour of a status (the same in every plot and in the legend).
pub(super) fn colour(s: Status) -> &'static str {
    match s {
        Status::Pass => "#4caf50",
        Status::Deviation => "#d32f2f",
        Status::Observation => "#f0a800",
        Status::Skip => "#b0b0b0",
        Status::Error => "#7b1fa2",
    }
}

/// How bad a status is, for a cell that stands for several checks.
fn rank(s: Status) -> u8 {
    match s {
        Status::Skip => 0,
        Status::Pass => 1,
        Status::Observation => 2,
        Status::Error => 3,
        Status::Deviation => 4,
    }
}

/// A round step for an axis of `span` units with about `ticks` ticks.
pub(super) fn step(span: f64, ticks: f64) -> f64 {
    let raw = (span / ticks).max(1e-9);
    let mag = 10f64.powf(raw.log10().floor());
    let n = raw / mag;
    let m = if n <= 1.0 {
        1.0
    } else if n <= 2.0 {
        2.0
    } else if n <= 5.0 {
        5.0
    } else {
        10.0
    };
    m * mag
}

fn ms(d: std::time::Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

/// Median of a non-empty sorted slice.
pub(crate) fn median(sorted: &[f64]) -> Option<f64> {
    let n = sorted.len();
    if n == 0 {
        return None;
    }
    Some(if n % 2 == 1 {
        sorted[n / 2]
    } else {
        (sorted[n / 2 - 1] + sorted[n / 2]) / 2.0
    })
}

/// Latencies (ms) of the replies of each mode, sorted.
pub(crate) fn latencies(report: &Report) -> BTreeMap<String, Vec<f64>> {
    let mut by_mode: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    for r in &report.results {
        let mode = r
            .mode
            .map(|m| m.to_string())
            .unwrap_or_else(|| "run".into());
        for e in &r.exchanges {
            if let Some(l) = e.latency {
                by_mode.entry(mode.clone()).or_default().push(ms(l));
            }
        }
    }
    for v in by_mode.values_mut() {
        v.sort_by(f64::total_cmp);
    }
    by_mode
}

/// The response-time distribution per mode: a histogram for each, with the manual's
/// response time and the allowance beyond which a reply is late.
pub(super) fn latency_plot(report: &Report) -> String {
    let by_mode = latencies(report);
    if by_mode.is_empty() {
        return "<p class=\"muted\">No reply was timed.</p>".into();
    }
    let manual = report.options.response_time_ms;
    let late = manual
        .zip(report.options.response_allowance_ms)
        .map(|(m, a)| m + a as f64);
    let longest = by_mode
        .values()
        .filter_map(|v| v.last().copied())
        .fold(0.0f64, f64::max);
    let top = longest.max(late.unwrap_or(0.0)).max(1.0) * 1.08;
    let tick = step(top, 8.0);
    let x_max = (top / tick).ceil() * tick;
    let bins = 60usize;
    let bin_w = x_max / bins as f64;
    let (left, right, row_h, gap) = (110.0, 20.0, 90.0, 30.0);
    let width = 900.0;
    let plot_w = width - left - right;
    let height = 20.0 + by_mode.len() as f64 * (row_h + gap) + 20.0;
    let x = |v: f64| left + v / x_max * plot_w;
    let mut s = String::new();
    w!(
        s,
        "<svg id=\"plot-latency\" class=\"plot\" viewBox=\"0 0 {width} {height}\" role=\"img\" aria-label=\"Response time per mode\" xmlns=\"http://www.w3.org/2000/svg\">"
    );
    for (i, (mode, v)) in by_mode.iter().enumerate() {
        let top_y = 20.0 + i as f64 * (row_h + gap);
        let base = top_y + row_h;
        let mut counts = vec![0usize; bins];
        for &l in v {
            let b = ((l / bin_w) as usize).min(bins - 1);
            counts[b] += 1;
        }
        let peak = counts.iter().copied().max().unwrap_or(1).max(1) as f64;
        let med = median(v).unwrap_or(0.0);
        w!(
            s,
            "<text x=\"{}\" y=\"{}\" class=\"lab\" text-anchor=\"end\">{}</text>",
            left - 8.0,
            top_y + row_h / 2.0,
            esc(&mode.to_uppercase())
        );
        w!(
            s,
            "<text x=\"{}\" y=\"{}\" class=\"small\" text-anchor=\"end\">n={}</text>",
            left - 8.0,
            top_y + row_h / 2.0 + 14.0,
            v.len()
        );
        for (b, &c) in counts.iter().enumerate() {
            if c == 0 {
                continue;
            }
            let h = c as f64 / peak * (row_h - 4.0);
            let lo = b as f64 * bin_w;
            let is_late = late.is_some_and(|l| lo >= l);
            w!(
                s,
                "<rect class=\"bar{}\" x=\"{:.1}\" y=\"{:.1}\" width=\"{:.1}\" height=\"{:.1}\"><title>{:.1}–{:.1} ms: {} replies</title></rect>",
                if is_late { " late" } else { "" },
                x(lo) + 0.5,
                base - h,
                (plot_w / bins as f64 - 1.0).max(0.5),
                h,
                lo,
                lo + bin_w,
                c
            );
        }
        w!(
            s,
            "<line class=\"axis\" x1=\"{left}\" y1=\"{base}\" x2=\"{}\" y2=\"{base}\"/>",
            left + plot_w
        );
        w!(
            s,
            "<line class=\"median\" x1=\"{0:.1}\" y1=\"{1}\" x2=\"{0:.1}\" y2=\"{base}\"><title>median {2:.2} ms</title></line><text class=\"small\" x=\"{3}\" y=\"{4}\" text-anchor=\"end\">median {2:.1} ms</text>",
            x(med),
            top_y,
            med,
            left - 8.0,
            top_y + row_h / 2.0 + 28.0
        );
        let mut t = 0.0;
        while t <= x_max + 1e-9 {
            w!(
                s,
                "<line class=\"tick\" x1=\"{0:.1}\" y1=\"{base}\" x2=\"{0:.1}\" y2=\"{1}\"/><text class=\"small\" x=\"{0:.1}\" y=\"{2}\" text-anchor=\"middle\">{3}</text>",
                x(t),
                base + 4.0,
                base + 16.0,
                trim(t)
            );
            t += tick;
        }
    }
    let y0 = 14.0;
    let y1 = height - 30.0;
    if let Some(m) = manual {
        w!(
            s,
            "<line class=\"limit\" x1=\"{0:.1}\" y1=\"{y0}\" x2=\"{0:.1}\" y2=\"{y1}\"/><text class=\"small limit-t\" x=\"{1:.1}\" y=\"{2}\">manual {3} ms</text>",
            x(m),
            x(m) + 3.0,
            y0 + 2.0,
            trim(m)
        );
    }
    if let Some(l) = late {
        w!(
            s,
            "<line class=\"limit late\" x1=\"{0:.1}\" y1=\"{y0}\" x2=\"{0:.1}\" y2=\"{y1}\"/><text class=\"small late-t\" x=\"{1:.1}\" y=\"{2}\">late beyond {3} ms</text>",
            x(l),
            x(l) + 3.0,
            y0 + 2.0,
            trim(l)
        );
    }
    w!(
        s,
        "<text class=\"small\" x=\"{}\" y=\"{}\" text-anchor=\"middle\">time to the first byte of the reply (ms)</text></svg>",
        left + plot_w / 2.0,
        height - 4.0
    );
    s
}

/// A number for an axis or a label: at most two decimals, no trailing zeros.
pub(super) fn trim(v: f64) -> String {
    let s = format!("{v:.2}");
    s.trim_end_matches('0').trim_end_matches('.').to_string()
}

/// A timeline of the exchanges: one dot per exchange at its time in the run (the checks'
/// durations laid end to end, the exchanges of a check spread over its duration) and its
/// latency; an exchange that got no reply is a cross on the axis.
pub(super) fn timeline_plot(report: &Report) -> String {
    let total: f64 = report.results.iter().map(|r| ms(r.duration)).sum();
    let longest = report
        .results
        .iter()
        .flat_map(|r| r.exchanges.iter().filter_map(|e| e.latency.map(ms)))
        .fold(0.0f64, f64::max);
    if report
        .results
        .iter()
        .all(|r| r.exchanges.iter().all(|e| e.latency.is_none()))
    {
        return "<p class=\"muted\">No reply was timed.</p>".into();
    }
    let late = report
        .options
        .response_time_ms
        .zip(report.options.response_allowance_ms)
        .map(|(m, a)| m + a as f64);
    let y_top_v = longest.max(late.unwrap_or(0.0)).max(1.0) * 1.1;
    let ytick = step(y_top_v, 5.0);
    let y_max = (y_top_v / ytick).ceil() * ytick;
    let total = total.max(1.0);
    let xtick = step(total / 1000.0, 10.0);
    let (left, right, top, bottom) = (70.0, 20.0, 14.0, 44.0);
    let (width, height) = (900.0, 260.0);
    let plot_w = width - left - right;
    let plot_h = height - top - bottom;
    let x = |t: f64| left + t / total * plot_w;
    let y = |v: f64| top + plot_h - v / y_max * plot_h;
    let mut s = String::new();
    w!(
        s,
        "<svg id=\"plot-timeline\" class=\"plot\" viewBox=\"0 0 {width} {height}\" role=\"img\" aria-label=\"Timeline of the exchanges\" xmlns=\"http://www.w3.org/2000/svg\">"
    );
    // Mode bands.
    let mut t = 0.0;
    let mut band: Option<(String, f64)> = None;
    let mut bands = Vec::new();
    for r in &report.results {
        let mode = r
            .mode
            .map(|m| m.to_string())
            .unwrap_or_else(|| "run".into());
        match &band {
            Some((m, _)) if *m == mode => {}
            _ => {
                if let Some((m, start)) = band.take() {
                    bands.push((m, start, t));
                }
                band = Some((mode, t));
            }
        }
        t += ms(r.duration);
    }
    if let Some((m, start)) = band {
        bands.push((m, start, t));
    }
    for (i, (m, a, b)) in bands.iter().enumerate() {
        w!(
            s,
            "<rect class=\"band{}\" x=\"{:.1}\" y=\"{top}\" width=\"{:.1}\" height=\"{plot_h}\"/><text class=\"small\" x=\"{:.1}\" y=\"{}\">{}</text>",
            i % 2,
            x(*a),
            (x(*b) - x(*a)).max(0.0),
            x(*a) + 4.0,
            top + 12.0,
            esc(&m.to_uppercase())
        );
    }
    let mut v = 0.0;
    while v <= y_max + 1e-9 {
        w!(
            s,
            "<line class=\"grid\" x1=\"{left}\" y1=\"{0:.1}\" x2=\"{1}\" y2=\"{0:.1}\"/><text class=\"small\" x=\"{2}\" y=\"{3:.1}\" text-anchor=\"end\">{4}</text>",
            y(v),
            left + plot_w,
            left - 6.0,
            y(v) + 4.0,
            trim(v)
        );
        v += ytick;
    }
    let mut sec = 0.0;
    while sec * 1000.0 <= total + 1e-9 {
        w!(
            s,
            "<line class=\"tick\" x1=\"{0:.1}\" y1=\"{1}\" x2=\"{0:.1}\" y2=\"{2}\"/><text class=\"small\" x=\"{0:.1}\" y=\"{3}\" text-anchor=\"middle\">{4}</text>",
            x(sec * 1000.0),
            top + plot_h,
            top + plot_h + 4.0,
            top + plot_h + 16.0,
            trim(sec)
        );
        sec += xtick;
    }
    if let Some(l) = late {
        w!(
            s,
            "<line class=\"limit late\" x1=\"{left}\" y1=\"{0:.1}\" x2=\"{1}\" y2=\"{0:.1}\"/><text class=\"small late-t\" x=\"{2}\" y=\"{3:.1}\" text-anchor=\"end\">late</text>",
            y(l),
            left + plot_w,
            left + plot_w - 2.0,
            y(l) - 3.0
        );
    }
    let mut start = 0.0;
    for r in &report.results {
        let d = ms(r.duration);
        let n = r.exchanges.len();
        for (i, e) in r.exchanges.iter().enumerate() {
            let at = start + d * (i as f64 + 0.5) / n as f64;
            match e.latency {
                Some(l) => w!(
                    s,
                    "<circle class=\"dot\" cx=\"{:.1}\" cy=\"{:.1}\" r=\"2.6\" fill=\"{}\"><title>{} ({}): {:.2} ms</title></circle>",
                    x(at),
                    y(ms(l)),
                    colour(r.status),
                    esc(&r.key()),
                    r.status,
                    ms(l)
                ),
                None => w!(
                    s,
                    "<path class=\"silent\" d=\"M{0:.1} {1:.1}l4 4m0 -4l-4 4\" stroke=\"{2}\"><title>{3} ({4}): no reply</title></path>",
                    x(at) - 2.0,
                    top + plot_h - 6.0,
                    colour(r.status),
                    esc(&r.key()),
                    r.status
                ),
            }
        }
        start += d;
    }
    w!(
        s,
        "<line class=\"axis\" x1=\"{left}\" y1=\"{0}\" x2=\"{1}\" y2=\"{0}\"/><text class=\"small\" x=\"{2}\" y=\"{3}\" text-anchor=\"middle\">time in the run (s; the checks' durations end to end) — dot: a reply's latency (ms), cross: no reply</text><text class=\"small\" transform=\"translate(14 {4}) rotate(-90)\" text-anchor=\"middle\">latency (ms)</text></svg>",
        top + plot_h,
        left + plot_w,
        left + plot_w / 2.0,
        height - 8.0,
        top + plot_h / 2.0
    );
    s
}

/// The columns of the register-map grid: what the part of a check id after the group
/// names, and the column it goes in.
const MAP_COLUMNS: [&str; 7] = [
    "first",
    "last",
    "whole",
    "past-end",
    "gap",
    "no-access",
    "write",
];

/// Places a check in the register-map grid: (mode, group, column).
fn map_cell(r: &CheckResult) -> Option<(String, String, &'static str)> {
    let mut parts = r.id.splitn(3, '.');
    let mode = parts.next()?.to_string();
    let kind = parts.next()?;
    let rest = parts.next()?;
    match kind {
        "map" => {
            let (group, which) = rest.rsplit_once('.')?;
            let col = if which.starts_with("gap-") {
                "gap"
            } else if which.starts_with("no-access-") {
                "no-access"
            } else {
                MAP_COLUMNS.iter().find(|c| **c == which)?
            };
            Some((mode, group.to_string(), col))
        }
        // A write to a group: placed only in a row a map check opened (not the other
        // write checks, whose names are not groups).
        "write" if !rest.contains('.') => Some((mode, rest.to_string(), "write")),
        _ => None,
    }
}

/// The register-map grid: a row per mode and register group, a column per kind of map
/// check, each cell coloured by the worst status of its checks.
pub(super) fn map_grid(report: &Report) -> String {
    type Cell = (Status, Vec<String>);
    let mut rows: Vec<(String, String)> = Vec::new();
    let mut cells: BTreeMap<(String, String, &'static str), Cell> = BTreeMap::new();
    for r in &report.results {
        if let Some((mode, group, col)) = map_cell(r) {
            let key = (mode, group);
            if col != "write" && !rows.contains(&key) {
                rows.push(key);
            }
        }
    }
    for r in &report.results {
        let Some((mode, group, col)) = map_cell(r) else {
            continue;
        };
        if !rows.contains(&(mode.clone(), group.clone())) {
            continue;
        }
        let cell = cells
            .entry((mode, group, col))
            .or_insert((r.status, Vec::new()));
        if rank(r.status) > rank(cell.0) {
            cell.0 = r.status;
        }
        cell.1.push(format!("{}: {}", r.key(), r.status));
    }
    if rows.is_empty() {
        return "<p class=\"muted\">No register-map checks ran.</p>".into();
    }
    let (left, top, cw, ch) = (230.0, 56.0, 76.0, 22.0);
    let width = left + cw * MAP_COLUMNS.len() as f64 + 10.0;
    let height = top + ch * rows.len() as f64 + 10.0;
    let mut s = String::new();
    w!(
        s,
        "<svg id=\"plot-map\" class=\"plot map\" viewBox=\"0 0 {width} {height}\" style=\"max-width:{width}px\" role=\"img\" aria-label=\"Register map checks\" xmlns=\"http://www.w3.org/2000/svg\">"
    );
    for (j, c) in MAP_COLUMNS.iter().enumerate() {
        w!(
            s,
            "<text class=\"lab\" x=\"{:.1}\" y=\"{}\" text-anchor=\"middle\">{}</text>",
            left + cw * (j as f64 + 0.5),
            top - 10.0,
            c
        );
    }
    for (i, (mode, group)) in rows.iter().enumerate() {
        let yy = top + ch * i as f64;
        w!(
            s,
            "<text class=\"lab\" x=\"{}\" y=\"{:.1}\" text-anchor=\"end\">{} {}</text>",
            left - 8.0,
            yy + ch * 0.7,
            esc(&mode.to_uppercase()),
            esc(group)
        );
        for (j, c) in MAP_COLUMNS.iter().enumerate() {
            let xx = left + cw * j as f64;
            match cells.get(&(mode.clone(), group.clone(), *c)) {
                Some((st, ids)) => w!(
                    s,
                    "<rect class=\"cell {}\" x=\"{:.1}\" y=\"{:.1}\" width=\"{}\" height=\"{}\" fill=\"{}\"><title>{}</title></rect>",
                    format!("{st:?}").to_lowercase(),
                    xx + 1.0,
                    yy + 1.0,
                    cw - 2.0,
                    ch - 2.0,
                    colour(*st),
                    esc(&ids.join("\n"))
                ),
                None => w!(
                    s,
                    "<rect class=\"cell none\" x=\"{:.1}\" y=\"{:.1}\" width=\"{}\" height=\"{}\"><title>no such check</title></rect>",
                    xx + 1.0,
                    yy + 1.0,
                    cw - 2.0,
                    ch - 2.0
                ),
            }
        }
    }
    s.push_str("</svg>");
    s
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_steps_are_round() {
        assert_eq!(step(100.0, 10.0), 10.0);
        assert_eq!(step(33.0, 8.0), 5.0);
        assert_eq!(step(0.7, 7.0), 0.1);
    }

    #[test]
    fn medians() {
        assert_eq!(median(&[]), None);
        assert_eq!(median(&[1.0, 2.0, 9.0]), Some(2.0));
        assert_eq!(median(&[1.0, 2.0, 4.0, 9.0]), Some(3.0));
    }
}
