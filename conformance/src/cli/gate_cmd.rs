//! `conformance gate`: check another Modbus codec through an adapter.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Args;
use conformance::gate::{self, Adapter, GateOptions};
use conformance::vectors::VectorSet;

use super::gate_run::Common;
use super::output::shell_quote;

const AFTER_HELP: &str = "\
The adapter protocol (line-delimited JSON on the adapter's stdin/stdout) is documented in
adapters/PROTOCOL.md; adapters/*/ holds adapters for six implementations in four languages.

Examples:
  conformance gate --codec \"conformance adapter\"           this suite's own codec (the reference;
                                                         `conformance` is this program)
  conformance gate --codec \"python3 adapters/pymodbus/adapter.py\"
  conformance gate --codec target/release/rmodbus-adapter --format junit -o gate.xml
  conformance gate --codec \"./my-adapter\" --seed 7 --count 5000 --no-vectors

Masters (--master): the adapter wraps a Modbus master (client) library; the gate plays the
drive on a pseudo-terminal pair and misbehaves on purpose, one fault per case (stale reply,
no reply, bad CRC/LRC, another node's reply, exceptions, ...). See docs/src/master-gate.md.
  conformance gate --master \"conformance adapter --master\"   this suite's own master (a
                                                         test double)
  conformance gate --master \"python3 adapters/pymodbus-master/adapter.py\" --model l510-legacy
  conformance gate --master \"CMD\" --only rtu.read.stale-reply --master-timeout 500

--expect FILE accepts known deviations by case id: they are reported apart and do not
make the exit code 1.

Exit codes: 0 no deviations (with --expect: none the file does not expect); 1 deviations
found; 2 the gate could not complete (the
adapter could not start, exited twice, or a case could not be decided).";

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct GateArgs {
    /// The adapter command, run through `sh -c`. A first word `conformance` is this
    /// program (its own codec: `conformance adapter`), whatever is on the PATH.
    #[arg(
        long,
        value_name = "CMD",
        required_unless_present = "master",
        conflicts_with = "master"
    )]
    codec: Option<String>,
    /// A master adapter command (adapters/PROTOCOL.md, role "master"), run through
    /// `sh -c`: the gate plays the drive and judges the master. A first word
    /// `conformance` is this program (`conformance adapter --master`).
    #[arg(long, value_name = "CMD")]
    master: Option<String>,
    #[command(flatten)]
    master_opts: super::master_gate_cmd::MasterGateArgs,
    /// Seed of the differential cases.
    #[arg(long, value_parser = parse_seed, default_value = "0x7ECC0")]
    seed: u64,
    /// Number of differential cases.
    #[arg(long, default_value_t = 1000)]
    count: usize,
    /// Leave out the golden-vector cases.
    #[arg(long)]
    no_vectors: bool,
    /// Run only the cases whose id contains PATTERN ('*' matches anything). Repeatable.
    #[arg(long, value_name = "PATTERN")]
    only: Vec<String>,
    /// List the cases without starting the adapter.
    #[arg(long)]
    list: bool,
    /// Milliseconds to wait for each answer.
    #[arg(long, value_name = "MS", default_value_t = 2000)]
    timeout: u64,
    #[command(flatten)]
    report: super::expect_cmd::JudgedReportArgs,
    /// Write the report here (kept valid after every case) instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// List every passing case in the text report.
    #[arg(short, long)]
    verbose: bool,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
}

/// The adapter command as it is run: a command whose first word is `conformance` runs this
/// very program (`conformance adapter` works from a fresh clone, where `conformance` is
/// not on the PATH, and always tests the codec of the version that runs the gate).
pub(super) fn this_program(command: &str) -> anyhow::Result<String> {
    let trimmed = command.trim_start();
    let Some(rest) = trimmed.strip_prefix("conformance") else {
        return Ok(command.to_string());
    };
    if !(rest.is_empty() || rest.starts_with(char::is_whitespace)) {
        return Ok(command.to_string());
    }
    let exe = std::env::current_exe()
        .context("--codec \"conformance ...\" runs this program, but its path cannot be found: give the path of the conformance binary (e.g. target/release/conformance adapter)")?;
    Ok(format!("{}{rest}", shell_quote(&exe.to_string_lossy())))
}

fn parse_seed(s: &str) -> Result<u64, String> {
    let t = s.trim();
    match t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        Some(h) => u64::from_str_radix(h, 16),
        None => t.parse(),
    }
    .map_err(|e| format!("{s:?} is not a seed (decimal or 0x hex): {e}"))
}

/// The options of `args` that codecs and masters share (`--expect` loaded).
fn common(args: &GateArgs) -> anyhow::Result<Common> {
    Ok(Common {
        only: args.only.clone(),
        list: args.list,
        timeout: args.timeout,
        format: args.report.format,
        output: args.output.clone(),
        verbose: args.verbose,
        quiet: args.quiet,
        expect: args.report.expect.load()?,
    })
}

pub fn run(args: GateArgs) -> anyhow::Result<ExitCode> {
    if let Some(master) = args.master.clone() {
        let resolved = this_program(&master)?;
        return super::master_gate_cmd::run(&master, &resolved, &args.master_opts, common(&args)?);
    }
    let common = common(&args)?;
    let codec = args.codec.clone().unwrap_or_default();
    let set = VectorSet::builtin()?;
    let opts = GateOptions {
        seed: args.seed,
        count: args.count,
        vectors: !args.no_vectors,
        only: args.only.clone(),
        timeout: Duration::from_millis(args.timeout),
    };
    let cases = gate::cases(&set, &opts, &codec);
    let rows = cases.iter().map(|c| (c.id.as_str(), c.title.as_str()));
    if let Some(code) = common.before_run(rows, 52)? {
        return Ok(code);
    }
    let stop = super::gate_run::stop_flag()?;
    let mut adapter = Adapter::start(&this_program(&codec)?, opts.timeout)?;
    let report = common.report(&adapter.hello, &codec, args.seed, args.count);
    let mut progress = common.progress(report, cases.len());
    gate::run(&mut adapter, &cases, &stop, &mut progress);
    common.end(progress, &adapter.incidents, cases.len(), &stop, |_| {})
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn conformance_is_this_program() {
        let exe = std::env::current_exe().unwrap();
        let me = shell_quote(&exe.to_string_lossy());
        assert_eq!(
            this_program("conformance adapter").unwrap(),
            format!("{me} adapter")
        );
        assert_eq!(this_program("conformance").unwrap(), me);
        assert_eq!(
            this_program("  conformance adapter --break accept-bad-checksum").unwrap(),
            format!("{me} adapter --break accept-bad-checksum")
        );
        for other in [
            "conformance-adapter",
            "./conformance adapter",
            "python3 adapters/pymodbus/adapter.py",
        ] {
            assert_eq!(this_program(other).unwrap(), other);
        }
        assert_eq!(shell_quote("/a b/it's"), "'/a b/it'\\''s'");
    }
}

#[derive(Debug, Args)]
pub struct AdapterArgs {
    /// Break the adapter on purpose, to see the gate catch it: accept-bad-checksum decodes
    /// frames whatever their CRC or LRC.
    #[arg(long, value_name = "FAULT", hide = true)]
    r#break: Option<String>,
    /// This suite's own Modbus master behind the master adapter protocol (for
    /// `conformance gate --master`): a test double, for the gate's own tests.
    #[arg(long)]
    master: bool,
    /// With --master, a planted bug, for tests only: takes-stale-reply, no-t35,
    /// accepts-bad-crc, retry-storm, ignores-exception, reads-over-limit.
    #[arg(long, value_name = "QUIRK", requires = "master")]
    master_quirk: Option<String>,
}

pub fn adapter(args: AdapterArgs) -> anyhow::Result<ExitCode> {
    if args.master {
        let quirk = match args.master_quirk.as_deref() {
            None => None,
            Some(name) => Some(gate::master::reference::Quirk::parse(name).ok_or_else(|| {
                anyhow::anyhow!(
                    "unknown master quirk {name:?}; the quirks are {}",
                    gate::master::reference::Quirk::ALL
                        .iter()
                        .map(|(n, _)| *n)
                        .collect::<Vec<_>>()
                        .join(", ")
                )
            })?),
        };
        let stdin = std::io::stdin().lock();
        let stdout = std::io::stdout().lock();
        gate::master::reference::serve(stdin, stdout, quirk)?;
        return Ok(ExitCode::SUCCESS);
    }
    let fault = match args.r#break.as_deref() {
        None => None,
        Some("accept-bad-checksum") => Some(gate::reference::Fault::AcceptBadChecksum),
        Some(other) => {
            anyhow::bail!("unknown fault {other:?}; the one fault is accept-bad-checksum")
        }
    };
    let stdin = std::io::stdin().lock();
    let stdout = std::io::stdout().lock();
    gate::reference::serve(stdin, stdout, fault)?;
    Ok(ExitCode::SUCCESS)
}
