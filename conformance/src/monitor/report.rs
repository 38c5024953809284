//! A listening session as a report: one result per node, side and kind of finding (its
//! first example and how often it came), a passing result per node and side where
//! nothing was found, and the per-node statistics.

use std::time::Duration;

use serde_json::{json, Value};

use super::stats::count_of;
use super::{Monitor, NodeStats, Side};
use crate::judge::{Finding, Severity};
use crate::runner::{CheckResult, ExchangeRecord, Status};

/// The monitor section of a report.
#[derive(Debug, Clone, Default)]
pub struct MonitorSummary {
    /// RTU or ASCII.
    pub mode: String,
    /// The port listened to.
    pub port: String,
    /// The line ("9600 8E1").
    pub line: String,
    /// The response window, ms.
    pub window_ms: u64,
    /// Frames seen.
    pub frames: u64,
    /// Bytes seen.
    pub bytes: u64,
    /// How long the bus was listened to: on a port, from the start to the end of the
    /// listening, the search for its settings included; in a capture, from its first
    /// packet to the end of its last.
    pub listened: Duration,
    /// The first part of [`MonitorSummary::listened`] spent finding the line's settings
    /// or its mode (with no `-b`, or `--mode auto`), before the judging began; `None`
    /// where nothing was searched for.
    pub searched: Option<Duration>,
    /// Why listening ended.
    pub ended: String,
    /// Per node (address 00 is the broadcast address), its statistics.
    pub nodes: Vec<(u8, NodeStats)>,
    /// What the monitor said once about the tap (its latency timer).
    pub notices: Vec<String>,
}

impl MonitorSummary {
    /// The section as the JSON report carries it.
    pub fn to_json(&self) -> Value {
        json!({
            "mode": self.mode,
            "port": self.port,
            "line": self.line,
            "window_ms": self.window_ms,
            "frames": self.frames,
            "bytes": self.bytes,
            "listened_s": secs(self.listened),
            "searched_s": self.searched.map(secs),
            "ended": self.ended,
            "nodes": self.nodes.iter().map(|(a, s)| s.to_json(*a)).collect::<Vec<_>>(),
            "notices": self.notices,
        })
    }

    /// The section read back from [`MonitorSummary::to_json`] (`.monitor` of a saved
    /// report), or what is wrong with it, by its path. Reports older than `searched_s`
    /// searched nothing.
    pub fn from_json(v: &Value) -> Result<MonitorSummary, String> {
        let p = ".monitor";
        let text = |key: &str| -> Result<String, String> {
            v.get(key)
                .and_then(Value::as_str)
                .map(str::to_string)
                .ok_or_else(|| format!("{p}.{key}: missing or not a string"))
        };
        let seconds = |key: &str| -> Result<Option<Duration>, String> {
            match v.get(key) {
                None | Some(Value::Null) => Ok(None),
                Some(x) => x
                    .as_f64()
                    .filter(|s| s.is_finite() && *s >= 0.0 && *s < 1e9)
                    .map(|s| Some(Duration::from_secs_f64(s)))
                    .ok_or_else(|| format!("{p}.{key}: {x} is not a number of seconds")),
            }
        };
        let list = |key: &str| -> Result<&Vec<Value>, String> {
            v.get(key)
                .and_then(Value::as_array)
                .ok_or_else(|| format!("{p}.{key}: missing or not an array"))
        };
        Ok(MonitorSummary {
            mode: text("mode")?,
            port: text("port")?,
            line: text("line")?,
            window_ms: count_of(v, "window_ms", p)?,
            frames: count_of(v, "frames", p)?,
            bytes: count_of(v, "bytes", p)?,
            listened: seconds("listened_s")?.ok_or_else(|| format!("{p}.listened_s: missing"))?,
            searched: seconds("searched_s")?,
            ended: text("ended")?,
            nodes: list("nodes")?
                .iter()
                .enumerate()
                .map(|(i, n)| NodeStats::from_json(n, &format!("{p}.nodes[{i}]")))
                .collect::<Result<_, _>>()?,
            notices: match v.get("notices") {
                None | Some(Value::Null) => &[][..],
                Some(_) => list("notices")?,
            }
            .iter()
            .enumerate()
            .map(|(i, n)| {
                n.as_str()
                    .map(str::to_string)
                    .ok_or_else(|| format!("{p}.notices[{i}]: not a string"))
            })
            .collect::<Result<_, _>>()?,
        })
    }

    /// How long the bus was listened to, and the part of it the search took.
    pub fn listened_phrase(&self) -> String {
        match self.searched {
            // What was heard at the setting found is judged too: the search's time is
            // named, not taken off.
            Some(s) => format!(
                "listened {:.1} s, of which {:.1} s finding the line's settings",
                self.listened.as_secs_f64(),
                s.as_secs_f64(),
            ),
            None => format!("listened {:.1} s", self.listened.as_secs_f64()),
        }
    }

    /// One line per node: its counts, response times and findings so far.
    pub fn node_lines(&self) -> Vec<String> {
        self.text_lines()
            .into_iter()
            .skip(1 + self.notices.len())
            .collect()
    }

    /// The per-node statistics as text lines.
    pub fn text_lines(&self) -> Vec<String> {
        let mut out = vec![format!(
            "{}{} on {} ({}, {}): {} frames, {} bytes; {}",
            self.listened_phrase(),
            if self.searched.is_some() { "," } else { "" },
            self.port,
            self.mode,
            self.line,
            self.frames,
            self.bytes,
            self.ended
        )];
        for n in &self.notices {
            out.push(format!("notice: {n}"));
        }
        for (a, s) in &self.nodes {
            let [requests, exchanges, replies, timeouts, crc_errors, retries, p50, p95, p99, max] =
                s.figures();
            out.push(format!(
                "node {a:02X}: {requests} requests, {exchanges} exchanges, {replies} replies, {timeouts} timeouts, {crc_errors} CRC errors, {retries} retries; response ms p50 {p50} p95 {p95} p99 {p99} max {max}"
            ));
            if !s.errors.is_empty() {
                out.push(format!("         findings: {}", s.findings_text()));
            }
        }
        out
    }
}

/// Seconds to the millisecond, as the JSON carries them.
fn secs(d: Duration) -> f64 {
    (d.as_secs_f64() * 1000.0).round() / 1000.0
}

impl Monitor {
    /// The session's summary: `port` listened to, `ended` why it stopped.
    pub fn summary(&self, port: &str, ended: &str) -> MonitorSummary {
        MonitorSummary {
            mode: self.cfg.mode.to_string(),
            port: port.to_string(),
            line: self.cfg.line.to_string(),
            window_ms: u64::try_from(self.cfg.window.as_millis()).unwrap_or(u64::MAX),
            frames: self.frames,
            bytes: self.bytes,
            listened: self
                .last_at
                .zip(self.first_at)
                .map_or(Duration::ZERO, |(l, f)| l.saturating_sub(f)),
            searched: None,
            ended: ended.to_string(),
            nodes: self.nodes.iter().map(|(a, s)| (*a, s.clone())).collect(),
            notices: self.notices.clone(),
        }
    }

    /// One result per node, side and kind of finding; a pass per node and side where
    /// nothing was found.
    pub fn results(&self) -> Vec<CheckResult> {
        let mode = self.cfg.mode;
        let m = mode.to_string();
        let mut out = Vec::new();
        for (&node, stats) in &self.nodes {
            for side in [Side::Drive, Side::Master] {
                let mut any = false;
                for ((_, _, kind), e) in self
                    .examples
                    .range((node, side, "")..)
                    .take_while(|((n, s, _), _)| *n == node && *s == side)
                {
                    any = true;
                    out.push(CheckResult {
                        id: format!("{m}.node{node:02X}.{}.{kind}", side.key()),
                        title: format!("{} of node {node:02X}: {kind}", title(side)),
                        mode: Some(mode),
                        source: source(self, side, &e.citations),
                        status: match e.severity {
                            Severity::Deviation => Status::Deviation,
                            Severity::Observation => Status::Observation,
                        },
                        summary: format!("{} exchange(s); the first: {}", e.count, e.text),
                        findings: vec![Finding {
                            severity: e.severity,
                            text: format!("{} (seen {} time(s))", e.text, e.count),
                        }],
                        exchanges: vec![match side {
                            Side::Drive => e.exchange.clone(),
                            Side::Master => as_master_finding(&e.exchange),
                        }],
                        duration: Duration::ZERO,
                        node: Some(node),
                    });
                }
                let judged = match side {
                    Side::Drive => stats.exchanges,
                    Side::Master => stats.requests,
                };
                if !any && judged > 0 {
                    out.push(CheckResult {
                        id: format!("{m}.node{node:02X}.{}", side.key()),
                        title: format!("{} of node {node:02X}", title(side)),
                        mode: Some(mode),
                        source: source(self, side, &[]),
                        status: Status::Pass,
                        summary: format!(
                            "{judged} {} judged; nothing found",
                            match side {
                                Side::Drive => "exchanges",
                                Side::Master => "requests",
                            }
                        ),
                        findings: Vec::new(),
                        exchanges: Vec::new(),
                        duration: Duration::ZERO,
                        node: Some(node),
                    });
                }
            }
        }
        out
    }
}

/// The exchange of a finding on the master's side as its result shows it: the request
/// is what deviates, and the drive's reply (often the very one the model predicts) is
/// only its context, so no predicted frame is set beside it to compare with (the same
/// bytes twice, under "expected" and "received", told a reader nothing).
fn as_master_finding(x: &ExchangeRecord) -> ExchangeRecord {
    ExchangeRecord {
        expected: None,
        predicted: format!("what a drive answers to this request: {}", x.predicted),
        ..x.clone()
    }
}

fn title(side: Side) -> &'static str {
    match side {
        Side::Drive => "What the drive answered, heard on the bus",
        Side::Master => "What the master asked, heard on the bus",
    }
}

fn source(m: &Monitor, side: Side, citations: &[String]) -> String {
    let base = match side {
        Side::Drive => format!("{} (the model's prediction, as check)", m.model.manual),
        Side::Master => format!(
            "{}; Modbus over Serial Line V1.02, 2.1 and 2.5.1",
            m.model.manual
        ),
    };
    if citations.is_empty() {
        base
    } else {
        format!("{base}: {}", citations.join("; "))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Issue 33, item 9: a session that began by finding the line's settings says how
    /// long it listened in all and how much of it went to the search, in the text, the
    /// HTML (which shows the same line) and the JSON, which reads back.
    #[test]
    fn the_search_is_part_of_the_time_listened() {
        let mut m = MonitorSummary {
            mode: "rtu".into(),
            port: "pty /tmp/tap".into(),
            line: "19200 8O1".into(),
            listened: Duration::from_millis(15_000),
            searched: Some(Duration::from_millis(8_700)),
            ended: "--duration passed".into(),
            ..MonitorSummary::default()
        };
        assert!(
            m.text_lines()[0].starts_with(
                "listened 15.0 s, of which 8.7 s finding the line's settings, on pty /tmp/tap"
            ),
            "{:?}",
            m.text_lines()
        );
        let json = m.to_json();
        assert_eq!(json["searched_s"], 8.7);
        assert_eq!(MonitorSummary::from_json(&json).unwrap().to_json(), json);
        m.searched = None;
        assert!(m.text_lines()[0].starts_with("listened 15.0 s on "));
        assert_eq!(m.to_json()["searched_s"], Value::Null);
    }
}
