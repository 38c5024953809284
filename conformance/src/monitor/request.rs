//! The master's requests as they come: each judged on the master's side (the model's
//! judgement of it, the findings on the request and its timing), held as the request under
//! way until its reply or its silence; replies with no request under way.

use std::sync::Arc;
use std::time::Duration;

use super::{
    judge_master, ms, Issue, Line, Monitor, Pending, Side, TapFrame, BROADCAST_TURNAROUND,
};
use crate::codec::pdu::{function, Direction, Message};
use crate::judge::{self, Severity, VerdictStatus};
use crate::model::Judgement;
use crate::monitor::FrameStatus;
use crate::runner::ExchangeRecord;

impl Monitor {
    pub(super) fn on_request(&mut self, f: TapFrame, since_previous: Option<Duration>) {
        let mode = self.cfg.mode;
        let body = judge::body_cow(mode, &f.bytes);
        let address = body.as_ref().map_or(0, |b| b[0]);
        let has_body = body.is_some();
        if f.status == FrameStatus::Valid {
            if let Some(b) = &body {
                // Functions 80H..FFH are exceptions: no master sends one.
                let exception = b.len() >= 2 && b[1] & function::EXCEPTION_BIT != 0;
                if exception
                    || Message::parse_body(b, Direction::Request).is_err()
                        && Message::parse_body(b, Direction::Response).is_ok()
                {
                    if since_previous.is_none() {
                        // Its request, if any, came before listening began.
                        self.notices.push(format!(
                            "the first frame heard was a reply ({}): its request came before listening began, so it was not judged",
                            judge::show(mode, &f.bytes)
                        ));
                        self.tally.unpaired += 1;
                        return;
                    }
                    self.tally.unpaired += 1;
                    self.unsolicited(f, since_previous, address);
                    return;
                }
            }
        }
        drop(body);
        let judged_as = self.judged_as(address);
        let (judgement, mut issues) = self.judge_request(&f, judged_as);
        self.tally.requests += 1;
        let stats = self.nodes.entry(address).or_default();
        stats.requests += 1;
        let crc_error = f.status != FrameStatus::Valid && has_body;
        if crc_error {
            stats.crc_errors += 1;
        }
        // After a broadcast the master waits the turnaround delay before its next
        // request: the drives are still acting on it, and none answers to say so. The
        // silence is the longest the reads allow (from the earliest the broadcast can
        // have ended).
        if let Some(broadcast_end) = self.last_broadcast_end.take() {
            let gap = f.start.unwrap_or(f.end).saturating_sub(broadcast_end);
            if gap < BROADCAST_TURNAROUND {
                issues.push(Issue {
                    side: Side::Master,
                    kind: "broadcast-turnaround",
                    severity: Severity::Observation,
                    text: format!(
                        "the next request began {:.1} ms after a broadcast, under the turnaround delay of {} ms; Modbus over Serial Line V1.02, 2.4.1 (the master waits a turnaround delay after a broadcast, typically 100 to 200 ms; the TECO manuals give none)",
                        ms(gap),
                        BROADCAST_TURNAROUND.as_millis()
                    ),
                });
            }
        }
        if address == 0 && f.status == FrameStatus::Valid {
            self.last_broadcast_end = Some(f.end_low);
        }
        let stats = self.nodes.entry(address).or_default();
        let mut retry_after = None;
        if let Some((last, at, answered)) = self.last_request.get(&address) {
            if *last == f.bytes && !answered {
                stats.retries += 1;
                retry_after = Some(f.start.unwrap_or(f.end).saturating_sub(*at));
                issues.push(Issue {
                    side: Side::Master,
                    kind: "retry",
                    severity: Severity::Observation,
                    text: format!(
                        "sent again {:.1} ms after the first try, which got no reply",
                        ms(retry_after.unwrap_or_default())
                    ),
                });
            }
        }
        if f.bytes.len() <= crate::codec::MAX_ASCII_FRAME {
            // The entry's buffer is reused: no allocation per request.
            let e = self
                .last_request
                .entry(address)
                .or_insert_with(|| (Vec::new(), f.end, false));
            e.0.clear();
            e.0.extend_from_slice(&f.bytes);
            e.1 = f.end;
            e.2 = false;
        }
        self.pending = Some(Pending {
            address,
            judged_as,
            valid: f.status == FrameStatus::Valid,
            bytes: f.bytes,
            start: f.start,
            end: f.end,
            end_low: f.end_low,
            side: f.side,
            silence_before: f.silence_before,
            judgement,
            leading: Vec::new(),
            leading_start: None,
            issues,
            retry_after,
        });
    }

    /// The model's judgement of the request `f` as node `judged_as` and the master's
    /// findings on it ([`judge_master::judge_request`]), from the memo where the same
    /// request was judged before (the t3.5 before it is judged each time).
    fn judge_request(&mut self, f: &TapFrame, judged_as: u8) -> (Arc<Judgement>, Vec<Issue>) {
        let mut issues = Vec::new();
        if f.status == FrameStatus::Valid {
            issues.extend(judge_master::t35_before(self, f));
        }
        let fresh = |m: &Monitor| {
            let judgement = m.model.judge(judged_as, m.cfg.mode, &f.bytes);
            let issues = judge_master::request_issues(m, &f.bytes, f.status, &judgement);
            (Arc::new(judgement), issues)
        };
        if !self.memo {
            let (judgement, rest) = fresh(self);
            issues.extend(rest);
            return (judgement, issues);
        }
        let mut key = std::mem::take(&mut self.key);
        key.clear();
        key.push(judged_as);
        key.push(f.status as u8);
        key.extend_from_slice(&f.bytes);
        let judgement = match self.requests_memo.get(&key) {
            Some((judgement, rest)) => {
                issues.extend(rest.iter().cloned());
                judgement.clone()
            }
            None => {
                let (judgement, rest) = fresh(self);
                issues.extend(rest.iter().cloned());
                self.requests_memo.insert(&key, (judgement.clone(), rest));
                judgement
            }
        };
        self.key = key;
        (judgement, issues)
    }

    /// A reply with no request under way: after the window, a second reply, or a reply
    /// where none was asked for.
    fn unsolicited(&mut self, f: TapFrame, since_previous: Option<Duration>, address: u8) {
        let text = format!(
            "a reply from node {address:02X} with no request under way ({}): {} = {}",
            match since_previous {
                Some(d) => format!("{:.1} ms after the previous frame", ms(d)),
                None => "the first frame heard".to_string(),
            },
            judge::show(self.cfg.mode, &f.bytes),
            judge::describe_reply(self.cfg.mode, &f.bytes)
        );
        let issue = Issue {
            side: Side::Drive,
            kind: judge::Kind::UnexpectedReply.key(),
            severity: Severity::Deviation,
            text,
        };
        let record = ExchangeRecord {
            request: Vec::new(),
            expected: None,
            received: f.bytes.clone(),
            reply: Some(f.bytes.clone()),
            predicted: "no reply (no request under way)".to_string(),
            actual: judge::describe_reply(self.cfg.mode, &f.bytes),
            latency: None,
        };
        let line = self.line_for(
            &f,
            since_previous,
            address,
            None,
            "-",
            VerdictStatus::Deviation,
            std::slice::from_ref(&issue),
        );
        let line = Line {
            received: line.request.clone(),
            request: Vec::new(),
            ..line
        };
        self.account(
            address,
            &[issue],
            || record.clone(),
            &[],
            VerdictStatus::Deviation,
        );
        self.lines.push(line);
    }
}
