//! The register map of a model as data: access, the simulator's roles, named registers,
//! groups, limits, the identification register and alias spellings.

use std::fmt;
use std::ops::RangeInclusive;

use super::Fact;
use crate::codec::Mode;

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
    /// Written, never read (a v2 block): a read gets the illegal-register exception.
    WriteOnly,
}

impl Access {
    pub(super) fn parse(s: &str) -> Option<Self> {
        match s {
            "read-write" => Some(Access::ReadWrite),
            "read-only" => Some(Access::ReadOnly),
            "reserved" => Some(Access::Reserved),
            "write-only" => Some(Access::WriteOnly),
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
            Access::WriteOnly => "write-only",
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
    pub(super) fn parse(s: &str) -> Option<Self> {
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
    /// The bits the table names (the command and status words), lowest first; empty for
    /// a register that is a number.
    pub bits: Vec<NamedBit>,
}

/// One bit of a command or status word, as the table names it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NamedBit {
    /// Bit number, 0 = least significant.
    pub bit: u8,
    /// Meaning as printed ("Inverter ready (1: ready)", "Reserved").
    pub name: String,
}

impl NamedBit {
    /// Whether the table marks the bit reserved: a device that sets it does something
    /// the manual does not describe.
    pub fn reserved(&self) -> bool {
        self.name
            .get(..8)
            .is_some_and(|w| w.eq_ignore_ascii_case("reserved"))
    }
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
    /// A plain block of a v2 description ([`Block`]).
    Block,
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
    /// Response time in milliseconds; `None` where the description does not state one
    /// (the response-time check is skipped, and the master waits its own timeout).
    pub response_time_ms: Option<u64>,
    /// Basis of the response time.
    pub response_time_fact: Option<Fact>,
    /// Longest ASCII frame in characters where it differs from `max_frame` (a v2
    /// description that leaves the frame to the Modbus specification: 256 bytes RTU,
    /// 513 characters ASCII); `None`: `max_frame` holds in both modes.
    pub max_frame_ascii: Option<usize>,
}

impl Limits {
    /// Longest frame in `mode`: bytes (RTU) or characters (ASCII).
    pub fn max_frame_in(&self, mode: Mode) -> usize {
        match (mode, self.max_frame_ascii) {
            (Mode::Ascii, Some(n)) => n,
            _ => self.max_frame,
        }
    }
}

/// A plain block of registers of a v2 description.
#[derive(Debug, Clone, PartialEq)]
pub struct Block {
    /// First and last register.
    pub span: RangeInclusive<u16>,
    /// Name for people, if the description gives one.
    pub name: Option<String>,
    /// Access (a reserved block is in no map: every function refuses it).
    pub access: Access,
    /// Smallest value a write may carry.
    pub min: Option<u16>,
    /// Largest value a write may carry.
    pub max: Option<u16>,
    /// Unit, for display.
    pub unit: Option<String>,
    /// Value = raw x scale, for display.
    pub scale: Option<f64>,
    /// Basis and citation.
    pub fact: Fact,
}

impl Block {
    /// Whether `value` is within the block's bounds.
    pub fn admits(&self, value: u16) -> bool {
        self.min.is_none_or(|m| value >= m) && self.max.is_none_or(|m| value <= m)
    }
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
