//! The drive-model files (`vectors/models/<model>.json`) as serde types.
//!
//! These mirror the JSON one to one; [`super::DriveModel::from_file`] checks them and builds
//! the indexed model that the simulator and the runner use.

use std::collections::BTreeMap;

use serde::{Deserialize, Serialize};

use super::Basis;

/// How a fact is known, with its citation.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct FactFile {
    /// Documented, derived or decision.
    pub basis: Basis,
    /// Manual section, with a quote where it helps.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
    /// For derived facts: the rule that derives them.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rule: Option<String>,
    /// For decisions: what the model does and why.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub why: Option<String>,
    /// For observed facts (v2, written by `model learn`): the request frame that showed
    /// the fact, in hex.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub request: Option<String>,
    /// For observed facts: the reply to `request`, in hex.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub reply: Option<String>,
}

/// One model file: schema_version 1 (the five manuals) or 2 (any device; see
/// `vectors/schema/model.schema.json` and the guide's "Describing your own device").
///
/// Version 1 requires every field that is an `Option` or a defaulted collection here;
/// the loader says which one a version 1 file lacks. In version 2 each is optional, and a
/// check whose facts a description leaves out is skipped, naming the field.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ModelFile {
    /// Format version (1 or 2).
    pub schema_version: u32,
    /// Model id: f510, a510, l510, e510, l510-legacy, or a description's own.
    pub model: String,
    /// The document the model is read from.
    pub title: String,
    /// Short name of the document, for citations ("F510 manual"); v2 default: the title.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub manual: Option<String>,
    /// How to read the file.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub notes: Option<String>,
    /// Transmission modes ("rtu", "ascii"): v1 both, v2 any non-empty subset.
    pub modes: Vec<String>,
    /// Node addresses; v2 default: the Modbus serial line's 01..F7, broadcast 00.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub addresses: Option<AddressesFile>,
    /// Function codes served.
    pub functions: FunctionsFile,
    /// The loop-back function.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub loop_back: Option<LoopBackFile>,
    /// The exception-code table, as printed.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exception_codes: Option<Vec<ExceptionCodeFile>>,
    /// Where the table is.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exception_codes_source: Option<String>,
    /// Which exception each kind of bad request gets (key: fault kind).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exceptions: Option<BTreeMap<String, ExceptionRuleFile>>,
    /// Requests that get no reply (key: reason).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub silence: Option<BTreeMap<String, FactFile>>,
    /// Frame, count and timing limits.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub limits: Option<LimitsFile>,
    /// Plain register blocks (v2).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub blocks: Option<Vec<BlockFile>>,
    /// TECO's naming rule, register = group x 100H + number (v2; v1 implies it).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub naming: Option<NamingFile>,
    /// Register groups outside the parameter table (command, monitor).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub groups: Option<Vec<GroupFile>>,
    /// Command and monitor registers, one entry each.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub registers: Option<Vec<RegisterFile>>,
    /// The identification register.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub identification: Option<IdentificationFile>,
    /// Parameter groups from the "Parameter Data" tables.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parameter_groups: Option<Vec<ParameterGroupFile>>,
    /// What the model assumes about parameter access and values, and the parameters
    /// some table of the document marks read-only.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub parameter_access: Option<ParameterAccessFile>,
    /// Registers used by the manual's examples outside its tables.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub example_registers: Option<Vec<ExampleRegisterFile>>,
    /// Values the simulator starts with, other than 0000H.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub initial_values: Option<Vec<InitialValueFile>>,
    /// Other spellings of register blocks (the legacy note's A0xxH).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub aliases: Option<Vec<AliasFile>>,
}

/// A plain block of registers (v2): a range with optional name, access, value bounds,
/// unit and scale.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BlockFile {
    /// First register (hex).
    pub first: String,
    /// Last register (hex).
    pub last: String,
    /// Name for people ("holding", "setpoints").
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub name: Option<String>,
    /// read-write (default), read-only, write-only or reserved.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub access: Option<String>,
    /// Smallest value a write may carry (hex).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub min: Option<String>,
    /// Largest value a write may carry (hex).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<String>,
    /// Unit of the raw value times `scale`, for display.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub unit: Option<String>,
    /// Value = raw x scale, for display.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub scale: Option<f64>,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// TECO's naming rule (v2): register = group x 100H + number.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct NamingFile {
    /// The rule: "group-number".
    pub rule: String,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// Node addresses.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AddressesFile {
    /// Broadcast address (hex).
    pub broadcast: String,
    /// Lowest node address (hex).
    pub first: String,
    /// Highest node address (hex).
    pub last: String,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// Function codes served.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct FunctionsFile {
    /// Codes in hex.
    pub codes: Vec<String>,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// The loop-back function.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct LoopBackFile {
    /// Data bytes after the test code in the manual's frames.
    pub data_bytes: usize,
    /// What a test code (sub-function) other than 0000H gets: the manuals show 0000H
    /// only; the legacy note says any test code is echoed.
    pub other_test_codes: FactFile,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// One row of the exception-code table.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ExceptionCodeFile {
    /// Code in hex.
    pub code: String,
    /// Meaning as printed.
    pub meaning: String,
}

/// The exception a kind of bad request gets.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ExceptionRuleFile {
    /// Code in hex.
    pub code: String,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// Limits.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LimitsFile {
    /// Longest frame, bytes (RTU) or characters (ASCII).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max_frame_bytes: Option<ValueFile<usize>>,
    /// Registers per 03H request.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub read_registers: Option<PerModeFile>,
    /// Registers per 10H request.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub write_registers: Option<PerModeFile>,
    /// Whether one request must stay within one register group.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub same_group: Option<ValueFile<bool>>,
    /// Response time.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub response_time_ms: Option<ValueFile<u64>>,
}

/// A value with its basis.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ValueFile<T> {
    /// The value.
    pub value: T,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// A limit per transmission mode.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct PerModeFile {
    /// RTU (required where the description serves RTU, and in schema_version 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rtu: Option<u16>,
    /// ASCII (required where the description serves ASCII, and in schema_version 1).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ascii: Option<u16>,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// A named block of registers.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroupFile {
    /// Name (command, monitor).
    pub name: String,
    /// First register (hex).
    pub first: String,
    /// Last register (hex).
    pub last: String,
}

/// One bit of a bit-field register.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BitFile {
    /// Bit number, 0 = least significant.
    pub bit: u8,
    /// Meaning as printed.
    pub name: String,
    /// What the simulator does with it (run, reverse, external-fault, fault-reset,
    /// running, ready, fault).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub role: Option<String>,
}

/// A value bound with its basis.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct BoundFile {
    /// The bound (hex).
    pub value: String,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
    /// Lines of the manual's text extraction the bound comes from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lines: Option<String>,
    /// Other rows that contradict the bound, and which one the model takes.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
}

/// A coarser resolution of a register above a value (A510: 0.1 Hz over 300 Hz).
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ResolutionFile {
    /// Values over this one (hex) have the coarser resolution.
    pub above: String,
    /// The step, in the register's units (10 = 0.1 Hz for a 0.01 Hz register).
    pub step: u16,
    /// Basis and citation of the resolution.
    #[serde(flatten)]
    pub fact: FactFile,
    /// Lines of the manual's text extraction it comes from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lines: Option<String>,
    /// What a drive of the model does with a value that is not a whole step.
    pub handling: FactFile,
}

/// Parameter access: the general assumption and the parameters marked read-only.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ParameterAccessFile {
    /// What the model assumes about every other parameter.
    #[serde(flatten)]
    pub fact: FactFile,
    /// Parameters some table of the document marks read-only.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub read_only: Vec<ReadOnlyParameterFile>,
}

/// Parameter registers marked read-only.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ReadOnlyParameterFile {
    /// Registers, as "XXXX" or "XXXX-YYYY".
    pub registers: String,
    /// The same as parameter numbers, "GG-NN" or "GG-NN..GG-NN" (register = group x 100H
    /// + number).
    pub parameters: String,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
    /// Lines of the manual's text extraction it comes from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub lines: Option<String>,
}

/// A fault code with its basis.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct CodeFile {
    /// The code (decimal, as the manuals number their fault lists).
    pub value: u16,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// A command or monitor register.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct RegisterFile {
    /// Register (hex).
    pub register: String,
    /// Meaning as printed.
    pub name: String,
    /// read-write, read-only or reserved.
    pub access: String,
    /// What the simulator does with it.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub role: Option<String>,
    /// Bits of a bit-field register.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub bits: Vec<BitFile>,
    /// Largest value accepted.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub max: Option<BoundFile>,
    /// A coarser resolution above some value.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub resolution: Option<ResolutionFile>,
    /// For the fault-code register: the code the external-fault bit raises.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub external_fault_code: Option<CodeFile>,
    /// Where the register is documented (absent for decisions).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub source: Option<String>,
    /// For registers the model adds: basis.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub basis: Option<Basis>,
    /// For registers the model adds: why.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub why: Option<String>,
}

/// The identification register.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct IdentificationFile {
    /// Register (hex), if the document has one.
    pub register: Option<String>,
    /// Documented value (hex), if any.
    pub value: Option<String>,
    /// Value the simulator answers where none is documented (hex).
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub simulated: Option<String>,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// One parameter group of the "Parameter Data" table.
#[derive(Debug, Clone, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ParameterGroupFile {
    /// Group number.
    pub group: u8,
    /// Registers, as "XXXX" or "XXXX-YYYY" ranges.
    pub registers: Vec<String>,
    /// Registers the table marks "-" (no Modbus access).
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub no_access: Vec<String>,
    /// Table and group.
    pub source: String,
    /// Misprints, repeats and other remarks.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub notes: Vec<String>,
}

/// A register used by an example outside the tables.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct ExampleRegisterFile {
    /// Register (hex).
    pub register: String,
    /// Value the simulator starts with (hex).
    pub initial: String,
    /// read-write or read-only.
    pub access: String,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// A starting value of the simulator.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct InitialValueFile {
    /// Register (hex).
    pub register: String,
    /// Value (hex).
    pub value: String,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}

/// Another spelling of a block of registers.
#[derive(Debug, Clone, Serialize, Deserialize)]
pub struct AliasFile {
    /// First alias register (hex).
    pub first: String,
    /// Last alias register (hex).
    pub last: String,
    /// The register `first` stands for (hex).
    pub target: String,
    /// Basis and citation.
    #[serde(flatten)]
    pub fact: FactFile,
}
