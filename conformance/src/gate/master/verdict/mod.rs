//! The judgement of one operation of the master under test:
//!
//! 1. every request it put on the line, against the manual and the model, through the
//!    monitor's judge of a master's request
//!    ([`crate::monitor::Monitor::judge_master_request`]), with the silence before it
//!    measured on the gate's line (t3.5; a request while the drive was still sending);
//! 2. its retries (how many, how soon) and the wait after a broadcast, against its own
//!    settings;
//! 3. what it reported against what the drive sent for that operation: the values of a
//!    valid reply to one of its own requests, the exception code sent, a failure where
//!    nothing valid came; never values from a frame of an earlier request, another node
//!    or with a wrong checksum (the values are tags: [`super::drive::tags`]);
//! 4. for the read after each fault, the same: it must succeed (recovery).
//!
//! Items 1 and 2 are `requests.rs`, items 3 and 4 `report.rs`.

use std::time::Duration;

use super::drive::{Behaviour, Chunk, Request, Sent};
use super::protocol::{Operation, Reported};
use crate::judge::Severity;

mod report;
mod requests;

pub use report::judge_report;
pub use requests::judge_requests;

/// One finding about the master, with its kind.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct MasterFinding {
    /// The kind ("stale-reply-taken", "no-t3.5", ...).
    pub kind: String,
    /// Deviation or observation.
    pub severity: Severity,
    /// What, with bytes in hex.
    pub text: String,
}

fn dev(kind: &str, text: String) -> MasterFinding {
    MasterFinding {
        kind: kind.to_string(),
        severity: Severity::Deviation,
        text,
    }
}

fn obs(kind: &str, text: String) -> MasterFinding {
    MasterFinding {
        kind: kind.to_string(),
        severity: Severity::Observation,
        text,
    }
}

/// Which operation of a case is judged.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Role {
    /// The operation under the fault.
    Fault,
    /// The normal read after it.
    Recovery,
}

/// What one operation put on the line and got back.
#[derive(Debug)]
pub struct OpRecord<'a> {
    /// The operation.
    pub op: &'a Operation,
    /// What the drive did.
    pub behaviour: &'a Behaviour,
    /// Fault or recovery.
    pub role: Role,
    /// What the master reported.
    pub reported: &'a Reported,
    /// How long the call took.
    pub took: Duration,
    /// The requests the drive received during the call.
    pub requests: &'a [Request],
    /// Every frame the drive sent in the run so far (to look values up).
    pub sent: &'a [Sent],
    /// The whole line log so far.
    pub log: &'a [Chunk],
    /// When the call began (the gate asked the adapter).
    pub called: Duration,
    /// When the call ended (the adapter's answer).
    pub ended: Duration,
    /// When the master's previous operation began: frames for earlier requests sent
    /// since are what a master that does not match replies to requests can take.
    pub recent: Duration,
    /// Whether the line has a line's timing (a pty: t3.5 is judged; TCP: not).
    pub timed: bool,
}

fn ms(d: Duration) -> f64 {
    d.as_secs_f64() * 1000.0
}

#[cfg(test)]
mod tests;
