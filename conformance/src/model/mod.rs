//! Drive models: each manual as data (`vectors/models/<model>.json`), checked on load, and
//! the rules that say how a drive of that model answers a request ([`DriveModel::judge`]).
//!
//! The simulator and the runner read the same model: the simulator to answer, the runner
//! to predict. Every fact carries its [`Basis`]: where the manual is silent or contradicts
//! itself, the model records a *decision* and says why, and the runner reports a device
//! that differs from a decision as an observation, not a deviation.

mod file;
mod judge;

use std::collections::BTreeMap;
use std::fmt;
use std::ops::RangeInclusive;

use serde::{Deserialize, Serialize};

pub use file::ModelFile;
pub use judge::{Expectation, Judgement, ReadPlan, WritePlan};

pub use crate::codec::{frame_len, read_response_len, write_request_len};

use crate::codec::Mode;

/// The models, in the order reports list them.
pub const MODELS: [&str; 5] = ["f510", "a510", "l510", "e510", "l510-legacy"];

/// The model files as built into the binary.
const BUILTIN: [(&str, &str); 5] = [
    ("f510", include_str!("../../../vectors/models/f510.json")),
    ("a510", include_str!("../../../vectors/models/a510.json")),
    ("l510", include_str!("../../../vectors/models/l510.json")),
    ("e510", include_str!("../../../vectors/models/e510.json")),
    (
        "l510-legacy",
        include_str!("../../../vectors/models/l510-legacy.json"),
    ),
];

/// How a fact of a model is known.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Basis {
    /// The manual states it.
    Documented,
    /// It follows from documented facts by a stated rule.
    Derived,
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
    fn from_file(f: &file::FactFile) -> Self {
        Fact {
            basis: f.basis,
            source: f.source.clone(),
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

/// How a register may be accessed.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Access {
    /// Read and write.
    ReadWrite,
    /// Read only (monitor registers, and parameters a table marks read-only).
    ReadOnly,
    /// Reserved: reads answer 0000H, writes get the reserved-write exception.
    Reserved,
    /// Marked "-" in the parameter table: no Modbus access.
    NoAccess,
}

impl Access {
    fn parse(s: &str) -> Option<Self> {
        match s {
            "read-write" => Some(Access::ReadWrite),
            "read-only" => Some(Access::ReadOnly),
            "reserved" => Some(Access::Reserved),
            _ => None,
        }
    }
}

impl fmt::Display for Access {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Access::ReadWrite => "read-write",
            Access::ReadOnly => "read-only",
            Access::Reserved => "reserved",
            Access::NoAccess => "no access",
        })
    }
}

/// What the simulator does with a register.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Role {
    /// 2501H: run, direction, external fault, fault reset.
    Operation,
    /// 2502H: frequency command.
    FrequencyCommand,
    /// 2510H: high word of the two-word register 12-00.
    TwoWordHigh,
    /// 2511H: low word of the two-word register 12-00.
    TwoWordLow,
    /// 2520H: state bits.
    Status,
    /// 2521H: fault code.
    FaultCode,
    /// 2523H: the frequency command, as the drive sees it.
    FrequencyCommandMonitor,
    /// 2524H: output frequency.
    OutputFrequency,
    /// 252FH: identification.
    Identification,
}

impl Role {
    fn parse(s: &str) -> Option<Self> {
        Some(match s {
            "operation" => Role::Operation,
            "frequency-command" => Role::FrequencyCommand,
            "two-word-high" => Role::TwoWordHigh,
            "two-word-low" => Role::TwoWordLow,
            "status" => Role::Status,
            "fault-code" => Role::FaultCode,
            "frequency-command-monitor" => Role::FrequencyCommandMonitor,
            "output-frequency" => Role::OutputFrequency,
            "identification" => Role::Identification,
            _ => return None,
        })
    }
}

/// Bits of the operation (2501H) and status (2520H) registers that the simulator drives.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct BitRoles {
    /// 2501H: run.
    pub run: Option<u8>,
    /// 2501H: reverse.
    pub reverse: Option<u8>,
    /// 2501H: external fault.
    pub external_fault: Option<u8>,
    /// 2501H: fault reset.
    pub fault_reset: Option<u8>,
    /// 2520H: running.
    pub running: Option<u8>,
    /// 2520H: reverse.
    pub status_reverse: Option<u8>,
    /// 2520H: ready.
    pub ready: Option<u8>,
    /// 2520H: fault.
    pub fault: Option<u8>,
}

/// A named command or monitor register.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NamedRegister {
    /// Register number.
    pub register: u16,
    /// Meaning as printed.
    pub name: String,
    /// Access.
    pub access: Access,
    /// What the simulator does with it.
    pub role: Option<Role>,
    /// Largest value accepted, with its basis.
    pub max: Option<(u16, Fact)>,
    /// Lines of the manual's text extraction the maximum comes from.
    pub max_lines: Option<String>,
    /// Rows that contradict the maximum, and which one the model takes.
    pub max_notes: Vec<String>,
    /// A coarser resolution above some value (the A510's 0.1 Hz over 300 Hz).
    pub resolution: Option<Resolution>,
    /// Basis: documented, or the model's decision for registers it adds.
    pub fact: Fact,
}

/// A coarser resolution of a register above a value: the A510's "If the maximum output
/// frequency of the motor is over 300Hz the frequency resolution is 0.1Hz".
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Resolution {
    /// Values over this one have the coarser resolution.
    pub above: u16,
    /// The step in the register's units (10: 0.1 Hz in a 0.01 Hz register).
    pub step: u16,
    /// Basis of the resolution.
    pub fact: Fact,
    /// Lines of the manual's text extraction it comes from.
    pub lines: Option<String>,
    /// What a drive of the model does with a value that is not a whole step.
    pub handling: Fact,
}

impl Resolution {
    /// The value as the drive uses it: over `above`, the part below one step is dropped.
    pub fn apply(&self, value: u16) -> u16 {
        if value > self.above && self.step > 1 {
            value - value % self.step
        } else {
            value
        }
    }
}

/// Parameter registers that a table of the document marks read-only.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReadOnlyParameter {
    /// The registers.
    pub registers: RangeInclusive<u16>,
    /// The same as parameter numbers, as printed ("12-16..12-18").
    pub parameters: String,
    /// Basis and citation.
    pub fact: Fact,
    /// Lines of the manual's text extraction it comes from.
    pub lines: Option<String>,
}

/// Which table a register comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Origin {
    /// Command or monitor table.
    Named,
    /// Parameter table.
    Parameter,
    /// Used only by an example of the manual.
    Example,
}

/// Where a register sits in the map.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RegisterInfo {
    /// The register as the map knows it (after resolving an alias).
    pub register: u16,
    /// Access.
    pub access: Access,
    /// Group index (see [`DriveModel::group_name`]).
    pub group: usize,
    /// Which table.
    pub origin: Origin,
    /// Whether the request used an alias spelling.
    pub via_alias: bool,
}

/// A register group: the command block, the monitor block, a parameter group, or an
/// example-only register.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Group {
    /// Name ("command", "monitor", "group 3", "example 0123").
    pub name: String,
    /// Parameter group number, for parameter groups.
    pub parameter_group: Option<u8>,
    /// First and last register of the group.
    pub span: RangeInclusive<u16>,
    /// Accessible registers, as ranges.
    pub registers: Vec<RangeInclusive<u16>>,
    /// Registers marked "-".
    pub no_access: Vec<RangeInclusive<u16>>,
    /// Where the group is documented.
    pub source: String,
    /// Remarks (misprints, repeats).
    pub notes: Vec<String>,
}

/// A limit per transmission mode.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PerMode {
    /// RTU.
    pub rtu: u16,
    /// ASCII.
    pub ascii: u16,
    /// Basis.
    pub fact: Fact,
}

impl PerMode {
    /// The limit in `mode`.
    pub fn get(&self, mode: Mode) -> u16 {
        match mode {
            Mode::Rtu => self.rtu,
            Mode::Ascii => self.ascii,
        }
    }
}

/// Limits of the model.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Limits {
    /// Longest frame in bytes (RTU) or characters (ASCII).
    pub max_frame: usize,
    /// Basis of the maximum frame.
    pub max_frame_fact: Fact,
    /// Registers per 03H request.
    pub read: PerMode,
    /// Registers per 10H request.
    pub write: PerMode,
    /// Whether one request must stay within one group.
    pub same_group: bool,
    /// Basis of the same-group rule.
    pub same_group_fact: Fact,
    /// Response time in milliseconds.
    pub response_time_ms: u64,
    /// Basis of the response time.
    pub response_time_fact: Fact,
}

/// An exception rule: the code a fault gets, and its basis.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExceptionRule {
    /// Exception code.
    pub code: u8,
    /// Basis.
    pub fact: Fact,
}

/// The identification register.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identification {
    /// Register, if the document has one.
    pub register: Option<u16>,
    /// Documented value.
    pub value: Option<u16>,
    /// What the simulator answers.
    pub simulated: u16,
    /// Basis.
    pub fact: Fact,
}

/// Another spelling of a block of registers.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Alias {
    /// The alias registers.
    pub span: RangeInclusive<u16>,
    /// The register the first alias stands for.
    pub target: u16,
    /// Basis.
    pub fact: Fact,
}

/// Why a model file is not a valid model.
#[derive(Debug, thiserror::Error)]
pub enum ModelError {
    /// Not JSON, or not of the file format.
    #[error("{model}: not a valid model file")]
    Json {
        /// The model or file.
        model: String,
        /// What serde said.
        source: serde_json::Error,
    },
    /// A rule of the format is broken.
    #[error("{model}: {problem}")]
    Invalid {
        /// The model.
        model: String,
        /// What is wrong.
        problem: String,
    },
    /// No such model.
    #[error("unknown model {0:?}; the models are f510, a510, l510, e510, l510-legacy")]
    Unknown(String),
    /// The file could not be read.
    #[error("cannot read {file}")]
    Io {
        /// The file.
        file: String,
        /// The error.
        source: std::io::Error,
    },
}

/// One drive model, checked and indexed.
#[derive(Debug, Clone)]
pub struct DriveModel {
    /// Model id (f510, ...).
    pub id: String,
    /// The document.
    pub title: String,
    /// Short name of the document.
    pub manual: String,
    /// Broadcast address.
    pub broadcast: u8,
    /// Lowest and highest node address.
    pub addresses: RangeInclusive<u8>,
    /// Basis of the addresses.
    pub addresses_fact: Fact,
    /// Function codes served.
    pub functions: Vec<u8>,
    /// Basis of the functions.
    pub functions_fact: Fact,
    /// Data bytes of the manual's loop-back frames.
    pub loop_back_data_bytes: usize,
    /// Basis of the loop-back.
    pub loop_back_fact: Fact,
    /// Basis of the echo of a test code (sub-function) other than 0000H.
    pub loop_back_other_fact: Fact,
    /// The exception-code table.
    pub exception_codes: Vec<(u8, String)>,
    /// Where the table is.
    pub exception_codes_source: String,
    /// Which exception each fault gets.
    pub exceptions: BTreeMap<Fault, ExceptionRule>,
    /// Why requests get no reply.
    pub silence: BTreeMap<SilenceReason, Fact>,
    /// Limits.
    pub limits: Limits,
    /// Groups: command, monitor, parameter groups, example registers.
    pub groups: Vec<Group>,
    /// The command and monitor registers.
    pub named: Vec<NamedRegister>,
    /// Bits the simulator drives.
    pub bits: BitRoles,
    /// Fault code raised by the external-fault bit.
    pub external_fault_code: Option<(u16, Fact)>,
    /// The identification register.
    pub identification: Identification,
    /// Parameter access and values: what the model assumes of parameters that no table
    /// marks.
    pub parameter_access: Fact,
    /// Parameters a table of the document marks read-only (see
    /// [`DriveModel::read_only_parameters`]).
    pub parameter_read_only: Vec<ReadOnlyParameter>,
    /// Example-only registers: register, initial value, access, basis.
    pub example_registers: Vec<(u16, u16, Access, Fact)>,
    /// Values the simulator starts with.
    pub initial_values: Vec<(u16, u16, Fact)>,
    /// Alias spellings.
    pub aliases: Vec<Alias>,
    /// Sorted, non-overlapping spans of the map: (range, access, group, origin).
    map: Vec<(RangeInclusive<u16>, Access, usize, Origin)>,
}

fn hex16(model: &str, what: &str, s: &str) -> Result<u16, ModelError> {
    if s.len() == 4
        && s.bytes()
            .all(|c| c.is_ascii_digit() || (b'A'..=b'F').contains(&c))
    {
        if let Ok(v) = u16::from_str_radix(s, 16) {
            return Ok(v);
        }
    }
    Err(ModelError::Invalid {
        model: model.to_string(),
        problem: format!("{what}: {s:?} is not four upper-case hex digits"),
    })
}

fn hex8(model: &str, what: &str, s: &str) -> Result<u8, ModelError> {
    if s.len() == 2
        && s.bytes()
            .all(|c| c.is_ascii_digit() || (b'A'..=b'F').contains(&c))
    {
        if let Ok(v) = u8::from_str_radix(s, 16) {
            return Ok(v);
        }
    }
    Err(ModelError::Invalid {
        model: model.to_string(),
        problem: format!("{what}: {s:?} is not two upper-case hex digits"),
    })
}

fn hex_range(model: &str, what: &str, s: &str) -> Result<RangeInclusive<u16>, ModelError> {
    let (a, b) = match s.split_once('-') {
        Some((a, b)) => (hex16(model, what, a)?, hex16(model, what, b)?),
        None => {
            let a = hex16(model, what, s)?;
            (a, a)
        }
    };
    if a > b {
        return Err(ModelError::Invalid {
            model: model.to_string(),
            problem: format!("{what}: range {s} runs backwards"),
        });
    }
    Ok(a..=b)
}

impl DriveModel {
    /// How long the drive takes to answer on `line`: the manual's response time, but never
    /// less than t3.5 of the line plus one character time, because a reply that starts
    /// sooner than t3.5 would run into the request it answers (Modbus over Serial Line
    /// V1.02, 2.5.1.1: frames are separated by at least 3.5 character times), and a
    /// master's clock reads the end of its request a little late. At 4800 baud and
    /// below (8E1) that is longer than the manuals' 10 ms: 18.3 ms at 2400 baud, 41.3 ms
    /// at 1200.
    pub fn response_delay(&self, line: &crate::codec::timing::LineSettings) -> std::time::Duration {
        let manual = std::time::Duration::from_millis(self.limits.response_time_ms);
        manual.max(std::time::Duration::from_micros(
            line.t3_5_us() + line.char_time_us(),
        ))
    }

    /// The shortest response time a device can keep on `line`: the manual's, or t3.5
    /// where that is longer (a reply must not start before t3.5).
    pub fn response_time_on(
        &self,
        line: Option<&crate::codec::timing::LineSettings>,
    ) -> std::time::Duration {
        let manual = std::time::Duration::from_millis(self.limits.response_time_ms);
        match line {
            Some(l) => manual.max(std::time::Duration::from_micros(l.t3_5_us())),
            None => manual,
        }
    }

    /// The built-in model `id` (f510, a510, l510, e510, l510-legacy).
    pub fn builtin(id: &str) -> Result<Self, ModelError> {
        let text = BUILTIN
            .iter()
            .find(|(m, _)| *m == id)
            .map(|(_, t)| *t)
            .ok_or_else(|| ModelError::Unknown(id.to_string()))?;
        Self::from_json(id, text)
    }

    /// The model files as built in: (model, JSON text).
    pub fn builtin_files() -> &'static [(&'static str, &'static str)] {
        &BUILTIN
    }

    /// Reads a model file from disk.
    pub fn from_path(path: &std::path::Path) -> Result<Self, ModelError> {
        let text = std::fs::read_to_string(path).map_err(|source| ModelError::Io {
            file: path.display().to_string(),
            source,
        })?;
        Self::from_json(&path.display().to_string(), &text)
    }

    /// Parses and checks a model file's text; `name` names it in errors.
    pub fn from_json(name: &str, text: &str) -> Result<Self, ModelError> {
        let file: ModelFile = serde_json::from_str(text).map_err(|source| ModelError::Json {
            model: name.to_string(),
            source,
        })?;
        Self::from_file(&file)
    }

    /// Checks a parsed model file and builds the model.
    pub fn from_file(f: &ModelFile) -> Result<Self, ModelError> {
        let m = f.model.as_str();
        let invalid = |problem: String| ModelError::Invalid {
            model: m.to_string(),
            problem,
        };
        if f.schema_version != 1 {
            return Err(invalid(format!(
                "schema_version {} is not supported (1 is)",
                f.schema_version
            )));
        }
        if f.modes != ["rtu", "ascii"] {
            return Err(invalid(format!(
                "modes must be [\"rtu\", \"ascii\"], found {:?}",
                f.modes
            )));
        }
        let broadcast = hex8(m, "addresses.broadcast", &f.addresses.broadcast)?;
        let first = hex8(m, "addresses.first", &f.addresses.first)?;
        let last = hex8(m, "addresses.last", &f.addresses.last)?;
        if broadcast != 0 || first == 0 || first > last {
            return Err(invalid(format!(
                "addresses: broadcast must be 00 and 01 <= first <= last, found {broadcast:02X} {first:02X}..{last:02X}"
            )));
        }
        let functions = f
            .functions
            .codes
            .iter()
            .map(|c| hex8(m, "functions.codes", c))
            .collect::<Result<Vec<_>, _>>()?;
        let mut exception_codes = Vec::new();
        for e in &f.exception_codes {
            exception_codes.push((hex8(m, "exception_codes", &e.code)?, e.meaning.clone()));
        }
        let mut exceptions = BTreeMap::new();
        for fault in Fault::ALL {
            match f.exceptions.get(fault.key()) {
                Some(rule) => {
                    let code = hex8(m, "exceptions", &rule.code)?;
                    if !exception_codes.iter().any(|(c, _)| *c == code) {
                        return Err(invalid(format!(
                            "exceptions.{}: code {code:02X} is not in the exception-code table",
                            fault.key()
                        )));
                    }
                    check_fact(m, &format!("exceptions.{}", fault.key()), &rule.fact)?;
                    exceptions.insert(
                        fault,
                        ExceptionRule {
                            code,
                            fact: Fact::from_file(&rule.fact),
                        },
                    );
                }
                None if fault == Fault::NoAccess => {}
                None => return Err(invalid(format!("exceptions: no rule for {}", fault.key()))),
            }
        }
        if let Some(k) = f
            .exceptions
            .keys()
            .find(|k| !Fault::ALL.iter().any(|x| x.key() == k.as_str()))
        {
            return Err(invalid(format!("exceptions: unknown fault kind {k:?}")));
        }
        let mut silence = BTreeMap::new();
        for r in SilenceReason::ALL {
            let fact = f
                .silence
                .get(r.key())
                .ok_or_else(|| invalid(format!("silence: no entry for {}", r.key())))?;
            check_fact(m, &format!("silence.{}", r.key()), fact)?;
            silence.insert(r, Fact::from_file(fact));
        }
        if silence.len() != f.silence.len() {
            return Err(invalid("silence: unknown reason".to_string()));
        }

        let l = &f.limits;
        let limits = Limits {
            max_frame: l.max_frame_bytes.value,
            max_frame_fact: Fact::from_file(&l.max_frame_bytes.fact),
            read: PerMode {
                rtu: l.read_registers.rtu,
                ascii: l.read_registers.ascii,
                fact: Fact::from_file(&l.read_registers.fact),
            },
            write: PerMode {
                rtu: l.write_registers.rtu,
                ascii: l.write_registers.ascii,
                fact: Fact::from_file(&l.write_registers.fact),
            },
            same_group: l.same_group.value,
            same_group_fact: Fact::from_file(&l.same_group.fact),
            response_time_ms: l.response_time_ms.value,
            response_time_fact: Fact::from_file(&l.response_time_ms.fact),
        };
        for (what, fact) in [
            ("limits.max_frame_bytes", &l.max_frame_bytes.fact),
            ("limits.read_registers", &l.read_registers.fact),
            ("limits.write_registers", &l.write_registers.fact),
            ("limits.same_group", &l.same_group.fact),
            ("limits.response_time_ms", &l.response_time_ms.fact),
        ] {
            check_fact(m, what, fact)?;
        }
        // Counts must fit the frame: the derivation the legacy note confirms.
        for mode in [Mode::Rtu, Mode::Ascii] {
            let r = limits.read.get(mode);
            let w = limits.write.get(mode);
            let read_len = read_response_len(mode, r);
            let write_len = write_request_len(mode, w);
            if r == 0 || read_len > limits.max_frame {
                return Err(invalid(format!(
                    "limits.read_registers.{mode}: {r} registers need a {read_len}-byte response, over the {}-byte frame",
                    limits.max_frame
                )));
            }
            if w == 0 || write_len > limits.max_frame {
                return Err(invalid(format!(
                    "limits.write_registers.{mode}: {w} registers need a {write_len}-byte request, over the {}-byte frame",
                    limits.max_frame
                )));
            }
        }

        // Groups: command and monitor first, then parameter groups, then examples.
        let mut groups = Vec::new();
        for g in &f.groups {
            let first = hex16(m, "groups.first", &g.first)?;
            let last = hex16(m, "groups.last", &g.last)?;
            groups.push(Group {
                name: g.name.clone(),
                parameter_group: None,
                span: first..=last,
                registers: vec![],
                no_access: vec![],
                source: String::new(),
                notes: vec![],
            });
        }
        let mut map: Vec<(RangeInclusive<u16>, Access, usize, Origin)> = Vec::new();
        let mut named = Vec::new();
        let mut bits = BitRoles::default();
        let mut external_fault_code = None;
        for r in &f.registers {
            let register = hex16(m, "registers.register", &r.register)?;
            let access = Access::parse(&r.access).ok_or_else(|| {
                invalid(format!(
                    "register {register:04X}: access {:?} is not read-write, read-only or reserved",
                    r.access
                ))
            })?;
            let role = match &r.role {
                Some(s) => Some(Role::parse(s).ok_or_else(|| {
                    invalid(format!("register {register:04X}: unknown role {s:?}"))
                })?),
                None => None,
            };
            let group = groups
                .iter()
                .position(|g| g.span.contains(&register))
                .ok_or_else(|| invalid(format!("register {register:04X} is in no group")))?;
            let fact = match (&r.source, r.basis) {
                (Some(s), None) => Fact::documented(s),
                (source, Some(basis)) => {
                    let ff = file::FactFile {
                        basis,
                        source: source.clone(),
                        rule: None,
                        why: r.why.clone(),
                    };
                    check_fact(m, &format!("register {register:04X}"), &ff)?;
                    Fact::from_file(&ff)
                }
                (None, None) => {
                    return Err(invalid(format!(
                        "register {register:04X}: needs a source or a basis"
                    )))
                }
            };
            let max = match &r.max {
                Some(b) => {
                    check_fact(m, &format!("register {register:04X} max"), &b.fact)?;
                    Some((
                        hex16(m, "registers.max", &b.value)?,
                        Fact::from_file(&b.fact),
                    ))
                }
                None => None,
            };
            let resolution = match &r.resolution {
                Some(res) => {
                    check_fact(m, &format!("register {register:04X} resolution"), &res.fact)?;
                    check_fact(
                        m,
                        &format!("register {register:04X} resolution handling"),
                        &res.handling,
                    )?;
                    if res.step < 2 {
                        return Err(invalid(format!(
                            "register {register:04X}: resolution step {} must be 2 or more",
                            res.step
                        )));
                    }
                    Some(Resolution {
                        above: hex16(m, "registers.resolution.above", &res.above)?,
                        step: res.step,
                        fact: Fact::from_file(&res.fact),
                        lines: res.lines.clone(),
                        handling: Fact::from_file(&res.handling),
                    })
                }
                None => None,
            };
            if (max.is_some() || resolution.is_some()) && access != Access::ReadWrite {
                return Err(invalid(format!(
                    "register {register:04X}: a max or resolution needs a read-write register"
                )));
            }
            if let Some(code) = &r.external_fault_code {
                check_fact(m, "external_fault_code", &code.fact)?;
                external_fault_code = Some((code.value, Fact::from_file(&code.fact)));
            }
            for b in &r.bits {
                if b.bit > 15 {
                    return Err(invalid(format!(
                        "register {register:04X}: bit {} is over 15",
                        b.bit
                    )));
                }
                let slot = match (role, b.role.as_deref()) {
                    (_, None) => continue,
                    (Some(Role::Operation), Some("run")) => &mut bits.run,
                    (Some(Role::Operation), Some("reverse")) => &mut bits.reverse,
                    (Some(Role::Operation), Some("external-fault")) => &mut bits.external_fault,
                    (Some(Role::Operation), Some("fault-reset")) => &mut bits.fault_reset,
                    (Some(Role::Status), Some("running")) => &mut bits.running,
                    (Some(Role::Status), Some("reverse")) => &mut bits.status_reverse,
                    (Some(Role::Status), Some("ready")) => &mut bits.ready,
                    (Some(Role::Status), Some("fault")) => &mut bits.fault,
                    (_, Some(other)) => {
                        return Err(invalid(format!(
                            "register {register:04X}: bit role {other:?} is not known for this register"
                        )))
                    }
                };
                *slot = Some(b.bit);
            }
            map.push((register..=register, access, group, Origin::Named));
            named.push(NamedRegister {
                register,
                name: r.name.clone(),
                access,
                role,
                max,
                max_lines: r.max.as_ref().and_then(|b| b.lines.clone()),
                max_notes: r.max.as_ref().map(|b| b.notes.clone()).unwrap_or_default(),
                resolution,
                fact,
            });
        }
        for g in groups.iter_mut() {
            let regs: Vec<u16> = named
                .iter()
                .filter(|n| g.span.contains(&n.register))
                .map(|n| n.register)
                .collect();
            if regs.len() != g.span.clone().count() {
                return Err(invalid(format!(
                    "group {}: {} named registers for a span of {} ({:04X}..{:04X}); every register of the block must be listed",
                    g.name,
                    regs.len(),
                    g.span.clone().count(),
                    g.span.start(),
                    g.span.end()
                )));
            }
            g.registers = vec![g.span.clone()];
            g.source = named
                .iter()
                .find(|n| n.register == *g.span.start())
                .and_then(|n| n.fact.source.clone())
                .unwrap_or_default();
        }
        for p in &f.parameter_groups {
            let idx = groups.len();
            let mut registers = Vec::new();
            for r in &p.registers {
                registers.push(hex_range(m, "parameter_groups.registers", r)?);
            }
            let mut no_access = Vec::new();
            for r in &p.no_access {
                no_access.push(hex_range(m, "parameter_groups.no_access", r)?);
            }
            for r in registers.iter().chain(&no_access) {
                if (*r.start() >> 8) as u8 != p.group || (*r.end() >> 8) as u8 != p.group {
                    return Err(invalid(format!(
                        "parameter group {}: {:04X}..{:04X} is outside the group (register = group x 100H + number)",
                        p.group,
                        r.start(),
                        r.end()
                    )));
                }
            }
            for r in &registers {
                map.push((r.clone(), Access::ReadWrite, idx, Origin::Parameter));
            }
            for r in &no_access {
                map.push((r.clone(), Access::NoAccess, idx, Origin::Parameter));
            }
            let lo = registers.iter().chain(&no_access).map(|r| *r.start()).min();
            let hi = registers.iter().chain(&no_access).map(|r| *r.end()).max();
            let (Some(lo), Some(hi)) = (lo, hi) else {
                return Err(invalid(format!(
                    "parameter group {}: no registers",
                    p.group
                )));
            };
            groups.push(Group {
                name: format!("group {}", p.group),
                parameter_group: Some(p.group),
                span: lo..=hi,
                registers,
                no_access,
                source: p.source.clone(),
                notes: p.notes.clone(),
            });
        }
        let mut example_registers = Vec::new();
        for e in &f.example_registers {
            let register = hex16(m, "example_registers.register", &e.register)?;
            let initial = hex16(m, "example_registers.initial", &e.initial)?;
            let access = Access::parse(&e.access)
                .filter(|a| matches!(a, Access::ReadWrite | Access::ReadOnly))
                .ok_or_else(|| {
                    invalid(format!(
                        "example register {register:04X}: access must be read-write or read-only"
                    ))
                })?;
            check_fact(m, "example_registers", &e.fact)?;
            let idx = groups.len();
            groups.push(Group {
                name: format!("example {register:04X}"),
                parameter_group: None,
                span: register..=register,
                registers: vec![register..=register],
                no_access: vec![],
                source: e.fact.citation_text(),
                notes: vec![],
            });
            map.push((register..=register, access, idx, Origin::Example));
            example_registers.push((register, initial, access, Fact::from_file(&e.fact)));
        }
        map.sort_by_key(|(r, ..)| *r.start());
        for w in map.windows(2) {
            if w[0].0.end() >= w[1].0.start() {
                return Err(invalid(format!(
                    "registers {:04X}..{:04X} and {:04X}..{:04X} overlap",
                    w[0].0.start(),
                    w[0].0.end(),
                    w[1].0.start(),
                    w[1].0.end()
                )));
            }
        }
        let mut aliases = Vec::new();
        for a in &f.aliases {
            let first = hex16(m, "aliases.first", &a.first)?;
            let last = hex16(m, "aliases.last", &a.last)?;
            let target = hex16(m, "aliases.target", &a.target)?;
            check_fact(m, "aliases", &a.fact)?;
            if first > last || u32::from(target) + u32::from(last - first) > 0xFFFF {
                return Err(invalid(format!(
                    "alias {first:04X}..{last:04X} -> {target:04X} is out of range"
                )));
            }
            aliases.push(Alias {
                span: first..=last,
                target,
                fact: Fact::from_file(&a.fact),
            });
        }
        let id = &f.identification;
        check_fact(m, "identification", &id.fact)?;
        let identification = Identification {
            register: id
                .register
                .as_deref()
                .map(|r| hex16(m, "identification.register", r))
                .transpose()?,
            value: id
                .value
                .as_deref()
                .map(|r| hex16(m, "identification.value", r))
                .transpose()?,
            simulated: match (&id.value, &id.simulated) {
                (Some(v), _) | (None, Some(v)) => hex16(m, "identification", v)?,
                (None, None) => 0,
            },
            fact: Fact::from_file(&id.fact),
        };
        let mut initial_values = Vec::new();
        for v in &f.initial_values {
            check_fact(m, "initial_values", &v.fact)?;
            initial_values.push((
                hex16(m, "initial_values.register", &v.register)?,
                hex16(m, "initial_values.value", &v.value)?,
                Fact::from_file(&v.fact),
            ));
        }
        check_fact(m, "parameter_access", &f.parameter_access.fact)?;
        check_fact(m, "addresses", &f.addresses.fact)?;
        check_fact(m, "functions", &f.functions.fact)?;
        check_fact(m, "loop_back", &f.loop_back.fact)?;
        check_fact(
            m,
            "loop_back.other_test_codes",
            &f.loop_back.other_test_codes,
        )?;

        let mut model = DriveModel {
            id: f.model.clone(),
            title: f.title.clone(),
            manual: f.manual.clone(),
            broadcast,
            addresses: first..=last,
            addresses_fact: Fact::from_file(&f.addresses.fact),
            functions,
            functions_fact: Fact::from_file(&f.functions.fact),
            loop_back_data_bytes: f.loop_back.data_bytes,
            loop_back_fact: Fact::from_file(&f.loop_back.fact),
            loop_back_other_fact: Fact::from_file(&f.loop_back.other_test_codes),
            exception_codes,
            exception_codes_source: f.exception_codes_source.clone(),
            exceptions,
            silence,
            limits,
            groups,
            named,
            bits,
            external_fault_code,
            identification,
            parameter_access: Fact::from_file(&f.parameter_access.fact),
            parameter_read_only: Vec::new(),
            example_registers,
            initial_values,
            aliases,
            map,
        };
        model.parameter_read_only = read_only_parameters(&model, &f.parameter_access.read_only)?;
        for (r, ..) in &model.initial_values {
            if model.lookup(*r).is_none() {
                return Err(invalid(format!(
                    "initial value for {r:04X}, which is not in the map"
                )));
            }
        }
        if let Some(r) = model.identification.register {
            if model.lookup(r).is_none() {
                return Err(invalid(format!(
                    "identification register {r:04X} is not in the map"
                )));
            }
        }
        Ok(model)
    }

    /// Where `register` sits in the map, resolving alias spellings; `None` if the model
    /// does not know it.
    pub fn lookup(&self, register: u16) -> Option<RegisterInfo> {
        let (register, via_alias) = match self.aliases.iter().find(|a| a.span.contains(&register)) {
            Some(a) => (a.target + (register - a.span.start()), true),
            None => (register, false),
        };
        let i = self.map.partition_point(|(r, ..)| *r.end() < register);
        let (r, access, group, origin) = self.map.get(i)?;
        let access = match (origin, access) {
            (Origin::Parameter, Access::ReadWrite)
                if self.read_only_parameter(register).is_some() =>
            {
                Access::ReadOnly
            }
            _ => *access,
        };
        r.contains(&register).then_some(RegisterInfo {
            register,
            access,
            group: *group,
            origin: *origin,
            via_alias,
        })
    }

    /// The parameter registers a table of the document marks read-only, one by one, each
    /// with its fact (basis and citation). A write to one gets the `read-only` exception
    /// rule; reads are served.
    pub fn read_only_parameters(&self) -> impl Iterator<Item = (u16, &Fact)> + '_ {
        self.parameter_read_only
            .iter()
            .flat_map(|p| p.registers.clone().map(move |r| (r, &p.fact)))
    }

    /// The read-only entry that covers parameter register `register`, if any.
    pub fn read_only_parameter(&self, register: u16) -> Option<&ReadOnlyParameter> {
        self.parameter_read_only
            .iter()
            .find(|p| p.registers.contains(&register))
    }

    /// The frequency command register, its largest accepted value and that value's fact.
    pub fn frequency_command_max(&self) -> Option<(u16, u16, &Fact)> {
        let r = self.register_with_role(Role::FrequencyCommand)?;
        let (max, fact) = self.named(r)?.max.as_ref()?;
        Some((r, *max, fact))
    }

    /// The frequency command's coarser resolution, if the model has one (A510).
    pub fn frequency_resolution(&self) -> Option<&Resolution> {
        let r = self.register_with_role(Role::FrequencyCommand)?;
        self.named(r)?.resolution.as_ref()
    }

    /// The frequency command `value` as the drive uses it (the frequency command monitor
    /// and the output frequency): `value` itself, or with the resolution applied.
    pub fn frequency_in_use(&self, value: u16) -> u16 {
        self.frequency_resolution()
            .map_or(value, |res| res.apply(value))
    }

    /// The named register `register` (command or monitor table), if any.
    pub fn named(&self, register: u16) -> Option<&NamedRegister> {
        self.named.iter().find(|n| n.register == register)
    }

    /// The register that plays `role`, if the model has one.
    pub fn register_with_role(&self, role: Role) -> Option<u16> {
        self.named
            .iter()
            .find(|n| n.role == Some(role))
            .map(|n| n.register)
    }

    /// The exception rule for `fault`. Models without a rule for "-" registers (only E510
    /// marks them) answer them as unknown registers.
    pub fn rule(&self, fault: Fault) -> &ExceptionRule {
        self.exceptions
            .get(&fault)
            .or_else(|| self.exceptions.get(&Fault::IllegalRegister))
            .expect("validated: every model has an illegal-register rule")
    }

    /// The meaning of exception `code` in this model's table.
    pub fn exception_meaning(&self, code: u8) -> Option<&str> {
        self.exception_codes
            .iter()
            .find(|(c, _)| *c == code)
            .map(|(_, s)| s.as_str())
    }

    /// Whether the model numbers exceptions 51H..55H (the legacy note) rather than 01H..05H.
    pub fn numbers_exceptions_from_51(&self) -> bool {
        self.exception_codes.iter().all(|(c, _)| *c >= 0x51)
    }

    /// Name of group `i`.
    pub fn group_name(&self, i: usize) -> &str {
        self.groups.get(i).map(|g| g.name.as_str()).unwrap_or("?")
    }

    /// The parameter groups.
    pub fn parameter_groups(&self) -> impl Iterator<Item = &Group> {
        self.groups.iter().filter(|g| g.parameter_group.is_some())
    }

    /// The group named `name` (command, monitor).
    pub fn group(&self, name: &str) -> Option<&Group> {
        self.groups.iter().find(|g| g.name == name)
    }

    /// Every register in the map, in order, with its access.
    pub fn registers(&self) -> impl Iterator<Item = (u16, Access)> + '_ {
        self.map
            .iter()
            .flat_map(|(r, a, ..)| r.clone().map(move |x| (x, *a)))
    }
}

impl file::FactFile {
    fn citation_text(&self) -> String {
        Fact::from_file(self).citation()
    }
}

/// "12-16" as (group, number).
fn parameter_number(s: &str) -> Option<(u8, u8)> {
    let (g, n) = s.split_once('-')?;
    let ok = |t: &str| !t.is_empty() && t.len() <= 2 && t.bytes().all(|c| c.is_ascii_digit());
    if !ok(g) || !ok(n) {
        return None;
    }
    Some((g.parse().ok()?, n.parse().ok()?))
}

/// Checks the read-only entries against the map built so far: every register a listed
/// parameter (not "-"), the parameter numbers spelling the same registers, no overlaps.
fn read_only_parameters(
    model: &DriveModel,
    entries: &[file::ReadOnlyParameterFile],
) -> Result<Vec<ReadOnlyParameter>, ModelError> {
    let m = model.id.as_str();
    let invalid = |problem: String| ModelError::Invalid {
        model: m.to_string(),
        problem,
    };
    let mut out: Vec<ReadOnlyParameter> = Vec::new();
    for e in entries {
        let what = format!("parameter_access.read_only {}", e.registers);
        let registers = hex_range(m, "parameter_access.read_only.registers", &e.registers)?;
        check_fact(m, &what, &e.fact)?;
        let (a, b) = match e.parameters.split_once("..") {
            Some((a, b)) => (a, b),
            None => (e.parameters.as_str(), e.parameters.as_str()),
        };
        let spelled = parameter_number(a)
            .zip(parameter_number(b))
            .map(|((ga, na), (gb, nb))| {
                (u16::from(ga) << 8 | u16::from(na))..=(u16::from(gb) << 8 | u16::from(nb))
            });
        if spelled.as_ref() != Some(&registers) {
            return Err(invalid(format!(
                "{what}: parameters {:?} are not registers {:04X}..{:04X} (register = group x 100H + number)",
                e.parameters,
                registers.start(),
                registers.end()
            )));
        }
        for r in registers.clone() {
            let i = model.map.partition_point(|(x, ..)| *x.end() < r);
            match model.map.get(i) {
                Some((x, Access::ReadWrite, _, Origin::Parameter)) if x.contains(&r) => {}
                _ => {
                    return Err(invalid(format!(
                        "{what}: {r:04X}H is not a listed parameter register of the map"
                    )))
                }
            }
        }
        if let Some(o) = out.iter().find(|o| {
            o.registers.start() <= registers.end() && registers.start() <= o.registers.end()
        }) {
            return Err(invalid(format!("{what}: overlaps {}", o.parameters)));
        }
        out.push(ReadOnlyParameter {
            registers,
            parameters: e.parameters.clone(),
            fact: Fact::from_file(&e.fact),
            lines: e.lines.clone(),
        });
    }
    Ok(out)
}

fn check_fact(model: &str, what: &str, f: &file::FactFile) -> Result<(), ModelError> {
    let problem = match f.basis {
        Basis::Documented if f.source.as_deref().unwrap_or("").is_empty() => {
            Some("a documented fact needs a source")
        }
        Basis::Derived if f.rule.as_deref().unwrap_or("").is_empty() => {
            Some("a derived fact needs a rule")
        }
        Basis::Decision if f.why.as_deref().unwrap_or("").is_empty() => {
            Some("a decision needs a why")
        }
        _ => None,
    };
    match problem {
        Some(p) => Err(ModelError::Invalid {
            model: model.to_string(),
            problem: format!("{what}: {p}"),
        }),
        None => Ok(()),
    }
}
