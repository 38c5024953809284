//! The live side: reading every parameter, and carrying out a restore plan through the
//! runner's master ([`Ctx`]), so that every reply is judged by the one judge and every
//! register written is in the runner's journal first (an interrupted restore is undone
//! by the runner's own restore, as an interrupted `check` is).

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};

use super::audit::{now, AuditLog, AuditRecord};
use super::PlannedWrite;
use crate::codec::hex::Hex;
use crate::codec::pdu::{Direction, Message, Pdu};
use crate::judge;
use crate::model::DriveModel;
use crate::runner::{Ctx, RestoreRecord, RunError, SetupError};

/// Why the device's parameters could not be read.
#[derive(Debug, thiserror::Error)]
pub enum LiveError {
    /// The link failed, or the device stopped answering.
    #[error(transparent)]
    Run(#[from] RunError),
    /// A read was refused or not answered.
    #[error("{0}")]
    Read(String),
    /// Ctrl-C, SIGTERM or SIGHUP.
    #[error("interrupted before every parameter was read")]
    Interrupted,
}

/// What a read of every parameter found.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct ReadOut {
    /// The values read, by register.
    pub values: BTreeMap<u16, u16>,
    /// The registers the device refused to read one by one, with its answer in words
    /// (a firmware that does not serve a parameter its manual lists).
    pub refused: BTreeMap<u16, String>,
}

/// Reads the registers of `plan` (start, count) from `node`. A read the device refuses
/// with an exception is read again one register at a time, so that one register it does
/// not serve costs only that register; no valid answer ends the read.
pub fn read_values(
    ctx: &mut Ctx<'_>,
    node: u8,
    plan: &[(u16, u16)],
    stop: &AtomicBool,
) -> Result<ReadOut, LiveError> {
    let mut out = ReadOut::default();
    for &(start, count) in plan {
        if stop.load(Ordering::Relaxed) {
            return Err(LiveError::Interrupted);
        }
        match ctx.read_at(node, start, count)? {
            Ok(values) => {
                for (i, v) in values.into_iter().enumerate() {
                    out.values.insert(start.wrapping_add(i as u16), v);
                }
            }
            Err(SetupError::Refused { .. }) if count > 1 => {
                for r in (0..count).map(|i| start.wrapping_add(i)) {
                    if stop.load(Ordering::Relaxed) {
                        return Err(LiveError::Interrupted);
                    }
                    match ctx.read_at(node, r, 1)? {
                        Ok(v) => {
                            out.values.insert(r, v[0]);
                        }
                        Err(e @ SetupError::Refused { .. }) => {
                            out.refused.insert(r, e.to_string());
                        }
                        Err(e) => return Err(LiveError::Read(e.to_string())),
                    }
                }
            }
            Err(e @ SetupError::Refused { .. }) => {
                out.refused.insert(start, e.to_string());
            }
            Err(e) => return Err(LiveError::Read(e.to_string())),
        }
    }
    Ok(out)
}

/// The identification register's value, where the model has one and the device answers.
pub fn read_identification(ctx: &mut Ctx<'_>, model: &DriveModel, node: u8) -> Option<u16> {
    let r = model.identification.as_ref()?.register?;
    match ctx.read_at(node, r, 1) {
        Ok(Ok(v)) => v.first().copied(),
        _ => None,
    }
}

/// What came of one planned write.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum StepResult {
    /// Confirmed by the device and read back with the values written.
    Written,
    /// Confirmed, but the read-back showed other values.
    NotHeld {
        /// What was read back (empty where the read-back failed).
        read_back: Vec<u16>,
        /// Why, in words.
        why: String,
    },
    /// The device answered with an exception.
    Refused {
        /// The exception code.
        code: u8,
        /// The reply in words, with the model's meaning of the code.
        why: String,
    },
    /// No valid reply, or the link failed.
    NoAnswer(String),
}

/// One planned write and what came of it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Step {
    /// The write.
    pub write: PlannedWrite,
    /// The values read just before it (journalled).
    pub before: Vec<u16>,
    /// Whether the write went out (not where the read before it failed).
    pub sent: bool,
    /// The reply frame, where one came.
    pub reply: Option<Vec<u8>>,
    /// What came of it.
    pub result: StepResult,
}

/// What a restore did.
#[derive(Debug, Clone, Default)]
pub struct RestoreOutcome {
    /// The writes sent, in order, with what came of each; the last one stopped the
    /// restore where it is not [`StepResult::Written`].
    pub steps: Vec<Step>,
    /// The writes not sent (after a stop or an interruption).
    pub not_sent: Vec<PlannedWrite>,
    /// Whether Ctrl-C, SIGTERM or SIGHUP stopped it.
    pub interrupted: bool,
    /// The runner's journal as the restore left it: (node, register, value before).
    pub journal: Vec<(u8, u16, u16)>,
    /// After an interruption: the runner's restore of every journalled register.
    pub undo: Vec<RestoreRecord>,
}

impl RestoreOutcome {
    /// Whether every planned write was written and read back.
    pub fn complete(&self) -> bool {
        !self.interrupted
            && self.not_sent.is_empty()
            && self.steps.iter().all(|s| s.result == StepResult::Written)
    }

    /// The step that stopped the restore, if one did.
    pub fn failed(&self) -> Option<&Step> {
        self.steps.iter().find(|s| s.result != StepResult::Written)
    }
}

/// Whether `reply` is the normal reply to the write `w`.
fn confirms(ctx: &Ctx<'_>, w: &PlannedWrite, reply: &[u8]) -> bool {
    let Some(body) = judge::body_of(ctx.mode, reply) else {
        return false;
    };
    let Ok(m) = Message::parse_body(&body, Direction::Response) else {
        return false;
    };
    match m.pdu {
        Pdu::WriteSingle { register, value } => {
            w.function == 0x06 && register == w.start && Some(&value) == w.new.first()
        }
        Pdu::WriteMultipleResponse { start, count } => {
            w.function == 0x10 && start == w.start && usize::from(count) == w.new.len()
        }
        _ => false,
    }
}

/// Carries out `writes` on `node`, one after another: each register is read and
/// journalled first, the write goes out and its reply is judged, the registers are read
/// back, and one line per register goes to `audit` before the next write. The first
/// write that is refused, not answered or not held stops it (what was written stays:
/// running the same restore again plans only what is left). `stop` (Ctrl-C, SIGTERM)
/// ends it after the current write, and then the runner's restore undoes every
/// journalled register, each undo in the audit log too. An audit line that cannot be
/// written stops the restore before the next write.
pub fn restore(
    ctx: &mut Ctx<'_>,
    model: &DriveModel,
    node: u8,
    writes: &[PlannedWrite],
    audit: &mut AuditLog,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(&Step),
) -> std::io::Result<RestoreOutcome> {
    let mut out = RestoreOutcome::default();
    let mut rest = writes.iter();
    for w in rest.by_ref() {
        if stop.load(Ordering::Relaxed) {
            out.interrupted = true;
            out.not_sent.push(w.clone());
            break;
        }
        let step = one_write(ctx, model, node, w);
        for (i, r) in w.registers().enumerate().filter(|_| step.sent) {
            audit.append(&AuditRecord {
                time: now(),
                node,
                register: format!("{r:04X}"),
                old: step.before.get(i).copied().unwrap_or(w.old[i]),
                new: w.new[i],
                function: format!("{:02X}", w.function),
                request: w.hex(),
                reply: step
                    .reply
                    .as_deref()
                    .map(|b| Hex(b).to_string())
                    .unwrap_or_default(),
                outcome: outcome_words(&step.result, w, i),
                verified: step.result == StepResult::Written,
                undo: false,
            })?;
        }
        progress(&step);
        let stops = step.result != StepResult::Written;
        out.steps.push(step);
        if stops {
            break;
        }
    }
    out.not_sent.extend(rest.cloned());
    out.journal = ctx.journal().to_vec();
    if out.interrupted {
        out.undo = ctx.restore();
        for rec in out.undo.iter().filter(|r| r.changed) {
            // The runner writes a register back with 06H and takes only the echo of its
            // request as success, so the reply of a restored register is its request.
            let frame = ctx.frame_to(
                node,
                Pdu::WriteSingle {
                    register: rec.register,
                    value: rec.original,
                },
            );
            let written = out
                .steps
                .iter()
                .find_map(|s| {
                    s.write
                        .registers()
                        .position(|r| r == rec.register)
                        .map(|i| s.write.new[i])
                })
                .unwrap_or(rec.original);
            audit.append(&AuditRecord {
                time: now(),
                node: rec.node.unwrap_or(node),
                register: format!("{:04X}", rec.register),
                old: written,
                new: rec.original,
                function: "06".into(),
                request: Hex(&frame).to_string(),
                reply: if rec.restored {
                    Hex(&frame).to_string()
                } else {
                    String::new()
                },
                outcome: format!("undo: {}", rec.detail),
                verified: rec.restored,
                undo: true,
            })?;
        }
    }
    Ok(out)
}

/// One write: journal, send, judge, read back.
fn one_write(ctx: &mut Ctx<'_>, model: &DriveModel, node: u8, w: &PlannedWrite) -> Step {
    let mut step = Step {
        write: w.clone(),
        before: Vec::new(),
        sent: false,
        reply: None,
        result: StepResult::Written,
    };
    for r in w.registers() {
        match ctx.remember_at(node, r) {
            Ok(Ok(v)) => step.before.push(v),
            Ok(Err(e)) => {
                step.result = StepResult::NoAnswer(format!(
                    "not sent: the read of {r:04X}H before it (for the journal) failed: {e}"
                ));
                return step;
            }
            Err(e) => {
                step.result = StepResult::NoAnswer(format!(
                    "not sent: the read of {r:04X}H before it (for the journal) failed: {e}"
                ));
                return step;
            }
        }
    }
    step.sent = true;
    let probed = match ctx.probe_at(node, w.frame.clone(), None) {
        Ok(p) => p,
        Err(e) => {
            step.result = StepResult::NoAnswer(format!("the link failed: {e}"));
            return step;
        }
    };
    step.reply = probed.exchange.reply.clone();
    let reply = match &probed.exchange.reply {
        Some(r) => r.clone(),
        None => {
            step.result = StepResult::NoAnswer(format!(
                "no valid reply ({}): it may or may not have been written",
                probed.comparison.actual
            ));
            return step;
        }
    };
    if let Some(body) = judge::body_of(ctx.mode, &reply) {
        if body.len() == 3 && body[1] & 0x80 != 0 {
            let code = body[2];
            step.result = StepResult::Refused {
                code,
                why: format!(
                    "exception {code:02X}H{} ({})",
                    model
                        .exception_meaning(code)
                        .map(|m| format!(", {m} in the {}", model.manual))
                        .unwrap_or_default(),
                    judge::describe_reply(ctx.mode, &reply)
                ),
            };
            return step;
        }
    }
    if !confirms(ctx, w, &reply) {
        step.result = StepResult::NoAnswer(format!(
            "the reply is not the normal reply to this write: {}",
            judge::describe_reply(ctx.mode, &reply)
        ));
        return step;
    }
    let count = u16::try_from(w.new.len()).unwrap_or(u16::MAX);
    step.result = match ctx.read_at(node, w.start, count) {
        Ok(Ok(v)) if v == w.new => StepResult::Written,
        Ok(Ok(v)) => StepResult::NotHeld {
            why: format!(
                "confirmed, but reads back {} instead of {}",
                words(&v),
                words(&w.new)
            ),
            read_back: v,
        },
        Ok(Err(e)) => StepResult::NotHeld {
            read_back: Vec::new(),
            why: format!("confirmed, but the read-back failed: {e}"),
        },
        Err(e) => StepResult::NotHeld {
            read_back: Vec::new(),
            why: format!("confirmed, but the read-back failed: {e}"),
        },
    };
    step
}

/// Values as "0005H 0007H".
fn words(v: &[u16]) -> String {
    v.iter()
        .map(|x| format!("{x:04X}H"))
        .collect::<Vec<_>>()
        .join(" ")
}

/// The audit line's outcome for register `i` of `w`.
fn outcome_words(result: &StepResult, w: &PlannedWrite, i: usize) -> String {
    match result {
        StepResult::Written => format!("written, read back {:04X}H", w.new[i]),
        StepResult::NotHeld { why, .. } => format!("not held: {why}"),
        StepResult::Refused { why, .. } => format!("refused: {why}"),
        StepResult::NoAnswer(why) => format!("no answer: {why}"),
    }
}
