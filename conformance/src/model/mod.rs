//! Drive models: each manual as data (`vectors/models/<model>.json`), checked on load, and
//! the rules that say how a drive of that model answers a request ([`DriveModel::judge`]).
//!
//! The simulator and the runner read the same model: the simulator to answer, the runner
//! to predict. Every fact carries its [`Basis`]: where the manual is silent or contradicts
//! itself, the model records a *decision* and says why, and the runner reports a device
//! that differs from a decision as an observation, not a deviation.

mod error;
mod facts;
mod fields;
mod file;
pub mod fuzzing;
mod judge;
pub mod lint;
mod load;
mod map;
mod source;
mod value;

use std::collections::BTreeMap;
use std::ops::RangeInclusive;

pub use error::ModelError;
pub use facts::{Basis, ExceptionRule, Fact, Fault, SilenceReason};
pub use file::ModelFile;
pub use judge::{Expectation, Judgement, ReadPlan, WritePlan};
pub use map::{
    Access, Alias, BitRoles, Block, Group, Identification, Limits, NamedBit, NamedRegister, Origin,
    PerMode, ReadOnlyParameter, RegisterInfo, Resolution, Role,
};
pub use source::{sha256_hex, Source};
pub use value::{Unit, ValueRange};

pub use crate::codec::{frame_len, read_response_len, write_request_len};

use crate::codec::Mode;

/// What a model id is, in words (`^[a-z0-9][a-z0-9._-]{0,63}$`).
pub const MODEL_ID_RULE: &str =
    "lower-case letters, digits, '.', '_' or '-', 1 to 64 characters, starting with a letter or digit";

/// Whether `id` is a model id ([`MODEL_ID_RULE`]): the loader, `model lint`, `model
/// learn --id` and `model import --model` all hold ids to this one rule.
pub fn valid_model_id(id: &str) -> bool {
    (1..=64).contains(&id.len())
        && id.bytes().enumerate().all(|(i, c)| {
            c.is_ascii_lowercase()
                || c.is_ascii_digit()
                || (i > 0 && matches!(c, b'.' | b'_' | b'-'))
        })
}

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

/// One drive model, checked and indexed.
#[derive(Debug, Clone)]
pub struct DriveModel {
    /// Model id (f510, ...).
    pub id: String,
    /// The file's schema_version (1: the five manuals; 2: any device).
    pub version: u32,
    /// Transmission modes the device serves (v1: both).
    pub modes: Vec<Mode>,
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
    /// Data bytes of the manual's loop-back frames (2 where the description has no
    /// `loop_back`).
    pub loop_back_data_bytes: usize,
    /// Basis of the loop-back; `None` where the description has no `loop_back` (its
    /// checks are skipped).
    pub loop_back_fact: Option<Fact>,
    /// Basis of the echo of a test code (sub-function) other than 0000H.
    pub loop_back_other_fact: Option<Fact>,
    /// The exception-code table (empty where the description has none).
    pub exception_codes: Vec<(u8, String)>,
    /// Where the table is.
    pub exception_codes_source: Option<String>,
    /// Which exception each fault gets (v2: only the faults the description states).
    pub exceptions: BTreeMap<Fault, ExceptionRule>,
    /// Why requests get no reply (v2: only the reasons the description states).
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
    /// The identification register; `None` where the description has none.
    pub identification: Option<Identification>,
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
    /// The description the model was read from (file, title, hash), for reports.
    pub source: Source,
    /// Plain register blocks (v2); each is also a [`Group`] of the map.
    pub blocks: Vec<Block>,
    /// TECO's naming rule (register = group x 100H + number), where the description
    /// uses it (v1 implies it).
    pub naming: Option<Fact>,
    /// The optional fields the description leaves out, by their path in the file
    /// ("loop_back", "exceptions.illegal-count", "limits.response_time_ms"): each check
    /// that needs one is skipped, naming it.
    pub absent: Vec<String>,
    /// Sorted, non-overlapping spans of the map: (range, access, group, origin).
    map: Vec<(RangeInclusive<u16>, Access, usize, Origin)>,
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
        // Where the description states no response time, the soonest a reply may start.
        let manual = std::time::Duration::from_millis(self.limits.response_time_ms.unwrap_or(0));
        manual.max(std::time::Duration::from_micros(
            line.t3_5_us() + line.char_time_us(),
        ))
    }

    /// The shortest response time a device can keep on `line`: the manual's, or t3.5
    /// where that is longer (a reply must not start before t3.5). Where the description
    /// states no response time, t3.5 alone (zero without a line): callers that judge
    /// lateness check [`Limits::response_time_ms`] first.
    pub fn response_time_on(
        &self,
        line: Option<&crate::codec::timing::LineSettings>,
    ) -> std::time::Duration {
        let manual = std::time::Duration::from_millis(self.limits.response_time_ms.unwrap_or(0));
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
        // Built-in models are linted by tests/model_schema.rs, not at every load.
        Self::from_json_unlinted(id, text)
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
        let mut m = Self::from_json(&path.display().to_string(), &text)?;
        m.source.file = Some(path.display().to_string());
        Ok(m)
    }

    /// Lints a description's text ([`lint::lint`]), then parses and checks it; `name`
    /// names it in errors. Any lint error refuses it, with every finding.
    pub fn from_json(name: &str, text: &str) -> Result<Self, ModelError> {
        let findings = lint::lint(name, text);
        if lint::has_errors(&findings) {
            return Err(ModelError::Lint {
                file: name.to_string(),
                findings,
            });
        }
        Self::from_json_unlinted(name, text)
    }

    /// Parses and checks a model file's text without linting it first; `name` names it
    /// in errors.
    pub fn from_json_unlinted(name: &str, text: &str) -> Result<Self, ModelError> {
        let file: ModelFile = serde_json::from_str(text).map_err(|source| ModelError::Json {
            model: name.to_string(),
            source,
        })?;
        let mut m = Self::from_file(&file)?;
        m.source = Source::of(None, &m.title, text.as_bytes());
        Ok(m)
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

    /// The exception rule for `fault`, if the description states one. Models without a
    /// rule for "-" registers (only E510 marks them) answer them as unknown registers.
    pub fn rule(&self, fault: Fault) -> Option<&ExceptionRule> {
        self.exceptions.get(&fault).or_else(|| match fault {
            Fault::NoAccess => self.exceptions.get(&Fault::IllegalRegister),
            _ => None,
        })
    }

    /// The exception code a drive of this description answers for `fault`: the stated
    /// rule's, or where the description has none the Modbus application protocol's
    /// (V1.1b3, 7: 01H illegal function; 02H illegal data address for a register outside
    /// the map, read-only, reserved or across blocks; 03H illegal data value for a count
    /// or value out of range and a malformed request). The simulator needs some answer;
    /// the runner skips the checks that rest on an absent rule.
    pub fn answer_code(&self, fault: Fault) -> u8 {
        match self.rule(fault) {
            Some(r) => r.code,
            None => fault.modbus_code(),
        }
    }

    /// Whether the description states `field` (a path such as "loop_back" or
    /// "exceptions.illegal-count"); see [`DriveModel::absent`].
    pub fn states(&self, field: &str) -> bool {
        !self.absent.iter().any(|a| a == field)
    }

    /// The transmission modes the device serves.
    pub fn modes(&self) -> &[Mode] {
        &self.modes
    }

    /// Whether the device serves `mode`.
    pub fn serves_mode(&self, mode: Mode) -> bool {
        self.modes.contains(&mode)
    }

    /// The block that holds `register`, if any (v2).
    pub fn block_of(&self, register: u16) -> Option<&Block> {
        self.blocks.iter().find(|b| b.span.contains(&register))
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
        !self.exception_codes.is_empty() && self.exception_codes.iter().all(|(c, _)| *c >= 0x51)
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
