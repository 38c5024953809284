//! Reading a saved JSON report back into a [`Report`], so that every format (text, JUnit,
//! HTML, CSV) and `conformance diff` work from the one source: the JSON a run wrote.

use std::collections::BTreeMap;
use std::time::Duration;

use serde_json::Value;

use super::{Codec, Device, NodeInfo, Report, ReportKind, RunOptions};
use crate::codec::hex::parse_hex;
use crate::codec::Mode;
use crate::runner::{
    CheckResult, ExchangeRecord, Finding, LineBudget, ModeBudget, RestoreRecord, Severity, Status,
};

use super::error::{field, ReportError};

fn get<'a>(v: &'a Value, key: &str, path: &str) -> Result<&'a Value, ReportError> {
    v.get(key)
        .ok_or_else(|| field(&format!("{path}.{key}"), "missing"))
}

fn string(v: &Value, key: &str, path: &str) -> Result<String, ReportError> {
    get(v, key, path)?
        .as_str()
        .map(str::to_string)
        .ok_or_else(|| field(&format!("{path}.{key}"), "not a string"))
}

fn opt_string(v: &Value, key: &str, path: &str) -> Result<Option<String>, ReportError> {
    match v.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(Value::String(s)) => Ok(Some(s.clone())),
        Some(_) => Err(field(&format!("{path}.{key}"), "not a string")),
    }
}

fn boolean(v: &Value, key: &str, path: &str) -> Result<bool, ReportError> {
    get(v, key, path)?
        .as_bool()
        .ok_or_else(|| field(&format!("{path}.{key}"), "not true or false"))
}

fn uint(v: &Value, key: &str, path: &str) -> Result<u64, ReportError> {
    get(v, key, path)?
        .as_u64()
        .ok_or_else(|| field(&format!("{path}.{key}"), "not a whole number"))
}

fn millis(v: &Value, key: &str, path: &str) -> Result<Duration, ReportError> {
    let ms = get(v, key, path)?
        .as_f64()
        .filter(|x| x.is_finite() && *x >= 0.0 && *x < 1e12)
        .ok_or_else(|| field(&format!("{path}.{key}"), "not a number of milliseconds"))?;
    Ok(Duration::from_secs_f64(ms / 1000.0))
}

fn array<'a>(v: &'a Value, key: &str, path: &str) -> Result<&'a Vec<Value>, ReportError> {
    get(v, key, path)?
        .as_array()
        .ok_or_else(|| field(&format!("{path}.{key}"), "not an array"))
}

fn strings(v: &Value, key: &str, path: &str) -> Result<Vec<String>, ReportError> {
    array(v, key, path)?
        .iter()
        .enumerate()
        .map(|(i, s)| {
            s.as_str()
                .map(str::to_string)
                .ok_or_else(|| field(&format!("{path}.{key}[{i}]"), "not a string"))
        })
        .collect()
}

fn hex_u(v: &Value, key: &str, path: &str) -> Result<u64, ReportError> {
    let s = string(v, key, path)?;
    let digits = s.strip_prefix("0x").unwrap_or(&s);
    u64::from_str_radix(digits, 16)
        .map_err(|_| field(&format!("{path}.{key}"), format!("{s:?} is not hex")))
}

/// An optional node address ("05", hex as the report writes it).
fn opt_node(v: &Value, key: &str, path: &str) -> Result<Option<u8>, ReportError> {
    match opt_string(v, key, path)? {
        None => Ok(None),
        Some(s) => u8::from_str_radix(&s, 16).map(Some).map_err(|_| {
            field(
                &format!("{path}.{key}"),
                format!("{s:?} is not a node address"),
            )
        }),
    }
}

/// A 16-bit value written as hex, or null.
fn opt_word(v: &Value, key: &str, path: &str) -> Result<Option<u16>, ReportError> {
    match opt_string(v, key, path)? {
        None => Ok(None),
        Some(s) => u16::from_str_radix(&s, 16)
            .map(Some)
            .map_err(|_| field(&format!("{path}.{key}"), format!("{s:?} is not hex"))),
    }
}

fn bytes(s: &str, path: &str) -> Result<Vec<u8>, ReportError> {
    parse_hex(s).map_err(|e| field(path, format!("not hex bytes: {e}")))
}

fn mode(s: &str, path: &str) -> Result<Mode, ReportError> {
    Mode::from_key(s).ok_or_else(|| field(path, format!("{s:?} is not rtu or ascii")))
}

fn status(s: &str, path: &str) -> Result<Status, ReportError> {
    Ok(match s {
        "pass" => Status::Pass,
        "deviation" => Status::Deviation,
        "observation" => Status::Observation,
        "skip" => Status::Skip,
        "error" => Status::Error,
        _ => return Err(field(path, format!("{s:?} is not a status"))),
    })
}

fn exchange(e: &Value, path: &str) -> Result<ExchangeRecord, ReportError> {
    let opt_bytes = |key: &str| -> Result<Option<Vec<u8>>, ReportError> {
        opt_string(e, key, path)?
            .map(|s| bytes(&s, &format!("{path}.{key}")))
            .transpose()
    };
    Ok(ExchangeRecord {
        request: bytes(&string(e, "request", path)?, &format!("{path}.request"))?,
        expected: opt_bytes("expected")?,
        received: bytes(&string(e, "received", path)?, &format!("{path}.received"))?,
        reply: opt_bytes("reply")?,
        predicted: string(e, "predicted", path)?,
        actual: string(e, "actual", path)?,
        latency: match e.get("latency_ms") {
            None | Some(Value::Null) => None,
            Some(_) => Some(millis(e, "latency_ms", path)?),
        },
    })
}

fn check(c: &Value, path: &str) -> Result<CheckResult, ReportError> {
    let findings = array(c, "findings", path)?
        .iter()
        .enumerate()
        .map(|(i, f)| {
            let p = format!("{path}.findings[{i}]");
            let severity = match string(f, "severity", &p)?.as_str() {
                "deviation" => Severity::Deviation,
                "observation" => Severity::Observation,
                s => return Err(field(&p, format!("{s:?} is not a severity"))),
            };
            Ok(Finding {
                severity,
                text: string(f, "text", &p)?,
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    let exchanges = array(c, "exchanges", path)?
        .iter()
        .enumerate()
        .map(|(i, e)| exchange(e, &format!("{path}.exchanges[{i}]")))
        .collect::<Result<Vec<_>, _>>()?;
    Ok(CheckResult {
        id: string(c, "id", path)?,
        title: string(c, "title", path)?,
        mode: opt_string(c, "mode", path)?
            .map(|m| mode(&m, &format!("{path}.mode")))
            .transpose()?,
        source: string(c, "source", path)?,
        status: status(&string(c, "status", path)?, &format!("{path}.status"))?,
        summary: string(c, "summary", path)?,
        findings,
        exchanges,
        duration: millis(c, "duration_ms", path)?,
        node: opt_node(c, "node", path)?,
    })
}

fn budget(b: &Value, path: &str) -> Result<ModeBudget, ReportError> {
    let bound = millis(b, "bound_ms", path)?;
    let frames = uint(b, "frames", path)?;
    let no_bound = match b.get("no_bound") {
        None | Some(Value::Null) if bound.is_zero() && frames > 0 => {
            // Older reports: a zero bound was only ever a gateway's.
            Some(crate::runner::NoBound::Gateway)
        }
        None | Some(Value::Null) => None,
        Some(v) => Some(
            v.as_str()
                .and_then(crate::runner::NoBound::from_key)
                .ok_or_else(|| {
                    field(
                        &format!("{path}.no_bound"),
                        format!("{v} is not \"gateway\" or \"pty\""),
                    )
                })?,
        ),
    };
    Ok(ModeBudget {
        host_reruns: match b.get("host_reruns") {
            None | Some(Value::Null) => 0,
            Some(_) => u32::try_from(uint(b, "host_reruns", path)?).unwrap_or(u32::MAX),
        },
        wall: millis(b, "wall_ms", path)?,
        bound,
        no_bound,
        line: LineBudget {
            frames: uint(b, "frames", path)?,
            bytes_sent: uint(b, "bytes_sent", path)?,
            bytes_received: uint(b, "bytes_received", path)?,
            response: millis(b, "response_ms", path)?,
            silences: uint(b, "silences", path)?,
            max_response: millis(b, "max_response_ms", path)?,
            busy: Duration::ZERO,
            // Absent: none (and from reports older than the field).
            broken_sends: match b.get("broken_sends") {
                None => 0,
                Some(_) => uint(b, "broken_sends", path)?,
            },
        },
    })
}

impl Report {
    /// Parses the text of a JSON report.
    pub fn from_json_str(text: &str) -> Result<Report, ReportError> {
        Report::from_json(&serde_json::from_str(text)?)
    }

    /// Reads a report back from the JSON [`Report::to_json`] wrote (schema
    /// `vectors/schema/report.schema.json`). What the JSON does not hold (the line's busy
    /// time) is zero.
    pub fn from_json(v: &Value) -> Result<Report, ReportError> {
        if v.get("schema").and_then(Value::as_str) != Some("teco-modbus-conformance/report") {
            return Err(ReportError::NotAReport(
                "no \"schema\": \"teco-modbus-conformance/report\" field".into(),
            ));
        }
        let version = uint(v, "schema_version", "")?;
        if version != u64::from(super::SCHEMA_VERSION) {
            return Err(ReportError::NotAReport(format!(
                "schema version {version}; this suite reads version {}",
                super::SCHEMA_VERSION
            )));
        }
        let kind = match string(v, "kind", "")?.as_str() {
            "drive" => ReportKind::Drive,
            "gate" => ReportKind::Gate,
            "fuzz" => ReportKind::Fuzz,
            "monitor" => ReportKind::Monitor,
            k => {
                return Err(field(
                    ".kind",
                    format!("{k:?} is not drive, gate, fuzz or monitor"),
                ))
            }
        };
        let device = match get(v, "device", "")? {
            Value::Null => Device::default(),
            d => {
                let p = ".device";
                let links = match d.get("links") {
                    Some(Value::Object(m)) => m
                        .iter()
                        .map(|(k, l)| {
                            l.as_str()
                                .map(|s| (k.clone(), s.to_string()))
                                .ok_or_else(|| field(&format!("{p}.links.{k}"), "not a string"))
                        })
                        .collect::<Result<BTreeMap<_, _>, _>>()?,
                    _ => BTreeMap::new(),
                };
                Device {
                    model: string(d, "model", p)?,
                    manual: string(d, "manual", p)?,
                    address: u8::try_from(hex_u(d, "address", p)?)
                        .map_err(|_| field(".device.address", "not a node address"))?,
                    links,
                    line: string(d, "line", p)?,
                    identification: opt_word(d, "identification", p)?,
                    simulated: if boolean(d, "simulated", p)? {
                        Some(strings(d, "quirks", p)?)
                    } else {
                        None
                    },
                    // Reports older than the description's record have none.
                    description: match d.get("description") {
                        None | Some(Value::Null) => None,
                        Some(s) => {
                            let p = format!("{p}.description");
                            Some(crate::model::Source {
                                file: opt_string(s, "file", &p)?,
                                title: string(s, "title", &p)?,
                                sha256: string(s, "sha256", &p)?,
                            })
                        }
                    },
                    // Reports of one node (and reports older than several-node runs)
                    // have no list.
                    nodes: match d.get("nodes") {
                        None | Some(Value::Null) => Vec::new(),
                        Some(_) => array(d, "nodes", p)?
                            .iter()
                            .enumerate()
                            .map(|(i, n)| {
                                let p = format!("{p}.nodes[{i}]");
                                Ok(NodeInfo {
                                    address: opt_node(n, "address", &p)?
                                        .ok_or_else(|| field(&format!("{p}.address"), "missing"))?,
                                    identification: opt_word(n, "identification", &p)?,
                                    stopped: opt_string(n, "stopped", &p)?,
                                    quirks: match n.get("quirks") {
                                        None | Some(Value::Null) => Vec::new(),
                                        Some(_) => strings(n, "quirks", &p)?,
                                    },
                                })
                            })
                            .collect::<Result<Vec<_>, ReportError>>()?,
                    },
                }
            }
        };
        let codec = match v.get("codec") {
            None | Some(Value::Null) => None,
            Some(c) => {
                let p = ".codec";
                Some(Codec {
                    adapter: string(c, "adapter", p)?,
                    implementation: string(c, "implementation", p)?,
                    version: string(c, "version", p)?,
                    command: string(c, "command", p)?,
                    supports: strings(c, "supports", p)?,
                    incidents: strings(c, "incidents", p)?,
                    seed: hex_u(c, "seed", p)?,
                    count: usize::try_from(uint(c, "count", p)?).unwrap_or(usize::MAX),
                })
            }
        };
        let o = get(v, "options", "")?;
        let p = ".options";
        let options = RunOptions {
            modes: strings(o, "modes", p)?
                .iter()
                .map(|m| mode(m, ".options.modes"))
                .collect::<Result<_, _>>()?,
            read_only: boolean(o, "read_only", p)?,
            allow_motion: boolean(o, "allow_motion", p)?,
            timeout_ms: uint(o, "timeout_ms", p)?,
            retries: u32::try_from(uint(o, "retries", p)?).unwrap_or(u32::MAX),
            only: strings(o, "only", p)?,
            response_time_ms: o.get("response_time_ms").and_then(Value::as_f64),
            response_allowance_ms: o.get("response_allowance_ms").and_then(Value::as_u64),
        };
        let results = array(v, "checks", "")?
            .iter()
            .enumerate()
            .map(|(i, c)| check(c, &format!(".checks[{i}]")))
            .collect::<Result<Vec<_>, _>>()?;
        let restore = array(v, "restore", "")?
            .iter()
            .enumerate()
            .map(|(i, r)| {
                let p = format!(".restore[{i}]");
                Ok(RestoreRecord {
                    node: opt_node(r, "node", &p)?,
                    register: u16::try_from(hex_u(r, "register", &p)?)
                        .map_err(|_| field(&p, "register beyond FFFF"))?,
                    original: u16::try_from(hex_u(r, "original", &p)?)
                        .map_err(|_| field(&p, "value beyond FFFF"))?,
                    restored: boolean(r, "restored", &p)?,
                    // Older reports counted every journalled register as changed.
                    changed: r.get("changed").and_then(Value::as_bool).unwrap_or(true),
                    detail: string(r, "detail", &p)?,
                })
            })
            .collect::<Result<Vec<_>, ReportError>>()?;
        let budget = match v.get("budget") {
            Some(Value::Object(m)) => m
                .iter()
                .map(|(k, b)| Ok((k.clone(), budget(b, &format!(".budget.{k}"))?)))
                .collect::<Result<BTreeMap<_, _>, ReportError>>()?,
            _ => BTreeMap::new(),
        };
        let expect = super::expect_json::read_outcome(v, &results)?;
        Ok(Report {
            kind,
            codec,
            started: string(v, "started", "")?,
            finished: opt_string(v, "finished", "")?,
            complete: boolean(v, "complete", "")?,
            stopped: opt_string(v, "stopped", "")?,
            device,
            options,
            results,
            restore,
            budget,
            // The campaign summary of a fuzz report is not read back: its checks are.
            fuzz: None,
            // What the monitor heard: its per-node statistics, histograms and notices.
            monitor: match v.get("monitor") {
                Some(m) if !m.is_null() => {
                    Some(crate::monitor::MonitorSummary::from_json(m).map_err(|e| {
                        // The error names its own path (".monitor.nodes[2].address: ...").
                        let (path, problem) = e.split_once(": ").unwrap_or((".monitor", &e));
                        field(path, problem)
                    })?)
                }
                _ => None,
            },
            expect,
            master: match v.get("master") {
                Some(m) if !m.is_null() => Some(
                    crate::gate::master::MasterSummary::from_json(m)
                        .map_err(|e| field(".master", e))?,
                ),
                _ => None,
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::report::fixtures;

    /// A run of one deviation with a restore, of a node other than 01H, simulated with a
    /// fault, from a description, run with --only: every part the reader reads back.
    fn sample() -> Report {
        let mut r = fixtures::base(
            vec![fixtures::result(
                "rtu.map.group-0.past-end",
                Status::Deviation,
                None,
            )],
            vec![fixtures::restore(None, 0x2502, true, true)],
        );
        r.device.address = 0x0A;
        r.device.simulated = Some(vec!["wrong-exception".into()]);
        r.device.description = Some(crate::model::Source::of(
            Some("models/x100.json"),
            "Acme X100 user manual rev C",
            b"{}",
        ));
        r.options.only = vec!["rtu.*".into()];
        r
    }

    #[test]
    fn a_report_reads_back_as_it_was_written() {
        let json = sample().to_json();
        let back = Report::from_json(&json).unwrap();
        assert_eq!(back.to_json(), json);
        assert_eq!(
            back.results[0].exchanges[0].reply,
            Some(vec![1, 0x83, 3, 1, 0x31])
        );
    }

    #[test]
    fn a_broken_report_names_the_field() {
        let mut json = sample().to_json();
        json["checks"][0]["status"] = "fine".into();
        let e = Report::from_json(&json).unwrap_err().to_string();
        assert!(e.contains(".checks[0].status"), "{e}");
        assert!(e.contains("\"fine\" is not a status"), "{e}");
        assert!(matches!(
            Report::from_json_str("[1, 2]"),
            Err(ReportError::NotAReport(_))
        ));
        assert!(matches!(
            Report::from_json_str("{ nope"),
            Err(ReportError::Json(_))
        ));
    }
}
