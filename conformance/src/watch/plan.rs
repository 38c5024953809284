//! What to watch and how to read it: the names on the command line resolved to
//! registers (a register number, a register's name, a block's name), and the fewest 03H
//! reads that cover them within the model's limits.

use crate::codec::pdu::{Message, Pdu};
use crate::codec::Mode;
use crate::model::{Access, DriveModel, Expectation};

use super::WatchError;

/// One 03H read of the plan.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Read {
    /// First register.
    pub start: u16,
    /// Registers read.
    pub count: u16,
}

impl Read {
    /// The registers it reads.
    pub fn registers(&self) -> impl Iterator<Item = u16> {
        let start = u32::from(self.start);
        (start..start + u32::from(self.count)).filter_map(|r| u16::try_from(r).ok())
    }

    /// Its request frame to `node` in `mode`.
    pub fn frame(&self, node: u8, mode: Mode) -> Result<Vec<u8>, WatchError> {
        Message {
            address: node,
            pdu: Pdu::ReadRequest {
                start: self.start,
                count: self.count,
            },
        }
        .to_frame_vec(mode)
        .map_err(|e| WatchError::Frame(e.to_string()))
    }
}

/// The registers watched and the reads that cover them.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PollPlan {
    /// The registers watched, in order (a read may cover more: those are not shown).
    pub registers: Vec<u16>,
    /// The reads, in order.
    pub reads: Vec<Read>,
}

/// The registers `names` stand for, in order, each once: a register number (2520H,
/// 0x2520, or decimal), a register's name (case-insensitive; a unique prefix will do),
/// a block's name (`monitor`, `command`, a description's block), or `status` (the
/// status word, whatever its table calls it). With no names, the
/// monitor block and the status word.
pub fn resolve(model: &DriveModel, names: &[String]) -> Result<Vec<u16>, WatchError> {
    let mut out: Vec<u16> = Vec::new();
    let add = |r: u16, out: &mut Vec<u16>| {
        if !out.contains(&r) {
            out.push(r);
        }
    };
    if names.is_empty() {
        for r in default_registers(model)? {
            add(r, &mut out);
        }
        return Ok(out);
    }
    for name in names {
        for r in resolve_one(model, name)? {
            add(r, &mut out);
        }
    }
    Ok(out)
}

/// The monitor block (its registers that are not reserved) and the status word; for a
/// description without them, its read-only blocks.
fn default_registers(model: &DriveModel) -> Result<Vec<u16>, WatchError> {
    let mut out: Vec<u16> = model
        .group("monitor")
        .map(|g| g.span.clone().filter(|r| shown(model, *r)).collect())
        .unwrap_or_default();
    if let Some(s) = model.register_with_role(crate::model::Role::Status) {
        if !out.contains(&s) {
            out.insert(0, s);
        }
    }
    // A description without the manuals' monitor block: its read-only blocks, which
    // are what a device reports rather than what it is told.
    if out.is_empty() {
        out = model
            .blocks
            .iter()
            .filter(|b| b.access == Access::ReadOnly)
            .flat_map(|b| b.span.clone())
            .collect();
    }
    if out.is_empty() {
        return Err(WatchError::NothingByDefault(model.id.clone()));
    }
    Ok(out)
}

/// Whether a register of a block is worth a row: not reserved, not without access.
fn shown(model: &DriveModel, r: u16) -> bool {
    model.lookup(r).is_some_and(|i| {
        !matches!(
            i.access,
            Access::Reserved | Access::NoAccess | Access::WriteOnly
        )
    })
}

/// A register number: hex with H or 0x, or decimal digits.
fn number(text: &str) -> Option<Result<u16, ()>> {
    let t = text.trim();
    let hex = t
        .strip_prefix("0x")
        .or_else(|| t.strip_prefix("0X"))
        .or_else(|| {
            t.strip_suffix(['H', 'h'])
                .filter(|d| d.bytes().all(|b| b.is_ascii_hexdigit()))
        });
    match hex {
        Some(d) => Some(u16::from_str_radix(d, 16).map_err(|_| ())),
        None if !t.is_empty() && t.bytes().all(|b| b.is_ascii_digit()) => {
            Some(t.parse::<u16>().map_err(|_| ()))
        }
        None => None,
    }
}

fn resolve_one(model: &DriveModel, name: &str) -> Result<Vec<u16>, WatchError> {
    if let Some(n) = number(name) {
        let r = n.map_err(|_| WatchError::BadNumber(name.to_string()))?;
        if model.lookup(r).is_none() {
            let decimal_note = if name.bytes().all(|b| b.is_ascii_digit()) {
                format!(" (a bare number is decimal: {name} is {r:04X}H; write {name}H for hex)")
            } else {
                String::new()
            };
            return Err(WatchError::NotInMap {
                name: name.to_string(),
                register: r,
                note: decimal_note,
            });
        }
        return Ok(vec![r]);
    }
    let lower = name.to_lowercase();
    // A block: a group of the map (command, monitor, a parameter group) or a
    // description's named block.
    if let Some(g) = model.groups.iter().find(|g| g.name.to_lowercase() == lower) {
        let regs: Vec<u16> = g.span.clone().filter(|r| shown(model, *r)).collect();
        if !regs.is_empty() {
            return Ok(regs);
        }
    }
    if let Some(b) = model
        .blocks
        .iter()
        .find(|b| b.name.as_deref().is_some_and(|n| n.to_lowercase() == lower))
    {
        return Ok(b.span.clone().collect());
    }
    // The status word by its role, whatever the table calls it ("State signal").
    if lower == "status" || lower == "status word" {
        if let Some(r) = model.register_with_role(crate::model::Role::Status) {
            return Ok(vec![r]);
        }
    }
    // A register by its name: exact first, then a unique prefix.
    let names: Vec<(u16, &str)> = model
        .named
        .iter()
        .filter(|n| n.access != Access::Reserved)
        .map(|n| (n.register, n.name.as_str()))
        .collect();
    let exact: Vec<&(u16, &str)> = names
        .iter()
        .filter(|(_, n)| n.to_lowercase() == lower)
        .collect();
    let candidates: Vec<&(u16, &str)> = if exact.is_empty() {
        names
            .iter()
            .filter(|(_, n)| n.to_lowercase().starts_with(&lower))
            .collect()
    } else {
        exact
    };
    match candidates.as_slice() {
        [(r, _)] => Ok(vec![*r]),
        [] => Err(WatchError::UnknownName {
            name: name.to_string(),
            model: model.id.clone(),
        }),
        several => Err(WatchError::Ambiguous {
            name: name.to_string(),
            candidates: several
                .iter()
                .map(|(r, n)| format!("{r:04X}H ({n})"))
                .collect(),
        }),
    }
}

/// Whether the model says `node` answers a read of `start..start+count` in `mode` with
/// a normal reply.
fn served(model: &DriveModel, node: u8, mode: Mode, start: u16, count: u16) -> bool {
    let read = Read { start, count };
    read.frame(node, mode)
        .is_ok_and(|f| matches!(model.judge(node, mode, &f).expect, Expectation::Read(_)))
}

/// The fewest 03H reads that cover `registers` in `mode`: each read as long as the
/// model's limit allows (registers per read, one group per read, no register the model
/// refuses inside it), from the lowest register not yet covered to the farthest one
/// watched that such a read reaches. A register that no read can reach is refused with
/// the model's reason.
pub fn plan(
    model: &DriveModel,
    node: u8,
    mode: Mode,
    registers: &[u16],
) -> Result<PollPlan, WatchError> {
    let mut sorted = registers.to_vec();
    sorted.sort_unstable();
    sorted.dedup();
    for &r in &sorted {
        if !served(model, node, mode, r, 1) {
            let f = Read { start: r, count: 1 }.frame(node, mode)?;
            return Err(WatchError::NotReadable {
                register: model.describe(r),
                why: model.judge(node, mode, &f).detail,
            });
        }
    }
    let max = model.limits.read.get(mode).max(1);
    let mut reads = Vec::new();
    let mut i = 0;
    while let Some(&start) = sorted.get(i) {
        // The farthest watched register a served read from `start` reaches: the greedy
        // cover from the left is the fewest reads of an interval cover.
        let mut j = i;
        for (k, &end) in sorted.iter().enumerate().skip(i + 1) {
            let count = u32::from(end) - u32::from(start) + 1;
            if count > u32::from(max) {
                break;
            }
            if served(model, node, mode, start, count as u16) {
                j = k;
            }
        }
        let count = sorted[j] - start + 1;
        reads.push(Read { start, count });
        i = j + 1;
    }
    Ok(PollPlan {
        registers: registers.to_vec(),
        reads,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn f510() -> DriveModel {
        DriveModel::builtin("f510").unwrap()
    }

    #[test]
    fn the_default_is_the_monitor_block_and_the_status_word_in_one_read() {
        let m = f510();
        let regs = resolve(&m, &[]).unwrap();
        assert_eq!(regs[0], 0x2520);
        // 2525H and 252EH are reserved: not shown, but read through.
        assert!(!regs.contains(&0x2525) && regs.contains(&0x252F));
        let p = plan(&m, 1, Mode::Rtu, &regs).unwrap();
        assert_eq!(
            p.reads,
            [Read {
                start: 0x2520,
                count: 16
            }]
        );
    }

    #[test]
    fn reads_stay_within_the_limit_and_the_group() {
        let m = f510();
        // The command block and the monitor block are two groups: two reads, never one
        // across them.
        let p = plan(&m, 1, Mode::Rtu, &[0x2502, 0x2520, 0x2524]).unwrap();
        assert_eq!(
            p.reads,
            [
                Read {
                    start: 0x2502,
                    count: 1
                },
                Read {
                    start: 0x2520,
                    count: 5
                }
            ]
        );
        // ASCII reads at most 17 registers in the F510: 2520H..252FH is 16, one read.
        let all: Vec<u16> = (0x2520..=0x252F).collect();
        assert_eq!(plan(&m, 1, Mode::Ascii, &all).unwrap().reads.len(), 1);
    }

    #[test]
    fn names_resolve_by_number_name_prefix_and_block() {
        let m = f510();
        let r = |n: &str| resolve(&m, &[n.to_string()]);
        assert_eq!(r("2520H").unwrap(), [0x2520]);
        assert_eq!(r("0x2524").unwrap(), [0x2524]);
        assert_eq!(r("output freq").unwrap(), [0x2524]);
        assert_eq!(r("STATE SIGNAL").unwrap(), [0x2520]);
        assert_eq!(r("status").unwrap(), [0x2520]);
        assert_eq!(r("monitor").unwrap().len(), 14);
        match r("frequency command (0.01 hz)") {
            Err(WatchError::Ambiguous { candidates, .. }) => {
                assert_eq!(candidates.len(), 2, "{candidates:?}");
                assert!(candidates[0].starts_with("2502H"));
            }
            other => panic!("{other:?}"),
        }
        let e = r("2520").unwrap_err().to_string();
        assert!(e.contains("09D8H") && e.contains("2520H"), "{e}");
        assert!(matches!(r("nosuch"), Err(WatchError::UnknownName { .. })));
    }

    #[test]
    fn a_description_is_watched_by_its_blocks() {
        let text = include_str!("../../../vectors/models/examples/acme-x100.json");
        let m = DriveModel::from_json("acme-x100.json", text).unwrap();
        // No monitor block: the read-only block "status", in one read.
        let regs = resolve(&m, &[]).unwrap();
        assert_eq!(regs, (0x2520..=0x252F).collect::<Vec<u16>>());
        assert_eq!(plan(&m, 1, Mode::Rtu, &regs).unwrap().reads.len(), 1);
        // A block by its name, with its unit and range.
        let cmds = resolve(&m, &["Commands".to_string()]).unwrap();
        assert_eq!(cmds.len(), 16);
        assert_eq!(m.value_text(0x2500, 1500).unwrap(), "15.00 Hz");
        assert!(!m.range_of(0x2500).unwrap().admits(0x1771));
        // The reserved block cannot be read.
        assert!(plan(&m, 1, Mode::Rtu, &[0x2510]).is_err());
    }

    #[test]
    fn a_register_the_model_refuses_is_refused_with_its_reason() {
        let m = f510();
        // 2500H is reserved: F510 reads it as 0000H; the parameter groups' "-" registers
        // are refused. A register outside the map is refused by resolve.
        assert!(resolve(&m, &["3000H".to_string()]).is_err());
        assert!(plan(&m, 1, Mode::Rtu, &[0x2520]).is_ok());
    }
}
