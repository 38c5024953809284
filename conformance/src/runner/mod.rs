//! The conformance runner: probes a device as a Modbus master and compares every answer
//! with its model.
//!
//! - [`master`]: sends requests, collects the raw answer, finds the reply.
//! - the comparison of what the device did with what the model predicts is the
//!   [`judge`](crate::judge)'s, which `monitor` shares.
//! - [`checks`]: the checks, derived from the model, each citing its manual section.
//! - `run`: the loop that runs a mode's checks (or one node's section of them) and
//!   restores at the end ([`run_mode`], [`run_section`]).
//!
//! Safety on a real drive: the run bit and the external-fault bit are only set by checks
//! marked `motion`, which run with [`Options::allow_motion`] only; every register a check
//! writes is read first, journalled, and written back at the end (also after an
//! interruption), and the restore is verified by reading back.

pub mod checks;
pub mod liveness;
pub mod master;
pub mod pieces;
mod setup;

use setup::exception_code;
pub use setup::SetupError;
pub(crate) mod run;

use std::collections::BTreeSet;
use std::time::Duration;

use serde::Serialize;

use crate::judge::{self, Judge};
pub use crate::judge::{Finding, Severity};
pub use checks::{plan, Check};
pub use master::{EchoMode, Exchange, LineBudget, Master, MasterTiming};
pub use run::{id_matches, run_mode, run_section, selected, Plain, Progress, Section};

use crate::codec::pdu::{Direction, Message, Pdu};
use crate::codec::Mode;
use crate::model::{DriveModel, Fact, Judgement};
use crate::transport::{Transport, TransportError};
use crate::vectors::VectorFile;

/// How many times the restore tries one register before it gives up on it.
pub const RESTORE_ATTEMPTS: u32 = 3;

/// Why a check could not go on.
#[derive(Debug, thiserror::Error)]
pub enum RunError {
    /// The link failed.
    #[error(transparent)]
    Transport(TransportError),
    /// The device stopped answering: neither the check's request nor a liveness probe
    /// got a byte back. The run ends; nothing after this can be judged.
    #[error("{0}")]
    DeviceLost(String),
    /// This host could not put a request on the emulated line whole (it stalled while
    /// pacing every send of it: [`TransportError::Stalled`]), or delayed the answer of
    /// the program at the other end of a pseudo-terminal past the timeout every time
    /// ([`TransportError::LateOnHost`]). The check that sent it cannot tell anything
    /// about the device and ends as ERROR; the run goes on.
    #[error(transparent)]
    HostStalled(TransportError),
    /// The model's prediction rests on a fact the description leaves out (the reason
    /// names the field): the check is skipped, nothing is sent, and no device is held
    /// to a guess.
    #[error("{0}")]
    Undescribed(String),
}

impl From<TransportError> for RunError {
    fn from(e: TransportError) -> Self {
        match e {
            TransportError::Stalled { .. } | TransportError::LateOnHost { .. } => {
                RunError::HostStalled(e)
            }
            e => RunError::Transport(e),
        }
    }
}

/// How a check ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Status {
    /// The device did what the manual says.
    Pass,
    /// The manual says X, the device did Y.
    Deviation,
    /// The manual is silent or contradicts itself; this is what the device did.
    Observation,
    /// Not run, with the reason.
    Skip,
    /// The run could not tell.
    Error,
}

impl std::fmt::Display for Status {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Status::Pass => "PASS",
            Status::Deviation => "DEVIATION",
            Status::Observation => "OBSERVATION",
            Status::Skip => "SKIP",
            Status::Error => "ERROR",
        })
    }
}

/// One request and its answer, as a report shows it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExchangeRecord {
    /// The request as sent.
    pub request: Vec<u8>,
    /// The reply the model predicts, where it is known to the byte.
    pub expected: Option<Vec<u8>>,
    /// Everything received.
    pub received: Vec<u8>,
    /// The reply frame found in it.
    pub reply: Option<Vec<u8>>,
    /// The model's prediction, in words.
    pub predicted: String,
    /// The reply, decoded.
    pub actual: String,
    /// Time to the first byte of the reply.
    pub latency: Option<Duration>,
}

/// The result of one check.
#[derive(Debug, Clone)]
pub struct CheckResult {
    /// Stable id, e.g. "rtu.map.group-0.past-end".
    pub id: String,
    /// What the check does.
    pub title: String,
    /// The transmission mode it ran in (None for checks of the whole run).
    pub mode: Option<Mode>,
    /// The manual section it tests.
    pub source: String,
    /// How it ended.
    pub status: Status,
    /// One line: the manual says X, the device did Y.
    pub summary: String,
    /// Every finding, worst first.
    pub findings: Vec<Finding>,
    /// The exchanges.
    pub exchanges: Vec<ExchangeRecord>,
    /// How long it took.
    pub duration: Duration,
    /// The node it is about, in a run of several nodes on one bus (`check --address
    /// 1,2,5`); None in a run of one node and for checks of the whole bus.
    pub node: Option<u8>,
}

impl CheckResult {
    /// The result's key in a report: its id, and `@N` (decimal node address) in a run of
    /// several nodes, where the same check runs once per node.
    pub fn key(&self) -> String {
        match self.node {
            Some(n) => format!("{}@{n}", self.id),
            None => self.id.clone(),
        }
    }
}

/// What a check returns.
#[derive(Debug, Default)]
pub struct Verdict {
    /// Findings; none means PASS.
    pub findings: Vec<Finding>,
    /// Exchanges made.
    pub exchanges: Vec<ExchangeRecord>,
    /// Summary when it passes.
    pub pass_summary: String,
    /// Set when the check did not run.
    pub skip: Option<String>,
    /// Set when the run could not tell.
    pub error: Option<String>,
}

impl Verdict {
    /// A skipped check.
    pub fn skip(reason: impl Into<String>) -> Self {
        Verdict {
            skip: Some(reason.into()),
            ..Verdict::default()
        }
    }

    /// A check the run could not decide.
    pub fn error(reason: impl Into<String>) -> Self {
        Verdict {
            error: Some(reason.into()),
            ..Verdict::default()
        }
    }
}

/// Options of a run.
#[derive(Debug, Clone)]
pub struct Options {
    /// The device's node address.
    pub address: u8,
    /// An address no device on the line has, for the other-node check.
    pub other_address: u8,
    /// Skip every write.
    pub read_only: bool,
    /// Run the checks that set the run or external-fault bit.
    pub allow_motion: bool,
    /// Run only checks whose id matches one of these (substring, or glob with '*').
    pub only: Vec<String>,
    /// Master timing.
    pub timing: MasterTiming,
    /// Allowance over the manual's response time before a reply counts as late.
    pub response_allowance: Duration,
    /// Allowance over t1.5 for gaps inside a reply (host and adapter buffering).
    pub gap_allowance: Duration,
    /// Seed of the arbitrary data the checks send.
    pub seed: u64,
    /// What to do about a local echo of every request.
    pub echo: EchoMode,
    /// The line's settings, for the budget where the link has no timing of its own (a
    /// pseudo-terminal or TCP carries the frames of a line with these settings).
    pub line: Option<crate::codec::timing::LineSettings>,
    /// Send the 08H sub-functions that restart the device's communications (0001H) or
    /// silence it (0004H, Force Listen Only Mode, undone by 0001H).
    pub allow_restart: bool,
    /// Every node this run checks on the bus, in order (`[address]` for a run of one
    /// node). The checks of the whole bus ([`Check::bus`]: broadcasts, another address)
    /// read back from each of them.
    pub bus: Vec<u8>,
    /// For the suite's own tests (the hidden `--inject-host-stall PATTERN:N`): the first
    /// N runs of each check whose id matches PATTERN end as if this host had stalled
    /// while pacing its request, so that running a check again after a stall can be
    /// tested without a busy host. `None` in every real run.
    pub injected_stalls: Option<(String, u32)>,
}

/// How many times a check runs in all when this host stalls under it (it could not put
/// a request on an emulated line whole, or delayed the other end past the timeout):
/// as the master gate does, the check runs again twice before it is an ERROR.
pub const HOST_STALL_RUNS: u32 = 3;

impl Options {
    /// Options for listing a model's checks without running them (the requirements'
    /// traceability): node 1, every kind of check allowed, the default seed.
    pub fn for_listing() -> Options {
        Options {
            address: 1,
            other_address: 0x7F,
            read_only: false,
            allow_motion: true,
            only: Vec::new(),
            timing: MasterTiming {
                timeout: Duration::from_millis(300),
                silence: Duration::from_millis(100),
                derive_silence: true,
                quiet: Duration::from_millis(10),
                gap: Duration::from_millis(1),
                retries: 0,
            },
            response_allowance: Duration::from_millis(20),
            gap_allowance: Duration::from_millis(20),
            seed: 1,
            echo: EchoMode::Off,
            line: None,
            allow_restart: true,
            bus: vec![1],
            injected_stalls: None,
        }
    }
}

/// A register the run changed and restored.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct RestoreRecord {
    /// The node it belongs to, in a run of several nodes (None: the run's one node).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub node: Option<u8>,
    /// Register.
    pub register: u16,
    /// Value before the run changed it.
    pub original: u16,
    /// Whether the read-back after restoring showed the original value.
    pub restored: bool,
    /// Whether the run left it changed: false for a register found holding its original
    /// value at the end (only value-preserving writes, or writes the device refused), which
    /// needed no write back.
    pub changed: bool,
    /// What happened.
    pub detail: String,
}

/// Everything a run of one mode produced.
#[derive(Debug, Clone, Default)]
pub struct ModeRun {
    /// Check results, in order.
    pub results: Vec<CheckResult>,
    /// Registers restored.
    pub restore: Vec<RestoreRecord>,
    /// The identification register's value, if read.
    pub identification: Option<u16>,
    /// Why the run stopped early, if it did.
    pub stopped: Option<String>,
    /// Whether the line echoed requests (None: no exchange told).
    pub echo: Option<bool>,
    /// Where the time went.
    pub budget: ModeBudget,
    /// Whether it stopped because the device stopped answering (not the link, not an
    /// interruption): in a run of several nodes the other nodes are still checked.
    pub lost: bool,
}

/// A mode's wall time against its lower bound on the line.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ModeBudget {
    /// Wall time of the mode, restore included.
    pub wall: Duration,
    /// What the exchanges needed (see [`LineBudget`]).
    pub line: LineBudget,
    /// The line's lower bound for those exchanges (zero where there is none).
    pub bound: Duration,
    /// Why there is no bound, where there is none.
    pub no_bound: Option<NoBound>,
    /// Checks run again because this host stalled under them ([`HOST_STALL_RUNS`]):
    /// their time is in the wall time.
    pub host_reruns: u32,
}

/// Why a link has no line bound to measure a run against.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoBound {
    /// Behind a Modbus TCP gateway the serial line's timing is the gateway's.
    Gateway,
    /// A pseudo-terminal (a simulator's `--link`, a socat pair) carries bytes at once,
    /// with no character time.
    Pty,
}

impl NoBound {
    /// Its name in the JSON report.
    pub fn key(self) -> &'static str {
        match self {
            NoBound::Gateway => "gateway",
            NoBound::Pty => "pty",
        }
    }

    /// The one read back from the JSON report.
    pub fn from_key(key: &str) -> Option<NoBound> {
        match key {
            "gateway" => Some(NoBound::Gateway),
            "pty" => Some(NoBound::Pty),
            _ => None,
        }
    }

    /// Why, for people: "no line bound: {reason}".
    pub fn reason(self) -> &'static str {
        match self {
            NoBound::Gateway => {
                "the serial line is behind a gateway, whose timing is not seen from here"
            }
            NoBound::Pty => {
                "a pseudo-terminal has no line timing (bytes cross at once, not at the character time)"
            }
        }
    }

    /// In a table cell.
    pub fn short(self) -> &'static str {
        match self {
            NoBound::Gateway => "none (gateway)",
            NoBound::Pty => "none (pseudo-terminal)",
        }
    }
}

impl ModeBudget {
    /// Bound over wall time (1.0: no time beyond what the line and the device need).
    pub fn efficiency(&self) -> f64 {
        if self.wall.is_zero() {
            return 0.0;
        }
        self.bound.as_secs_f64() / self.wall.as_secs_f64()
    }
}

/// State shared by the checks of one mode.
pub struct Ctx<'a> {
    /// The model.
    pub model: &'a DriveModel,
    /// The model's golden vectors (for the example checks).
    pub vectors: Option<&'a VectorFile>,
    /// The mode.
    pub mode: Mode,
    /// Options.
    pub opts: &'a Options,
    master: Master<dyn Transport>,
    /// (node, register, original value), in the order journalled.
    journal: Vec<(u8, u16, u16)>,
    /// Latencies of replies, for the response-time check.
    pub latencies: Vec<Duration>,
    /// Gaps inside replies over t1.5 (line timing only): (request hex, gap).
    pub gaps: Vec<(String, Duration)>,
    /// Largest gap seen inside a reply.
    pub max_gap: Duration,
    /// Replies measured for gaps.
    pub gap_replies: usize,
    /// Exception codes the device sent, with the fault the model predicted.
    pub codes_seen: BTreeSet<u8>,
    /// The identification register's value.
    pub identification: Option<u16>,
    /// The id of the check that is running.
    pub current: String,
    /// The last check in which the device sent anything.
    pub answered_in: Option<String>,
    /// Set when the device stopped answering: why.
    pub lost: Option<String>,
    /// Liveness probes sent (after silences).
    pub liveness_probes: usize,
}

/// A probe: one exchange judged by the model.
pub struct Probed {
    /// The model's judgement.
    pub judgement: Judgement,
    /// What happened on the line.
    pub exchange: Exchange,
    /// The comparison.
    pub comparison: judge::Verdict,
    /// The mode of the exchange.
    pub mode: Mode,
    /// Where nothing came back: whether a liveness probe right after was answered
    /// (always true, or the probe would have ended the run with [`RunError::DeviceLost`]).
    pub proven_alive: bool,
}

impl Probed {
    /// The exchange as a report shows it.
    pub fn record(&self) -> ExchangeRecord {
        ExchangeRecord {
            request: self.exchange.request.clone(),
            expected: self.comparison.expected.clone(),
            received: self.exchange.raw.clone(),
            reply: self.exchange.reply.clone(),
            predicted: format!(
                "{} ({}; {})",
                self.judgement.expect.describe(),
                self.judgement.detail,
                self.judgement.basis()
            ),
            actual: self.comparison.actual.clone(),
            latency: self.exchange.first_byte,
        }
    }

    /// Values of a normal 03H reply, if that is what came.
    pub fn read_values(&self) -> Option<Vec<u16>> {
        let reply = self.exchange.reply.as_ref()?;
        let body = judge::body_of(self.mode, reply)?;
        match Message::parse_body(&body, Direction::Response).ok()?.pdu {
            Pdu::ReadResponse { values } => Some(values.iter().collect()),
            _ => None,
        }
    }
}

impl<'a> Ctx<'a> {
    /// A context for `mode` over `transport`.
    pub fn new(
        model: &'a DriveModel,
        vectors: Option<&'a VectorFile>,
        mode: Mode,
        opts: &'a Options,
        transport: Box<dyn Transport>,
    ) -> Self {
        let master = Master::new(transport, mode, opts.timing).with_echo(opts.echo);
        Self::on_master(model, vectors, mode, opts, master)
    }

    /// A context over a master that has talked on this bus already (the echo and the
    /// response time it learnt hold for every node of the bus).
    pub fn on_master(
        model: &'a DriveModel,
        vectors: Option<&'a VectorFile>,
        mode: Mode,
        opts: &'a Options,
        master: Master<dyn Transport>,
    ) -> Self {
        Ctx {
            model,
            vectors,
            mode,
            opts,
            master,
            journal: Vec::new(),
            latencies: Vec::new(),
            gaps: Vec::new(),
            max_gap: Duration::ZERO,
            gap_replies: 0,
            codes_seen: BTreeSet::new(),
            identification: None,
            current: String::new(),
            answered_in: None,
            lost: None,
            liveness_probes: 0,
        }
    }

    /// The master, for a caller that drives the exchanges itself (the fuzzer's brisk
    /// path).
    pub fn master_mut(&mut self) -> &mut Master<dyn Transport> {
        &mut self.master
    }

    /// How long the master listens where no reply is expected: fixed, or derived from
    /// the device's measured response time.
    pub fn silence_window(&self) -> Duration {
        self.master.silence_window()
    }

    /// Whether the line echoes requests, as configured or learnt.
    pub fn echoes(&self) -> Option<bool> {
        self.master.echoes()
    }

    /// The transport's description.
    pub fn link(&self) -> String {
        self.master.transport().describe()
    }

    /// How late the emulated line's paced writes came, where the other end is the
    /// simulator (see [`Transport::peer_lateness`]).
    pub fn peer_lateness(&self) -> Option<Duration> {
        self.master.transport().peer_lateness()
    }

    /// Where the link carries whole valid frames only (a Modbus TCP gateway): why the
    /// line itself cannot be seen (see [`Transport::frames_only`]).
    pub fn frames_only(&self) -> Option<&'static str> {
        self.master.transport().frames_only()
    }

    /// What kind of link the device is on.
    pub fn link_kind(&self) -> crate::transport::LinkKind {
        self.master.transport().kind()
    }

    /// The line settings whose timing the link has.
    pub fn line_timing(&self) -> Option<crate::codec::timing::LineSettings> {
        self.master.transport().line_timing()
    }

    /// The frame of `pdu` addressed to `address`, in this mode.
    pub fn frame_to(&self, address: u8, pdu: Pdu<'_>) -> Vec<u8> {
        Message { address, pdu }
            .to_frame_vec(self.mode)
            .unwrap_or_default()
    }

    /// The frame of `pdu` addressed to the device.
    pub fn frame(&self, pdu: Pdu<'_>) -> Vec<u8> {
        self.frame_to(self.opts.address, pdu)
    }

    /// Sends `frame`, judges it by the model and compares. `known` gives values a read
    /// must return, with the basis of that knowledge.
    pub fn probe(
        &mut self,
        frame: Vec<u8>,
        known: Option<(Vec<Option<u16>>, Fact)>,
    ) -> Result<Probed, RunError> {
        self.probe_at(self.opts.address, frame, known)
    }

    /// [`Ctx::probe`], judged as node `node` would judge it (a check of the whole bus
    /// that reads back from every node).
    pub fn probe_at(
        &mut self,
        node: u8,
        frame: Vec<u8>,
        known: Option<(Vec<Option<u16>>, Fact)>,
    ) -> Result<Probed, RunError> {
        let judgement = self.model.judge(node, self.mode, &frame);
        if let Some(why) = judgement.missing_reason() {
            return Err(RunError::Undescribed(why));
        }
        let (exchange, proven_alive) = self.exchange(&frame, judgement.expect.replies())?;
        let comparison = Judge::new(self.model).verdict_on(
            &judgement,
            &exchange.conversation(self.mode, node),
            known.as_ref().map(|(v, f)| (v.as_slice(), f)),
        );
        if let Some(reply) = &exchange.reply {
            if let Some(t) = exchange.first_byte {
                self.latencies.push(t);
            }
            if let Some(body) = judge::body_of(self.mode, reply) {
                if body.len() == 3 && body[1] & 0x80 != 0 {
                    self.codes_seen.insert(body[2]);
                }
            }
            self.measure_gaps(&exchange);
        }
        Ok(Probed {
            judgement,
            exchange,
            comparison,
            mode: self.mode,
            proven_alive,
        })
    }

    fn measure_gaps(&mut self, ex: &Exchange) {
        let Some(line) = self.line_timing() else {
            return;
        };
        self.gap_replies += 1;
        // t1.5 in RTU; in ASCII up to 1 s may pass between characters.
        let (limit, _) = crate::judge::gap_limit(self.mode, &line, self.opts.gap_allowance);
        let skip = if ex.echo { ex.request.len() } else { 0 };
        let ct = Duration::from_micros(line.char_time_us());
        let mut seen = 0;
        let mut prev: Option<Duration> = None;
        for c in &ex.chunks {
            let m = c.bytes.len();
            for i in 0..m {
                if seen >= skip {
                    // A byte read with k more after it came at least k character times
                    // before the read (the line carries one per character time), and
                    // not sooner than one after the byte before it: a reader that woke
                    // late (a busy host) does not make the gap before its chunk longer
                    // than the line allows.
                    let behind = ct * u32::try_from(m - 1 - i).unwrap_or(u32::MAX);
                    let mut at = c.at.saturating_sub(behind);
                    if let Some(p) = prev {
                        at = at.max(p + ct);
                        // The silence between two characters: their arrivals apart, less
                        // the time of the character itself.
                        let gap = at.saturating_sub(p).saturating_sub(ct);
                        self.max_gap = self.max_gap.max(gap);
                        if gap > limit {
                            self.gaps
                                .push((crate::codec::hex::Hex(&ex.request).to_string(), gap));
                        }
                    }
                    prev = Some(at);
                }
                seen += 1;
            }
        }
    }

    /// Sends bytes that are not a request and waits `pause`.
    pub fn send_raw(&mut self, bytes: &[u8], pause: Duration) -> Result<(), TransportError> {
        self.master.send_raw(bytes, pause)
    }

    /// Reads `count` registers from `start`; the values, or why not.
    pub fn read(
        &mut self,
        start: u16,
        count: u16,
    ) -> Result<Result<Vec<u16>, SetupError>, RunError> {
        self.read_at(self.opts.address, start, count)
    }

    /// [`Ctx::read`] from node `node`.
    pub fn read_at(
        &mut self,
        node: u8,
        start: u16,
        count: u16,
    ) -> Result<Result<Vec<u16>, SetupError>, RunError> {
        let frame = self.frame_to(node, Pdu::ReadRequest { start, count });
        let p = self.probe_at(node, frame, None)?;
        let text = || format!("reading {count} from {start:04X}H: {}", p.comparison.actual);
        Ok(match p.read_values() {
            Some(v) if v.len() == usize::from(count) => Ok(v),
            _ => match exception_code(self.mode, p.exchange.reply.as_ref()) {
                Some(code) => Err(SetupError::Refused {
                    text: text(),
                    code,
                    documented: !matches!(
                        p.judgement.expect,
                        crate::model::Expectation::Exception { .. }
                            | crate::model::Expectation::Silence(_)
                    ),
                    exchange: Some(Box::new(p.record())),
                }),
                None => Err(SetupError::NoAnswer(text())),
            },
        })
    }

    /// Reads `register`'s value before a check changes it, once per run, so that the
    /// restore can put it back.
    pub fn remember(&mut self, register: u16) -> Result<Result<u16, SetupError>, RunError> {
        self.remember_at(self.opts.address, register)
    }

    /// [`Ctx::remember`] on node `node` (a check of the whole bus, whose broadcast write
    /// changes every node).
    pub fn remember_at(
        &mut self,
        node: u8,
        register: u16,
    ) -> Result<Result<u16, SetupError>, RunError> {
        if let Some((_, _, v)) = self
            .journal
            .iter()
            .find(|(n, r, _)| *n == node && *r == register)
        {
            return Ok(Ok(*v));
        }
        // A set-up read is not what a check judges: where no reply came (and the
        // liveness probe showed the device alive), it is sent once more.
        let first = self.read_at(node, register, 1)?;
        let read = match first {
            Err(SetupError::NoAnswer(e)) if e.ends_with("no reply") => {
                self.read_at(node, register, 1)?
            }
            other => other,
        };
        Ok(match read {
            Ok(v) => {
                self.journal.push((node, register, v[0]));
                Ok(v[0])
            }
            Err(e) => Err(e),
        })
    }

    /// The journal: (node, register, value before), in the order journalled; what
    /// [`Ctx::restore`] writes back. `params restore` reports it.
    pub fn journal(&self) -> &[(u8, u16, u16)] {
        &self.journal
    }

    /// The value `register` holds now, journalling it first if no check changed it yet
    /// (so that the restore can put it back).
    pub fn remember_current(&mut self, register: u16) -> Result<Result<u16, SetupError>, RunError> {
        let node = self.opts.address;
        if self
            .journal
            .iter()
            .any(|(n, r, _)| *n == node && *r == register)
        {
            return Ok(self.read(register, 1)?.map(|v| v[0]));
        }
        self.remember(register)
    }

    /// Writes one register and reports whether the device confirmed it (plain, for
    /// set-up and restore).
    pub fn write(&mut self, register: u16, value: u16) -> Result<Result<(), SetupError>, RunError> {
        self.write_at(self.opts.address, register, value)
    }

    /// [`Ctx::write`] to node `node`.
    pub fn write_at(
        &mut self,
        node: u8,
        register: u16,
        value: u16,
    ) -> Result<Result<(), SetupError>, RunError> {
        let frame = self.frame_to(node, Pdu::WriteSingle { register, value });
        let (ex, _) = self.exchange(&frame, true)?;
        Ok(match &ex.reply {
            Some(r) if *r == frame => Ok(()),
            Some(r) => {
                let text = format!(
                    "writing {value:04X} to {register:04X}H: {}",
                    judge::describe_reply(self.mode, r)
                );
                match exception_code(self.mode, Some(r)) {
                    Some(code) => Err(SetupError::Refused {
                        text,
                        code,
                        documented: !matches!(
                            self.model.judge(node, self.mode, &frame).expect,
                            crate::model::Expectation::Exception { .. }
                                | crate::model::Expectation::Silence(_)
                        ),
                        exchange: None,
                    }),
                    // A reply that is no echo and no exception: the device answered
                    // something else; the check's own judgement is not made.
                    None => Err(SetupError::NoAnswer(text)),
                }
            }
            None => Err(SetupError::NoAnswer(format!(
                "writing {value:04X} to {register:04X}H: {}",
                if ex.raw.is_empty() {
                    "no reply".to_string()
                } else {
                    judge::explain_invalid(self.mode, ex.after_echo())
                }
            ))),
        })
    }

    /// Writes back every journalled register, newest first, and verifies by reading.
    /// After the device stopped answering, one liveness probe decides whether to try.
    pub fn restore(&mut self) -> Vec<RestoreRecord> {
        let journal: Vec<(u8, u16, u16)> = self.journal.drain(..).rev().collect();
        // Records name their node in a run of several nodes only.
        let several = self.opts.bus.len() > 1;
        let tag = |n: u8| several.then_some(n);
        let mut out = Vec::new();
        if let Some(why) = self.lost.clone() {
            if !journal.is_empty() && matches!(self.liveness(), Ok(true)) {
                self.lost = None;
            } else {
                for (node, register, original) in journal {
                    out.push(RestoreRecord {
                        node: tag(node),
                        register,
                        original,
                        restored: false,
                        changed: true,
                        detail: format!(
                            "not restored: the device does not answer ({why}); write {original:04X}H back by hand"
                        ),
                    });
                }
                return out;
            }
        }
        for (node, register, original) in journal {
            let record = self.restore_one(node, register, original);
            out.push(RestoreRecord {
                node: tag(node),
                ..record
            });
        }
        out
    }

    /// Puts one register back: reads it, writes `original` where it differs, and reads it
    /// back. A step that got no reply, a damaged one, or that this host could not carry
    /// out (it stalled sending, or delayed the answer past the timeout) is tried again, up
    /// to [`RESTORE_ATTEMPTS`] times in all: writing the original value twice is
    /// harmless, and a register left changed is worse than a second request. A link that
    /// failed ends the attempts at once.
    fn restore_one(&mut self, node: u8, register: u16, original: u16) -> RestoreRecord {
        let rec = |restored, changed, detail: String| RestoreRecord {
            node: None,
            register,
            original,
            restored,
            changed,
            detail,
        };
        let mut written = false;
        let mut last = String::new();
        for attempt in 1..=RESTORE_ATTEMPTS {
            let again = if attempt > 1 {
                format!(" (attempt {attempt} of {RESTORE_ATTEMPTS}; before: {last})")
            } else {
                String::new()
            };
            // A register that holds its original value needs no write (a rejected
            // write, a value-preserving write): say so, and do not write.
            let now = match self.read_at(node, register, 1) {
                Ok(Ok(v)) => v[0],
                Ok(Err(e)) => {
                    last = format!("could not read it to restore it: {e}");
                    continue;
                }
                Err(RunError::HostStalled(e)) => {
                    last = format!("could not read it to restore it: {e}");
                    continue;
                }
                Err(e) => {
                    return rec(false, true, format!("could not read it to restore it: {e}"));
                }
            };
            if now == original {
                return if written {
                    rec(
                        true,
                        true,
                        format!("restored to {original:04X}H and read back{again}"),
                    )
                } else {
                    rec(
                        true,
                        false,
                        format!(
                            "unchanged, verified: it holds its original value {original:04X}H (only written with the value it held, or the write was refused); nothing to write{again}"
                        ),
                    )
                };
            }
            match self.write_at(node, register, original) {
                Ok(Ok(())) => written = true,
                Ok(Err(e)) => {
                    last = format!("could not write it back: {e}");
                    continue;
                }
                Err(RunError::HostStalled(e)) => {
                    last = format!("could not write it back: {e}");
                    continue;
                }
                Err(e) => return rec(false, true, format!("could not write it back: {e}")),
            }
            match self.read_at(node, register, 1) {
                Ok(Ok(v)) if v[0] == original => {
                    return rec(
                        true,
                        true,
                        format!("restored to {original:04X}H and read back{again}"),
                    );
                }
                Ok(Ok(v)) => {
                    last = format!(
                        "written back, but it reads {:04X}H, not {original:04X}H",
                        v[0]
                    );
                }
                Ok(Err(e)) => last = format!("written back, but the read-back failed: {e}"),
                Err(RunError::HostStalled(e)) => {
                    last = format!("written back, but the read-back failed: {e}")
                }
                Err(e) => {
                    return rec(
                        false,
                        true,
                        format!("written back, but the read-back failed: {e}"),
                    )
                }
            }
        }
        rec(
            false,
            true,
            format!("{last} ({RESTORE_ATTEMPTS} attempts; write {original:04X}H back by hand)"),
        )
    }
}
