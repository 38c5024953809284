//! One exchange judged: a request with its reply (or its silence) through the shared
//! judge, counted in the node's statistics, its findings' first examples kept, and its
//! live line made where anyone reads it.

use std::borrow::Cow;
use std::sync::Arc;
use std::time::Duration;

use super::{
    is_copy, live, ms, worst, EndedBy, Example, FrameStatus, Issue, Line, Monitor, Pending, Side,
    TapFrame,
};
use crate::codec::pdu::Direction;
use crate::codec::{self, Mode};
use crate::judge::{self, Conversation, Judge, Severity, Timing, Verdict, VerdictStatus};
use crate::model::Expectation;
use crate::runner::ExchangeRecord;

impl Monitor {
    pub(super) fn close_with_reply(&mut self, f: TapFrame, _since: Option<Duration>) {
        let Some(p) = self.pending.take() else {
            return;
        };
        self.tally.answered += 1;
        self.watch_slices(f.start.is_none());
        let received: Cow<'_, [u8]> = if p.leading.is_empty() {
            Cow::Borrowed(&f.bytes)
        } else {
            let mut r = p.leading.clone();
            r.extend_from_slice(&f.bytes);
            Cow::Owned(r)
        };
        let first_byte = if p.leading.is_empty() {
            f.start
        } else {
            p.leading_start
        };
        // The earliest the reply can have begun, where it came in a read of its own: a
        // busy host reads late, and the reads prove only that none of its bytes was there
        // at the read before ([`TapFrame::earliest_start`]).
        let first_byte_earliest = if p.leading.is_empty() {
            f.start
                .map(|_| f.earliest_start(self.cfg.line.char_time_us()))
        } else {
            None
        };
        let timing = Timing {
            request_end: Some(p.end),
            request_end_earliest: Some(p.end_low),
            first_byte,
            first_byte_earliest,
            last_byte: Some(f.end),
            max_gap: f.max_gap,
            silence_before: p.silence_before,
            listened: f.end.saturating_sub(p.end),
        };
        let mut extra = Vec::new();
        // The notes are for the live line only.
        if self.live && is_copy(&p.bytes, &f.bytes) {
            extra.push(format!(
                "a copy of the request, taken as its reply by order and time ({}, within the {} ms window)",
                first_byte.map_or("in the same piece from the tap after it".to_string(), |t| {
                    let as_read = t.saturating_sub(p.end);
                    let shortest = first_byte_earliest.map_or(as_read, |e| e.saturating_sub(p.end));
                    if as_read.saturating_sub(shortest) >= Duration::from_millis(1) {
                        format!("{:.1} ms after it as read, no sooner than {:.1} ms: the listener read it late", ms(as_read), ms(shortest))
                    } else {
                        format!("{:.1} ms after it", ms(as_read))
                    }
                }),
                self.cfg.window.as_millis()
            ));
        }
        let reply = &received[received.len() - f.bytes.len()..];
        self.judge_exchange(p, &received, Some(reply), timing, f.status, extra, true);
    }

    /// Closes the request under way with nothing (valid) after it: `early` is set where
    /// the master's next request cut the window short.
    pub(super) fn close_unanswered(&mut self, early: Option<Duration>) {
        let Some(mut p) = self.pending.take() else {
            return;
        };
        self.tally.unanswered += 1;
        let limit = self.timing_rule().response_limit(&self.model);
        let mut cut_short = false;
        if let Some(after) = early {
            if p.judgement.expect.replies() && after < limit && p.leading.is_empty() {
                cut_short = true;
                p.issues.push(Issue {
                    side: Side::Master,
                    kind: "request-before-reply",
                    severity: Severity::Deviation,
                    text: format!(
                        "the next request began {:.1} ms after this one, before the drive's reply was due (manual: {}; limit {:.1} ms): the master did not wait for the reply",
                        ms(after),
                        self.model.limits.response_time_ms.map_or("not stated".to_string(), |t| format!("{t} ms")),
                        ms(limit)
                    ),
                });
            }
        }
        let listened = early.unwrap_or(self.cfg.window);
        let timing = Timing {
            request_end: Some(p.end),
            request_end_earliest: Some(p.end_low),
            first_byte: if p.leading.is_empty() {
                None
            } else {
                p.leading_start
            },
            first_byte_earliest: None,
            last_byte: None,
            max_gap: None,
            silence_before: p.silence_before,
            listened,
        };
        let leading = std::mem::take(&mut p.leading);
        let status = if leading.is_empty() {
            FrameStatus::Valid
        } else {
            FrameStatus::Corrupt
        };
        let notes = if cut_short {
            vec!["the drive's reply not judged: the master did not leave it time".to_string()]
        } else {
            Vec::new()
        };
        self.judge_exchange(p, &leading, None, timing, status, notes, !cut_short);
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn judge_exchange(
        &mut self,
        mut p: Pending,
        received: &[u8],
        reply: Option<&[u8]>,
        timing: Timing,
        reply_status: FrameStatus,
        notes: Vec<String>,
        judge_drive: bool,
    ) {
        let mode = self.cfg.mode;
        let leading_len = reply.map_or(received.len(), |r| received.len() - r.len());
        let conv = Conversation {
            mode,
            node: p.judged_as,
            request: &p.bytes,
            received,
            leading: &received[..leading_len.min(received.len())],
            reply,
            trailing: &[],
            timing,
            retries: 0,
            link_notes: &[],
        };
        // As `check` judges: where the drive did what a decision of the model says (the
        // manual is silent), that is an observation. The part that does not depend on
        // timing comes from the memo where the same exchange was judged before; the
        // timing is judged here, its findings after the others (as `verdict_on` lists
        // them).
        let verdict = self.untimed_verdict(&p, &conv);
        let mut timed = Vec::new();
        Judge::new(&self.model)
            .with_timing(self.timing_rule())
            .timing_findings(&p.judgement, &conv, |kind, f| timed.push((kind, f)));
        let mut issues = std::mem::take(&mut p.issues);
        if judge_drive {
            for (kind, f) in verdict.found() {
                issues.push(Issue {
                    side: Side::Drive,
                    kind: kind.key(),
                    severity: f.severity,
                    text: f.text.clone(),
                });
            }
            for (kind, f) in timed {
                issues.push(Issue {
                    side: Side::Drive,
                    kind: kind.key(),
                    severity: f.severity,
                    text: f.text,
                });
            }
        }
        let (node, status) = {
            let status = worst(&issues);
            (p.address, status)
        };
        let bad_checksum = verdict.kinds.contains(&judge::Kind::BadChecksum);
        {
            let stats = self.nodes.entry(node).or_default();
            stats.exchanges += 1;
            if !received.is_empty() {
                stats.replies += u64::from(reply.is_some());
            }
            if received.is_empty() && p.judgement.expect.replies() && judge_drive {
                stats.timeouts += 1;
            }
            stats.crc_errors += u64::from(bad_checksum);
            if let (Some(rt), true) = (timing.response_time(), reply.is_some()) {
                stats.response.record(rt);
            }
        }
        if reply.is_some() || received.is_empty() {
            if let Some(e) = self.last_request.get_mut(&p.address) {
                e.2 = reply.is_some() || !p.judgement.expect.replies();
            }
        }
        self.learn(&p, reply);
        // The exchange as an example keeps it: made only where a finding is the first of
        // its kind on its node.
        let record = || ExchangeRecord {
            request: p.bytes.clone(),
            expected: verdict.expected.clone(),
            received: received.to_vec(),
            reply: reply.map(<[u8]>::to_vec),
            predicted: verdict.predicted.clone(),
            actual: verdict.actual.clone(),
            latency: timing.response_time().filter(|_| !received.is_empty()),
        };
        if !self.live {
            self.account(node, &issues, record, &verdict.citations, status);
            return;
        }
        let rt = timing.response_time().filter(|_| !received.is_empty());
        let checksum = match (p.valid, reply_status, received.is_empty()) {
            (false, _, _) => "CRC bad (request)",
            (true, FrameStatus::Valid, _) => "CRC ok",
            (true, _, _) => "CRC bad (reply)",
        };
        let checksum = if mode == Mode::Ascii {
            checksum.replace("CRC", "LRC")
        } else {
            checksum.to_string()
        };
        let req_frame = TapFrame {
            bytes: p.bytes.clone(),
            status: if p.valid {
                FrameStatus::Valid
            } else {
                FrameStatus::Corrupt
            },
            ended_by: EndedBy::Silence,
            start: p.start,
            end: p.end,
            end_low: p.end_low,
            silence_before: p.silence_before,
            max_gap: None,
            side: p.side,
        };
        let mut line = self.line_for(
            &req_frame,
            p.silence_before,
            p.address,
            rt,
            &checksum,
            status,
            &issues,
        );
        line.received = received.to_vec();
        if let Some(r) = reply {
            line.reply = Some(live::meaning(&self.model, mode, r, Direction::Response));
        } else if !received.is_empty() {
            line.reply = Some(judge::explain_invalid(mode, received));
        }
        line.notes.extend(notes);
        if let Some(after) = p.retry_after {
            line.notes
                .push(format!("resend, {:.1} ms after the first try", ms(after)));
        }
        self.account(node, &issues, record, &verdict.citations, status);
        self.lines.push(line);
    }

    #[allow(clippy::too_many_arguments)]
    pub(super) fn line_for(
        &self,
        f: &TapFrame,
        since_previous: Option<Duration>,
        node: u8,
        response: Option<Duration>,
        checksum: &str,
        status: VerdictStatus,
        issues: &[Issue],
    ) -> Line {
        let mode = self.cfg.mode;
        let function = judge::body_of(mode, &f.bytes).map_or(0, |b| b[1]);
        Line {
            at: f.start.unwrap_or(f.end),
            since_previous,
            node,
            function,
            meaning: live::meaning(&self.model, mode, &f.bytes, Direction::Request),
            reply: None,
            checksum: checksum.to_string(),
            response,
            status,
            issues: issues
                .iter()
                .map(|i| format!("{}.{}", i.side.key(), i.kind))
                .collect(),
            notes: Vec::new(),
            request: f.bytes.clone(),
            received: Vec::new(),
        }
    }

    /// Counts an exchange's findings on `node`, keeping the first example of each kind.
    pub(super) fn account(
        &mut self,
        node: u8,
        issues: &[Issue],
        record: impl Fn() -> ExchangeRecord,
        citations: &[String],
        status: VerdictStatus,
    ) {
        #[cfg(test)]
        self.trail
            .push((node, status, issues.to_vec(), citations.to_vec(), record()));
        let stats = self.nodes.entry(node).or_default();
        match status {
            VerdictStatus::Deviation => stats.deviations += 1,
            VerdictStatus::Observation => stats.observations += 1,
            VerdictStatus::Pass => {}
        }
        for i in issues {
            *stats
                .errors
                .entry(format!("{}.{}", i.side.key(), i.kind))
                .or_default() += 1;
            let e = self
                .examples
                .entry((node, i.side, i.kind))
                .or_insert_with(|| Example {
                    severity: i.severity,
                    count: 0,
                    text: i.text.clone(),
                    citations: citations.to_vec(),
                    exchange: record(),
                });
            e.count += 1;
            e.severity = e.severity.max(i.severity);
        }
    }

    /// Values a read must return because a write seen on the bus set them (and nothing
    /// else is known): never assumed, learnt from the traffic. Into `into`; whether any is
    /// known.
    fn known_values(&self, p: &Pending, into: &mut Vec<Option<u16>>) -> bool {
        into.clear();
        let Expectation::Read(plan) = &p.judgement.expect else {
            return false;
        };
        if self.written.is_empty() {
            return false;
        }
        into.extend(
            plan.registers
                .iter()
                .map(|r| self.written.get(&(p.address, *r)).copied()),
        );
        into.iter().any(Option::is_some)
    }

    /// The drive's side of the exchange `conv` of the request `p`, without its timing:
    /// from the memo where the same exchange was judged before (see the `memo` module:
    /// the key holds everything this depends on).
    fn untimed_verdict(&mut self, p: &Pending, conv: &Conversation<'_>) -> Arc<Verdict> {
        let mut known = std::mem::take(&mut self.known);
        let any_known = self.known_values(p, &mut known);
        let fact = &self.written_fact;
        let judge = || {
            Arc::new(Judge::new(&self.model).untimed_verdict_on(
                &p.judgement,
                conv,
                any_known.then_some((known.as_slice(), fact)),
            ))
        };
        let verdict = if self.memo {
            let mut key = std::mem::take(&mut self.key);
            exchange_key(&mut key, p.judged_as, conv, any_known.then_some(&known[..]));
            let verdict = match self.verdicts_memo.get(&key) {
                Some(v) => v.clone(),
                None => {
                    let v = judge();
                    self.verdicts_memo.insert(&key, v.clone());
                    v
                }
            };
            self.key = key;
            verdict
        } else {
            judge()
        };
        self.known = known;
        verdict
    }

    /// Learns register values from writes the drive confirmed (or broadcast writes).
    ///
    /// A write is confirmed by its normal reply (06H: the copy of the request; 10H: its
    /// start and count), whatever else was found on the exchange: a reply that came early,
    /// a master that did not keep t3.5, or a drive that took a value the manual says it
    /// refuses (that finding is the write's; the value read back later is the one the
    /// drive took). An exception, a reply that is no confirmation, or none, teaches
    /// nothing.
    fn learn(&mut self, p: &Pending, reply: Option<&[u8]>) {
        let Some(plan) = &p.judgement.write else {
            return;
        };
        let mode = self.cfg.mode;
        let confirmed = reply.is_some_and(|r| confirms_write(mode, &p.bytes, r));
        let broadcast = p.address == 0;
        if !(confirmed || broadcast) {
            return;
        }
        // Values the drive changes itself (status, monitor registers) are not learnt:
        // only writable parameters and commands keep what was written.
        for (r, v) in &plan.writes {
            if self
                .model
                .lookup(*r)
                .is_some_and(|i| i.access == crate::model::Access::ReadWrite)
            {
                if broadcast {
                    for n in self.nodes.keys().copied().filter(|n| *n != 0) {
                        self.written.insert((n, *r), *v);
                    }
                } else {
                    self.written.insert((p.address, *r), *v);
                }
            }
        }
    }
}

/// Whether `reply` is the normal reply that confirms the write `request`: both frames
/// whole with their CRC or LRC holding, and for 06H the same message, for 10H its address,
/// function, start and count (in ASCII the messages are compared, not the characters:
/// an echo in upper case confirms a request in lower case).
pub(super) fn confirms_write(mode: Mode, request: &[u8], reply: &[u8]) -> bool {
    let body = |frame| {
        codec::frame_parts(mode, frame)
            .ok()
            .filter(|p| p.checksum.verify().is_ok())
            .map(|p| p.body)
    };
    let (Some(q), Some(r)) = (body(request), body(reply)) else {
        return false;
    };
    match q.get(1) {
        Some(0x06) => q == r,
        Some(0x10) => q.len() >= 6 && r.len() == 6 && q[..6] == r[..],
        _ => false,
    }
}

/// The memo key of an exchange's drive side without timing: everything
/// [`Judge::untimed_verdict_on`] depends on in the monitor (the model, the mode and the
/// monitor's settings are the memo's own). Each part with its length, so that no two
/// exchanges share a key.
fn exchange_key(
    key: &mut Vec<u8>,
    judged_as: u8,
    conv: &Conversation<'_>,
    known: Option<&[Option<u16>]>,
) {
    let len = |n: usize| u32::try_from(n).unwrap_or(u32::MAX).to_le_bytes();
    key.clear();
    key.push(judged_as);
    key.extend_from_slice(&len(conv.request.len()));
    key.extend_from_slice(conv.request);
    key.extend_from_slice(&len(conv.received.len()));
    key.extend_from_slice(conv.received);
    match conv.reply {
        Some(r) => {
            key.push(1);
            key.extend_from_slice(&len(r.len()));
        }
        None => key.push(0),
    }
    // Where nothing came back, the finding says how long the monitor listened.
    if conv.received.is_empty() {
        let listened = u64::try_from(conv.timing.listened.as_nanos()).unwrap_or(u64::MAX);
        key.extend_from_slice(&listened.to_le_bytes());
    }
    match known {
        None => key.push(0),
        Some(values) => {
            key.push(1);
            key.extend_from_slice(&len(values.len()));
            for v in values {
                match v {
                    None => key.push(0),
                    Some(v) => {
                        key.push(1);
                        key.extend_from_slice(&v.to_le_bytes());
                    }
                }
            }
        }
    }
}
