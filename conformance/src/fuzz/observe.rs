//! Sending one case and judging it against the model: the careful path every other way
//! of sending (brisk, minimizing) falls back on.

use std::time::{Duration, Instant};

use super::cases::Step;
use super::state::{Observed, State};
use super::Kind;
use crate::judge::{self, Judge, Severity};
use crate::model::{Basis, DriveModel, Expectation, Fact, Role};
use crate::runner::{Ctx, RunError};

/// The fact behind a value a read must return: the device confirmed writing it.
fn written_fact() -> Fact {
    Fact {
        basis: Basis::Derived,
        source: Some("Modbus Application Protocol V1.1b3, 6.6 and 6.12: a normal 06H/10H response confirms the write".into()),
        rule: Some("a register the device confirmed writing returns the written value (plain parameters)".into()),
        why: None,
    }
}

/// Whether a read of `register` must return what was written to it: a plain read/write
/// parameter, not a register the drive changes itself or that has a role.
fn plain(model: &DriveModel, register: u16) -> bool {
    model.named(register).and_then(|n| n.role).is_none()
        && model
            .named(register)
            .is_none_or(|n| n.role != Some(Role::Operation))
        && model
            .lookup(register)
            .is_some_and(|i| i.access == crate::model::Access::ReadWrite && i.register == register)
}

/// Why a case is not judged when the model's prediction for it rests on a field the
/// description leaves out (an exception rule, a silence, the loop-back).
pub const UNDESCRIBED: &str = "its prediction rests on a field the description leaves out";

/// Why a case counts as not sent where this host could not put its request on the
/// emulated line whole ([`RunError::HostStalled`]).
pub const HOST_STALLED: &str =
    "this host stalled while pacing every send of the request (an emulated line on a busy host): nothing to judge";

/// Sends one step and judges it. `Ok(None)`: the device did what the model predicts.
/// `Err(DeviceLost)`: it stopped answering (a hang).
pub fn observe(
    ctx: &mut Ctx<'_>,
    step: &Step,
    state: &mut State,
) -> Result<Option<Observed>, RunError> {
    match step {
        Step::Burst(frames) => {
            let all: Vec<u8> = frames.concat();
            // Long enough for the answers to every frame of the burst to be over before
            // the probe (on a paced line, each answer takes its delay and its bytes).
            let per_frame = match ctx.line_timing() {
                Some(l) => {
                    ctx.model.response_delay(&l) + Duration::from_micros(16 * l.char_time_us())
                }
                None => Duration::from_millis(2),
            };
            let n = u32::try_from(frames.len()).unwrap_or(u32::MAX);
            let pause = ctx.silence_window() + per_frame * n;
            let t0 = Instant::now();
            ctx.send_raw(&all, pause)?;
            // The next request must be answered at once: one probe without a resend (a
            // resend a timeout later would hide a receiver that needs a silence to
            // recover); if it is not, the liveness probe (with its resend) tells whether
            // the device came back.
            let Some(r) =
                crate::runner::liveness::liveness_register(ctx.model, ctx.opts.address, ctx.mode)
            else {
                return Ok(None);
            };
            let probe = ctx.frame(crate::codec::pdu::Pdu::ReadRequest { start: r, count: 1 });
            let (ex, _) = ctx.exchange(&probe, true)?;
            if !ex.after_echo().is_empty() {
                return Ok(None);
            }
            Ok(Some(Observed {
                kind: Kind::Hang,
                severity: Severity::Deviation,
                text: format!(
                    "after {} frames sent back to back (less than t3.5 apart), the next request {} got no reply; the device answered again {:.1} s later",
                    frames.len(),
                    judge::show(ctx.mode, &probe),
                    t0.elapsed().as_secs_f64()
                ),
                exchange: None,
                register: None,
                recovery: Some(Some(t0.elapsed())),
                field: super::signature::of_request(ctx.mode, step),
            }))
        }
        Step::Timed(t) => super::timing::observe(ctx, t, state),
        Step::Frame(frame) => {
            let model = ctx.model;
            let mode = ctx.mode;
            let judgement = model.judge(ctx.opts.address, mode, frame);
            let fact = written_fact();
            let known: Option<Vec<Option<u16>>> = match &judgement.expect {
                Expectation::Read(plan)
                    if plan.registers.iter().any(|r| state.written.contains_key(r)) =>
                {
                    Some(
                        plan.registers
                            .iter()
                            .map(|r| state.written.get(r).copied())
                            .collect(),
                    )
                }
                _ => None,
            };
            let p = ctx.probe(frame.clone(), known.clone().map(|k| (k, fact.clone())))?;
            let diff = Judge::new(model).differences(
                &p.judgement,
                &p.exchange.conversation(mode, ctx.opts.address),
                known.as_deref().map(|k| (k, &fact)),
            );
            let values = p.read_values();
            // What the device now holds, as far as its answers tell.
            let mut wrong = None;
            if let (Expectation::Read(plan), Some(v)) = (&p.judgement.expect, &values) {
                for (r, x) in plan.registers.iter().zip(v) {
                    if let Some(&w) = state.written.get(r) {
                        if w != *x && wrong.is_none() {
                            wrong = Some(*r);
                        }
                    }
                    state.known.insert(*r, *x);
                }
            }
            if diff.findings.is_empty() {
                if let (Some(plan), true) = (&p.judgement.write, p.judgement.expect.replies()) {
                    for &(r, v) in &plan.writes {
                        state.known.insert(r, v);
                        if plain(model, r) {
                            state.written.insert(r, v);
                        }
                    }
                }
                return Ok(None);
            }
            let rx_empty = p.exchange.after_echo().is_empty();
            let kind = match (&p.judgement.expect, rx_empty) {
                (Expectation::Silence(_), _) => Kind::UnexpectedReply,
                (_, true) => Kind::NoReply,
                _ if wrong.is_some() => Kind::WrongValue,
                _ => Kind::Mismatch,
            };
            let severity = diff.worst().unwrap_or(Severity::Deviation);
            let text = diff.text();
            let field = super::signature::of_difference(
                kind,
                mode,
                &p.judgement.expect,
                &p.exchange,
                diff.expected.as_deref(),
                wrong,
            );
            Ok(Some(Observed {
                kind,
                severity,
                text,
                exchange: Some(p.record()),
                register: wrong,
                recovery: None,
                field,
            }))
        }
    }
}
