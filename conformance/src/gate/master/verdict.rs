//! The judgement of one operation of the master under test:
//!
//! 1. every request it put on the line, against the manual and the model, through the
//!    monitor's judge of a master's request ([`Monitor::judge_master_request`]), with the
//!    silence before it measured on the gate's line (t3.5; a request while the drive
//!    was still sending);
//! 2. its retries (how many, how soon) and the wait after a broadcast, against its own
//!    settings;
//! 3. what it reported against what the drive sent for that operation: the values of a
//!    valid reply to one of its own requests, the exception code sent, a failure where
//!    nothing valid came; never values from a frame of an earlier request, another node
//!    or with a wrong checksum (the values are tags: [`super::drive::tags`]);
//! 4. for the read after each fault, the same: it must succeed (recovery).

use std::time::Duration;

use super::drive::{Behaviour, Chunk, Dir, Request, Sent, SentClass};
use super::protocol::{MasterSettings, Operation, Reported};
use crate::codec::hex::Hex;
use crate::judge::Severity;
use crate::monitor::{EndedBy, FrameStatus, Monitor, Side, TapFrame};

/// One finding about the master, with its kind.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MasterFinding {
    /// The kind ("stale-reply-taken", "no-t3.5", ...).
    pub kind: String,
    /// Deviation or observation.
    pub severity: Severity,
    /// What, with bytes in hex.
    pub text: String,
}

fn dev(kind: &str, text: String) -> MasterFinding {
    MasterFinding {
        kind: kind.to_string(),
        severity: Severity::Deviation,
        text,
    }
}

fn obs(kind: &str, text: String) -> MasterFinding {
    MasterFinding {
        kind: kind.to_string(),
        severity: Severity::Observation,
        text,
    }
}

/// Which operation of a case is judged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// The operation under the fault.
    Fault,
    /// The normal read after it.
    Recovery,
}

/// What one operation put on the line and got back.
pub struct OpRecord<'a> {
    /// The operation.
    pub op: &'a Operation,
    /// What the drive did.
    pub behaviour: &'a Behaviour,
    /// Fault or recovery.
    pub role: Role,
    /// What the master reported.
    pub reported: &'a Reported,
    /// How long the call took.
    pub took: Duration,
    /// The requests the drive received during the call.
    pub requests: &'a [Request],
    /// Every frame the drive sent in the run so far (to look values up).
    pub sent: &'a [Sent],
    /// The whole line log so far.
    pub log: &'a [Chunk],
    /// When the call ended (the adapter's answer).
    pub ended: Duration,
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

/// The silence on the line before `at`: since the last bytes either way before it.
fn silence_before(log: &[Chunk], at: Duration) -> Option<Duration> {
    log.iter()
        .filter(|c| c.at < at)
        .map(|c| c.at)
        .max()
        .map(|last| at.saturating_sub(last))
}

/// Whether the drive was sending bytes just before `at` (a chunk to the master within
/// `within` before it).
fn drive_sending(log: &[Chunk], at: Duration, within: Duration) -> bool {
    log.iter()
        .any(|c| c.dir == Dir::ToMaster && c.at < at && at.saturating_sub(c.at) <= within)
}

/// The kind a monitor finding on a master's request gets in the master gate.
fn kind_of_issue(kind: &str) -> &str {
    match kind {
        "count-over-limit" => "request-over-limit",
        other => other,
    }
}

/// Items 1 and 2: the requests on the line.
pub fn judge_requests(
    rec: &OpRecord<'_>,
    monitor: &Monitor,
    settings: &MasterSettings,
) -> Vec<MasterFinding> {
    let mut out = Vec::new();
    let mode = monitor.config().mode;
    let line = monitor.config().line;
    if rec.requests.is_empty() {
        if !rec.reported.failed() {
            out.push(dev(
                "no-request",
                format!(
                    "the master reported {} for {} but sent no request",
                    rec.reported, rec.op
                ),
            ));
        }
        return out;
    }
    for r in rec.requests {
        let silence = silence_before(rec.log, r.start);
        let f = TapFrame {
            bytes: r.bytes.clone(),
            status: if r.valid {
                FrameStatus::Valid
            } else {
                FrameStatus::Corrupt
            },
            ended_by: EndedBy::Silence,
            start: Some(r.start),
            end: r.end,
            end_low: r.end,
            silence_before: silence,
            max_gap: None,
            side: Some(true),
        };
        for issue in monitor.judge_master_request(&f) {
            if issue.side != Side::Master {
                continue;
            }
            let mut text = issue.text.clone();
            if issue.kind == "no-t3.5"
                && drive_sending(rec.log, r.start, Duration::from_micros(line.t3_5_us()))
            {
                text.push_str(": the drive was still sending");
            }
            out.push(MasterFinding {
                kind: kind_of_issue(issue.kind).to_string(),
                severity: issue.severity,
                text: format!("request {}: {text}", Hex(&r.bytes)),
            });
        }
    }
    let _ = mode;
    // Retries: how many, and how soon. Only requests carrying the operation (another
    // frame of the master is judged above).
    let tries: Vec<&Request> = rec.requests.iter().filter(|r| r.valid).collect();
    let allowed = settings.retries as usize + 1;
    let broadcast = rec.op.broadcast();
    let allowed = if broadcast { 1 } else { allowed };
    if tries.len() > allowed {
        out.push(dev(
            "retry-storm",
            format!(
                "{} tries of {} (its setting: {} retries{})",
                tries.len(),
                rec.op,
                settings.retries,
                if broadcast {
                    "; a broadcast is never resent, no reply can come"
                } else {
                    ""
                }
            ),
        ));
    }
    for w in tries.windows(2) {
        let (a, b) = (w[0], w[1]);
        let answered = rec
            .sent
            .iter()
            .any(|s| s.for_seq == a.seq && s.class.valid() && s.at.is_some_and(|t| t < b.start));
        let pause = b.start.saturating_sub(a.end);
        if answered {
            out.push(dev(
                "retry-storm",
                format!(
                    "sent {} again {:.1} ms after a valid reply to it came",
                    Hex(&b.bytes),
                    ms(pause)
                ),
            ));
        } else if pause < settings.timeout / 2 {
            out.push(dev(
                "retry-storm",
                format!(
                    "sent {} again {:.1} ms after the previous try, before its own timeout of {} ms",
                    Hex(&b.bytes),
                    ms(pause),
                    settings.timeout.as_millis()
                ),
            ));
        }
    }
    if broadcast && rec.took >= settings.timeout && !rec.reported.failed() {
        out.push(obs(
            "waits-after-broadcast",
            format!(
                "the broadcast took {:.0} ms, as long as its timeout of {} ms: it waited for a reply that cannot come",
                ms(rec.took),
                settings.timeout.as_millis()
            ),
        ));
    }
    out
}

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
    }
}

/// Items 3 and 4: what the master reported for the operation.
pub fn judge_report(rec: &OpRecord<'_>, settings: &MasterSettings) -> Vec<MasterFinding> {
    let mut out = Vec::new();
    let seqs: Vec<u32> = rec.requests.iter().map(|r| r.seq).collect();
    let ours = |s: &Sent| seqs.contains(&s.for_seq);
    // The valid replies to this operation's requests that came while it waited.
    let valid: Vec<&Sent> = rec
        .sent
        .iter()
        .filter(|s| ours(s) && s.class == SentClass::Reply && s.at.is_some_and(|t| t <= rec.ended))
        .collect();
    let split = matches!(rec.behaviour, Behaviour::Split(_)) && rec.role == Role::Fault;
    let valid_exception = valid.iter().find_map(|s| s.exception);
    let valid_values: Option<&Sent> = valid.iter().copied().find(|s| s.values.is_some());
    let failing_kind = match rec.role {
        Role::Recovery => "no-recovery",
        Role::Fault => "missed-reply",
    };
    let what_came = |list: &[&Sent]| -> String {
        list.iter()
            .map(|s| Hex(&s.bytes).to_string())
            .collect::<Vec<_>>()
            .join(" / ")
    };
    if let Reported::Raised { kind, message } = rec.reported {
        out.push(dev(
            "raised",
            format!(
                "the library raised {kind}: {message} (for {}; the drive sent {})",
                rec.op,
                if valid.is_empty() {
                    "no valid reply".to_string()
                } else {
                    what_came(&valid)
                }
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
    if let (Some(code), false) = (valid_exception, split) {
        match rec.reported {
            Reported::Exception(c) if *c == code => {}
            Reported::Exception(c) => out.push(dev(
                "wrong-exception-code",
                format!(
                    "reported exception {c:02X}H where the drive sent {code:02X}H ({})",
                    what_came(&valid)
                ),
            )),
            Reported::Error { .. } => out.push(dev(
                "exception-not-recognised",
                format!(
                    "reported {} where the drive sent exception {code:02X}H ({})",
                    rec.reported,
                    what_came(&valid)
                ),
            )),
            other => out.push(dev(
                "exception-ignored",
                format!(
                    "reported {other} where the drive sent exception {code:02X}H ({}): the exception taken as data",
                    what_came(&valid)
                ),
            )),
        }
        return out;
    }
    match rec.reported {
        Reported::Values(v) => {
            // A valid reply to this operation first: a copy of it carries the same values.
            let from = rec
                .sent
                .iter()
                .find(|s| ours(s) && s.class == SentClass::Reply && s.values.as_deref() == Some(v))
                .or_else(|| source_of(rec.sent, v));
            match (from, valid_values) {
                (Some(s), _) if ours(s) && s.class == SentClass::Reply => {
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
                (Some(s), _) => {
                    let (kind, what) = if ours(s) {
                        class_kind(s.class)
                    } else if matches!(s.class, SentClass::OtherNode | SentClass::BadChecksum) {
                        class_kind(s.class)
                    } else {
                        ("stale-reply-taken", "a reply to an earlier request")
                    };
                    out.push(dev(
                        kind,
                        format!(
                            "reported the values {} of {what} ({}, for request #{}) as the answer to {}{}",
                            v.iter().map(|x| format!("{x:04X}")).collect::<Vec<_>>().join(" "),
                            Hex(&s.bytes),
                            s.for_seq,
                            rec.op,
                            match valid_values {
                                Some(r) => format!("; its own reply was {}", Hex(&r.bytes)),
                                None => String::new(),
                            }
                        ),
                    ));
                }
                (None, Some(r)) => out.push(dev(
                    "wrong-values",
                    format!(
                        "reported values {} where the drive sent {}",
                        v.iter().map(|x| format!("{x:04X}")).collect::<Vec<_>>().join(" "),
                        Hex(&r.bytes)
                    ),
                )),
                (None, None) => out.push(dev(
                    "wrong-values",
                    format!(
                        "reported values {} where no valid reply came",
                        v.iter().map(|x| format!("{x:04X}")).collect::<Vec<_>>().join(" ")
                    ),
                )),
            }
        }
        Reported::Done | Reported::Echo { .. } => {
            if valid.is_empty() {
                let came: Vec<&Sent> = rec.sent.iter().filter(|s| ours(s)).collect();
                let (kind, what) = came
                    .iter()
                    .find(|s| s.class != SentClass::Garbage)
                    .map_or(("success-without-reply", "nothing valid"), |s| {
                        class_kind(s.class)
                    });
                let kind = if kind == "stale-reply-taken" && rec.role == Role::Fault {
                    // A reply to this very operation, sent after it ended: the master did
                    // not wait for it.
                    "success-without-reply"
                } else {
                    kind
                };
                out.push(dev(
                    kind,
                    format!(
                        "reported {} for {} where the drive sent {what}{}",
                        rec.reported,
                        rec.op,
                        if came.is_empty() {
                            String::new()
                        } else {
                            format!(" ({})", what_came(&came))
                        }
                    ),
                ));
            } else if let (Reported::Echo { data, .. }, Operation::LoopBack { data: asked, .. }) =
                (rec.reported, rec.op)
            {
                if data != asked {
                    out.push(dev(
                        "wrong-values",
                        format!("a loop-back echoed {} for {}", Hex(data), Hex(asked)),
                    ));
                }
            }
        }
        Reported::Exception(c)
            if rec.sent.iter().any(|s| {
                ours(s)
                    && matches!(s.class, SentClass::NoChecksum | SentClass::BadChecksum)
                    && s.exception == Some(*c)
            }) =>
        {
            out.push(dev(
                "accepted-bad-checksum",
                format!(
                    "reported exception {c:02X}H from a frame with a wrong or missing checksum ({})",
                    what_came(&rec.sent.iter().filter(|s| ours(s)).collect::<Vec<_>>())
                ),
            ))
        }
        Reported::Exception(c) => out.push(dev(
            "invented-exception",
            format!(
                "reported exception {c:02X}H where the drive sent no valid exception{}",
                {
                    let came: Vec<&Sent> = rec.sent.iter().filter(|s| ours(s)).collect();
                    if came.is_empty() {
                        String::new()
                    } else {
                        format!(" (it sent {})", what_came(&came))
                    }
                }
            ),
        )),
        Reported::Error { .. } => {
            if !valid.is_empty() && !split {
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
                    what_came(&valid),
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
