//! `conformance report`: render a saved JSON report in another format; `conformance diff`:
//! what changed between two runs of the same model.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use conformance::report::Report;

use super::common::Number;
use super::output::{format_for, render, write_atomic, Format, FORMAT_DEFAULT};

const REPORT_AFTER_HELP: &str = "\
Examples:
  conformance check --sim f510 --format json -o run.json
  conformance report run.json                  text on the terminal (the default)
  conformance report run.json -o run.html      a page for people (the format from .html)
  conformance report run.json --format csv > run.csv
  conformance report bus.json                  a run of several nodes (check -a 1,2,5)

A report of a run of several nodes renders per node: text in one section per node and one
for the bus checks, JUnit one suite per node and one for the bus, CSV with a node column,
HTML with a table of the nodes and a node filter.

Exit codes: 0 rendered; 2 the file is not a report (or cannot be read or written).";

#[derive(Debug, Args)]
#[command(after_help = REPORT_AFTER_HELP)]
pub struct ReportArgs {
    /// A JSON report written by `check` or `gate` (--format json).
    #[arg(value_name = "FILE.json")]
    file: PathBuf,
    #[arg(long, value_enum, help = FORMAT_DEFAULT)]
    format: Option<Format>,
    /// Write here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// With --format text: list every passing check and every exchange.
    #[arg(short, long)]
    verbose: bool,
}

/// Reads a JSON report, naming the file in every error.
pub fn load(path: &Path) -> anyhow::Result<Report> {
    let text =
        std::fs::read_to_string(path).with_context(|| format!("cannot read {}", path.display()))?;
    Report::from_json_str(&text).with_context(|| format!("{}", path.display()))
}

/// Writes `text` to `output` or stdout.
pub fn emit(text: &str, output: Option<&Path>) -> anyhow::Result<()> {
    match output {
        Some(p) => write_atomic(p, text).with_context(|| format!("cannot write {}", p.display())),
        None => {
            let mut out = std::io::stdout().lock();
            out.write_all(text.as_bytes())?;
            out.flush()?;
            Ok(())
        }
    }
}

pub fn report(args: ReportArgs) -> anyhow::Result<ExitCode> {
    let report = load(&args.file)?;
    let format = format_for(args.format, args.output.as_deref());
    emit(
        &render(&report, format, args.verbose)?,
        args.output.as_deref(),
    )?;
    Ok(ExitCode::SUCCESS)
}

const DIFF_AFTER_HELP: &str = "\
Examples:
  conformance check --model f510 --port /dev/ttyUSB0 --format json -o fw-1.20.json
  conformance check --model f510 --port /dev/ttyUSB0 --format json -o fw-1.21.json
  conformance diff fw-1.20.json fw-1.21.json --format html -o changes.html

Runs of several nodes (check -a 1,2,5): checks are matched by check and node, so the same
check on two nodes is two checks. Two runs of several nodes compare node by node (a node in
one run only shows its checks as only in that run); --node N compares node N alone. A run
of one node and a run of several are compared only with --node N: node N's checks and the
bus checks (broadcasts, another address) of the run of several nodes against the run of one
node, whatever that one's address (a drive moved to another address on the bus); without
--node the pair is refused (exit 2).
  conformance diff single.json bus.json --node 5

Noise: a median response time (per mode, and per check where both runs timed at least 3
of its replies) counts as changed when it moved by more than max(20 % of the old median,
5 ms).

Exit codes: 0 nothing got worse; 1 something got worse (a check's status, a check new in
the second run that does not pass, or a median response time beyond noise); 2 a file is
not a report, or the two are of different models, or a run of one node and one of several
without --node (or --node names a node the run of several nodes does not have).";

/// Output format of a diff.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum DiffFormat {
    /// Human text.
    Text,
    /// JSON.
    Json,
    /// One self-contained HTML page.
    Html,
}

#[derive(Debug, Args)]
#[command(after_help = DIFF_AFTER_HELP)]
pub struct DiffArgs {
    /// The earlier run's JSON report.
    #[arg(value_name = "OLD.json")]
    old: PathBuf,
    /// The later run's JSON report.
    #[arg(value_name = "NEW.json")]
    new: PathBuf,
    /// Output format.
    #[arg(long, value_enum, default_value = "text")]
    format: DiffFormat,
    /// Write here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Compare this node only: its checks and the bus checks of a run of several nodes
    /// (a run of one node is taken whole). Needed to compare a run of one node with a run
    /// of several. Decimal, or hex as 05H / 0x05.
    #[arg(long, value_name = "N", value_parser = Number::<u8>::quiet())]
    node: Option<u8>,
}

pub fn diff(args: DiffArgs) -> anyhow::Result<ExitCode> {
    let old = load(&args.old)?;
    let new = load(&args.new)?;
    let d = match args.node {
        Some(n) => conformance::report::diff::Diff::for_node(&old, &new, n),
        None => conformance::report::diff::Diff::new(&old, &new),
    }
    .with_context(|| {
        format!(
            "cannot compare {} with {}",
            args.old.display(),
            args.new.display()
        )
    })?;
    let text = match args.format {
        DiffFormat::Text => d.text(),
        DiffFormat::Json => serde_json::to_string_pretty(&d.to_json())? + "\n",
        DiffFormat::Html => d.html(),
    };
    emit(&text, args.output.as_deref())?;
    Ok(ExitCode::from(d.exit_code()))
}
