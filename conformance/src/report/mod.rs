//! Reports of a conformance run: human text (summary first, deviations first), JSON (a
//! stable, documented schema: `vectors/schema/report.schema.json`) and JUnit XML (one test
//! case per check, deviations as failures).
//!
//! A report is valid at every moment of a run: [`Report::complete`] is false until the
//! run ends, so a run cut short by a disconnect or an interruption still leaves a whole
//! report of what ran, marked incomplete.

mod csv;
pub mod diff;
mod error;
mod expect_apply;
mod expect_html;
mod expect_json;
mod expect_write;
mod html;
mod junit;
mod markup;
mod parse;
pub mod requirements;
mod text;
pub mod watch;

use std::collections::BTreeMap;

use serde_json::{json, Value};

pub use csv::csv;
pub use error::ReportError;
pub use expect_apply::apply as apply_expectations;
pub use expect_write::starting_file as starting_expectations;
pub use html::{html, unresolved_links, watch_html};
pub use junit::junit;
pub use text::text;

/// Positions where two frames differ (the judge's rule, one place).
pub use crate::judge::diff_positions;

use crate::codec::hex::Hex;
use crate::codec::Mode;
use crate::runner::{CheckResult, ModeBudget, RestoreRecord, Status};

/// Schema version of the JSON report.
pub const SCHEMA_VERSION: u32 = 1;

/// The device a report is about.
#[derive(Debug, Clone, Default)]
pub struct Device {
    /// Model id.
    pub model: String,
    /// The manual.
    pub manual: String,
    /// Node address.
    pub address: u8,
    /// Link per mode ("rtu" -> "pty /dev/pts/3 ...").
    pub links: BTreeMap<String, String>,
    /// Line settings ("9600 8E1").
    pub line: String,
    /// The identification register's value, if read.
    pub identification: Option<u16>,
    /// Whether the device is this suite's simulator, and its quirks.
    pub simulated: Option<Vec<String>>,
    /// In a run of several nodes on one bus (`check --address 1,2,5`): each node, in the
    /// order checked; empty for a run of one node. [`Device::address`] is then the first.
    pub nodes: Vec<NodeInfo>,
    /// The description the device was judged by: its file (`None` for a built-in model),
    /// title and SHA-256. `None` in reports older than it.
    pub description: Option<crate::model::Source>,
}

/// One node of a run of several nodes on one bus.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct NodeInfo {
    /// Node address.
    pub address: u8,
    /// Its identification register's value, if read.
    pub identification: Option<u16>,
    /// Why its checks stopped early (it stopped answering), if they did; the other nodes
    /// were still checked.
    pub stopped: Option<String>,
    /// The simulator's quirks planted on this node only (`QUIRK@NODE`).
    pub quirks: Vec<String>,
}

/// Options a report records.
#[derive(Debug, Clone, Default)]
pub struct RunOptions {
    /// Modes run.
    pub modes: Vec<Mode>,
    /// No writes.
    pub read_only: bool,
    /// Motion checks enabled.
    pub allow_motion: bool,
    /// Reply timeout.
    pub timeout_ms: u64,
    /// Resends.
    pub retries: u32,
    /// --only patterns.
    pub only: Vec<String>,
    /// The manual's response time on the run's line (or t3.5 where that is longer), ms.
    pub response_time_ms: Option<f64>,
    /// Allowance over it before a reply counts as late, ms.
    pub response_allowance_ms: Option<u64>,
}

/// What a report is about.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum ReportKind {
    /// A drive (real or simulated), checked by `conformance check`.
    #[default]
    Drive,
    /// A codec, checked by `conformance gate` through an adapter.
    Gate,
    /// A drive (real or simulated), fuzzed by `conformance fuzz`.
    Fuzz,
    /// A bus listened to by `conformance monitor`: its drives and its master.
    Monitor,
}

/// The codec a gate report is about.
#[derive(Debug, Clone, Default)]
pub struct Codec {
    /// The adapter's name.
    pub adapter: String,
    /// The implementation it wraps.
    pub implementation: String,
    /// Its version.
    pub version: String,
    /// The command that runs the adapter.
    pub command: String,
    /// Operations it supports.
    pub supports: Vec<String>,
    /// Crashes, restarts and hangs of the adapter.
    pub incidents: Vec<String>,
    /// Seed and count of the differential cases.
    pub seed: u64,
    /// Number of differential cases.
    pub count: usize,
}

/// A whole report.
#[derive(Debug, Clone, Default)]
pub struct Report {
    /// Drive or gate.
    pub kind: ReportKind,
    /// For a gate report: the codec.
    pub codec: Option<Codec>,
    /// When the run started (RFC 3339).
    pub started: String,
    /// When it ended, if it has.
    pub finished: Option<String>,
    /// Whether every selected check ran.
    pub complete: bool,
    /// Why the run stopped early.
    pub stopped: Option<String>,
    /// The device.
    pub device: Device,
    /// The options.
    pub options: RunOptions,
    /// Results in the order they ran.
    pub results: Vec<CheckResult>,
    /// Registers restored at the end.
    pub restore: Vec<RestoreRecord>,
    /// Per mode: the wall time against the line's lower bound.
    pub budget: BTreeMap<String, ModeBudget>,
    /// For a fuzz report: the campaign.
    pub fuzz: Option<crate::fuzz::report::FuzzSummary>,
    /// For a monitor report: what was heard, per node.
    pub monitor: Option<crate::monitor::MonitorSummary>,
    /// The run's results against an expectations file (`--expect`), if one was given.
    pub expect: Option<crate::expect::Outcome>,
    /// For a gate report on a master (`gate --master`): its settings and its findings by
    /// kind.
    pub master: Option<crate::gate::master::MasterSummary>,
}

/// Counts per status.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Summary {
    /// All checks.
    pub total: usize,
    /// PASS.
    pub pass: usize,
    /// DEVIATION.
    pub deviation: usize,
    /// OBSERVATION.
    pub observation: usize,
    /// SKIP.
    pub skip: usize,
    /// ERROR.
    pub error: usize,
}

impl Summary {
    /// Counts one result of `status` (not in `total`, which the caller sets).
    fn count(&mut self, status: Status) {
        match status {
            Status::Pass => self.pass += 1,
            Status::Deviation => self.deviation += 1,
            Status::Observation => self.observation += 1,
            Status::Skip => self.skip += 1,
            Status::Error => self.error += 1,
        }
    }
}

impl Report {
    /// The run's timeout as what it means for the kind of run: a drive's response timeout
    /// and retries; for a monitor, how long it waits for a reply; for a master gate, the gate's allowance beyond the master's own worst
    /// case (its retries are the master's, in its settings); for a codec gate, how long an
    /// adapter may take over a case.
    pub fn timeout_phrase(&self) -> String {
        let o = &self.options;
        match (self.kind, &self.master) {
            (ReportKind::Gate, Some(_)) => format!(
                "allowance {} ms beyond the master's worst case (its timeout × (retries + 1))",
                o.timeout_ms
            ),
            (ReportKind::Gate, None) => format!("adapter timeout {} ms a case", o.timeout_ms),
            // A monitor sends nothing, so it neither times out nor retries: it waits this
            // long for a reply before it counts the request unanswered.
            (ReportKind::Monitor, _) => format!("reply window {} ms", o.timeout_ms),
            _ => format!("timeout {} ms, {} retries", o.timeout_ms, o.retries),
        }
    }

    /// Counts per status.
    pub fn summary(&self) -> Summary {
        let mut s = Summary {
            total: self.results.len(),
            ..Summary::default()
        };
        for r in &self.results {
            s.count(r.status);
        }
        s
    }

    /// The nodes of a run of several nodes, with their results' counts; the last entry,
    /// with `None`, counts the checks of the whole bus, where there are any (a monitor has
    /// none, nor a check run whose `--only` left them out). Empty for a run of one node.
    pub fn node_summaries(&self) -> Vec<(Option<u8>, Summary)> {
        if self.device.nodes.is_empty() {
            return Vec::new();
        }
        let mut out: Vec<(Option<u8>, Summary)> = self
            .device
            .nodes
            .iter()
            .map(|n| (Some(n.address), Summary::default()))
            .collect();
        out.push((None, Summary::default()));
        for r in &self.results {
            let at = match out.iter().position(|(n, _)| *n == r.node) {
                Some(i) => i,
                None => {
                    out.push((r.node, Summary::default()));
                    out.len() - 1
                }
            };
            out[at].1.total += 1;
            out[at].1.count(r.status);
        }
        out.retain(|(n, c)| n.is_some() || c.total > 0);
        out
    }

    /// Whether the run may have written to the device, so that its report has a restore
    /// journal: a monitor only listens and a gate talks to no drive.
    pub fn writes(&self) -> bool {
        matches!(self.kind, ReportKind::Drive | ReportKind::Fuzz) || !self.restore.is_empty()
    }

    /// Registers that could not be restored.
    pub fn unrestored(&self) -> Vec<&RestoreRecord> {
        self.restore.iter().filter(|r| !r.restored).collect()
    }

    /// The exit code: 0 no deviations (or only expected ones); 1 deviations found that no
    /// expectation accepts (or, with `--strict-expect`, an unexpected pass); 2 the run
    /// could not complete (cut short, a check that could not tell, or a register left
    /// unrestored).
    pub fn exit_code(&self) -> u8 {
        let s = self.summary();
        if !self.complete || s.error > 0 || !self.unrestored().is_empty() {
            2
        } else if !self.unexpected_findings().is_empty()
            || self
                .expect
                .as_ref()
                .is_some_and(|e| e.strict && self.unexpected_passes() > 0)
        {
            1
        } else {
            0
        }
    }

    /// Why [`Report::exit_code`] is what it is, in a few words for a report's header
    /// ("1 check ended in ERROR (it could not tell)"); every reason that applies.
    pub fn exit_reason(&self) -> String {
        let s = self.summary();
        let plural = |n: usize, one: &str, many: &str| {
            if n == 1 {
                format!("1 {one}")
            } else {
                format!("{n} {many}")
            }
        };
        let mut why = Vec::new();
        if !self.complete {
            why.push("the run did not complete".to_string());
        }
        if s.error > 0 {
            why.push(format!(
                "{} in ERROR (nothing could be judged from {})",
                plural(s.error, "check ended", "checks ended"),
                if s.error == 1 { "it" } else { "them" }
            ));
        }
        let unrestored = self.unrestored().len();
        if unrestored > 0 {
            why.push(format!(
                "{} not restored",
                plural(unrestored, "register", "registers")
            ));
        }
        if !why.is_empty() {
            return why.join("; ");
        }
        let new = self.unexpected_findings().len();
        if new > 0 {
            return if self.expect.is_some() {
                format!(
                    "{} that no expectation accepts",
                    plural(new, "finding", "findings")
                )
            } else {
                plural(new, "finding", "findings")
            };
        }
        let passes = self.unexpected_passes();
        if self.expect.as_ref().is_some_and(|e| e.strict) && passes > 0 {
            return format!(
                "{} that the expectations call a finding (--strict-expect)",
                plural(passes, "pass", "passes")
            );
        }
        "no deviation that fails the run".to_string()
    }

    /// Whether `r` is a result that fails a run: a deviation, or in a fuzz run a finding
    /// (an observation replayed and seen again, or never replayed).
    /// `unconfirmed`: [`Report::unconfirmed_ids`].
    fn fails_run(&self, r: &CheckResult, unconfirmed: &[String]) -> bool {
        match r.status {
            Status::Deviation => true,
            Status::Observation if self.kind == ReportKind::Fuzz => !unconfirmed.contains(&r.id),
            _ => false,
        }
    }

    /// The results that fail the run and that no expectation accepts: new deviations.
    pub fn unexpected_findings(&self) -> Vec<&CheckResult> {
        let unconfirmed = if self.kind == ReportKind::Fuzz {
            self.unconfirmed_ids()
        } else {
            Vec::new()
        };
        self.results
            .iter()
            .filter(|r| self.fails_run(r, &unconfirmed) && !self.is_expected(r))
            .collect()
    }

    /// Whether an expectation accepts `r` as it is.
    pub fn is_expected(&self, r: &CheckResult) -> bool {
        self.expectation(r)
            .is_some_and(|m| m.kind == crate::expect::MarkKind::Expected)
    }

    /// The mark an expectations file gave `r`, if any.
    pub fn expectation(&self, r: &CheckResult) -> Option<&crate::expect::Mark> {
        self.expect.as_ref().and_then(|e| e.mark(r))
    }

    /// Checks an expectation says deviate that passed, and (fuzz) expected finding
    /// signatures that a complete campaign did not find again.
    pub fn unexpected_passes(&self) -> usize {
        self.results
            .iter()
            .filter(|r| {
                self.expectation(r)
                    .is_some_and(|m| m.kind == crate::expect::MarkKind::UnexpectedPass)
            })
            .count()
            + self.expect.as_ref().map_or(0, |e| e.not_found())
    }

    /// The ids of fuzz findings that were replayed and not seen again: observations that
    /// do not make the exit code 1 (one such event may be this host's timing). A report
    /// read back from JSON has no campaign: its findings' text says so.
    fn unconfirmed_ids(&self) -> Vec<String> {
        match &self.fuzz {
            Some(f) => f
                .modes
                .iter()
                .flat_map(|m| &m.findings)
                .filter(|x| x.replays > 0 && !x.reproduced)
                .map(|x| format!("fuzz.{}", x.signature()))
                .collect(),
            None => self
                .results
                .iter()
                .filter(|r| {
                    r.findings
                        .iter()
                        .any(|f| f.text.starts_with("not a deviation: "))
                })
                .map(|r| r.id.clone())
                .collect(),
        }
    }

    /// The report as JSON.
    pub fn to_json(&self) -> Value {
        let s = self.summary();
        let checks: Vec<Value> = self
            .results
            .iter()
            .map(|r| {
                let mut v = check_json(r, &self.device.model);
                if let Some(m) = self.expectation(r) {
                    v["expectation"] = expect_json::mark(m);
                }
                v
            })
            .collect();
        let restore: Vec<Value> = self
            .restore
            .iter()
            .map(|r| {
                let mut v = json!({
                    "register": format!("{:04X}", r.register),
                    "original": format!("{:04X}", r.original),
                    "restored": r.restored,
                    "changed": r.changed,
                    "detail": r.detail,
                });
                if let Some(n) = r.node {
                    v["node"] = json!(format!("{n:02X}"));
                }
                v
            })
            .collect();
        let mut device = match self.kind {
            ReportKind::Gate => Value::Null,
            ReportKind::Drive | ReportKind::Fuzz | ReportKind::Monitor => json!({
                "model": self.device.model,
                "manual": self.device.manual,
                "address": format!("{:02X}", self.device.address),
                "links": self.device.links,
                "line": self.device.line,
                "identification": self.device.identification.map(|v| format!("{v:04X}")),
                "simulated": self.device.simulated.is_some(),
                "quirks": self.device.simulated.clone().unwrap_or_default(),
            }),
        };
        if let (Some(s), true) = (&self.device.description, device.is_object()) {
            device["description"] = json!({
                "file": s.file,
                "title": s.title,
                "sha256": s.sha256,
            });
        }
        if !self.device.nodes.is_empty() && device.is_object() {
            device["nodes"] = self
                .device
                .nodes
                .iter()
                .map(|n| {
                    json!({
                        "address": format!("{:02X}", n.address),
                        "identification": n.identification.map(|v| format!("{v:04X}")),
                        "stopped": n.stopped,
                        "quirks": n.quirks,
                    })
                })
                .collect();
        }
        let codec = match &self.codec {
            None => Value::Null,
            Some(c) => json!({
                "adapter": c.adapter,
                "implementation": c.implementation,
                "version": c.version,
                "command": c.command,
                "supports": c.supports,
                "incidents": c.incidents,
                "seed": format!("{:#x}", c.seed),
                "count": c.count,
            }),
        };
        json!({
            "schema": "teco-modbus-conformance/report",
            "schema_version": SCHEMA_VERSION,
            "kind": match self.kind { ReportKind::Drive => "drive", ReportKind::Gate => "gate", ReportKind::Fuzz => "fuzz", ReportKind::Monitor => "monitor" },
            "suite": { "name": env!("CARGO_PKG_NAME"), "version": env!("CARGO_PKG_VERSION") },
            "started": self.started,
            "finished": self.finished,
            "complete": self.complete,
            "stopped": self.stopped,
            "exit_code": self.exit_code(),
            "device": device,
            "codec": codec,
            "options": {
                "modes": self.options.modes.iter().map(|m| m.to_string()).collect::<Vec<_>>(),
                "read_only": self.options.read_only,
                "allow_motion": self.options.allow_motion,
                "timeout_ms": self.options.timeout_ms,
                "retries": self.options.retries,
                "only": self.options.only,
                "response_time_ms": self.options.response_time_ms,
                "response_allowance_ms": self.options.response_allowance_ms,
            },
            "summary": {
                "total": s.total, "pass": s.pass, "deviation": s.deviation,
                "observation": s.observation, "skip": s.skip, "error": s.error,
            },
            "checks": checks,
            "restore": restore,
            "budget": self.budget.iter().map(|(mode, b)| (mode.clone(), budget_json(b))).collect::<serde_json::Map<String, Value>>(),
            "fuzz": self.fuzz.as_ref().map(|f| f.to_json()),
            "monitor": self.monitor.as_ref().map(|m| m.to_json()),
            "expectations": self.expect.as_ref().map(|o| expect_json::outcome(self, o)),
            "master": self.master.as_ref().map(|m| m.to_json()),
        })
    }
}

fn ms(d: std::time::Duration) -> f64 {
    (d.as_secs_f64() * 10_000.0).round() / 10.0
}

fn budget_json(b: &ModeBudget) -> Value {
    let mut v = json!({
        "wall_ms": ms(b.wall),
        "bound_ms": ms(b.bound),
        "efficiency": (b.efficiency() * 1000.0).round() / 1000.0,
        "frames": b.line.frames,
        "bytes_sent": b.line.bytes_sent,
        "bytes_received": b.line.bytes_received,
        "response_ms": ms(b.line.response),
        "max_response_ms": ms(b.line.max_response),
        "silences": b.line.silences,
    });
    if let Some(why) = b.no_bound {
        v["no_bound"] = json!(why.key());
    }
    if b.line.broken_sends > 0 {
        v["broken_sends"] = json!(b.line.broken_sends);
    }
    if b.host_reruns > 0 {
        v["host_reruns"] = json!(b.host_reruns);
    }
    v
}

fn check_json(r: &CheckResult, model: &str) -> Value {
    let exchanges: Vec<Value> = r
        .exchanges
        .iter()
        .map(|e| {
            json!({
                "request": Hex(&e.request).to_string(),
                "expected": e.expected.as_ref().map(|b| Hex(b).to_string()),
                "received": Hex(&e.received).to_string(),
                "reply": e.reply.as_ref().map(|b| Hex(b).to_string()),
                "differs_at": e.expected.as_ref().zip(e.reply.as_ref()).map(|(x, y)| diff_positions(x, y)).unwrap_or_default(),
                "predicted": e.predicted,
                "actual": e.actual,
                "latency_ms": e.latency.map(|d| (d.as_secs_f64() * 1e6).round() / 1e3),
            })
        })
        .collect();
    let findings: Vec<Value> = r
        .findings
        .iter()
        .map(|f| {
            json!({
                "severity": match f.severity {
                    crate::runner::Severity::Deviation => "deviation",
                    crate::runner::Severity::Observation => "observation",
                },
                "text": f.text,
            })
        })
        .collect();
    let mut v = json!({
        "id": r.id,
        "title": r.title,
        "mode": r.mode.map(|m| m.to_string()),
        "source": r.source,
        "status": format!("{:?}", r.status).to_lowercase(),
        "summary": r.summary,
        "findings": findings,
        "exchanges": exchanges,
        "duration_ms": (r.duration.as_secs_f64() * 1e6).round() / 1e3,
    });
    if let Some(n) = r.node {
        v["node"] = json!(format!("{n:02X}"));
    }
    let reqs = crate::requirements::for_check(model, &r.id);
    if !reqs.is_empty() {
        v["requirements"] = json!(reqs);
    }
    v
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differing_bytes_are_found() {
        assert_eq!(
            diff_positions(&[1, 0x83, 2, 0xC0, 0xF1], &[1, 0x83, 3, 0x01, 0x31]),
            [2, 3, 4]
        );
        assert_eq!(diff_positions(&[1, 2, 3], &[1, 2]), [2]);
        assert!(diff_positions(&[1, 2], &[1, 2]).is_empty());
    }
}

#[cfg(test)]
mod fixtures;
#[cfg(test)]
mod nodes_tests;
