//! How a model knows what it says: the [`Basis`] and citation of each fact ([`Fact`]),
//! the kinds of bad request ([`Fault`]) with the exception each gets
//! ([`ExceptionRule`]), and why a request gets no reply ([`SilenceReason`]).

use std::fmt;

use serde::{Deserialize, Serialize};

use super::file;

/// How a fact of a model is known.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Basis {
    /// The manual states it.
    Documented,
    /// It follows from documented facts by a stated rule.
    Derived,
    /// Seen on a device (v2, written by `model learn`): the file gives the request that
    /// showed it. Binding like a documented fact: a device that differs deviates from
    /// its description.
    /// (Declared before `Decision`: a judgement's basis is its weakest fact's, and a
    /// decision is weaker.)
    Observed,
    /// The manual is silent or contradicts itself; the model decides.
    Decision,
}

impl Basis {
    /// Whether a device that differs from this fact deviates from its manual (documented
    /// and derived facts) rather than being observed (decisions).
    pub fn binding(self) -> bool {
        !matches!(self, Basis::Decision)
    }
}

impl fmt::Display for Basis {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Basis::Documented => "documented",
            Basis::Derived => "derived",
            Basis::Decision => "decision",
            Basis::Observed => "observed",
        })
    }
}

/// A fact's basis and citation.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Fact {
    /// Documented, derived or decision.
    pub basis: Basis,
    /// Manual section, with a quote where it helps.
    pub source: Option<String>,
    /// For derived facts: the rule.
    pub rule: Option<String>,
    /// For decisions: what the model does and why.
    pub why: Option<String>,
}

impl Fact {
    pub(super) fn from_file(f: &file::FactFile) -> Self {
        // An observed fact's citation is the exchange that showed it.
        let observed = f.request.as_ref().map(|req| match &f.reply {
            Some(rep) => format!("observed: request {req}, reply {rep}"),
            None => format!("observed: request {req}"),
        });
        Fact {
            basis: f.basis,
            source: match (&f.source, observed) {
                (Some(s), Some(o)) => Some(format!("{s}; {o}")),
                (s, o) => s.clone().or(o),
            },
            rule: f.rule.clone(),
            why: f.why.clone(),
        }
    }

    /// A fact of the Modbus serial-line specification rather than of the manual.
    pub fn documented(source: &str) -> Self {
        Fact {
            basis: Basis::Documented,
            source: Some(source.to_string()),
            rule: None,
            why: None,
        }
    }

    /// The citation in one line: the source, the rule or the reason.
    pub fn citation(&self) -> String {
        let mut parts = Vec::new();
        if let Some(s) = &self.source {
            parts.push(s.clone());
        }
        if let Some(r) = &self.rule {
            parts.push(format!("rule: {r}"));
        }
        if let Some(w) = &self.why {
            parts.push(format!("decision: {w}"));
        }
        parts.join("; ")
    }
}

/// Kinds of bad request, each answered by one exception code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Fault {
    /// A function code the drive does not serve.
    IllegalFunction,
    /// A register that is not in the map.
    IllegalRegister,
    /// A register count of 0 or over the limit.
    IllegalCount,
    /// A value out of the register's range.
    DataOutOfRange,
    /// A write to a read-only register: a monitor register, or a parameter a table marks
    /// read-only.
    ReadOnly,
    /// A write to a reserved register.
    ReservedWrite,
    /// A read or write that spans two register groups.
    CrossesGroup,
    /// A register marked "-" (no Modbus access).
    NoAccess,
    /// A served function whose length or count fields disagree.
    Malformed,
}

impl Fault {
    /// All kinds.
    pub const ALL: [Fault; 9] = [
        Fault::IllegalFunction,
        Fault::IllegalRegister,
        Fault::IllegalCount,
        Fault::DataOutOfRange,
        Fault::ReadOnly,
        Fault::ReservedWrite,
        Fault::CrossesGroup,
        Fault::NoAccess,
        Fault::Malformed,
    ];

    /// The code the Modbus application protocol (V1.1b3, 7) gives this kind of fault,
    /// for a description that states no rule for it.
    pub fn modbus_code(self) -> u8 {
        match self {
            Fault::IllegalFunction => 0x01,
            Fault::IllegalRegister
            | Fault::ReadOnly
            | Fault::ReservedWrite
            | Fault::CrossesGroup
            | Fault::NoAccess => 0x02,
            Fault::IllegalCount | Fault::DataOutOfRange | Fault::Malformed => 0x03,
        }
    }

    /// The key in the model file.
    pub fn key(self) -> &'static str {
        match self {
            Fault::IllegalFunction => "illegal-function",
            Fault::IllegalRegister => "illegal-register",
            Fault::IllegalCount => "illegal-count",
            Fault::DataOutOfRange => "data-out-of-range",
            Fault::ReadOnly => "read-only",
            Fault::ReservedWrite => "reserved-write",
            Fault::CrossesGroup => "crosses-group",
            Fault::NoAccess => "no-access",
            Fault::Malformed => "malformed",
        }
    }
}

impl fmt::Display for Fault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.key())
    }
}

/// Why a request gets no reply.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum SilenceReason {
    /// Sent to address 00H.
    Broadcast,
    /// Sent to another node.
    OtherAddress,
    /// Wrong CRC or LRC.
    BadChecksum,
    /// Longer than the model's maximum frame.
    FrameTooLong,
}

impl SilenceReason {
    /// All reasons.
    pub const ALL: [SilenceReason; 4] = [
        SilenceReason::Broadcast,
        SilenceReason::OtherAddress,
        SilenceReason::BadChecksum,
        SilenceReason::FrameTooLong,
    ];

    /// The key in the model file.
    pub fn key(self) -> &'static str {
        match self {
            SilenceReason::Broadcast => "broadcast",
            SilenceReason::OtherAddress => "other-address",
            SilenceReason::BadChecksum => "bad-checksum",
            SilenceReason::FrameTooLong => "frame-too-long",
        }
    }
}

impl fmt::Display for SilenceReason {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(self.key())
    }
}

/// An exception rule: the code a fault gets, and its basis.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExceptionRule {
    /// Exception code.
    pub code: u8,
    /// Basis.
    pub fact: Fact,
}
