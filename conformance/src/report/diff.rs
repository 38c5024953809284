//! What changed between two runs of the same model (two firmware versions of one drive,
//! or a drive before and after a repair): checks whose status changed (the ones that got
//! worse first), deviations whose received bytes changed, response-time shifts beyond
//! noise, and checks present in one run only.
//!
//! Checks are matched by their key ([`CheckResult::key`]): the id, and the node in a run of
//! several nodes on one bus, so the same check on two nodes is two checks. A run of one
//! node is compared with a run of several nodes only through one node of it
//! ([`Diff::for_node`]): that node's checks, and the checks of the whole bus, which a run
//! of one node has too; [`Diff::new`] refuses the pair.
//!
//! Noise: the median latencies of a mode (or of one check) differ by more than
//! [`NOISE_RATIO`] of the old median or [`NOISE_MS`], whichever is larger. A pseudo
//! terminal or a USB adapter moves single replies by a few milliseconds; a median that
//! moves by more than both is a change in the device. A check's own median is compared
//! only where both runs timed at least [`MIN_REPLIES`] of its replies.

use std::collections::{BTreeMap, BTreeSet};
use std::fmt::Write;

use serde_json::{json, Value};

use super::markup::{esc, hex_marked, CSS};
use super::{Report, ReportKind};
use crate::codec::hex::Hex;
use crate::expect::MarkKind;
use crate::runner::{CheckResult, Status};

/// A shift of the median smaller than this share of the old median is noise.
pub const NOISE_RATIO: f64 = 0.20;
/// A shift of the median smaller than this is noise (ms).
pub const NOISE_MS: f64 = 5.0;
/// A check's median is compared only when both runs timed at least this many of its
/// replies (one reply on a busy host moves by more than the noise bound).
pub const MIN_REPLIES: usize = 3;

macro_rules! w {
    ($out:expr, $($arg:tt)*) => {{
        // Writing to a String cannot fail.
        let _ = write!($out, $($arg)*);
    }};
}

/// Why two reports cannot be compared.
#[derive(Debug, thiserror::Error)]
pub enum DiffError {
    /// The reports are about different models.
    #[error("the reports are about different models: {old} (old) and {new} (new)")]
    DifferentModels {
        /// The old report's model.
        old: String,
        /// The new report's.
        new: String,
    },
    /// One is a drive report, the other a gate report.
    #[error("one report is of a drive, the other of a codec gate")]
    DifferentKinds,
    /// One report is of a run of one node, the other of several: their checks are keyed
    /// differently, and which node to compare is not known.
    #[error("the {several} report is of a run of several nodes ({nodes}), the other of one node ({one:02X}H): give --node N to compare node N's checks (and the bus checks) of the run of several nodes with the run of one node")]
    OneAndSeveralNodes {
        /// "old" or "new": the report of several nodes.
        several: &'static str,
        /// Its nodes ("01H 02H 05H").
        nodes: String,
        /// The node of the other.
        one: u8,
    },
    /// The node asked for is not one of a run of several nodes.
    #[error("node {node:02X}H ({node}) is not one of the {which} report's nodes ({nodes})")]
    NoSuchNode {
        /// The node asked for.
        node: u8,
        /// "old" or "new".
        which: &'static str,
        /// Its nodes.
        nodes: String,
    },
}

/// "01H 02H 05H".
fn node_list(r: &Report) -> String {
    r.device
        .nodes
        .iter()
        .map(|n| format!("{:02X}H", n.address))
        .collect::<Vec<_>>()
        .join(" ")
}

/// One node's section of a run of several nodes, as the run of that one node would have
/// reported it: its checks (keyed by id alone) and the checks of the whole bus, its
/// restored registers, its identification. A run of one node is returned as it is.
pub fn node_section(r: &Report, node: u8, which: &'static str) -> Result<Report, DiffError> {
    if r.device.nodes.is_empty() {
        return Ok(r.clone());
    }
    let Some(info) = r.device.nodes.iter().find(|n| n.address == node) else {
        return Err(DiffError::NoSuchNode {
            node,
            which,
            nodes: node_list(r),
        });
    };
    let mut out = r.clone();
    out.results = r
        .results
        .iter()
        .filter(|c| c.node.is_none() || c.node == Some(node))
        .cloned()
        .map(|mut c| {
            c.node = None;
            c
        })
        .collect();
    out.restore = r
        .restore
        .iter()
        .filter(|x| x.node == Some(node))
        .cloned()
        .map(|mut x| {
            x.node = None;
            x
        })
        .collect();
    out.device.address = node;
    out.device.identification = info.identification;
    out.device.nodes.clear();
    // Marks are keyed like the results: this node's lose their `@N`.
    if let Some(e) = out.expect.as_mut() {
        let suffix = format!("@{node}");
        e.marks = std::mem::take(&mut e.marks)
            .into_iter()
            .filter_map(|(k, m)| match k.strip_suffix(&suffix) {
                Some(id) => Some((id.to_string(), m)),
                None if !k.contains('@') => Some((k, m)),
                None => None,
            })
            .collect();
    }
    Ok(out)
}

/// How bad a status is: a check got worse when this grows.
fn badness(s: Status) -> u8 {
    match s {
        Status::Pass | Status::Skip => 0,
        Status::Observation => 1,
        Status::Error => 2,
        Status::Deviation => 3,
    }
}

/// A check whose status changed.
#[derive(Debug, Clone, PartialEq)]
pub struct StatusChange {
    /// Check key: its id, with `@N` for node N of a run of several nodes.
    pub id: String,
    /// What it does.
    pub title: String,
    /// Status in the old run.
    pub old: Status,
    /// Status in the new run.
    pub new: Status,
    /// The new run's summary of it.
    pub summary: String,
    /// How the new run's expectations file (`--expect`) marks it, if it names it.
    pub expectation: Option<MarkKind>,
}

impl StatusChange {
    /// Whether the check got worse: its status did, and the new run's expectations do
    /// not accept the new status.
    pub fn worse(&self) -> bool {
        badness(self.new) > badness(self.old) && self.expectation != Some(MarkKind::Expected)
    }
}

/// A deviation whose received bytes changed.
#[derive(Debug, Clone, PartialEq)]
pub struct BytesChange {
    /// Check key (see [`StatusChange::id`]).
    pub id: String,
    /// Which exchange of the check (0-based).
    pub exchange: usize,
    /// The request (new run).
    pub request: Vec<u8>,
    /// Received in the old run.
    pub old: Vec<u8>,
    /// Received in the new run.
    pub new: Vec<u8>,
}

/// A median response time that moved beyond noise.
#[derive(Debug, Clone, PartialEq)]
pub struct TimingShift {
    /// A mode ("rtu") or a check key.
    pub what: String,
    /// Old median, ms.
    pub old_ms: f64,
    /// New median, ms.
    pub new_ms: f64,
    /// Replies timed in the old run.
    pub old_n: usize,
    /// In the new run.
    pub new_n: usize,
}

impl TimingShift {
    /// Whether the device got slower.
    pub fn worse(&self) -> bool {
        self.new_ms > self.old_ms
    }
}

/// Whether two medians differ by more than noise.
pub fn beyond_noise(old_ms: f64, new_ms: f64) -> bool {
    (new_ms - old_ms).abs() > (old_ms * NOISE_RATIO).max(NOISE_MS)
}

/// The differences between two runs.
#[derive(Debug, Clone, Default)]
pub struct Diff {
    /// Old run: model, start time, summary line.
    pub old_label: String,
    /// New run.
    pub new_label: String,
    /// Status changes, the ones that got worse first (new deviations first among them).
    pub status: Vec<StatusChange>,
    /// Deviations in both runs whose received bytes changed.
    pub bytes: Vec<BytesChange>,
    /// Median response times per mode and per check that moved beyond noise.
    pub timing: Vec<TimingShift>,
    /// Checks only the old run has, with their status.
    pub only_old: Vec<(String, Status)>,
    /// Checks only the new run has.
    pub only_new: Vec<(String, Status)>,
    /// The new run's expectations (`--expect`): its file and one line of counts.
    pub expect_line: Option<String>,
    /// Keys of the new run's results its expectations accept as they are.
    pub expected_new: BTreeSet<String>,
}

fn label(r: &Report) -> String {
    let s = r.summary();
    let what = match r.kind {
        ReportKind::Drive | ReportKind::Fuzz | ReportKind::Monitor => {
            let mut w = r.device.model.clone();
            if let Some(q) = r.device.simulated.as_ref().filter(|q| !q.is_empty()) {
                w.push_str(&format!(" (simulator, quirks: {})", q.join(", ")));
            }
            w
        }
        ReportKind::Gate => r
            .codec
            .as_ref()
            .map(|c| format!("{} {}", c.implementation, c.version))
            .unwrap_or_else(|| "codec".into()),
    };
    format!(
        "{what}, started {}: {} checks, {} deviations, {} errors",
        r.started, s.total, s.deviation, s.error
    )
}

fn check_latencies(r: &CheckResult) -> Vec<f64> {
    let mut v: Vec<f64> = r
        .exchanges
        .iter()
        .filter_map(|e| e.latency.map(|l| l.as_secs_f64() * 1000.0))
        .collect();
    v.sort_by(f64::total_cmp);
    v
}

impl Diff {
    /// Compares one node of two runs of the same model: the node's section of a run of
    /// several nodes (see [`node_section`]); a run of one node is taken as it is, whatever
    /// its address.
    pub fn for_node(old: &Report, new: &Report, node: u8) -> Result<Diff, DiffError> {
        let section = |r: &Report, which| -> Result<(Report, String), DiffError> {
            let label = if r.device.nodes.is_empty() {
                label(r)
            } else {
                format!(
                    "node {node:02X}H (its checks and the bus checks) of a run of nodes {}: {}",
                    node_list(r),
                    label(&node_section(r, node, which)?)
                )
            };
            Ok((node_section(r, node, which)?, label))
        };
        let (o, ol) = section(old, "old")?;
        let (n, nl) = section(new, "new")?;
        let mut d = Diff::new(&o, &n)?;
        d.old_label = ol;
        d.new_label = nl;
        Ok(d)
    }

    /// Compares two runs of the same model, both of one node or both of several (checks
    /// matched by key: a node's check with the same node's).
    pub fn new(old: &Report, new: &Report) -> Result<Diff, DiffError> {
        if old.kind != new.kind {
            return Err(DiffError::DifferentKinds);
        }
        if old.kind == ReportKind::Drive && old.device.model != new.device.model {
            return Err(DiffError::DifferentModels {
                old: old.device.model.clone(),
                new: new.device.model.clone(),
            });
        }
        match (old.device.nodes.is_empty(), new.device.nodes.is_empty()) {
            (true, false) => {
                return Err(DiffError::OneAndSeveralNodes {
                    several: "new",
                    nodes: node_list(new),
                    one: old.device.address,
                })
            }
            (false, true) => {
                return Err(DiffError::OneAndSeveralNodes {
                    several: "old",
                    nodes: node_list(old),
                    one: new.device.address,
                })
            }
            _ => {}
        }
        let olds: BTreeMap<String, &CheckResult> =
            old.results.iter().map(|r| (r.key(), r)).collect();
        let news: BTreeMap<String, &CheckResult> =
            new.results.iter().map(|r| (r.key(), r)).collect();
        let mut d = Diff {
            old_label: label(old),
            new_label: label(new),
            expected_new: new
                .results
                .iter()
                .filter(|r| new.is_expected(r))
                .map(CheckResult::key)
                .collect(),
            expect_line: new.expect.as_ref().map(|e| {
                let count = |k: MarkKind| e.marks.values().filter(|m| m.kind == k).count();
                format!(
                    "the new run against {}: {} expected, {} new, {} unexpected passes; {} entries not applied",
                    e.path,
                    count(MarkKind::Expected),
                    new.unexpected_findings().len(),
                    new.unexpected_passes(),
                    e.stale().count()
                )
            }),
            ..Diff::default()
        };
        for n in &new.results {
            let key = n.key();
            let Some(o) = olds.get(&key) else {
                d.only_new.push((key, n.status));
                continue;
            };
            if o.status != n.status {
                d.status.push(StatusChange {
                    id: key.clone(),
                    title: n.title.clone(),
                    old: o.status,
                    new: n.status,
                    summary: n.summary.clone(),
                    expectation: new.expectation(n).map(|m| m.kind),
                });
            } else if n.status == Status::Deviation {
                for (i, (eo, en)) in o.exchanges.iter().zip(&n.exchanges).enumerate() {
                    if eo.received != en.received {
                        d.bytes.push(BytesChange {
                            id: key.clone(),
                            exchange: i,
                            request: en.request.clone(),
                            old: eo.received.clone(),
                            new: en.received.clone(),
                        });
                    }
                }
            }
            let (lo, ln) = (check_latencies(o), check_latencies(n));
            let enough = lo.len().min(ln.len()) >= MIN_REPLIES;
            if let (true, Some(mo), Some(mn)) =
                (enough, super::html::median(&lo), super::html::median(&ln))
            {
                if beyond_noise(mo, mn) {
                    d.timing.push(TimingShift {
                        what: key.clone(),
                        old_ms: mo,
                        new_ms: mn,
                        old_n: lo.len(),
                        new_n: ln.len(),
                    });
                }
            }
        }
        for o in &old.results {
            let key = o.key();
            if !news.contains_key(&key) {
                d.only_old.push((key, o.status));
            }
        }
        // Worse first, new deviations first among them; then the improvements.
        d.status
            .sort_by_key(|c| (!c.worse(), std::cmp::Reverse(badness(c.new)), c.id.clone()));
        let (lo, ln) = (super::html::latencies(old), super::html::latencies(new));
        let modes: BTreeSet<&String> = lo.keys().chain(ln.keys()).collect();
        let mut per_mode = Vec::new();
        for m in modes {
            let (Some(a), Some(b)) = (lo.get(m), ln.get(m)) else {
                continue;
            };
            if let (Some(mo), Some(mn)) = (super::html::median(a), super::html::median(b)) {
                if beyond_noise(mo, mn) {
                    per_mode.push(TimingShift {
                        what: m.clone(),
                        old_ms: mo,
                        new_ms: mn,
                        old_n: a.len(),
                        new_n: b.len(),
                    });
                }
            }
        }
        per_mode.append(&mut d.timing);
        d.timing = per_mode;
        Ok(d)
    }

    /// Whether something got worse: a status, a check new in this run that does not
    /// pass, or a response time beyond noise.
    pub fn worse(&self) -> bool {
        self.status.iter().any(StatusChange::worse)
            || self.timing.iter().any(TimingShift::worse)
            || self
                .only_new
                .iter()
                .any(|(k, s)| badness(*s) > 0 && !self.expected_new.contains(k))
    }

    /// Whether the runs differ at all.
    pub fn is_empty(&self) -> bool {
        self.status.is_empty()
            && self.bytes.is_empty()
            && self.timing.is_empty()
            && self.only_old.is_empty()
            && self.only_new.is_empty()
    }

    /// The exit code: 1 when something got worse, 0 otherwise.
    pub fn exit_code(&self) -> u8 {
        u8::from(self.worse())
    }

    /// One line of counts.
    pub fn counts(&self) -> String {
        let worse = self.status.iter().filter(|c| c.worse()).count();
        format!(
            "{worse} checks worse, {} better; {} deviations with other bytes; {} response-time shifts; {} checks only in the old run, {} only in the new",
            self.status.len() - worse,
            self.bytes.len(),
            self.timing.len(),
            self.only_old.len(),
            self.only_new.len()
        )
    }

    /// Human text.
    pub fn text(&self) -> String {
        let mut out = String::new();
        w!(out, "old: {}\nnew: {}\n", self.old_label, self.new_label);
        w!(
            out,
            "{}\n",
            if self.is_empty() {
                "No differences."
            } else if self.worse() {
                "WORSE: something got worse (exit 1)."
            } else {
                "Changed, nothing got worse."
            }
        );
        if !self.is_empty() {
            w!(out, "{}\n", self.counts());
        }
        if let Some(e) = &self.expect_line {
            w!(out, "expectations: {e}\n");
        }
        if !self.status.is_empty() {
            w!(out, "\nStatus changes ({}):\n", self.status.len());
            for c in &self.status {
                w!(
                    out,
                    "  {} {:<44} {} -> {}{}\n      {}\n",
                    match (c.worse(), c.expectation) {
                        (true, _) => "worse   ",
                        (false, Some(MarkKind::Expected)) if badness(c.new) > badness(c.old) =>
                            "expected",
                        _ => "better  ",
                    },
                    c.id,
                    c.old,
                    c.new,
                    match c.expectation {
                        Some(MarkKind::Expected) => " (expected)",
                        Some(MarkKind::UnexpectedPass) => " (UNEXPECTED PASS)",
                        Some(MarkKind::Changed) => " (not the expected status)",
                        None => "",
                    },
                    c.summary
                );
            }
        }
        if !self.bytes.is_empty() {
            w!(
                out,
                "\nDeviations whose received bytes changed ({}):\n",
                self.bytes.len()
            );
            for b in &self.bytes {
                w!(
                    out,
                    "  {} (exchange {})\n      request {}\n      old     {}\n      new     {}\n",
                    b.id,
                    b.exchange + 1,
                    Hex(&b.request),
                    Hex(&b.old),
                    Hex(&b.new)
                );
            }
        }
        if !self.timing.is_empty() {
            w!(
                out,
                "\nResponse-time medians that moved beyond noise (max({:.0} %, {NOISE_MS} ms)) ({}):\n",
                NOISE_RATIO * 100.0,
                self.timing.len()
            );
            for t in &self.timing {
                w!(
                    out,
                    "  {} {:<44} {:.1} ms -> {:.1} ms (n={} / {})\n",
                    if t.worse() { "slower" } else { "faster" },
                    t.what,
                    t.old_ms,
                    t.new_ms,
                    t.old_n,
                    t.new_n
                );
            }
        }
        for (name, list) in [
            ("Only in the old run", &self.only_old),
            ("Only in the new run", &self.only_new),
        ] {
            if !list.is_empty() {
                w!(out, "\n{name} ({}):\n", list.len());
                for (id, s) in list {
                    let expected = if self.expected_new.contains(id) && name.contains("new") {
                        " (expected)"
                    } else {
                        ""
                    };
                    w!(out, "  {id:<50} {s}{expected}\n");
                }
            }
        }
        out
    }

    /// JSON.
    pub fn to_json(&self) -> Value {
        let st = |s: Status| format!("{s:?}").to_lowercase();
        json!({
            "schema": "teco-modbus-conformance/diff",
            "old": self.old_label,
            "new": self.new_label,
            "worse": self.worse(),
            "exit_code": self.exit_code(),
            "noise": { "ratio": NOISE_RATIO, "ms": NOISE_MS },
            "status_changes": self.status.iter().map(|c| json!({
                "id": c.id, "title": c.title, "old": st(c.old), "new": st(c.new),
                "worse": c.worse(), "summary": c.summary,
                "expectation": c.expectation.map(|k| k.key()),
            })).collect::<Vec<_>>(),
            "received_changes": self.bytes.iter().map(|b| json!({
                "id": b.id, "exchange": b.exchange, "request": Hex(&b.request).to_string(),
                "old": Hex(&b.old).to_string(), "new": Hex(&b.new).to_string(),
            })).collect::<Vec<_>>(),
            "timing_shifts": self.timing.iter().map(|t| json!({
                "what": t.what, "old_median_ms": t.old_ms, "new_median_ms": t.new_ms,
                "old_n": t.old_n, "new_n": t.new_n, "worse": t.worse(),
            })).collect::<Vec<_>>(),
            "only_old": self.only_old.iter().map(|(id, s)| json!({"id": id, "status": st(*s)})).collect::<Vec<_>>(),
            "only_new": self.only_new.iter().map(|(id, s)| json!({"id": id, "status": st(*s), "expected": self.expected_new.contains(id)})).collect::<Vec<_>>(),
            "expectations": self.expect_line,
        })
    }

    /// One self-contained HTML page.
    pub fn html(&self) -> String {
        let mut out = String::new();
        w!(
            out,
            "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>Conformance diff</title><style>{CSS}</style></head><body><main><h1>What changed between two runs</h1><div class=\"facts\"><table><tr><td>old</td><td>{}</td></tr><tr><td>new</td><td>{}</td></tr></table></div>",
            esc(&self.old_label),
            esc(&self.new_label)
        );
        let (cls, verdict) = if self.is_empty() {
            ("ok", "No differences")
        } else if self.worse() {
            ("bad", "Something got worse")
        } else {
            ("ok", "Changed; nothing got worse")
        };
        w!(
            out,
            "<div class=\"verdict {cls}\" id=\"verdict\">{verdict}</div>"
        );
        let badge = |s: Status| {
            format!(
                "<span class=\"badge {}\">{s}</span>",
                format!("{s:?}").to_lowercase()
            )
        };
        w!(out, "<h2>Status changes ({})</h2>", self.status.len());
        if !self.status.is_empty() {
            out.push_str("<table id=\"status\"><thead><tr><th>id</th><th>old</th><th>new</th><th></th><th>new summary</th></tr></thead><tbody>");
            for c in &self.status {
                w!(
                    out,
                    "<tr class=\"{}\"><td class=\"id\">{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td></tr>",
                    if c.worse() { "deviation" } else { "pass" },
                    esc(&c.id),
                    badge(c.old),
                    badge(c.new),
                    if c.worse() { "<b>worse</b>" } else { "better" },
                    esc(&c.summary)
                );
            }
            out.push_str("</tbody></table>");
        }
        w!(
            out,
            "<h2>Deviations whose received bytes changed ({})</h2>",
            self.bytes.len()
        );
        for b in &self.bytes {
            let diff = super::diff_positions(&b.old, &b.new);
            let mark = |bytes: &[u8]| hex_marked(bytes, &diff, "");
            w!(
                out,
                "<article class=\"finding\"><h3><code>{}</code> exchange {}</h3><table class=\"frames\"><tr><td>request</td><td class=\"hex\">{}</td></tr><tr><td>old</td><td>{}</td></tr><tr><td>new</td><td>{}</td></tr></table></article>",
                esc(&b.id),
                b.exchange + 1,
                Hex(&b.request),
                mark(&b.old),
                mark(&b.new)
            );
        }
        w!(
            out,
            "<h2>Response-time medians beyond noise ({})</h2><p class=\"muted\">Noise: a median that moved by less than max({:.0} % of the old median, {NOISE_MS} ms).</p>",
            self.timing.len(),
            NOISE_RATIO * 100.0
        );
        if !self.timing.is_empty() {
            out.push_str("<table id=\"timing\"><thead><tr><th>mode or check</th><th class=\"num\">old median</th><th class=\"num\">new median</th><th></th></tr></thead><tbody>");
            for t in &self.timing {
                w!(
                    out,
                    "<tr><td class=\"id\">{}</td><td class=\"num\">{:.1} ms (n={})</td><td class=\"num\">{:.1} ms (n={})</td><td>{}</td></tr>",
                    esc(&t.what),
                    t.old_ms,
                    t.old_n,
                    t.new_ms,
                    t.new_n,
                    if t.worse() { "<b>slower</b>" } else { "faster" }
                );
            }
            out.push_str("</tbody></table>");
        }
        for (name, list) in [
            ("Only in the old run", &self.only_old),
            ("Only in the new run", &self.only_new),
        ] {
            w!(out, "<h2>{name} ({})</h2>", list.len());
            if !list.is_empty() {
                out.push_str("<table><tbody>");
                for (id, s) in list {
                    w!(
                        out,
                        "<tr><td class=\"id\">{}</td><td>{}</td></tr>",
                        esc(id),
                        badge(*s)
                    );
                }
                out.push_str("</tbody></table>");
            }
        }
        out.push_str("</main></body></html>\n");
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::Mode;
    use crate::runner::ExchangeRecord;
    use std::time::Duration;

    fn check(id: &str, status: Status, received: &[u8], latency_ms: u64) -> CheckResult {
        CheckResult {
            id: id.into(),
            title: format!("title of {id}"),
            mode: Some(Mode::Rtu),
            source: "manual".into(),
            status,
            summary: format!("{id} is {status}"),
            findings: vec![],
            exchanges: vec![ExchangeRecord {
                request: vec![1, 3, 0, 0, 0, 1],
                expected: None,
                received: received.to_vec(),
                reply: Some(received.to_vec()),
                predicted: String::new(),
                actual: String::new(),
                latency: Some(Duration::from_millis(latency_ms)),
            }],
            duration: Duration::from_millis(20),
            node: None,
        }
    }

    fn run(results: Vec<CheckResult>) -> Report {
        Report {
            complete: true,
            device: crate::report::Device {
                model: "f510".into(),
                ..Default::default()
            },
            results,
            ..Report::default()
        }
    }

    #[test]
    fn noise_is_twenty_percent_or_five_ms() {
        assert!(!beyond_noise(10.0, 14.9));
        assert!(beyond_noise(10.0, 15.1));
        assert!(!beyond_noise(100.0, 119.0));
        assert!(beyond_noise(100.0, 121.0));
        assert!(beyond_noise(10.0, 4.0));
    }

    #[test]
    fn what_got_worse_comes_first_and_sets_the_exit_code() {
        let old = run(vec![
            check("rtu.a", Status::Pass, &[1, 3], 9),
            check("rtu.b", Status::Deviation, &[1, 0x83, 2], 9),
            check("rtu.c", Status::Deviation, &[1, 0x83, 3], 9),
            check("rtu.d", Status::Pass, &[1, 3], 9),
            check("rtu.gone", Status::Pass, &[1, 3], 9),
        ]);
        let new = run(vec![
            check("rtu.a", Status::Pass, &[1, 3], 9),
            check("rtu.b", Status::Pass, &[1, 3], 9),
            check("rtu.c", Status::Deviation, &[1, 0x83, 4], 9),
            check("rtu.d", Status::Deviation, &[1, 0x83, 2], 40),
            check("rtu.fresh", Status::Observation, &[1, 3], 9),
        ]);
        let mut old = old;
        let mut new = new;
        let triple = |r: &mut CheckResult| {
            let e = r.exchanges[0].clone();
            r.exchanges.extend([e.clone(), e]);
        };
        triple(&mut old.results[3]);
        triple(&mut new.results[3]);
        triple(&mut old.results[0]);
        let d = Diff::new(&old, &new).unwrap();
        let ids: Vec<_> = d
            .status
            .iter()
            .map(|c| (c.id.as_str(), c.worse()))
            .collect();
        assert_eq!(ids, [("rtu.d", true), ("rtu.b", false)]);
        assert_eq!(d.bytes.len(), 1);
        assert_eq!(d.bytes[0].id, "rtu.c");
        assert_eq!(
            (d.bytes[0].old.clone(), d.bytes[0].new.clone()),
            (vec![1, 0x83, 3], vec![1, 0x83, 4])
        );
        assert_eq!(d.only_old, [("rtu.gone".to_string(), Status::Pass)]);
        assert_eq!(d.only_new, [("rtu.fresh".to_string(), Status::Observation)]);
        // The check that took 40 ms instead of 9, three times, moved beyond noise; the
        // mode's median (9 ms in both) did not, nor rtu.a (3 replies in the old run, 1 in
        // the new: too few to compare).
        let t: Vec<_> = d.timing.iter().map(|t| t.what.as_str()).collect();
        assert_eq!(t, ["rtu.d"]);
        assert!(d.worse());
        assert_eq!(d.exit_code(), 1);
        let text = d.text();
        assert!(text.find("rtu.d").unwrap() < text.find("rtu.b").unwrap());
        assert_eq!(d.to_json()["status_changes"][0]["worse"], true);
        assert!(d.html().contains("<span class=\"d\">03</span>"));
    }

    #[test]
    fn a_run_against_itself_is_no_change() {
        let r = run(vec![check("rtu.a", Status::Deviation, &[1, 0x83, 2], 9)]);
        let d = Diff::new(&r, &r).unwrap();
        assert!(d.is_empty());
        assert_eq!(d.exit_code(), 0);
    }

    #[test]
    fn different_models_are_refused() {
        let a = run(vec![]);
        let mut b = run(vec![]);
        b.device.model = "a510".into();
        assert!(matches!(
            Diff::new(&a, &b),
            Err(DiffError::DifferentModels { .. })
        ));
    }
}
