//! Comparing what a device did with what its model predicts.
//!
//! Findings are DEVIATIONs where the prediction rests only on documented or derived facts
//! (or on the frame format, which every manual documents), and OBSERVATIONs where it rests
//! on a decision of the model.

use std::fmt::Write as _;

use super::master::Exchange;
use crate::codec::ascii::AsciiFrame;
use crate::codec::hex::Hex;
use crate::codec::pdu::{function, Direction, Message, Pdu, Registers};
use crate::codec::rtu::RtuFrame;
use crate::codec::{self, Mode};
use crate::model::{Basis, DriveModel, Expectation, Fact, Judgement};

/// How serious a finding is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Severity {
    /// The manual is silent or contradicts itself; this is what the device did.
    Observation,
    /// The device does not do what the manual says.
    Deviation,
}

impl Severity {
    /// Deviation for binding facts, observation for decisions.
    pub fn of(basis: Basis) -> Self {
        if basis.binding() {
            Severity::Deviation
        } else {
            Severity::Observation
        }
    }
}

/// One thing a check found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Finding {
    /// Deviation or observation.
    pub severity: Severity,
    /// What, in words, with bytes in hex.
    pub text: String,
}

impl Finding {
    /// A deviation.
    pub fn deviation(text: impl Into<String>) -> Self {
        Finding {
            severity: Severity::Deviation,
            text: text.into(),
        }
    }

    /// An observation.
    pub fn observation(text: impl Into<String>) -> Self {
        Finding {
            severity: Severity::Observation,
            text: text.into(),
        }
    }
}

/// The comparison of one exchange with its judgement.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Comparison {
    /// What was found; empty when the device did what the model says.
    pub findings: Vec<Finding>,
    /// The frame the model predicts, where it can be built (values the check does not
    /// know are taken from the reply).
    pub expected: Option<Vec<u8>>,
    /// The reply decoded, one line.
    pub actual: String,
}

/// Decodes a reply frame for display.
pub fn describe_reply(mode: Mode, frame: &[u8]) -> String {
    let mut scratch = [0u8; codec::MAX_RTU_FRAME];
    match codec::decode_unchecked(mode, frame, Direction::Response, &mut scratch) {
        Ok(u) if u.checksum.is_valid() => u.message.to_string(),
        Ok(u) => format!("{} ({})", u.message, u.checksum),
        Err(e) => format!("not a frame: {e}"),
    }
}

/// Explains bytes that hold no valid reply: a wrong checksum (and whether its bytes are
/// merely swapped), or a frame cut short.
pub fn explain_invalid(mode: Mode, rx: &[u8]) -> String {
    let shown = match mode {
        Mode::Rtu => Hex(rx).to_string(),
        Mode::Ascii => format!("{:?}", String::from_utf8_lossy(rx)),
    };
    let why = match mode {
        Mode::Rtu => match RtuFrame::new_checked(rx) {
            Ok(f) if f.checksum().is_valid() => format!(
                "a frame that does not answer the request ({})",
                describe_reply(mode, rx)
            ),
            Ok(f) => {
                let swapped = f.carried_crc().swap_bytes() == f.computed_crc();
                format!(
                    "{}{}",
                    f.checksum(),
                    if swapped {
                        " (the two CRC bytes are swapped)"
                    } else {
                        ""
                    }
                )
            }
            Err(e) => e.to_string(),
        },
        Mode::Ascii => match rx.iter().position(|&c| c == b':') {
            None => "no ':' start character".to_string(),
            Some(s) => match AsciiFrame::new_checked(&rx[s..]) {
                Ok(f) => {
                    let c = f.checksum();
                    if c.is_valid() {
                        "a frame that does not answer the request".to_string()
                    } else {
                        let b = f.as_bytes();
                        let n = b.len();
                        let mut fixed = b.to_vec();
                        fixed.swap(n - 4, n - 3);
                        let swapped = crate::codec::ascii::is_valid_frame(&fixed);
                        format!(
                            "{c}{}",
                            if swapped {
                                " (the two LRC characters are swapped)"
                            } else {
                                ""
                            }
                        )
                    }
                }
                Err(e) => e.to_string(),
            },
        },
    };
    format!("{} bytes without a valid reply: {shown}: {why}", rx.len())
}

/// Compares `ex` with `judgement`. `known` gives, for a read, the values the check knows
/// (None where any value is right) and the fact that says so.
pub fn compare(
    model: &DriveModel,
    mode: Mode,
    judgement: &Judgement,
    ex: &Exchange,
    known: Option<(&[Option<u16>], &Fact)>,
) -> Comparison {
    let mut c = compare_inner(model, mode, judgement, ex, known.map(|(v, f)| (v, f.basis)));
    if c.findings.is_empty() {
        // The device did what the model says; where that rests on a decision, the manual
        // does not say it, so it is an observation of what the device does.
        let mut whys: Vec<&str> = judgement
            .facts
            .iter()
            .filter(|f| f.basis == Basis::Decision)
            .filter_map(|f| f.why.as_deref())
            .collect();
        if let Some((_, f)) = known {
            if f.basis == Basis::Decision {
                whys.extend(f.why.as_deref());
            }
        }
        if let Some(why) = whys.first() {
            c.findings.push(Finding::observation(format!(
                "the manual does not settle this; the device did what the model decides: {} ({}). Model: {why}",
                c.actual, judgement.detail
            )));
        }
    }
    c
}

/// Only the differences between `ex` and `judgement`: [`compare`] without the
/// observation that the device did what a decision of the model says (the fuzzer's
/// oracle, for which agreeing is no finding).
pub fn differences(
    model: &DriveModel,
    mode: Mode,
    judgement: &Judgement,
    ex: &Exchange,
    known: Option<(&[Option<u16>], &Fact)>,
) -> Comparison {
    compare_inner(model, mode, judgement, ex, known.map(|(v, f)| (v, f.basis)))
}

fn compare_inner(
    model: &DriveModel,
    mode: Mode,
    judgement: &Judgement,
    ex: &Exchange,
    known: Option<(&[Option<u16>], Basis)>,
) -> Comparison {
    let mut findings = Vec::new();
    let expect_sev = Severity::of(judgement.basis());
    let unit = if mode == Mode::Rtu {
        "bytes"
    } else {
        "characters"
    };
    // A local echo is the adapter's, not the device's: the master strips it (and the
    // report's link line says so); with --echo off it stays in the bytes and shows as
    // bytes before or after the reply.
    if ex.retries > 0 {
        findings.push(Finding::observation(format!(
            "answered only after {} resend(s)",
            ex.retries
        )));
    }
    let rx = ex.after_echo();
    let actual = match &ex.reply {
        // What the link said (a gateway's 0BH) comes first: "no reply" stays the end.
        None if rx.is_empty() && !ex.link_notes.is_empty() => {
            format!("{}: no reply", ex.link_notes.join("; "))
        }
        Some(r) => describe_reply(mode, r),
        None if rx.is_empty() => "no reply".to_string(),
        None => explain_invalid(mode, rx),
    };
    let manual = judgement.expect.describe();
    match &judgement.expect {
        Expectation::Silence(_) => {
            if !rx.is_empty() {
                findings.push(Finding {
                    severity: expect_sev,
                    text: format!(
                        "manual: {manual} ({}); device sent {} {unit}: {}",
                        judgement.detail,
                        rx.len(),
                        match &ex.reply {
                            Some(r) => format!("{} = {}", show(mode, r), describe_reply(mode, r)),
                            None => show(mode, rx),
                        }
                    ),
                });
            }
            return Comparison {
                findings,
                expected: None,
                actual,
            };
        }
        _ if rx.is_empty() => {
            findings.push(Finding {
                severity: expect_sev,
                text: format!(
                    "manual: {manual} ({}); device: no reply within {} ms{}",
                    judgement.detail,
                    ex.listened.as_millis(),
                    if ex.link_notes.is_empty() {
                        String::new()
                    } else {
                        format!(" ({})", ex.link_notes.join("; "))
                    }
                ),
            });
            return Comparison {
                findings,
                expected: None,
                actual,
            };
        }
        _ => {}
    }
    let Some(reply) = &ex.reply else {
        let want = predicted_len(mode, judgement, &ex.request);
        let text = match want {
            Some(n) if rx.len() < n => format!(
                "manual: {manual}; device: a truncated reply, {} of the {n} {unit} it needs: {}",
                rx.len(),
                show(mode, rx)
            ),
            _ => format!("manual: {manual}; device: {actual}"),
        };
        findings.push(Finding::deviation(text));
        return Comparison {
            findings,
            expected: None,
            actual,
        };
    };
    if !ex.leading.is_empty() {
        findings.push(Finding::deviation(format!(
            "{} {unit} before the reply: {}",
            ex.leading.len(),
            show(mode, &ex.leading)
        )));
    }
    if !ex.trailing.is_empty() {
        findings.push(Finding::deviation(format!(
            "{} {unit} after the reply: {}",
            ex.trailing.len(),
            show(mode, &ex.trailing)
        )));
    }
    let expected = expected_frame(mode, judgement, &ex.request, reply, known.map(|k| k.0));
    if let Some(exp) = &expected {
        if exp != reply {
            let got_body = body_of(mode, reply);
            let want_body = body_of(mode, exp);
            let got = got_body
                .as_deref()
                .and_then(|b| Message::parse_body(b, Direction::Response).ok());
            let want = want_body
                .as_deref()
                .and_then(|b| Message::parse_body(b, Direction::Response).ok());
            let sev = match (&want, &got) {
                (Some(w), Some(g)) if w.address != g.address => Severity::Deviation,
                (Some(w), Some(g)) => match (w.pdu, g.pdu) {
                    (Pdu::ReadResponse { values: a }, Pdu::ReadResponse { values: b })
                        if a.len() == b.len() =>
                    {
                        known.map_or(Severity::Deviation, |k| Severity::of(k.1))
                    }
                    _ => expect_sev,
                },
                _ => expect_sev,
            };
            let mut text = format!(
                "manual: {} ({}); device: {}",
                want.map(|m| m.to_string())
                    .unwrap_or_else(|| manual.clone()),
                judgement.detail,
                got.map(|m| m.to_string()).unwrap_or_else(|| actual.clone())
            );
            if let (Expectation::Exception { code, .. }, Some(Pdu::Exception { code: c, .. })) =
                (&judgement.expect, got.map(|m| m.pdu))
            {
                let _ = write!(
                    text,
                    "; code {code:02X}H means {:?} in the manual's table, {c:02X}H {}",
                    model.exception_meaning(*code).unwrap_or("?"),
                    match model.exception_meaning(c) {
                        Some(m) => format!("means {m:?}"),
                        None => "is not in the table".to_string(),
                    }
                );
            }
            findings.push(Finding {
                severity: sev,
                text,
            });
        }
    }
    Comparison {
        findings,
        expected,
        actual,
    }
}

/// The frame the model predicts for `request`, using the reply's values where the check
/// does not know them.
fn expected_frame(
    mode: Mode,
    judgement: &Judgement,
    request: &[u8],
    reply: &[u8],
    known: Option<&[Option<u16>]>,
) -> Option<Vec<u8>> {
    let req_body = body_of(mode, request)?;
    let address = req_body[0];
    let fc = req_body[1];
    let reply_body = body_of(mode, reply);
    let msg = match &judgement.expect {
        Expectation::Exception { code, .. } => Message {
            address,
            pdu: Pdu::Exception {
                function: fc & !function::EXCEPTION_BIT,
                code: *code,
            },
        }
        .to_frame_vec(mode)
        .ok()?,
        // The echo of the request, in the frame a device emits: an ASCII request in lower
        // case is answered in the upper case of the standard (Modbus over Serial Line
        // V1.02, 2.5.2.1: hexadecimal characters 0-9, A-F).
        Expectation::WriteSingle | Expectation::LoopBack => match mode {
            Mode::Ascii => codec::frame_of_body(mode, &req_body).ok()?,
            Mode::Rtu => request.to_vec(),
        },
        Expectation::WriteMultiple => {
            let m = Message::parse_body(&req_body, Direction::Request).ok()?;
            let Pdu::WriteMultipleRequest { start, values } = m.pdu else {
                return None;
            };
            Message {
                address,
                pdu: Pdu::WriteMultipleResponse {
                    start,
                    count: u16::try_from(values.len()).ok()?,
                },
            }
            .to_frame_vec(mode)
            .ok()?
        }
        Expectation::Read(plan) => {
            let actual: Vec<u16> = reply_body
                .as_deref()
                .and_then(|b| Message::parse_body(b, Direction::Response).ok())
                .and_then(|m| match m.pdu {
                    Pdu::ReadResponse { values } => Some(values.iter().collect()),
                    _ => None,
                })
                .unwrap_or_default();
            let mut bytes = Vec::with_capacity(plan.registers.len() * 2);
            for i in 0..plan.registers.len() {
                let v = known
                    .and_then(|k| k.get(i).copied().flatten())
                    .or_else(|| actual.get(i).copied())
                    .unwrap_or(0);
                bytes.extend_from_slice(&v.to_be_bytes());
            }
            Message {
                address,
                pdu: Pdu::ReadResponse {
                    values: Registers::new(&bytes).ok()?,
                },
            }
            .to_frame_vec(mode)
            .ok()?
        }
        Expectation::Silence(_) => return None,
    };
    Some(msg)
}

/// Length of the reply the model predicts, in bytes (RTU) or characters (ASCII).
fn predicted_len(mode: Mode, judgement: &Judgement, request: &[u8]) -> Option<usize> {
    let body = match &judgement.expect {
        Expectation::Read(p) => 3 + 2 * p.registers.len(),
        Expectation::Exception { .. } => 3,
        Expectation::WriteSingle | Expectation::LoopBack => return Some(request.len()),
        Expectation::WriteMultiple => 6,
        Expectation::Silence(_) => return None,
    };
    Some(crate::model::frame_len(mode, body))
}

/// Address, function and data of a frame whose structure is sound (checksum not checked).
pub fn body_of(mode: Mode, frame: &[u8]) -> Option<Vec<u8>> {
    codec::frame_parts(mode, frame).ok().map(|p| p.body)
}

/// Bytes for a report line: hex in RTU, the characters in ASCII.
pub fn show(mode: Mode, bytes: &[u8]) -> String {
    match mode {
        Mode::Rtu => Hex(bytes).to_string(),
        Mode::Ascii => format!("{:?}", String::from_utf8_lossy(bytes)),
    }
}
