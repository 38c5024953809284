//! Items 1 and 2 of the judgement: the requests the master put on the line, the silence
//! before each, its retries and its wait after a broadcast.

use std::time::Duration;

use crate::codec::hex::Hex;
use crate::gate::master::drive::{Behaviour, Chunk, Dir, Request};
use crate::gate::master::protocol::{MasterSettings, Reported};
use crate::monitor::{EndedBy, FrameStatus, Monitor, Side, TapFrame};

use super::{dev, ms, obs, MasterFinding, OpRecord, Role};

/// The longest silence the master can have seen on the line at any moment from `from`
/// (when it can have begun to wait: the operation asked, or its previous request sent)
/// to `to` (its request read): an upper bound, from each chunk's earliest and latest
/// time, so that a host that stalls while the drive sends never makes a master that
/// waited look as if it did not. `None`: nothing before it to be silent after.
pub(super) fn longest_silence(log: &[Chunk], from: Duration, to: Duration) -> Option<Duration> {
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
pub(super) fn open_ascii_frame(log: &[Chunk], from: Duration, at: Duration) -> Option<Duration> {
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
