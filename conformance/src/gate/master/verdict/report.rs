//! Items 3 and 4 of the judgement: what the master reported against what the drive sent
//! for the operation, and the recovery read after each fault.

use std::time::Duration;

use crate::codec::hex::Hex;
use crate::gate::master::drive::{Behaviour, Sent, SentClass};
use crate::gate::master::protocol::{MasterSettings, Operation, Reported};

use super::{dev, ms, obs, MasterFinding, OpRecord, Role};

/// Where values the master reported came from.
fn source_of<'a>(sent: &'a [Sent], values: &[u16]) -> Option<&'a Sent> {
    sent.iter()
        .rev()
        .find(|s| s.values.as_deref() == Some(values))
}

fn class_kind(class: SentClass) -> (&'static str, &'static str) {
    match class {
        SentClass::Reply | SentClass::Stale | SentClass::Duplicate => {
            ("stale-reply-taken", "a reply to an earlier request")
        }
        SentClass::OtherNode => ("accepted-other-node", "another node's reply"),
        SentClass::BadChecksum | SentClass::NoChecksum | SentClass::Truncated => (
            "accepted-bad-checksum",
            "a frame with a wrong or missing checksum",
        ),
        SentClass::BroadcastReply => ("accepted-broadcast-reply", "a reply to a broadcast"),
        SentClass::Garbage => ("wrong-values", "bytes that are no frame"),
        SentClass::WrongFunction => ("accepted-wrong-function", "a reply of another function"),
    }
}

/// Items 3 and 4: what the master reported for the operation.
pub fn judge_report(rec: &OpRecord<'_>, settings: &MasterSettings) -> Vec<MasterFinding> {
    let mut out = Vec::new();
    let seqs: Vec<u32> = rec.requests.iter().map(|r| r.seq).collect();
    let ours = |s: &Sent| seqs.contains(&s.for_seq);
    let came_in_time = |s: &Sent| s.at.is_some_and(|t| t <= rec.ended);
    // The valid replies to this operation's requests that came while it waited.
    // A late reply to an earlier try of this very operation (stale, but ours) answers
    // the same question.
    let valid: Vec<&Sent> = rec
        .sent
        .iter()
        .filter(|s| {
            ours(s) && matches!(s.class, SentClass::Reply | SentClass::Stale) && came_in_time(s)
        })
        .collect();
    let mine: Vec<&Sent> = rec
        .sent
        .iter()
        .filter(|s| ours(s) && came_in_time(s))
        .collect();
    let split = matches!(rec.behaviour, Behaviour::Split(_)) && rec.role == Role::Fault;
    let valid_exception = valid.iter().find_map(|s| s.exception).filter(|_| !split);
    let function = rec.op.function();
    // Valid frames for earlier requests, of this operation's function, that came since
    // the master's previous operation began: what a master that does not match replies
    // to requests can have taken.
    let earlier = |exception: Option<u8>| -> Option<&Sent> {
        rec.sent.iter().rev().find(|s| {
            !ours(s)
                && matches!(
                    s.class,
                    SentClass::Reply
                        | SentClass::Stale
                        | SentClass::Duplicate
                        | SentClass::BroadcastReply
                )
                && s.at.is_some_and(|t| t > rec.recent && t <= rec.ended)
                && s.bytes.len() > 1
                && frame_function(&s.bytes)
                    == Some(function | if exception.is_some() { 0x80 } else { 0 })
                && (exception.is_none() || s.exception == exception)
        })
    };
    let listed = |list: &[&Sent]| -> String {
        if list.is_empty() {
            return "nothing".into();
        }
        list.iter()
            .map(|s| Hex(&s.bytes).to_string())
            .collect::<Vec<_>>()
            .join(" / ")
    };
    let stale = |s: &Sent| {
        dev(
            "stale-reply-taken",
            format!(
                "reported {} for {}: what a frame for an earlier request says ({}, request #{}, which came after its previous operation began); for this operation the drive sent {}",
                rec.reported,
                rec.op,
                Hex(&s.bytes),
                s.for_seq,
                listed(&mine)
            ),
        )
    };
    let failing_kind = match rec.role {
        Role::Recovery => "no-recovery",
        Role::Fault => "missed-reply",
    };
    if let Reported::Raised { kind, message } = rec.reported {
        out.push(dev(
            "raised",
            format!(
                "the library raised {kind}: {message} (for {}; the drive sent {})",
                rec.op,
                listed(&mine)
            ),
        ));
        return out;
    }
    let tagged = match rec.reported {
        Reported::Values(v) => source_of(rec.sent, v).is_some(),
        _ => false,
    };
    if matches!(rec.behaviour, Behaviour::WrongFunction)
        && rec.role == Role::Fault
        && !rec.reported.failed()
        && !tagged
    {
        out.push(dev(
            "accepted-wrong-function",
            format!(
                "reported {} for {} where the drive sent only a frame of another function ({}): a reply must answer the request's function",
                rec.reported,
                rec.op,
                listed(&mine)
            ),
        ));
        return out;
    }
    if rec.op.broadcast() {
        if rec.reported.failed() {
            out.push(dev(
                "waits-after-broadcast",
                format!(
                    "a broadcast returned {} (no reply can come to unit 0: the master must not wait for one)",
                    rec.reported
                ),
            ));
        }
        return out;
    }
    match rec.reported {
        Reported::Values(v) => {
            // By the tags: a valid reply to this operation first (a copy of it carries
            // the same values), then any frame of the run.
            let from = rec
                .sent
                .iter()
                .find(|s| ours(s) && s.class == SentClass::Reply && s.values.as_deref() == Some(v))
                .or_else(|| source_of(rec.sent, v));
            let values = v
                .iter()
                .map(|x| format!("{x:04X}"))
                .collect::<Vec<_>>()
                .join(" ");
            match from {
                Some(s) if ours(s) && s.class == SentClass::Reply => {
                    if split {
                        out.push(obs(
                            "accepted-split-reply",
                            format!(
                                "took the values of a reply with a silence over t1.5 inside it ({}); Modbus over Serial Line V1.02, 2.5.1.1 says such a frame is discarded (a master behind OS buffering cannot always see the silence)",
                                Hex(&s.bytes)
                            ),
                        ));
                    }
                }
                // A late reply to an earlier try of this very operation: the same
                // question, the same answer.
                Some(s) if ours(s) && s.class == SentClass::Stale => {}
                Some(s) if !ours(s) && !matches!(s.class, SentClass::OtherNode | SentClass::BadChecksum) => {
                    out.push(stale(s))
                }
                Some(s) => {
                    let (kind, what) = class_kind(s.class);
                    out.push(dev(
                        kind,
                        format!(
                            "reported the values {values} of {what} ({}, for request #{}) as the answer to {}; for it the drive sent {}",
                            Hex(&s.bytes),
                            s.for_seq,
                            rec.op,
                            listed(&mine)
                        ),
                    ));
                }
                None if valid_exception.is_some() => out.push(dev(
                    "exception-ignored",
                    format!(
                        "reported values {values} where the drive sent exception {:02X}H ({}): the exception taken as data",
                        valid_exception.unwrap_or(0),
                        listed(&valid)
                    ),
                )),
                None => out.push(dev(
                    "wrong-values",
                    format!(
                        "reported values {values} for {}, which no frame carried; the drive sent {}",
                        rec.op,
                        listed(&mine)
                    ),
                )),
            }
        }
        Reported::Exception(c) => {
            if valid_exception == Some(*c) {
                let sent = valid.iter().filter_map(|s| s.at).min().unwrap_or(rec.ended);
                if rec.ended.saturating_sub(sent) >= settings.timeout {
                    out.push(obs(
                        "slow-exception",
                        format!(
                            "reported exception {c:02X}H only {:.0} ms after it came, as long as its timeout of {} ms",
                            ms(rec.ended.saturating_sub(sent)),
                            settings.timeout.as_millis()
                        ),
                    ));
                }
                return out;
            }
            if let Some(s) = mine.iter().find(|s| {
                matches!(s.class, SentClass::NoChecksum | SentClass::BadChecksum)
                    && s.exception == Some(*c)
            }) {
                out.push(dev(
                    "accepted-bad-checksum",
                    format!(
                        "reported exception {c:02X}H from a frame with a wrong or missing checksum ({})",
                        Hex(&s.bytes)
                    ),
                ));
            } else if let Some(s) = earlier(Some(*c)) {
                out.push(stale(s));
            } else if let Some(code) = valid_exception {
                out.push(dev(
                    "wrong-exception-code",
                    format!(
                        "reported exception {c:02X}H where the drive sent {code:02X}H ({})",
                        listed(&valid)
                    ),
                ));
            } else {
                out.push(dev(
                    "invented-exception",
                    format!(
                        "reported exception {c:02X}H where the drive sent no valid exception ({})",
                        listed(&mine)
                    ),
                ));
            }
        }
        Reported::Done | Reported::Echo { .. } => {
            // A success reported where the drive sent `what`.
            let success_on = |kind: &str, what: &str| {
                dev(
                    kind,
                    format!(
                        "reported {} for {} where the drive sent {what} ({})",
                        rec.reported,
                        rec.op,
                        listed(&mine)
                    ),
                )
            };
            let normal = valid.iter().any(|s| s.exception.is_none()) && !split;
            if normal {
                if let (Reported::Echo { data, .. }, Operation::LoopBack { data: asked, .. }) =
                    (rec.reported, rec.op)
                {
                    if data != asked {
                        out.push(dev(
                            "wrong-values",
                            format!("a loop-back echoed {} for {}", Hex(data), Hex(asked)),
                        ));
                    }
                }
            } else if let Some(bad) = mine.iter().find(|s| {
                valid_exception.is_none()
                    && !matches!(
                        s.class,
                        SentClass::Garbage | SentClass::Reply | SentClass::Stale
                    )
            }) {
                // A frame of its own that answers it, but must not be taken.
                let (kind, what) = class_kind(bad.class);
                out.push(success_on(kind, what));
            } else if let Some(s) = earlier(None) {
                out.push(stale(s));
            } else if let Some(code) = valid_exception {
                out.push(dev(
                    "exception-ignored",
                    format!(
                        "reported {} where the drive sent exception {code:02X}H ({}): the exception taken as success",
                        rec.reported,
                        listed(&valid)
                    ),
                ));
            } else {
                out.push(success_on("success-without-reply", "nothing valid"));
            }
        }
        Reported::Error { .. } => {
            if let (Some(code), false) = (valid_exception, split) {
                out.push(dev(
                    "exception-not-recognised",
                    format!(
                        "reported {} where the drive sent exception {code:02X}H ({})",
                        rec.reported,
                        listed(&valid)
                    ),
                ));
            } else if !valid.is_empty() && !split {
                let late = matches!(rec.behaviour, Behaviour::Late(_)) && rec.role == Role::Fault;
                let garbage = matches!(
                    rec.behaviour,
                    Behaviour::GarbageBefore(_) | Behaviour::GarbageAfter(_)
                ) && rec.role == Role::Fault;
                let first = rec.requests.first().map_or(Duration::ZERO, |r| r.end);
                let when = valid
                    .iter()
                    .filter_map(|s| s.at)
                    .min()
                    .unwrap_or_default()
                    .saturating_sub(first);
                let text = format!(
                    "reported {} for {} although a valid reply came {:.1} ms after the request ({}), inside its timeout of {} ms",
                    rec.reported,
                    rec.op,
                    ms(when),
                    listed(&valid),
                    settings.timeout.as_millis()
                );
                if late {
                    out.push(obs("late-reply-missed", text));
                } else if garbage {
                    out.push(dev("garbage-breaks-reply", text));
                } else {
                    out.push(dev(failing_kind, text));
                }
            }
        }
        Reported::Raised { .. } => {}
    }
    out
}

/// The function byte of an RTU or ASCII frame.
fn frame_function(bytes: &[u8]) -> Option<u8> {
    if bytes.first() == Some(&b':') {
        let hex = std::str::from_utf8(bytes.get(3..5)?).ok()?;
        u8::from_str_radix(hex, 16).ok()
    } else {
        bytes.get(1).copied()
    }
}
