//! Comparing what a device did with what its model predicts: the body of
//! [`Judge::verdict`](super::Judge::verdict), moved here from the runner so that every
//! listener shares it.

use std::fmt::Write as _;

use super::show::{body_of, describe_reply, explain_invalid, show};
use super::{Conversation, Finding, Kind, Severity, Verdict};
use crate::codec::ascii::AsciiFrame;
use crate::codec::pdu::{function, Direction, Message, Pdu, Registers};
use crate::codec::rtu::RtuFrame;
use crate::codec::{self, Mode};
use crate::model::{Basis, DriveModel, Expectation, Fact, Judgement};

/// Values a read must return, known to the caller (None where any value is right), and
/// the fact that says so.
pub type Known<'a> = (&'a [Option<u16>], &'a Fact);

/// Compares `conv` with `judgement`; with `decisions`, where the device did what a
/// decision of the model says, adds the observation that the manual does not settle it.
pub(super) fn compare(
    model: &DriveModel,
    judgement: &Judgement,
    conv: &Conversation<'_>,
    known: Option<Known<'_>>,
    decisions: bool,
) -> Verdict {
    let mut c = compare_inner(model, judgement, conv, known.map(|(v, f)| (v, f.basis)));
    if decisions && c.findings.is_empty() {
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
            let text = format!(
                "the manual does not settle this; the device did what the model decides: {} ({}). Model: {why}",
                c.actual, judgement.detail
            );
            c.push(Kind::Decision, Finding::observation(text));
        }
    }
    c
}

/// Why bytes hold no valid reply, as a kind: a frame whose checksum is wrong, or no
/// frame at all.
fn invalid_kind(mode: Mode, rx: &[u8]) -> Kind {
    let bad_checksum = match mode {
        Mode::Rtu => RtuFrame::new_checked(rx).is_ok_and(|f| !f.checksum().is_valid()),
        Mode::Ascii => rx
            .iter()
            .position(|&c| c == b':')
            .and_then(|s| AsciiFrame::new_checked(&rx[s..]).ok())
            .is_some_and(|f| !f.checksum().is_valid()),
    };
    if bad_checksum {
        Kind::BadChecksum
    } else {
        Kind::Malformed
    }
}

fn compare_inner(
    model: &DriveModel,
    judgement: &Judgement,
    conv: &Conversation<'_>,
    known: Option<(&[Option<u16>], Basis)>,
) -> Verdict {
    let mode = conv.mode;
    let expect_sev = Severity::of(judgement.basis());
    let unit = if mode == Mode::Rtu {
        "bytes"
    } else {
        "characters"
    };
    let rx = conv.received;
    let actual = match conv.reply {
        // What the link said (a gateway's 0BH) comes first: "no reply" stays the end.
        None if rx.is_empty() && !conv.link_notes.is_empty() => {
            format!("{}: no reply", conv.link_notes.join("; "))
        }
        Some(r) => describe_reply(mode, r),
        None if rx.is_empty() => "no reply".to_string(),
        None => explain_invalid(mode, rx),
    };
    let mut v = Verdict {
        findings: Vec::new(),
        kinds: Vec::new(),
        expected: None,
        received: conv.reply.map(<[u8]>::to_vec),
        differing: Vec::new(),
        actual,
        predicted: format!(
            "{} ({}; {})",
            judgement.expect.describe(),
            judgement.detail,
            judgement.basis()
        ),
        citations: judgement.citations(),
    };
    // A local echo is the adapter's, not the device's: the master strips it (and the
    // report's link line says so); with --echo off it stays in the bytes and shows as
    // bytes before or after the reply.
    if conv.retries > 0 {
        v.push(
            Kind::Retried,
            Finding::observation(format!("answered only after {} resend(s)", conv.retries)),
        );
    }
    let manual = judgement.expect.describe();
    match &judgement.expect {
        Expectation::Silence(_) => {
            if !rx.is_empty() {
                let text = format!(
                    "manual: {manual} ({}); device sent {} {unit}: {}",
                    judgement.detail,
                    rx.len(),
                    match conv.reply {
                        Some(r) => format!("{} = {}", show(mode, r), describe_reply(mode, r)),
                        None => show(mode, rx),
                    }
                );
                v.push(
                    Kind::UnexpectedReply,
                    Finding {
                        severity: expect_sev,
                        text,
                    },
                );
            }
            return v;
        }
        _ if rx.is_empty() => {
            let text = format!(
                "manual: {manual} ({}); device: no reply within {} ms{}",
                judgement.detail,
                conv.timing.listened.as_millis(),
                if conv.link_notes.is_empty() {
                    String::new()
                } else {
                    format!(" ({})", conv.link_notes.join("; "))
                }
            );
            v.push(
                Kind::NoReply,
                Finding {
                    severity: expect_sev,
                    text,
                },
            );
            return v;
        }
        _ => {}
    }
    let Some(reply) = conv.reply else {
        let want = predicted_len(mode, judgement, conv.request);
        let (kind, text) = match want {
            Some(n) if rx.len() < n => (
                Kind::Truncated,
                format!(
                    "manual: {manual}; device: a truncated reply, {} of the {n} {unit} it needs: {}",
                    rx.len(),
                    show(mode, rx)
                ),
            ),
            _ => (
                invalid_kind(mode, rx),
                format!("manual: {manual}; device: {}", v.actual),
            ),
        };
        v.push(kind, Finding::deviation(text));
        return v;
    };
    for (extra, side) in [(conv.leading, "before"), (conv.trailing, "after")] {
        if !extra.is_empty() {
            v.push(
                Kind::ExtraBytes,
                Finding::deviation(format!(
                    "{} {unit} {side} the reply: {}",
                    extra.len(),
                    show(mode, extra)
                )),
            );
        }
    }
    let expected = expected_frame(mode, judgement, conv.request, reply, known.map(|k| k.0));
    if let Some(exp) = &expected {
        if exp != reply {
            v.differing = diff_positions(exp, reply);
            let got_body = body_of(mode, reply);
            let want_body = body_of(mode, exp);
            let got = got_body
                .as_deref()
                .and_then(|b| Message::parse_body(b, Direction::Response).ok());
            let want = want_body
                .as_deref()
                .and_then(|b| Message::parse_body(b, Direction::Response).ok());
            let (kind, sev) = match (&want, &got) {
                (Some(w), Some(g)) if w.address != g.address => {
                    (Kind::WrongAddress, Severity::Deviation)
                }
                (Some(w), Some(g)) => match (w.pdu, g.pdu) {
                    (Pdu::ReadResponse { values: a }, Pdu::ReadResponse { values: b })
                        if a.len() == b.len() =>
                    {
                        (
                            Kind::WrongValue,
                            known.map_or(Severity::Deviation, |k| Severity::of(k.1)),
                        )
                    }
                    (Pdu::Exception { .. }, _) | (_, Pdu::Exception { .. }) => {
                        (Kind::WrongException, expect_sev)
                    }
                    _ => (Kind::WrongReply, expect_sev),
                },
                _ => (Kind::WrongReply, expect_sev),
            };
            let mut text = format!(
                "manual: {} ({}); device: {}",
                want.map(|m| m.to_string())
                    .unwrap_or_else(|| manual.clone()),
                judgement.detail,
                got.map(|m| m.to_string())
                    .unwrap_or_else(|| v.actual.clone())
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
            v.push(
                kind,
                Finding {
                    severity: sev,
                    text,
                },
            );
        }
    }
    v.expected = expected;
    v
}

/// Positions where two frames differ, including the bytes one has beyond the other.
pub fn diff_positions(expected: &[u8], actual: &[u8]) -> Vec<usize> {
    let n = expected.len().max(actual.len());
    (0..n)
        .filter(|&i| expected.get(i) != actual.get(i))
        .collect()
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
