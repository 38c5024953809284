//! `conformance model`: what a device description says, fact by fact, with its basis
//! (`model show`, also `conformance model [MODEL]` as before); `model lint`, `model learn`,
//! `model import` and `model export`.

use std::fmt::Write as _;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, Subcommand, ValueEnum};
use conformance::model::lint::{self, Finding, Severity};
use conformance::model::{Basis, DriveModel, Fact, Fault, SilenceReason, MODELS};

/// `conformance model`: a subcommand, or the arguments of `show` directly (the command
/// line before `show` existed).
#[derive(Debug, Args)]
#[command(args_conflicts_with_subcommands = true)]
pub struct ModelArgs {
    #[command(subcommand)]
    command: Option<ModelCommand>,
    #[command(flatten)]
    show: ShowArgs,
}

/// What `conformance model` does.
#[derive(Debug, Subcommand)]
pub enum ModelCommand {
    /// Show a description: the manual's facts and the model's decisions, with their basis.
    Show(ShowArgs),
    /// Check descriptions before use: every error with FILE:LINE:COL and the field's path.
    Lint(LintArgs),
    /// Draw up a first description from a live device (reads only, unless
    /// --allow-write): its map, functions, exceptions, silences and timing.
    Learn(super::model_learn_cmd::LearnArgs),
    /// A description (schema_version 2) from a register map as integrators keep it (CSV:
    /// register, name, access, min, max, unit, scale).
    Import(super::model_io_cmd::ImportArgs),
    /// A description in another format: pymodbus's simulator JSON.
    Export(super::model_io_cmd::ExportArgs),
}

/// `model lint`.
#[derive(Debug, Args)]
#[command(
    after_help = "Exit codes: 0 no error (warnings allowed unless --deny-warnings); 1 errors found; 2 a file cannot be read."
)]
pub struct LintArgs {
    /// The description files.
    #[arg(required = true, value_name = "FILE")]
    files: Vec<PathBuf>,
    /// Output: one line per finding as FILE:LINE:COL: error: PATH: message, or JSON.
    #[arg(long, value_enum, default_value_t = LintFormat::Text)]
    format: LintFormat,
    /// Fail (exit 1) on warnings too.
    #[arg(long)]
    deny_warnings: bool,
}

/// Output of `model lint`.
#[derive(Debug, Clone, Copy, ValueEnum)]
pub enum LintFormat {
    /// One finding a line, as compilers print theirs, then a count.
    Text,
    /// `{"files": [{"file", "findings": [...]}], "errors", "warnings"}`.
    Json,
}

/// `model show`.
#[derive(Debug, Args)]
pub struct ShowArgs {
    /// The model: f510, a510, l510, e510, l510-legacy (all of them if left out).
    model: Option<String>,
    /// Read the model from this file instead of the built-in one.
    #[arg(long, value_name = "FILE")]
    model_file: Option<PathBuf>,
    /// Only the model's decisions (where the manual is silent or contradicts itself).
    #[arg(long)]
    decisions: bool,
}

fn fact(o: &mut String, what: &str, f: &Fact, only_decisions: bool) {
    if only_decisions && f.basis != Basis::Decision {
        return;
    }
    let _ = writeln!(o, "  {what}  [{}]", f.basis);
    let _ = writeln!(o, "      {}", f.citation());
}

fn show(m: &DriveModel, only_decisions: bool) -> String {
    let mut o = String::new();
    let _ = writeln!(o, "{} — {}", m.id, m.title);
    let _ = writeln!(
        o,
        "  addresses {:02X}..{:02X}, broadcast {:02X}; functions {}",
        m.addresses.start(),
        m.addresses.end(),
        m.broadcast,
        m.functions
            .iter()
            .map(|f| format!("{f:02X}H"))
            .collect::<Vec<_>>()
            .join(" ")
    );
    let _ = writeln!(
        o,
        "  exception table: {}",
        m.exception_codes
            .iter()
            .map(|(c, t)| format!("{c:02X} {t}"))
            .collect::<Vec<_>>()
            .join("; ")
    );
    let l = &m.limits;
    let _ = writeln!(
        o,
        "  limits: frame {} bytes; read {} (RTU) / {} (ASCII); write {} / {}; same group: {}; response {}",
        l.max_frame, l.read.rtu, l.read.ascii, l.write.rtu, l.write.ascii, l.same_group,
        l.response_time_ms.map_or("not stated".to_string(), |t| format!("{t} ms"))
    );
    let groups = m.parameter_groups().count();
    let params: usize = m
        .parameter_groups()
        .flat_map(|g| g.registers.iter())
        .map(|r| r.clone().count())
        .sum();
    let no_access: usize = m
        .parameter_groups()
        .flat_map(|g| g.no_access.iter())
        .map(|r| r.clone().count())
        .sum();
    let _ = writeln!(
        o,
        "  parameters: {params} registers in {groups} groups, {no_access} marked '-' (no access)"
    );
    for fault in Fault::ALL {
        if let Some(r) = m.exceptions.get(&fault) {
            fact(
                &mut o,
                &format!("{fault}: exception {:02X}H", r.code),
                &r.fact,
                only_decisions,
            );
        }
    }
    for reason in SilenceReason::ALL {
        if let Some(f) = m.silence.get(&reason) {
            fact(&mut o, &format!("{reason}: no reply"), f, only_decisions);
        }
    }
    fact(
        &mut o,
        &format!("read limit {} / {}", l.read.rtu, l.read.ascii),
        &l.read.fact,
        only_decisions,
    );
    fact(
        &mut o,
        &format!("write limit {} / {}", l.write.rtu, l.write.ascii),
        &l.write.fact,
        only_decisions,
    );
    fact(
        &mut o,
        "same-group rule",
        &l.same_group_fact,
        only_decisions,
    );
    if let Some(id) = &m.identification {
        fact(&mut o, "identification", &id.fact, only_decisions);
    }
    fact(
        &mut o,
        "parameter access",
        &m.parameter_access,
        only_decisions,
    );
    for p in &m.parameter_read_only {
        fact(
            &mut o,
            &if p.registers.start() == p.registers.end() {
                format!(
                    "parameter {} ({:04X}H) read-only",
                    p.parameters,
                    p.registers.start()
                )
            } else {
                format!(
                    "parameters {} ({:04X}H..{:04X}H) read-only",
                    p.parameters,
                    p.registers.start(),
                    p.registers.end()
                )
            },
            &p.fact,
            only_decisions,
        );
    }
    for n in &m.named {
        if let Some((max, f)) = &n.max {
            fact(
                &mut o,
                &format!("{:04X}H maximum {max:04X}H", n.register),
                f,
                only_decisions,
            );
            if !only_decisions {
                for note in &n.max_notes {
                    let _ = writeln!(o, "      note: {note}");
                }
            }
        }
        if let Some(r) = &n.resolution {
            fact(
                &mut o,
                &format!(
                    "{:04X}H resolution {} units over {:04X}H",
                    n.register, r.step, r.above
                ),
                &r.fact,
                only_decisions,
            );
            fact(
                &mut o,
                &format!("{:04X}H value between steps", n.register),
                &r.handling,
                only_decisions,
            );
        }
    }
    // Registers the model adds, as runs of one decision.
    let added: Vec<_> = m
        .named
        .iter()
        .filter(|n| n.fact.basis == Basis::Decision)
        .collect();
    let mut i = 0;
    while i < added.len() {
        let mut j = i;
        while j + 1 < added.len()
            && added[j + 1].register == added[j].register + 1
            && added[j + 1].fact == added[i].fact
        {
            j += 1;
        }
        let (a, b) = (added[i], added[j]);
        let what = if i == j {
            format!("{:04X}H {} ({})", a.register, a.name, a.access)
        } else {
            format!(
                "{:04X}H..{:04X}H {} ({})",
                a.register, b.register, a.name, a.access
            )
        };
        fact(&mut o, &what, &a.fact, only_decisions);
        i = j + 1;
    }
    if let Some((code, f)) = &m.external_fault_code {
        fact(
            &mut o,
            &format!("external fault code {code}"),
            f,
            only_decisions,
        );
    }
    for (r, v, _, f) in &m.example_registers {
        fact(
            &mut o,
            &format!("example register {r:04X}H = {v:04X}H"),
            f,
            only_decisions,
        );
    }
    for (r, v, f) in &m.initial_values {
        fact(
            &mut o,
            &format!("initial value {r:04X}H = {v:04X}H"),
            f,
            only_decisions,
        );
    }
    for a in &m.aliases {
        fact(
            &mut o,
            &format!(
                "alias {:04X}H..{:04X}H = {:04X}H..",
                a.span.start(),
                a.span.end(),
                a.target
            ),
            &a.fact,
            only_decisions,
        );
    }
    for g in m.parameter_groups() {
        for n in &g.notes {
            let _ = writeln!(o, "  {}: {n}", g.name);
        }
    }
    o
}

/// Runs `conformance model`.
pub fn run(args: ModelArgs) -> anyhow::Result<ExitCode> {
    match args.command {
        Some(ModelCommand::Show(a)) => run_show(a),
        Some(ModelCommand::Lint(a)) => run_lint(a),
        Some(ModelCommand::Learn(a)) => super::model_learn_cmd::run(a),
        Some(ModelCommand::Import(a)) => super::model_io_cmd::import(a),
        Some(ModelCommand::Export(a)) => super::model_io_cmd::export(a),
        None => run_show(args.show),
    }
}

fn run_lint(args: LintArgs) -> anyhow::Result<ExitCode> {
    let mut files = Vec::new();
    let mut unreadable = false;
    for path in &args.files {
        let name = path.display().to_string();
        match std::fs::read_to_string(path) {
            Ok(text) => files.push((name.clone(), lint::lint(&name, &text), None)),
            Err(e) => {
                unreadable = true;
                files.push((name, Vec::new(), Some(format!("cannot read: {e}"))));
            }
        }
    }
    let all: Vec<&Finding> = files.iter().flat_map(|(_, f, _)| f).collect();
    let count = |s: Severity| all.iter().filter(|f| f.severity == s).count();
    let (errors, warnings) = (count(Severity::Error), count(Severity::Warning));
    let mut out = std::io::stdout().lock();
    match args.format {
        LintFormat::Text => {
            for (name, findings, unread) in &files {
                if let Some(e) = unread {
                    writeln!(out, "{name}: error: {e}")?;
                }
                for f in findings {
                    writeln!(out, "{f}")?;
                }
            }
            let owned: Vec<Finding> = all.iter().map(|f| (*f).clone()).collect();
            writeln!(
                out,
                "{}: {} in {} file{}",
                if errors > 0 || unreadable {
                    "failed"
                } else {
                    "ok"
                },
                lint::summary(&owned),
                files.len(),
                if files.len() == 1 { "" } else { "s" }
            )?;
        }
        LintFormat::Json => {
            let v = serde_json::json!({
                "files": files.iter().map(|(name, findings, unread)| serde_json::json!({
                    "file": name,
                    "readable": unread.is_none(),
                    "error": unread,
                    "findings": findings,
                })).collect::<Vec<_>>(),
                "errors": errors,
                "warnings": warnings,
            });
            writeln!(out, "{}", serde_json::to_string_pretty(&v)?)?;
        }
    }
    Ok(if unreadable {
        ExitCode::from(2)
    } else if errors > 0 || (args.deny_warnings && warnings > 0) {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

fn run_show(args: ShowArgs) -> anyhow::Result<ExitCode> {
    let models: Vec<DriveModel> = match (&args.model, &args.model_file) {
        (_, Some(path)) => vec![DriveModel::from_path(path)?],
        (Some(id), None) => vec![DriveModel::builtin(id)?],
        (None, None) => MODELS
            .iter()
            .map(|m| DriveModel::builtin(m))
            .collect::<Result<_, _>>()?,
    };
    let mut out = std::io::stdout().lock();
    for (i, m) in models.iter().enumerate() {
        if i > 0 {
            writeln!(out)?;
        }
        out.write_all(show(m, args.decisions).as_bytes())?;
    }
    Ok(ExitCode::SUCCESS)
}
