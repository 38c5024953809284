//! A campaign as the suite's report: one result per finding signature (with its count,
//! its reproducer and the command that replays it), one result per mode for the campaign
//! itself (cases, cases/s, the line's bound), and the `fuzz` section of the JSON report.

use std::time::Duration;

use serde_json::{json, Value};

use super::{FuzzFinding, Kind, ModeOutcome};
use crate::codec::hex::Hex;
use crate::runner::{CheckResult, Finding, Severity, Status};

/// The fuzz section of a report.
#[derive(Debug, Clone, Default)]
pub struct FuzzSummary {
    /// Seed.
    pub seed: u64,
    /// Write level.
    pub writes: String,
    /// Per mode.
    pub modes: Vec<ModeOutcome>,
}

fn ms(d: Duration) -> f64 {
    (d.as_secs_f64() * 1e6).round() / 1e3
}

/// The result of one finding signature.
pub fn finding_result(f: &FuzzFinding) -> CheckResult {
    // Replayed and not seen again: one event this host may have made (a stall that
    // delayed a reply into the next case) or an intermittent fault; reported, with its
    // frames and the command that replays it, but not as a deviation.
    let unconfirmed = f.replays > 0 && !f.reproduced;
    let status = match (f.kind, f.severity) {
        _ if unconfirmed => Status::Observation,
        (Kind::Hang, _) | (_, Severity::Deviation) => Status::Deviation,
        (_, Severity::Observation) => Status::Observation,
    };
    let mut lines = vec![Finding {
        severity: f.severity,
        text: f.text.clone(),
    }];
    let frames = |fs: &[Vec<u8>]| {
        fs.iter()
            .map(|x| crate::judge::show(f.mode, x))
            .collect::<Vec<_>>()
            .join(", ")
    };
    lines.push(Finding::observation(format!(
        "first in case {} ({} case(s) with this signature, found by {}): {}{}",
        f.first_case,
        f.count,
        f.classes_text(),
        frames(&f.frames),
        if f.burst { " (back to back)" } else { "" }
    )));
    if !f.minimized.is_empty() {
        lines.push(Finding::observation(format!(
            "minimized to {} frame(s) in {} replay(s){}: {}",
            f.minimized.len(),
            f.replays,
            if f.reproduced {
                ", reproduced"
            } else {
                ", NOT reproduced on replay"
            },
            frames(&f.minimized)
        )));
    }
    if unconfirmed {
        lines.push(Finding::observation(format!(
            "not a deviation: {} replay(s) did not show it again, so it may be this host's timing (a stall that delays a reply into the next case) or an intermittent fault; run the replay below to look again",
            f.replays
        )));
    }
    lines.push(Finding::observation(format!("replay: {}", f.replay)));
    CheckResult {
        id: format!("fuzz.{}", f.signature()),
        title: format!(
            "{} on {:02X}H: {} (found by {})",
            f.kind.name(),
            f.function,
            f.field,
            f.classes_text()
        ),
        mode: Some(f.mode),
        source: "the model's prediction (DriveModel::judge) for every frame; liveness probes after every silence".into(),
        status,
        summary: format!("{} x{}: {}", f.kind.name(), f.count, f.text),
        findings: lines,
        exchanges: f.exchange.clone().into_iter().collect(),
        duration: f.recovery.flatten().unwrap_or_default(),
        node: None,
    }
}

/// The result of a mode's campaign.
pub fn campaign_result(m: &ModeOutcome) -> CheckResult {
    let mode = m.mode.unwrap_or(crate::codec::Mode::Rtu);
    let bound = match m.bound_rate() {
        Some(b) => format!(
            "; the line allows {b:.1} cases/s, {:.0}% of it used",
            100.0 * m.rate() / b.max(1e-9)
        ),
        None => "; the link has no line timing (no bound)".into(),
    };
    let skipped: u64 = m.skipped.values().sum();
    let summary = format!(
        "{} cases in {:.1} s ({:.1} cases/s{bound}), {} liveness probes, {} finding signature(s){}",
        m.cases,
        m.elapsed.as_secs_f64(),
        m.rate(),
        m.probes,
        m.findings.len(),
        if skipped > 0 {
            let why: Vec<String> = m
                .skipped
                .iter()
                .map(|(why, n)| format!("{n}: {why}"))
                .collect();
            format!("; {skipped} case(s) not sent ({})", why.join("; "))
        } else {
            String::new()
        }
    );
    let summary = format!("{summary}; {}", m.timing.describe());
    let summary = match m.hangs.describe() {
        Some(h) => format!("{summary}; {h}"),
        None => summary,
    };
    let summary = if m.host_reruns > 0 {
        format!(
            "{summary}; {} case(s) sent again because this host stalled under them",
            m.host_reruns
        )
    } else {
        summary
    };
    let summary = match &m.brisk {
        Some(g) => format!("{summary}; {}", g.describe()),
        None => summary,
    };
    let (status, summary) = match (&m.stopped, m.ran) {
        (Some(why), false) => (Status::Error, why.clone()),
        (Some(why), true) if why != "interrupted" => {
            (Status::Error, format!("{summary}; stopped: {why}"))
        }
        _ => (Status::Pass, summary),
    };
    CheckResult {
        id: format!("fuzz.{mode}.campaign"),
        title: "fuzz campaign: every answer predicted by the model".into(),
        mode: Some(mode),
        source: "conformance fuzz".into(),
        status,
        summary,
        findings: Vec::new(),
        exchanges: Vec::new(),
        duration: m.elapsed,
        node: None,
    }
}

impl FuzzSummary {
    /// The `fuzz` section of the JSON report.
    pub fn to_json(&self) -> Value {
        let modes: Vec<Value> = self
            .modes
            .iter()
            .map(|m| {
                json!({
                    "mode": m.mode.map(|x| x.to_string()),
                    "cases": m.cases,
                    "skipped": m.skipped,
                    "elapsed_ms": ms(m.elapsed),
                    "cases_per_s": (m.rate() * 10.0).round() / 10.0,
                    "bound_cases_per_s": m.bound_rate().map(|b| (b * 10.0).round() / 10.0),
                    "liveness_probes": m.probes,
                    "hangs": m.hangs.to_json(),
                    "host_reruns": m.host_reruns,
                    "timing": m.timing.to_json(),
                    "storm": m.storm.as_ref().map(|s| s.to_json()),
                    "brisk": m.brisk.map(|g| json!({
                        "sequenced": g.sequenced,
                        "waited": g.waited,
                        "bursts": g.bursts,
                        "reruns": g.reruns,
                        "rerun_cases": g.rerun_cases,
                        "stray_bytes": g.stray_bytes,
                        "unconfirmed": g.unconfirmed,
                        "framing_delay_ms": ms(g.framing_delay),
                    })),
                    "findings": m.findings.iter().map(|f| json!({
                        "signature": f.signature(),
                        "kind": f.kind.name(),
                        "function": format!("{:02X}", f.function),
                        "field_class": f.field,
                        "classes": f.classes,
                        "count": f.count,
                        "first_case": f.first_case,
                        "frames": f.frames.iter().map(|x| Hex(x).to_string()).collect::<Vec<_>>(),
                        "burst": f.burst,
                        "minimized": f.minimized.iter().map(|x| Hex(x).to_string()).collect::<Vec<_>>(),
                        "reproduced": f.reproduced,
                        "replays": f.replays,
                        "recovery_ms": f.recovery.map(|r| r.map(ms)),
                        "replay": f.replay,
                    })).collect::<Vec<_>>(),
                })
            })
            .collect();
        json!({
            "seed": format!("{:#x}", self.seed),
            "writes": self.writes,
            "modes": modes,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::Mode;

    fn finding(kind: Kind, severity: Severity, replays: u32, reproduced: bool) -> FuzzFinding {
        FuzzFinding {
            kind,
            mode: Mode::Rtu,
            function: 0x03,
            field: "reply-to-other-address".into(),
            classes: [("read", 1)].into_iter().collect(),
            count: 1,
            first_case: 7,
            frames: vec![vec![0xF3, 0x03, 0x00, 0x2C, 0x00, 0x7C, 0x90, 0xF0]],
            burst: false,
            timed: None,
            minimized: vec![vec![0xF3, 0x03, 0x00, 0x2C, 0x00, 0x7C, 0x90, 0xF0]],
            reproduced,
            replays,
            text: "a reply to another node's request".into(),
            severity,
            exchange: None,
            recovery: None,
            register: None,
            replay: "conformance send ...".into(),
        }
    }

    #[test]
    fn a_finding_replayed_and_not_seen_again_is_an_observation() {
        for kind in [Kind::Hang, Kind::UnexpectedReply] {
            let r = finding_result(&finding(kind, Severity::Deviation, 2, false));
            assert_eq!(r.status, Status::Observation, "{kind:?}");
            assert!(
                r.findings.iter().any(|f| f
                    .text
                    .starts_with("not a deviation: 2 replay(s) did not show it again")),
                "{:?}",
                r.findings
            );
            // Reproduced, or never replayed (--no-minimize): as its kind and severity say.
            assert_eq!(
                finding_result(&finding(kind, Severity::Deviation, 2, true)).status,
                Status::Deviation
            );
            assert_eq!(
                finding_result(&finding(kind, Severity::Deviation, 0, false)).status,
                Status::Deviation
            );
        }
    }
}
