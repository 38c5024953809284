//! The oracle and the campaign of one mode.
//!
//! Every case goes through the runner's [`Ctx`]: the model judges the frame, the master
//! sends it and collects the answer (stripping a local echo), and every exchange that
//! brought nothing back is followed by a liveness probe. The comparison is the runner's
//! ([`Judge::differences`]): any difference is a finding. Frames sent back to back are
//! judged by a liveness probe only (the standard leaves open whether a receiver takes them
//! as one frame or two). A liveness probe also follows every `probe_every` cases.
//!
//! A device that does not answer its probe has hung: the campaign waits, re-probing with
//! growing pauses (a device that stays overloaded while it hears frames needs silence to
//! recover), records how long it took, and carries on only if it came back.

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::cases::{Case, Generator, Step};
use super::observe::{observe, HOST_STALLED, UNDESCRIBED};
use super::state::{function_of, recover, Observed, State};
use super::{FuzzConfig, FuzzFinding, Kind, ModeOutcome};
use crate::codec::Mode;
use crate::judge::Severity;
use crate::model::{DriveModel, Expectation};
use crate::runner::{Ctx, Options, RunError};
use crate::transport::Transport;
use crate::vectors::VectorFile;

/// The least time `case` needs on a line with timing: its bytes at the character time,
/// t3.5 before each frame, the model's response delay or the silence window, and the
/// liveness probe after a silence.
fn line_time(ctx: &Ctx<'_>, step: &Step, replied: Option<usize>) -> Duration {
    let Some(line) = ctx.line_timing() else {
        return Duration::ZERO;
    };
    let ch = Duration::from_micros(line.char_time_us());
    let t35 = Duration::from_micros(line.t3_5_us());
    let delay = ctx.model.response_delay(&line);
    let n = |k: usize| ch * u32::try_from(k).unwrap_or(u32::MAX);
    let probe = |ctx: &Ctx<'_>| {
        let len = if ctx.mode == Mode::Rtu {
            8 + 7
        } else {
            17 + 15
        };
        n(len) + t35 * 2 + delay
    };
    match step {
        Step::Burst(fs) => {
            n(fs.iter().map(Vec::len).sum()) + t35 + ctx.silence_window() + probe(ctx)
        }
        Step::Timed(t) => super::timing::line_time(ctx, t, replied.is_some()),
        Step::Frame(f) => match replied {
            Some(r) => n(f.len() + r) + t35 * 2 + delay,
            None => n(f.len()) + t35 + ctx.silence_window() + probe(ctx),
        },
    }
}

/// Runs the campaign of `mode`: preflight, cases until the count or the duration is
/// reached (or `stop`), minimizing each new finding, then the restore.
#[allow(clippy::too_many_arguments)]
pub fn fuzz_mode(
    model: &DriveModel,
    vectors: Option<&VectorFile>,
    mode: Mode,
    transport: Box<dyn Transport>,
    opts: &Options,
    cfg: &FuzzConfig,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(u64, usize),
) -> ModeOutcome {
    let mut ctx = Ctx::new(model, vectors, mode, opts, transport);
    let mut out = ModeOutcome {
        mode: Some(mode),
        ..ModeOutcome::default()
    };
    ctx.current = format!("{mode}.fuzz.preflight");
    match ctx.preflight() {
        Ok(v) if ctx.lost.is_none() => {
            out.ran = true;
            out.preflight = v.pass_summary;
        }
        Ok(v) => {
            out.preflight = v.error.unwrap_or_default();
            out.stopped = Some(format!("no answer to the preflight: {}", out.preflight));
            return out;
        }
        Err(e) => {
            out.stopped = Some(e.to_string());
            return out;
        }
    }
    // A real port, or the simulator's paced pseudo-terminal (which frames RTU by silence).
    let timed = ctx.line_timing().is_some();
    let gen = Generator::new(
        model,
        vectors,
        mode,
        opts.address,
        opts.other_address,
        cfg.writes,
        cfg.seed,
        timed,
    );
    // Timing damage where the link carries the line's timing (see `timing`).
    let mut gen = match (super::timing::unavailable(&ctx), ctx.line_timing()) {
        (None, Some(line)) => gen.with_timing_damage(line),
        (why, _) => {
            out.timing.not_sent = why;
            gen
        }
    };
    if let Some(storm) = &cfg.storm {
        return super::storm::run(&mut ctx, storm, cfg, out, stop);
    }
    let mut state = State::default();
    let mut by_signature: BTreeMap<String, usize> = BTreeMap::new();
    let mut bound = Duration::ZERO;
    let started = Instant::now();
    let mut spent_minimizing = Duration::ZERO;
    // The brisk path where the link has no timing (see [`super::brisk`]).
    let mut guard =
        (ctx.line_timing().is_none() && !cfg.full_windows).then(super::brisk::GuardStats::default);
    ctx.master_mut().set_brisk(guard.is_some());
    let mut prev: Option<Case> = None;
    let mut prev_careful = false;
    loop {
        if stop.load(Ordering::Relaxed) {
            out.stopped = Some("interrupted".into());
            break;
        }
        if cfg.cases.is_some_and(|n| out.cases >= n) {
            break;
        }
        if cfg
            .duration
            .is_some_and(|d| started.elapsed().saturating_sub(spent_minimizing) >= d)
        {
            break;
        }
        let case = gen.next_case(&state.known);
        // Safety: every frame vetted, whatever made it.
        let mut journal = Vec::new();
        let mut refused = None;
        for f in case.step.frames() {
            match super::safety::vet(
                model,
                mode,
                f,
                opts.address,
                cfg.writes,
                opts.allow_motion,
                opts.allow_restart,
                &state.known,
            ) {
                Ok(regs) => journal.extend(regs),
                Err(why) => refused = Some(why),
            }
        }
        if let Some(why) = refused {
            *out.skipped.entry(why).or_default() += 1;
            continue;
        }
        // Through a Modbus TCP gateway only whole frames with a valid checksum cross, one
        // at a time: damaged and back-to-back cases are not sent.
        if let Some(why) = ctx.frames_only() {
            if !super::cases::crosses_a_gateway(mode, &case.step) {
                *out.skipped.entry(why).or_default() += 1;
                continue;
            }
        }
        // A case of the shape of a hang the campaign knows costs seconds and tells little
        // more: sent only within the re-trigger budget (see `steer`).
        if !out.hangs.admits(mode, &case.step) {
            *out.skipped.entry(super::steer::STEERED_AWAY).or_default() += 1;
            continue;
        }
        ctx.current = format!("{mode}.fuzz.case-{}", case.index);
        let mut lost = None;
        let mut stalled = false;
        for r in journal {
            match ctx.remember(r) {
                Ok(_) => {}
                Err(RunError::DeviceLost(w)) => lost = Some(w),
                Err(RunError::HostStalled(_)) => {
                    stalled = true;
                    break;
                }
                // A register read back for the journal is in the map: never undescribed.
                Err(RunError::Undescribed(_)) => {}
                Err(RunError::Transport(e)) => {
                    out.stopped = Some(e.to_string());
                    break;
                }
            }
        }
        if out.stopped.is_some() {
            break;
        }
        if stalled {
            *out.skipped.entry(HOST_STALLED).or_default() += 1;
            continue;
        }
        out.cases += 1;
        if let Step::Timed(t) = &case.step {
            *out.timing.sent.entry(t.damage.class()).or_default() += 1;
        }
        let sent_at = Instant::now();
        let mut doubt = false;
        let result = match (lost, guard.as_mut()) {
            (Some(w), _) => Err(RunError::DeviceLost(w)),
            (None, Some(g)) => {
                super::brisk::observe(&mut ctx, &case.step, &mut state, g).map(|(o, d)| {
                    doubt = d;
                    o
                })
            }
            (None, None) => {
                // A case this host stalled under (its request never left whole) is sent
                // again, as `check` runs a check again, before it counts as not sent.
                let mut runs = 1;
                loop {
                    match observe(&mut ctx, &case.step, &mut state) {
                        Err(RunError::HostStalled(_)) if runs < crate::runner::HOST_STALL_RUNS => {
                            runs += 1;
                            out.host_reruns += 1;
                        }
                        r => break r,
                    }
                }
            }
        };
        let result = match result {
            Ok(None) if (case.index + 1).is_multiple_of(cfg.probe_every.max(1)) => {
                let answered = if guard.is_some() {
                    super::brisk::periodic(&mut ctx).map(|(answered, clean)| {
                        doubt |= !clean;
                        answered
                    })
                } else {
                    ctx.liveness()
                };
                match answered {
                    Ok(true) => Ok(None),
                    Ok(false) => Err(RunError::DeviceLost(format!(
                        "no answer to the periodic liveness probe after case {}",
                        case.index
                    ))),
                    Err(e) => Err(e),
                }
            }
            r => r,
        };
        // The guard of the brisk path: a case in doubt, and the one before it, are sent
        // again with full windows; only those verdicts count.
        let mut verdicts = Vec::new();
        let mut careful = false;
        match guard.as_mut() {
            Some(g) => {
                let stray = ctx.master_mut().take_stray();
                g.stray_bytes += stray as u64;
                let late_could_make_it = matches!(&result, Ok(Some(o))
                    if matches!(o.kind, Kind::Mismatch | Kind::UnexpectedReply | Kind::WrongValue));
                if doubt || stray > 0 || late_could_make_it {
                    let before = prev.as_ref().filter(|_| !prev_careful);
                    let steps: Vec<&Step> =
                        before.iter().map(|c| &c.step).chain([&case.step]).collect();
                    let again =
                        super::brisk::rerun(&mut ctx, &steps, &mut state, g, cfg.recover_wait);
                    let cases: Vec<&Case> = before.into_iter().chain([&case]).collect();
                    if late_could_make_it && matches!(again.last(), Some(Ok(None))) {
                        g.unconfirmed += 1;
                    }
                    for (c, r) in cases.into_iter().zip(again) {
                        verdicts.push((c.clone(), r));
                    }
                    careful = true;
                } else {
                    verdicts.push((case.clone(), result));
                }
            }
            None => verdicts.push((case.clone(), result)),
        }
        if let Some((_, r)) = verdicts.iter().rev().find(|(c, _)| c.index == case.index) {
            let replied = match (r, &case.step) {
                (Ok(None), Step::Frame(f)) => {
                    let j = model.judge(opts.address, mode, f);
                    j.expect.replies().then(|| predicted_len(mode, &j.expect))
                }
                (Ok(None), Step::Timed(t)) => {
                    let j = super::timing::predict(&ctx, t);
                    j.expect.replies().then(|| predicted_len(mode, &j.expect))
                }
                _ => None,
            };
            bound += line_time(&ctx, &case.step, replied);
        }
        let mut stop_now = false;
        for (c, r) in verdicts {
            if conclude(
                &mut ctx,
                &mut out,
                &mut by_signature,
                cfg,
                &mut state,
                &mut spent_minimizing,
                &c,
                r,
                sent_at,
            ) {
                stop_now = true;
                break;
            }
        }
        if stop_now {
            break;
        }
        prev = Some(case);
        prev_careful = careful;
        progress(out.cases, out.findings.len());
    }
    // Anything still to come from the last brisk exchanges comes within a full window.
    if let (Some(g), Some(last), true) = (guard.as_mut(), prev.as_ref(), out.stopped.is_none()) {
        std::thread::sleep(ctx.silence_window());
        let late = ctx.master_mut().drain_input().unwrap_or(0);
        let _ = ctx.master_mut().take_stray();
        if late > 0 && !prev_careful {
            g.stray_bytes += late as u64;
            let again =
                super::brisk::rerun(&mut ctx, &[&last.step], &mut state, g, cfg.recover_wait);
            for r in again {
                if conclude(
                    &mut ctx,
                    &mut out,
                    &mut by_signature,
                    cfg,
                    &mut state,
                    &mut spent_minimizing,
                    last,
                    r,
                    Instant::now(),
                ) {
                    break;
                }
            }
        }
    }
    ctx.master_mut().set_brisk(false);
    out.brisk = guard;
    out.elapsed = started.elapsed().saturating_sub(spent_minimizing);
    out.bound = ctx.line_timing().map(|_| bound);
    out.probes = ctx.liveness_probes;
    out.timing.unconfirmed = state.timing_unconfirmed;
    out.timing.resent = ctx.broken_requests();
    out.echo = ctx.echoes();
    out.restore = ctx.restore();
    out
}

/// Concludes one case's verdict: waits out a hang, groups a finding under its signature
/// (minimizing a new one with full windows). Whether the campaign must stop.
#[allow(clippy::too_many_arguments)]
fn conclude(
    ctx: &mut Ctx<'_>,
    out: &mut ModeOutcome,
    by_signature: &mut BTreeMap<String, usize>,
    cfg: &FuzzConfig,
    state: &mut State,
    spent_minimizing: &mut Duration,
    case: &Case,
    result: Result<Option<Observed>, RunError>,
    sent_at: Instant,
) -> bool {
    let mode = ctx.mode;
    let observed = match result {
        Ok(o) => o.map(|o| {
            let r = o.recovery;
            (o, r)
        }),
        Err(RunError::Transport(e)) => {
            out.stopped = Some(e.to_string());
            return true;
        }
        // The request never reached the device whole: no verdict, and not a case sent.
        Err(RunError::HostStalled(_)) => {
            out.cases = out.cases.saturating_sub(1);
            *out.skipped.entry(HOST_STALLED).or_default() += 1;
            return false;
        }
        Err(RunError::Undescribed(_)) => {
            out.cases = out.cases.saturating_sub(1);
            *out.skipped.entry(UNDESCRIBED).or_default() += 1;
            return false;
        }
        Err(RunError::DeviceLost(why)) => {
            let t = Instant::now();
            // How long it was gone: from the case that silenced it.
            let recovery = match recover(ctx, cfg.recover_wait) {
                Ok(r) => r.map(|_| sent_at.elapsed()),
                Err(e) => {
                    out.stopped = Some(e.to_string());
                    None
                }
            };
            let _ = ctx.master_mut().take_stray();
            *spent_minimizing += t.elapsed();
            out.hangs.hung(mode, &case.step, sent_at.elapsed());
            Some((
                Observed {
                    kind: Kind::Hang,
                    severity: Severity::Deviation,
                    text: format!(
                        "{why}; {}",
                        match recovery {
                            Some(d) => format!("it answered again after {:.1} s", d.as_secs_f64()),
                            None => format!(
                                "it did not answer again within {:.1} s (--recover-wait)",
                                cfg.recover_wait.as_secs_f64()
                            ),
                        }
                    ),
                    exchange: None,
                    register: None,
                    recovery: None,
                    field: super::signature::of_request(mode, &case.step),
                },
                Some(recovery),
            ))
        }
    };
    let Some((o, recovery)) = observed else {
        return false;
    };
    let finding = finding_of(mode, case, o, recovery, cfg);
    let sig = finding.signature();
    match by_signature.get(&sig) {
        Some(&i) => {
            out.findings[i].count += 1;
            *out.findings[i].classes.entry(case.class).or_default() += 1;
            // A hang seen again is confirmed, minimized or not.
            out.hangs.confirm(mode, &out.findings[i]);
        }
        None => {
            let t = Instant::now();
            let mut finding = finding;
            if cfg.minimize && recovery.is_none_or(|r| r.is_some()) {
                // Replays are judged with full windows.
                let brisk = ctx.master_mut().brisk();
                ctx.master_mut().set_brisk(false);
                super::minimize::minimize(ctx, &mut finding, state, cfg);
                ctx.master_mut().set_brisk(brisk);
                let _ = ctx.master_mut().take_stray();
            }
            *spent_minimizing += t.elapsed();
            finding.replay = replay_line(&cfg.replay, mode, &finding);
            if finding.reproduced {
                out.hangs.confirm(mode, &finding);
            }
            by_signature.insert(sig, out.findings.len());
            out.findings.push(finding);
        }
    }
    if matches!(recovery, Some(None)) {
        out.stopped = Some(format!(
            "the device stopped answering in case {} and did not come back",
            case.index
        ));
        ctx.lost = Some(out.stopped.clone().unwrap_or_default());
        return true;
    }
    ctx.lost = None;
    false
}

/// The predicted reply's length on the line.
fn predicted_len(mode: Mode, e: &Expectation) -> usize {
    let body = match e {
        Expectation::Read(p) => 3 + 2 * p.registers.len(),
        Expectation::WriteSingle | Expectation::WriteMultiple | Expectation::LoopBack => 6,
        Expectation::Exception { .. } => 3,
        Expectation::Silence(_) => 0,
    };
    crate::codec::frame_len(mode, body)
}

fn finding_of(
    mode: Mode,
    case: &Case,
    o: Observed,
    recovery: Option<Option<Duration>>,
    _cfg: &FuzzConfig,
) -> FuzzFinding {
    let frames: Vec<Vec<u8>> = case.step.frames().iter().map(|f| f.to_vec()).collect();
    FuzzFinding {
        kind: o.kind,
        mode,
        function: frames.first().map_or(0, |f| function_of(mode, f)),
        field: o.field,
        classes: [(case.class, 1)].into_iter().collect(),
        count: 1,
        first_case: case.index,
        burst: matches!(case.step, Step::Burst(_)),
        timed: match &case.step {
            Step::Timed(t) => Some(t.clone()),
            _ => None,
        },
        frames,
        minimized: Vec::new(),
        reproduced: false,
        replays: 0,
        text: o.text,
        severity: o.severity,
        exchange: o.exchange,
        recovery,
        register: o.register,
        replay: String::new(),
    }
}

/// The one-line command that replays a finding's reproducer (or its frames).
pub fn replay_line(prefix: &str, mode: Mode, f: &FuzzFinding) -> String {
    let frames = if f.minimized.is_empty() {
        &f.frames
    } else {
        &f.minimized
    };
    let shown: Vec<String> = frames
        .iter()
        .map(|fr| match mode {
            Mode::Rtu => crate::codec::hex::Hex(fr).to_string().replace(' ', ""),
            Mode::Ascii => format!(
                "'{}'",
                String::from_utf8_lossy(fr)
                    .replace('\r', "\\r")
                    .replace('\n', "\\n")
            ),
        })
        .collect();
    if let Some(t) = &f.timed {
        // Timing damage: the bytes as one transmission, cut where the silences go.
        return format!(
            "{prefix} --mode {mode} {} {}",
            t.send_options(),
            crate::codec::hex::Hex(&t.bytes())
                .to_string()
                .replace(' ', "")
        );
    }
    format!(
        "{prefix} --mode {mode}{} {}",
        if f.burst { " --burst" } else { "" },
        shown.join(" ")
    )
}
