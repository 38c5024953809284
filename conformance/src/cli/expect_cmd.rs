//! `--expect FILE` and `--strict-expect` (check, fuzz, gate, monitor), and `conformance
//! expect --from REPORT.json`: a starting expectations file from a run.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::Context;
use clap::Args;
use conformance::expect::{Day, Expectations};
use conformance::report::Report;

use super::output::{Format, FORMAT_DEFAULT};
use super::report_cmd::{emit, load};

/// The options that gate a run on an expectations file.
#[derive(Debug, Clone, Default, Args)]
pub struct ExpectArgs {
    /// An expectations file (TOML, docs: expectations): known, accepted results. Expected
    /// deviations are reported apart from new ones and do not make the exit code 1.
    #[arg(long, value_name = "FILE")]
    expect: Option<PathBuf>,
    /// With --expect: a check expected to deviate that passes (UNEXPECTED PASS) makes the
    /// exit code 1, so that the file is kept up to date.
    #[arg(long, requires = "expect")]
    strict_expect: bool,
}

/// The report options of a run held to expectations (`check`, `fuzz`, `gate`,
/// `monitor`): the report's format and the expectations file, which come together.
#[derive(Debug, Args)]
pub struct JudgedReportArgs {
    #[arg(long, value_enum, help = FORMAT_DEFAULT)]
    pub format: Option<Format>,
    #[command(flatten)]
    pub expect: ExpectArgs,
}

/// An expectations file, read before the run (an invalid file stops it before any
/// frame is sent).
#[derive(Debug, Default)]
pub struct Loaded {
    file: Option<Expectations>,
    strict: bool,
}

impl ExpectArgs {
    /// Reads the file, if one was given.
    pub fn load(&self) -> anyhow::Result<Loaded> {
        let file = match &self.expect {
            None => None,
            Some(p) => Some(Expectations::load(p)?),
        };
        Ok(Loaded {
            file,
            strict: self.strict_expect,
        })
    }
}

impl Loaded {
    /// Marks the report's results against the file (today's date judges expiry).
    pub fn apply(&self, report: &mut Report) {
        if let Some(f) = &self.file {
            conformance::report::apply_expectations(report, f, self.strict, Day::today());
        }
    }
}

const AFTER_HELP: &str = "\
Examples:
  conformance check --sim f510 --quirk wrong-exception -o run.json
  conformance expect --from run.json --reason \"firmware 1.2 answers 03H, ticket 123\" -o expect.toml
  conformance check --sim f510 --quirk wrong-exception --expect expect.toml      exit 0
  conformance check --sim f510 --expect expect.toml --strict-expect             UNEXPECTED PASS, exit 1

The file has one [[expect]] entry per deviation of the run (and per finding signature of a
fuzz run), each with the reason given (or a TODO to replace) and an empty ticket; the
device's identification and an expiry are written as comments to fill in.

Exit codes: 0 written; 2 the report cannot be read or the file cannot be written.";

/// `conformance expect`.
#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct ExpectCmdArgs {
    /// A JSON report (check, fuzz, gate or monitor --format json).
    #[arg(long, value_name = "REPORT.json")]
    from: PathBuf,
    /// The reason written into every entry (default: a TODO to replace).
    #[arg(long, value_name = "TEXT")]
    reason: Option<String>,
    /// Write here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
}

pub fn run(args: ExpectCmdArgs) -> anyhow::Result<ExitCode> {
    let report = load(&args.from)?;
    let text = conformance::report::starting_expectations(
        &report,
        &args.from.display().to_string(),
        args.reason.as_deref(),
    );
    // What was written must read back: the same parser gates the run.
    Expectations::parse(&text, "(written)").context("the written file does not read back")?;
    emit(&text, args.output.as_deref())?;
    Ok(ExitCode::SUCCESS)
}
