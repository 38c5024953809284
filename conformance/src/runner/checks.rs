//! The checks, derived from a drive model. Each cites the manual section it tests; what
//! it expects comes from [`DriveModel::judge`], so the runner and the simulator share one
//! source of truth, and a device that differs from a decision of the model is reported as
//! an observation.

use std::time::Duration;

use super::compare::{show, Finding};
use super::{Ctx, Probed, RunError, Verdict};
use crate::codec::hex::Hex;
use crate::codec::pdu::{Pdu, Registers};
use crate::codec::Mode;
use crate::model::{Access, Basis, DriveModel, Fact, Role};
use crate::rng::Rng;
use crate::vectors::model::FileDirection;
use crate::vectors::{Body, VectorFile};

type Run = Box<dyn Fn(&mut Ctx<'_>) -> Result<Verdict, RunError>>;

/// One check.
pub struct Check {
    /// Stable id, "rtu.map.group-0.past-end".
    pub id: String,
    /// What it does.
    pub title: String,
    /// The manual section it tests.
    pub source: String,
    /// Whether it writes registers (skipped with --read-only; restored afterwards).
    pub writes: bool,
    /// Whether it sets the run or external-fault bit (needs --allow-motion).
    pub motion: bool,
    /// Whether it restarts or silences the device's communications (needs
    /// --allow-restart).
    pub restarts: bool,
    /// The check.
    pub run: Run,
}

fn check(
    id: String,
    title: String,
    source: String,
    writes: bool,
    motion: bool,
    run: impl Fn(&mut Ctx<'_>) -> Result<Verdict, RunError> + 'static,
) -> Check {
    Check {
        id,
        title,
        source,
        writes,
        motion,
        restarts: false,
        run: Box::new(run),
    }
}

/// The preflight of `mode`: a read the model says is answered (see [`super::liveness`]).
pub fn preflight(model: &DriveModel, mode: Mode) -> Check {
    let what = match super::liveness::liveness_register(model, 1, mode) {
        Some(r) => format!("{r:04X}H"),
        None => "a register".to_string(),
    };
    check(
        format!("{mode}.preflight"),
        format!("Preflight: the device answers a read of {what} (and whether the line echoes)"),
        "Modbus over Serial Line V1.02, 2.4.1: a unicast request gets a reply; without one nothing can be judged".to_string(),
        false,
        false,
        |ctx| ctx.preflight(),
    )
}

/// Findings and records of several probes.
fn verdict(probes: &[&Probed], pass: String) -> Verdict {
    Verdict {
        findings: probes
            .iter()
            .flat_map(|p| p.comparison.findings.iter().cloned())
            .collect(),
        exchanges: probes.iter().map(|p| p.record()).collect(),
        pass_summary: pass,
        ..Verdict::default()
    }
}

fn pass_text(p: &Probed) -> String {
    format!(
        "as the model says: {} ({})",
        p.judgement.expect.describe(),
        p.judgement.detail
    )
}

/// A check that sends one frame and compares the answer with the model.
fn probe_check(
    id: String,
    title: String,
    source: String,
    writes: bool,
    build: impl Fn(&Ctx<'_>) -> Vec<u8> + 'static,
) -> Check {
    check(id, title, source, writes, false, move |ctx| {
        let frame = build(ctx);
        let p = ctx.probe(frame, None)?;
        let pass = pass_text(&p);
        Ok(verdict(&[&p], pass))
    })
}

/// What a written register reads back: the value written (Modbus 06H/10H semantics).
fn write_fact() -> Fact {
    Fact::documented("Modbus application protocol V1.1b3, 6.6 and 6.12: a holding register keeps the value written to it")
}

/// The frequency-command monitor shows the command written by communication.
fn mirror_fact() -> Fact {
    Fact {
        basis: Basis::Decision,
        source: None,
        rule: None,
        why: Some("the monitor register shows the frequency command the drive uses, which is the one written by communication only when the frequency source parameter selects communication; the model (and the simulator) assume it does".to_string()),
    }
}

fn slug(name: &str) -> String {
    name.replace(' ', "-")
}

fn cite(model: &DriveModel, fact: &Fact) -> String {
    format!("{}: {}", model.manual, fact.citation())
}

/// Runs of contiguous readable registers (read-write or read-only or reserved) of one group.
fn readable_runs(model: &DriveModel) -> Vec<(u16, u16)> {
    let mut runs: Vec<(u16, u16)> = Vec::new();
    let mut prev: Option<(u16, usize)> = None;
    for (r, access) in model.registers() {
        if access == Access::NoAccess {
            prev = None;
            continue;
        }
        let group = model.lookup(r).map(|i| i.group).unwrap_or(usize::MAX);
        match (prev, runs.last_mut()) {
            (Some((p, g)), Some(last)) if p + 1 == r && g == group => last.1 += 1,
            _ => runs.push((r, 1)),
        }
        prev = Some((r, group));
    }
    runs
}

/// The checks of `mode` for `model`, in the order they run.
pub fn plan(
    model: &DriveModel,
    vectors: Option<&VectorFile>,
    mode: Mode,
    opts: &super::Options,
) -> Vec<Check> {
    let m = mode.to_string();
    let mut out = Vec::new();
    examples(model, vectors, mode, &mut out);
    identification(model, &m, &mut out);
    map(model, &m, &mut out);
    counts(model, mode, &m, &mut out);
    writes(model, mode, &m, &mut out);
    functions(model, &m, &mut out);
    loop_back(model, &m, opts.seed, &mut out);
    addressing(model, &m, &mut out);
    line(model, mode, &m, opts.seed, &mut out);
    motion(model, &m, &mut out);
    aggregates(model, &m, &mut out);
    out
}

fn examples(model: &DriveModel, vectors: Option<&VectorFile>, mode: Mode, out: &mut Vec<Check>) {
    let Some(file) = vectors else { return };
    for v in &file.vectors {
        let Body::Frame(fv) = &v.body else { continue };
        if fv.direction != FileDirection::Request || Mode::from(fv.mode) != mode {
            continue;
        }
        let Some(request) = fv.correct_bytes() else {
            continue;
        };
        let response_id = v.id.replace(".request", ".response");
        let response = file
            .vectors
            .iter()
            .find(|r| r.id == response_id)
            .and_then(|r| match &r.body {
                Body::Frame(rf) => rf.correct_bytes(),
                _ => None,
            });
        let judgement = model.judge(1, mode, &request);
        let plan_writes = judgement
            .write
            .clone()
            .map(|w| w.writes)
            .unwrap_or_default();
        let op = model.register_with_role(Role::Operation);
        let bits = model.bits;
        let motion = plan_writes.iter().any(|&(r, val)| {
            Some(r) == op
                && [bits.run, bits.external_fault]
                    .iter()
                    .flatten()
                    .any(|b| val & (1 << b) != 0)
        });
        let writes = !plan_writes.is_empty();
        let id = format!("{mode}.example.{}", v.id);
        let title = format!(
            "Replay the manual's example request {} ({}){}",
            v.id,
            show(mode, &request),
            if v.verdict == crate::vectors::Verdict::Consistent {
                String::new()
            } else {
                " as corrected".to_string()
            }
        );
        let source = v.source.clone();
        out.push(check(id, title, source, writes, motion, move |ctx| {
            // Address the device, not the manual's node 01.
            let mut frame = request.clone();
            if ctx.opts.address != 1 {
                frame = crate::codec::readdressed(ctx.mode, &request, ctx.opts.address)
                    .unwrap_or(frame);
            }
            for &(r, _) in &plan_writes {
                if let Err(e) = ctx.remember(r)? {
                    return Ok(Verdict::skip(format!(
                        "cannot read the value of {r:04X}H to restore it, so the example is not replayed: {e}"
                    )));
                }
            }
            let p = ctx.probe(frame, None)?;
            let mut v = verdict(&[&p], pass_text(&p));
            if let (Some(reply), Some(manual)) = (&p.exchange.reply, &response) {
                if ctx.opts.address == 1 && reply != manual && p.comparison.findings.is_empty() {
                    v.findings.push(Finding::observation(format!(
                        "the manual's example response is {}; the device answered {} (a read's values are the state of the drive, not of the protocol)",
                        show(ctx.mode, manual),
                        show(ctx.mode, reply)
                    )));
                }
                if ctx.opts.address == 1 && reply == manual {
                    v.pass_summary = format!("the device answered the manual's example response {}", show(ctx.mode, manual));
                }
            }
            Ok(v)
        }));
    }
}

fn identification(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    let id = &model.identification;
    let register = id.register.unwrap_or(0x252F);
    let documented = id.value;
    let source = cite(model, &id.fact);
    let title = match documented {
        Some(v) => {
            format!("Read the identification register {register:04X}H (the manual gives {v:04X}H)")
        }
        None => format!("Read the identification register {register:04X}H"),
    };
    out.push(check(
        format!("{m}.identification"),
        title,
        source,
        false,
        false,
        move |ctx| {
            let known = documented.map(|v| (vec![Some(v)], ctx.model.identification.fact.clone()));
            let frame = ctx.frame(Pdu::ReadRequest {
                start: register,
                count: 1,
            });
            let p = ctx.probe(frame, known)?;
            let value = p.read_values().and_then(|v| v.first().copied());
            ctx.identification = value;
            let mut v = verdict(&[&p], pass_text(&p));
            match (value, documented) {
                (Some(x), Some(d)) if x == d => {
                    v.pass_summary = format!("{register:04X}H reads {x:04X}H, as the manual says")
                }
                (Some(x), None)
                    if p.comparison
                        .findings
                        .iter()
                        .all(|f| f.severity == super::Severity::Observation) =>
                {
                    v.findings
                        .retain(|f| f.severity != super::Severity::Observation);
                    v.findings.push(Finding::observation(format!(
                        "{register:04X}H reads {x:04X}H; the manual gives no value"
                    )))
                }
                _ => {}
            }
            Ok(v)
        },
    ));
}

fn map(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    for g in &model.groups {
        if g.name.starts_with("example") {
            continue;
        }
        let name = slug(&g.name);
        let source = format!("{}, {}", model.manual, g.source);
        let accessible: Vec<u16> = g.registers.iter().flat_map(|r| r.clone()).collect();
        let (Some(&first), Some(&last)) = (accessible.first(), accessible.last()) else {
            continue;
        };
        for (which, r) in [("first", first), ("last", last)] {
            out.push(probe_check(
                format!("{m}.map.{name}.{which}"),
                format!("Read the {which} register of {} ({r:04X}H)", g.name),
                source.clone(),
                false,
                move |ctx| ctx.frame(Pdu::ReadRequest { start: r, count: 1 }),
            ));
        }
        if g.parameter_group.is_none() {
            let count = u16::try_from(g.span.clone().count()).unwrap_or(u16::MAX);
            let start = *g.span.start();
            out.push(probe_check(
                format!("{m}.map.{name}.whole"),
                format!("Read the whole {} block ({start:04X}H, {count} registers, within the mode's limit)", g.name),
                source.clone(),
                false,
                move |ctx| {
                    let limit = ctx.model.limits.read.get(ctx.mode);
                    ctx.frame(Pdu::ReadRequest { start, count: count.min(limit) })
                },
            ));
        }
        let past = g.span.end().wrapping_add(1);
        if model.lookup(past).is_none() {
            out.push(probe_check(
                format!("{m}.map.{name}.past-end"),
                format!(
                    "Read one register past the end of {} ({past:04X}H, not in the map)",
                    g.name
                ),
                source.clone(),
                false,
                move |ctx| {
                    ctx.frame(Pdu::ReadRequest {
                        start: past,
                        count: 1,
                    })
                },
            ));
        }
        for w in g.registers.windows(2) {
            let gap = w[0].end() + 1;
            if model.lookup(gap).is_none() {
                out.push(probe_check(
                    format!("{m}.map.{name}.gap-{gap:04X}"),
                    format!("Read {gap:04X}H, in a gap of {} (not in the table)", g.name),
                    source.clone(),
                    false,
                    move |ctx| {
                        ctx.frame(Pdu::ReadRequest {
                            start: gap,
                            count: 1,
                        })
                    },
                ));
            }
        }
        if let Some(na) = g.no_access.first() {
            let r = *na.start();
            out.push(probe_check(
                format!("{m}.map.{name}.no-access-{r:04X}"),
                format!("Read {r:04X}H, marked '-' (no Modbus access) in {}", g.name),
                source.clone(),
                false,
                move |ctx| ctx.frame(Pdu::ReadRequest { start: r, count: 1 }),
            ));
        }
    }
    // Reserved registers read 0000H (a decision).
    if let Some(r) = model
        .named
        .iter()
        .find(|n| n.access == Access::Reserved)
        .map(|n| n.register)
    {
        let fact = model.rule(crate::model::Fault::ReservedWrite).fact.clone();
        out.push(check(
            format!("{m}.map.reserved-reads-zero"),
            format!("Read the reserved register {r:04X}H"),
            cite(model, &fact),
            false,
            false,
            move |ctx| {
                let frame = ctx.frame(Pdu::ReadRequest { start: r, count: 1 });
                let p = ctx.probe(frame, Some((vec![Some(0)], fact.clone())))?;
                Ok(verdict(
                    &[&p],
                    format!("{r:04X}H reads 0000H (model decision)"),
                ))
            },
        ));
    }
}

fn counts(model: &DriveModel, mode: Mode, m: &str, out: &mut Vec<Check>) {
    let limit = model.limits.read.get(mode);
    let runs = readable_runs(model);
    let start = runs
        .iter()
        .find(|(_, n)| *n > limit)
        .or_else(|| runs.iter().max_by_key(|(_, n)| *n))
        .map(|(s, _)| *s)
        .unwrap_or(0);
    let source = cite(model, &model.limits.read.fact);
    for (name, count) in [
        ("zero", 0),
        ("one", 1),
        ("limit", limit),
        ("over-limit", limit + 1),
    ] {
        out.push(probe_check(
            format!("{m}.read-count.{name}"),
            format!("Read {count} registers from {start:04X}H (the {mode} read limit is {limit})"),
            source.clone(),
            false,
            move |ctx| ctx.frame(Pdu::ReadRequest { start, count }),
        ));
    }
    // Same-group rule: a read across the command and monitor blocks.
    if let (Some(c), Some(mon)) = (model.group("command"), model.group("monitor")) {
        let from = *c.span.end();
        if *mon.span.start() == from + 1 {
            out.push(probe_check(
                format!("{m}.same-group"),
                format!("Read 2 registers from {from:04X}H, across the command and monitor blocks"),
                cite(model, &model.limits.same_group_fact),
                false,
                move |ctx| {
                    ctx.frame(Pdu::ReadRequest {
                        start: from,
                        count: 2,
                    })
                },
            ));
        }
    }
    // Write counts: a value-preserving write of the limit, a write of 0, and one over
    // the limit (a frame over 80 bytes).
    let wlimit = model.limits.write.get(mode);
    let wsource = cite(model, &model.limits.write.fact);
    let wstart = runs
        .iter()
        .find(|(s, n)| {
            *n > wlimit
                && model
                    .lookup(*s)
                    .is_some_and(|i| i.access == Access::ReadWrite)
                && (0..=wlimit).all(|k| {
                    model
                        .lookup(s + k)
                        .is_some_and(|i| i.access == Access::ReadWrite)
                })
        })
        .map(|(s, _)| *s);
    if let Some(wstart) = wstart {
        for (name, count) in [("limit", wlimit), ("over-limit", wlimit + 1)] {
            let title = if name == "limit" {
                format!("Write {count} registers from {wstart:04X}H with the values they hold (the {mode} write limit is {wlimit}), and read them back")
            } else {
                format!("Write {count} registers from {wstart:04X}H with the values they hold: one over the limit, a frame over {} bytes", model.limits.max_frame)
            };
            let src = if name == "limit" {
                wsource.clone()
            } else {
                format!(
                    "{wsource}; {}",
                    cite(
                        model,
                        &model.silence[&crate::model::SilenceReason::FrameTooLong]
                    )
                )
            };
            out.push(check(
                format!("{m}.write-count.{name}"),
                title,
                src,
                true,
                false,
                move |ctx| {
                    let mut values = Vec::new();
                    let rlimit = ctx.model.limits.read.get(ctx.mode);
                    let mut at = 0u16;
                    while at < count {
                        let n = (count - at).min(rlimit);
                        match ctx.read(wstart + at, n)? {
                            Ok(v) => values.extend(v),
                            Err(e) => {
                                return Ok(Verdict::error(format!(
                                    "cannot read the values to write back: {e}"
                                )))
                            }
                        }
                        at += n;
                    }
                    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
                    let Ok(regs) = Registers::new(&bytes) else {
                        return Ok(Verdict::error("internal: odd register bytes"));
                    };
                    let frame = ctx.frame(Pdu::WriteMultipleRequest {
                        start: wstart,
                        values: regs,
                    });
                    let p = ctx.probe(frame, None)?;
                    let mut v = verdict(&[&p], pass_text(&p));
                    // The values must be unchanged either way.
                    let mut after = Vec::new();
                    let mut at = 0u16;
                    while at < count {
                        let n = (count - at).min(rlimit);
                        match ctx.read(wstart + at, n)? {
                            Ok(x) => after.extend(x),
                            Err(e) => {
                                v.findings
                                    .push(Finding::deviation(format!("read-back failed: {e}")));
                                return Ok(v);
                            }
                        }
                        at += n;
                    }
                    if after != values {
                        v.findings.push(Finding::deviation(format!(
                            "the registers changed: before {:04X?}, after {:04X?}",
                            values, after
                        )));
                    }
                    Ok(v)
                },
            ));
        }
    }
    out.push(probe_check(
        format!("{m}.write-count.zero"),
        "Write 0 registers (10H with count 0)".to_string(),
        wsource,
        true,
        move |ctx| {
            ctx.frame(Pdu::WriteMultipleRequest {
                start: wstart.unwrap_or(0),
                values: Registers::new(&[]).unwrap_or_else(|_| unreachable_regs()),
            })
        },
    ));
}

fn unreachable_regs() -> Registers<'static> {
    // Registers::new only fails on an odd length; the empty slice is even.
    match Registers::new(&[]) {
        Ok(r) => r,
        Err(_) => unreachable!("an empty register list is valid"),
    }
}

fn writes(model: &DriveModel, mode: Mode, m: &str, out: &mut Vec<Check>) {
    let _ = mode;
    // A value-preserving write to the first parameter of every group, read back.
    for g in model.parameter_groups() {
        let Some(r) = g.registers.first().map(|r| *r.start()) else {
            continue;
        };
        let source = format!("{}, {}", model.manual, g.source);
        out.push(check(
            format!("{m}.write.{}", slug(&g.name)),
            format!("Write the first parameter of {} ({r:04X}H) with the value it holds, and read it back", g.name),
            source,
            true,
            false,
            move |ctx| {
                let orig = match ctx.remember(r)? {
                    Ok(v) => v,
                    Err(e) => return Ok(Verdict::error(format!("cannot read {r:04X}H first: {e}"))),
                };
                let w = ctx.probe(ctx.frame(Pdu::WriteSingle { register: r, value: orig }), None)?;
                let rb = ctx.probe(
                    ctx.frame(Pdu::ReadRequest { start: r, count: 1 }),
                    Some((vec![Some(orig)], write_fact())),
                )?;
                Ok(verdict(&[&w, &rb], format!("{r:04X}H accepted {orig:04X}H and reads it back")))
            },
        ));
    }
    let fc = model.register_with_role(Role::FrequencyCommand);
    let mirror = model.register_with_role(Role::FrequencyCommandMonitor);
    if let Some(f) = fc {
        let named = model.named(f).cloned();
        let source = named
            .as_ref()
            .and_then(|n| n.fact.source.clone())
            .unwrap_or_default();
        out.push(check(
            format!("{m}.write.frequency-command"),
            format!(
                "Write the frequency command {f:04X}H (12.34 Hz), read it back and its monitor"
            ),
            format!("{}, {source}", model.manual),
            true,
            false,
            move |ctx| {
                if let Err(e) = ctx.remember(f)? {
                    return Ok(Verdict::error(format!("cannot read {f:04X}H first: {e}")));
                }
                let value = 1234;
                let w = ctx.probe(ctx.frame(Pdu::WriteSingle { register: f, value }), None)?;
                let rb = ctx.probe(
                    ctx.frame(Pdu::ReadRequest { start: f, count: 1 }),
                    Some((vec![Some(value)], write_fact())),
                )?;
                let mut probes = vec![w, rb];
                if let Some(mon) = mirror {
                    // The monitor shows the command only when the frequency source is
                    // communication: a parameter the manual's chapter does not cover.
                    probes.push(ctx.probe(
                        ctx.frame(Pdu::ReadRequest {
                            start: mon,
                            count: 1,
                        }),
                        Some((vec![Some(value)], mirror_fact())),
                    )?);
                }
                let refs: Vec<&Probed> = probes.iter().collect();
                Ok(verdict(
                    &refs,
                    format!("{f:04X}H takes 04D2H and reads it back"),
                ))
            },
        ));
        out.push(probe_check_with_restore(
            format!("{m}.write.out-of-range"),
            format!("Write FFFFH (655.35 Hz) to the frequency command {f:04X}H"),
            cite(model, &model.rule(crate::model::Fault::DataOutOfRange).fact),
            f,
            move |ctx| {
                ctx.frame(Pdu::WriteSingle {
                    register: f,
                    value: 0xFFFF,
                })
            },
        ));
    }
    // Two-word register (12-00 at 2510H/2511H), value-preserving, by 10H.
    if let (Some(hi), Some(lo)) = (
        model.register_with_role(Role::TwoWordHigh),
        model.register_with_role(Role::TwoWordLow),
    ) {
        if lo == hi + 1 {
            let source = model
                .named(hi)
                .and_then(|n| n.fact.source.clone())
                .unwrap_or_default();
            out.push(check(
                format!("{m}.write.two-word"),
                format!("Write the two-word register {hi:04X}H/{lo:04X}H (10H) with its value, and read it back"),
                format!("{}, {source}", model.manual),
                true,
                false,
                move |ctx| {
                    let (Ok(a), Ok(b)) = (ctx.remember(hi)?, ctx.remember(lo)?) else {
                        return Ok(Verdict::error(format!("cannot read {hi:04X}H/{lo:04X}H first")));
                    };
                    let bytes = [a.to_be_bytes(), b.to_be_bytes()].concat();
                    let Ok(values) = Registers::new(&bytes) else {
                        return Ok(Verdict::error("internal: odd register bytes"));
                    };
                    let w = ctx.probe(ctx.frame(Pdu::WriteMultipleRequest { start: hi, values }), None)?;
                    let rb = ctx.probe(
                        ctx.frame(Pdu::ReadRequest { start: hi, count: 2 }),
                        Some((vec![Some(a), Some(b)], write_fact())),
                    )?;
                    Ok(verdict(&[&w, &rb], format!("{hi:04X}H/{lo:04X}H accept {a:04X} {b:04X} and read them back")))
                },
            ));
        }
    }
    if let Some(ro) = model.register_with_role(Role::Status) {
        // Not journalled: 2520H is state, not a stored value, and writing it back at the
        // end would be a second write to a read-only register.
        out.push(probe_check(
            format!("{m}.write.read-only"),
            format!("Write 0000H to the monitor register {ro:04X}H (read-only)"),
            cite(model, &model.rule(crate::model::Fault::ReadOnly).fact),
            true,
            move |ctx| {
                ctx.frame(Pdu::WriteSingle {
                    register: ro,
                    value: 0,
                })
            },
        ));
    }
    if let Some(res) = model
        .named
        .iter()
        .find(|n| n.access == Access::Reserved)
        .map(|n| n.register)
    {
        out.push(probe_check_with_restore(
            format!("{m}.write.reserved"),
            format!("Write 0000H to the reserved register {res:04X}H"),
            cite(model, &model.rule(crate::model::Fault::ReservedWrite).fact),
            res,
            move |ctx| {
                ctx.frame(Pdu::WriteSingle {
                    register: res,
                    value: 0,
                })
            },
        ));
    }
}

/// A one-frame write check that journals `register` first, so that a device that takes
/// the write gets its value back at the end.
fn probe_check_with_restore(
    id: String,
    title: String,
    source: String,
    register: u16,
    build: impl Fn(&Ctx<'_>) -> Vec<u8> + 'static,
) -> Check {
    check(id, title, source, true, false, move |ctx| {
        if let Err(e) = ctx.remember(register)? {
            return Ok(Verdict::error(format!(
                "cannot read {register:04X}H first, so a write could not be undone: {e}"
            )));
        }
        let frame = build(ctx);
        let p = ctx.probe(frame, None)?;
        let pass = pass_text(&p);
        Ok(verdict(&[&p], pass))
    })
}

fn functions(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    let source = cite(
        model,
        &model.rule(crate::model::Fault::IllegalFunction).fact,
    );
    for fc in [0x04u8, 0x41] {
        out.push(probe_check(
            format!("{m}.function.{fc:02X}"),
            format!("Send function {fc:02X}H, which the drive does not serve"),
            source.clone(),
            false,
            move |ctx| {
                ctx.frame(Pdu::Other {
                    function: fc,
                    data: &[0x25, 0x20, 0x00, 0x01],
                })
            },
        ));
    }
    out.push(check(
        format!("{m}.exception-numbering"),
        format!(
            "Exception numbering: the manual numbers its codes {}",
            if model.numbers_exceptions_from_51() { "51H..55H" } else { "01H..05H" }
        ),
        format!("{}, {}", model.manual, model.exception_codes_source),
        false,
        false,
        move |ctx| {
            let p = ctx.probe(ctx.frame(Pdu::Other { function: 0x04, data: &[0x25, 0x20, 0x00, 0x01] }), None)?;
            let code = p.exchange.reply.as_ref().and_then(|r| super::compare::body_of(ctx.mode, r)).and_then(|b| (b.len() == 3 && b[1] & 0x80 != 0).then_some(b[2]));
            let want51 = ctx.model.numbers_exceptions_from_51();
            let mut v = verdict(&[&p], String::new());
            v.findings.retain(|_| false);
            match code {
                None => v.findings.push(Finding::deviation(format!(
                    "no exception reply to function 04H: {}",
                    p.comparison.actual
                ))),
                Some(c) => {
                    let style = match c {
                        0x01..=0x05 => Some(false),
                        0x51..=0x55 => Some(true),
                        _ => None,
                    };
                    let name = |s: bool| if s { "51H..55H" } else { "01H..05H" };
                    match style {
                        Some(s) if s == want51 => v.pass_summary = format!("the device answers {c:02X}H: numbered {} as the manual says", name(s)),
                        Some(s) => v.findings.push(Finding::deviation(format!(
                            "the manual numbers exceptions {}, the device answered {c:02X}H ({} numbering)",
                            name(want51),
                            name(s)
                        ))),
                        None => v.findings.push(Finding::deviation(format!(
                            "the device answered code {c:02X}H, in neither numbering (01H..05H, 51H..55H)"
                        ))),
                    }
                }
            }
            Ok(v)
        },
    ));
}

fn loop_back(model: &DriveModel, m: &str, seed: u64, out: &mut Vec<Check>) {
    let mut rng = Rng::new(seed ^ 0x08);
    let source = cite(model, &model.loop_back_fact);
    for i in 0..3 {
        let r = rng.next_u64();
        let test_code = if i == 2 { (r >> 32) as u16 } else { 0 };
        let data = [(r & 0xFF) as u8, ((r >> 8) & 0xFF) as u8];
        out.push(probe_check(
            format!("{m}.loop-back.{}", i + 1),
            format!(
                "Loop-back (08H) with test code {test_code:04X}H and data {}",
                Hex(&data)
            ),
            source.clone(),
            false,
            move |ctx| {
                ctx.frame(Pdu::LoopBack {
                    test_code,
                    data: &data,
                })
            },
        ));
    }
}

fn addressing(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    let bsource = cite(
        model,
        &model.silence[&crate::model::SilenceReason::Broadcast],
    );
    if let Some(f) = model.register_with_role(Role::FrequencyCommand) {
        out.push(check(
            format!("{m}.broadcast.write"),
            format!("Broadcast (node 00H) a write of the frequency command {f:04X}H: no reply, and the value is taken"),
            bsource.clone(),
            true,
            false,
            move |ctx| {
                let orig = match ctx.remember(f)? {
                    Ok(v) => v,
                    Err(e) => return Ok(Verdict::error(format!("cannot read {f:04X}H first: {e}"))),
                };
                let value = if orig == 0x0A0A { 0x0B0B } else { 0x0A0A };
                let bc = ctx.probe(ctx.frame_to(0, Pdu::WriteSingle { register: f, value }), None)?;
                let rb = ctx.probe(
                    ctx.frame(Pdu::ReadRequest { start: f, count: 1 }),
                    Some((vec![Some(value)], write_fact())),
                )?;
                Ok(verdict(&[&bc, &rb], format!("no reply to the broadcast, and {f:04X}H reads {value:04X}H")))
            },
        ));
    }
    out.push(probe_check(
        format!("{m}.broadcast.read"),
        "Broadcast (node 00H) a read of 2520H: no reply".to_string(),
        bsource,
        false,
        |ctx| {
            ctx.frame_to(
                0,
                Pdu::ReadRequest {
                    start: 0x2520,
                    count: 1,
                },
            )
        },
    ));
    out.push(probe_check(
        format!("{m}.other-address"),
        "Read 2520H from another node address: no reply".to_string(),
        cite(
            model,
            &model.silence[&crate::model::SilenceReason::OtherAddress],
        ),
        false,
        |ctx| {
            ctx.frame_to(
                ctx.opts.other_address,
                Pdu::ReadRequest {
                    start: 0x2520,
                    count: 1,
                },
            )
        },
    ));
}

fn line(model: &DriveModel, mode: Mode, m: &str, seed: u64, out: &mut Vec<Check>) {
    let csource = cite(
        model,
        &model.silence[&crate::model::SilenceReason::BadChecksum],
    );
    let (name, what) = match mode {
        Mode::Rtu => ("bad-crc", "CRC"),
        Mode::Ascii => ("bad-lrc", "LRC"),
    };
    out.push(probe_check(
        format!("{m}.{name}"),
        format!("Read 2520H with a wrong {what}: no reply"),
        csource,
        false,
        move |ctx| {
            let mut f = ctx.frame(Pdu::ReadRequest {
                start: 0x2520,
                count: 1,
            });
            let n = f.len();
            match ctx.mode {
                Mode::Rtu => f[n - 1] ^= 0xFF,
                // Change the LRC's last hex digit to another hex digit.
                Mode::Ascii => f[n - 3] = if f[n - 3] == b'0' { b'1' } else { b'0' },
            }
            f
        },
    ));
    let recover = "Modbus over Serial Line V1.02, 2.5.1.1 and 2.5.2.1: a receiver drops what is not a frame and takes the next frame".to_string();
    let mut rng = Rng::new(seed ^ 0x6A);
    let garbage: Vec<u8> = match mode {
        // Random bytes; the pause after them is a silence over t3.5, so a device that
        // frames by silence sees them as one bad frame.
        Mode::Rtu => (0..12).map(|_| rng.byte()).collect(),
        // Printable characters other than ':', CR and LF.
        Mode::Ascii => (0..12)
            .map(|_| b"ABCDEFGHIJ0123456789#!"[rng.below(22) as usize])
            .collect(),
    };
    out.push(check(
        format!("{m}.garbage-then-frame"),
        format!(
            "Send 12 garbage bytes ({}), pause, then read 2520H: the device recovers",
            show(mode, &garbage)
        ),
        recover.clone(),
        false,
        false,
        move |ctx| {
            ctx.send_raw(&garbage, Duration::from_millis(30))?;
            let p = ctx.probe(
                ctx.frame(Pdu::ReadRequest {
                    start: 0x2520,
                    count: 1,
                }),
                None,
            )?;
            Ok(verdict(
                &[&p],
                "the device answered the frame after the garbage".into(),
            ))
        },
    ));
    out.push(check(
        format!("{m}.partial-then-frame"),
        "Send the first half of a frame, pause, then a whole frame: the device answers the whole one".to_string(),
        recover,
        false,
        false,
        move |ctx| {
            let f = ctx.frame(Pdu::ReadRequest { start: 0x2520, count: 1 });
            let half = f[..f.len() / 2].to_vec();
            // ASCII: the next ':' restarts the frame; RTU: the pause ends the partial frame.
            let pause = if ctx.mode == Mode::Ascii { Duration::from_millis(5) } else { Duration::from_millis(30) };
            ctx.send_raw(&half, pause)?;
            let p = ctx.probe(f, None)?;
            Ok(verdict(&[&p], "the device answered the whole frame".into()))
        },
    ));
}

fn motion(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    let (Some(op), Some(st)) = (
        model.register_with_role(Role::Operation),
        model.register_with_role(Role::Status),
    ) else {
        return;
    };
    let bits = model.bits;
    let fc = model.register_with_role(Role::FrequencyCommand);
    let outf = model.register_with_role(Role::OutputFrequency);
    let src = model
        .named(op)
        .and_then(|n| n.fact.source.clone())
        .unwrap_or_default();
    let source = format!("{}, {src}", model.manual);
    if let (Some(run), Some(running)) = (bits.run, bits.running) {
        out.push(check(
            format!("{m}.motion.run-stop"),
            format!("Run at 10.00 Hz ({op:04X}H bit {run}), watch {st:04X}H and the output frequency, then stop"),
            source.clone(),
            true,
            true,
            move |ctx| {
                let mut findings = Vec::new();
                for r in [Some(op), fc].into_iter().flatten() {
                    if let Err(e) = ctx.remember(r)? {
                        return Ok(Verdict::error(format!("cannot read {r:04X}H first: {e}")));
                    }
                }
                if let Some(f) = fc {
                    if let Err(e) = ctx.write(f, 1000)? {
                        return Ok(Verdict::error(e));
                    }
                }
                let w = ctx.probe(ctx.frame(Pdu::WriteSingle { register: op, value: 1 << run }), None)?;
                findings.extend(w.comparison.findings.clone());
                std::thread::sleep(Duration::from_millis(300));
                match ctx.read(st, 1)? {
                    Ok(v) if v[0] & (1 << running) != 0 => {}
                    Ok(v) => findings.push(Finding::deviation(format!("after the run command {st:04X}H reads {:04X}H: bit {running} (running) is 0", v[0]))),
                    Err(e) => findings.push(Finding::deviation(e)),
                }
                if let Some(o) = outf {
                    let mut moving = false;
                    for _ in 0..30 {
                        if let Ok(v) = ctx.read(o, 1)? {
                            if v[0] > 0 {
                                moving = true;
                                break;
                            }
                        }
                        std::thread::sleep(Duration::from_millis(100));
                    }
                    if !moving {
                        findings.push(Finding::observation(format!("the output frequency {o:04X}H stayed 0 for 3 s after the run command (acceleration time?)")));
                    }
                }
                let s = ctx.probe(ctx.frame(Pdu::WriteSingle { register: op, value: 0 }), None)?;
                findings.extend(s.comparison.findings.clone());
                let mut stopped = false;
                for _ in 0..100 {
                    if let Ok(v) = ctx.read(st, 1)? {
                        if v[0] & (1 << running) == 0 {
                            stopped = true;
                            break;
                        }
                    }
                    std::thread::sleep(Duration::from_millis(100));
                }
                if !stopped {
                    findings.push(Finding::deviation(format!("{st:04X}H bit {running} (running) still set 10 s after the stop command")));
                }
                Ok(Verdict {
                    findings,
                    exchanges: vec![w.record(), s.record()],
                    pass_summary: format!("{st:04X}H bit {running} follows the run command, the output frequency rises, and the drive stops"),
                    ..Verdict::default()
                })
            },
        ));
    }
    if let (Some(ef), Some(reset), Some(fault)) =
        (bits.external_fault, bits.fault_reset, bits.fault)
    {
        let code = model.external_fault_code.clone();
        let fault_reg = model.register_with_role(Role::FaultCode);
        out.push(check(
            format!("{m}.motion.external-fault"),
            format!("Raise an external fault ({op:04X}H bit {ef}), read {st:04X}H and the fault code, then reset it (bit {reset})"),
            source,
            true,
            true,
            move |ctx| {
                let mut findings = Vec::new();
                if let Err(e) = ctx.remember(op)? {
                    return Ok(Verdict::error(format!("cannot read {op:04X}H first: {e}")));
                }
                let w = ctx.probe(ctx.frame(Pdu::WriteSingle { register: op, value: 1 << ef }), None)?;
                findings.extend(w.comparison.findings.clone());
                std::thread::sleep(Duration::from_millis(200));
                match ctx.read(st, 1)? {
                    Ok(v) if v[0] & (1 << fault) != 0 => {}
                    Ok(v) => findings.push(Finding::deviation(format!("after the external fault {st:04X}H reads {:04X}H: bit {fault} (fault) is 0", v[0]))),
                    Err(e) => findings.push(Finding::deviation(e)),
                }
                if let (Some(fr), Some((c, fact))) = (fault_reg, &code) {
                    match ctx.read(fr, 1)? {
                        Ok(v) if v[0] == *c && fact.basis == Basis::Decision => {
                            findings.push(Finding::observation(format!(
                                "fault code {fr:04X}H reads {c}, as the model decides ({})",
                                fact.citation()
                            )))
                        }
                        Ok(v) if v[0] == *c => {}
                        Ok(v) => findings.push(Finding {
                            severity: super::Severity::of(fact.basis),
                            text: format!("fault code {fr:04X}H reads {} (model: {c}, {})", v[0], fact.citation()),
                        }),
                        Err(e) => findings.push(Finding::deviation(e)),
                    }
                }
                let r = ctx.probe(ctx.frame(Pdu::WriteSingle { register: op, value: 1 << reset }), None)?;
                findings.extend(r.comparison.findings.clone());
                std::thread::sleep(Duration::from_millis(200));
                let _ = ctx.write(op, 0)?;
                match ctx.read(st, 1)? {
                    Ok(v) if v[0] & (1 << fault) == 0 => {}
                    Ok(v) => findings.push(Finding::deviation(format!("after the fault reset {st:04X}H reads {:04X}H: bit {fault} (fault) is still 1", v[0]))),
                    Err(e) => findings.push(Finding::deviation(e)),
                }
                Ok(Verdict {
                    findings,
                    exchanges: vec![w.record(), r.record()],
                    pass_summary: format!("{st:04X}H bit {fault} shows the external fault and clears on reset"),
                    ..Verdict::default()
                })
            },
        ));
    }
}

fn aggregates(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    out.push(check(
        format!("{m}.response-time"),
        format!("Response time of every reply of this mode against the manual's {} ms", model.limits.response_time_ms),
        cite(model, &model.limits.response_time_fact),
        false,
        false,
        |ctx| {
            if ctx.latencies.is_empty() {
                return Ok(Verdict::skip("no replies were measured"));
            }
            let mut l = ctx.latencies.clone();
            l.sort();
            let median = l[l.len() / 2];
            let max = l[l.len() - 1];
            // Below 4800 baud t3.5 is longer than the manuals' 10 ms: no reply may start
            // sooner, so t3.5 is the response time a drive can keep there.
            let line = ctx.line_timing();
            let manual = ctx.model.response_time_on(line.as_ref());
            // The first byte of a reply is received one character time after it starts
            // (a UART hands over a byte after its stop bit).
            let first_char = line.map_or(Duration::ZERO, |l| Duration::from_micros(l.char_time_us()));
            let limit = manual + first_char + ctx.opts.response_allowance;
            let ms = |d: Duration| d.as_secs_f64() * 1000.0;
            let stats = format!(
                "median {:.1} ms, max {:.1} ms over {} replies (manual: {} ms{}; allowance for host and adapter {} ms)",
                ms(median),
                ms(max),
                l.len(),
                ctx.model.limits.response_time_ms,
                if manual.as_millis() > u128::from(ctx.model.limits.response_time_ms) {
                    format!(", t3.5 on this line: {:.1} ms", ms(manual))
                } else {
                    String::new()
                },
                ctx.opts.response_allowance.as_millis()
            );
            let mut v = Verdict { pass_summary: stats.clone(), ..Verdict::default() };
            if median > limit {
                v.findings.push(Finding::deviation(format!("replies are late: {stats}")));
            } else if max > limit {
                let late = l.iter().filter(|d| **d > limit).count();
                v.findings.push(Finding::observation(format!("{late} replies took longer than {:.0} ms: {stats}", ms(limit))));
            }
            Ok(v)
        },
    ));
    out.push(check(
        format!("{m}.line-timing"),
        "Silence inside replies (at most t1.5) and before them (at least t3.5), on a line with timing".to_string(),
        "Modbus over Serial Line V1.02, 2.5.1.1 (t1.5, t3.5)".to_string(),
        false,
        false,
        |ctx| {
            let Some(line) = ctx.line_timing() else {
                return Ok(Verdict::skip(
                    "the link has no line timing (a pseudo-terminal without pacing, or TCP): gaps are the host's, not the device's",
                ));
            };
            if ctx.gap_replies == 0 {
                return Ok(Verdict::skip("no replies were measured"));
            }
            let t15 = Duration::from_micros(line.t1_5_us());
            let t35 = Duration::from_micros(line.t3_5_us());
            let mut v = Verdict {
                pass_summary: format!(
                    "{} replies: largest gap inside a reply {} us (t1.5 = {} us), none sooner than t3.5 = {} us",
                    ctx.gap_replies,
                    ctx.max_gap.as_micros(),
                    t15.as_micros(),
                    t35.as_micros()
                ),
                ..Verdict::default()
            };
            if let Some((req, gap)) = ctx.gaps.first() {
                v.findings.push(Finding::deviation(format!(
                    "{} replies had a silence over t1.5 ({} us + allowance {} us) inside them; the first, to request {req}, had {} us",
                    ctx.gaps.len(),
                    t15.as_micros(),
                    ctx.opts.gap_allowance.as_micros(),
                    gap.as_micros()
                )));
            }
            // The host reads the end of its request a little late (the write returns after
            // the bytes left): one character time of tolerance.
            let tolerance = Duration::from_micros(line.char_time_us());
            let early: Vec<&Duration> = ctx.latencies.iter().filter(|l| **l + tolerance < t35).collect();
            if let Some(first) = early.iter().min() {
                v.findings.push(Finding::deviation(format!(
                    "{} replies began less than t3.5 ({} us, less a tolerance of one character, {} us) after the request ended; the earliest after {} us",
                    early.len(),
                    t35.as_micros(),
                    tolerance.as_micros(),
                    first.as_micros()
                )));
            }
            Ok(v)
        },
    ));
    out.push(check(
        format!("{m}.exception-codes"),
        "Exception codes the device sent during this mode's checks, against the manual's table"
            .to_string(),
        format!("{}, {}", model.manual, model.exception_codes_source),
        false,
        false,
        |ctx| {
            let table: Vec<u8> = ctx.model.exception_codes.iter().map(|(c, _)| *c).collect();
            let seen: Vec<u8> = ctx.codes_seen.iter().copied().collect();
            let hex = |v: &[u8]| {
                v.iter()
                    .map(|c| format!("{c:02X}"))
                    .collect::<Vec<_>>()
                    .join(" ")
            };
            let foreign: Vec<u8> = seen
                .iter()
                .copied()
                .filter(|c| !table.contains(c))
                .collect();
            let unseen: Vec<u8> = table
                .iter()
                .copied()
                .filter(|c| !seen.contains(c))
                .collect();
            let mut v = Verdict {
                pass_summary: format!("table {}; sent {}", hex(&table), hex(&seen)),
                ..Verdict::default()
            };
            if !foreign.is_empty() {
                v.findings.push(Finding::deviation(format!(
                    "the device sent exception codes that are not in the manual's table ({}): {}",
                    hex(&table),
                    hex(&foreign)
                )));
            }
            if !unseen.is_empty() {
                v.findings.push(Finding::observation(format!(
                    "codes of the table that no check elicited: {} (sent: {})",
                    hex(&unseen),
                    hex(&seen)
                )));
            }
            Ok(v)
        },
    ));
}
