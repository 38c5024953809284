//! The checks, derived from a drive model. Each cites the manual section it tests; what
//! it expects comes from [`DriveModel::judge`], so the runner and the simulator share one
//! source of truth, and a device that differs from a decision of the model is reported as
//! an observation.

mod aggregate;
mod motion;
mod order;
mod protocol;
mod reads;
mod writes;

use super::{Ctx, Probed, RunError, Verdict};
use crate::codec::hex::Hex;
use crate::codec::pdu::{Pdu, Registers};
use crate::codec::Mode;
use crate::judge::{show, Finding};
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
    /// Whether it needs the serial line's own bytes: it sends what is not one whole
    /// valid frame (garbage, a partial frame, a wrong checksum) or judges the line's
    /// timing. Skipped, with the link's reason, where the link carries frames only (a
    /// Modbus TCP gateway: [`crate::transport::Transport::frames_only`]).
    pub needs_line: bool,
    /// Whether it is a check of the whole bus (a broadcast, a request to an address no
    /// device has): in a run of several nodes it runs once, after the nodes' sections,
    /// and reads back from every node ([`super::Options::bus`]).
    pub bus: bool,
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
        needs_line: false,
        bus: false,
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

/// The one check of a mode the description does not list in `modes`: skipped, saying
/// so (nothing is sent in that mode, not even the preflight).
pub fn mode_not_served(model: &DriveModel, mode: Mode) -> Check {
    let why = mode_not_served_reason(model, mode);
    check(
        format!("{mode}.mode"),
        format!("The device serves {}", mode.to_string().to_uppercase()),
        format!("{}: modes", model.manual),
        false,
        false,
        move |_| Ok(Verdict::skip(why.clone())),
    )
}

/// Why [`mode_not_served`] skips.
pub fn mode_not_served_reason(model: &DriveModel, mode: Mode) -> String {
    let listed: Vec<String> = model.modes().iter().map(|m| format!("\"{m}\"")).collect();
    format!(
        "the description's modes are [{}]: the device does not serve {}",
        listed.join(", "),
        mode.to_string().to_uppercase()
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

/// [`cite`] for a fact the description may leave out (`field` names it).
fn cite_or(model: &DriveModel, fact: Option<&Fact>, field: &str) -> String {
    match fact {
        Some(f) => cite(model, f),
        None => format!("{}: the description has no {field}", model.manual),
    }
}

/// The citation of the exception rule for `fault`, or that the description has none
/// (`exceptions.<kind>`).
fn cite_rule(model: &DriveModel, fault: crate::model::Fault) -> String {
    cite_or(
        model,
        model.rule(fault).map(|r| &r.fact),
        &format!("exceptions.{}", fault.key()),
    )
}

/// Why a check whose facts the description leaves out is skipped.
fn undescribed(fields: &[String]) -> String {
    format!("the description has no {}", fields.join(", no "))
}

/// A check that is skipped because the description leaves out `fields`: listed, so that
/// a report says what was not checked and why, never run.
fn undescribed_check(id: String, title: String, source: String, fields: Vec<String>) -> Check {
    let why = undescribed(&fields);
    check(id, title, source, false, false, move |_| {
        Ok(Verdict::skip(why.clone()))
    })
}

/// [`undescribed_check`] of the one field `field` (a path in the description), cited
/// where the description says something of it.
fn undescribed_field(model: &DriveModel, id: String, title: String, field: &str) -> Check {
    undescribed_check(
        id,
        title,
        cite_or(model, None, field),
        vec![field.to_string()],
    )
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
    if !model.serves_mode(mode) {
        return vec![mode_not_served(model, mode)];
    }
    let mut out = Vec::new();
    reads::examples(model, vectors, mode, &mut out);
    reads::identification(model, &m, &mut out);
    reads::map(model, &m, &mut out);
    reads::counts(model, mode, &m, &mut out);
    writes::writes(model, mode, &m, &mut out);
    protocol::functions(model, &m, &mut out);
    protocol::loop_back(model, &m, opts.seed, &mut out);
    protocol::diagnostics(model, &m, &mut out);
    order::order(model, mode, &m, &mut out);
    protocol::addressing(model, &m, &mut out);
    protocol::line(model, mode, &m, opts.seed, &mut out);
    motion::motion(model, &m, &mut out);
    aggregate::aggregates(model, &m, &mut out);
    out
}
