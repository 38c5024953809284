//! The cases of a master gate run: one operation paired with one behaviour of the drive,
//! each followed by a normal read (the recovery).

use std::time::Duration;

use super::drive::Behaviour;
use super::protocol::{MasterSettings, Operation};
use crate::codec::pdu::{Message, Pdu, Registers};
use crate::codec::Mode;
use crate::model::{Access, DriveModel, Expectation};

/// What the drive does in a case, by name: the `--only` key and the finding's
/// reproducer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Fault {
    /// The key ("normal", "exception-02", "stale-reply", ...).
    pub key: String,
    /// In words.
    pub title: String,
    /// The behaviour.
    pub behaviour: Behaviour,
    /// The line is busy (the drive still sending) when the operation starts.
    pub busy: bool,
    /// Public reports of the failure this case looks for.
    pub source: &'static str,
}

/// One case.
#[derive(Debug, Clone)]
pub struct MasterCase {
    /// "rtu.read.stale-reply".
    pub id: String,
    /// What it checks.
    pub title: String,
    /// The mode.
    pub mode: Mode,
    /// The operation under the fault.
    pub op: Operation,
    /// The fault.
    pub fault: Fault,
    /// The normal read after it (recovery).
    pub recovery: Operation,
}

/// The registers and values a run uses, chosen from the model so that every request of
/// a correct master is one the drive accepts.
#[derive(Debug, Clone)]
pub struct Plan {
    /// The node of the drive.
    pub node: u8,
    /// A read of two registers the drive answers.
    pub read: (u16, u16),
    /// A register and value a write-single may carry.
    pub write_single: Option<(u16, u16)>,
    /// Two registers and values a write-multiple may carry.
    pub write_multiple: Option<(u16, Vec<u16>)>,
    /// Loop-back data.
    pub loop_back: Option<Vec<u8>>,
    /// Exception codes the model uses.
    pub exception_codes: Vec<u8>,
}

fn frame(mode: Mode, node: u8, pdu: Pdu<'_>) -> Vec<u8> {
    Message { address: node, pdu }
        .to_frame_vec(mode)
        .unwrap_or_default()
}

fn words(values: &[u16]) -> Vec<u8> {
    values.iter().flat_map(|v| v.to_be_bytes()).collect()
}

impl Plan {
    /// The plan for node `node` of `model`.
    pub fn of(model: &DriveModel, node: u8) -> Plan {
        let mode = Mode::Rtu;
        let judge = |f: &[u8]| model.judge(node, mode, f).expect;
        let registers: Vec<(u16, Access)> = model.registers().collect();
        let read = registers
            .iter()
            .map(|(r, _)| *r)
            .find(|r| {
                // Two registers, and three for the read after a stale reply in flight.
                [2u16, 3].iter().all(|n| {
                    matches!(judge(&frame(mode, node, Pdu::ReadRequest { start: *r, count: *n })),
                        Expectation::Read(p) if p.registers.len() == usize::from(*n))
                })
            })
            .unwrap_or(0x2520);
        let value_of = |r: u16| {
            model
                .initial_values
                .iter()
                .map(|(x, v, _)| (*x, *v))
                .chain(model.example_registers.iter().map(|(x, v, ..)| (*x, *v)))
                .find(|(x, _)| *x == r)
                .map(|(_, v)| v)
        };
        let accepts_single = |r: u16, v: u16| {
            judge(&frame(
                mode,
                node,
                Pdu::WriteSingle {
                    register: r,
                    value: v,
                },
            )) == Expectation::WriteSingle
        };
        let candidates = |r: u16| {
            let mut c: Vec<u16> = value_of(r).into_iter().collect();
            c.extend([0, 1, 10, 100]);
            c
        };
        let writable: Vec<u16> = registers
            .iter()
            .filter(|(_, a)| *a == Access::ReadWrite)
            .map(|(r, _)| *r)
            .collect();
        let write_single = writable.iter().find_map(|r| {
            candidates(*r)
                .into_iter()
                .find(|v| accepts_single(*r, *v))
                .map(|v| (*r, v))
        });
        let write_multiple = writable.iter().find_map(|r| {
            let next = r.checked_add(1)?;
            let a = candidates(*r)
                .into_iter()
                .find(|v| accepts_single(*r, *v))?;
            let b = candidates(next)
                .into_iter()
                .find(|v| accepts_single(next, *v))?;
            let bytes = words(&[a, b]);
            let values = Registers::new(&bytes).ok()?;
            (judge(&frame(
                mode,
                node,
                Pdu::WriteMultipleRequest { start: *r, values },
            )) == Expectation::WriteMultiple)
                .then(|| (*r, vec![a, b]))
        });
        let data: Vec<u8> = [0xA5u8, 0x37, 0x5A, 0x73]
            .iter()
            .copied()
            .cycle()
            .take(model.loop_back_data_bytes.max(1))
            .collect();
        let loop_back = (judge(&frame(
            mode,
            node,
            Pdu::LoopBack {
                test_code: 0,
                data: &data,
            },
        )) == Expectation::LoopBack)
            .then_some(data);
        let mut exception_codes: Vec<u8> = model.exception_codes.iter().map(|(c, _)| *c).collect();
        exception_codes.sort_unstable();
        exception_codes.dedup();
        Plan {
            node,
            read: (read, 2),
            write_single,
            write_multiple,
            loop_back,
            exception_codes,
        }
    }

    /// The read the plan uses.
    pub fn read_op(&self) -> Operation {
        Operation::Read {
            unit: self.node,
            start: self.read.0,
            count: self.read.1,
        }
    }
}

/// The other node whose reply the drive sends in the other-node case.
pub fn other_node(node: u8) -> u8 {
    if node == 2 {
        3
    } else {
        2
    }
}

/// The faults of a run, for the master's settings.
pub fn faults(
    plan: &Plan,
    settings: &MasterSettings,
    line: &crate::codec::timing::LineSettings,
    read: bool,
) -> Vec<Fault> {
    let f = |key: &str, title: &str, behaviour: Behaviour, source: &'static str| Fault {
        key: key.to_string(),
        title: title.to_string(),
        behaviour,
        busy: false,
        source,
    };
    let gap = super::drive::apart(line);
    let mut out = vec![f(
        "normal",
        "a normal reply",
        Behaviour::Normal,
        "the manual's function",
    )];
    for code in &plan.exception_codes {
        out.push(f(
            &format!("exception-{code:02x}"),
            &format!("exception {code:02X}H"),
            Behaviour::Exception(*code),
            "the model's exception table (the legacy L510's 51H..55H)",
        ));
    }
    out.push(f(
        "no-reply",
        "no reply",
        Behaviour::NoReply,
        "Modbus over Serial Line V1.02, 2.4.1 (response timeout)",
    ));
    out.push(f(
        "stale-reply",
        "the reply only after the master's timeout (the stale reply), before its next request",
        Behaviour::AfterTimeout,
        "pymodbus #2636, Home Assistant core #138077, eModbus #74, pymodbus #375",
    ));
    out.push(f(
        "stale-in-flight",
        "the reply only when the master's next request (a read of 3 registers) has come, just before that one's own reply (the stale reply in flight)",
        Behaviour::InFlight,
        "pymodbus #2636, Home Assistant core #138077, eModbus #74",
    ));
    out.push(f(
        "bad-checksum",
        "a reply with a wrong CRC or LRC",
        Behaviour::BadChecksum,
        "Modbus over Serial Line V1.02, 2.5.1.2 / 2.5.2.2",
    ));
    out.push(f(
        "other-node",
        "a reply from another node, and none from the node asked",
        Behaviour::OtherNode(other_node(plan.node)),
        "Modbus over Serial Line V1.02, 2.2",
    ));
    out.push(f(
        "twice",
        "the reply sent twice",
        Behaviour::Twice,
        "eModbus #74 (a reply taken as the next one's)",
    ));
    if !read {
        return out;
    }
    out.push(f(
        "late",
        "a reply late but inside the master's timeout",
        Behaviour::Late(settings.timeout / 2),
        "Modbus over Serial Line V1.02, 2.4.1",
    ));
    out.push(f(
        "wrong-function",
        "a 06H echo in place of the read's reply (a reply of another function)",
        Behaviour::WrongFunction,
        "Modbus Application Protocol V1.1b3, 6.3 (a reply answers the request's function)",
    ));
    out.push(f(
        "truncated",
        "a reply cut short",
        Behaviour::Truncated,
        "eModbus #74 (a frame ended early)",
    ));
    out.push(f(
        "garbage-before",
        "garbage, a silence, then the reply",
        Behaviour::GarbageBefore(vec![0xFF, 0x13, 0x7E]),
        "Home Assistant core #69742",
    ));
    out.push(f(
        "garbage-after",
        "the reply, a silence, then garbage",
        Behaviour::GarbageAfter(vec![0xFF, 0x13, 0x7E]),
        "Home Assistant core #69742",
    ));
    out.push(f(
        "zero-before",
        "a lone 00H, a silence, then the reply",
        Behaviour::GarbageBefore(vec![0x00]),
        "tokio-modbus #374, minimalmodbus #61",
    ));
    out.push(f(
        "zero-after",
        "the reply, a silence, then a lone 00H",
        Behaviour::GarbageAfter(vec![0x00]),
        "tokio-modbus #374, minimalmodbus #61",
    ));
    if let Some(code) = plan.exception_codes.first() {
        out.push(f(
            "exception-no-checksum",
            &format!("exception {code:02X}H without its CRC or LRC"),
            Behaviour::ExceptionNoChecksum(*code),
            "tokio-modbus #60",
        ));
    }
    out.push(f(
        "split",
        &format!(
            "a reply split by a silence of {} ms (over t1.5)",
            gap.as_millis()
        ),
        Behaviour::Split(gap),
        "Modbus over Serial Line V1.02, 2.5.1.1",
    ));
    let mut busy = f(
        "line-busy",
        "the drive still sending when the operation starts (a master must wait for t3.5 of silence)",
        Behaviour::Normal,
        "Modbus over Serial Line V1.02, 2.5.1.1",
    );
    busy.busy = true;
    out.push(busy);
    out
}

fn mode_key(m: Mode) -> &'static str {
    match m {
        Mode::Rtu => "rtu",
        Mode::Ascii => "ascii",
    }
}

/// Every case for `modes`.
pub fn cases(
    plan: &Plan,
    settings: &MasterSettings,
    line: &crate::codec::timing::LineSettings,
    modes: &[Mode],
) -> Vec<MasterCase> {
    let node = plan.node;
    let mut ops: Vec<(&str, Operation)> = vec![("read", plan.read_op())];
    if let Some((register, value)) = plan.write_single {
        ops.push((
            "write-single",
            Operation::WriteSingle {
                unit: node,
                register,
                value,
            },
        ));
    }
    if let Some((start, values)) = &plan.write_multiple {
        ops.push((
            "write-multiple",
            Operation::WriteMultiple {
                unit: node,
                start: *start,
                values: values.clone(),
            },
        ));
    }
    if let Some(data) = &plan.loop_back {
        ops.push((
            "loop-back",
            Operation::LoopBack {
                unit: node,
                test_code: 0,
                data: data.clone(),
            },
        ));
    }
    let mut out = Vec::new();
    for &mode in modes {
        for (name, op) in &ops {
            for fault in faults(plan, settings, line, *name == "read") {
                // In flight, the stale reply has another shape than the reply due (a
                // read of 3 registers, not 2): a master that matches a reply to its
                // request can tell them apart.
                let recovery = match (&fault.behaviour, plan.read_op()) {
                    (Behaviour::InFlight, Operation::Read { unit, start, .. }) => Operation::Read {
                        unit,
                        start,
                        count: plan.read.1 + 1,
                    },
                    (_, read) => read,
                };
                out.push(MasterCase {
                    id: format!("{}.{name}.{}", mode_key(mode), fault.key),
                    title: format!("{op}: {}", fault.title),
                    mode,
                    op: op.clone(),
                    fault,
                    recovery,
                });
            }
        }
        let broadcasts = [
            plan.write_single
                .map(|(register, value)| Operation::WriteSingle {
                    unit: 0,
                    register,
                    value,
                }),
            plan.write_multiple
                .clone()
                .map(|(start, values)| Operation::WriteMultiple {
                    unit: 0,
                    start,
                    values,
                }),
        ];
        for (name, op) in ["broadcast-single", "broadcast-multiple"]
            .iter()
            .zip(broadcasts)
        {
            let Some(op) = op else { continue };
            for (key, title, behaviour) in [
                (
                    "normal",
                    "no reply (a broadcast is not answered)",
                    Behaviour::Normal,
                ),
                (
                    "reply-to-broadcast",
                    "a drive that answers the broadcast",
                    Behaviour::ReplyToBroadcast,
                ),
            ] {
                out.push(MasterCase {
                    id: format!("{}.{name}.{key}", mode_key(mode)),
                    title: format!("{op}: {title}"),
                    mode,
                    op: op.clone(),
                    fault: Fault {
                        key: key.to_string(),
                        title: title.to_string(),
                        behaviour,
                        busy: false,
                        source: "Modbus over Serial Line V1.02, 2.1; pymodbus #2378",
                    },
                    recovery: plan.read_op(),
                });
            }
        }
    }
    out
}

/// How long the busy line lasts, and the pause between its bytes.
pub const BUSY_FOR: Duration = Duration::from_millis(150);
/// See [`BUSY_FOR`].
pub const BUSY_PACE: Duration = Duration::from_millis(1);

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::timing::{LineSettings, Parity};

    #[test]
    fn plans_use_registers_the_model_accepts() {
        for id in ["f510", "a510", "l510", "e510", "l510-legacy"] {
            let model = DriveModel::builtin(id).unwrap();
            let plan = Plan::of(&model, 1);
            assert!(plan.write_single.is_some(), "{id}: no writable register");
            assert!(!plan.exception_codes.is_empty(), "{id}");
        }
        let legacy = Plan::of(&DriveModel::builtin("l510-legacy").unwrap(), 1);
        assert!(legacy.exception_codes.contains(&0x51), "{legacy:?}");
    }

    #[test]
    fn case_ids_are_unique() {
        let model = DriveModel::builtin("f510").unwrap();
        let plan = Plan::of(&model, 1);
        let settings = MasterSettings {
            timeout: Duration::from_millis(300),
            retries: 0,
        };
        let line = LineSettings::new(9600, 8, Parity::None, 1);
        let all = cases(&plan, &settings, &line, &[Mode::Rtu, Mode::Ascii]);
        let mut ids: Vec<&str> = all.iter().map(|c| c.id.as_str()).collect();
        let n = ids.len();
        ids.sort_unstable();
        ids.dedup();
        assert_eq!(ids.len(), n);
        assert!(ids.contains(&"rtu.read.stale-reply"));
        assert!(ids.contains(&"ascii.broadcast-single.normal"));
    }
}
