//! A day of a bus in minutes: a generator of the capture a tap would have made on an RS-485
//! line where a master polls several drives for hours, with rare faults planted at known
//! times, and the truth it knows about that traffic (`conformance capture synth`).
//!
//! The monitor (`monitor --capture-in`) is then held to that truth: its per-node counts
//! must equal the generator's exactly, and it must find every planted fault at its time.
//! A week on a plant's bus is where an unbounded buffer or a counter that drifts would
//! show; this makes such a bus in minutes.
//!
//! The traffic is not uniform:
//! - a poll cycle over the drives: every cycle the status block (2520H x5), every fourth
//!   the monitor block (2526H x8), now and then a frequency command or a run/stop (06H), a
//!   command block (10H), a parameter block (03H of group 0), and rarely a read the drive
//!   answers with an exception (a register the model's map does not have);
//! - now and then a broadcast write, with the master's turnaround delay after it;
//! - the master's silences between requests and between cycles vary, longer at night;
//! - each drive answers after its own delay, with jitter, and now and then slower;
//! - the replies are the simulated drive's ([`crate::sim::Drive`]): values move as the
//!   drives run up and down, as the writes command.
//!
//! Planted faults ([`FaultKind`]): a noise burst in a silence, a collision that garbles a
//! reply (the master waits its timeout and asks again), a drive silent for a minute (each
//! request times out and is asked once more), a master restarting (it stops in the middle
//! of a request, is silent for seconds, then writes its setpoints again and polls from the
//! first drive).
//!
//! The generator streams: the capture is written packet by packet and what it keeps is
//! the drives' state, per-node counters and the list of planted faults (a few per hour).

mod gen;

use std::time::Duration;

use serde::Serialize;

pub use gen::generate;

use crate::codec::timing::LineSettings;

/// What a day of a bus is made of.
#[derive(Debug, Clone)]
pub struct DayConfig {
    /// How long the bus runs.
    pub span: Duration,
    /// The line (its timing: the character time, t3.5).
    pub line: LineSettings,
    /// How many drives, at nodes 1..=drives (1..=32).
    pub drives: u8,
    /// The seed of every choice: the same seed gives the same capture, byte for byte.
    pub seed: u64,
    /// The first packet's time, microseconds since the Unix epoch.
    pub start_unix_us: u64,
}

/// Why a day could not be made.
#[derive(Debug, thiserror::Error)]
pub enum DayError {
    /// The capture could not be written.
    #[error(transparent)]
    Write(#[from] crate::capture::WriteError),
    /// The configuration makes no sense.
    #[error("{0}")]
    Config(String),
}

/// The kinds of planted fault.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "kebab-case")]
pub enum FaultKind {
    /// Bytes on the line in a silence between exchanges, nobody's frame.
    Noise,
    /// A reply garbled by another transmitter at the same time (the wired AND of both).
    Collision,
    /// A drive that answers nothing for a while.
    SilentDrive,
    /// The master stops in the middle of a request and starts again seconds later.
    MasterRestart,
}

/// One planted fault, as it happened.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Fault {
    /// Its kind.
    pub kind: FaultKind,
    /// When its first byte was on the line (the noise, the request whose reply collided,
    /// the cut request), or when the drive went silent: seconds from the first packet.
    pub at_s: f64,
    /// The address the monitor will count it at: the noise's first byte, the node whose
    /// reply collided, the silent node, the node of the cut request.
    pub node: u8,
    /// The bytes on the line (noise, the garbled reply, the cut request), in hex.
    pub bytes: String,
    /// Silent drive: from when it would answer again, seconds from the first packet.
    pub until_s: Option<f64>,
    /// Silent drive: the requests to it that went unanswered.
    pub unanswered: u64,
}

/// Per node, what the bus carried, counted as the monitor defines its statistics
/// ([`crate::monitor::NodeStats`]): the address is the frame's first byte.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct NodeTruth {
    /// Frames that began an exchange (the master's requests, and noise or a cut request
    /// at the address their first byte names).
    pub requests: u64,
    /// Exchanges: each request with its reply or its silence.
    pub exchanges: u64,
    /// Valid replies.
    pub replies: u64,
    /// Requests due a reply that got nothing.
    pub timeouts: u64,
    /// Frames with a wrong CRC: noise, cut requests, garbled replies.
    pub crc_errors: u64,
    /// Requests with the same bytes as the node's request before, which got no reply.
    pub retries: u64,
    /// Replies that were exceptions.
    pub exceptions: u64,
    /// Requests that read a register the model's map does not have (the master's side:
    /// each is one, answered with an exception or not, a retry included).
    pub unmapped_reads: u64,
    /// 06H and 10H requests (broadcasts included).
    pub writes: u64,
}

/// What the generator knows about the day it made (the capture's sidecar JSON).
#[derive(Debug, Clone, Default, Serialize)]
pub struct Truth {
    /// The span asked for, seconds.
    pub span_s: f64,
    /// The line ("115200 8E1").
    pub line: String,
    /// How many drives.
    pub drives: u8,
    /// The seed.
    pub seed: u64,
    /// The drives' model.
    pub model: String,
    /// Packets written.
    pub packets: u64,
    /// Bytes carried (the packets' data).
    pub bytes: u64,
    /// From the first packet to the end of the last, seconds.
    pub heard_s: f64,
    /// Per address (hex) that any frame began with.
    pub nodes: std::collections::BTreeMap<String, NodeTruth>,
    /// The planted faults, in time order.
    pub faults: Vec<Fault>,
}

impl Truth {
    /// The counts of the node at `address`, if any frame named it.
    pub fn node(&self, address: u8) -> Option<&NodeTruth> {
        self.nodes.get(&format!("{address:02X}"))
    }
}

#[cfg(test)]
mod tests;
