//! HTML: one self-contained file for people (a QA lead, the drive's vendor, an auditor).
//! Inline CSS and SVG, nothing fetched from anywhere, readable offline and printable; a
//! small inline script filters the table of checks (without it every check is shown); a
//! link can preselect the filter: `report.html#status=deviation&mode=rtu&id=map`.
//!
//! Built from the [`Report`], the same data the JSON holds (a saved JSON report is read
//! back with [`Report::from_json`]). Every string that came from a device, a model file
//! or a report file is escaped.

mod coverage;
mod heard;
mod master;
mod nodes;
mod svg;
mod trend;

pub(crate) use svg::{latencies, median};
pub use trend::watch_html;

use std::fmt::Write;

use super::markup::{esc, CSS};
use super::{diff_positions, Report, ReportKind};
use crate::runner::{CheckResult, ExchangeRecord, Status};

macro_rules! w {
    ($out:expr, $($arg:tt)*) => {{
        // Writing to a String cannot fail.
        let _ = write!($out, $($arg)*);
    }};
}

const SCRIPT: &str = r#"
(function(){
var q=document.getElementById('q'),st=document.getElementById('fs'),md=document.getElementById('fm'),n=document.getElementById('shown');
function f(){var t=q.value.toLowerCase(),s=st.value,m=md.value,c=0;
document.querySelectorAll('#checks tbody tr').forEach(function(r){
var ok=(!s||r.dataset.status===s)&&(!m||r.dataset.mode===m)&&(!t||r.dataset.id.toLowerCase().indexOf(t)>=0);
r.style.display=ok?'':'none';if(ok)c++;});n.textContent=c;}
var h=location.hash.slice(1);if(h.indexOf('=')>0){h.split('&').forEach(function(kv){var p=kv.split('='),v=p[1]||'';try{v=decodeURIComponent(v);}catch(e){}if(p[0]==='status')st.value=v;if(p[0]==='mode')md.value=v;if(p[0]==='id')q.value=v;});}
[q,st,md].forEach(function(e){e.addEventListener('input',f);e.addEventListener('change',f);});f();
})();
"#;

fn class(s: Status) -> &'static str {
    match s {
        Status::Pass => "pass",
        Status::Deviation => "deviation",
        Status::Observation => "observation",
        Status::Skip => "skip",
        Status::Error => "error",
    }
}

fn badge(s: Status) -> String {
    format!("<span class=\"badge {}\">{s}</span>", class(s))
}

/// Bytes in hex, the ones at `diff` marked; "nothing" where there are none.
fn hex_marked(bytes: &[u8], diff: &[usize]) -> String {
    super::markup::hex_marked(bytes, diff, "<i class=\"muted\">nothing</i>")
}

fn row(out: &mut String, label: &str, value: &str) {
    w!(out, "<tr><td>{}</td><td>{value}</td></tr>", esc(label));
}

fn exchange(out: &mut String, e: &ExchangeRecord) {
    let diff = match (&e.expected, &e.reply) {
        (Some(x), Some(y)) => diff_positions(x, y),
        (Some(x), None) => (0..x.len()).collect(),
        // A reply where the model predicts none: all of it is unexpected.
        (None, Some(y)) if e.predicted.starts_with("no reply") => (0..y.len()).collect(),
        _ => Vec::new(),
    };
    out.push_str("<div class=\"ex\"><table class=\"frames\">");
    row(out, "request", &hex_marked(&e.request, &[]));
    match &e.expected {
        Some(x) => row(out, "expected", &hex_marked(x, &diff)),
        None => row(out, "expected", &esc(&e.predicted)),
    }
    match &e.reply {
        Some(r) => row(out, "reply", &hex_marked(r, &diff)),
        // Bytes came, but none of them is this request's reply (an echo of another
        // function, a stale reply, garbage): say so, not that nothing was found.
        None if !e.received.is_empty() => row(
            out,
            "reply",
            "<i class=\"muted\">none: what came (below) is no valid reply to this request</i>",
        ),
        None => row(out, "reply", "<i class=\"muted\">no reply frame found</i>"),
    }
    if e.reply.as_deref() != Some(&e.received[..]) {
        row(out, "received", &hex_marked(&e.received, &[]));
    }
    row(
        out,
        "decoded",
        &format!(
            "{} <span class=\"muted\">(predicted: {})</span>",
            esc(&e.actual),
            esc(&e.predicted)
        ),
    );
    row(
        out,
        "latency",
        &match e.latency {
            Some(l) => format!("{:.2} ms", l.as_secs_f64() * 1000.0),
            None => "<i class=\"muted\">no reply</i>".into(),
        },
    );
    out.push_str("</table></div>");
}

fn finding_block(out: &mut String, r: &CheckResult, folded: bool, several: bool, cite: &str) {
    let (open, close) = if folded {
        ("<details><summary>", "</summary>")
    } else {
        ("", "")
    };
    // In a run of several nodes the same check runs on each: its anchor is its key, and
    // its node is named.
    let node = if several {
        format!(
            "<span class=\"node\">{}</span>",
            esc(&nodes::node_label(r.node))
        )
    } else {
        String::new()
    };
    w!(
        out,
        "<article class=\"finding {0}\" id=\"f-{1}\">{open}<h3>{2} {node}<code>{6}</code></h3><div>{3}</div>{close}<div class=\"cite\">{cite}: {4}</div><p>{5}</p>",
        class(r.status),
        esc(&r.key()),
        badge(r.status),
        esc(&r.title),
        esc(&r.source),
        esc(&r.summary),
        esc(&r.id)
    );
    if r.findings.len() > 1 || r.findings.first().is_some_and(|f| f.text != r.summary) {
        out.push_str("<ul>");
        for f in &r.findings {
            w!(out, "<li>{}</li>", esc(&f.text));
        }
        out.push_str("</ul>");
    }
    for e in &r.exchanges {
        exchange(out, e);
    }
    if folded {
        out.push_str("</details>");
    }
    out.push_str("</article>");
}

/// Whether the device was judged by a description file other than a built-in model.
fn described_by_file(report: &Report) -> bool {
    report.device.description.as_ref().is_some_and(|d| {
        d.file.is_some() && !crate::model::MODELS.contains(&report.device.model.as_str())
    })
}

fn header(out: &mut String, report: &Report) {
    let s = report.summary();
    let words = master::words(report);
    let what = match report.kind {
        // A device described by a file of its own is no TECO drive.
        ReportKind::Drive | ReportKind::Fuzz if described_by_file(report) => {
            format!("{} device", report.device.model)
        }
        ReportKind::Monitor if described_by_file(report) => {
            format!("{} devices, heard on the bus", report.device.model)
        }
        ReportKind::Drive | ReportKind::Fuzz => format!("TECO {} drive", report.device.model),
        ReportKind::Monitor => format!("TECO {} drives, heard on the bus", report.device.model),
        ReportKind::Gate => match (&report.codec, report.master.is_some()) {
            (Some(c), true) => format!("master {} {}", c.implementation, c.version),
            (Some(c), false) => format!("codec {} {}", c.implementation, c.version),
            (None, _) => "codec".into(),
        },
    };
    let report_of = match report.kind {
        ReportKind::Monitor => "Modbus bus monitor report",
        ReportKind::Gate if report.master.is_some() => "Modbus master gate report",
        _ => "Modbus conformance report",
    };
    w!(out, "<h1>{report_of}: {}</h1>", esc(&what));
    let (cls, verdict) = if !report.complete {
        (
            "incomplete",
            format!(
                "INCOMPLETE{}",
                report
                    .stopped
                    .as_deref()
                    .map(|s| format!(": {}", esc(s)))
                    .unwrap_or_default()
            ),
        )
    } else if s.deviation > 0 {
        (
            "bad",
            format!(
                "{} deviation{} {}",
                s.deviation,
                if s.deviation == 1 { "" } else { "s" },
                words.from
            ),
        )
    } else if s.error > 0 {
        (
            "incomplete",
            format!(
                "{} {} could not tell",
                s.error,
                if s.error == 1 { words.one } else { words.many }
            ),
        )
    } else {
        ("ok", format!("No deviations {}", words.from))
    };
    w!(
        out,
        "<div class=\"verdict {cls}\" id=\"verdict\">{verdict}</div> <span class=\"muted\" id=\"exit\">exit code {}: {}</span>",
        report.exit_code(),
        esc(&report.exit_reason())
    );
    out.push_str("<div class=\"tiles\" id=\"summary\">");
    for (name, c, n) in [
        (words.many, "", s.total),
        ("pass", "pass", s.pass),
        ("deviations", "deviation", s.deviation),
        ("observations", "observation", s.observation),
        ("skipped", "skip", s.skip),
        ("errors", "error", s.error),
    ] {
        w!(out, "<div class=\"tile {c}\"><b>{n}</b>{name}</div>");
    }
    out.push_str("</div><div class=\"facts\"><table>");
    match report.kind {
        ReportKind::Drive | ReportKind::Fuzz | ReportKind::Monitor => {
            let d = &report.device;
            row(out, "model", &esc(&d.model));
            row(out, "manual", &esc(&d.manual));
            if let Some(s) = &d.description {
                row(
                    out,
                    "description",
                    &format!(
                        "{}<br>{}<br><span class=\"muted\">sha256 {}</span>",
                        esc(s.file_or_builtin()),
                        esc(&s.title),
                        esc(&s.sha256)
                    ),
                );
            }
            if d.nodes.is_empty() && report.kind == ReportKind::Monitor {
                row(out, "node addresses", "<i>no node heard</i>");
            } else if d.nodes.is_empty() {
                row(out, "node address", &format!("{:02X}H", d.address));
                if let Some(id) = d.identification {
                    row(out, "identification", &format!("{id:04X}H"));
                }
            } else {
                row(
                    out,
                    "node addresses",
                    &format!(
                        "{} (<a href=\"#nodes-h\">{} node{} on one bus</a>)",
                        d.nodes
                            .iter()
                            .map(|n| format!("{:02X}H", n.address))
                            .collect::<Vec<_>>()
                            .join(", "),
                        d.nodes.len(),
                        if d.nodes.len() == 1 { "" } else { "s" }
                    ),
                );
            }
            row(
                out,
                "device",
                &match &d.simulated {
                    None if report.kind == ReportKind::Monitor => {
                        "the drives heard on the bus (listened to, never written to)".into()
                    }
                    None => "a real drive".into(),
                    Some(q) if q.is_empty() => "this suite's simulator".into(),
                    Some(q) => format!(
                        "this suite's simulator, with quirks: <b>{}</b>",
                        esc(&q.join(", "))
                    ),
                },
            );
            row(out, "line", &esc(&d.line));
            for (mode, link) in &d.links {
                row(out, &format!("link ({mode})"), &esc(link));
            }
        }
        ReportKind::Gate => {
            if let Some(c) = &report.codec {
                row(out, "adapter", &esc(&c.adapter));
                row(
                    out,
                    "implementation",
                    &esc(&format!("{} {}", c.implementation, c.version)),
                );
                row(out, "command", &format!("<code>{}</code>", esc(&c.command)));
                row(out, "supports", &esc(&c.supports.join(", ")));
                match &report.master {
                    // A master: its settings (what was found has a section of its own).
                    Some(m) => {
                        for l in m.settings_lines() {
                            row(out, "master", &esc(&l));
                        }
                    }
                    None => row(
                        out,
                        "differential cases",
                        &format!("{} (seed {:#x})", c.count, c.seed),
                    ),
                }
                for i in &c.incidents {
                    row(out, "incident", &esc(i));
                }
            }
        }
    }
    out.push_str("</table><table>");
    row(out, "started", &esc(&report.started));
    row(
        out,
        "finished",
        &report
            .finished
            .as_deref()
            .map(esc)
            .unwrap_or_else(|| "<i>not finished</i>".into()),
    );
    let o = &report.options;
    if !o.modes.is_empty() {
        row(
            out,
            "modes",
            &esc(&o
                .modes
                .iter()
                .map(|m| m.to_string().to_uppercase())
                .collect::<Vec<_>>()
                .join(", ")),
        );
    }
    let mut flags = Vec::new();
    if o.read_only {
        flags.push("read-only");
    }
    if o.allow_motion {
        flags.push("motion allowed");
    }
    row(
        out,
        "options",
        &esc(&format!(
            "{}{}{}",
            report.timeout_phrase(),
            if flags.is_empty() { "" } else { ", " },
            flags.join(", ")
        )),
    );
    if let Some(m) = o.response_time_ms {
        row(
            out,
            "response time",
            &format!(
                "{m:.1} ms (manual){}",
                o.response_allowance_ms
                    .map(|a| format!(", late beyond {:.1} ms (allowance {a} ms)", m + a as f64))
                    .unwrap_or_default()
            ),
        );
    }
    if !o.only.is_empty() {
        row(out, "only", &esc(&o.only.join(", ")));
    }
    row(
        out,
        "suite",
        &esc(&format!(
            "{} {}",
            env!("CARGO_PKG_NAME"),
            env!("CARGO_PKG_VERSION")
        )),
    );
    out.push_str("</table></div>");
    if !report.budget.is_empty() {
        out.push_str("<h2 id=\"budget\">Line budget</h2><table class=\"budget\"><thead><tr><th>mode</th><th class=\"num\">wall</th><th class=\"num\">line's bound</th><th class=\"num\">efficiency</th><th class=\"num\">frames</th><th class=\"num\">bytes sent / received</th><th class=\"num\">silences</th><th class=\"num\">mean response</th><th class=\"num\">longest response</th></tr></thead><tbody>");
        for (mode, b) in &report.budget {
            let replies = b.line.frames.saturating_sub(b.line.silences).max(1);
            w!(
                out,
                "<tr><td>{}</td><td class=\"num\">{:.1} s</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{} / {}</td><td class=\"num\">{}</td><td class=\"num\">{:.1} ms</td><td class=\"num\">{:.1} ms</td></tr>",
                esc(&mode.to_uppercase()),
                b.wall.as_secs_f64(),
                // No bound behind a Modbus TCP gateway (the line's timing is its own) or
                // on a pseudo-terminal (no line timing at all).
                match b.no_bound {
                    Some(why) => format!("<span title=\"{}\">{}</span>", esc(why.reason()), why.short()),
                    None => format!("{:.1} s", b.bound.as_secs_f64()),
                },
                if b.no_bound.is_some() || b.bound.is_zero() {
                    "-".to_string()
                } else {
                    format!("{:.0} %", b.efficiency() * 100.0)
                },
                b.line.frames,
                b.line.bytes_sent,
                b.line.bytes_received,
                b.line.silences,
                b.line.response.as_secs_f64() * 1000.0 / replies as f64,
                b.line.max_response.as_secs_f64() * 1000.0
            );
        }
        out.push_str("</tbody></table><p class=\"muted\">The line's bound: what the bytes on the wire, the gaps between frames, the device's response delays and the silences where no reply comes need at the line's speed; efficiency is the bound over the wall time.</p>");
    }
}

fn legend(out: &mut String) {
    out.push_str("<div class=\"legend\">");
    for s in [
        Status::Pass,
        Status::Deviation,
        Status::Observation,
        Status::Skip,
        Status::Error,
    ] {
        w!(
            out,
            "<span><i style=\"background:{}\"></i>{s}</span>",
            svg::colour(s)
        );
    }
    out.push_str("</div>");
}

fn worst_latency(r: &CheckResult) -> String {
    r.exchanges
        .iter()
        .filter_map(|e| e.latency)
        .max()
        .map(|l| format!("{:.1}", l.as_secs_f64() * 1000.0))
        .unwrap_or_default()
}

/// The report as one self-contained HTML page.
pub fn html(report: &Report) -> String {
    let mut out = String::with_capacity(64 * 1024 + report.results.len() * 600);
    let several = !report.device.nodes.is_empty();
    let title = match report.kind {
        ReportKind::Drive | ReportKind::Fuzz => {
            format!("Conformance report: {}", report.device.model)
        }
        ReportKind::Monitor => format!("Bus monitor report: {}", report.device.model),
        ReportKind::Gate if report.master.is_some() => match &report.codec {
            Some(c) => format!("Master gate report: {}", c.implementation),
            None => "Master gate report".to_string(),
        },
        ReportKind::Gate => "Conformance report: codec gate".to_string(),
    };
    w!(
        out,
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><meta name=\"viewport\" content=\"width=device-width,initial-scale=1\"><title>{}</title><style>{CSS}{}</style></head><body><main>",
        esc(&title),
        if several { nodes::CSS } else { "" }
    );
    let drive = report.kind == ReportKind::Drive;
    out.push_str("<nav class=\"toc\">");
    if several {
        out.push_str("<a href=\"#nodes-h\">Nodes</a> · ");
    }
    let s = report.summary();
    if report.master.as_ref().is_some_and(|m| !m.kinds.is_empty()) {
        out.push_str("<a href=\"#found\">Found by kind</a> · ");
    }
    out.push_str("<a href=\"#deviations\">Deviations</a> · ");
    // The section is there only when there are observations.
    if s.observation > 0 {
        out.push_str("<a href=\"#observations\">Observations</a> · ");
    }
    if drive {
        out.push_str("<a href=\"#plots\">Response time</a> · <a href=\"#timeline\">Timeline</a> · <a href=\"#map\">Register map</a> · <a href=\"#coverage\">Requirements</a> · ");
    }
    w!(
        out,
        "<a href=\"#all\">Every {}</a>",
        master::words(report).one
    );
    if report.writes() {
        out.push_str(" · <a href=\"#restore\">Restore journal</a>");
    }
    out.push_str("</nav>");
    header(&mut out, report);
    if several {
        nodes::table(&mut out, report);
    }

    if let Some(m) = &report.master {
        out.push_str(&master::section(m, |id| {
            report.results.iter().any(|r| {
                r.id == id
                    && matches!(
                        r.status,
                        Status::Deviation | Status::Error | Status::Observation
                    )
            })
        }));
    }

    // What the run could not tell first (an ERROR is what makes the exit code 2, and a
    // reader looks for why before anything else), then deviations; observations (the
    // manual is silent) after them, folded.
    // With an expectations file, the results it accepts have a section of their own.
    let mut notable: Vec<&CheckResult> = report
        .results
        .iter()
        .filter(|r| matches!(r.status, Status::Deviation | Status::Error))
        .filter(|r| !report.is_expected(r))
        .collect();
    w!(
        out,
        "<h2 id=\"deviations\">Errors ({}) and {} ({})</h2>",
        s.error,
        if report.expect.is_some() {
            "new deviations"
        } else {
            "deviations"
        },
        notable.len() - s.error,
    );
    notable.sort_by_key(|r| r.status != Status::Error);
    let words = master::words(report);
    if notable.is_empty() {
        w!(out, "<p>{}</p>", words.none);
    }
    for r in notable {
        finding_block(&mut out, r, false, several, words.cite);
    }
    if let Some(e) = &report.expect {
        super::expect_html::section(&mut out, report, e, |out, r| {
            finding_block(out, r, true, several, words.cite)
        });
    }
    if s.observation > 0 {
        w!(
            out,
            "<h2 id=\"observations\">Observations ({})</h2><p class=\"muted\">Where the manual is silent or contradicts itself: what the device did (click one for its frames).</p>",
            s.observation
        );
        for r in report
            .results
            .iter()
            .filter(|r| r.status == Status::Observation)
        {
            finding_block(&mut out, r, true, several, words.cite);
        }
    }

    if let Some(m) = &report.monitor {
        let o = &report.options;
        let late = o
            .response_time_ms
            .zip(o.response_allowance_ms)
            .map(|(m, a)| m + a as f64);
        out.push_str(&heard::section(m, (o.response_time_ms, late)));
    }

    // A gate's cases are not timed exchanges with a device: no plots.
    if drive {
        out.push_str("<h2 id=\"plots\">Response time</h2><p class=\"muted\">How long the device took to start each reply, per mode, against the manual's response time and the allowance beyond which a reply counts as late.</p>");
        out.push_str(&svg::latency_plot(report));
        out.push_str("<h2 id=\"timeline\">Timeline of the exchanges</h2>");
        legend(&mut out);
        out.push_str(&svg::timeline_plot(report));
        out.push_str("<h2 id=\"map\">Register map</h2><p class=\"muted\">Each register group (block) against the map checks: its first and last register, the whole block, one past its end, the gaps inside it, registers without access, and a write to the group; a cell is coloured by the worst status of its checks (hover for the ids).</p>");
        legend(&mut out);
        out.push_str(&svg::map_grid(report));
        out.push_str(&coverage::section(report));
    }

    let mut modes: Vec<String> = report
        .results
        .iter()
        .map(|r| {
            r.mode
                .map(|m| m.to_string())
                .unwrap_or_else(|| "run".into())
        })
        .collect();
    modes.dedup();
    modes.sort();
    modes.dedup();
    w!(
        out,
        "<h2 id=\"all\">Every {} ({})</h2><div class=\"controls\"><label>id contains <input id=\"q\" type=\"search\" placeholder=\"e.g. map.group\"></label><label>status <select id=\"fs\"><option value=\"\">any</option>",
        master::words(report).one,
        report.results.len()
    );
    for st in [
        Status::Deviation,
        Status::Error,
        Status::Observation,
        Status::Pass,
        Status::Skip,
    ] {
        w!(out, "<option value=\"{}\">{st}</option>", class(st));
    }
    out.push_str("</select></label><label>mode <select id=\"fm\"><option value=\"\">any</option>");
    for m in &modes {
        w!(out, "<option value=\"{0}\">{0}</option>", esc(m));
    }
    out.push_str("</select></label>");
    if several {
        nodes::select(&mut out, report);
    }
    w!(
        out,
        "<span class=\"muted\"><span id=\"shown\">{}</span> shown</span></div>",
        report.results.len()
    );
    if several {
        out.push_str("<table id=\"checks\" class=\"nodes\"><thead><tr><th>id</th><th>node</th><th>mode</th><th>status</th><th>title</th><th>summary</th><th class=\"num\">latency (ms)</th></tr></thead><tbody>");
    } else {
        out.push_str("<table id=\"checks\"><thead><tr><th>id</th><th>mode</th><th>status</th><th>title</th><th>summary</th><th class=\"num\">latency (ms)</th></tr></thead><tbody>");
    }
    for r in &report.results {
        let mode = r
            .mode
            .map(|m| m.to_string())
            .unwrap_or_else(|| "run".into());
        let id = esc(&r.id);
        let link = if matches!(r.status, Status::Pass | Status::Skip) {
            id.clone()
        } else {
            format!("<a href=\"#f-{}\">{id}</a>", esc(&r.key()))
        };
        let node = if several {
            let v = nodes::node_value(r);
            format!(" data-node=\"{v}\"><td class=\"id\">{link}</td><td class=\"id\">{v}</td")
        } else {
            format!("><td class=\"id\">{link}</td")
        };
        w!(
            out,
            "<tr class=\"{c}\" data-id=\"{id}\" data-status=\"{c}\" data-mode=\"{m}\"{node}><td>{m}</td><td>{b}</td><td>{t}<div class=\"muted\">{src}</div>{reqs}</td><td>{sum}</td><td class=\"num\">{lat}</td></tr>",
            c = class(r.status),
            m = esc(&mode),
            b = badge(r.status) + &super::expect_html::tag(report, r),
            t = esc(&r.title),
            src = esc(&r.source),
            sum = esc(&r.summary),
            lat = worst_latency(r),
            reqs = if drive {
                coverage::links(report, &r.id)
            } else {
                String::new()
            }
        );
    }
    out.push_str("</tbody></table>");

    // A monitor only listens and a gate talks to no drive: no register to restore, and
    // no section saying so.
    if report.writes() {
        restore_section(&mut out, report, several);
    }
    w!(
        out,
        "<footer>Generated by {} {} from the run's report data (the same as its JSON report). Offline and self-contained.</footer></main><script>{}</script></body></html>\n",
        env!("CARGO_PKG_NAME"),
        env!("CARGO_PKG_VERSION"),
        if several { nodes::SCRIPT } else { SCRIPT }
    );
    out
}

/// The restore journal: each register the run changed, its original value and whether it
/// was restored.
fn restore_section(out: &mut String, report: &Report, several: bool) {
    out.push_str("<h2 id=\"restore\">Restore journal</h2>");
    if report.restore.is_empty() {
        out.push_str("<p>No register was changed, so none needed restoring.</p>");
    } else {
        out.push_str(if several {
            "<table id=\"restore-t\"><thead><tr><th>node</th><th>register</th><th>original value</th><th>restored</th><th>detail</th></tr></thead><tbody>"
        } else {
            "<table><thead><tr><th>register</th><th>original value</th><th>restored</th><th>detail</th></tr></thead><tbody>"
        });
        for r in &report.restore {
            if several {
                w!(
                    out,
                    "<tr><td class=\"id\">{}</td>",
                    r.node.map(|n| format!("{n:02X}H")).unwrap_or_default()
                );
            } else {
                out.push_str("<tr>");
            }
            w!(
                out,
                "<td class=\"id\">{:04X}H</td><td class=\"id\">{:04X}H</td><td>{}</td><td>{}</td></tr>",
                r.register,
                r.original,
                if r.restored && !r.changed {
                    badge(Status::Pass).replace("PASS", "unchanged")
                } else if r.restored {
                    badge(Status::Pass).replace("PASS", "yes")
                } else {
                    badge(Status::Deviation).replace("DEVIATION", "NOT RESTORED")
                },
                esc(&r.detail)
            );
        }
        out.push_str("</tbody></table>");
    }
}

/// The in-page links of `page` (`href="#x"`) that land on no element (`id="x"`), in
/// order: a check that a rendered report's table of contents and cross-links hold. A
/// fragment `key=value` (`#node=05&status=deviation`) is a filter the page's script
/// reads, not an anchor, and is left out.
pub fn unresolved_links(page: &str) -> Vec<String> {
    let after = |pat: &'static str| page.split(pat).skip(1).filter_map(|s| s.split('"').next());
    let ids: std::collections::BTreeSet<&str> = after("id=\"").collect();
    after("href=\"#")
        .filter(|h| !h.contains('=') && !ids.contains(h))
        .map(str::to_string)
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::Mode;
    use crate::runner::{Finding, Severity};

    /// Every in-page link of a rendered report lands on its section or row: one node, several
    /// nodes, and a run with no observations (whose table of contents has no link to them).
    #[test]
    fn every_in_page_link_lands() {
        use crate::report::fixtures::{one_node, several_nodes};
        let mut quiet = one_node();
        quiet.results.retain(|r| r.status != Status::Observation);
        for (name, r) in [
            ("one node", one_node()),
            ("several", several_nodes()),
            ("no observations", quiet),
        ] {
            let page = html(&r);
            assert!(page.contains("href=\"#"), "{name}");
            assert_eq!(unresolved_links(&page), Vec::<String>::new(), "{name}");
        }
        assert_eq!(
            unresolved_links(
                "<a href=\"#a\"></a><h2 id=\"a\"></h2><a href=\"#b\"></a><a href=\"#node=05\"></a>"
            ),
            ["b"]
        );
    }

    fn hostile() -> Report {
        let evil = "<script>alert(1)</script>";
        Report {
            started: evil.into(),
            complete: true,
            device: crate::report::Device {
                model: evil.into(),
                manual: "\"quoted\" & 'single'".into(),
                line: evil.into(),
                simulated: Some(vec![evil.into()]),
                ..Default::default()
            },
            results: vec![CheckResult {
                id: "rtu.map.<img src=x onerror=alert(1)>.first".into(),
                title: evil.into(),
                mode: Some(Mode::Rtu),
                source: evil.into(),
                status: Status::Deviation,
                summary: evil.into(),
                findings: vec![Finding {
                    severity: Severity::Deviation,
                    text: evil.into(),
                }],
                exchanges: vec![ExchangeRecord {
                    request: vec![1, 3, 0, 0, 0, 1, 0x84, 0x0A],
                    expected: Some(vec![1, 3, 2, 0, 0, 0xB8, 0x44]),
                    received: vec![1, 3, 2, 0, 1, 0x79, 0x84],
                    reply: Some(vec![1, 3, 2, 0, 1, 0x79, 0x84]),
                    predicted: evil.into(),
                    actual: evil.into(),
                    latency: Some(std::time::Duration::from_millis(7)),
                }],
                duration: std::time::Duration::from_millis(20),
                node: None,
            }],
            ..Report::default()
        }
    }

    #[test]
    fn everything_from_a_device_or_a_file_is_escaped() {
        let page = html(&hostile());
        assert!(!page.contains("<script>alert"), "unescaped script");
        assert!(!page.contains("<img"), "unescaped tag");
        assert!(page.contains("&lt;script&gt;alert(1)&lt;/script&gt;"));
        assert!(page.contains("&quot;quoted&quot; &amp; &#39;single&#39;"));
        // The only script is the page's own filter.
        assert_eq!(page.matches("<script>").count(), 1);
    }

    #[test]
    fn differing_bytes_are_marked() {
        let page = html(&hostile());
        // Expected 00 00 B8 44 against 00 01 79 84: the last three bytes differ.
        assert!(page.contains(
            "01 03 02 00 <span class=\"d\">00</span> <span class=\"d\">B8</span> <span class=\"d\">44</span>"
        ));
        assert!(page.contains(
            "01 03 02 00 <span class=\"d\">01</span> <span class=\"d\">79</span> <span class=\"d\">84</span>"
        ));
        assert!(page.contains("7.00 ms"));
    }

    #[test]
    fn a_gate_report_has_no_device_plots() {
        let mut r = hostile();
        r.kind = ReportKind::Gate;
        let page = html(&r);
        assert!(!page.contains("<svg"));
        assert!(!page.contains("href=\"#map\""));
        assert!(page.contains("data-id=\"rtu.map."));
        let drive = html(&hostile());
        for plot in ["plot-latency", "plot-timeline", "plot-map"] {
            assert!(drive.contains(&format!("<svg id=\"{plot}\"")), "{plot}");
        }
    }

    /// Issue 33, item 9: a run that never writes (a master gate, a monitor) has no
    /// restore journal, nor a link to one, and its page is titled by what it is; a drive's
    /// run keeps both.
    #[test]
    fn a_run_that_never_writes_has_no_restore_journal_and_its_own_title() {
        let mut gate = hostile();
        gate.kind = ReportKind::Gate;
        gate.codec = Some(crate::report::Codec {
            implementation: "pymodbus".into(),
            version: "3.16.1".into(),
            ..Default::default()
        });
        gate.master = Some(crate::gate::master::MasterSummary::default());
        let mut monitor = hostile();
        monitor.kind = ReportKind::Monitor;
        monitor.device.model = "f510".into();
        for (r, title, h1) in [
            (
                &gate,
                "Master gate report: pymodbus",
                "Modbus master gate report: master pymodbus 3.16.1",
            ),
            (
                &monitor,
                "Bus monitor report: f510",
                "Modbus bus monitor report: TECO f510 drives, heard on the bus",
            ),
        ] {
            let page = html(r);
            assert!(!page.contains("Restore journal"), "{title}");
            assert!(!page.contains("#restore"), "{title}");
            assert!(page.contains(&format!("<title>{title}</title>")), "{title}");
            assert!(page.contains(&format!("<h1>{h1}</h1>")), "{title}");
        }
        let drive = html(&hostile());
        assert!(drive.contains("<h2 id=\"restore\">Restore journal</h2>"));
        assert!(drive.contains("href=\"#restore\""));
    }

    #[test]
    fn the_page_holds_nothing_fetched() {
        let page = html(&hostile());
        for outside in ["http://", "https://", "src=\"", "@import", "url("] {
            let hits: Vec<_> = page
                .match_indices(outside)
                .filter(|(i, _)| !page[..*i].ends_with("xmlns=\""))
                .collect();
            assert!(hits.is_empty(), "{outside} in the page");
        }
    }
}
