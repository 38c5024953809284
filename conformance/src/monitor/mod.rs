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
//! kind of finding, the register values the traffic has set (at most the model's map per
//! node), and the memos of exchanges judged (the `memo` module: a fixed number of
//! entries, emptied when full), from which the same exchange seen again is judged without
//! redoing the work (its timing is judged each time).

mod exchange;
pub mod frames;
pub mod fuzzing;
pub mod guess;
mod judge_master;
pub mod line_search;
mod live;
mod memo;
pub mod replay;
mod report;
mod request;
pub mod stats;
pub mod tap;

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::time::Duration;

pub use frames::{EndedBy, FrameStatus, TapFrame};
pub use live::Line;
pub use report::MonitorSummary;
pub use stats::NodeStats;
pub use tap::{
    first_read, listen_for_mode, run, run_from, Ended, ReadOnlyPort, ReadOnlySerial, Said, Tap,
};

use crate::codec::pdu::{function, Direction, Message};
use crate::codec::timing::LineSettings;
use crate::codec::Mode;
use crate::judge::{self, Severity, TimingRule, VerdictStatus};
use crate::model::{DriveModel, Fact, Judgement};
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

impl MonitorConfig {
    /// `conformance monitor`'s default window for a reply, ms (`--window`).
    pub const WINDOW_MS: u64 = 1000;
    /// `conformance monitor`'s default allowance, ms (`--allowance`): over the manual's
    /// response time before a reply is late, and over t1.5 before a gap inside a reply
    /// counts.
    pub const ALLOWANCE_MS: u64 = 20;

    /// What `conformance monitor` judges with when no option changes it: a reply within
    /// [`Self::WINDOW_MS`], [`Self::ALLOWANCE_MS`] for replies and gaps.
    pub fn new(mode: Mode, line: LineSettings, nodes: Vec<u8>) -> MonitorConfig {
        MonitorConfig {
            mode,
            line,
            nodes,
            window: Duration::from_millis(Self::WINDOW_MS),
            response_allowance: Duration::from_millis(Self::ALLOWANCE_MS),
            gap_allowance: Duration::from_millis(Self::ALLOWANCE_MS),
        }
    }
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
    side: Option<u64>,
    silence_before: Option<Duration>,
    judgement: Arc<Judgement>,
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
    last_request: HashMap<u8, (Vec<u8>, Duration, bool), memo::FastHash>,
    /// Register values that writes seen on the bus set, per node.
    written: HashMap<(u8, u16), u16, memo::FastHash>,
    /// The fact values learnt from writes rest on.
    written_fact: Fact,
    /// Whether the memos below are used (see [`Monitor::set_memo`]).
    memo: bool,
    /// Requests judged: the model's judgement and the master's findings not on timing.
    requests_memo: memo::Memo<(Arc<Judgement>, Vec<Issue>)>,
    /// Exchanges judged: the drive's side, without timing.
    verdicts_memo: memo::Memo<Arc<judge::Verdict>>,
    /// Scratch: a memo key, the values known for a read.
    key: Vec<u8>,
    known: Vec<Option<u16>>,
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
    /// The framer's output buffer, kept between calls.
    framed: Vec<TapFrame>,
    /// What became of each frame heard, and of each request.
    tally: FrameTally,
    /// Tests: every exchange as counted.
    #[cfg(test)]
    trail: Vec<Counted>,
}

/// Tests: one exchange as counted (node, status, findings, citations, exchange).
#[cfg(test)]
type Counted = (u8, VerdictStatus, Vec<Issue>, Vec<String>, ExchangeRecord);

/// What became of every frame the monitor heard, and of every request among them: each
/// frame is counted once, where its fate is decided, so that a frame dropped or counted
/// twice shows as a sum that does not add up (the `monitor_stream` fuzz target's law).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct FrameTally {
    /// Frames taken as a request (valid or not), each then closed once below.
    pub requests: u64,
    /// Frames taken as the reply to the request under way.
    pub replies: u64,
    /// Damaged frames after a request, held as the start of its reply (or of its
    /// silence).
    pub damaged: u64,
    /// Replies with no request under way (the first frame heard among them).
    pub unpaired: u64,
    /// Requests closed with a reply.
    pub answered: u64,
    /// Requests closed without a (valid) reply: the window passed, or the next request
    /// came.
    pub unanswered: u64,
    /// Requests left unjudged because listening ended inside their window.
    pub unjudged: u64,
    /// Frames that listening ended inside (not whole, no silence after them): not
    /// judged.
    pub cut: u64,
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
            last_request: HashMap::with_hasher(memo::FastHash::random()),
            written: HashMap::with_hasher(memo::FastHash::random()),
            written_fact: Fact::documented(
                "a write seen on the bus set it, and a parameter holds what was written (the manual's 06H/10H)",
            ),
            memo: true,
            requests_memo: memo::Memo::new(),
            verdicts_memo: memo::Memo::new(),
            key: Vec::new(),
            known: Vec::new(),
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
            framed: Vec::new(),
            tally: FrameTally::default(),
            #[cfg(test)]
            trail: Vec::new(),
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

    /// Whether to keep what judging an exchange found, to judge the same exchange again
    /// from it (default: yes; see the `memo` module). The verdicts are the same either
    /// way: off, every exchange is judged from scratch (differential tests, measurements).
    pub fn set_memo(&mut self, on: bool) {
        self.memo = on;
    }

    /// The sender the next bytes come from, where the source knows it (`None`, a tap,
    /// the default): frames from the sender of a request are never its reply, frames
    /// from another sender are. An opaque id: a capture's direction flag says which way
    /// a packet went *on its interface*, so the id is the interface with the direction
    /// ([`capture_side`]); a `bus` capture has one interface per endpoint, each frame
    /// outbound on its sender's, and a master's and a drive's frames differ by interface.
    pub fn set_side(&mut self, side: Option<u64>) {
        self.framer.set_side(side);
    }
}

/// What a [`Monitor`] holds at one moment, by kind: its memory apart from the model and
/// the per-node statistics (fixed size each). Every field has a bound that no traffic can
/// pass ([`Held::within_bounds`]).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Held {
    /// Bytes the framer holds (a block under way, a frame cut short).
    pub framer: usize,
    /// Bytes of the request under way and of what came after it that is no frame.
    pub pending: usize,
    /// Bytes of the last request kept per node (to tell retries).
    pub last_requests: usize,
    /// Register values learnt from writes.
    pub written: usize,
    /// First examples kept (one per node, side and kind).
    pub examples: usize,
    /// Entries of the two memos.
    pub memo_entries: usize,
    /// Notices made.
    pub notices: usize,
    /// Live lines not taken yet (the caller takes them as it goes).
    pub lines: usize,
}

/// The most notices a session makes: each kind is said once (latency timer, first frame a
/// reply, the last request unjudged), and the caller's own (how the line was found).
pub const MAX_NOTICES: usize = 8;

impl Held {
    /// Whether every field is under its bound, given the registers the model maps
    /// (`map_registers`) and the nodes on the bus (`nodes`, 0: any of 247); the first
    /// field over its bound, with the bound, where one is.
    pub fn within_bounds(&self, map_registers: usize, nodes: usize) -> Result<(), String> {
        use crate::codec::MAX_ASCII_FRAME;
        let nodes = if nodes == 0 { 248 } else { nodes + 1 };
        let kinds = kinds().len();
        let bounds = [
            ("framer", self.framer, 4 * MAX_ASCII_FRAME),
            ("pending", self.pending, 3 * MAX_ASCII_FRAME),
            ("last_requests", self.last_requests, 256 * MAX_ASCII_FRAME),
            ("written", self.written, nodes * map_registers),
            ("examples", self.examples, 256 * 2 * kinds),
            ("memo_entries", self.memo_entries, 2 * memo::MEMO_ENTRIES),
            ("notices", self.notices, MAX_NOTICES),
        ];
        match bounds.iter().find(|(_, v, b)| v > b) {
            Some((name, v, b)) => Err(format!("{name}: {v} held, over its bound of {b}")),
            None => Ok(()),
        }
    }
}

/// The sender id ([`Monitor::set_side`]) of a capture's packet on `interface` that went
/// `direction` on it, where its flags give one.
pub fn capture_side(interface: u32, direction: Option<crate::capture::Direction>) -> Option<u64> {
    direction
        .map(|d| u64::from(interface) << 1 | u64::from(d == crate::capture::Direction::Outbound))
}

impl Monitor {
    /// Bytes that arrived at `at` (since the listener's origin).
    pub fn feed(&mut self, at: Duration, bytes: &[u8]) {
        if bytes.is_empty() {
            return;
        }
        self.tick(at);
        self.bytes += bytes.len() as u64;
        let mut out = std::mem::take(&mut self.framed);
        self.framer.push(at, bytes, &mut out);
        self.on_frames(out);
    }

    /// One whole packet from a capture: its first byte arrived at `first_byte_at`, its
    /// last at `end_at`. The same as `feed(first_byte_at, &bytes[..1])` then
    /// `feed(end_at, &bytes[1..])` (response times measured to the first byte, the
    /// packet's end at its last byte), framed whole where nothing is held before it.
    pub fn feed_packet(&mut self, first_byte_at: Duration, end_at: Duration, bytes: &[u8]) {
        // A read held for bytes at its moment is framed first: a packet is one read.
        let mut out = std::mem::take(&mut self.framed);
        self.framer.settle(&mut out);
        self.on_frames(out);
        if !self.framer.takes_whole(bytes) {
            let (head, rest) = bytes.split_at(1.min(bytes.len()));
            self.feed(first_byte_at, head);
            self.feed(end_at, rest);
            return;
        }
        self.tick(first_byte_at);
        self.tick(end_at);
        self.bytes += bytes.len() as u64;
        let mut out = std::mem::take(&mut self.framed);
        self.framer
            .push_packet(first_byte_at, end_at, bytes, &mut out);
        self.on_frames(out);
    }

    /// Nothing came up to `now`: frames followed by t3.5 end, and a request whose window
    /// has passed is judged.
    pub fn idle(&mut self, now: Duration) {
        self.tick(now);
        let mut out = std::mem::take(&mut self.framed);
        self.framer.idle(now, &mut out);
        self.on_frames(out);
        self.close_if_the_window_passed(now);
    }

    /// Judges the frames the framer gave, then keeps their buffer for the next call.
    fn on_frames(&mut self, mut frames: Vec<TapFrame>) {
        for f in frames.drain(..) {
            self.on_frame(f);
        }
        if self.framed.is_empty() {
            self.framed = frames;
        }
    }

    /// The listener's clock reached `at`.
    fn tick(&mut self, at: Duration) {
        self.first_at.get_or_insert(at);
        self.last_at = Some(self.last_at.map_or(at, |l| l.max(at)));
    }

    /// The end of the input: everything held is framed and judged.
    ///
    /// A frame that the end cut (bytes still arriving, no silence after them, and not a
    /// whole frame) is not judged: its bytes say nothing of the sender, only that
    /// listening stopped. It is counted ([`FrameTally::cut`]) and named in a notice, and
    /// the request under way, if a reply is due, is left unjudged with it.
    pub fn finish(&mut self) {
        let mut out = Vec::new();
        self.framer.finish(&mut out);
        for f in out {
            if f.ended_by == EndedBy::EndOfInput && f.status != FrameStatus::Valid {
                self.cut_by_the_end(f);
            } else {
                self.on_frame(f);
            }
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
                self.tally.unjudged += 1;
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

    /// Closes the request under way unanswered where its window was over by `began`: when
    /// a frame began (at the earliest the reads allow), or a read found the line quiet.
    fn close_if_the_window_passed(&mut self, began: Duration) {
        if self
            .pending
            .as_ref()
            .is_some_and(|p| began.saturating_sub(p.end) > self.cfg.window)
        {
            self.close_unanswered(None);
        }
    }

    /// A frame that listening ended inside (see [`Monitor::finish`]).
    fn cut_by_the_end(&mut self, f: TapFrame) {
        self.frames += 1;
        self.tally.cut += 1;
        let began = f.earliest_start(self.cfg.line.char_time_us());
        self.close_if_the_window_passed(began);
        let heard = judge::show(self.cfg.mode, &f.bytes);
        let n = f.bytes.len();
        match self.pending.take() {
            Some(p) if p.judgement.expect.replies() => {
                let after = began.saturating_sub(p.end);
                self.notices.push(format!(
                    "listening ended inside the frame after the last request ({}): {n} bytes of it were heard ({heard}), {:.1} ms after the request, and neither was judged",
                    judge::show(self.cfg.mode, &p.bytes),
                    ms(after)
                ));
                self.tally.unjudged += 1;
            }
            p => {
                self.pending = p;
                self.notices.push(format!(
                    "listening ended inside a frame: {n} bytes of it were heard ({heard}), and it was not judged"
                ));
            }
        }
    }

    /// Per-node statistics.
    pub fn nodes(&self) -> &BTreeMap<u8, NodeStats> {
        &self.nodes
    }

    /// The first example of each kind of finding, per node and side.
    pub fn examples(&self) -> &BTreeMap<(u8, Side, &'static str), Example> {
        &self.examples
    }

    /// What became of the frames heard so far (see [`FrameTally`]).
    pub fn tally(&self) -> FrameTally {
        self.tally
    }

    /// Frames heard so far.
    pub fn frames_heard(&self) -> u64 {
        self.frames
    }

    /// Bytes heard so far (every byte given to [`Monitor::feed`] and
    /// [`Monitor::feed_packet`]).
    pub fn bytes_heard(&self) -> u64 {
        self.bytes
    }

    /// What the monitor holds now, by kind (see [`Held`]): bounded whatever it hears.
    pub fn held(&self) -> Held {
        let pending = self
            .pending
            .as_ref()
            .map_or(0, |p| p.bytes.len() + p.leading.len());
        Held {
            framer: self.framer.held_bytes(),
            pending,
            last_requests: self.last_request.values().map(|(b, ..)| b.len()).sum(),
            written: self.written.len(),
            examples: self.examples.len(),
            memo_entries: self.requests_memo.len() + self.verdicts_memo.len(),
            notices: self.notices.len(),
            lines: self.lines.len(),
        }
    }

    /// Whether a frame is under way: the framer holds bytes of one (or the start of one
    /// cut short, held for its rest). Listening that stops now cuts it.
    pub fn frame_under_way(&self) -> bool {
        self.framer.held_bytes() > 0
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
        // When the frame began, at the earliest the reads allow: a listener whose host
        // was busy reads a reply in time late. The window, and whether a copy of the
        // request is its reply or a resend, are judged from it.
        let began = f.earliest_start(self.cfg.line.char_time_us());
        self.close_if_the_window_passed(began);
        // A copy of a 06H/08H request is its normal reply, or the master sending it
        // again: by time, a copy later than any reply is due is the master's resend.
        let copy_limit = || {
            self.model
                .response_time_on(Some(&self.cfg.line))
                .saturating_add(self.cfg.response_allowance)
                .saturating_add(Duration::from_micros(self.cfg.line.char_time_us()))
        };
        // Where the source knows the side each frame came from (a capture's direction
        // flags), that settles it: a frame from the request's side is never its reply.
        let same_side = self
            .pending
            .as_ref()
            .and_then(|p| p.side.zip(f.side).map(|(a, b)| a == b));
        let resend = same_side.unwrap_or_else(|| {
            self.pending.as_ref().is_some_and(|p| {
                is_copy(&p.bytes, &f.bytes) && began.saturating_sub(p.end) > copy_limit()
            })
        });
        if let Some(p) = self.pending.as_mut() {
            match f.status {
                FrameStatus::Valid
                    if !resend
                        && (same_side == Some(false)
                            || is_reply_to(self.cfg.mode, &p.bytes, &f.bytes)) =>
                {
                    self.tally.replies += 1;
                    self.close_with_reply(f, since_previous);
                    return;
                }
                // (Not a frame from the request's side, nor a copy of the request later
                // than a reply is due: the master sending it again, damaged or not.)
                FrameStatus::Corrupt | FrameStatus::Incomplete
                    if !resend
                        && p.leading.len() + f.bytes.len() <= 2 * crate::codec::MAX_ASCII_FRAME =>
                {
                    // Bytes that are no frame after a request: the reply, damaged, or
                    // garbage before it; the next frame or the window tells.
                    if p.leading.is_empty() {
                        p.leading_start = f.start;
                    }
                    p.leading.extend_from_slice(&f.bytes);
                    self.tally.damaged += 1;
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
}

/// Whether `frame` answers `request`: the same address or not, the request's function
/// (or its exception), and a reply's shape.
fn is_reply_to(mode: Mode, request: &[u8], frame: &[u8]) -> bool {
    let (Some(req), Some(rep)) = (judge::body_cow(mode, request), judge::body_cow(mode, frame))
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
#[cfg(test)]
mod tests_drain;
#[cfg(test)]
mod tests_packet;
#[cfg(test)]
mod tests_stream;
