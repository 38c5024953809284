//! A scan's result as a table for people and as JSON for machines.

use std::fmt::Write;

use serde_json::{json, Value};

use super::probe::Answer;
use super::{ScanReport, Verdict};
use crate::codec::hex;

fn hex_bytes(bytes: &[u8]) -> String {
    let mut s = String::with_capacity(bytes.len() * 3);
    for (i, b) in bytes.iter().enumerate() {
        if i > 0 {
            s.push(' ');
        }
        let [h, l] = hex::encode_byte(*b);
        s.push(char::from(h));
        s.push(char::from(l));
    }
    s
}

fn ms(d: std::time::Duration) -> f64 {
    (d.as_secs_f64() * 10_000.0).round() / 10.0
}

/// The table: one row a device (address, mode, line, what answered with its bytes, the
/// identification value), then the settings that showed garbage and a summary.
pub fn text(r: &ScanReport) -> String {
    let mut out = String::new();
    let found = r.found.len();
    let _ = writeln!(
        out,
        "scan of {}: {} found in {:.1} s, {} tries{}",
        r.link,
        match found {
            0 => "no device".to_string(),
            1 => "1 device".to_string(),
            n => format!("{n} devices"),
        },
        r.elapsed.as_secs_f64(),
        r.tries,
        r.stopped
            .as_ref()
            .map_or(String::new(), |s| format!(" [{s}]"))
    );
    if !r.searchable {
        let _ = writeln!(
            out,
            "line settings: set in the gateway (not searchable from here); addresses searched only"
        );
    }
    if found > 0 {
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "{:<9} {:<6} {:<10} {:<52} identification",
            "address", "mode", "line", "answered"
        );
        for f in &r.found {
            let answered = format!(
                "{}: {}",
                match f.answer {
                    Answer::Value(_) => "reply",
                    Answer::Exception(_) => "exception",
                    Answer::Other => "frame",
                },
                hex_bytes(&f.frame)
            );
            let ident = match &f.answer {
                Answer::Value(v) if f.models.is_empty() => {
                    format!("252FH = {v:04X}H (no model names this value)")
                }
                Answer::Value(v) => format!("252FH = {v:04X}H: {}", f.models.join(", ")),
                Answer::Exception(c) => format!("none: exception {c:02X}H to a read of 252FH"),
                Answer::Other => "-".into(),
            };
            let line = if r.searchable {
                f.setting.line.to_string()
            } else {
                "gateway".into()
            };
            let mut address = format!("{:02X}H ({})", f.address, f.address);
            if f.asked != f.address {
                address.push_str(&format!(" asked {:02X}H", f.asked));
            }
            let _ = writeln!(
                out,
                "{:<9} {:<6} {:<10} {:<52} {}",
                address,
                f.setting.mode.to_string(),
                line,
                answered,
                ident
            );
            if f.echo {
                let _ = writeln!(out, "{:<9} (local echo: the request came back first)", "");
            }
        }
    }
    let garbage: Vec<_> = r
        .settings
        .iter()
        .filter_map(|s| match &s.verdict {
            Verdict::Garbage { address, bytes } => Some((s, *address, bytes)),
            _ => None,
        })
        .collect();
    if !garbage.is_empty() {
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "garbage (bytes that make no frame: a device talks at another setting; skipped):"
        );
        for (s, a, bytes) in garbage {
            let _ = writeln!(
                out,
                "  {:<16} after a read of node {:02X}H: {}",
                s.setting.to_string(),
                a,
                hex_bytes(bytes)
            );
        }
    }
    if !r.noise.is_empty() {
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "noise at the line's setting (bytes that make no frame; the address was asked again):"
        );
        for n in &r.noise {
            let _ = writeln!(
                out,
                "  after a read of node {:02X}H: {}",
                n.address,
                hex_bytes(&n.bytes)
            );
        }
        if r.noise_more > 0 {
            let _ = writeln!(out, "  and {} more, not kept", r.noise_more);
        }
    }
    if r.retried > 0 {
        let _ = writeln!(out);
        let _ = writeln!(
            out,
            "asked again: {} tries to addresses that drew no valid frame{}",
            r.retried,
            if r.found_on_retry.is_empty() {
                String::new()
            } else {
                format!(
                    "; found only then: {}",
                    r.found_on_retry
                        .iter()
                        .map(|a| format!("{a:02X}H"))
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            }
        );
    }
    if r.host_resends > 0 {
        let _ = writeln!(
            out,
            "sent again: {} requests this host broke while pacing them (a stall between two characters; not tries)",
            r.host_resends
        );
    }
    let count = |f: fn(&Verdict) -> bool| r.settings.iter().filter(|s| f(&s.verdict)).count();
    let _ = writeln!(out);
    let _ = writeln!(
        out,
        "settings: {} answered, {} silent, {} garbage, {} not tried ({} of {} addresses a setting at most)",
        count(|v| matches!(v, Verdict::Answered)),
        count(|v| matches!(v, Verdict::Silent)),
        count(|v| matches!(v, Verdict::Garbage { .. })),
        count(|v| matches!(v, Verdict::Untried | Verdict::Dropped)),
        r.settings
            .iter()
            .map(|s| s.tries - s.retried)
            .max()
            .unwrap_or(0),
        r.addresses
    );
    if let Some(s) = r
        .found
        .first()
        .and_then(|f| r.settings.iter().find(|s| s.setting == f.setting))
        .or_else(|| r.settings.first())
    {
        let w = &s.windows;
        let _ = writeln!(
            out,
            "one try at {}: request {} ms + t3.5 {} ms + reply window {} ms (response time {} ms, 2 characters, slack {} ms) = {} ms",
            s.setting,
            ms(w.request),
            ms(w.t3_5),
            ms(w.reply),
            ms(r.response),
            ms(r.slack),
            ms(w.bound())
        );
    }
    out
}

/// The JSON form.
pub fn json(r: &ScanReport) -> Value {
    json!({
        "link": r.link,
        "line_searchable": r.searchable,
        "found": r.found.iter().map(|f| json!({
            "address": f.address,
            "asked": f.asked,
            "mode": f.setting.mode.to_string(),
            "line": {
                "baud": f.setting.line.baud,
                "data_bits": f.setting.line.data_bits,
                "parity": f.setting.line.parity.to_string(),
                "stop_bits": f.setting.line.stop_bits,
            },
            "answer": match f.answer {
                Answer::Value(_) => "reply",
                Answer::Exception(_) => "exception",
                Answer::Other => "other",
            },
            "exception_code": match f.answer { Answer::Exception(c) => Some(c), _ => None },
            "identification": match f.answer { Answer::Value(v) => Some(format!("{v:04X}")), _ => None },
            "models": f.models,
            "frame_hex": hex_bytes(&f.frame),
            "local_echo": f.echo,
        })).collect::<Vec<_>>(),
        "settings": r.settings.iter().map(|s| json!({
            "setting": s.setting.to_string(),
            "tries": s.tries,
            "retried": s.retried,
            "verdict": match &s.verdict {
                Verdict::Untried => "untried",
                Verdict::Silent => "silent",
                Verdict::Garbage { .. } => "garbage",
                Verdict::Answered => "answered",
                Verdict::Dropped => "dropped",
            },
            "garbage_hex": match &s.verdict {
                Verdict::Garbage { bytes, .. } => Some(hex_bytes(bytes)),
                _ => None,
            },
            "garbage_after_address": match &s.verdict {
                Verdict::Garbage { address, .. } => Some(*address),
                _ => None,
            },
            "try_bound_ms": ms(s.windows.bound()),
            "reply_window_ms": ms(s.windows.reply),
        })).collect::<Vec<_>>(),
        "tries": r.tries,
        "retried": r.retried,
        "found_on_retry": r.found_on_retry,
        "noise": r.noise.iter().map(|n| json!({
            "address": n.address,
            "bytes_hex": hex_bytes(&n.bytes),
        })).collect::<Vec<_>>(),
        "noise_more": r.noise_more,
        "host_resends": r.host_resends,
        "addresses": r.addresses,
        "elapsed_ms": ms(r.elapsed),
        "stopped": r.stopped,
        "response_time_ms": ms(r.response),
        "slack_ms": ms(r.slack),
    })
}
