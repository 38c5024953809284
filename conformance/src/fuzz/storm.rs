//! The storm test (`conformance fuzz --storm`): the device's own requests at line rate,
//! interleaved with traffic for other nodes and broadcasts, as on a busy RS-485 bus.
//!
//! Frames follow each other with t3.5 of silence and no more (Modbus over Serial Line
//! V1.02, 2.5.1.1: the least a receiver must accept); after one of the device's own
//! requests, t3.5 after the last byte of its reply. The mix, seeded by `--seed`:
//!
//! - the device's own requests (40%): reads of registers the model says are readable, the
//!   08H loop-back, and with `--writes preserving` or `any` writes of the value just read;
//! - requests for another node (`--other-address`, a node that should not exist on the
//!   line), reads; with `--writes any` also writes (other drives would execute them);
//! - replies *from* that node after its requests, as a real bus carries the other
//!   slaves' answers: a device must not take them for requests;
//! - broadcast reads (03H to node 00H, which Modbus does not allow: the device must stay
//!   silent), always;
//! - broadcast writes only with `--writes any` (a decision: a broadcast reaches every
//!   drive on the bus, and no value can be preserved for drives this suite has not
//!   read; it writes the value the device under test returned, journalled and restored
//!   for it only, with a warning).
//!
//! The device must answer every own request within the manual's response time (on a
//! line with timing, at least t3.5, plus one character for the first byte to arrive and
//! the allowance `check` uses), lose none, answer each as the model predicts, and answer
//! nothing else. The same requests are first sent on an idle line, so the report sets the
//! response-time distribution under load against the idle one, measured in the same run.
//!
//! The storm owns the link between the preflight and the restore (through
//! [`Ctx::transport_mut`]); the journal, the liveness probe after it and the restore are
//! the runner's.

use std::collections::{BTreeMap, VecDeque};
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::{FuzzConfig, ModeOutcome, Writes};
use crate::codec::deframe::{AsciiDeframer, Event, RtuDeframer, RtuFraming};
use crate::codec::pdu::{Direction, Pdu};
use crate::codec::{frame_of_body, frame_parts, Mode};
use crate::judge::{self, Judge};
use crate::model::{Access, Expectation};
use crate::rng::Rng;
use crate::runner::master::Chunk;
use crate::runner::{Ctx, Exchange, RunError};
use crate::transport::{sleep_until, Transport, TransportError};

/// The settings of a storm.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct StormConfig {
    /// Frames in the storm (all kinds).
    pub frames: u64,
    /// Own requests sent first on an idle line (the reference distribution).
    pub idle: u64,
}

/// What goes on the line in one slot.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Slot {
    /// A request for the device.
    Own,
    /// A read for another node.
    OtherRequest,
    /// A write for another node (`--writes any`).
    OtherWrite,
    /// A reply from another node.
    OtherReply,
    /// A broadcast read (not allowed by Modbus: no answer).
    BroadcastRead,
    /// A broadcast write (`--writes any`).
    BroadcastWrite,
}

impl Slot {
    /// The name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Slot::Own => "own-request",
            Slot::OtherRequest => "other-request",
            Slot::OtherWrite => "other-write",
            Slot::OtherReply => "other-reply",
            Slot::BroadcastRead => "broadcast-read",
            Slot::BroadcastWrite => "broadcast-write",
        }
    }
}

/// Response times, with their distribution.
#[derive(Debug, Clone, Default)]
pub struct Latencies {
    /// Every measured response time (end of request to first byte of reply).
    pub samples: Vec<Duration>,
}

/// A distribution in milliseconds.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Distribution {
    /// Samples.
    pub count: usize,
    /// Least.
    pub min: f64,
    /// Median.
    pub median: f64,
    /// 95th percentile.
    pub p95: f64,
    /// 99th percentile.
    pub p99: f64,
    /// Largest.
    pub max: f64,
}

impl Latencies {
    /// The distribution (None without samples). Percentiles by the nearest rank.
    pub fn distribution(&self) -> Option<Distribution> {
        if self.samples.is_empty() {
            return None;
        }
        let mut s: Vec<f64> = self.samples.iter().map(|d| d.as_secs_f64() * 1e3).collect();
        s.sort_by(f64::total_cmp);
        let rank = |p: f64| {
            let k = ((p * s.len() as f64).ceil() as usize).clamp(1, s.len());
            s[k - 1]
        };
        Some(Distribution {
            count: s.len(),
            min: s[0],
            median: rank(0.5),
            p95: rank(0.95),
            p99: rank(0.99),
            max: s[s.len() - 1],
        })
    }
}

impl Distribution {
    fn text(&self) -> String {
        format!(
            "n={} min {:.2} / median {:.2} / p95 {:.2} / p99 {:.2} / max {:.2} ms",
            self.count, self.min, self.median, self.p95, self.p99, self.max
        )
    }

    fn json(&self) -> serde_json::Value {
        let r = |x: f64| (x * 1000.0).round() / 1000.0;
        serde_json::json!({
            "count": self.count,
            "min_ms": r(self.min),
            "median_ms": r(self.median),
            "p95_ms": r(self.p95),
            "p99_ms": r(self.p99),
            "max_ms": r(self.max),
        })
    }
}

/// What the storm of one mode found.
#[derive(Debug, Clone, Default)]
pub struct StormOutcome {
    /// Whether the link has line timing (else response times are the host's).
    pub timed: bool,
    /// Silence kept between frames.
    pub gap: Duration,
    /// The response-time limit (manual, at least t3.5, + one character + allowance).
    pub limit: Duration,
    /// Own requests on the idle line.
    pub idle: Latencies,
    /// Own requests in the storm.
    pub load: Latencies,
    /// Frames sent in the storm, by kind.
    pub sent: BTreeMap<&'static str, u64>,
    /// Own requests in the storm.
    pub own: u64,
    /// Own requests of the storm not answered within the timeout.
    pub lost: u64,
    /// Own requests answered later than the limit.
    pub late: u64,
    /// Own requests answered other than the model predicts.
    pub wrong: u64,
    /// Frames the device sent that answer nothing of its own (other nodes' traffic,
    /// broadcasts), and bytes that are no frame.
    pub unexpected: u64,
    /// Lost or late on the idle line (the reference must be clean to compare).
    pub idle_problems: u64,
    /// Frames sent again because the host stalled inside them while pacing them.
    pub resent: u64,
    /// Own requests given up after every send of them was broken by this host's stalls:
    /// never seen whole by the device, so neither lost nor answered.
    pub own_unsent: u64,
    /// The first problems, in words with the frames in hex.
    pub problems: Vec<String>,
    /// Time of the storm.
    pub elapsed: Duration,
    /// Share of the storm's time the line carried characters (on a timed line).
    pub busy: Option<f64>,
    /// Why frames of a kind were not sent (safety).
    pub not_sent: Vec<String>,
}

const MAX_PROBLEMS: usize = 12;

impl StormOutcome {
    /// Whether the device did everything the storm asks.
    pub fn passed(&self) -> bool {
        self.lost == 0 && self.late == 0 && self.wrong == 0 && self.unexpected == 0
    }

    fn problem(&mut self, text: String) {
        if self.problems.len() < MAX_PROBLEMS {
            self.problems.push(text);
        }
    }

    /// The `storm` object of a mode in the JSON report.
    pub fn to_json(&self) -> serde_json::Value {
        let ms = |d: Duration| (d.as_secs_f64() * 1e6).round() / 1e3;
        serde_json::json!({
            "passed": self.passed(),
            "line_timing": self.timed,
            "gap_ms": ms(self.gap),
            "limit_ms": ms(self.limit),
            "sent": self.sent,
            "own_requests": self.own,
            "lost": self.lost,
            "late": self.late,
            "wrong": self.wrong,
            "unexpected": self.unexpected,
            "idle_problems": self.idle_problems,
            "resent": self.resent,
            "own_unsent": self.own_unsent,
            "idle": self.idle.distribution().map(|d| d.json()),
            "load": self.load.distribution().map(|d| d.json()),
            "elapsed_ms": ms(self.elapsed),
            "line_busy": self.busy.map(|b| (b * 1000.0).round() / 1000.0),
            "problems": self.problems,
            "not_sent": self.not_sent,
        })
    }

    /// The lines of the text report.
    pub fn lines(&self) -> Vec<String> {
        let mut out = Vec::new();
        let total: u64 = self.sent.values().sum();
        let by: Vec<String> = self.sent.iter().map(|(k, n)| format!("{k} {n}")).collect();
        out.push(format!(
            "{total} frames in {:.1} s, {} us of silence between frames{} ({})",
            self.elapsed.as_secs_f64(),
            self.gap.as_micros(),
            match self.busy {
                Some(b) => format!(", line busy {:.0}% of the time", b * 100.0),
                None => " (the link has no line timing: response times are the host's)".into(),
            },
            by.join(", ")
        ));
        out.push(format!(
            "own requests: {} sent, {} lost, {} late (over {:.1} ms), {} answered wrongly; {} answer(s) to other traffic",
            self.own,
            self.lost,
            self.late,
            self.limit.as_secs_f64() * 1e3,
            self.wrong,
            self.unexpected
        ));
        let d = |l: &Latencies| l.distribution().map_or("no replies".into(), |d| d.text());
        out.push(format!("response time idle:       {}", d(&self.idle)));
        out.push(format!("response time under load: {}", d(&self.load)));
        if self.idle_problems > 0 {
            out.push(format!(
                "{} own request(s) lost or late on the idle line already",
                self.idle_problems
            ));
        }
        if self.resent > 0 {
            out.push(format!(
                "{} frame(s) sent again: the host stalled inside them while pacing them (not judged)",
                self.resent
            ));
        }
        for n in &self.not_sent {
            out.push(format!("not sent: {n}"));
        }
        out
    }
}

/// The result of the storm as the suite's report (JUnit: one testcase).
pub fn result(mode: Mode, s: &StormOutcome) -> crate::runner::CheckResult {
    use crate::runner::{CheckResult, Finding, Status};
    let mut findings: Vec<Finding> = s.lines().into_iter().map(Finding::observation).collect();
    for p in &s.problems {
        findings.push(Finding::deviation(p.clone()));
    }
    let status = if s.passed() {
        Status::Pass
    } else {
        Status::Deviation
    };
    let lines = s.lines();
    CheckResult {
        id: format!("fuzz.{mode}.storm"),
        title: "storm: own requests at line rate among other nodes' traffic and broadcasts".into(),
        mode: Some(mode),
        source: "Modbus over Serial Line V1.02, 2.5.1.1 (t3.5 between frames) and 2.1 (broadcast: no reply; a slave answers only requests addressed to it); the manual's response time".into(),
        status,
        summary: format!("{} {}", lines[1], lines.get(3).cloned().unwrap_or_default()),
        findings,
        exchanges: Vec::new(),
        duration: s.elapsed,
        node: None,
    }
}

/// Frames received, deframed as replies, with the local echo stripped.
struct Rx {
    mode: Mode,
    rtu: RtuDeframer,
    ascii: AsciiDeframer,
    echo: VecDeque<u8>,
    echoes: bool,
    start: Option<Instant>,
    frames: VecDeque<(Instant, Vec<u8>)>,
    garbage: Vec<u8>,
    last: Option<Instant>,
    epoch: Instant,
}

impl Rx {
    fn new(mode: Mode, echoes: bool) -> Self {
        Rx {
            mode,
            rtu: RtuDeframer::new(Direction::Response, RtuFraming::ByLength),
            ascii: AsciiDeframer::default(),
            echo: VecDeque::new(),
            echoes,
            start: None,
            frames: VecDeque::new(),
            garbage: Vec::new(),
            last: None,
            epoch: Instant::now(),
        }
    }

    fn sent(&mut self, bytes: &[u8]) {
        if self.echoes {
            self.echo.extend(bytes.iter().copied());
        }
    }

    fn feed(&mut self, at: Instant, bytes: &[u8]) {
        let us = u64::try_from(at.duration_since(self.epoch).as_micros()).unwrap_or(u64::MAX);
        for &b in bytes {
            match self.echo.front() {
                Some(&e) if e == b => {
                    self.echo.pop_front();
                    continue;
                }
                Some(_) => self.echo.clear(),
                None => {}
            }
            let pending = match self.mode {
                Mode::Rtu => self.rtu.pending(),
                Mode::Ascii => usize::from(self.start.is_some()),
            };
            if pending == 0 {
                self.start = Some(at);
            }
            let mut events: Vec<(bool, Vec<u8>)> = Vec::new();
            let mut emit = |e: Event<'_>| match e {
                Event::Frame(f) => events.push((true, f.to_vec())),
                Event::Corrupt(f) | Event::Incomplete(f) | Event::Garbage(f) => {
                    events.push((false, f.to_vec()))
                }
            };
            match self.mode {
                Mode::Rtu => self.rtu.push(std::slice::from_ref(&b), &mut emit),
                Mode::Ascii => self.ascii.push_at(us, std::slice::from_ref(&b), &mut emit),
            }
            for (frame, bytes) in events {
                if frame {
                    self.frames.push_back((self.start.unwrap_or(at), bytes));
                } else {
                    self.garbage.extend_from_slice(&bytes);
                }
                self.start = None;
            }
        }
        if !bytes.is_empty() {
            self.last = Some(at);
        }
    }

    /// Reads what has come, waiting at most `wait`.
    fn pump(&mut self, t: &mut dyn Transport, wait: Duration) -> Result<usize, TransportError> {
        let mut buf = [0u8; 256];
        let n = t.recv(&mut buf, wait)?;
        if n > 0 {
            self.feed(Instant::now(), &buf[..n]);
        }
        Ok(n)
    }
}

/// The storm's state between slots.
struct Storm<'o> {
    rx: Rx,
    /// When the line was last busy (end of a frame sent or received).
    quiet: Instant,
    gap: Duration,
    limit: Duration,
    out: &'o mut StormOutcome,
    /// The last frames for others before an own request, to name what an unexpected
    /// answer may answer.
    recent: VecDeque<Vec<u8>>,
    /// Characters on the line (for the busy share).
    chars: u64,
}

impl Storm<'_> {
    fn drain_unexpected(&mut self, mode: Mode) {
        while let Some((_, f)) = self.rx.frames.pop_front() {
            self.unexpected(mode, &f);
        }
        if !self.rx.garbage.is_empty() {
            let g = std::mem::take(&mut self.rx.garbage);
            self.out.unexpected += 1;
            self.out.problem(format!(
                "{} byte(s) that are no frame: {}",
                g.len(),
                crate::codec::hex::Hex(&g)
            ));
        }
    }

    fn unexpected(&mut self, mode: Mode, f: &[u8]) {
        self.out.unexpected += 1;
        self.chars += f.len() as u64;
        let recent: Vec<String> = self.recent.iter().map(|r| judge::show(mode, r)).collect();
        self.out.problem(format!(
            "the device sent {} = {}, which answers none of its own requests (the frames before it: {})",
            judge::show(mode, f),
            judge::describe_reply(mode, f),
            recent.join(", ")
        ));
    }

    /// Sends `frame` after t3.5, again where the host stalled inside it while pacing it:
    /// such a frame is not the one meant (the device sees a broken frame and must drop
    /// it), so nothing of it is judged. [`TransportError::Stalled`] after
    /// [`crate::runner::master::MAX_BROKEN_SENDS`] broken sends.
    fn send(&mut self, ctx: &mut Ctx<'_>, frame: &[u8]) -> Result<Instant, TransportError> {
        let mut tries = 0;
        let ascii = ctx.mode == crate::codec::Mode::Ascii;
        loop {
            sleep_until(self.quiet + self.gap);
            let t = ctx.transport_mut(self.quiet);
            self.rx.pump(t, Duration::ZERO)?;
            t.send(frame)?;
            self.rx.sent(frame);
            let sent = t.sent_at().unwrap_or_else(Instant::now);
            self.quiet = sent;
            // An ASCII frame is not broken by a silence (see Master::send_broken).
            if !t.send_was_broken() || ascii {
                return Ok(sent);
            }
            tries += 1;
            // Every send broken: the device never saw the frame (issue 24). Not its
            // silence to judge: the caller leaves the frame out.
            if tries >= crate::runner::master::MAX_BROKEN_SENDS {
                return Err(TransportError::Stalled {
                    link: t.describe(),
                    request: crate::codec::hex::Hex(&frame[..frame.len().min(64)]).to_string(),
                    sends: tries,
                });
            }
            self.out.resent += 1;
        }
    }

    /// Sends a frame that is not the device's own request.
    fn other(&mut self, ctx: &mut Ctx<'_>, frame: &[u8]) -> Result<(), TransportError> {
        self.send(ctx, frame)?;
        let t = ctx.transport_mut(self.quiet);
        self.rx.pump(t, Duration::ZERO)?;
        self.chars += frame.len() as u64;
        self.recent.push_back(frame.to_vec());
        if self.recent.len() > 3 {
            self.recent.pop_front();
        }
        Ok(())
    }

    /// Sends an own request and waits for its reply; the response time if one came.
    fn own(
        &mut self,
        ctx: &mut Ctx<'_>,
        frame: &[u8],
    ) -> Result<Option<(Duration, Vec<u8>)>, TransportError> {
        let mode = ctx.mode;
        let own = ctx.opts.address;
        let timeout = ctx.opts.timing.timeout;
        {
            let t = ctx.transport_mut(self.quiet);
            self.rx.pump(t, Duration::ZERO)?;
        }
        self.drain_unexpected(mode);
        let sent = self.send(ctx, frame)?;
        self.chars += frame.len() as u64;
        let function = compare_function(mode, frame);
        let deadline = sent + timeout;
        let mut reply: Option<(Instant, Vec<u8>)> = None;
        loop {
            while let Some((at, f)) = self.rx.frames.pop_front() {
                let ours = reply.is_none()
                    && at >= sent
                    && frame_parts(mode, &f).is_ok_and(|p| {
                        p.body.first() == Some(&own)
                            && p.body.get(1).is_some_and(|&fc| fc & 0x7F == function)
                    });
                if ours {
                    self.chars += f.len() as u64;
                    reply = Some((at, f));
                } else {
                    self.unexpected(mode, &f);
                }
            }
            if reply.is_some() {
                break;
            }
            let now = Instant::now();
            if now >= deadline {
                break;
            }
            let t = ctx.transport_mut(self.quiet);
            self.rx
                .pump(t, (deadline - now).min(Duration::from_millis(5)))?;
        }
        self.quiet = self.rx.last.unwrap_or(sent).max(sent);
        self.recent.clear();
        Ok(reply.map(|(at, f)| (at.saturating_duration_since(sent), f)))
    }
}

fn compare_function(mode: Mode, frame: &[u8]) -> u8 {
    super::state::function_of(mode, frame)
}

/// The device's own requests: reads of readable registers (the writable ones among them,
/// so that their values are known), the 08H loop-back.
fn own_reads(ctx: &Ctx<'_>) -> Vec<Vec<u8>> {
    let model = ctx.model;
    let mut regs: Vec<u16> = Vec::new();
    if let Some(r) = crate::runner::liveness::liveness_register(model, ctx.opts.address, ctx.mode) {
        regs.push(r);
    }
    let readable: Vec<(u16, Access)> = model
        .registers()
        .filter(|(_, a)| matches!(a, Access::ReadWrite | Access::ReadOnly))
        .collect();
    // A spread over the map: every n-th readable register, the writable ones favoured.
    let step = (readable.len() / 6).max(1);
    for (i, (r, _)) in readable.iter().enumerate() {
        if i % step == 0 && regs.len() < 8 {
            regs.push(*r);
        }
    }
    for (r, a) in &readable {
        if *a == Access::ReadWrite && regs.len() < 12 && !regs.contains(r) {
            regs.push(*r);
        }
    }
    let mut out = Vec::new();
    for r in regs {
        let f = ctx.frame(Pdu::ReadRequest { start: r, count: 1 });
        if matches!(
            model.judge(ctx.opts.address, ctx.mode, &f).expect,
            Expectation::Read(_)
        ) {
            out.push(f);
        }
    }
    let lb = ctx.frame(Pdu::LoopBack {
        test_code: 0,
        data: &[0x12, 0x34],
    });
    if model
        .judge(ctx.opts.address, ctx.mode, &lb)
        .expect
        .replies()
    {
        out.push(lb);
    }
    out
}

/// Runs the storm of one mode (after the preflight): the idle reference, the storm, a
/// liveness probe, the restore.
pub fn run(
    ctx: &mut Ctx<'_>,
    scfg: &StormConfig,
    cfg: &FuzzConfig,
    mut out: ModeOutcome,
    stop: &AtomicBool,
) -> ModeOutcome {
    let mut s = StormOutcome::default();
    let started = Instant::now();
    match storm(ctx, scfg, cfg, &mut s, stop) {
        Ok(()) => {}
        Err(e @ (RunError::Transport(_) | RunError::HostStalled(_))) => {
            out.stopped = Some(e.to_string())
        }
        Err(RunError::DeviceLost(why)) => out.stopped = Some(why),
        // The storm sends without probing: nothing of it is undescribed.
        Err(RunError::Undescribed(_)) => {}
    }
    // Let the line go quiet, then the device must still answer.
    std::thread::sleep(ctx.silence_window());
    ctx.lost = None;
    match ctx.liveness() {
        Ok(true) => {}
        Ok(false) => {
            out.stopped.get_or_insert_with(|| {
                "the device did not answer its liveness probe after the storm".into()
            });
        }
        Err(e) => {
            out.stopped.get_or_insert_with(|| e.to_string());
        }
    }
    if stop.load(Ordering::Relaxed) && out.stopped.is_none() {
        out.stopped = Some("interrupted".into());
    }
    out.cases = s.sent.values().sum::<u64>() + s.idle.samples.len() as u64;
    out.elapsed = started.elapsed();
    out.probes = ctx.liveness_probes;
    out.echo = ctx.echoes();
    out.restore = ctx.restore();
    out.storm = Some(s);
    out.timing.not_sent = Some("the storm test ran instead of the cases");
    out
}

fn storm(
    ctx: &mut Ctx<'_>,
    scfg: &StormConfig,
    cfg: &FuzzConfig,
    s: &mut StormOutcome,
    stop: &AtomicBool,
) -> Result<(), RunError> {
    let mode = ctx.mode;
    let own = ctx.opts.address;
    let other = ctx.opts.other_address;
    let model = ctx.model;
    let line = ctx.line_timing();
    s.timed = line.is_some();
    // t3.5 of the line (or of the configured line where the link has no timing).
    let configured = line.or(ctx.opts.line);
    s.gap = configured.map_or(Duration::from_millis(2), |l| {
        Duration::from_micros(l.t3_5_us())
    });
    let first_char = line.map_or(Duration::ZERO, |l| Duration::from_micros(l.char_time_us()));
    // A description that states no response time holds no reply late: the master's own
    // timeout is the only bound.
    s.limit = match model.limits.response_time_ms {
        Some(_) => model.response_time_on(line.as_ref()) + first_char + ctx.opts.response_allowance,
        None => ctx.opts.timing.timeout,
    };
    let mut rng = Rng::new(cfg.seed ^ 0x5707_4D00);
    let reads = own_reads(ctx);
    if reads.is_empty() {
        s.not_sent
            .push("own requests: the model answers no read of this device".into());
        return Ok(());
    }
    let mut storm = Storm {
        rx: Rx::new(mode, ctx.echoes() == Some(true)),
        quiet: Instant::now(),
        gap: s.gap,
        limit: s.limit,
        out: s,
        recent: VecDeque::new(),
        chars: 0,
    };
    // The idle reference: the same requests, each after a quiet line.
    let idle_gap = storm.gap.max(Duration::from_millis(20));
    let mut known: BTreeMap<u16, u16> = BTreeMap::new();
    for i in 0..scfg.idle {
        if stop.load(Ordering::Relaxed) {
            return Ok(());
        }
        let f = &reads[(i as usize) % reads.len()];
        std::thread::sleep(idle_gap);
        let answer = match storm.own(ctx, f) {
            // Not sent whole (this host stalled while pacing it): nothing to measure.
            Err(TransportError::Stalled { .. }) => continue,
            r => r?,
        };
        match answer {
            Some((lat, reply)) => {
                if lat > storm.limit {
                    storm.out.idle_problems += 1;
                }
                storm.out.idle.samples.push(lat);
                learn(mode, f, &reply, &mut known);
            }
            None => storm.out.idle_problems += 1,
        }
    }
    storm.drain_unexpected(mode);
    // Own writes of a value just read, as the safety level allows; journalled.
    let mut own_frames = reads.clone();
    let mut broadcast_writes = Vec::new();
    let mut other_writes = Vec::new();
    let (allow_motion, allow_restart) = (ctx.opts.allow_motion, ctx.opts.allow_restart);
    let vet = |f: &[u8], known: &BTreeMap<u16, u16>| {
        super::safety::vet(
            model,
            mode,
            f,
            own,
            cfg.writes,
            allow_motion,
            allow_restart,
            known,
        )
    };
    let mut journal = Vec::new();
    for (&r, &v) in &known {
        let w = ctx.frame(Pdu::WriteSingle {
            register: r,
            value: v,
        });
        if !model.judge(own, mode, &w).expect.replies() {
            continue;
        }
        if let Ok(regs) = vet(&w, &known) {
            journal.extend(regs);
            own_frames.push(w.clone());
        }
        let b = ctx.frame_to(
            0,
            Pdu::WriteSingle {
                register: r,
                value: v,
            },
        );
        if cfg.writes == Writes::Any {
            if let Ok(regs) = vet(&b, &known) {
                journal.extend(regs);
                broadcast_writes.push(b);
            }
            let o = ctx.frame_to(
                other,
                Pdu::WriteSingle {
                    register: r,
                    value: rng.word(),
                },
            );
            if vet(&o, &known).is_ok() {
                other_writes.push(o);
            }
        }
    }
    if cfg.writes != Writes::Any {
        storm.out.not_sent.push(format!(
            "writes to other nodes and broadcast writes: only with --writes any (now {})",
            cfg.writes
        ));
    }
    journal.sort_unstable();
    journal.dedup();
    for r in journal {
        // `remember` reads through the master: the line is quiet here.
        if let Err(e) = ctx.remember(r)? {
            storm
                .out
                .not_sent
                .push(format!("{r:04X}H could not be journalled: {e}"));
        }
    }
    storm.quiet = Instant::now();
    // Reads for the other node, and the replies it would send.
    let other_regs: Vec<u16> = reads
        .iter()
        .filter_map(|f| frame_parts(mode, f).ok())
        .filter(|p| p.body.get(1) == Some(&0x03))
        .map(|p| u16::from_be_bytes([p.body[2], p.body[3]]))
        .collect();
    let t0 = Instant::now();
    let mut n = 0u64;
    while n < scfg.frames {
        if stop.load(Ordering::Relaxed) {
            break;
        }
        let roll = rng.below(100);
        let slot = match roll {
            0..=39 => Slot::Own,
            40..=69 => Slot::OtherRequest,
            70..=79 if !other_writes.is_empty() => Slot::OtherWrite,
            70..=79 => Slot::OtherReply,
            80..=91 => Slot::BroadcastRead,
            _ if !broadcast_writes.is_empty() => Slot::BroadcastWrite,
            _ => Slot::BroadcastRead,
        };
        let pick = |rng: &mut Rng, v: &[Vec<u8>]| v[rng.below(v.len() as u64) as usize].clone();
        let reg = other_regs
            .get(rng.below(other_regs.len().max(1) as u64) as usize)
            .copied()
            .unwrap_or(0);
        let count = 1 + rng.below(4) as u16;
        let frame = match slot {
            Slot::Own => pick(&mut rng, &own_frames),
            Slot::OtherRequest => ctx.frame_to(other, Pdu::ReadRequest { start: reg, count }),
            Slot::OtherWrite => pick(&mut rng, &other_writes),
            Slot::OtherReply => other_reply(mode, other, count, &mut rng),
            Slot::BroadcastRead => ctx.frame_to(
                0,
                Pdu::ReadRequest {
                    start: reg,
                    count: 1,
                },
            ),
            Slot::BroadcastWrite => pick(&mut rng, &broadcast_writes),
        };
        if frame.is_empty() {
            continue;
        }
        // Every frame vetted, whatever made it.
        if let Err(why) = vet(&frame, &known) {
            let t = format!("{}: {why}", slot.name());
            if !storm.out.not_sent.contains(&t) {
                storm.out.not_sent.push(t);
            }
            continue;
        }
        n += 1;
        *storm.out.sent.entry(slot.name()).or_default() += 1;
        if slot != Slot::Own {
            match storm.other(ctx, &frame) {
                // A frame for others this host could not send whole: garbage on the line,
                // which the device must drop anyway.
                Err(TransportError::Stalled { .. }) => continue,
                r => r?,
            }
            // A real bus carries the other node's reply after its request.
            if slot == Slot::OtherRequest && rng.below(10) < 6 && n < scfg.frames {
                let r = other_reply(mode, other, count, &mut rng);
                n += 1;
                *storm.out.sent.entry(Slot::OtherReply.name()).or_default() += 1;
                match storm.other(ctx, &r) {
                    Err(TransportError::Stalled { .. }) => {}
                    r => r?,
                }
            }
            continue;
        }
        let judgement = model.judge(own, mode, &frame);
        let answer = match storm.own(ctx, &frame) {
            // An own request this host could not send whole is not one of the device's:
            // neither lost nor answered (the resends are counted).
            Err(TransportError::Stalled { .. }) => {
                storm.out.own_unsent += 1;
                continue;
            }
            r => r?,
        };
        storm.out.own += 1;
        match answer {
            None => {
                storm.out.lost += 1;
                storm.out.problem(format!(
                    "lost: {} got no reply within {} ms",
                    judge::show(mode, &frame),
                    ctx.opts.timing.timeout.as_millis()
                ));
            }
            Some((lat, reply)) => {
                storm.out.load.samples.push(lat);
                if lat > storm.limit {
                    storm.out.late += 1;
                    storm.out.problem(format!(
                        "late: {} answered after {:.2} ms (limit {:.2} ms)",
                        judge::show(mode, &frame),
                        lat.as_secs_f64() * 1e3,
                        storm.limit.as_secs_f64() * 1e3
                    ));
                }
                let ex = Exchange {
                    request: frame.clone(),
                    raw: reply.clone(),
                    chunks: vec![Chunk {
                        at: lat,
                        bytes: reply.clone(),
                    }],
                    echo: false,
                    leading: Vec::new(),
                    reply: Some(reply.clone()),
                    trailing: Vec::new(),
                    first_byte: Some(lat),
                    listened: lat,
                    retries: 0,
                    link_notes: Vec::new(),
                };
                let diff =
                    Judge::new(model).differences(&judgement, &ex.conversation(mode, own), None);
                if !diff.findings.is_empty() {
                    storm.out.wrong += 1;
                    storm.out.problem(format!(
                        "wrong answer to {}: {}",
                        judge::show(mode, &frame),
                        diff.text()
                    ));
                }
                learn(mode, &frame, &reply, &mut known);
            }
        }
    }
    storm.out.elapsed = t0.elapsed();
    // Answers to the last frames come within the silence window.
    let until = Instant::now() + ctx.silence_window();
    while Instant::now() < until {
        let t = ctx.transport_mut(storm.quiet);
        storm.rx.pump(t, Duration::from_millis(5))?;
    }
    storm.drain_unexpected(mode);
    if let Some(l) = line {
        let on_line = Duration::from_micros(l.char_time_us())
            * u32::try_from(storm.chars).unwrap_or(u32::MAX);
        storm.out.busy = Some(on_line.as_secs_f64() / storm.out.elapsed.as_secs_f64().max(1e-9));
    }
    Ok(())
}

/// Values a read returned (what a preserving write may carry).
fn learn(mode: Mode, request: &[u8], reply: &[u8], known: &mut BTreeMap<u16, u16>) {
    let (Ok(q), Ok(r)) = (frame_parts(mode, request), frame_parts(mode, reply)) else {
        return;
    };
    let (q, r) = (q.body, r.body);
    if q.get(1) != Some(&0x03) || r.get(1) != Some(&0x03) || q.len() < 6 {
        return;
    }
    let start = u16::from_be_bytes([q[2], q[3]]);
    for (i, w) in r.get(3..).unwrap_or_default().chunks_exact(2).enumerate() {
        let Some(reg) = start.checked_add(i as u16) else {
            break;
        };
        known.insert(reg, u16::from_be_bytes([w[0], w[1]]));
    }
}

/// A reply as another node would send it after a read of `count` registers.
fn other_reply(mode: Mode, other: u8, count: u16, rng: &mut Rng) -> Vec<u8> {
    let n = usize::from(count.min(4));
    let mut body = vec![other, 0x03, (2 * n) as u8];
    for _ in 0..2 * n {
        body.push(rng.byte());
    }
    // One in eight an exception from that node.
    if rng.below(8) == 0 {
        body = vec![other, 0x83, 0x02];
    }
    frame_of_body(mode, &body).unwrap_or_default()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_by_nearest_rank() {
        let l = Latencies {
            samples: (1..=100).map(Duration::from_millis).collect(),
        };
        let d = l.distribution().unwrap();
        assert_eq!(
            (d.count, d.min, d.median, d.p95, d.p99, d.max),
            (100, 1.0, 50.0, 95.0, 99.0, 100.0)
        );
        assert!(Latencies::default().distribution().is_none());
    }

    #[test]
    fn replies_of_other_nodes_are_frames_for_them() {
        let mut rng = Rng::new(3);
        for _ in 0..50 {
            let f = other_reply(Mode::Rtu, 0xF7, 3, &mut rng);
            assert_eq!(f[0], 0xF7);
            assert_eq!(crate::codec::crc::crc16(&f), 0);
        }
    }
}
