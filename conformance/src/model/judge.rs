//! The model's rules: what a drive of the model does with one request frame.
//!
//! [`DriveModel::judge`] takes the frame as it travels on the line and returns a
//! [`Judgement`]: a normal reply (and the registers it reads or writes), an exception
//! (with the fault and code), or silence (with the reason), together with the facts of
//! the model it rests on. The simulator executes the judgement; the runner predicts with it.

use std::fmt::Write as _;

use super::{Access, Basis, DriveModel, Fact, Fault, Origin, SilenceReason};
use crate::codec::pdu::{Direction, Message, Pdu};
use crate::codec::Mode;

/// Registers a normal 03H reply reads, resolved through aliases.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ReadPlan {
    /// The registers, in order.
    pub registers: Vec<u16>,
}

/// Registers a write changes, resolved through aliases, with their new values.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct WritePlan {
    /// (register, value) in order.
    pub writes: Vec<(u16, u16)>,
}

/// What the drive does.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Expectation {
    /// A normal 03H reply.
    Read(ReadPlan),
    /// A normal 06H reply (echo), after writing.
    WriteSingle,
    /// A normal 10H reply (start and count), after writing.
    WriteMultiple,
    /// A normal 08H reply (echo).
    LoopBack,
    /// An exception reply.
    Exception {
        /// The kind of bad request.
        fault: Fault,
        /// The code the model answers.
        code: u8,
    },
    /// No reply.
    Silence(SilenceReason),
}

impl Expectation {
    /// Whether a reply is expected.
    pub fn replies(&self) -> bool {
        !matches!(self, Expectation::Silence(_))
    }

    /// One-line description.
    pub fn describe(&self) -> String {
        match self {
            Expectation::Read(p) => {
                format!("normal 03H reply with {} registers", p.registers.len())
            }
            Expectation::WriteSingle => "normal 06H reply (echo of the request)".to_string(),
            Expectation::WriteMultiple => "normal 10H reply (start and count)".to_string(),
            Expectation::LoopBack => "normal 08H reply (echo of the request)".to_string(),
            Expectation::Exception { fault, code } => {
                format!("exception {code:02X}H ({fault})")
            }
            Expectation::Silence(r) => format!("no reply ({r})"),
        }
    }
}

/// The model's verdict on one request frame.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Judgement {
    /// What the drive does on the line.
    pub expect: Expectation,
    /// Registers the request changes (also for a broadcast write, which gets no reply).
    pub write: Option<WritePlan>,
    /// The facts the judgement rests on.
    pub facts: Vec<Fact>,
    /// Why, in words, with registers in hex.
    pub detail: String,
    /// The fields the judgement needs that the description leaves out
    /// ("exceptions.illegal-count", "silence.broadcast", "loop_back"): the expectation is
    /// then the Modbus specification's (what the simulator does), and no device is held
    /// to it. The runner skips a check that rests on one, naming it.
    pub missing: Vec<String>,
}

impl Judgement {
    /// The weakest basis of the facts: a judgement is binding only if every fact it rests
    /// on is documented or derived.
    pub fn basis(&self) -> Basis {
        // A judgement that rests on a fact the description leaves out binds no device.
        if !self.missing.is_empty() {
            return Basis::Decision;
        }
        self.facts
            .iter()
            .map(|f| f.basis)
            .max()
            .unwrap_or(Basis::Documented)
    }

    /// "the description has no exceptions.illegal-count": why a check that rests on
    /// this judgement is skipped; `None` where nothing is missing.
    pub fn missing_reason(&self) -> Option<String> {
        (!self.missing.is_empty())
            .then(|| format!("the description has no {}", self.missing.join(", no ")))
    }

    /// The facts' citations, one line each.
    pub fn citations(&self) -> Vec<String> {
        self.facts.iter().map(Fact::citation).collect()
    }
}

impl DriveModel {
    /// What a drive of this model at node `own_address` does with `frame` (a whole RTU or
    /// ASCII frame, checksum included) received in `mode`.
    pub fn judge(&self, own_address: u8, mode: Mode, frame: &[u8]) -> Judgement {
        // An absent reason still means silence: the Modbus serial line answers none of
        // these (V1.02, 2.1, 2.4.1, 2.5.1.2).
        let silence = |reason: SilenceReason, detail: String| Judgement {
            expect: Expectation::Silence(reason),
            write: None,
            facts: self.silence.get(&reason).cloned().into_iter().collect(),
            detail,
            missing: match self.silence.contains_key(&reason) {
                true => vec![],
                false => vec![format!("silence.{}", reason.key())],
            },
        };
        let (body, checksum_ok) = match crate::codec::frame_parts(mode, frame) {
            Ok(p) => (p.body, p.checksum.is_valid()),
            Err(e) => {
                return silence(
                    SilenceReason::BadChecksum,
                    format!("not a {mode} frame: {e}"),
                )
            }
        };
        if !checksum_ok {
            return silence(
                SilenceReason::BadChecksum,
                format!(
                    "the {} is wrong",
                    if mode == Mode::Rtu { "CRC" } else { "LRC" }
                ),
            );
        }
        if frame.len() > self.limits.max_frame_in(mode) {
            let mut j = silence(
                SilenceReason::FrameTooLong,
                format!(
                    "the frame is {} {}, over the model's {}",
                    frame.len(),
                    if mode == Mode::Rtu {
                        "bytes"
                    } else {
                        "characters"
                    },
                    self.limits.max_frame_in(mode)
                ),
            );
            j.facts.push(self.limits.max_frame_fact.clone());
            return j;
        }
        let address = body[0];
        if address != self.broadcast && address != own_address {
            return silence(
                SilenceReason::OtherAddress,
                format!("addressed to node {address:02X}, this drive is {own_address:02X}"),
            );
        }
        let mut j = self.judge_body(mode, &body);
        if address == self.broadcast {
            let executes = matches!(
                j.expect,
                Expectation::WriteSingle | Expectation::WriteMultiple
            );
            let mut b = silence(
                SilenceReason::Broadcast,
                if executes {
                    format!("broadcast: executed ({}) and not answered", j.detail)
                } else {
                    format!("broadcast: not executed ({}) and not answered", j.detail)
                },
            );
            if executes {
                b.write = j.write.take();
            }
            b.missing.extend(j.missing);
            return b;
        }
        j
    }

    fn exception(&self, fault: Fault, extra: Vec<Fact>, detail: String) -> Judgement {
        let rule = self.rule(fault);
        let mut facts: Vec<Fact> = rule.map(|r| r.fact.clone()).into_iter().collect();
        facts.extend(extra);
        Judgement {
            expect: Expectation::Exception {
                fault,
                code: self.answer_code(fault),
            },
            write: None,
            facts,
            detail,
            missing: match rule {
                Some(_) => vec![],
                None => vec![format!("exceptions.{}", fault.key())],
            },
        }
    }

    /// A judgement of the loop-back function, which a description may leave out (the
    /// drive then echoes, as the Modbus application protocol's 08H 0000H does).
    fn loop_back(&self, facts: Vec<Option<&Fact>>, detail: String) -> Judgement {
        Judgement {
            expect: Expectation::LoopBack,
            write: None,
            missing: match facts.iter().all(Option::is_some) {
                true => vec![],
                false => vec!["loop_back".to_string()],
            },
            facts: facts.into_iter().flatten().cloned().collect(),
            detail,
        }
    }

    fn judge_body(&self, mode: Mode, body: &[u8]) -> Judgement {
        let fc = body[1];
        if !self.functions.contains(&fc) {
            return self.exception(
                Fault::IllegalFunction,
                vec![self.functions_fact.clone()],
                format!("function {fc:02X}H is not served"),
            );
        }
        let msg = match Message::parse_body(body, Direction::Request) {
            Ok(m) => m,
            Err(e) => {
                return self.exception(Fault::Malformed, vec![], format!("malformed request: {e}"))
            }
        };
        match msg.pdu {
            Pdu::ReadRequest { start, count } => self.judge_read(mode, start, count),
            Pdu::WriteSingle { register, value } => self.judge_write(
                start_values(register, &[value]),
                Expectation::WriteSingle,
                || format!("write {value:04X} to {}", self.describe(register)),
            ),
            Pdu::WriteMultipleRequest { start, values } => {
                let count = values.len();
                let limit = self.limits.write.get(mode);
                if count == 0 || count > usize::from(limit) {
                    return self.exception(
                        Fault::IllegalCount,
                        vec![self.limits.write.fact.clone()],
                        format!("10H count {count}: must be 1..{limit} in {mode}"),
                    );
                }
                let vals: Vec<u16> = values.iter().collect();
                self.judge_write(
                    start_values(start, &vals),
                    Expectation::WriteMultiple,
                    || format!("write {count} registers from {}", self.describe(start)),
                )
            }
            Pdu::LoopBack { test_code: 0, .. } => self.loop_back(
                vec![self.loop_back_fact.as_ref()],
                "loop-back: echo".to_string(),
            ),
            Pdu::LoopBack { test_code, .. } => self.loop_back(
                vec![
                    self.loop_back_fact.as_ref(),
                    self.loop_back_other_fact.as_ref(),
                ],
                format!("loop-back with test code {test_code:04X}H: echo"),
            ),
            // Parsed as a request, a served function code always gives one of the above.
            _ => self.exception(Fault::Malformed, vec![], "unexpected layout".to_string()),
        }
    }

    fn judge_read(&self, mode: Mode, start: u16, count: u16) -> Judgement {
        let limit = self.limits.read.get(mode);
        if count == 0 || count > limit {
            return self.exception(
                Fault::IllegalCount,
                vec![self.limits.read.fact.clone()],
                format!("03H count {count}: must be 1..{limit} in {mode}"),
            );
        }
        let mut registers = Vec::with_capacity(usize::from(count));
        let mut group = None;
        let mut facts = vec![self.functions_fact.clone()];
        for i in 0..u32::from(count) {
            let Some(r) = u16::try_from(u32::from(start) + i).ok() else {
                return self.exception(
                    Fault::IllegalRegister,
                    vec![],
                    format!("{start:04X} + {count} runs past FFFFH"),
                );
            };
            let info = match self.lookup(r) {
                Some(info) => info,
                None => {
                    return self.exception(
                        Fault::IllegalRegister,
                        vec![],
                        format!("{r:04X}H is not in the {} register map", self.id),
                    )
                }
            };
            if info.access == Access::NoAccess {
                return self.exception(
                    Fault::NoAccess,
                    vec![],
                    format!("{r:04X}H is marked '-' (no Modbus access)"),
                );
            }
            if info.access == Access::WriteOnly {
                let fact = self.block_of(r).map(|b| b.fact.clone());
                return self.exception(
                    Fault::IllegalRegister,
                    fact.into_iter().collect(),
                    format!("{} is write-only", self.describe(r)),
                );
            }
            if let Some(e) = self.crosses(&mut group, info.group, r) {
                return e;
            }
            self.note_origin(&info, &mut facts);
            registers.push(info.register);
        }
        Judgement {
            expect: Expectation::Read(ReadPlan { registers }),
            write: None,
            facts,
            detail: format!("read {count} from {}", self.describe(start)),
            missing: vec![],
        }
    }

    fn crosses(&self, group: &mut Option<usize>, g: usize, r: u16) -> Option<Judgement> {
        match *group {
            None => {
                *group = Some(g);
                None
            }
            Some(first) if first != g && self.limits.same_group => Some(self.exception(
                Fault::CrossesGroup,
                vec![self.limits.same_group_fact.clone()],
                format!(
                    "{r:04X}H is in {}, the request starts in {}",
                    self.group_name(g),
                    self.group_name(first)
                ),
            )),
            Some(_) => None,
        }
    }

    /// A write request: expected to be answered `expect` (its `detail` saying what it
    /// writes) where every register takes its value, else the judgement of the first
    /// that does not ([`Self::check_writes`]).
    fn judge_write(
        &self,
        writes: impl Iterator<Item = Option<(u16, u16)>>,
        expect: Expectation,
        detail: impl FnOnce() -> String,
    ) -> Judgement {
        let mut facts = vec![self.functions_fact.clone()];
        match self.check_writes(writes, &mut facts) {
            Ok(plan) => Judgement {
                expect,
                detail: detail(),
                write: Some(plan),
                facts,
                missing: vec![],
            },
            Err(j) => j,
        }
    }

    fn check_writes(
        &self,
        writes: impl Iterator<Item = Option<(u16, u16)>>,
        extra: &mut Vec<Fact>,
    ) -> Result<WritePlan, Judgement> {
        let mut plan = Vec::new();
        let mut group = None;
        for w in writes {
            let Some((r, value)) = w else {
                return Err(self.exception(
                    Fault::IllegalRegister,
                    vec![],
                    "the write runs past FFFFH".to_string(),
                ));
            };
            let Some(info) = self.lookup(r) else {
                return Err(self.exception(
                    Fault::IllegalRegister,
                    vec![],
                    format!("{r:04X}H is not in the {} register map", self.id),
                ));
            };
            if let Some(e) = self.crosses(&mut group, info.group, r) {
                return Err(e);
            }
            match info.access {
                Access::NoAccess => {
                    return Err(self.exception(
                        Fault::NoAccess,
                        vec![],
                        format!("{r:04X}H is marked '-' (no Modbus access)"),
                    ))
                }
                Access::ReadOnly => {
                    // A parameter marked read-only: the mark's own fact counts too.
                    return Err(match self.read_only_parameter(info.register) {
                        Some(p) => self.exception(
                            Fault::ReadOnly,
                            vec![p.fact.clone()],
                            format!(
                                "{} is parameter {}-{:02}, which the {} marks read-only",
                                self.describe(r),
                                info.register >> 8,
                                info.register & 0xFF,
                                self.manual
                            ),
                        ),
                        None => self.exception(
                            Fault::ReadOnly,
                            vec![],
                            format!("{} is read-only", self.describe(r)),
                        ),
                    });
                }
                Access::Reserved => {
                    return Err(self.exception(
                        Fault::ReservedWrite,
                        vec![],
                        format!("{} is reserved", self.describe(r)),
                    ))
                }
                Access::ReadWrite | Access::WriteOnly => {}
            }
            if let Some(b) = self
                .block_of(info.register)
                .filter(|_| info.origin == Origin::Block)
            {
                if !b.admits(value) {
                    let bound = match (b.min, b.max) {
                        (Some(lo), Some(hi)) => format!("{lo:04X}..{hi:04X}"),
                        (Some(lo), None) => format!("{lo:04X} or more"),
                        (None, Some(hi)) => format!("{hi:04X} or less"),
                        (None, None) => String::new(),
                    };
                    return Err(self.exception(
                        Fault::DataOutOfRange,
                        vec![b.fact.clone()],
                        format!("{value:04X} is outside {bound} of {}", self.describe(r)),
                    ));
                }
            }
            if let Some((max, fact)) = self.named(info.register).and_then(|n| n.max.as_ref()) {
                if value > *max {
                    return Err(self.exception(
                        Fault::DataOutOfRange,
                        vec![fact.clone()],
                        format!(
                            "{value:04X} is over the maximum {max:04X} of {}",
                            self.describe(r)
                        ),
                    ));
                }
            }
            self.note_origin(&info, extra);
            plan.push((info.register, value));
        }
        Ok(WritePlan { writes: plan })
    }

    /// Registers that only an example uses, and alias spellings, are the model's
    /// decisions: a judgement that rests on them says so.
    fn note_origin(&self, info: &super::RegisterInfo, facts: &mut Vec<Fact>) {
        if info.origin == Origin::Example {
            if let Some((.., f)) = self.example_registers.iter().find(|e| e.0 == info.register) {
                if !facts.contains(f) {
                    facts.push(f.clone());
                }
            }
        }
        if info.via_alias {
            for a in &self.aliases {
                if !facts.contains(&a.fact) {
                    facts.push(a.fact.clone());
                }
            }
        }
    }

    /// "2502H (Frequency command (0.01 Hz))", "0123H (example register)", "0005H (group 0)".
    pub fn describe(&self, register: u16) -> String {
        let mut s = format!("{register:04X}H");
        match self.lookup(register) {
            Some(info) => {
                let _ = match (self.named(info.register), info.origin) {
                    (Some(n), _) => write!(s, " ({})", n.name),
                    (None, Origin::Example) => write!(s, " (example register)"),
                    (None, Origin::Block) => match self.block_of(info.register) {
                        Some(b) => match &b.name {
                            Some(n) => write!(s, " ({n})"),
                            None => {
                                write!(s, " (block {:04X}..{:04X})", b.span.start(), b.span.end())
                            }
                        },
                        None => Ok(()),
                    },
                    (None, _) => write!(s, " ({})", self.group_name(info.group)),
                };
                if info.via_alias {
                    let _ = write!(s, " = {:04X}H", info.register);
                }
            }
            None => s.push_str(" (not in the map)"),
        }
        s
    }
}

fn start_values(start: u16, values: &[u16]) -> impl Iterator<Item = Option<(u16, u16)>> + '_ {
    values
        .iter()
        .enumerate()
        .map(move |(i, v)| u16::try_from(usize::from(start) + i).ok().map(|r| (r, *v)))
}
