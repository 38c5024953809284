//! `conformance watch`: polls named registers of one or more drives with 03H reads only,
//! and judges every poll as it comes.
//!
//! - [`plan`]: the names resolved to registers, and the fewest reads that cover them
//!   within the model's limits.
//! - [`table`]: per node, the last value of each register (changed or not), the counts
//!   of what was observed, a thinned trend per register, the round-trip times; fixed
//!   memory however long the watch runs.
//! - [`Watcher::poll`]: one node's poll. Each reply goes through the one [`judge`]
//!   (timeouts, CRC errors, exceptions, every other finding by its kind); each value is
//!   then held to the model's range and reserved bits (observations, each kind apart).
//! - The table as text, one row per poll as CSV or a JSON line, and the HTML trend
//!   report are the report layer's (`report::watch`, [`crate::report::watch_html`]).
//!
//! It never writes: every request it sends is a 03H read the plan built.
//!
//! [`judge`]: crate::judge

pub mod plan;
pub mod table;

use std::sync::Arc;
use std::time::{Duration, Instant, SystemTime};

use crate::codec::pdu::{Direction, Message, Pdu};
use crate::codec::Mode;
use crate::judge::{body_of, Judge, Kind};
use crate::model::DriveModel;
use crate::runner::Master;
use crate::transport::{Transport, TransportError};

pub use plan::{plan, resolve, PollPlan, Read};
pub use table::{Cell, NodeStats, NodeTable, Trend};

/// Why a watch cannot start.
#[derive(Debug, thiserror::Error)]
pub enum WatchError {
    /// A number that is no register.
    #[error(
        "{0:?} is not a register number: write hex with H or 0x (2520H, 0x2520), or decimal digits"
    )]
    BadNumber(String),
    /// A register the model's map does not have.
    #[error("{name}: register {register:04X}H is not in the model's map{note}")]
    NotInMap {
        /// As given.
        name: String,
        /// The register.
        register: u16,
        /// A hint (a bare number is decimal).
        note: String,
    },
    /// No register, block or group has the name.
    #[error("{name:?}: no register, block or group of {model} is named so (expected a register number such as 2520H, a register's name or its prefix, or a block: monitor, command); `conformance model show --model {model}` lists them")]
    UnknownName {
        /// As given.
        name: String,
        /// The model.
        model: String,
    },
    /// More than one register has the name (or the prefix).
    #[error("{name:?} names {} registers: {}; give one by its number", candidates.len(), candidates.join(", "))]
    Ambiguous {
        /// As given.
        name: String,
        /// "2502H (Frequency command (0.01 Hz))", ...
        candidates: Vec<String>,
    },
    /// The model says a read of the register gets no normal reply.
    #[error("{register} cannot be read: the model says {why}")]
    NotReadable {
        /// The register described.
        register: String,
        /// The model's reason.
        why: String,
    },
    /// The description has neither a monitor block nor a status word.
    #[error("the description {0} has no monitor block, no status word and no read-only block to watch by default: name the registers or blocks to watch")]
    NothingByDefault(String),
    /// A request could not be built.
    #[error("cannot build the read: {0}")]
    Frame(String),
}

/// How one read of a poll ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum ReadEnd {
    /// The values came back.
    Values(Vec<u16>),
    /// Nothing came back.
    Timeout,
    /// Bytes came back, but with a wrong CRC or LRC.
    BadChecksum,
    /// An exception reply, with its code.
    Exception(u8),
    /// Something else came back: the judge's kinds of finding.
    BadReply(Vec<&'static str>),
}

impl ReadEnd {
    /// The read's outcome word and how bad it is (an exception is the worst: the drive
    /// refused a read its manual serves).
    fn outcome(&self) -> (&'static str, u8) {
        match self {
            ReadEnd::Values(_) => ("ok", 0),
            ReadEnd::BadReply(_) => ("bad-reply", 1),
            ReadEnd::BadChecksum => ("bad-checksum", 2),
            ReadEnd::Timeout => ("timeout", 3),
            ReadEnd::Exception(_) => ("exception", 4),
        }
    }
}

/// What one value was observed to do against the model.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Observation {
    /// The value is outside the model's range.
    OutOfRange {
        /// The register.
        register: u16,
        /// The value.
        value: u16,
        /// In words, with the bound and its source.
        text: String,
    },
    /// Bits the model says are reserved are set.
    ReservedBits {
        /// The register.
        register: u16,
        /// The value.
        value: u16,
        /// The reserved bits set.
        bits: Vec<u8>,
    },
}

impl Observation {
    /// The kind as rows and summaries spell it.
    pub fn key(&self) -> &'static str {
        match self {
            Observation::OutOfRange { .. } => "out-of-range",
            Observation::ReservedBits { .. } => "reserved-bit",
        }
    }

    /// In words.
    pub fn text(&self) -> String {
        match self {
            Observation::OutOfRange { text, .. } => text.clone(),
            Observation::ReservedBits {
                register,
                value,
                bits,
            } => format!(
                "{register:04X}H = {value:04X}H sets reserved bit{} {}",
                if bits.len() > 1 { "s" } else { "" },
                bits.iter()
                    .map(|b| b.to_string())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        }
    }
}

/// One node's poll: when, how each read ended, what was observed.
#[derive(Debug, Clone, PartialEq)]
pub struct Poll {
    /// The node.
    pub node: u8,
    /// The poll's number for this node, from 1.
    pub number: u64,
    /// Wall-clock time of its start.
    pub at: SystemTime,
    /// Time since the watch started.
    pub elapsed: Duration,
    /// Round trip: for each read, from the end of the request to the reply's last byte,
    /// added over the node's reads; `None` where a read got no reply.
    pub rtt: Option<Duration>,
    /// How each read of the plan ended, in the plan's order.
    pub reads: Vec<ReadEnd>,
    /// The judge's findings on the replies, in words.
    pub findings: Vec<String>,
    /// What the values were observed to do.
    pub observations: Vec<Observation>,
    /// The watched registers whose value changed in this poll.
    pub changed: Vec<u16>,
}

impl Poll {
    /// "ok", or the worst way a read ended: "timeout", "bad-checksum", "exception",
    /// "bad-reply".
    pub fn outcome(&self) -> &'static str {
        self.reads
            .iter()
            .map(ReadEnd::outcome)
            .max_by_key(|(_, rank)| *rank)
            .map_or("ok", |(word, _)| word)
    }

    /// The exception codes the poll's reads got.
    pub fn exceptions(&self) -> Vec<u8> {
        self.reads
            .iter()
            .filter_map(|r| match r {
                ReadEnd::Exception(c) => Some(*c),
                _ => None,
            })
            .collect()
    }
}

/// A watch: the model, the plan, and one table per node.
#[derive(Debug, Clone)]
pub struct Watcher {
    /// The model the values are judged by.
    pub model: Arc<DriveModel>,
    /// The mode polled in.
    pub mode: Mode,
    /// What is read.
    pub plan: PollPlan,
    /// One table per node, in the order polled.
    pub nodes: Vec<NodeTable>,
    /// The request frames of each node, in the plan's order.
    frames: Vec<Vec<Vec<u8>>>,
    started: Instant,
    /// Wall-clock time of the start.
    pub started_at: SystemTime,
}

impl Watcher {
    /// A watch of `plan` on `nodes` in `mode`, starting now.
    pub fn new(
        model: Arc<DriveModel>,
        mode: Mode,
        plan: PollPlan,
        nodes: &[u8],
    ) -> Result<Self, WatchError> {
        let tables = nodes
            .iter()
            .map(|&n| NodeTable::new(n, &plan.registers))
            .collect();
        let frames = nodes
            .iter()
            .map(|&n| plan.reads.iter().map(|r| r.frame(n, mode)).collect())
            .collect::<Result<_, _>>()?;
        Ok(Watcher {
            model,
            mode,
            plan,
            nodes: tables,
            frames,
            started: Instant::now(),
            started_at: SystemTime::now(),
        })
    }

    /// The request frames node `nodes[index]` is polled with: 03H reads, nothing else.
    pub fn requests(&self, index: usize) -> &[Vec<u8>] {
        &self.frames[index]
    }

    /// Time since the start.
    pub fn elapsed(&self) -> Duration {
        self.started.elapsed()
    }

    /// Polls node `nodes[index]` through `master`: every read of the plan, each judged;
    /// the table and the statistics take the result. An error is the link's (the port
    /// went away): nothing of the poll is counted.
    pub fn poll(
        &mut self,
        index: usize,
        master: &mut Master<dyn Transport>,
    ) -> Result<Poll, TransportError> {
        let model = self.model.clone();
        let mode = self.mode;
        let node = self.nodes[index].node;
        let at = SystemTime::now();
        let elapsed = self.started.elapsed();
        let judge = Judge::new(&model);
        let mut reads = Vec::with_capacity(self.plan.reads.len());
        let mut findings = Vec::new();
        let mut rtt = Some(Duration::ZERO);
        let mut values: Vec<(u16, u16)> = Vec::new();
        for (read, frame) in self.plan.reads.iter().zip(&self.frames[index]) {
            let judgement = model.judge(node, mode, frame);
            let ex = master.exchange(frame, judgement.expect.replies())?;
            let verdict = judge.differences(&judgement, &ex.conversation(mode, node), None);
            for f in &verdict.findings {
                findings.push(f.text.clone());
            }
            rtt = match (rtt, ex.reply.as_ref(), ex.chunks.last()) {
                (Some(sum), Some(_), Some(last)) => Some(sum + last.at),
                _ => None,
            };
            let end = read_end(mode, read, &ex.reply, ex.after_echo(), &verdict.kinds);
            if let ReadEnd::Values(v) = &end {
                values.extend(read.registers().zip(v.iter().copied()));
            }
            reads.push(end);
        }
        let table = &mut self.nodes[index];
        let stats = &mut table.stats;
        stats.polls += 1;
        for r in &reads {
            match r {
                ReadEnd::Values(_) => {}
                ReadEnd::Timeout => stats.timeouts += 1,
                ReadEnd::BadChecksum => stats.crc_errors += 1,
                ReadEnd::Exception(c) => *stats.exceptions.entry(*c).or_default() += 1,
                ReadEnd::BadReply(kinds) => {
                    for k in kinds {
                        *stats.other.entry(k).or_default() += 1;
                    }
                }
            }
        }
        let rtt = rtt.filter(|_| reads.iter().all(|r| matches!(r, ReadEnd::Values(_))));
        if let Some(d) = rtt {
            stats.whole += 1;
            stats.rtt.record(d);
        }
        stats.last_rtt = rtt;
        let t = elapsed.as_secs_f64();
        let mut observations = Vec::new();
        let mut changed = Vec::new();
        for cell in &mut table.cells {
            cell.changed = false;
            let Some(&(_, v)) = values.iter().find(|(r, _)| *r == cell.register) else {
                continue;
            };
            if cell.value.is_some_and(|old| old != v) {
                cell.changed = true;
                cell.changes += 1;
                changed.push(cell.register);
            }
            cell.value = Some(v);
            cell.trend.push(t, v);
            cell.out_of_range = false;
            if let Some(range) = model.range_of(cell.register).filter(|r| !r.admits(v)) {
                cell.out_of_range = true;
                cell.out_of_range_count += 1;
                table.stats.out_of_range += 1;
                observations.push(Observation::OutOfRange {
                    register: cell.register,
                    value: v,
                    text: format!(
                        "{} = {v:04X}H{} is outside {}. Source: {}",
                        model.describe(cell.register),
                        model
                            .value_text(cell.register, v)
                            .map_or(String::new(), |t| format!(" ({t})")),
                        range.bounds(),
                        range.fact.citation()
                    ),
                });
            }
            cell.reserved_bits = model
                .bits_of(cell.register)
                .iter()
                .filter(|b| b.reserved() && v & (1 << b.bit) != 0)
                .map(|b| b.bit)
                .collect();
            if !cell.reserved_bits.is_empty() {
                cell.reserved_count += 1;
                table.stats.reserved_bits += 1;
                observations.push(Observation::ReservedBits {
                    register: cell.register,
                    value: v,
                    bits: cell.reserved_bits.clone(),
                });
            }
        }
        Ok(Poll {
            node,
            number: table.stats.polls,
            at,
            elapsed,
            rtt,
            reads,
            findings,
            observations,
            changed,
        })
    }

    /// Whether an exception or a value out of range was seen (exit 1).
    pub fn found(&self) -> bool {
        self.nodes
            .iter()
            .any(|n| n.stats.exception_count() > 0 || n.stats.out_of_range > 0)
    }
}

/// How a read ended, from what came back and the judge's kinds of finding.
fn read_end(
    mode: Mode,
    read: &Read,
    reply: &Option<Vec<u8>>,
    received: &[u8],
    kinds: &[Kind],
) -> ReadEnd {
    let Some(reply) = reply else {
        if received.is_empty() {
            return ReadEnd::Timeout;
        }
        if kinds.contains(&Kind::BadChecksum) {
            return ReadEnd::BadChecksum;
        }
        return ReadEnd::BadReply(kinds.iter().map(|k| k.key()).collect());
    };
    let parsed = body_of(mode, reply).and_then(|body| {
        Message::parse_body(&body, Direction::Response)
            .ok()
            .map(|m| match m.pdu {
                Pdu::Exception { code, .. } => ReadEnd::Exception(code),
                Pdu::ReadResponse { values } if values.len() == usize::from(read.count) => {
                    ReadEnd::Values(values.iter().collect())
                }
                _ => ReadEnd::BadReply(vec![Kind::WrongReply.key()]),
            })
    });
    parsed.unwrap_or_else(|| {
        ReadEnd::BadReply(if kinds.is_empty() {
            vec![Kind::Malformed.key()]
        } else {
            kinds.iter().map(|k| k.key()).collect()
        })
    })
}
