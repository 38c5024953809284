//! `model learn`: a first device description drawn up from the device itself.
//!
//! Reads only, by default: the register map ([`map`]), the functions it serves, the
//! exceptions it answers for an unserved function, a register outside its map and a
//! count over its limit, whether it keeps silent to a broadcast, another node and a bad
//! checksum, its response time, and a register that tells it from the five built-in
//! models ([`probe`]). With `allow_write` it writes one register of each block with the
//! value it just read, and reads it back, to learn whether the block takes writes.
//! Every fact is kept with the request that showed it, and [`draft`] writes them as a
//! description in the format of `vectors/models` (schema_version 2), each marked
//! `basis: observed`.
//!
//! The line settings, mode and node come from [`crate::scan`] before this runs.

pub mod ask;
pub mod draft;
pub mod map;
pub mod probe;

use std::sync::atomic::AtomicBool;
use std::time::Duration;

use crate::codec::Mode;
use crate::transport::TransportError;

use ask::{Answer, Asker, Device, Evidence, Progress};
use map::{MapConfig, MapFound};

/// Why learning stopped before its end.
#[derive(Debug, thiserror::Error)]
pub enum LearnError {
    /// The link failed.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// Ctrl-C, SIGTERM or SIGHUP.
    #[error("interrupted")]
    Interrupted,
    /// The request cap was reached.
    #[error("the request cap ({0} requests) was reached")]
    Budget(u64),
    /// The device stopped answering a read it had answered.
    #[error("the device stopped answering after {after}: the read {request} got {answer}")]
    Gone {
        /// The probe after which it fell silent.
        after: String,
        /// The read that it no longer answered.
        request: String,
        /// What came back instead.
        answer: String,
    },
    /// A request could not be framed (a bug of this suite).
    #[error("cannot frame a request: {0}")]
    Frame(String),
}

/// What to learn, and how far.
#[derive(Debug, Clone)]
pub struct LearnConfig {
    /// The device's node address.
    pub node: u8,
    /// The range searched for the map, and the stride of its samples.
    pub map: MapConfig,
    /// The most requests in all.
    pub max_requests: u64,
    /// Write one register of each block with the value just read (and read it back).
    pub allow_write: bool,
    /// The node address asked for the other-address silence (none has it).
    pub other_address: u8,
}

/// Requests kept back from the map search for the probes that follow it.
pub const PROBE_RESERVE: u64 = 200;

/// A function code tried, and what it drew.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FunctionSeen {
    /// The code.
    pub code: u8,
    /// Served (a reply, or an exception other than the unserved-function one), not
    /// served, or not known (no reply).
    pub served: Option<bool>,
    /// The answer.
    pub answer: Answer,
    /// The exchange.
    pub evidence: Evidence,
}

/// A silence tried: a request the device must not answer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SilenceSeen {
    /// The format's reason: broadcast, other-address, bad-checksum.
    pub reason: &'static str,
    /// Whether nothing came back.
    pub silent: bool,
    /// The exchange.
    pub evidence: Evidence,
}

/// A write of the value just read, to one register of a block.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WriteSeen {
    /// The block's first register (the one written).
    pub register: u16,
    /// The function (06H or 10H).
    pub function: u8,
    /// The answer.
    pub answer: Answer,
    /// Whether the value read back was the value written (None: not read back).
    pub verified: Option<bool>,
    /// The write's exchange.
    pub evidence: Evidence,
}

/// Everything learned, filled in as it goes: an interrupted learn keeps what it had.
#[derive(Debug, Clone)]
pub struct Learned {
    /// The link ("serial /dev/ttyUSB0").
    pub link: String,
    /// The line settings, as the scan found them ("9600 8N1").
    pub line: String,
    /// The mode.
    pub mode: Mode,
    /// The node address.
    pub node: u8,
    /// What the scan heard (its request and reply).
    pub scan: Option<Evidence>,
    /// The range and stride searched.
    pub map_config: MapConfig,
    /// The map.
    pub map: MapFound,
    /// Functions tried.
    pub functions: Vec<FunctionSeen>,
    /// The code of the unserved-function exception, and the exchange that showed it.
    pub illegal_function: Option<(u8, Evidence)>,
    /// The read limit shown beyond the map (a count refused with the count exception
    /// while one less was refused with another code).
    pub read_limit: Option<(u16, Evidence)>,
    /// The exception for a count over the limit, if count 0 drew the same.
    pub illegal_count: Option<(u8, Evidence)>,
    /// Silences tried.
    pub silence: Vec<SilenceSeen>,
    /// Writes tried (with `allow_write`).
    pub writes: Vec<WriteSeen>,
    /// The identification register candidate: register, value, the re-read.
    pub identification: Option<(u16, u16, Evidence)>,
    /// Response times: median, 99th percentile, and the exchange of the latter.
    pub response: Option<(Duration, Duration, Evidence)>,
    /// Replies timed.
    pub timed: usize,
    /// What a reader should know that no field says.
    pub notes: Vec<String>,
    /// Why it stopped early, if it did.
    pub stopped: Option<String>,
    /// Requests in all.
    pub requests: u64,
    /// Time in all (scan not included).
    pub elapsed: Duration,
    /// Whether writes were allowed.
    pub allow_write: bool,
}

impl Learned {
    /// Nothing learned yet about node `node` on `link` (`line`, `mode`).
    pub fn new(link: String, line: String, mode: Mode, node: u8, map_config: MapConfig) -> Self {
        Learned {
            link,
            line,
            mode,
            node,
            scan: None,
            map_config,
            map: MapFound::default(),
            functions: Vec::new(),
            illegal_function: None,
            read_limit: None,
            illegal_count: None,
            silence: Vec::new(),
            writes: Vec::new(),
            identification: None,
            response: None,
            timed: 0,
            notes: Vec::new(),
            stopped: None,
            requests: 0,
            elapsed: Duration::ZERO,
            allow_write: false,
        }
    }
}

/// Learns what `device` (node `cfg.node`) does, into `learned`. An interruption, the
/// request cap or a failed link ends it early: `learned` keeps what was found, its
/// `stopped` says why, and the error is returned.
pub fn learn(
    device: &mut dyn Device,
    cfg: &LearnConfig,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(Progress<'_>),
    learned: &mut Learned,
) -> Result<(), LearnError> {
    learned.allow_write = cfg.allow_write;
    let mut ask = Asker::new(device, cfg.node, stop, cfg.max_requests, progress);
    let result = run(&mut ask, cfg, learned);
    learned.requests = ask.requests();
    learned.elapsed = ask.elapsed();
    let times: Vec<Duration> = ask.latencies().iter().map(|(t, _)| *t).collect();
    learned.timed = times.len();
    if let Some((median, p99)) = ask::median_p99(&times) {
        let ev = ask
            .latencies()
            .iter()
            .find(|(t, _)| *t == p99)
            .map(|(_, e)| e.clone())
            .unwrap_or_default();
        learned.response = Some((median, p99, ev));
    }
    if let Err(e) = &result {
        learned.stopped = Some(e.to_string());
    }
    result
}

fn run(ask: &mut Asker<'_>, cfg: &LearnConfig, learned: &mut Learned) -> Result<(), LearnError> {
    // The map first, under the cap less what the probes need.
    let cap = cfg.max_requests.saturating_sub(PROBE_RESERVE).max(1);
    ask.set_cap(cap);
    let mapped = map::search(ask, cfg.map, &mut learned.map);
    ask.set_cap(cfg.max_requests);
    match mapped {
        Ok(()) => {}
        Err(LearnError::Budget(n)) => learned.notes.push(format!(
            "The map search stopped at its share of the request cap ({n} of {} requests): registers after {} were not searched.",
            cfg.max_requests,
            learned
                .map
                .searched_to
                .map_or("the range's start".to_string(), |r| format!("{r:04X}H"))
        )),
        Err(e) => return Err(e),
    }
    probe::all(ask, cfg, learned)
}

#[cfg(test)]
mod tests;
