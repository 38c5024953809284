//! Shrinking a finding by replaying smaller candidates on the device (delta debugging):
//! fewer frames of a back-to-back sequence, fewer data bytes of a frame (its checksum
//! recomputed where it was valid). A candidate is kept when its replay gives the same
//! kind of finding. Before every replay the device must answer (a hang is waited out).

use std::time::Duration;

use super::cases::{damage_checksum, Step};
use super::observe::observe;
use super::state::{recover, State};
use super::{FuzzConfig, FuzzFinding, Kind};
use crate::codec::pdu::Pdu;
use crate::codec::{frame_of_body, frame_parts, Mode};
use crate::runner::{Ctx, RunError};

/// Replays at most this many candidates per finding.
const MAX_REPLAYS: u32 = 12;

/// Whether `step` still gives a finding of `kind`.
fn reproduces(
    ctx: &mut Ctx<'_>,
    step: &Step,
    kind: Kind,
    state: &mut State,
    wait: Duration,
) -> bool {
    // The device must answer before a replay can mean anything.
    match recover(ctx, wait) {
        Ok(Some(_)) => {}
        _ => return false,
    }
    match observe(ctx, step, state) {
        Ok(Some(o)) => o.kind == kind,
        Err(RunError::DeviceLost(_)) => kind == Kind::Hang,
        _ => false,
    }
}

/// Smaller frames than `frame`: its body without data bytes (all of them, then halves,
/// then one at a time), its checksum recomputed if it was valid, left wrong if not.
fn smaller_frames(mode: Mode, frame: &[u8]) -> Vec<Vec<u8>> {
    let Ok(parts) = frame_parts(mode, frame) else {
        return Vec::new();
    };
    let valid = parts.checksum.is_valid();
    let body = parts.body;
    // Keep the header: address, function, and for 10H the start, count and byte count.
    let head = match body.get(1) {
        Some(0x10) => 7.min(body.len()),
        _ => 2.min(body.len()),
    };
    let data = body.len() - head;
    let mut cuts: Vec<usize> = vec![data];
    let mut k = data / 2;
    while k > 0 {
        cuts.push(k);
        k /= 2;
    }
    cuts.dedup();
    let mut out = Vec::new();
    for cut in cuts.into_iter().filter(|&c| c > 0) {
        let b: Vec<u8> = body[..body.len() - cut].to_vec();
        if let Ok(mut f) = frame_of_body(mode, &b) {
            if !valid {
                damage_checksum(mode, &mut f);
            }
            out.push(f);
        }
    }
    out
}

/// Minimizes `finding` in place: its `minimized` frames, whether they `reproduced`, and
/// the replays spent.
pub fn minimize(ctx: &mut Ctx<'_>, finding: &mut FuzzFinding, state: &mut State, cfg: &FuzzConfig) {
    let wait = cfg.recover_wait;
    let kind = finding.kind;
    if let Some(t) = finding.timed.clone() {
        // Timing damage: the same damage on the shortest request, at the first position
        // that reproduces it.
        let (best, reproduced, replays) =
            super::timing::minimize(ctx, &t, kind, state, MAX_REPLAYS);
        finding.minimized = vec![best.bytes()];
        finding.timed = Some(best);
        finding.reproduced = reproduced;
        finding.replays = replays;
        let _ = recover(ctx, wait);
        return;
    }
    if kind == Kind::WrongValue {
        minimize_wrong_value(ctx, finding, state, wait);
        return;
    }
    let mut best = finding.frames.clone();
    let mut replays = 0;
    if finding.burst {
        // Drop frames from the sequence while it still reproduces.
        while best.len() > 1 && replays < MAX_REPLAYS {
            let candidate: Vec<Vec<u8>> = best[..best.len() - 1].to_vec();
            replays += 1;
            if reproduces(ctx, &Step::Burst(candidate.clone()), kind, state, wait) {
                best = candidate;
            } else {
                break;
            }
        }
        finding.reproduced =
            replays > 0 || reproduces(ctx, &Step::Burst(best.clone()), kind, state, wait);
    } else if let Some(frame) = best.first().cloned() {
        let mut current = frame;
        let mut reproduced = false;
        'shrink: loop {
            for candidate in smaller_frames(ctx.mode, &current) {
                if replays >= MAX_REPLAYS {
                    break 'shrink;
                }
                replays += 1;
                if reproduces(ctx, &Step::Frame(candidate.clone()), kind, state, wait) {
                    current = candidate;
                    reproduced = true;
                    continue 'shrink;
                }
            }
            break;
        }
        if !reproduced && replays < MAX_REPLAYS {
            replays += 1;
            reproduced = reproduces(ctx, &Step::Frame(current.clone()), kind, state, wait);
        }
        finding.reproduced = reproduced;
        best = vec![current];
    }
    finding.replays = replays;
    finding.minimized = best;
    let _ = recover(ctx, wait);
}

/// A wrong value needs a known value: the shortest sequence is a write of the value the
/// device returns, then a read of that one register.
fn minimize_wrong_value(
    ctx: &mut Ctx<'_>,
    finding: &mut FuzzFinding,
    state: &mut State,
    wait: Duration,
) {
    let Some(r) = finding.register else { return };
    let mut replays = 0;
    let mut reproduced = false;
    let mut frames = Vec::new();
    if let Ok(Ok(v)) = ctx.remember_current(r) {
        let write = ctx.frame(Pdu::WriteSingle {
            register: r,
            value: v,
        });
        let read = ctx.frame(Pdu::ReadRequest { start: r, count: 1 });
        replays += 1;
        let wrote = matches!(observe(ctx, &Step::Frame(write.clone()), state), Ok(None));
        reproduced = wrote
            && matches!(observe(ctx, &Step::Frame(read.clone()), state), Ok(Some(o)) if o.kind == Kind::WrongValue);
        frames = vec![write, read];
    }
    let _ = recover(ctx, wait);
    finding.replays = replays;
    finding.reproduced = reproduced;
    finding.minimized = frames;
}
