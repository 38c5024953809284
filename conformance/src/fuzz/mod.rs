//! Device fuzzing: malformed and hostile traffic against a real or simulated drive, every
//! answer predicted by the model.
//!
//! A room of its own beside the runner, built from the runner's parts: the cases go
//! through the runner's [`Ctx`](crate::runner::Ctx), so the echo handling, the liveness
//! probes after every silence, the journal of changed registers and the restore at the end
//! are the ones `conformance check` uses.
//!
//! - [`cases`]: the seeded case generator;
//! - [`safety`]: what may be sent to a real drive;
//! - [`campaign`]: the oracle (the model's prediction against the device, liveness
//!   every K cases, hangs and recovery) and the run of one mode;
//! - [`minimize`]: shrinking a finding to the shortest frame or sequence that still
//!   reproduces it, by replaying;
//! - [`brisk`]: the fast path on a link without timing, and the guard that repeats with
//!   full windows whatever late bytes put in doubt;
//! - [`signature`]: what a finding is about (one bug, one entry);
//! - [`report`](self::report): findings grouped by signature, as the suite's report;
//! - [`timing`]: timing damage (a silence inside a frame, frames without t3.5, a frame
//!   split at every position), on links with line timing;
//! - [`steer`]: steering away from a hang the campaign knows, and what hangs cost;
//! - [`storm`]: the storm test, the device's own requests at line rate among other
//!   nodes' traffic and broadcasts.

pub mod brisk;
pub mod campaign;
pub mod cases;
pub mod minimize;
pub mod observe;
pub mod report;
pub mod safety;
pub mod signature;
pub mod state;
pub mod steer;
pub mod storm;
pub mod timing;

use std::time::Duration;

use crate::codec::Mode;
use crate::runner::{ExchangeRecord, RestoreRecord, Severity};

pub use campaign::fuzz_mode;

/// Which writes the fuzzer may send.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum Writes {
    /// None at all.
    None,
    /// Only a value the device just returned for that register, to this device.
    #[default]
    Preserving,
    /// Any value (registers are journalled and restored).
    Any,
}

impl std::str::FromStr for Writes {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "none" => Ok(Writes::None),
            "preserving" => Ok(Writes::Preserving),
            "any" => Ok(Writes::Any),
            _ => Err(format!(
                "unknown write level {s:?}: none, preserving or any"
            )),
        }
    }
}

impl std::fmt::Display for Writes {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Writes::None => "none",
            Writes::Preserving => "preserving",
            Writes::Any => "any",
        })
    }
}

/// The settings of a campaign.
#[derive(Debug, Clone)]
pub struct FuzzConfig {
    /// Seed of the cases.
    pub seed: u64,
    /// Cases per mode (None: until the duration ends).
    pub cases: Option<u64>,
    /// Time per mode (None: until the cases are done).
    pub duration: Option<Duration>,
    /// Which writes may be sent.
    pub writes: Writes,
    /// A liveness probe at least every this many cases (besides the one after every
    /// silence).
    pub probe_every: u64,
    /// How long to wait for a device that stopped answering to come back.
    pub recover_wait: Duration,
    /// Shrink findings by replaying.
    pub minimize: bool,
    /// The start of the command line that replays a reproducer (`conformance send ...`),
    /// to which the frames in hex are appended.
    pub replay: String,
    /// Run the storm test instead of the cases (see [`storm`]).
    pub storm: Option<storm::StormConfig>,
    /// Full windows on every exchange, also on a link without timing (no brisk path;
    /// see [`brisk`]).
    pub full_windows: bool,
}

/// What kind of difference a finding is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Kind {
    /// A reply other than the one the model predicts.
    Mismatch,
    /// A reply where the model predicts silence.
    UnexpectedReply,
    /// No reply where the model predicts one (the device answers the probe after it).
    NoReply,
    /// A read returned another value than the one the device confirmed writing.
    WrongValue,
    /// The device stopped answering (also its liveness probes).
    Hang,
}

impl Kind {
    /// The name in ids and reports.
    pub fn name(self) -> &'static str {
        match self {
            Kind::Mismatch => "mismatch",
            Kind::UnexpectedReply => "unexpected-reply",
            Kind::NoReply => "no-reply",
            Kind::WrongValue => "wrong-value",
            Kind::Hang => "hang",
        }
    }
}

/// One finding (a group of cases with one signature).
#[derive(Debug, Clone)]
pub struct FuzzFinding {
    /// Its kind.
    pub kind: Kind,
    /// The mode.
    pub mode: Mode,
    /// The function code of the (first) frame.
    pub function: u8,
    /// The field of the difference (see [`signature`]).
    pub field: String,
    /// The case classes that found it, with their counts.
    pub classes: std::collections::BTreeMap<&'static str, u64>,
    /// Cases with this signature.
    pub count: u64,
    /// The number of the first case.
    pub first_case: u64,
    /// The frames of the first case, as sent.
    pub frames: Vec<Vec<u8>>,
    /// Whether they were sent back to back.
    pub burst: bool,
    /// For timing damage: how the frames were cut and the silences (after minimizing:
    /// the reproducer's).
    pub timed: Option<timing::Timed>,
    /// The shortest frames found that still reproduce it (empty: not minimized).
    pub minimized: Vec<Vec<u8>>,
    /// Whether the minimized frames were replayed and reproduced it.
    pub reproduced: bool,
    /// Replays made to minimize it.
    pub replays: u32,
    /// What, in words.
    pub text: String,
    /// Deviation (binding facts, hangs) or observation (a decision of the model).
    pub severity: Severity,
    /// The exchange of the first case, where there was one.
    pub exchange: Option<ExchangeRecord>,
    /// For a hang: how long the device took to answer again (None: it did not, within
    /// the recover wait).
    pub recovery: Option<Option<Duration>>,
    /// For a wrong value: the register.
    pub register: Option<u16>,
    /// The command that replays the reproducer.
    pub replay: String,
}

impl FuzzFinding {
    /// The signature that groups cases: mode, kind, function, field of the difference.
    pub fn signature(&self) -> String {
        format!(
            "{}.{}.{:02X}H.{}",
            self.mode,
            self.kind.name(),
            self.function,
            self.field
        )
    }

    /// The case classes that found it, as "class xN, ...".
    pub fn classes_text(&self) -> String {
        self.classes
            .iter()
            .map(|(c, n)| format!("{c} x{n}"))
            .collect::<Vec<_>>()
            .join(", ")
    }
}

/// What the campaign of one mode did.
#[derive(Debug, Clone, Default)]
pub struct ModeOutcome {
    /// The mode.
    pub mode: Option<Mode>,
    /// Findings, grouped by signature, in the order found.
    pub findings: Vec<FuzzFinding>,
    /// Cases sent.
    pub cases: u64,
    /// Cases not sent, by reason.
    pub skipped: std::collections::BTreeMap<&'static str, u64>,
    /// Time the cases took (without minimizing and restoring).
    pub elapsed: Duration,
    /// The time the cases need at least on the line (None: a link without timing).
    pub bound: Option<Duration>,
    /// Liveness probes sent.
    pub probes: usize,
    /// Registers restored at the end.
    pub restore: Vec<RestoreRecord>,
    /// Why it stopped early.
    pub stopped: Option<String>,
    /// Whether the preflight found the device (false: nothing could be fuzzed).
    pub ran: bool,
    /// The preflight's answer, or why it failed.
    pub preflight: String,
    /// Whether the line echoes.
    pub echo: Option<bool>,
    /// The timing damage cases.
    pub timing: timing::TimingStats,
    /// The storm test, where it ran instead of the cases.
    pub storm: Option<storm::StormOutcome>,
    /// What the brisk path did (None: full windows throughout).
    pub brisk: Option<brisk::GuardStats>,
    /// The hangs: their cost, and the known ones steered away from.
    pub hangs: steer::Steering,
    /// Cases sent again because this host stalled under them (it could not put the
    /// request on the emulated line whole): up to [`crate::runner::HOST_STALL_RUNS`]
    /// sends in all before the case counts as not sent.
    pub host_reruns: u64,
}

impl ModeOutcome {
    /// Cases per second.
    pub fn rate(&self) -> f64 {
        self.cases as f64 / self.elapsed.as_secs_f64().max(1e-9)
    }

    /// Cases per second the line allows at most, if it has timing.
    pub fn bound_rate(&self) -> Option<f64> {
        self.bound
            .map(|b| self.cases as f64 / b.as_secs_f64().max(1e-9))
    }
}
