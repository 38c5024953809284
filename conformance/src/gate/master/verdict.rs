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
#[derive(Debug)]
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
    /// When the call began (the gate asked the adapter).
    pub called: Duration,
    /// When the call ended (the adapter's answer).
    pub ended: Duration,
    /// When the master's previous operation began: frames for earlier requests sent
    /// since are what a master that does not match replies to requests can take.
    pub recent: Duration,
    /// Whether the line has a line's timing (a pty: t3.5 is judged; TCP: not).
    pub timed: bool,
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

/// The longest silence the master can have seen on the line at any moment from `from`
/// (when it can have begun to wait: the operation asked, or its previous request sent)
/// to `to` (its request read): an upper bound, from each chunk's earliest and latest
/// time, so that a host that stalls while the drive sends never makes a master that
/// waited look as if it did not. `None`: nothing before it to be silent after.
fn longest_silence(log: &[Chunk], from: Duration, to: Duration) -> Option<Duration> {
    let mut events: Vec<&Chunk> = log.iter().filter(|c| c.at < to).collect();
    events.sort_by_key(|c| c.at);
    let last = events.last()?;
    let mut longest = to.saturating_sub(last.at);
    for w in events.windows(2) {
        if w[1].done >= from {
            longest = longest.max(w[1].done.saturating_sub(w[0].at));
        }
    }
    if events[0].done >= from {
        // Nothing before the first chunk: the line was silent as long as it likes.
        return Some(Duration::MAX);
    }
    Some(longest)
}

/// Where the drive's ASCII frame was open when a request was read at `at`: the time its
/// ':' went out (only if it was out, `done`, before `from`, when the master could begin to
/// wait), with no LF written before `at`. `None`: no frame of the drive was under way.
fn open_ascii_frame(log: &[Chunk], from: Duration, at: Duration) -> Option<Duration> {
    let mut open: Option<(Duration, Duration)> = None;
    let mut chunks: Vec<&Chunk> = log
        .iter()
        .filter(|c| c.dir == Dir::ToMaster && c.at < at)
        .collect();
    chunks.sort_by_key(|c| c.at);
    for c in chunks {
        for b in &c.bytes {
            match b {
                b':' => open = Some((c.at, c.done)),
                b'\n' => open = None,
                _ => {}
            }
        }
    }
    let (colon, done) = open.filter(|(_, done)| *done < from)?;
    let _ = done;
    // And the drive went on with that frame after the request: its LF came later (a
    // frame the drive abandoned, such as a truncated reply, is no frame under way).
    let mut later: Vec<&Chunk> = log
        .iter()
        .filter(|c| c.dir == Dir::ToMaster && c.at >= at)
        .collect();
    later.sort_by_key(|c| c.at);
    for c in later {
        for b in &c.bytes {
            match b {
                b'\n' => return Some(colon),
                b':' => return None,
                _ => {}
            }
        }
    }
    None
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
        // A master that says it timed out but sent nothing did not ask.
        if !matches!(rec.reported, Reported::Raised { .. }) {
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
    let mut from = rec.called;
    for r in rec.requests {
        let silence = if rec.timed {
            longest_silence(rec.log, from, r.start)
        } else {
            None
        };
        let from_before = from;
        from = r.end;
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
            side: Some(1),
        };
        // ASCII has no t3.5 (a frame begins with ':' and may pause up to a second
        // between characters), but a master still must not send while the drive's frame
        // is under way: its ':' out before the master could begin to wait, its LF not
        // yet begun when the request was read.
        if mode == crate::codec::Mode::Ascii && rec.timed {
            if let Some(colon) = open_ascii_frame(rec.log, from_before, r.start) {
                out.push(dev(
                    "talks-over-drive",
                    format!(
                        "request {}: sent while the drive's ASCII frame was under way (its ':' went out {:.1} ms before, its CR LF had not); Modbus over Serial Line V1.02, 2.5.2.1 (one device sends at a time)",
                        Hex(&r.bytes),
                        r.start.saturating_sub(colon).as_secs_f64() * 1000.0
                    ),
                ));
            }
        }
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
        // (A reply split by a silence over t1.5 is no valid reply: trying again is right.)
        let split = matches!(rec.behaviour, Behaviour::Split(_)) && rec.role == Role::Fault;
        let answered = !split
            && rec.sent.iter().any(|s| {
                s.for_seq == a.seq && s.class.valid() && s.at.is_some_and(|t| t < b.start)
            });
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
                out.push(dev(
                    kind,
                    format!(
                        "reported {} for {} where the drive sent {what} ({})",
                        rec.reported,
                        rec.op,
                        listed(&mine)
                    ),
                ));
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
                let (kind, what) = ("success-without-reply", "nothing valid");
                out.push(dev(
                    kind,
                    format!(
                        "reported {} for {} where the drive sent {what} ({})",
                        rec.reported,
                        rec.op,
                        listed(&mine)
                    ),
                ));
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

#[cfg(test)]
mod tests {
    use super::*;

    fn ms_(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn settings() -> MasterSettings {
        MasterSettings {
            timeout: ms_(300),
            retries: 0,
        }
    }

    fn read() -> Operation {
        Operation::Read {
            unit: 1,
            start: 0,
            count: 2,
        }
    }

    fn request(seq: u32, at: u64) -> Request {
        Request {
            seq,
            start: ms_(at),
            end: ms_(at),
            bytes: vec![0x01, 0x03, 0x00, 0x00, 0x00, 0x02, 0xC4, 0x0B],
            valid: true,
            address: 1,
        }
    }

    fn sent(seq: u32, class: SentClass, values: Option<Vec<u16>>, at: u64) -> Sent {
        Sent {
            for_seq: seq,
            bytes: vec![0x01, 0x03, 0x04],
            class,
            values,
            exception: None,
            at: Some(ms_(at)),
        }
    }

    fn judged(
        reported: Reported,
        requests: &[Request],
        frames: &[Sent],
        behaviour: Behaviour,
    ) -> Vec<String> {
        let op = read();
        let rec = OpRecord {
            op: &op,
            behaviour: &behaviour,
            role: Role::Recovery,
            reported: &reported,
            took: ms_(10),
            requests,
            sent: frames,
            log: &[],
            called: ms_(100),
            ended: ms_(200),
            recent: ms_(50),
            timed: true,
        };
        judge_report(&rec, &settings())
            .into_iter()
            .map(|f| f.kind)
            .collect()
    }

    #[test]
    fn values_are_traced_to_the_frame_that_carried_them() {
        let frames = [
            sent(1, SentClass::Stale, Some(vec![0x8010, 0x8011]), 60),
            sent(2, SentClass::Reply, Some(vec![0x8020, 0x8021]), 120),
            sent(3, SentClass::BadChecksum, Some(vec![0x8030, 0x8031]), 130),
        ];
        let reqs = [request(2, 110)];
        // Its own reply: nothing to say.
        assert!(judged(
            Reported::Values(vec![0x8020, 0x8021]),
            &reqs,
            &frames,
            Behaviour::Normal
        )
        .is_empty());
        // The reply to an earlier request.
        assert_eq!(
            judged(
                Reported::Values(vec![0x8010, 0x8011]),
                &reqs,
                &frames,
                Behaviour::Normal
            ),
            ["stale-reply-taken"]
        );
        // Values no frame carried.
        assert_eq!(
            judged(
                Reported::Values(vec![1, 2]),
                &reqs,
                &frames,
                Behaviour::Normal
            ),
            ["wrong-values"]
        );
        // A frame with a bad checksum, for this request.
        let bad = [sent(
            2,
            SentClass::BadChecksum,
            Some(vec![0x8040, 0x8041]),
            120,
        )];
        assert_eq!(
            judged(
                Reported::Values(vec![0x8040, 0x8041]),
                &reqs,
                &bad,
                Behaviour::BadChecksum
            ),
            ["accepted-bad-checksum"]
        );
    }

    #[test]
    fn exceptions_are_held_to_the_code_sent() {
        let mut e = sent(2, SentClass::Reply, None, 120);
        e.exception = Some(0x52);
        let frames = [e];
        let reqs = [request(2, 110)];
        assert!(judged(
            Reported::Exception(0x52),
            &reqs,
            &frames,
            Behaviour::Exception(0x52)
        )
        .is_empty());
        assert_eq!(
            judged(
                Reported::Exception(0x02),
                &reqs,
                &frames,
                Behaviour::Exception(0x52)
            ),
            ["wrong-exception-code"]
        );
        let error = Reported::Error {
            kind: super::super::protocol::ErrorKind::Other,
            message: "unknown code".into(),
        };
        assert_eq!(
            judged(error, &reqs, &frames, Behaviour::Exception(0x52)),
            ["exception-not-recognised"]
        );
        assert_eq!(
            judged(
                Reported::Values(vec![]),
                &reqs,
                &frames,
                Behaviour::Exception(0x52)
            ),
            ["exception-ignored"]
        );
    }

    #[test]
    fn a_failure_is_right_only_where_nothing_valid_came_in_time() {
        let timeout = || Reported::Error {
            kind: super::super::protocol::ErrorKind::Timeout,
            message: "no reply".into(),
        };
        let reqs = [request(2, 110)];
        // Nothing came: a timeout is right.
        assert!(judged(timeout(), &reqs, &[], Behaviour::NoReply).is_empty());
        // The reply came after the call ended: right too.
        let late = [sent(2, SentClass::Reply, Some(vec![1, 2]), 250)];
        assert!(judged(timeout(), &reqs, &late, Behaviour::Normal).is_empty());
        // The reply came at once: the read after a fault did not recover.
        let prompt = [sent(2, SentClass::Reply, Some(vec![1, 2]), 111)];
        assert_eq!(
            judged(timeout(), &reqs, &prompt, Behaviour::Normal),
            ["no-recovery"]
        );
    }

    fn chunk(at: u64, done: u64, dir: Dir, bytes: &[u8]) -> Chunk {
        Chunk {
            at: ms_(at),
            done: ms_(done),
            dir,
            bytes: bytes.to_vec(),
        }
    }

    #[test]
    fn the_silence_before_a_request_is_an_upper_bound() {
        // The drive sent a byte every millisecond up to 50 ms; one write took 9 ms to
        // return (a stall between reading the clock and writing).
        let mut log: Vec<Chunk> = (0..50)
            .map(|t| chunk(t, t, Dir::ToMaster, &[0xFF]))
            .collect();
        log[20].done = ms_(29);
        // A request read at 51 ms, asked at 30 ms: after 30 ms the drive sent a byte a
        // millisecond, then the last one at 49 ms: at most 2 ms of silence. The stalled
        // write went out before 30 ms and does not count.
        assert_eq!(longest_silence(&log, ms_(30), ms_(51)), Some(ms_(2)));
        // Asked at 10 ms: the stalled write (recorded at 19, done at 29) may have left
        // 29 - 19 = 10 ms of silence.
        assert_eq!(longest_silence(&log, ms_(10), ms_(51)), Some(ms_(10)));
        // Nothing before the request: as long as it likes.
        assert_eq!(longest_silence(&[], ms_(0), ms_(5)), None);
    }

    #[test]
    fn an_ascii_frame_is_under_way_from_its_colon_to_its_lf() {
        let mut log = vec![chunk(0, 0, Dir::ToMaster, b":")];
        log.extend((1..40).map(|t| chunk(t, t, Dir::ToMaster, b"0")));
        log.push(chunk(40, 40, Dir::ToMaster, b"\r\n"));
        // Read at 20 ms, asked at 10 ms: under way.
        assert_eq!(
            open_ascii_frame(&log, ms_(10), ms_(20)),
            Some(Duration::ZERO)
        );
        // Read after the LF: not.
        assert_eq!(open_ascii_frame(&log, ms_(10), ms_(45)), None);
        // A frame the drive abandoned (no LF ever): not under way.
        let cut: Vec<Chunk> = log[..30].to_vec();
        assert_eq!(open_ascii_frame(&cut, ms_(10), ms_(20)), None);
    }

    // The gate's arithmetic over anything an option, an adapter or a stalled host can give
    // it: timeouts of any length (none, years), any retries and baud rate, any fault, and
    // requests and line chunks at any times, in any order. It returns findings or none;
    // it never panics (issue 33: a first request's unbounded silence plus one character
    // overflowed).
    mod arithmetic {
        use super::*;
        use crate::codec::timing::{LineSettings, Parity};
        use crate::codec::Mode;
        use crate::model::DriveModel;
        use crate::monitor::{Monitor, MonitorConfig};
        use proptest::prelude::*;

        fn any_duration() -> impl Strategy<Value = Duration> {
            prop_oneof![
                (0u64..2_000).prop_map(Duration::from_millis),
                any::<u64>().prop_map(Duration::from_micros),
                any::<u64>().prop_map(Duration::from_millis),
                Just(Duration::ZERO),
                Just(Duration::MAX),
            ]
        }

        fn any_behaviour() -> impl Strategy<Value = Behaviour> {
            prop_oneof![
                Just(Behaviour::Normal),
                Just(Behaviour::NoReply),
                Just(Behaviour::AfterTimeout),
                Just(Behaviour::InFlight),
                Just(Behaviour::Twice),
                Just(Behaviour::BadChecksum),
                Just(Behaviour::Truncated),
                Just(Behaviour::WrongFunction),
                any_duration().prop_map(Behaviour::Late),
                any_duration().prop_map(Behaviour::Split),
                any::<u8>().prop_map(Behaviour::Exception),
                proptest::collection::vec(any::<u8>(), 0..4).prop_map(Behaviour::GarbageBefore),
            ]
        }

        fn any_reported() -> impl Strategy<Value = Reported> {
            prop_oneof![
                proptest::collection::vec(any::<u16>(), 0..3).prop_map(Reported::Values),
                Just(Reported::Done),
                any::<u8>().prop_map(Reported::Exception),
                Just(Reported::Raised {
                    kind: "timeout".into(),
                    message: "no reply".into()
                }),
            ]
        }

        proptest! {
            #![proptest_config(ProptestConfig::with_cases(2_000))]
            #[test]
            fn judging_an_operation_never_panics(
                ascii in any::<bool>(),
                baud in any::<u32>(),
                timeout in any_duration(),
                retries in any::<u32>(),
                behaviour in any_behaviour(),
                reported in any_reported(),
                role_fault in any::<bool>(),
                times in proptest::collection::vec(any_duration(), 6),
                req_at in proptest::collection::vec((any_duration(), any_duration(), any::<bool>()), 0..4),
                chunks in proptest::collection::vec((any_duration(), any_duration(), any::<bool>(), any::<u8>()), 0..6),
                sent_at in proptest::collection::vec(proptest::option::of(any_duration()), 0..3),
                timed in any::<bool>(),
            ) {
                let mode = if ascii { Mode::Ascii } else { Mode::Rtu };
                let line = LineSettings::new(baud, if ascii { 7 } else { 8 }, Parity::Even, 1);
                let settings = MasterSettings { timeout, retries };
                let cfg = MonitorConfig {
                    mode,
                    line,
                    nodes: vec![1],
                    window: timeout.max(Duration::from_millis(1)),
                    response_allowance: Duration::from_millis(5),
                    gap_allowance: Duration::from_millis(5),
                };
                let monitor = Monitor::new(DriveModel::builtin("f510").unwrap(), cfg).unwrap();
                let requests: Vec<Request> = req_at
                    .iter()
                    .enumerate()
                    .map(|(i, (start, end, valid))| Request {
                        seq: i as u32,
                        start: *start,
                        end: *end,
                        bytes: vec![0x01, 0x03, 0x00, 0x00, 0x00, 0x02, 0xC4, 0x0B],
                        valid: *valid,
                        address: 1,
                    })
                    .collect();
                let log: Vec<Chunk> = chunks
                    .iter()
                    .map(|(at, done, to_master, b)| Chunk {
                        at: *at,
                        done: *done,
                        dir: if *to_master { Dir::ToMaster } else { Dir::FromMaster },
                        bytes: vec![*b, b':', b'\n'],
                    })
                    .collect();
                let frames: Vec<Sent> = sent_at
                    .iter()
                    .enumerate()
                    .map(|(i, at)| Sent {
                        for_seq: i as u32,
                        bytes: vec![0x01, 0x03, 0x04],
                        class: SentClass::Reply,
                        values: Some(vec![1, 2]),
                        exception: None,
                        at: *at,
                    })
                    .collect();
                let op = Operation::Read { unit: 1, start: 0, count: 2 };
                let rec = OpRecord {
                    op: &op,
                    behaviour: &behaviour,
                    role: if role_fault { Role::Fault } else { Role::Recovery },
                    reported: &reported,
                    took: times[0],
                    requests: &requests,
                    sent: &frames,
                    log: &log,
                    called: times[1],
                    ended: times[2],
                    recent: times[3],
                    timed,
                };
                let _ = judge_requests(&rec, &monitor, &settings);
                let _ = judge_report(&rec, &settings);
            }
        }
    }
}
