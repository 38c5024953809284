//! What `conformance watch` prints: the table a terminal redraws, one row per poll as
//! CSV or a JSON line, and the summary. The HTML trend report is in `html/trend.rs`.
//!
//! CSV columns, in order (RFC 4180, CRLF line ends): `time` (RFC 3339, UTC, ms),
//! `elapsed_s` (since the watch started), `node` (hex), `poll` (the node's poll number,
//! from 1), `outcome` (ok, timeout, bad-checksum, exception, bad-reply: the worst of the
//! poll's reads), `rtt_ms` (empty unless every read came back), `exceptions` (codes in
//! hex, `;` between), `observations` (`REG:kind`, `;` between: out-of-range,
//! reserved-bit), then per register watched `REGH` (the raw value, 4 hex digits) and
//! `REGH_value` (the value in the unit the model gives, else the raw value in decimal);
//! both empty where its read failed.

use std::fmt::Write as _;
use std::time::Duration;

use serde_json::{json, Value};

use super::csv::field;
use crate::watch::{Cell, NodeStats, Poll, ReadEnd, Watcher};

fn ms(d: Duration) -> String {
    format!("{:.1}", d.as_secs_f64() * 1000.0)
}

fn opt_ms(d: Option<Duration>) -> String {
    d.map_or("-".to_string(), ms)
}

/// The value of `raw` as text for a CSV cell: the unit's decimals, no unit.
fn number_text(w: &Watcher, register: u16, raw: u16) -> String {
    match w.model.unit_of(register) {
        Some(u) => {
            let shown = u.show(raw);
            shown
                .split(' ')
                .next()
                .unwrap_or(shown.as_str())
                .to_string()
        }
        None => raw.to_string(),
    }
}

/// The set bits of `v` by the model's names ("Inverter ready (1: ready)"), a reserved
/// one as "reserved bit N"; empty where the register has no named bits.
pub fn bits_text(w: &Watcher, register: u16, v: u16) -> String {
    let bits = w.model.bits_of(register);
    bits.iter()
        .filter(|b| v & (1 << b.bit) != 0)
        .map(|b| {
            if b.reserved() {
                format!("reserved bit {}", b.bit)
            } else {
                b.name.clone()
            }
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// A cell's marks: `*` changed in the last poll, `!` out of the model's range, `R` a
/// reserved bit set.
fn marks(c: &Cell) -> String {
    format!(
        "{}{}{}",
        if c.changed { '*' } else { ' ' },
        if c.out_of_range { '!' } else { ' ' },
        if c.reserved_bits.is_empty() { ' ' } else { 'R' }
    )
}

/// One node's statistics on one line.
pub fn stats_line(node: u8, s: &NodeStats) -> String {
    let exceptions = if s.exceptions.is_empty() {
        "0".to_string()
    } else {
        format!(
            "{} ({})",
            s.exception_count(),
            s.exceptions
                .iter()
                .map(|(c, n)| format!("{c:02X}H x{n}"))
                .collect::<Vec<_>>()
                .join(", ")
        )
    };
    let mut line = format!(
        "node {node:02X}: {} poll{}, rtt last {} median {} p99 {} ms; timeouts {}, CRC errors {}, exceptions {}, out of range {}, reserved bits {}",
        s.polls,
        if s.polls == 1 { "" } else { "s" },
        opt_ms(s.last_rtt),
        opt_ms(s.rtt.percentile(50)),
        opt_ms(s.rtt.percentile(99)),
        s.timeouts,
        s.crc_errors,
        exceptions,
        s.out_of_range,
        s.reserved_bits
    );
    for (k, n) in &s.other {
        let _ = write!(line, ", {k} {n}");
    }
    line
}

/// The table a terminal shows after each poll (no escape codes: the caller redraws).
pub fn table_text(w: &Watcher) -> String {
    let mut out = String::new();
    let reads: Vec<String> = w
        .plan
        .reads
        .iter()
        .map(|r| format!("{:04X}H x{}", r.start, r.count))
        .collect();
    let _ = writeln!(
        out,
        "watch {} ({})  {}  {:.1} s  reads per poll: {}",
        w.model.id,
        w.model.manual,
        w.mode,
        w.elapsed().as_secs_f64(),
        reads.join(", ")
    );
    let name_w = w
        .plan
        .registers
        .iter()
        .map(|&r| w.model.describe(r).len().saturating_sub(6))
        .max()
        .unwrap_or(4)
        .clamp(4, 44);
    for n in &w.nodes {
        let header = format!(
            "{:3} {:<5} {:<name_w$} {:>5}  {:<12} BITS",
            "", "REG", "NAME", "RAW", "VALUE"
        );
        let _ = writeln!(out, "\nnode {:02X}\n{header}", n.node);
        for c in &n.cells {
            let described = w.model.describe(c.register);
            // "2520H (State signal)": the name without the number and parentheses.
            let name = described
                .get(7..described.len().saturating_sub(1))
                .unwrap_or("")
                .chars()
                .take(name_w)
                .collect::<String>();
            let (raw, value, bits) = match c.value {
                Some(v) => (
                    format!("{v:04X}H"),
                    w.model.value_text(c.register, v).unwrap_or_default(),
                    bits_text(w, c.register, v),
                ),
                None => ("-".to_string(), String::new(), String::new()),
            };
            let mut extra = String::new();
            if c.out_of_range {
                if let Some(r) = w.model.range_of(c.register) {
                    let _ = write!(extra, "  [out of range: {}]", r.bounds());
                }
            }
            let row = format!(
                "{} {:04X}H {:<name_w$} {:>5}  {:<12} {}{}",
                marks(c),
                c.register,
                name,
                raw,
                value,
                bits,
                extra
            );
            let _ = writeln!(out, "{}", row.trim_end());
        }
        let _ = writeln!(out, "{}", stats_line(n.node, &n.stats));
    }
    out.push_str("\nmarks: * changed  ! out of the model's range  R reserved bit set\n");
    out
}

/// The CSV header for `w`'s registers (see the module notes), CRLF-terminated.
pub fn csv_header(w: &Watcher) -> String {
    let mut s = String::from("time,elapsed_s,node,poll,outcome,rtt_ms,exceptions,observations");
    for r in &w.plan.registers {
        let _ = write!(s, ",{r:04X}H,{r:04X}H_value");
    }
    s.push_str("\r\n");
    s
}

fn rfc3339(p: &Poll) -> String {
    humantime::format_rfc3339_millis(p.at).to_string()
}

/// The values of poll `p` by register, in the order watched (`None`: its read failed).
fn values(w: &Watcher, p: &Poll) -> Vec<(u16, Option<u16>)> {
    let mut got: Vec<(u16, u16)> = Vec::new();
    for (read, end) in w.plan.reads.iter().zip(&p.reads) {
        if let ReadEnd::Values(v) = end {
            got.extend(read.registers().zip(v.iter().copied()));
        }
    }
    w.plan
        .registers
        .iter()
        .map(|&r| (r, got.iter().find(|(x, _)| *x == r).map(|(_, v)| *v)))
        .collect()
}

/// Poll `p` as one CSV row, CRLF-terminated.
pub fn csv_row(w: &Watcher, p: &Poll) -> String {
    let mut s = format!(
        "{},{:.3},{:02X},{},{},{},{},{}",
        rfc3339(p),
        p.elapsed.as_secs_f64(),
        p.node,
        p.number,
        p.outcome(),
        p.rtt.map_or(String::new(), ms),
        field(
            &p.exceptions()
                .iter()
                .map(|c| format!("{c:02X}"))
                .collect::<Vec<_>>()
                .join(";")
        ),
        field(
            &p.observations
                .iter()
                .map(|o| format!("{:04X}H:{}", register_of(o), o.key()))
                .collect::<Vec<_>>()
                .join(";")
        ),
    );
    for (r, v) in values(w, p) {
        match v {
            Some(v) => {
                let _ = write!(s, ",{v:04X},{}", number_text(w, r, v));
            }
            None => s.push_str(",,"),
        }
    }
    s.push_str("\r\n");
    s
}

fn register_of(o: &crate::watch::Observation) -> u16 {
    match o {
        crate::watch::Observation::OutOfRange { register, .. }
        | crate::watch::Observation::ReservedBits { register, .. } => *register,
    }
}

/// Poll `p` as one JSON object (a JSON line): `time`, `elapsed_s`, `node`, `poll`,
/// `outcome`, `rtt_ms` (null unless every read came back), `exceptions` (codes in hex),
/// `findings` (the judge's, in words), `observations` (`register`, `kind`, `text`),
/// `changed` (registers), and `values`: per register (`"2520H"`) its `raw` (hex),
/// `value` (a number: in the unit where the model gives one, else the raw value), `unit`, `text` (as the
/// table shows it), `bits` (the set bits' names), or null where its read failed.
pub fn json_row(w: &Watcher, p: &Poll) -> Value {
    let mut vals = serde_json::Map::new();
    for (r, v) in values(w, p) {
        let entry = match v {
            Some(v) => json!({
                "raw": format!("{v:04X}"),
                "value": match w.model.unit_of(r) {
                    Some(u) => json!(u.value(v)),
                    None => json!(v),
                },
                "unit": w.model.unit_of(r).map(|u| u.unit),
                "text": w.model.value_text(r, v),
                "bits": w.model.bits_of(r).iter()
                    .filter(|b| v & (1 << b.bit) != 0)
                    .map(|b| b.name.clone())
                    .collect::<Vec<_>>(),
            }),
            None => Value::Null,
        };
        vals.insert(format!("{r:04X}H"), entry);
    }
    json!({
        "time": rfc3339(p),
        "elapsed_s": (p.elapsed.as_secs_f64() * 1000.0).round() / 1000.0,
        "node": format!("{:02X}", p.node),
        "poll": p.number,
        "outcome": p.outcome(),
        "rtt_ms": p.rtt.map(|d| (d.as_secs_f64() * 10_000.0).round() / 10.0),
        "exceptions": p.exceptions().iter().map(|c| format!("{c:02X}")).collect::<Vec<_>>(),
        "findings": p.findings,
        "observations": p.observations.iter().map(|o| json!({
            "register": format!("{:04X}H", register_of(o)),
            "kind": o.key(),
            "text": o.text(),
        })).collect::<Vec<_>>(),
        "changed": p.changed.iter().map(|r| format!("{r:04X}H")).collect::<Vec<_>>(),
        "values": vals,
    })
}

/// How a watch whose link failed ended, as its summary and report say it.
pub const LINK_FAILED: &str = "the link failed";

/// The summary at the end: one line per node, and the verdict.
pub fn summary(w: &Watcher, ended: &str) -> String {
    let mut out = format!(
        "watch ended ({ended}) after {:.1} s: {} {}, reads per poll {}\n",
        w.elapsed().as_secs_f64(),
        w.model.id,
        w.mode,
        w.plan.reads.len()
    );
    for n in &w.nodes {
        let _ = writeln!(out, "{}", stats_line(n.node, &n.stats));
        for c in n
            .cells
            .iter()
            .filter(|c| c.out_of_range_count > 0 || c.reserved_count > 0)
        {
            let _ = writeln!(
                out,
                "  {}: out of range {} times, reserved bits set {} times",
                w.model.describe(c.register),
                c.out_of_range_count,
                c.reserved_count
            );
        }
    }
    out.push_str(if ended == LINK_FAILED {
        "result: the link failed (exit 2); the counts above are of the polls before\n"
    } else if w.found() {
        "result: an exception or a value out of the model's range was seen (exit 1)\n"
    } else {
        "result: no exception and no value out of the model's range (exit 0)\n"
    });
    out
}
