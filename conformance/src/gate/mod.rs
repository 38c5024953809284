//! The gate: checks another Modbus implementation through an adapter (see
//! `adapters/PROTOCOL.md`) against the golden vectors and against this suite's codec.
//!
//! - Vector cases: every frame of the five manuals. A frame our codec accepts as printed
//!   must be accepted with the same fields (consistent frames, and errata whose fault is
//!   semantic, such as a node address that changes); a frame it rejects (checksum errata,
//!   framing errors) must be rejected; incomplete frames are skipped as printed and their
//!   corrected frames are checked instead. Every accepted frame is also encoded back, and
//!   its CRC or LRC computed.
//! - Differential cases: a seeded, reproducible stream of random valid and corrupted
//!   frames (bit flips, truncations, wrong counts with a valid checksum, an extra byte),
//!   whose verdicts and fields are compared with our codec's.
//!
//! Results are [`CheckResult`]s, reported like the runner's.

pub mod adapter;
pub mod fuzzing;
pub mod master;
pub mod reference;

use std::time::{Duration, Instant};

use serde_json::{json, Value};

pub use adapter::{Adapter, AdapterError, CallError, Hello};

use crate::codec::ascii::Scratch;
use crate::codec::crc::crc16;
use crate::codec::hex::{parse_hex, Hex};
use crate::codec::lrc::lrc;
use crate::codec::pdu::{Direction, Message, Pdu, Registers};
use crate::codec::{self, Mode};
use crate::rng::Rng;
use crate::runner::{CheckResult, ExchangeRecord, Finding, Status};
use crate::vectors::model::parse_known;
use crate::vectors::verify::frame_parts;
use crate::vectors::{Body, VectorSet, Verdict};

/// What a case asks the adapter.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Op {
    /// Decode a frame.
    Decode {
        /// Mode.
        mode: Mode,
        /// Direction.
        direction: Direction,
        /// The frame.
        frame: Vec<u8>,
    },
    /// Encode a message.
    Encode {
        /// Mode.
        mode: Mode,
        /// Direction.
        direction: Direction,
        /// The message, as the protocol describes it.
        message: Value,
    },
    /// CRC over bytes.
    Crc(Vec<u8>),
    /// LRC over bytes.
    Lrc(Vec<u8>),
}

/// What a correct implementation answers.
#[derive(Debug, Clone, PartialEq)]
pub enum Want {
    /// Accept, with these fields. With `may_reject`, rejecting is right too: the frame is
    /// sound but a value is outside the Modbus application protocol's range (a read of 0
    /// or over 125 registers, a write of over 123), which an implementation may refuse
    /// while decoding (the protocol lets a server answer exception 03), or a response
    /// answers no request within those ranges (a read response of 0 or over 125
    /// registers, a write response for 0 or over 123), which a master that checks the
    /// response against its request rejects; the text says why.
    Accept {
        /// The fields.
        message: Value,
        /// Why rejecting is right too, if it is.
        may_reject: Option<String>,
    },
    /// Reject (our codec's reason).
    Reject(String),
    /// These bytes.
    Frame(Vec<u8>),
    /// This CRC value.
    Crc(u16),
    /// This LRC.
    Lrc(u8),
}

/// One gate case.
#[derive(Debug, Clone)]
pub struct Case {
    /// Stable id ("vector.f510.03.rtu.request.decode", "diff.17.decode").
    pub id: String,
    /// What it checks.
    pub title: String,
    /// Where the expectation comes from.
    pub source: String,
    /// The request.
    pub op: Op,
    /// The answer a correct implementation gives.
    pub want: Want,
    /// Set for cases that are not run.
    pub skip: Option<String>,
    /// A command line that reproduces the case.
    pub repro: String,
}

fn mode_name(m: Mode) -> &'static str {
    match m {
        Mode::Rtu => "rtu",
        Mode::Ascii => "ascii",
    }
}

fn dir_name(d: Direction) -> &'static str {
    match d {
        Direction::Request => "request",
        Direction::Response => "response",
    }
}

/// What our codec says of a frame.
pub fn ours(mode: Mode, direction: Direction, frame: &[u8]) -> Want {
    let mut scratch: Scratch = [0; codec::MAX_RTU_FRAME];
    match codec::decode(mode, frame, direction, &mut scratch) {
        Ok(m) => {
            let may_reject = match m.pdu {
                Pdu::ReadRequest { count, .. } if !(1..=125).contains(&count) => Some(format!(
                    "a read of {count} registers (Modbus allows 1..125)"
                )),
                Pdu::WriteMultipleRequest { values, .. }
                    if values.len() > 123 || values.is_empty() =>
                {
                    Some(format!(
                        "a write of {} registers (Modbus allows 1..123)",
                        values.len()
                    ))
                }
                // A response that answers no valid request: a master that checks it
                // against the request it sent rejects it, and may.
                Pdu::ReadResponse { values } if values.is_empty() || values.len() > 125 => {
                    Some(format!(
                        "a read response of {} registers answers no valid request (Modbus reads 1..125)",
                        values.len()
                    ))
                }
                Pdu::WriteMultipleResponse { count, .. } if !(1..=123).contains(&count) => {
                    Some(format!(
                        "a write response for {count} registers answers no valid request (Modbus writes 1..123)"
                    ))
                }
                _ => None,
            };
            Want::Accept {
                message: crate::vectors::export::message_json(&m),
                may_reject,
            }
        }
        Err(e) => Want::Reject(e.to_string()),
    }
}

fn decode_repro(mode: Mode, direction: Direction, frame: &[u8]) -> String {
    format!(
        "conformance decode --{} --{} {}",
        mode_name(mode),
        dir_name(direction),
        Hex(frame)
    )
}

/// Cases from the golden vectors.
pub fn vector_cases(set: &VectorSet) -> Vec<Case> {
    let mut out = Vec::new();
    for (file, v) in set.iter() {
        match &v.body {
            Body::Frame(fv) => {
                let mode: Mode = fv.mode.into();
                let direction: Direction = fv.direction.into();
                let source = format!(
                    "{} ({}{})",
                    v.source,
                    v.verdict,
                    if v.flags.is_empty() {
                        String::new()
                    } else {
                        format!(": {}", v.flags.join(", "))
                    }
                );
                let printed = parse_known(&fv.printed).ok();
                let mut frames: Vec<(String, Vec<u8>, &str)> = Vec::new();
                match &printed {
                    Some(b) => frames.push((v.id.clone(), b.clone(), "as printed")),
                    None => out.push(Case {
                        id: format!("vector.{}.decode", v.id),
                        title: format!("Decode {} as printed", v.id),
                        source: source.clone(),
                        op: Op::Decode { mode, direction, frame: Vec::new() },
                        want: Want::Reject(String::new()),
                        skip: Some("the manual leaves bytes of this frame blank (incomplete); its corrected frame is checked instead".into()),
                        repro: String::new(),
                    }),
                }
                if v.verdict != Verdict::Consistent {
                    if let Some(c) = fv.corrected.as_deref().and_then(|c| parse_hex(c).ok()) {
                        frames.push((format!("{}.corrected", v.id), c, "as corrected"));
                    }
                }
                for (id, frame, how) in frames {
                    let want = ours(mode, direction, &frame);
                    let accepted = matches!(want, Want::Accept { .. });
                    out.push(Case {
                        id: format!("vector.{id}.decode"),
                        title: format!(
                            "Decode {} {how} ({} {}): {}",
                            v.id,
                            mode_name(mode),
                            dir_name(direction),
                            if accepted {
                                "accept with the same fields"
                            } else {
                                "reject"
                            }
                        ),
                        source: source.clone(),
                        op: Op::Decode {
                            mode,
                            direction,
                            frame: frame.clone(),
                        },
                        want: want.clone(),
                        skip: None,
                        repro: decode_repro(mode, direction, &frame),
                    });
                    let Want::Accept { message, .. } = want else {
                        continue;
                    };
                    out.push(Case {
                        id: format!("vector.{id}.encode"),
                        title: format!("Encode the message of {} {how} back to its bytes", v.id),
                        source: source.clone(),
                        op: Op::Encode {
                            mode,
                            direction,
                            message,
                        },
                        want: Want::Frame(frame.clone()),
                        skip: None,
                        repro: decode_repro(mode, direction, &frame),
                    });
                    if let Ok(parts) = frame_parts(mode, &frame) {
                        let (op, want, what) = match mode {
                            Mode::Rtu => (
                                Op::Crc(parts.body.clone()),
                                Want::Crc(crc16(&parts.body)),
                                "CRC",
                            ),
                            Mode::Ascii => (
                                Op::Lrc(parts.body.clone()),
                                Want::Lrc(lrc(&parts.body)),
                                "LRC",
                            ),
                        };
                        out.push(Case {
                            id: format!("vector.{id}.{}", what.to_lowercase()),
                            title: format!(
                                "{what} of the body of {} {how} ({})",
                                v.id,
                                Hex(&parts.body)
                            ),
                            source: source.clone(),
                            op,
                            want,
                            skip: None,
                            repro: String::new(),
                        });
                    }
                }
            }
            Body::LrcExample(e) => {
                let Ok(input) = parse_known(&e.input) else {
                    continue;
                };
                out.push(Case {
                    id: format!("vector.{}.lrc", v.id),
                    title: format!(
                        "LRC of the manual's worked example {} (the manual: {})",
                        Hex(&input),
                        e.printed_lrc
                    ),
                    source: v.source.clone(),
                    want: Want::Lrc(lrc(&input)),
                    op: Op::Lrc(input),
                    skip: None,
                    repro: String::new(),
                });
            }
            _ => {}
        }
        let _ = file;
    }
    out
}

/// Address, function and data of a message.
fn body_of_message(m: &Message<'_>) -> Vec<u8> {
    let mut body = vec![0; m.body_len()];
    // The generated messages are short; emit only fails on a frame over 256 bytes.
    let n = m.emit_body(&mut body).unwrap_or(0);
    body.truncate(n);
    body
}

/// A random valid message body and its direction.
fn random_body(rng: &mut Rng) -> (Direction, Vec<u8>) {
    let address = 1 + rng.below(247) as u8;
    let mut values = Vec::new();
    let mut words = |rng: &mut Rng, n: u64| {
        values.clear();
        for _ in 0..n {
            values.extend_from_slice(&rng.word().to_be_bytes());
        }
    };
    // Either way round, drawn after the message's fields (the order the cases were
    // always drawn in, so a seed gives the same cases).
    let either = |rng: &mut Rng| {
        if rng.below(2) == 0 {
            Direction::Request
        } else {
            Direction::Response
        }
    };
    let data: [u8; 2];
    let (direction, pdu) = match rng.below(7) {
        0 => {
            let count = 1 + rng.below(125) as u16;
            let start = rng.word();
            (Direction::Request, Pdu::ReadRequest { start, count })
        }
        1 => {
            let n = rng.below(21);
            words(rng, n);
            let values = Registers::new(&values).unwrap_or_else(|_| empty());
            (Direction::Response, Pdu::ReadResponse { values })
        }
        2 => {
            let (register, value) = (rng.word(), rng.word());
            (either(rng), Pdu::WriteSingle { register, value })
        }
        3 => {
            data = [rng.byte(), rng.byte()];
            let test_code = if rng.below(4) == 0 { rng.word() } else { 0 };
            let pdu = Pdu::LoopBack {
                test_code,
                data: &data,
            };
            (either(rng), pdu)
        }
        4 => {
            let n = 1 + rng.below(20);
            words(rng, n);
            let start = rng.word();
            let values = Registers::new(&values).unwrap_or_else(|_| empty());
            (
                Direction::Request,
                Pdu::WriteMultipleRequest { start, values },
            )
        }
        5 => {
            let start = rng.word();
            let count = 1 + rng.below(123) as u16;
            (
                Direction::Response,
                Pdu::WriteMultipleResponse { start, count },
            )
        }
        _ => {
            let function = [0x03, 0x06, 0x08, 0x10][rng.below(4) as usize];
            let code = 1 + rng.below(4) as u8;
            (Direction::Response, Pdu::Exception { function, code })
        }
    };
    let mut body = body_of_message(&Message { address, pdu });
    // Broadcast (00H) only where Modbus allows it: write requests. A slave that ignores
    // a broadcast read follows the specification, so such frames would test policy.
    if direction == Direction::Request
        && matches!(body.get(1), Some(0x06 | 0x10))
        && rng.below(8) == 0
    {
        body[0] = 0;
    }
    (direction, body)
}

fn empty() -> Registers<'static> {
    match Registers::new(&[]) {
        Ok(r) => r,
        Err(_) => unreachable!("an empty register list is valid"),
    }
}

/// The frame of a generated body (at most 5 + 2 x 20 + 1 bytes: always fits).
fn frame(mode: Mode, body: &[u8]) -> Vec<u8> {
    crate::codec::frame_of_body(mode, body).unwrap_or_default()
}

/// Differential cases: `count` frames from `seed`, half of them corrupted.
pub fn differential_cases(seed: u64, count: usize, command: &str) -> Vec<Case> {
    let mut out = Vec::with_capacity(count);
    for i in 0..count {
        // Each case has its own generator, so that one case reproduces alone.
        let mut rng = Rng::new(seed ^ (i as u64).wrapping_mul(0xA24B_AED4_963E_E407));
        let mode = if rng.below(2) == 0 {
            Mode::Rtu
        } else {
            Mode::Ascii
        };
        let (direction, mut body) = random_body(&mut rng);
        let (frame, what) = match rng.below(8) {
            0 => {
                let mut f = frame(mode, &body);
                let mut bit = rng.below(f.len() as u64 * 8) as usize;
                // In ASCII, flipping 20H of a letter only changes its case: the frame
                // means the same, so take the neighbouring bit.
                if mode == Mode::Ascii && bit % 8 == 5 && f[bit / 8].is_ascii_alphabetic() {
                    bit ^= 1;
                }
                f[bit / 8] ^= 1 << (bit % 8);
                (f, format!("bit {bit} flipped"))
            }
            1 => {
                let mut f = frame(mode, &body);
                let cut = 1 + rng.below(3) as usize;
                f.truncate(f.len().saturating_sub(cut));
                (f, format!("last {cut} bytes cut"))
            }
            2 if body.len() > 2 => {
                // A count field that disagrees, under a valid checksum.
                let at = 2 + rng.below(body.len() as u64 - 2) as usize;
                body[at] = body[at].wrapping_add(1 + rng.below(3) as u8);
                (
                    frame(mode, &body),
                    format!("data byte {at} changed, checksum valid"),
                )
            }
            3 => {
                body.push(rng.byte());
                (
                    frame(mode, &body),
                    "one byte added, checksum valid".to_string(),
                )
            }
            _ => (frame(mode, &body), "valid".to_string()),
        };
        let want = ours(mode, direction, &frame);
        out.push(Case {
            id: format!("diff.{i}.decode"),
            title: format!(
                "Random {} {} frame, {what}: {}",
                mode_name(mode),
                dir_name(direction),
                match &want {
                    Want::Accept {
                        may_reject: None, ..
                    } => "our codec accepts it",
                    Want::Accept { .. } => "out of Modbus's range: accept or reject",
                    _ => "our codec rejects it",
                }
            ),
            source: format!("differential against this suite's codec, seed {seed:#x}, case {i}"),
            op: Op::Decode { mode, direction, frame: frame.clone() },
            want,
            skip: None,
            repro: format!(
                "{}   # or: conformance gate --codec {command:?} --seed {seed:#x} --count {count} --no-vectors --only 'diff.{i}.*'",
                decode_repro(mode, direction, &frame)
            ),
        });
    }
    out
}

/// Upper-cases every string, so that hex compares without regard to case.
fn normalize(v: &Value) -> Value {
    match v {
        Value::String(s) => Value::String(s.to_uppercase()),
        Value::Array(a) => Value::Array(a.iter().map(normalize).collect()),
        Value::Object(o) => {
            Value::Object(o.iter().map(|(k, v)| (k.clone(), normalize(v))).collect())
        }
        other => other.clone(),
    }
}

fn compare_messages(want: &Value, got: &Value) -> Option<String> {
    let (w, g) = (normalize(want), normalize(got));
    for key in ["address", "function"] {
        if w.get(key) != g.get(key) {
            return Some(format!(
                "{key} {} (expected {})",
                show(g.get(key)),
                show(w.get(key))
            ));
        }
    }
    if w.get("kind") == Some(&json!("OTHER")) {
        return None;
    }
    if w.get("kind") != g.get("kind") {
        return Some(format!(
            "kind {} (expected {})",
            show(g.get("kind")),
            show(w.get("kind"))
        ));
    }
    let (Some(wf), Some(gf)) = (w.get("fields").and_then(Value::as_object), g.get("fields")) else {
        return Some("no \"fields\" in the answer".into());
    };
    for (k, wv) in wf {
        let gv = gf.get(k);
        if gv != Some(wv) {
            return Some(format!("{k} {} (expected {})", show(gv), wv));
        }
    }
    None
}

fn show(v: Option<&Value>) -> String {
    v.map(|v| v.to_string()).unwrap_or_else(|| "missing".into())
}

fn op_json(op: &Op) -> Value {
    match op {
        Op::Decode {
            mode,
            direction,
            frame,
        } => {
            json!({"op": "decode", "mode": mode_name(*mode), "direction": dir_name(*direction), "frame": Hex(frame).to_string()})
        }
        Op::Encode {
            mode,
            direction,
            message,
        } => {
            json!({"op": "encode", "mode": mode_name(*mode), "direction": dir_name(*direction), "message": message})
        }
        Op::Crc(d) => json!({"op": "crc", "data": Hex(d).to_string()}),
        Op::Lrc(d) => json!({"op": "lrc", "data": Hex(d).to_string()}),
    }
}

fn supported(hello: &Hello, op: &Op) -> bool {
    match op {
        Op::Decode { mode, .. } => hello.supports("decode", Some(mode_name(*mode))),
        Op::Encode { mode, .. } => hello.supports("encode", Some(mode_name(*mode))),
        Op::Crc(_) => hello.supports("crc", None),
        Op::Lrc(_) => hello.supports("lrc", None),
    }
}

fn want_text(w: &Want) -> String {
    match w {
        Want::Accept {
            message,
            may_reject: None,
        } => format!("accept: {message}"),
        Want::Accept {
            message,
            may_reject: Some(why),
        } => format!("accept ({message}) or reject: {why}"),
        Want::Reject(r) => format!("reject ({r})"),
        Want::Frame(f) => format!("frame {}", Hex(f)),
        Want::Crc(c) => format!("CRC {c:04X}"),
        Want::Lrc(l) => format!("LRC {l:02X}"),
    }
}

/// The checksum `key` ("crc" or "lrc") of an adapter's answer, `digits` hex digits wide,
/// against `want`: its text for the report, and a deviation in `f` where it differs, is
/// missing or does not fit in `digits`.
fn checksum_answer(
    answer: &Value,
    key: &str,
    digits: usize,
    want: u16,
    f: &mut Vec<Finding>,
) -> String {
    let got = answer
        .get(key)
        .and_then(Value::as_str)
        .and_then(|s| u16::from_str_radix(s, 16).ok())
        .filter(|&c| u32::from(c) < 1 << (4 * digits));
    let text = format!(
        "{} {}",
        key.to_uppercase(),
        got.map(|c| format!("{c:0digits$X}"))
            .unwrap_or_else(|| "missing".into())
    );
    if got != Some(want) {
        f.push(Finding::deviation(format!(
            "computed {text}, expected {want:0digits$X}"
        )));
    }
    text
}

/// Judges one answer; returns (findings, the answer in words).
fn judge(case: &Case, answer: &Value) -> (Vec<Finding>, String) {
    let mut f = Vec::new();
    let bytes = |k: &str| answer.get(k).and_then(Value::as_str).map(parse_hex);
    let accepted = answer.get("accepted").and_then(Value::as_bool);
    let text;
    match &case.want {
        Want::Accept { .. } | Want::Reject(_) if !matches!(case.op, Op::Decode { .. }) => {
            text = answer.to_string();
        }
        // A decode answer says whether it took the frame; one that does not say is
        // judged the same whichever verdict was wanted.
        Want::Accept { .. } | Want::Reject(_) if accepted.is_none() => {
            text = answer.to_string();
            f.push(Finding::deviation(format!(
                "no \"accepted\" in the answer: {answer}"
            )));
        }
        Want::Accept {
            message: want,
            may_reject,
        } => {
            if accepted == Some(true) {
                let got = answer.get("message").cloned().unwrap_or(Value::Null);
                text = format!("accepted: {got}");
                if let Some(d) = compare_messages(want, &got) {
                    f.push(Finding::deviation(format!(
                        "accepted the frame but decoded {d}"
                    )));
                }
            } else {
                let reason = answer.get("reason").and_then(Value::as_str).unwrap_or("");
                match may_reject {
                    Some(why) => {
                        text = format!(
                            "rejected ({why}, which an implementation may refuse): {reason}"
                        )
                    }
                    None => {
                        text = format!("rejected: {reason}");
                        f.push(Finding::deviation(format!(
                            "rejected a valid frame: {reason}"
                        )));
                    }
                }
            }
        }
        Want::Reject(ours) => {
            if accepted == Some(true) {
                let got = answer.get("message").cloned().unwrap_or(Value::Null);
                text = format!("accepted: {got}");
                f.push(Finding::deviation(format!(
                    "accepted a frame that must be rejected ({ours}) and decoded it as {got}"
                )));
            } else {
                text = format!(
                    "rejected: {}",
                    answer.get("reason").and_then(Value::as_str).unwrap_or("")
                );
            }
        }
        Want::Frame(want) => match bytes("frame") {
            Some(Ok(got)) => {
                text = Hex(&got).to_string();
                if &got != want {
                    f.push(Finding::deviation(format!(
                        "encoded {} instead of {}",
                        Hex(&got),
                        Hex(want)
                    )));
                }
            }
            other => {
                text = answer.to_string();
                f.push(Finding::deviation(format!(
                    "no frame in the answer ({:?})",
                    other.map(|r| r.map(|_| ()))
                )));
            }
        },
        Want::Crc(want) => text = checksum_answer(answer, "crc", 4, *want, &mut f),
        Want::Lrc(want) => text = checksum_answer(answer, "lrc", 2, u16::from(*want), &mut f),
    }
    if answer.get("raised") == Some(&Value::Bool(true)) {
        f.insert(
            0,
            Finding::deviation(format!(
                "the implementation rejected the frame only by raising an exception or panicking ({}): a receive loop that does not catch it stops",
                answer.get("reason").and_then(Value::as_str).unwrap_or("")
            )),
        );
    }
    // An adapter may say more than the protocol's fields (what the implementation's own
    // reply to the frame was, bytes it left unread): kept with the answer in the report.
    let text = match answer.get("note").and_then(Value::as_str) {
        Some(note) if !note.is_empty() => format!("{text} (adapter's note: {note})"),
        _ => text,
    };
    (f, text)
}

/// Told about each case as it ends.
pub trait GateProgress {
    /// A case is about to run.
    fn started(&mut self, case: &Case);
    /// A case ended.
    fn finished(&mut self, result: &CheckResult);
}

/// Runs `cases` through `adapter`; stops before the next case once `stop` is set (the
/// results so far are returned).
pub fn run(
    adapter: &mut Adapter,
    cases: &[Case],
    stop: &std::sync::atomic::AtomicBool,
    progress: &mut dyn GateProgress,
) -> Vec<CheckResult> {
    let mut out = Vec::with_capacity(cases.len());
    for case in cases {
        if stop.load(std::sync::atomic::Ordering::Relaxed) {
            break;
        }
        progress.started(case);
        let t0 = Instant::now();
        let request_bytes = match &case.op {
            Op::Decode { frame, .. } => frame.clone(),
            Op::Crc(d) | Op::Lrc(d) => d.clone(),
            Op::Encode { .. } => Vec::new(),
        };
        let mode = match &case.op {
            Op::Decode { mode, .. } | Op::Encode { mode, .. } => Some(*mode),
            _ => None,
        };
        let (status, summary, findings, actual) = if let Some(s) = &case.skip {
            (Status::Skip, s.clone(), vec![], String::new())
        } else if !supported(&adapter.hello, &case.op) {
            let op = op_json(&case.op);
            (
                Status::Skip,
                format!(
                    "the adapter does not support {}{}",
                    op["op"].as_str().unwrap_or("?"),
                    op.get("mode")
                        .and_then(Value::as_str)
                        .map(|m| format!(" in {m}"))
                        .unwrap_or_default()
                ),
                vec![],
                String::new(),
            )
        } else {
            match adapter.call(op_json(&case.op)) {
                Ok(answer) => {
                    let (mut findings, text) = judge(case, &answer);
                    if let (Some(first), false) = (findings.first_mut(), case.repro.is_empty()) {
                        first.text.push_str(&format!("; reproduce: {}", case.repro));
                    }
                    match findings.first() {
                        Some(first) => (Status::Deviation, first.text.clone(), findings, text),
                        None => (Status::Pass, format!("as expected: {text}"), findings, text),
                    }
                }
                Err(CallError::Unsupported) => (
                    Status::Skip,
                    "the adapter answered unsupported".into(),
                    vec![],
                    String::new(),
                ),
                Err(e) => (Status::Error, e.to_string(), vec![], String::new()),
            }
        };
        let result = CheckResult {
            id: case.id.clone(),
            title: case.title.clone(),
            mode,
            source: case.source.clone(),
            status,
            summary,
            findings,
            exchanges: if request_bytes.is_empty() && actual.is_empty() {
                vec![]
            } else {
                vec![ExchangeRecord {
                    request: request_bytes,
                    expected: match &case.want {
                        Want::Frame(f) => Some(f.clone()),
                        _ => None,
                    },
                    received: Vec::new(),
                    reply: None,
                    predicted: want_text(&case.want),
                    actual,
                    latency: None,
                }]
            },
            duration: t0.elapsed(),
            node: None,
        };
        progress.finished(&result);
        out.push(result);
    }
    out
}

/// Options of a gate run.
#[derive(Debug, Clone)]
pub struct GateOptions {
    /// Seed of the differential cases.
    pub seed: u64,
    /// Number of differential cases.
    pub count: usize,
    /// Include the vector cases.
    pub vectors: bool,
    /// Only cases whose id matches one of these.
    pub only: Vec<String>,
    /// Timeout of one answer.
    pub timeout: Duration,
}

/// The cases of a gate run, selected by `only`.
pub fn cases(set: &VectorSet, opts: &GateOptions, command: &str) -> Vec<Case> {
    let mut all = Vec::new();
    if opts.vectors {
        all.extend(vector_cases(set));
    }
    all.extend(differential_cases(opts.seed, opts.count, command));
    all.retain(|c| crate::runner::selected(&c.id, &opts.only));
    all
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_checksum_answer_is_read_at_its_width() {
        let judged = |want: Want, key: &str, got: Value| {
            let case = Case {
                id: "t".into(),
                title: String::new(),
                source: String::new(),
                op: Op::Crc(vec![1, 3]),
                want,
                skip: None,
                repro: String::new(),
            };
            let (f, text) = judge(&case, &json!({ key: got }));
            (text, f.iter().map(|f| f.text.clone()).collect::<Vec<_>>())
        };
        assert_eq!(
            judged(Want::Crc(0x1234), "crc", "1234".into()),
            ("CRC 1234".into(), vec![])
        );
        assert_eq!(
            judged(Want::Crc(0x1234), "crc", "5".into()),
            (
                "CRC 0005".into(),
                vec!["computed CRC 0005, expected 1234".to_string()]
            )
        );
        assert_eq!(
            judged(Want::Lrc(0xF1), "lrc", "0f1".into()),
            ("LRC F1".into(), vec![])
        );
        // An LRC wider than a byte, or not a hex string, is no LRC.
        for got in [Value::from("1F1"), Value::from(241)] {
            assert_eq!(
                judged(Want::Lrc(0xF1), "lrc", got),
                (
                    "LRC missing".into(),
                    vec!["computed LRC missing, expected F1".to_string()]
                )
            );
        }
    }

    #[test]
    fn vector_cases_follow_the_verdicts() {
        let set = VectorSet::builtin().unwrap();
        let cases = vector_cases(&set);
        let get = |id: &str| {
            cases
                .iter()
                .find(|c| c.id == id)
                .unwrap_or_else(|| panic!("{id}"))
        };
        assert!(matches!(
            get("vector.f510.03.rtu.request.decode").want,
            Want::Accept { .. }
        ));
        assert!(matches!(
            get("vector.f510.03.rtu.response.decode").want,
            Want::Reject(_)
        ));
        assert!(matches!(
            get("vector.f510.03.rtu.response.corrected.decode").want,
            Want::Accept { .. }
        ));
        assert!(get("vector.f510.03.ascii.request.decode").skip.is_some());
        assert_eq!(
            get("vector.f510.03.rtu.request.crc").want,
            Want::Crc(0x3C74)
        );
        assert_eq!(get("vector.f510.lrc-example.lrc").want, Want::Lrc(0xF1));
    }

    #[test]
    fn responses_that_answer_no_valid_request_may_be_rejected() {
        let may_reject = |frame: &[u8]| match ours(Mode::Rtu, Direction::Response, frame) {
            Want::Accept { may_reject, .. } => may_reject,
            other => panic!("{other:?}"),
        };
        let rtu = |body: &[u8]| frame(Mode::Rtu, body);
        // A read response of 0 registers, and one of 1 (an answer to a valid read).
        assert!(may_reject(&rtu(&[0x01, 0x03, 0x00]))
            .unwrap()
            .contains("0 registers"));
        assert_eq!(may_reject(&rtu(&[0x01, 0x03, 0x02, 0x17, 0x70])), None);
        // A write response for 0 and for 537 registers, and one for 2.
        assert!(may_reject(&rtu(&[0x01, 0x10, 0x01, 0x01, 0x00, 0x00])).is_some());
        assert!(may_reject(&rtu(&[0x01, 0x10, 0x01, 0x01, 0x02, 0x19]))
            .unwrap()
            .contains("537"));
        assert_eq!(
            may_reject(&rtu(&[0x01, 0x10, 0x01, 0x01, 0x00, 0x02])),
            None
        );
    }

    #[test]
    fn differential_cases_are_reproducible_and_mixed() {
        let a = differential_cases(42, 200, "x");
        let b = differential_cases(42, 200, "x");
        assert_eq!(
            a.iter().map(|c| &c.op).collect::<Vec<_>>(),
            b.iter().map(|c| &c.op).collect::<Vec<_>>()
        );
        let rejected = a
            .iter()
            .filter(|c| matches!(c.want, Want::Reject(_)))
            .count();
        let accepted = a
            .iter()
            .filter(|c| matches!(c.want, Want::Accept { .. }))
            .count();
        assert!(
            rejected > 30 && accepted > 100,
            "{rejected} rejected, {accepted} accepted"
        );
        let other = differential_cases(43, 200, "x");
        assert_ne!(a[0].op, other[0].op);
    }
}
