//! A drive's parameters as a file a person reads and edits: which registers are
//! parameters ([`parameters`]), the backup file ([`Backup`], a TOML subset with typed
//! errors by line and column), the comparison of two sets of values ([`diff`]), the
//! bounded reads and the planned writes ([`read_plan`], [`write_plan`]), and the live
//! side ([`read_values`], [`Restore`]), which goes through the runner's master, its
//! journal and the one judge.
//!
//! What is a parameter comes from the model room only: the parameter groups of a TECO
//! model, and the read-write blocks of a description (v2), less the command and monitor
//! registers, which are the drive's state, not its settings. Reserved, "-" (no access)
//! and write-only registers are never read; read-only parameters are read and shown but
//! never written.

mod audit;
mod device;
mod diff;
mod file;
mod plan;

pub use audit::{now, AuditLog, AuditRecord};
pub use device::{
    read_identification, read_values, restore, LiveError, ReadOut, RestoreOutcome, Step, StepResult,
};
pub use diff::{diff, Difference, Side, ValueDiff};
pub use file::{Backup, Entry, FileError, Header};
pub use plan::{read_plan, write_plan, PlanError, PlannedWrite};

use crate::model::{Access, DriveModel, Origin};

/// One parameter of a model: a register a backup holds a value of.
#[derive(Debug, Clone, PartialEq)]
pub struct Parameter {
    /// The register.
    pub register: u16,
    /// The group it belongs to, as the model names it ("group 3", a block's name).
    pub group: String,
    /// Its name for people: the parameter number where the model uses TECO's naming
    /// ("3-05"), else the block's name.
    pub name: String,
    /// Unit of the value times `scale`, where the description gives one.
    pub unit: Option<String>,
    /// Value = raw x scale, where the description gives one.
    pub scale: Option<f64>,
    /// Whether a restore may write it (read-write); read-only parameters are backed up
    /// as comments.
    pub writable: bool,
    /// Smallest and largest value a write may carry, where the description bounds it.
    pub bounds: (Option<u16>, Option<u16>),
}

impl Parameter {
    /// The value in its unit where the description gives a scale or a unit ("45.00 Hz"),
    /// for the comment beside a raw value; `None` where it gives neither.
    pub fn in_unit(&self, raw: u16) -> Option<String> {
        // The model room's one rule for a value in its unit (no digit made up, none lost).
        crate::model::Unit::of(self.scale, self.unit.as_deref()).map(|u| u.show(raw))
    }

    /// The comment a backup writes beside the value: name, unit, the value in its unit.
    pub fn comment(&self, raw: u16) -> String {
        let mut s = self.name.clone();
        if let Some(u) = &self.unit {
            s.push_str(", ");
            s.push_str(u);
        }
        if let Some(v) = self.in_unit(raw) {
            s.push_str(": ");
            s.push_str(&v);
        }
        s
    }
}

/// The parameters of `model`, in register order: what a backup reads. The command and
/// monitor registers, example-only registers, and reserved, "-" and write-only registers
/// are left out.
pub fn parameters(model: &DriveModel) -> Vec<Parameter> {
    let mut out = Vec::new();
    for (register, _) in model.registers() {
        let Some(info) = model.lookup(register) else {
            continue;
        };
        // An alias spelling is the same register: backed up once, by its own number.
        if info.via_alias || info.register != register {
            continue;
        }
        let writable = match info.access {
            Access::ReadWrite => true,
            Access::ReadOnly => false,
            Access::Reserved | Access::NoAccess | Access::WriteOnly => continue,
        };
        let group = model.group_name(info.group).to_string();
        let p = match info.origin {
            Origin::Parameter => Parameter {
                register,
                group,
                name: format!("{}-{:02}", register >> 8, register & 0xFF),
                unit: None,
                scale: None,
                writable,
                bounds: (None, None),
            },
            // A named register of a description is its command or monitor state.
            Origin::Block if model.named(register).is_none() => {
                let Some(b) = model.block_of(register) else {
                    continue;
                };
                Parameter {
                    register,
                    group,
                    name: b
                        .name
                        .clone()
                        .unwrap_or_else(|| format!("block {:04X}H", b.span.start())),
                    unit: b.unit.clone(),
                    scale: b.scale,
                    writable,
                    bounds: (b.min, b.max),
                }
            }
            _ => continue,
        };
        out.push(p);
    }
    out
}

/// The parameter `register` of `params` (sorted by register), if it is one.
pub fn find(params: &[Parameter], register: u16) -> Option<&Parameter> {
    params
        .binary_search_by_key(&register, |p| p.register)
        .ok()
        .map(|i| &params[i])
}

/// Why `register` is not a parameter a restore may write, in words for an error that
/// names the file's line; `None` where it may be written with `value`.
pub fn refusal(
    model: &DriveModel,
    params: &[Parameter],
    register: u16,
    value: u16,
) -> Option<String> {
    match find(params, register) {
        Some(p) if !p.writable => Some(format!(
            "{} is read-only in the {} model: a restore never writes it (make the line a comment)",
            model.describe(register),
            model.id
        )),
        Some(p) => match p.bounds {
            (Some(min), _) if value < min => Some(format!(
                "{value} is below the smallest value {min} the {} model allows for {}",
                model.id,
                model.describe(register)
            )),
            (_, Some(max)) if value > max => Some(format!(
                "{value} is above the largest value {max} the {} model allows for {}",
                model.id,
                model.describe(register)
            )),
            _ => None,
        },
        None => Some(match model.lookup(register) {
            Some(info) => format!(
                "{} is {} ({}), not a parameter: a restore never writes the command block or anything read-only or reserved",
                model.describe(register),
                model.group_name(info.group),
                info.access
            ),
            None => format!(
                "{} is not in the {} model's map",
                model.describe(register),
                model.id
            ),
        }),
    }
}

#[cfg(test)]
mod tests;
