//! Passive conformance: listens to a bus that a master (a PLC, an HMI) and drives already
//! run, and judges both sides of every conversation against the drive's model, without
//! ever sending a byte.
//!
//! - [`frames`]: frames from a tap, RTU by silence and by length, ASCII ':' to CR LF.
//! - [`Monitor`]: pairs each request with at most one reply from the addressed node within
//!   the response window, judges the drive's side through the shared
//!   [`judge`](crate::judge) (as `check` does), and the master's side against the manual
//!   (function served, registers in the map, counts, broadcasts, checksums, t3.5 before
//!   each request, no request while a reply is due).
//! - [`tap`]: the read-only port: a [`Tap`] has no way to write.
//! - [`stats`]: per-node counters and response-time histograms, in fixed memory.
//!
//! State is bounded: the request under way, per node its statistics, one example of each
//! kind of finding, and the register values the traffic has set (at most the model's
//! map per node).

pub mod frames;
pub mod guess;
mod judge_master;
pub mod line_search;
mod live;
pub mod replay;
mod report;
pub mod stats;
pub mod tap;

use std::collections::{BTreeMap, HashMap};
use std::time::Duration;

pub use frames::{EndedBy, FrameStatus, TapFrame};
pub use live::Line;
pub use report::MonitorSummary;
pub use stats::NodeStats;
pub use tap::{listen_for_mode, run, run_from, Ended, ReadOnlyPort, ReadOnlySerial, Said, Tap};

use crate::codec::pdu::{function, Direction, Message};
use crate::codec::timing::LineSettings;
use crate::codec::Mode;
use crate::judge::{self, Conversation, Judge, Severity, Timing, TimingRule, VerdictStatus};
use crate::model::{DriveModel, Expectation, Fact, Judgement};
use crate::runner::ExchangeRecord;
use crate::transport::TransportError;

/// Why a listening session could not run.
#[derive(Debug, thiserror::Error)]
pub enum MonitorError {
    /// The port could not be opened or read.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The settings make no sense.
    #[error("{0}")]
    Config(String),
    /// `--mode auto` heard no frame of either mode (what it heard, and what to try).
    #[error("{0}")]
    NoMode(String),
}

/// What the monitor listens to and how it judges.
#[derive(Debug, Clone)]
pub struct MonitorConfig {
    /// RTU or ASCII.
    pub mode: Mode,
    /// The line's settings (its timing: t1.5, t3.5, the character time).
    pub line: LineSettings,
    /// The nodes on the bus; empty: every node the master addresses.
    pub nodes: Vec<u8>,
    /// How long after a request its reply may come.
    pub window: Duration,
    /// Allowance over the manual's response time before a reply counts as late.
    pub response_allowance: Duration,
    /// Allowance over t1.5 before a gap inside a reply counts.
    pub gap_allowance: Duration,
}

/// Which side of the conversation a finding is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Side {
    /// The drive (its replies and silences).
    Drive,
    /// The master (its requests and its timing).
    Master,
}

impl Side {
    /// "drive" or "master".
    pub fn key(self) -> &'static str {
        match self {
            Side::Drive => "drive",
            Side::Master => "master",
        }
    }
}

/// One finding of the monitor.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Issue {
    /// Drive or master.
    pub side: Side,
    /// The kind ("wrong-exception", "no-t3.5", ...).
    pub kind: &'static str,
    /// Deviation or observation.
    pub severity: Severity,
    /// What, in words, with bytes in hex.
    pub text: String,
}

/// The first example of one kind of finding on one node, and how often it came.
#[derive(Debug, Clone)]
pub struct Example {
    /// The most serious severity seen.
    pub severity: Severity,
    /// How many exchanges had it.
    pub count: u64,
    /// The first one's text.
    pub text: String,
    /// The manual's citations for the first one.
    pub citations: Vec<String>,
    /// The first one's exchange.
    pub exchange: ExchangeRecord,
}

/// The request under way.
#[derive(Debug, Clone)]
struct Pending {
    /// The address the request carries.
    address: u8,
    /// The node whose model judges it (a node of the bus for broadcasts and requests to
    /// other nodes).
    judged_as: u8,
    bytes: Vec<u8>,
    valid: bool,
    start: Option<Duration>,
    end: Duration,
    /// The earliest its last byte can have come.
    end_low: Duration,
    /// The side it came from, where the source knows.
    side: Option<bool>,
    silence_before: Option<Duration>,
    judgement: Judgement,
    /// Bytes that came after it and are no frame (garbage before a reply).
    leading: Vec<u8>,
    leading_start: Option<Duration>,
    issues: Vec<Issue>,
    retry_after: Option<Duration>,
}

/// The kinds the monitor judges the master's side by (the drive's side is judged by the
/// [`judge`](crate::judge::Kind) kinds). The requirements catalogue links to them.
pub const MASTER_KINDS: [&str; 18] = [
    "no-t3.5",
    "incomplete-request",
    "bad-checksum",
    "malformed",
    "broadcast-read",
    "frame-too-long",
    "function-not-served",
    "register-not-in-map",
    "count-over-limit",
    "value-out-of-range",
    "write-to-read-only",
    "write-to-reserved",
    "crosses-group",
    "no-access-register",
    "malformed-request",
    "request-before-reply",
    "retry",
    "broadcast-turnaround",
];

/// The kinds of every monitor finding: the drive's (the judge's kinds) and the master's.
pub fn kinds() -> Vec<&'static str> {
    let mut out: Vec<&'static str> = crate::judge::Kind::ALL.iter().map(|k| k.key()).collect();
    for k in MASTER_KINDS {
        if !out.contains(&k) {
            out.push(k);
        }
    }
    out
}

/// The least silence after a broadcast before the master's next request: the low end of
/// Modbus over Serial Line's "typically 100 ms to 200 ms" turnaround delay.
pub const BROADCAST_TURNAROUND: Duration = Duration::from_millis(100);

/// The listener: frames in, judged exchanges and live lines out.
pub struct Monitor {
    cfg: MonitorConfig,
    model: DriveModel,
    framer: frames::TapFramer,
    pending: Option<Pending>,
    last_frame_end: Option<Duration>,
    /// The earliest the last broadcast heard can have ended, until the next request.
    last_broadcast_end: Option<Duration>,
    /// Per node: the last request's bytes and whether it was answered (retries).
    last_request: HashMap<u8, (Vec<u8>, Duration, bool)>,
    /// Register values that writes seen on the bus set, per node.
    written: HashMap<(u8, u16), u16>,
    nodes: BTreeMap<u8, NodeStats>,
    examples: BTreeMap<(u8, Side, &'static str), Example>,
    frames: u64,
    bytes: u64,
    /// The first and the latest time the listener reported (bytes or silence): how long
    /// the bus was listened to, traffic or not.
    first_at: Option<Duration>,
    last_at: Option<Duration>,
    lines: Vec<Line>,
    /// Replies that came in one read with the end of their request (the silence between
    /// them unseen), and replies that began a read of their own.
    blurred: u64,
    timed: u64,
    /// Said once each, live and in the report (the tap's latency timer).
    notices: Vec<String>,
    notices_taken: usize,
    /// Whether live lines are made (nobody reads them with `--quiet` and no `--log`).
    live: bool,
}

/// Replies read together with their request, at least, before the monitor says the tap
/// delivers bytes in slices (a USB adapter's latency timer), when half or more are.
pub const BLURRED_BEFORE_NOTICE: u64 = 4;

impl Monitor {
    /// A monitor of a bus of drives of `model`.
    pub fn new(model: DriveModel, cfg: MonitorConfig) -> Result<Self, MonitorError> {
        if cfg.nodes.iter().any(|n| *n == 0 || *n > 247) {
            return Err(MonitorError::Config(format!(
                "node addresses are 1..247 (0 is the broadcast address): {:?}",
                cfg.nodes
            )));
        }
        Ok(Monitor {
            framer: frames::TapFramer::new(cfg.mode, cfg.line),
            cfg,
            model,
            pending: None,
            last_frame_end: None,
            last_broadcast_end: None,
            last_request: HashMap::new(),
            written: HashMap::new(),
            nodes: BTreeMap::new(),
            examples: BTreeMap::new(),
            frames: 0,
            bytes: 0,
            first_at: None,
            last_at: None,
            lines: Vec::new(),
            blurred: 0,
            timed: 0,
            notices: Vec::new(),
            notices_taken: 0,
            live: true,
        })
    }

    /// The configuration.
    pub fn config(&self) -> &MonitorConfig {
        &self.cfg
    }

    /// The model.
    pub fn model(&self) -> &DriveModel {
        &self.model
    }

    /// Whether to make a live line per exchange (default: yes). Without them the
    /// verdicts, statistics and report are the same; judging a capture goes faster.
    pub fn set_live(&mut self, live: bool) {
        self.live = live;
    }

    /// The side the next bytes come from, where the source knows it (a capture's
    /// direction flags; `None`, a tap, the default): frames from the side of a request
    /// are never its reply, frames from the other side are.
    pub fn set_side(&mut self, side: Option<bool>) {
        self.framer.set_side(side);
    }

    /// Bytes that arrived at `at` (since the listener's origin).
    pub fn feed(&mut self, at: Duration, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        self.tick(at);
        self.bytes += bytes.len() as u64;
        let mut out = Vec::new();
        self.framer.push(at, bytes, &mut out);
        for f in out {
            self.on_frame(f);
        }
    }

    /// Nothing came up to `now`: frames followed by t3.5 end, and a request whose window
    /// has passed is judged.
    pub fn idle(&mut self, now: Duration) {
        self.tick(now);
        let mut out = Vec::new();
        self.framer.idle(now, &mut out);
        for f in out {
            self.on_frame(f);
        }
        if let Some(p) = &self.pending {
            if now.saturating_sub(p.end) > self.cfg.window {
                self.close_unanswered(None);
            }
        }
    }

    /// The listener's clock reached `at`.
    fn tick(&mut self, at: Duration) {
        self.first_at.get_or_insert(at);
        self.last_at = Some(self.last_at.map_or(at, |l| l.max(at)));
    }

    /// The end of the input: everything held is framed and judged.
    pub fn finish(&mut self) {
        let mut out = Vec::new();
        self.framer.finish(&mut out);
        for f in out {
            self.on_frame(f);
        }
        if let Some(p) = &self.pending {
            // Listening ended before the reply to the last request was due: nothing to
            // judge it by.
            let heard_for = self
                .last_at
                .map_or(Duration::ZERO, |l| l.saturating_sub(p.end));
            if p.judgement.expect.replies() && heard_for < self.cfg.window && p.leading.is_empty() {
                self.notices.push(format!(
                    "listening ended {:.1} ms after the last request ({}), before its window of {} ms was over: it was not judged",
                    ms(heard_for),
                    judge::show(self.cfg.mode, &p.bytes),
                    self.cfg.window.as_millis()
                ));
                self.pending = None;
                return;
            }
            self.close_unanswered(None);
        }
    }

    /// Counts a reply read together with its request (`blurred`) or on its own, and says
    /// once when the tap delivers bytes in slices longer than a drive takes to answer:
    /// what a USB adapter's latency timer does (an FTDI waits 16 ms by default before it
    /// hands over a short read). Response times, t3.5 and gaps cannot be measured then.
    fn watch_slices(&mut self, blurred: bool) {
        if blurred {
            self.blurred += 1;
        } else {
            self.timed += 1;
        }
        let said = self.notices.iter().any(|n| n.starts_with("latency timer"));
        if !said && self.blurred >= BLURRED_BEFORE_NOTICE && self.blurred >= self.timed {
            self.notices.push(format!(
                "latency timer: {} of {} replies came in one read with their request, so the adapter hands over bytes in slices longer than a drive takes to answer (a USB adapter's latency timer; an FTDI waits 16 ms by default). Response times, t3.5 and gaps inside frames are not measured where that happens. On Linux: echo 1 > /sys/bus/usb-serial/devices/ttyUSBn/latency_timer (n: the tap's port), or setserial /dev/ttyUSBn low_latency",
                self.blurred,
                self.blurred + self.timed
            ));
        }
    }

    /// Adds a notice about the listening (in the report, and said as it goes): how the
    /// line's settings were found, for one.
    pub fn notice(&mut self, text: String) {
        self.notices.push(text);
    }

    /// Notices made since the last call (each is made once).
    pub fn take_notices(&mut self) -> Vec<String> {
        let new = self.notices[self.notices_taken..].to_vec();
        self.notices_taken = self.notices.len();
        new
    }

    /// Every notice made so far.
    pub fn notices(&self) -> &[String] {
        &self.notices
    }

    /// The live lines made since the last call.
    pub fn take_lines(&mut self) -> Vec<Line> {
        std::mem::take(&mut self.lines)
    }

    /// Per-node statistics.
    pub fn nodes(&self) -> &BTreeMap<u8, NodeStats> {
        &self.nodes
    }

    /// The first example of each kind of finding, per node and side.
    pub fn examples(&self) -> &BTreeMap<(u8, Side, &'static str), Example> {
        &self.examples
    }

    /// Deviations found, over every node.
    pub fn deviations(&self) -> u64 {
        self.nodes.values().map(|n| n.deviations).sum()
    }

    /// The master's side of one request frame only: the request against the manual and
    /// the model (function, register map, counts, broadcasts, checksum) and t3.5 of
    /// silence before it (`f.silence_before`). The master gate judges every request of
    /// the master under test with it, so that a request gets one verdict whoever heard it.
    pub fn judge_master_request(&self, f: &TapFrame) -> Vec<Issue> {
        let address = judge::body_of(self.cfg.mode, &f.bytes).map_or(0, |b| b[0]);
        let judgement = self
            .model
            .judge(self.judged_as(address), self.cfg.mode, &f.bytes);
        judge_master::judge_request(self, f, &judgement)
    }

    fn timing_rule(&self) -> TimingRule {
        TimingRule {
            line: Some(self.cfg.line),
            response_allowance: self.cfg.response_allowance,
            gap_allowance: self.cfg.gap_allowance,
        }
    }

    /// The node whose model judges a request to `address`: itself, or for a broadcast or
    /// a node not on the bus, a node that is (whose model says: silence).
    fn judged_as(&self, address: u8) -> u8 {
        let on_bus = self.cfg.nodes.is_empty() || self.cfg.nodes.contains(&address);
        if address != 0 && on_bus {
            address
        } else {
            match self.cfg.nodes.first() {
                Some(&n) => n,
                // Any node but `address` (and not the broadcast address).
                None => {
                    if address == 1 {
                        2
                    } else {
                        1
                    }
                }
            }
        }
    }

    fn on_frame(&mut self, f: TapFrame) {
        self.frames += 1;
        let since_previous = self
            .last_frame_end
            .map(|e| f.start.unwrap_or(f.end).saturating_sub(e));
        self.last_frame_end = Some(f.end);
        if let Some(p) = &self.pending {
            let at = f.start.unwrap_or(f.end);
            if at.saturating_sub(p.end) > self.cfg.window {
                self.close_unanswered(None);
            }
        }
        // A copy of a 06H/08H request is its normal reply, or the master sending it
        // again: by time, a copy later than any reply is due is the master's resend.
        let copy_limit = || {
            self.model.response_time_on(Some(&self.cfg.line))
                + self.cfg.response_allowance
                + Duration::from_micros(self.cfg.line.char_time_us())
        };
        // Where the source knows the side each frame came from (a capture's direction
        // flags), that settles it: a frame from the request's side is never its reply.
        let same_side = self
            .pending
            .as_ref()
            .and_then(|p| p.side.zip(f.side).map(|(a, b)| a == b));
        let resend = same_side.unwrap_or_else(|| {
            self.pending.as_ref().is_some_and(|p| {
                is_copy(&p.bytes, &f.bytes)
                    && f.start.unwrap_or(f.end).saturating_sub(p.end) > copy_limit()
            })
        });
        if let Some(p) = self.pending.as_mut() {
            match f.status {
                FrameStatus::Valid
                    if !resend
                        && (same_side == Some(false)
                            || is_reply_to(self.cfg.mode, &p.bytes, &f.bytes)) =>
                {
                    self.close_with_reply(f, since_previous);
                    return;
                }
                FrameStatus::Corrupt | FrameStatus::Incomplete
                    if p.leading.len() + f.bytes.len() <= 2 * crate::codec::MAX_ASCII_FRAME =>
                {
                    // Bytes that are no frame after a request: the reply, damaged, or
                    // garbage before it; the next frame or the window tells.
                    if p.leading.is_empty() {
                        p.leading_start = f.start;
                    }
                    p.leading.extend_from_slice(&f.bytes);
                    return;
                }
                _ => {
                    // A new request while the previous one is still due a reply.
                    let early = f.start.unwrap_or(f.end).saturating_sub(p.end);
                    self.close_unanswered(Some(early));
                }
            }
        }
        self.on_request(f, since_previous);
    }

    fn on_request(&mut self, f: TapFrame, since_previous: Option<Duration>) {
        let mode = self.cfg.mode;
        let body = judge::body_of(mode, &f.bytes);
        let address = body.as_ref().map_or(0, |b| b[0]);
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
                        return;
                    }
                    self.unsolicited(f, since_previous, address);
                    return;
                }
            }
        }
        let judged_as = self.judged_as(address);
        let judgement = self.model.judge(judged_as, mode, &f.bytes);
        let mut issues = judge_master::judge_request(self, &f, &judgement);
        let stats = self.nodes.entry(address).or_default();
        stats.requests += 1;
        let crc_error = f.status != FrameStatus::Valid && body.is_some();
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
            self.last_request
                .insert(address, (f.bytes.clone(), f.end, false));
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
        self.account(address, &[issue], &record, &[], VerdictStatus::Deviation);
        self.lines.push(line);
    }

    fn close_with_reply(&mut self, f: TapFrame, _since: Option<Duration>) {
        let Some(p) = self.pending.take() else {
            return;
        };
        self.watch_slices(f.start.is_none());
        let mut received = p.leading.clone();
        received.extend_from_slice(&f.bytes);
        let first_byte = if p.leading.is_empty() {
            f.start
        } else {
            p.leading_start
        };
        let timing = Timing {
            request_end: Some(p.end),
            request_end_earliest: Some(p.end_low),
            first_byte,
            last_byte: Some(f.end),
            max_gap: f.max_gap,
            silence_before: p.silence_before,
            listened: f.end.saturating_sub(p.end),
        };
        let mut extra = Vec::new();
        if is_copy(&p.bytes, &f.bytes) {
            extra.push(format!(
                "a copy of the request, taken as its reply by order and time ({} after it, within the {} ms window)",
                first_byte.map_or("in the same piece from the tap".to_string(), |t| format!("{:.1} ms", ms(t.saturating_sub(p.end)))),
                self.cfg.window.as_millis()
            ));
        }
        let reply = &received[received.len() - f.bytes.len()..];
        self.judge_exchange(p, &received, Some(reply), timing, f.status, extra, true);
    }

    /// Closes the request under way with nothing (valid) after it: `early` is set where
    /// the master's next request cut the window short.
    fn close_unanswered(&mut self, early: Option<Duration>) {
        let Some(mut p) = self.pending.take() else {
            return;
        };
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
                        "the next request began {:.1} ms after this one, before the drive's reply was due (manual: {} ms; limit {:.1} ms): the master did not wait for the reply",
                        ms(after),
                        self.model.limits.response_time_ms,
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
    fn judge_exchange(
        &mut self,
        p: Pending,
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
        let known = self.known_values(&p);
        let judge = Judge::new(&self.model).with_timing(self.timing_rule());
        // As `check` judges: where the drive did what a decision of the model says (the
        // manual is silent), that is an observation.
        let verdict = judge.verdict_on(
            &p.judgement,
            &conv,
            known.as_ref().map(|(v, f)| (v.as_slice(), f)),
        );
        let mut issues = p.issues.clone();
        for (kind, f) in verdict.found().filter(|_| judge_drive) {
            issues.push(Issue {
                side: Side::Drive,
                kind: kind.key(),
                severity: f.severity,
                text: f.text.clone(),
            });
        }
        let (node, status) = {
            let status = worst(&issues);
            (p.address, status)
        };
        {
            let stats = self.nodes.entry(node).or_default();
            stats.exchanges += 1;
            if !received.is_empty() {
                stats.replies += u64::from(reply.is_some());
            }
            if received.is_empty() && p.judgement.expect.replies() && judge_drive {
                stats.timeouts += 1;
            }
            if reply_status != FrameStatus::Valid
                || verdict.kinds.contains(&judge::Kind::BadChecksum)
            {
                stats.crc_errors += u64::from(verdict.kinds.contains(&judge::Kind::BadChecksum));
            }
            if let (Some(rt), true) = (timing.response_time(), reply.is_some()) {
                stats.response.record(rt);
            }
        }
        if reply.is_some() || received.is_empty() {
            if let Some(e) = self.last_request.get_mut(&p.address) {
                e.2 = reply.is_some() || !p.judgement.expect.replies();
            }
        }
        self.learn(&p, reply, status);
        let record = ExchangeRecord {
            request: p.bytes.clone(),
            expected: verdict.expected.clone(),
            received: received.to_vec(),
            reply: reply.map(<[u8]>::to_vec),
            predicted: verdict.predicted.clone(),
            actual: verdict.actual.clone(),
            latency: timing.response_time().filter(|_| !received.is_empty()),
        };
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
        if !self.live {
            self.account(node, &issues, &record, &verdict.citations, status);
            return;
        }
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
        self.account(node, &issues, &record, &verdict.citations, status);
        self.lines.push(line);
    }

    #[allow(clippy::too_many_arguments)]
    fn line_for(
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
    fn account(
        &mut self,
        node: u8,
        issues: &[Issue],
        record: &ExchangeRecord,
        citations: &[String],
        status: VerdictStatus,
    ) {
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
                    exchange: record.clone(),
                });
            e.count += 1;
            e.severity = e.severity.max(i.severity);
        }
    }

    /// Values a read must return because a write seen on the bus set them (and nothing
    /// else is known): never assumed, learnt from the traffic.
    fn known_values(&self, p: &Pending) -> Option<(Vec<Option<u16>>, Fact)> {
        let Expectation::Read(plan) = &p.judgement.expect else {
            return None;
        };
        let values: Vec<Option<u16>> = plan
            .registers
            .iter()
            .map(|r| self.written.get(&(p.address, *r)).copied())
            .collect();
        values.iter().any(Option::is_some).then(|| {
            (
                values,
                Fact::documented(
                    "a write seen on the bus set it, and a parameter holds what was written (the manual's 06H/10H)",
                ),
            )
        })
    }

    /// Learns register values from writes the drive confirmed (or broadcast writes).
    fn learn(&mut self, p: &Pending, reply: Option<&[u8]>, status: VerdictStatus) {
        let Some(plan) = &p.judgement.write else {
            return;
        };
        let confirmed = reply.is_some() && status != VerdictStatus::Deviation;
        let broadcast = p.address == 0;
        if !(confirmed || broadcast) {
            return;
        }
        // Values the drive changes itself (status, monitor registers) are not learnt:
        // only writable parameters and commands keep what was written.
        let targets: Vec<u8> = if broadcast {
            self.nodes.keys().copied().filter(|n| *n != 0).collect()
        } else {
            vec![p.address]
        };
        for (r, v) in &plan.writes {
            if self
                .model
                .lookup(*r)
                .is_some_and(|i| i.access == crate::model::Access::ReadWrite)
            {
                for n in &targets {
                    self.written.insert((*n, *r), *v);
                }
            }
        }
    }
}

/// Whether `frame` answers `request`: the same address or not, the request's function
/// (or its exception), and a reply's shape.
fn is_reply_to(mode: Mode, request: &[u8], frame: &[u8]) -> bool {
    let (Some(req), Some(rep)) = (judge::body_of(mode, request), judge::body_of(mode, frame))
    else {
        return false;
    };
    // Functions 80H..FFH are exceptions, which no master sends: an exception frame from
    // the node a request went to is its reply, however wrong (pymodbus 3.16 answers a
    // read of 0 registers with 01 80 01, function 80H).
    if rep[1] & function::EXCEPTION_BIT != 0 && rep[0] == req[0] {
        return true;
    }
    if rep[1] & !function::EXCEPTION_BIT != req[1] {
        return false;
    }
    if is_copy(request, frame) {
        // 06H/08H: a copy of the request is its normal reply.
        return matches!(
            req[1],
            function::WRITE_SINGLE_REGISTER | function::LOOP_BACK
        );
    }
    // 06H/08H: a frame of the same function for another register (06H) or another test
    // code (08H) is the master's next request, not a wrong reply: taking it as the reply
    // would pair every request after it with the wrong frame.
    if matches!(
        req[1],
        function::WRITE_SINGLE_REGISTER | function::LOOP_BACK
    ) && (rep.len() < 4 || req.len() < 4 || rep[2..4] != req[2..4])
    {
        return false;
    }
    Message::parse_body(&rep, Direction::Response).is_ok()
}

fn is_copy(request: &[u8], frame: &[u8]) -> bool {
    request == frame
}

fn worst(issues: &[Issue]) -> VerdictStatus {
    match issues.iter().map(|i| i.severity).max() {
        None => VerdictStatus::Pass,
        Some(Severity::Observation) => VerdictStatus::Observation,
        Some(Severity::Deviation) => VerdictStatus::Deviation,
    }
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

/// Whether `fc` writes (06H, 10H): the only functions a broadcast may carry.
pub(crate) fn is_write(fc: u8) -> bool {
    matches!(
        fc,
        function::WRITE_SINGLE_REGISTER | function::WRITE_MULTIPLE_REGISTERS
    )
}

#[cfg(test)]
mod tests;
