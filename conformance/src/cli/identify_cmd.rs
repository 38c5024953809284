//! `conformance identify`: which of the five models a device follows, from its answers
//! to reads only; and the identification that `check --model auto` runs first.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use conformance::identify::{self, render, Identification, IdentifyConfig, PlanLimits};
use conformance::model::{DriveModel, MODELS};
use conformance::runner::Options;

use super::common::load_model;
use super::link::{Link, TargetArgs};
use super::output::{progress_bar, write_atomic};
use conformance::transport::capture::SharedRecorder;

const AFTER_HELP: &str = "\
Examples:
  conformance identify --sim a510 --mode rtu            (the simulator: names a510)
  conformance identify --port /dev/ttyUSB0 -b 9600 -P even --mode rtu -a 1
  conformance identify --tcp 10.0.0.7:4001 --mode ascii --format json -o identify.json
  conformance check --model auto --port /dev/ttyUSB0 -b 9600 -P even   (identify, then check)
  conformance identify --port /dev/ttyUSB0 --model-file x100.json --model-file x200.json
                    (two descriptions more as candidates, beside the five built-in models)
  conformance identify --port /dev/ttyUSB0 --model-file x100.json --model-file x200.json --only-files
                    (those two only)

Only reads (03H) are sent: nothing is written and nothing restarted. The reads are chosen
from the models, where their predictions exclude each other: the identification register
(252FH; its value where a manual gives one, as the L510's 0110H), a register outside every
map (exception 02H in four manuals, 52H in the legacy L510 note), the borders of the
register groups that differ (group sizes, E510's '-' registers, the legacy note's alias
block), and the read limits (32 registers in the A510, 37 in the others in RTU). Each
model is scored by how many answers it predicted exactly; the report gives every probe's
request and reply and the models for and against it.

Descriptions (--model-file FILE, repeatable) are more candidates, judged as the five are;
with --only-files they are the only ones. Every candidate needs its own model id (a copy
of f510.json still called f510 is refused beside the built-in f510: give it its own
\"model\", or --only-files). The report names each description by its file, title and
SHA-256.

A silent device is not identified: the runner's preflight read must be answered first
(as in `check`), and every silence is followed by a liveness probe.

Exit codes: 0 one model predicted the answers; 1 ambiguous, or none of the five; 2 could
not run (bad arguments, no answer to the preflight, the link failed).";

/// Report format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// Human text: verdict, scores, then every probe.
    Text,
    /// JSON: the verdict, the scores and every probe with each model's prediction.
    Json,
}

/// How many probes and how strict: shared by `identify` and `check --model auto`.
#[derive(Debug, Args)]
pub struct IdentifyTuning {
    /// Answers a model may fail to predict and still be named (0: it must predict every
    /// answer). A real drive with a firmware deviation in one place misses one answer.
    /// (identify, and check --model auto)
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub tolerance: usize,
    /// Probes wanted per pair of models that tell the two apart (identify, and check
    /// --model auto).
    #[arg(long, value_name = "N", default_value_t = 3, value_parser = clap::value_parser!(u16).range(1..))]
    pub cover: u16,
    /// Most probes per mode (identify, and check --model auto).
    #[arg(long, value_name = "N", default_value_t = 32, value_parser = clap::value_parser!(u16).range(1..))]
    pub max_probes: u16,
}

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct IdentifyArgs {
    #[command(flatten)]
    target: TargetArgs,
    #[command(flatten)]
    tuning: IdentifyTuning,
    /// Report format.
    #[arg(long, value_enum, default_value = "text")]
    format: Format,
    /// Write the report here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
    /// Only the descriptions given with --model-file are candidates, not the five built-in
    /// models.
    #[arg(long)]
    only_files: bool,
}

/// The identification of the device `target` names, over `link`, recorded on `capture`.
pub fn config(
    target: &TargetArgs,
    link: Link,
    tuning: &IdentifyTuning,
    capture: Option<SharedRecorder>,
) -> anyhow::Result<IdentifyConfig> {
    let address = target.address();
    if address == 0 {
        bail!(
            "-a 0 is the broadcast address: no device answers it; give the device's node address"
        );
    }
    let sim_model = match (&link.named, link.is_sim) {
        (Some(m), true) => Some(Arc::new(load_model(m, None, address)?)),
        _ => None,
    };
    let mut models = MODELS
        .iter()
        .map(|m| DriveModel::builtin(m).map(Arc::new))
        .collect::<Result<Vec<_>, _>>()?;
    // Descriptions given with --model-file are more candidates (`check --model auto`
    // refuses them before it gets here).
    for path in target.model_file.as_deref().unwrap_or_default() {
        let m = DriveModel::from_path(path)?;
        if let Some(other) = models.iter().find(|o| o.id == m.id) {
            bail!(
                "{} describes model {:?}, as {} does: each candidate needs its own id (the file's \"model\"); with --only-files the built-in models are left out",
                path.display(),
                m.id,
                other.source.file.as_deref().map_or_else(
                    || format!("the built-in {}", other.id),
                    |f| f.to_string()
                )
            );
        }
        models.push(Arc::new(m));
    }
    let options = Options {
        address,
        bus: vec![address],
        // Identify sends reads to the device's own node only.
        other_address: if address == 0xFE { 0xFD } else { 0xFE },
        read_only: true,
        allow_motion: false,
        only: Vec::new(),
        timing: target.timing(link.is_sim, 300),
        response_allowance: Duration::from_millis(20),
        gap_allowance: Duration::from_millis(20),
        seed: 0,
        echo: target.echo,
        line: Some(link.line),
        allow_restart: false,
        injected_stalls: None,
    };
    Ok(IdentifyConfig {
        models,
        target: link.target,
        sim_model,
        modes: link.modes,
        line: link.line,
        options,
        limits: PlanLimits {
            cover: usize::from(tuning.cover),
            max_probes: usize::from(tuning.max_probes),
        },
        tolerance: tuning.tolerance,
        capture,
    })
}

/// Runs the identification, with a progress bar on a terminal unless `quiet`.
pub fn identify_device(
    config: &IdentifyConfig,
    stop: &AtomicBool,
    quiet: bool,
) -> anyhow::Result<Identification> {
    let bar = progress_bar(quiet, 0, "{bar:30} {pos}/{len} identify {wide_msg}");
    let id = identify::run(config, stop, &mut |mode, i, n| {
        if let Some(b) = &bar {
            b.set_length(n as u64);
            b.set_position(i as u64);
            b.set_message(format!("{mode}"));
        }
    })?;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    Ok(id)
}

pub fn run(args: IdentifyArgs) -> anyhow::Result<ExitCode> {
    if args.target.model.is_some() {
        bail!("identify finds the model itself: --model is not taken (`check --model auto` identifies and then checks; --model-file adds a description to the candidates)");
    }
    if args.only_files && args.target.model_file.is_none() {
        bail!("--only-files leaves the built-in models out: give the candidates with --model-file FILE");
    }
    let link = args.target.resolve_link(false, None)?;
    let capture = args.target.open_capture()?;
    let mut config = config(&args.target, link, &args.tuning, capture.clone())?;
    if args.only_files {
        config.models.retain(|m| m.source.file.is_some());
    }
    let stop = super::interrupt::stop_flag()?;
    let id = identify_device(&config, &stop, args.quiet)?;
    args.target.close_capture(capture.as_ref());
    let rendered = match args.format {
        Format::Text => render::text(&id),
        Format::Json => serde_json::to_string_pretty(&render::json(&id))? + "\n",
    };
    match &args.output {
        Some(path) => {
            write_atomic(path, &rendered)
                .with_context(|| format!("cannot write {}", path.display()))?;
            eprintln!("{}; report in {}", render::headline(&id), path.display());
        }
        None => {
            let mut out = std::io::stdout().lock();
            out.write_all(rendered.as_bytes())?;
            out.flush()?;
        }
    }
    Ok(ExitCode::from(id.verdict.exit_code()))
}
