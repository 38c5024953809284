//! `conformance ports` as text for people and as JSON for scripts.

use std::fmt::Write;

use serde_json::json;

use super::latency::{self, ADVISED_MS};
use super::{Port, Roots};

/// The listing for people: one block a port, then the count (or the hint, when none).
pub fn text(ports: &[Port], roots: &Roots) -> String {
    let mut out = String::new();
    for p in ports {
        let _ = writeln!(out, "{}", headline(p));
        for link in &p.by_id {
            let _ = writeln!(out, "  by-id: {}", link.display());
        }
        if let Some(t) = &p.latency_timer {
            let _ = writeln!(out, "  latency timer: {} ms ({})", t.ms, t.file.display());
            let effects = latency::effects(t.ms);
            let breaks = effects.iter().filter(|e| e.breaks_framing).count();
            for e in &effects {
                let _ = writeln!(
                    out,
                    "    {:>6} baud: t3.5 is {:.2} ms; {} ms is {:.1}x t3.5: {}",
                    e.baud,
                    e.t3_5_us as f64 / 1000.0,
                    t.ms,
                    e.times_t3_5,
                    if e.breaks_framing {
                        "replies reach this computer in bursts up to the timer apart, so silences seen here are the adapter's, not the line's"
                    } else {
                        "below t3.5, framing by silence holds"
                    }
                );
            }
            if breaks > 0 {
                let _ = writeln!(
                    out,
                    "  set it to {ADVISED_MS} ms (until the adapter is plugged in again): {}",
                    latency::set_command(&t.file)
                );
            }
        }
        let a = &p.access;
        let _ = writeln!(
            out,
            "  access: {}: {}",
            match a.may_open {
                Some(true) => "you may open it",
                Some(false) => "you may NOT open it",
                None => "unknown",
            },
            a.why
        );
        if let Some(fix) = &a.fix {
            let _ = writeln!(out, "    fix: {fix}");
        }
        if let Some(l) = &p.lock {
            let who = match (l.pid, l.alive) {
                (Some(pid), Some(true)) => format!(
                    "held by pid {pid}{}: close that program first",
                    l.command
                        .as_ref()
                        .map(|c| format!(" ({c})"))
                        .unwrap_or_default()
                ),
                (Some(pid), Some(false)) => format!(
                    "stale: pid {pid} is gone; remove it with: sudo rm {}",
                    l.file.display()
                ),
                (Some(pid), None) => format!("held by pid {pid}"),
                (None, _) => "holds no process id".into(),
            };
            let _ = writeln!(out, "  lock: {} {who}", l.file.display());
        }
    }
    if ports.is_empty() {
        let _ = writeln!(out, "no serial ports found");
        let _ = writeln!(out, "hint: {}", super::none_hint(roots));
    } else {
        let _ = writeln!(
            out,
            "{} serial port{}",
            ports.len(),
            if ports.len() == 1 { "" } else { "s" }
        );
    }
    out
}

/// `/dev/ttyUSB0  FTDI FT232R USB UART (0403:6001, serial A1B2C3), driver ftdi_sio`.
fn headline(p: &Port) -> String {
    let mut what = Vec::new();
    if let Some(u) = &p.usb {
        let name: Vec<&str> = [u.manufacturer.as_deref(), u.product.as_deref()]
            .into_iter()
            .flatten()
            .collect();
        let mut ids = format!("USB {}:{}", u.vid, u.pid);
        if let Some(s) = &u.serial {
            let _ = write!(ids, ", serial {s}");
        }
        if name.is_empty() {
            what.push(ids);
        } else {
            what.push(format!("{} ({ids})", name.join(" ")));
        }
    } else {
        what.push(format!("{:?}", p.kind).to_lowercase());
    }
    if let Some(d) = &p.driver {
        what.push(format!("driver {d}"));
    }
    format!("{}  {}", p.path.display(), what.join(", "))
}

/// The listing for scripts: `{"ports": [...], "count", "hint"}`; each timer with its
/// effect at each rate and the command that sets it.
pub fn json(ports: &[Port], roots: &Roots) -> serde_json::Value {
    let ports: Vec<serde_json::Value> = ports
        .iter()
        .map(|p| {
            let mut v = serde_json::to_value(p).unwrap_or_default();
            if let (Some(t), Some(obj)) = (&p.latency_timer, v.get_mut("latency_timer")) {
                obj["effects"] = serde_json::to_value(latency::effects(t.ms)).unwrap_or_default();
                obj["set_command"] = json!(latency::set_command(&t.file));
            }
            v
        })
        .collect();
    json!({
        "count": ports.len(),
        "hint": if ports.is_empty() { Some(super::none_hint(roots)) } else { None },
        "ports": ports,
    })
}
