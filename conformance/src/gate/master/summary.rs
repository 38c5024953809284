//! What a master gate report says besides its results: the line and settings the master
//! ran with, and its findings grouped by kind, each with the command that reproduces its
//! first case; as JSON (the report's `master` object), read back, and as the lines of the
//! text and HTML reports.

use std::collections::BTreeMap;
use std::time::Duration;

use super::{drive, MasterRun, MasterSettings};
use crate::codec::timing::LineSettings;
use crate::gate::adapter::string_list;
use crate::judge::Severity;

/// The cases that had one kind of finding.
#[derive(Debug, Clone)]
pub struct KindSummary {
    /// The worst severity.
    pub severity: Severity,
    /// Case ids.
    pub cases: Vec<String>,
    /// The first finding's text.
    pub example: String,
    /// The one command that reproduces the first case.
    pub repro: String,
}

/// What a master gate report says besides its results: the master's settings and its
/// findings grouped by kind, each with the command that reproduces its first case.
#[derive(Debug, Clone, Default)]
pub struct MasterSummary {
    /// The modes the master speaks, as its hello says.
    pub modes: Vec<String>,
    /// The lines it can open, as its hello says.
    pub lines: Vec<String>,
    /// Per mode: the timeout and retries it ran with.
    pub settings: BTreeMap<String, MasterSettings>,
    /// Findings by kind.
    pub kinds: BTreeMap<String, KindSummary>,
    /// The line the gate served (`pty`, `tcp-rtu`).
    pub line: String,
    /// The baud rate, data bits, parity and stop bits given to the master in `open` (the
    /// timing the gate judges); None in a report written before they were recorded.
    pub serial: Option<LineSettings>,
}

impl MasterSummary {
    /// As the report's JSON `master` object.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "modes": self.modes,
            "lines": self.lines,
            "line": self.line,
            "serial": self.serial.map(|l| serde_json::json!({
                "baud": l.baud,
                "data_bits": l.data_bits,
                "parity": l.parity.name(),
                "stop_bits": l.stop_bits,
            })),
            "settings": self.settings.iter().map(|(m, s)| (m.clone(), serde_json::json!({
                "timeout_ms": s.timeout.as_millis() as u64,
                "retries": s.retries,
            }))).collect::<serde_json::Map<String, serde_json::Value>>(),
            "kinds": self.kinds.iter().map(|(k, v)| serde_json::json!({
                "kind": k,
                "severity": match v.severity { Severity::Deviation => "deviation", Severity::Observation => "observation" },
                "cases": v.cases,
                "example": v.example,
                "reproduce": v.repro,
            })).collect::<Vec<_>>(),
        })
    }
}

impl MasterSummary {
    /// The summary in the text report: the settings, then each kind of finding with its
    /// cases and the command that reproduces the first.
    pub fn text_lines(&self) -> Vec<String> {
        let mut out: Vec<String> = self
            .settings_lines()
            .into_iter()
            .map(|l| format!("master:  {l}"))
            .collect();
        for (kind, k) in &self.kinds {
            let sev = match k.severity {
                Severity::Deviation => "deviation",
                Severity::Observation => "observation",
            };
            out.push(format!(
                "found:   {kind} ({sev}) in {} case{}: {}",
                k.cases.len(),
                if k.cases.len() == 1 { "" } else { "s" },
                k.cases.join(" ")
            ));
            out.push(format!("         reproduce: {}", k.repro));
        }
        out
    }
}

impl MasterSummary {
    /// The line and the settings the master ran with, one line a mode (text and HTML
    /// reports): `rtu on a pty line, 9600 baud 8E1: its timeout 300 ms, 0 retries`. A run
    /// in which the master opened no line still says which line it was given.
    pub fn settings_lines(&self) -> Vec<String> {
        let serial = match self.serial {
            Some(l) => format!(
                ", {} baud {}{}{}",
                l.baud, l.data_bits, l.parity, l.stop_bits
            ),
            None => String::new(),
        };
        if self.settings.is_empty() {
            return vec![format!(
                "a {} line{serial}, which it did not open",
                self.line
            )];
        }
        self.settings
            .iter()
            .map(|(mode, s)| {
                format!(
                    "{mode} on a {} line{serial}: its timeout {} ms, {} retries",
                    self.line,
                    s.timeout.as_millis(),
                    s.retries
                )
            })
            .collect()
    }
}

impl MasterSummary {
    /// Reads the report's JSON `master` object back (`conformance report` of a saved
    /// master gate report).
    pub fn from_json(v: &serde_json::Value) -> Result<Self, String> {
        use serde_json::Value;
        let mut settings = BTreeMap::new();
        if let Some(m) = v.get("settings").and_then(Value::as_object) {
            for (mode, s) in m {
                let n = |k: &str| {
                    s.get(k)
                        .and_then(Value::as_u64)
                        .ok_or_else(|| format!("settings.{mode}.{k}: not a number"))
                };
                settings.insert(
                    mode.clone(),
                    MasterSettings {
                        timeout: Duration::from_millis(n("timeout_ms")?),
                        retries: u32::try_from(n("retries")?)
                            .map_err(|_| format!("settings.{mode}.retries: too large"))?,
                    },
                );
            }
        }
        let mut kinds = BTreeMap::new();
        for (i, k) in v
            .get("kinds")
            .and_then(Value::as_array)
            .into_iter()
            .flatten()
            .enumerate()
        {
            let text = |f: &str| {
                k.get(f)
                    .and_then(Value::as_str)
                    .map(String::from)
                    .ok_or_else(|| format!("kinds[{i}].{f}: not a string"))
            };
            kinds.insert(
                text("kind")?,
                KindSummary {
                    severity: match text("severity")?.as_str() {
                        "deviation" => Severity::Deviation,
                        "observation" => Severity::Observation,
                        other => return Err(format!("kinds[{i}].severity: {other:?}")),
                    },
                    cases: string_list(k, "cases"),
                    example: text("example")?,
                    repro: text("reproduce")?,
                },
            );
        }
        Ok(MasterSummary {
            modes: string_list(v, "modes"),
            lines: string_list(v, "lines"),
            settings,
            kinds,
            line: v
                .get("line")
                .and_then(Value::as_str)
                .unwrap_or("pty")
                .to_string(),
            serial: match v.get("serial") {
                None | Some(Value::Null) => None,
                Some(l) => Some(serial_from_json(l)?),
            },
        })
    }
}

/// The `serial` object of a report's `master` (see [`MasterSummary::to_json`]).
fn serial_from_json(v: &serde_json::Value) -> Result<LineSettings, String> {
    use crate::codec::timing::Parity;
    let n = |k: &str| {
        v.get(k)
            .and_then(serde_json::Value::as_u64)
            .ok_or_else(|| format!("serial.{k}: not a number"))
    };
    let small = |k: &str| {
        n(k).and_then(|x| u8::try_from(x).map_err(|_| format!("serial.{k}: {x} is too large")))
    };
    let parity = match v.get("parity").and_then(serde_json::Value::as_str) {
        Some("none") => Parity::None,
        Some("even") => Parity::Even,
        Some("odd") => Parity::Odd,
        other => return Err(format!("serial.parity: {other:?}, not none, even or odd")),
    };
    let baud = n("baud")?;
    Ok(LineSettings::new(
        u32::try_from(baud).map_err(|_| format!("serial.baud: {baud} is too large"))?,
        small("data_bits")?,
        parity,
        small("stop_bits")?,
    ))
}

/// The summary of a run, with what the adapter's hello (`raw`) says of the master, and
/// `serial`, the line's settings given to it.
pub fn summary(
    run: &MasterRun,
    raw: &serde_json::Value,
    line: drive::LineKind,
    serial: LineSettings,
) -> MasterSummary {
    MasterSummary {
        modes: string_list(raw, "modes"),
        lines: string_list(raw, "lines"),
        settings: run.settings.clone(),
        kinds: run.by_kind.clone(),
        line: line.key().to_string(),
        serial: Some(serial),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_summary_reads_back_as_it_was_written() {
        let mut s = MasterSummary {
            modes: vec!["rtu".into()],
            lines: vec!["pty".into(), "tcp-rtu".into()],
            line: "tcp-rtu".into(),
            ..MasterSummary::default()
        };
        s.settings.insert(
            "rtu".into(),
            MasterSettings {
                timeout: Duration::from_millis(300),
                retries: 1,
            },
        );
        s.kinds.insert(
            "stale-reply-taken".into(),
            KindSummary {
                severity: Severity::Deviation,
                cases: vec!["rtu.read.stale-reply".into()],
                example: "rtu.read.stale-reply: ...".into(),
                repro: "conformance gate --master 'x' --only rtu.read.stale-reply".into(),
            },
        );
        let back = MasterSummary::from_json(&s.to_json()).unwrap();
        assert_eq!(back.to_json(), s.to_json());
        assert!(MasterSummary::from_json(&serde_json::json!({
            "kinds": [{"kind": "x", "severity": "grave", "cases": [], "example": "", "reproduce": ""}]
        }))
        .unwrap_err()
        .contains("severity"));
        // The line given to the master, read back too.
        s.serial = Some(LineSettings::new(
            19200,
            8,
            crate::codec::timing::Parity::Even,
            1,
        ));
        let back = MasterSummary::from_json(&s.to_json()).unwrap();
        assert_eq!(back.serial, s.serial);
        assert!(MasterSummary::from_json(&serde_json::json!({"serial": {
            "baud": 9600, "data_bits": 8, "parity": "mark", "stop_bits": 1
        }}))
        .unwrap_err()
        .contains("serial.parity"));
    }

    #[test]
    fn the_master_line_says_the_baud_rate_and_the_parity_also_when_nothing_opened() {
        let mut s = MasterSummary {
            line: "pty".into(),
            serial: Some(LineSettings::new(
                9600,
                8,
                crate::codec::timing::Parity::Even,
                1,
            )),
            ..MasterSummary::default()
        };
        assert_eq!(
            s.text_lines(),
            ["master:  a pty line, 9600 baud 8E1, which it did not open"]
        );
        s.settings.insert(
            "rtu".into(),
            MasterSettings {
                timeout: Duration::from_millis(300),
                retries: 0,
            },
        );
        assert_eq!(
            s.settings_lines(),
            ["rtu on a pty line, 9600 baud 8E1: its timeout 300 ms, 0 retries"]
        );
    }
}
