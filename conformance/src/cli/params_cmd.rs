//! `conformance params`: backs up a drive's parameters to a file a person reads and
//! edits, compares two sets of them (files, a live device, the model's initial values),
//! and restores a file with a plan, a confirmation, the runner's journal and an audit log.

use std::collections::BTreeMap;
use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;

use anyhow::{bail, Context};
use clap::{Args, Subcommand};
use conformance::codec::Mode;
use conformance::model::DriveModel;
use conformance::params::{
    self, diff, read_plan, read_values, write_plan, AuditLog, Backup, FileError, Header, Parameter,
    ReadOut, Side, StepResult,
};
use conformance::runner::{Ctx, Options};
use conformance::session;
use conformance::transport::Transport;

use super::common::load_model;
use super::link::TargetArgs;
use super::output::write_atomic;

const AFTER_HELP: &str = "\
Examples:
  conformance params backup --model f510 --port /dev/ttyUSB0 -b 9600 -P even -o drive.toml
  conformance params diff drive.toml live --model f510 --port /dev/ttyUSB0
  conformance params diff before.toml after.toml
  conformance params diff model live --sim f510 --mode rtu
  conformance params restore drive.toml --model f510 --port /dev/ttyUSB0 --dry-run
  conformance params restore drive.toml --model f510 --port /dev/ttyUSB0 --yes

The backup file is TOML: a [device] table (model, node, identification, time, mode), then a
table per group with `REGISTER = VALUE  # name, unit` (register in hex, value in decimal).
Read-only parameters are comments. A restore refuses a line for the command block or a
register the model marks read-only or reserved, naming the line.

Exit codes: backup 0 written, 2 the device or the file could not be used; diff 0 the same,
1 a parameter differs or one side has one the other has not, 2 a side could not be read;
restore 0 every planned write written and read back (or nothing to write, or --dry-run),
1 the device refused a write or did not hold it (the restore stopped there), 2 the file,
the link or the confirmation stopped it, or it was interrupted (what it wrote is undone).";

/// `conformance params`.
#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct ParamsArgs {
    #[command(subcommand)]
    command: ParamsCommand,
}

#[derive(Debug, Subcommand)]
enum ParamsCommand {
    /// Read every parameter of the model's map (bounded multi-register reads) and write a
    /// backup file a person can read and edit.
    Backup(BackupArgs),
    /// Compare two sets of parameters: each a backup file, `live` (the device of the link
    /// options) or `model` (the model's initial values, where it states them).
    Diff(DiffArgs),
    /// Write a backup file's values to the device: only the writes needed, each shown as
    /// its frame first, confirmed, verified by reading back, journalled and audited.
    Restore(RestoreArgs),
}

#[derive(Debug, Args)]
struct BackupArgs {
    #[command(flatten)]
    target: TargetArgs,
    /// The backup file to write.
    #[arg(short, long, value_name = "FILE")]
    output: PathBuf,
}

#[derive(Debug, Args)]
struct DiffArgs {
    /// Side A: a backup file, `live` or `model`.
    #[arg(value_name = "A")]
    a: String,
    /// Side B: a backup file, `live` or `model`.
    #[arg(value_name = "B")]
    b: String,
    #[command(flatten)]
    target: TargetArgs,
}

#[derive(Debug, Args)]
struct RestoreArgs {
    /// The backup file to restore.
    #[arg(value_name = "FILE")]
    file: PathBuf,
    #[command(flatten)]
    target: TargetArgs,
    /// Read the device and show the writes, then stop: nothing is written.
    #[arg(long)]
    dry_run: bool,
    /// Write without asking (without it, the restore asks once on a terminal and refuses
    /// when stdin is not one).
    #[arg(long)]
    yes: bool,
    /// The audit log (JSON lines, appended): one line per register written. Default:
    /// conformance-audit.jsonl beside FILE.
    #[arg(long, value_name = "FILE")]
    audit: Option<PathBuf>,
}

/// Runs `conformance params`.
pub fn run(args: ParamsArgs) -> anyhow::Result<ExitCode> {
    match args.command {
        ParamsCommand::Backup(a) => backup(a),
        ParamsCommand::Diff(a) => diff_cmd(a),
        ParamsCommand::Restore(a) => restore(a),
    }
}

/// The device of the link options, opened: what a [`Ctx`] is made of (with the link's
/// transport, which [`open`] returns beside it). Dropped, it says on stderr what the
/// `--capture` file holds, however the command ends.
struct Live<'t> {
    target: &'t TargetArgs,
    model: Arc<DriveModel>,
    options: Options,
    mode: Mode,
    link: String,
    /// The `--capture` recorder; before `sim`, so that it is said before the simulator
    /// stops.
    capture: Option<conformance::transport::capture::SharedRecorder>,
    /// The simulator behind a `--sim` link, held so that it runs until the command ends.
    _sim: Option<session::SimThread>,
}

impl Drop for Live<'_> {
    fn drop(&mut self) {
        self.target.close_capture(self.capture.as_ref());
    }
}

impl Live<'_> {
    /// The node the link options address.
    fn node(&self) -> u8 {
        self.options.address
    }

    /// A runner context over `transport`, after the preflight: a read the model says is
    /// answered; an error where the device does not answer it.
    fn ctx(&self, transport: Box<dyn Transport>) -> anyhow::Result<Ctx<'_>> {
        let mut ctx = Ctx::new(&self.model, None, self.mode, &self.options, transport);
        let v = ctx.preflight()?;
        if ctx.lost.is_some() {
            bail!(
                "the device does not answer: {}",
                v.error.unwrap_or(v.pass_summary)
            );
        }
        Ok(ctx)
    }
}

/// Opens the link of `target` in its first mode.
fn open(target: &TargetArgs) -> anyhow::Result<(Live<'_>, Box<dyn Transport>)> {
    let resolved = target.resolve(false, None)?;
    let (model, mode) = (resolved.model.clone(), resolved.modes[0]);
    let config = target.plain_session(resolved, mode, vec![target.address()], false)?;
    let (sim, transport) = session::open(&config, mode)?;
    let link = transport.describe();
    let live = Live {
        target,
        model,
        options: config.options,
        mode,
        link,
        capture: config.capture,
        _sim: sim,
    };
    Ok((live, transport))
}

/// Reads every parameter of `params` from the device of `ctx`; the registers it refused
/// are said on stderr.
fn read_all(
    ctx: &mut Ctx<'_>,
    model: &DriveModel,
    mode: Mode,
    node: u8,
    params: &[Parameter],
    stop: &AtomicBool,
) -> anyhow::Result<(ReadOut, usize)> {
    let plan = read_plan(model, mode, params);
    let out = read_values(ctx, node, &plan, stop)?;
    for (r, why) in &out.refused {
        eprintln!("note: {} not read: {why}", model.describe(*r));
    }
    Ok((out, plan.len()))
}

fn backup(args: BackupArgs) -> anyhow::Result<ExitCode> {
    let stop = super::interrupt::stop_flag()?;
    let (live, transport) = open(&args.target)?;
    let (model, mode, link, node) = (&live.model, live.mode, &live.link, live.node());
    let mut ctx = live.ctx(transport)?;
    let params = params::parameters(model);
    if params.is_empty() {
        bail!(
            "the {} model has no parameters (no parameter group, and no read-write block outside the command and monitor registers)",
            model.id
        );
    }
    let (read, reads) = read_all(&mut ctx, model, mode, node, &params, &stop)?;
    let header = Header {
        model: model.id.clone(),
        node,
        identification: params::read_identification(&mut ctx, model, node),
        time: humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string(),
        mode: Some(mode.to_string()),
    };
    let text = Backup::write(model, &header, &params, &read.values, &read.refused);
    write_atomic(&args.output, &text)
        .with_context(|| format!("cannot write {}", args.output.display()))?;
    let read_only = params.iter().filter(|p| !p.writable).count();
    let refused = if read.refused.is_empty() {
        String::new()
    } else {
        format!(
            "; {} refused by the device, as comments",
            read.refused.len()
        )
    };
    println!(
        "backup: {} parameters of {} node {node:02X} ({} read-only, as comments{refused}) in {reads} reads over {link} ({mode}) -> {}",
        read.values.len(),
        model.id,
        read_only,
        args.output.display()
    );
    Ok(ExitCode::SUCCESS)
}

/// A backup file, read; its errors name the file, the line and the column.
fn read_backup(path: &Path) -> anyhow::Result<Backup> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    Backup::parse(&text).with_context(|| format!("{} is not a backup file", path.display()))
}

fn label(path: &str, b: &Backup) -> String {
    let h = &b.header;
    let mut s = format!("{path} ({}, node {:02X}", h.model, h.node);
    if let Some(id) = h.identification {
        s.push_str(&format!(", identification {id:04X}H"));
    }
    if !h.time.is_empty() {
        s.push_str(&format!(", {}", h.time));
    }
    s.push(')');
    s
}

fn diff_cmd(args: DiffArgs) -> anyhow::Result<ExitCode> {
    if args.a == "live" && args.b == "live" {
        bail!("both sides are `live`: one link is one device; back one up first (params backup -o FILE)");
    }
    let live_wanted = args.a == "live" || args.b == "live";
    let mut files = BTreeMap::new();
    for s in [&args.a, &args.b] {
        if s != "live" && s != "model" {
            files.insert(s.clone(), read_backup(Path::new(s))?);
        }
    }
    // The model: the link's where a side is live, else the one the options or the
    // first file name.
    let stop = super::interrupt::stop_flag()?;
    let mut live = None;
    let model: Arc<DriveModel> = if live_wanted {
        let l = open(&args.target)?;
        let m = l.0.model.clone();
        live = Some(l);
        m
    } else if args.target.model_file().is_some() || args.target.model.is_some() {
        let id = args.target.model.clone().unwrap_or_default();
        Arc::new(load_model(
            &id,
            args.target.model_file(),
            args.target.address(),
        )?)
    } else {
        match files.values().next() {
            Some(b) => Arc::new(DriveModel::builtin(&b.header.model).with_context(|| {
                format!(
                    "the backup names the model {:?}: give its description with --model-file",
                    b.header.model
                )
            })?),
            None => bail!("say which model: --model or --model-file (both sides are `model`)"),
        }
    };
    for (path, b) in &files {
        if b.header.model != model.id {
            eprintln!(
                "note: {path} was read from a {} device; compared by the {} model's parameters",
                b.header.model, model.id
            );
        }
    }
    let params = params::parameters(&model);
    // A backup holds the writable parameters (read-only ones are comments): live is read
    // for the same ones.
    let writable: Vec<Parameter> = params.iter().filter(|p| p.writable).cloned().collect();
    let mut live_values = None;
    if let Some((live, transport)) = live {
        let (mode, link, node) = (live.mode, &live.link, live.node());
        let mut ctx = live.ctx(transport)?;
        let (read, _) = read_all(&mut ctx, &model, mode, node, &writable, &stop)?;
        live_values = Some((
            format!("live ({} node {node:02X} over {link}, {mode})", model.id),
            read.values,
        ));
    }
    let side = |s: &str| -> Side {
        match s {
            "live" => {
                let (label, values) = live_values.clone().unwrap_or_default();
                Side {
                    label,
                    values,
                    partial: false,
                }
            }
            "model" => Side {
                label: format!("model ({}: its initial values)", model.id),
                values: model
                    .initial_values
                    .iter()
                    .filter(|(r, ..)| params::find(&params, *r).is_some())
                    .map(|(r, v, _)| (*r, *v))
                    .collect(),
                partial: true,
            },
            path => {
                let b = &files[path];
                Side {
                    label: label(path, b),
                    values: b.values(),
                    partial: false,
                }
            }
        }
    };
    let (a, b) = (side(&args.a), side(&args.b));
    let d = diff(&params, &a, &b);
    let mut out = std::io::stdout().lock();
    writeln!(out, "A: {}", a.label)?;
    writeln!(out, "B: {}", b.label)?;
    for v in &d.differ {
        writeln!(
            out,
            "differs: {:<12} {:04X}H {:<14} A {} ({:04X}H)  B {} ({:04X}H)",
            v.group, v.register, v.name, v.a, v.a, v.b, v.b
        )?;
    }
    for (which, regs) in [("A", &d.only_a), ("B", &d.only_b)] {
        for r in regs.iter() {
            writeln!(out, "only in {which}: {}", model.describe(*r))?;
        }
    }
    write!(
        out,
        "{} of {} parameters compared differ",
        d.differ.len(),
        d.compared
    )?;
    if !d.only_a.is_empty() || !d.only_b.is_empty() {
        write!(
            out,
            "; {} only in A, {} only in B",
            d.only_a.len(),
            d.only_b.len()
        )?;
    }
    if d.not_stated > 0 {
        write!(
            out,
            "; {} not compared (the model states no initial value for them)",
            d.not_stated
        )?;
    }
    writeln!(out)?;
    Ok(ExitCode::from(if d.any() { 1 } else { 0 }))
}

/// Asks once on the terminal; false unless the answer is yes.
fn confirm(question: &str) -> anyhow::Result<bool> {
    eprint!("{question} [y/N] ");
    std::io::stderr().flush()?;
    let mut answer = String::new();
    std::io::stdin().read_line(&mut answer)?;
    Ok(matches!(answer.trim(), "y" | "Y" | "yes" | "YES" | "Yes"))
}

fn restore(args: RestoreArgs) -> anyhow::Result<ExitCode> {
    let file = read_backup(&args.file)?;
    let stop = super::interrupt::stop_flag()?;
    let (live, transport) = open(&args.target)?;
    let (model, mode, link, node) = (&live.model, live.mode, &live.link, live.node());
    if file.header.model != model.id {
        bail!(
            "{} is a backup of a {} device; this device is described as {}: restore a backup of the same model",
            args.file.display(),
            file.header.model,
            model.id
        );
    }
    let params = params::parameters(model);
    for e in file.entries() {
        if let Some(why) = params::refusal(model, &params, e.register, e.value) {
            let err = FileError::Refused {
                line: e.line,
                register: e.register,
                value: e.value,
                why,
            };
            bail!("{}: {err}", args.file.display());
        }
    }
    if file.header.node != node {
        eprintln!(
            "note: {} was read from node {:02X}; it is restored to node {node:02X}",
            args.file.display(),
            file.header.node
        );
    }
    let wanted = file.values();
    let mine: Vec<Parameter> = params
        .iter()
        .filter(|p| wanted.contains_key(&p.register))
        .cloned()
        .collect();
    let mut ctx = live.ctx(transport)?;
    // Another identification is another firmware or another device: worth saying, not
    // a reason to refuse (copying settings between drives is what a restore is for).
    if let (Some(was), Some(is)) = (
        file.header.identification,
        params::read_identification(&mut ctx, model, node),
    ) {
        if was != is {
            eprintln!(
                "note: {} was read from a device identifying as {was:04X}H; this one is {is:04X}H",
                args.file.display()
            );
        }
    }
    let (read, _) = read_all(&mut ctx, model, mode, node, &mine, &stop)?;
    if let Some((r, why)) = read.refused.iter().next() {
        let line = file
            .entries()
            .find(|e| e.register == *r)
            .map_or(0, |e| e.line);
        bail!(
            "{}: line {line}: the device refuses to read {r:04X}H ({why}), so a restore cannot tell whether it needs a write: take the line out (or make it a comment)",
            args.file.display()
        );
    }
    let current = read.values;
    let changes: Vec<(&Parameter, u16, u16)> = mine
        .iter()
        .filter_map(|p| {
            let (now, want) = (current.get(&p.register)?, wanted.get(&p.register)?);
            (now != want).then_some((p, *now, *want))
        })
        .collect();
    let writes = write_plan(model, mode, node, &changes)?;
    let mut out = std::io::stdout().lock();
    writeln!(
        out,
        "device: {} node {node:02X} over {link} ({mode}); {} of the file's {} parameters differ",
        model.id,
        changes.len(),
        mine.len()
    )?;
    if writes.is_empty() {
        writeln!(
            out,
            "nothing to write: the device holds every value of {}",
            args.file.display()
        )?;
        return Ok(ExitCode::SUCCESS);
    }
    writeln!(out, "plan: {} writes", writes.len())?;
    for w in &writes {
        let what: Vec<String> = w
            .registers()
            .enumerate()
            .map(|(i, r)| {
                let name =
                    params::find(&params, r).map_or(String::new(), |p| format!(" ({})", p.name));
                format!("{r:04X}H{name} {} -> {}", w.old[i], w.new[i])
            })
            .collect();
        writeln!(
            out,
            "  write {:02X}H {}: {}",
            w.function,
            what.join(", "),
            w.shown(mode)
        )?;
    }
    if args.dry_run {
        writeln!(out, "dry run: nothing written")?;
        return Ok(ExitCode::SUCCESS);
    }
    if !args.yes {
        if !std::io::stdin().is_terminal() {
            bail!("refusing to write without --yes: stdin is not a terminal to ask on (check the plan with --dry-run, then give --yes)");
        }
        out.flush()?;
        if !confirm(&format!(
            "write these {} frames to node {node:02X} over {link}?",
            writes.len()
        ))? {
            writeln!(out, "not confirmed: nothing written")?;
            return Ok(ExitCode::from(2));
        }
    }
    let audit_path = args.audit.clone().unwrap_or_else(|| {
        args.file
            .parent()
            .unwrap_or(Path::new(""))
            .join("conformance-audit.jsonl")
    });
    let mut audit = AuditLog::open(&audit_path)
        .with_context(|| format!("cannot open the audit log {}", audit_path.display()))?;
    let outcome = params::restore(
        &mut ctx,
        model,
        node,
        &writes,
        &mut audit,
        &stop,
        &mut |s| {
            let regs: Vec<String> = s.write.registers().map(|r| format!("{r:04X}H")).collect();
            let said = match &s.result {
                StepResult::Written => "written, read back".to_string(),
                StepResult::NotHeld { why, .. } => format!("NOT HELD: {why}"),
                StepResult::Refused { why, .. } => format!("REFUSED: {why}"),
                StepResult::NoAnswer(why) => format!("NO ANSWER: {why}"),
            };
            println!("  {:02X}H {}: {said}", s.write.function, regs.join(" "));
        },
    )
    .with_context(|| format!("cannot append to the audit log {}", audit_path.display()))?;
    let written: Vec<String> = outcome
        .steps
        .iter()
        .filter(|s| s.result == StepResult::Written)
        .flat_map(|s| {
            s.write
                .registers()
                .map(|r| format!("{r:04X}H"))
                .collect::<Vec<_>>()
        })
        .collect();
    let not_written: Vec<String> = outcome
        .steps
        .iter()
        .filter(|s| s.result != StepResult::Written)
        .map(|s| &s.write)
        .chain(outcome.not_sent.iter())
        .flat_map(|w| {
            w.registers()
                .map(|r| format!("{r:04X}H"))
                .collect::<Vec<_>>()
        })
        .collect();
    // "N (0100H 0101H)", or "0 (none)".
    let counted = |registers: &[String]| {
        let list = if registers.is_empty() {
            "none".to_string()
        } else {
            registers.join(" ")
        };
        format!("{} ({list})", registers.len())
    };
    writeln!(out, "written and verified: {}", counted(&written))?;
    writeln!(out, "not written: {}", counted(&not_written))?;
    for (n, r, v) in &outcome.journal {
        let state = outcome
            .steps
            .iter()
            .find(|s| s.write.registers().any(|x| x == *r))
            .map_or("", |s| match s.result {
                StepResult::Written => "written",
                StepResult::NotHeld { .. } => "written, not held",
                StepResult::Refused { .. } => "refused, unchanged",
                StepResult::NoAnswer(_) => "unknown (no answer)",
            });
        writeln!(out, "journal: node {n:02X} {r:04X}H was {v:04X}H: {state}")?;
    }
    for u in &outcome.undo {
        writeln!(out, "undo: {:04X}H: {}", u.register, u.detail)?;
    }
    writeln!(out, "audit: {}", audit.path().display())?;
    if outcome.complete() {
        writeln!(out, "restored: every planned write written and read back")?;
        return Ok(ExitCode::SUCCESS);
    }
    let again = format!(
        "{} {}",
        args.target.replay_prefix("params restore", &model.id),
        args.file.display()
    );
    if outcome.interrupted {
        let undone = outcome.undo.iter().all(|u| u.restored);
        writeln!(
            out,
            "interrupted: {}; to restore the file after all: {again} --yes",
            if undone {
                "what this restore wrote is undone (the runner's journal)"
            } else {
                "NOT everything it wrote could be undone: see the undo lines"
            }
        )?;
        return Ok(ExitCode::from(2));
    }
    if let Some(s) = outcome.failed() {
        writeln!(
            out,
            "stopped at the write of {:04X}H: what was written stays; to resume (it plans only what is left): {again} --yes",
            s.write.start
        )?;
        return Ok(ExitCode::from(match s.result {
            StepResult::NoAnswer(_) => 2,
            _ => 1,
        }));
    }
    Ok(ExitCode::from(2))
}
