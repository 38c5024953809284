//! The draft description: what was learned, in the format of `vectors/models`
//! (schema_version 2, see the guide's "Describing your own device"), every fact marked
//! `basis: observed` with the request that showed it. What learn did not try is left
//! out (a check that needs it SKIPs and names the field) or, where the format needs a
//! value, stated as a decision that says it was not tried.

use serde_json::{json, Map, Value};

use super::ask::{Answer, Evidence};
use super::probe::{block_access, write_served};
use super::Learned;

/// The meanings of the exception codes, from the Modbus application protocol V1.1b3, 7.
fn meaning(code: u8) -> &'static str {
    match code {
        0x01 => "Illegal function",
        0x02 => "Illegal data address",
        0x03 => "Illegal data value",
        0x04 => "Server device failure",
        0x05 => "Acknowledge",
        0x06 => "Server device busy",
        0x08 => "Memory parity error",
        0x0A => "Gateway path unavailable",
        0x0B => "Gateway target device failed to respond",
        _ => "(not a code of the Modbus application protocol)",
    }
}

/// `{"basis": "observed", "request": ..., "reply": ...}`.
fn observed(ev: &Evidence) -> Map<String, Value> {
    let mut m = Map::new();
    m.insert("basis".into(), json!("observed"));
    m.insert("request".into(), json!(ev.request));
    if let Some(r) = &ev.reply {
        m.insert("reply".into(), json!(r));
    }
    m
}

fn with(mut m: Map<String, Value>, key: &str, value: Value) -> Value {
    m.insert(key.into(), value);
    Value::Object(m)
}

fn hex4(v: u16) -> String {
    format!("{v:04X}")
}

/// The draft of `learned`, as model `id`, learned on `date` (YYYY-MM-DD).
pub fn draft(learned: &Learned, id: &str, date: &str) -> Value {
    let mut d = Map::new();
    d.insert("schema_version".into(), json!(2));
    d.insert("model".into(), json!(id));
    // A serial link's description names its line settings already.
    let line = if learned.link.contains(&learned.line) {
        learned.mode.to_string()
    } else {
        format!("{} {}", learned.line, learned.mode)
    };
    d.insert(
        "title".into(),
        json!(format!(
            "learned from {} node {} on {date} ({line})",
            learned.link, learned.node
        )),
    );
    d.insert("manual".into(), json!("learned draft"));
    d.insert("notes".into(), json!(notes(learned)));
    d.insert("modes".into(), json!([learned.mode.to_string()]));

    // Functions: the ones seen served. 03H by the map (a reply, or an exception other
    // than the unserved-function one); 06H and 10H only where writes were tried.
    let mut codes: Vec<(u8, Evidence)> = Vec::new();
    if let Some(ev) = learned.map.largest.as_ref().map(|(_, e)| e).or(learned
        .map
        .miss
        .as_ref()
        .map(|(_, _, e)| e))
    {
        codes.push((0x03, ev.clone()));
    }
    for f in &learned.functions {
        if f.served == Some(true) {
            codes.push((f.code, f.evidence.clone()));
        }
    }
    for code in [0x06u8, 0x10] {
        if let Some(ev) = write_served(learned, code) {
            codes.push((code, ev.clone()));
        }
    }
    codes.sort_by_key(|(c, _)| *c);
    if let Some((_, ev)) = codes.first() {
        d.insert(
            "functions".into(),
            with(
                observed(ev),
                "codes",
                json!(codes
                    .iter()
                    .map(|(c, _)| format!("{c:02X}"))
                    .collect::<Vec<_>>()),
            ),
        );
    } else {
        // The format needs the codes; none was seen served.
        d.insert(
            "functions".into(),
            json!({"codes": [], "basis": "decision", "why": "learn saw no function served"}),
        );
    }

    if let Some(f) = learned
        .functions
        .iter()
        .find(|f| f.code == 0x08 && f.served == Some(true))
    {
        let mut lb = observed(&f.evidence);
        lb.insert("data_bytes".into(), json!(2));
        lb.insert(
            "other_test_codes".into(),
            json!({"basis": "decision", "why": "not tried: learn sends test code 0000H only; what the device does with other test codes is not known"}),
        );
        d.insert("loop_back".into(), Value::Object(lb));
    }

    // Exceptions, and the table of every code they use.
    let mut exceptions = Map::new();
    let mut used: Vec<u8> = Vec::new();
    let mut rule = |key: &str, code: u8, ev: &Evidence| {
        exceptions.insert(
            key.into(),
            with(observed(ev), "code", json!(format!("{code:02X}"))),
        );
        used.push(code);
    };
    if let Some((c, ev)) = &learned.illegal_function {
        rule("illegal-function", *c, ev);
    }
    if let Some((_, Answer::Exception(c), ev)) = &learned.map.miss {
        rule("illegal-register", *c, ev);
    }
    if let Some((c, ev)) = &learned.illegal_count {
        rule("illegal-count", *c, ev);
    }
    if let Some((_, Answer::Exception(c), ev)) = &learned.map.split {
        rule("crosses-group", *c, ev);
    }
    if let Some((c, w)) =
        learned
            .writes
            .iter()
            .find_map(|w| match (block_access(learned, w.register), &w.answer) {
                (Some(("read-only", _)), Answer::Exception(c)) => Some((*c, w)),
                _ => None,
            })
    {
        rule("read-only", c, &w.evidence);
    }
    used.sort_unstable();
    used.dedup();
    if !used.is_empty() {
        d.insert(
            "exception_codes".into(),
            json!(used
                .iter()
                .map(|c| json!({"code": format!("{c:02X}"), "meaning": meaning(*c)}))
                .collect::<Vec<_>>()),
        );
        d.insert(
            "exception_codes_source".into(),
            json!("the codes the device answered while learning; their meanings from the Modbus application protocol V1.1b3, 7"),
        );
        d.insert("exceptions".into(), Value::Object(exceptions));
    }

    let silence: Map<String, Value> = learned
        .silence
        .iter()
        .filter(|s| s.silent)
        .map(|s| (s.reason.to_string(), Value::Object(observed(&s.evidence))))
        .collect();
    if !silence.is_empty() {
        d.insert("silence".into(), Value::Object(silence));
    }

    let mut limits = Map::new();
    let mode = learned.mode.to_string();
    let limit = learned
        .map
        .limit
        .as_ref()
        .map(|(n, e)| (*n, e))
        .or(learned.read_limit.as_ref().map(|(n, e)| (*n, e)))
        .or(learned
            .map
            .largest
            .as_ref()
            .filter(|(n, _)| *n >= super::map::SPEC_READ_LIMIT)
            .map(|(n, e)| (*n, e)));
    if let Some((n, ev)) = limit {
        limits.insert("read_registers".into(), with(observed(ev), &mode, json!(n)));
    }
    if let Some((_, _, ev)) = &learned.map.split {
        limits.insert(
            "same_group".into(),
            with(observed(ev), "value", json!(true)),
        );
    }
    if let Some((_, p99, ev)) = &learned.response {
        // Whole milliseconds, rounded up: a device is held to what it showed.
        let ms = p99.as_micros().div_ceil(1000).max(1);
        limits.insert(
            "response_time_ms".into(),
            with(observed(ev), "value", json!(ms as u64)),
        );
    }
    if !limits.is_empty() {
        d.insert("limits".into(), Value::Object(limits));
    }

    // A block whose growth had not read anything yet when learn stopped (Ctrl-C, the
    // cap) has no request to cite: it is left out, and the notes say so.
    let blocks: Vec<Value> = learned
        .map
        .blocks
        .iter()
        .filter(|b| !b.shown_by.request.is_empty())
        .map(|b| {
            let mut m = observed(&b.shown_by);
            m.insert("first".into(), json!(hex4(b.first)));
            m.insert("last".into(), json!(hex4(b.last)));
            if let Some((access, _)) = block_access(learned, b.first) {
                m.insert("access".into(), json!(access));
            }
            Value::Object(m)
        })
        .collect();
    d.insert("blocks".into(), json!(blocks));
    if !learned.allow_write {
        d.insert(
            "parameter_access".into(),
            json!({"basis": "decision", "why": "not tried: learn was run without --allow-write, so every block is read-write by the format's default, not by anything the device showed"}),
        );
    }

    if let Some((r, v, ev)) = &learned.identification {
        let mut m = observed(ev);
        m.insert("register".into(), json!(hex4(*r)));
        m.insert("value".into(), json!(hex4(*v)));
        d.insert("identification".into(), Value::Object(m));
    }
    Value::Object(d)
}

/// The notes: how the draft was learned, what it covers, and what it leaves out.
fn notes(l: &Learned) -> String {
    let mut n: Vec<String> = Vec::new();
    n.push("A first draft drawn up by `conformance model learn` from the device's answers: every fact marked 'observed' carries the request that showed it (and the reply), so a reader can tell it from a fact taken from a manual. Check it, give it names, units and value ranges, and commit it.".into());
    let m = &l.map_config;
    let searched = match (l.map.complete, l.map.searched_to) {
        (true, _) => format!("{:04X}H..{:04X}H", m.first, m.last),
        (false, Some(t)) => format!(
            "{:04X}H..{t:04X}H (of {:04X}H..{:04X}H)",
            m.first, m.first, m.last
        ),
        (false, None) => "nothing".into(),
    };
    n.push(format!(
        "Map: {} block(s) of holding registers found in {searched} with {} requests (03H reads of up to {} registers, one sample every {} registers where nothing was known: a block shorter than that between two samples is not found).",
        l.map.blocks.len(),
        l.map.requests,
        l.map.largest.as_ref().map_or(0, |(c, _)| *c),
        m.stride
    ));
    for b in &l.map.blocks {
        if b.shown_by.request.is_empty() {
            n.push(format!(
                "A block from {:04X}H was being measured when learn stopped: not written (no read of it was kept to cite).",
                b.first
            ));
            continue;
        }
        if !b.start_shown {
            n.push(format!(
                "Block {:04X}H..{:04X}H starts at the first register searched: it may start lower.",
                b.first, b.last
            ));
        }
        if !b.end_shown {
            n.push(format!(
                "Block {:04X}H..{:04X}H ends where the search stopped: it may go on.",
                b.first, b.last
            ));
        }
    }
    if let Some((c, e)) = &l.map.largest {
        n.push(format!(
            "Largest read answered: {c} registers ({}).",
            e.request
        ));
    }
    if let Some((median, p99, _)) = &l.response {
        n.push(format!(
            "Response time over {} replies: median {:.1} ms, p99 {:.1} ms (limits.response_time_ms is the p99, rounded up).",
            l.timed,
            median.as_secs_f64() * 1000.0,
            p99.as_secs_f64() * 1000.0
        ));
    }
    if !l.allow_write {
        n.push("06H and 10H were not tried (learn was run without --allow-write): they are not listed as served; run `check --read-only` with this draft, or learn again with --allow-write.".into());
    }
    if l.identification.is_none() {
        n.push("No identification register: no register read the same twice and told the device from the five built-in models.".into());
    }
    n.extend(l.notes.iter().cloned());
    if let Some(s) = &l.stopped {
        n.push(format!(
            "Learning stopped early: {s}. This draft holds what was found until then."
        ));
    }
    n.push(format!(
        "{} requests in {:.1} s.",
        l.requests,
        l.elapsed.as_secs_f64()
    ));
    n.join(" ")
}
