//! `conformance check`: probe a real or simulated drive and report every deviation from
//! its manual's model.

use std::io::{IsTerminal, Write};
use std::path::{Path, PathBuf};
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use conformance::codec::Mode;
use conformance::report::{csv, html, junit, text, Report};
use conformance::runner::{EchoMode, MasterTiming, Options};
use conformance::session::{self, SessionConfig, Target};
use conformance::sim::Quirk;

use super::common::{load_model, LineArgs, Number};

const AFTER_HELP: &str = "\
Examples:
  conformance check --sim f510                          the whole suite against the simulator
  conformance check --model f510 --port /dev/ttyUSB0 -b 9600 -P even --mode rtu -a 1
  conformance check --model l510 --tcp 10.0.0.7:4001 --mode ascii --format junit -o report.xml
  conformance check --sim a510 --quirk wrong-exception --only 'rtu.*'
  conformance check --sim f510 --format html -o report.html   a page for people
  conformance report report.json --format html -o report.html (a saved JSON report)

Safety on a real drive: the run and external-fault bits are never set without
--allow-motion (which warns first). Every register a check writes is read first and
written back at the end, also after Ctrl-C, and the restore is verified by reading back;
--read-only skips all writes.

A silent device passes nothing: a preflight read must be answered before the first
check (no answer: exit 2, with what was tried and what to try), and every silence is
followed by a liveness probe; a device that stops answering mid-run ends the run, and
every check left is an ERROR. A local echo (--echo) is stripped and shown on the link
line.

Statuses: PASS; DEVIATION (the manual says X, the device did Y); OBSERVATION (the manual
is silent or contradicts itself: what the device did); SKIP (with the reason); ERROR (the
run could not tell).

Exit codes: 0 no deviations; 1 deviations found; 2 the run could not complete (bad
arguments, the link failed or was interrupted, a check could not tell, or a register
could not be restored).";

/// Report format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// Human text: summary, then deviations first.
    Text,
    /// JSON (schema: vectors/schema/report.schema.json).
    Json,
    /// JUnit XML: one test case per check, deviations as failures.
    Junit,
    /// One self-contained HTML page: summary, deviations with their frames, plots, every
    /// check (filterable), the restore journal.
    Html,
    /// CSV: one row per check (id, mode, status, title, source, summary), RFC 4180.
    Csv,
}

/// Modes to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModesArg {
    /// RTU only.
    Rtu,
    /// ASCII only.
    Ascii,
    /// RTU, then ASCII (the simulator is restarted in each mode; a real drive is in one).
    Both,
}

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct CheckArgs {
    /// Run the suite against this suite's simulator of MODEL, started in-process on a
    /// pseudo-terminal pair (no hardware needed).
    #[arg(long, value_name = "MODEL", group = "target")]
    sim: Option<String>,
    /// Drive model of the device: f510, a510, l510, e510, l510-legacy.
    #[arg(long, value_name = "MODEL")]
    model: Option<String>,
    /// Read the model from this file instead of the built-in one.
    #[arg(long, value_name = "FILE")]
    model_file: Option<PathBuf>,
    /// Serial port of the device.
    #[arg(long, value_name = "PATH", group = "target")]
    port: Option<String>,
    /// A serial gateway carrying RTU or ASCII frames over TCP.
    #[arg(long, value_name = "HOST:PORT", group = "target")]
    tcp: Option<String>,
    #[command(flatten)]
    line: LineArgs,
    /// Transmission mode (default: rtu for a device, both for --sim).
    #[arg(short = 'm', long, value_enum)]
    mode: Option<ModesArg>,
    /// Node address of the device: decimal as in mbpoll (a bare number is decimal), or hex
    /// with H suffix or 0x prefix (0AH, 0x0A).
    #[arg(short = 'a', long, value_parser = Number::<u8>::quiet(), default_value = "1")]
    address: u8,
    /// A node address no device on the line has, for the other-address check (default:
    /// the model's highest address, or the one below the device's). A bare number is
    /// decimal; hex with H suffix or 0x prefix (F7H, 0xF7).
    #[arg(long, value_parser = Number::<u8>::quiet())]
    other_address: Option<u8>,
    /// Report format.
    #[arg(long, value_enum, default_value = "text")]
    format: Format,
    /// Write the report here (kept valid after every check) instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Run only the checks whose id contains PATTERN ('*' matches anything). Repeatable.
    #[arg(long, value_name = "PATTERN")]
    only: Vec<String>,
    /// List the checks without running them.
    #[arg(long)]
    list: bool,
    /// Skip every check that writes.
    #[arg(long, conflicts_with = "allow_motion")]
    read_only: bool,
    /// Enable the checks that set the run and external-fault bits (the motor may turn).
    #[arg(long)]
    allow_motion: bool,
    /// Enable the 08H checks that restart the device's communications (sub-function
    /// 0001H) or make it stop answering (0004H, Force Listen Only Mode, then 0001H).
    #[arg(long)]
    allow_restart: bool,
    /// Local echo of every request (a 2-wire RS-485 adapter whose receiver hears its own
    /// transmission): auto learns it from the preflight read, on expects it, off trusts
    /// that there is none. An echo is stripped and the reply awaited for the whole
    /// response window; it is reported on the link line, not as a deviation.
    #[arg(long, value_name = "auto|on|off", default_value = "auto")]
    echo: EchoMode,
    /// Milliseconds to wait for a reply.
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    timeout: u64,
    /// Milliseconds to listen where no reply is expected (broadcast, bad CRC, ...);
    /// default: derived from the device's measured response time (twice the longest
    /// reply delay, plus t3.5 and 20 ms, at least 50 ms, at most the timeout).
    #[arg(long, value_name = "MS")]
    silence: Option<u64>,
    /// Resend a request this many times when no byte comes back.
    #[arg(long, value_name = "N", default_value_t = 0)]
    retries: u32,
    /// Milliseconds over the manual's response time before replies count as late.
    #[arg(long, value_name = "MS", default_value_t = 20)]
    response_allowance: u64,
    /// Microseconds over t1.5 allowed for gaps inside a reply (default 20000: USB serial
    /// adapters deliver bytes in latency-timer slices, and on the paced simulator's
    /// pseudo-terminal the host's scheduler adds gaps of a few ms when it is busy).
    #[arg(long, value_name = "US")]
    gap_allowance: Option<u64>,
    /// Seed of the arbitrary data some checks send.
    #[arg(long, default_value_t = 0x7ECC0)]
    seed: u64,
    /// With --sim: inject a fault into the simulator (see `conformance simulate --help`).
    #[arg(long = "quirk", value_name = "QUIRK", requires = "sim")]
    quirks: Vec<Quirk>,
    /// With --sim: do not pace the simulator at the line's character time.
    #[arg(long, requires = "sim")]
    no_pace: bool,
    /// With --sim: write the simulator's traffic log (JSON lines) to this file.
    #[arg(long, value_name = "FILE", requires = "sim")]
    sim_log: Option<PathBuf>,
    /// List every passing check and every exchange in the text report.
    #[arg(short, long)]
    verbose: bool,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
}

pub fn render(report: &Report, format: Format, verbose: bool) -> anyhow::Result<String> {
    Ok(match format {
        Format::Text => text(report, verbose),
        Format::Json => serde_json::to_string_pretty(&report.to_json())? + "\n",
        Format::Junit => junit(report),
        Format::Html => html(report),
        Format::Csv => csv(report),
    })
}

/// Writes `contents` to `path` through a temporary file and a rename, so that the file is
/// always a whole report.
pub fn write_atomic(path: &Path, contents: &str) -> std::io::Result<()> {
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".partial");
    let tmp = PathBuf::from(tmp);
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(contents.as_bytes())?;
        f.sync_data()?;
    }
    std::fs::rename(&tmp, path)
}

pub fn run(args: CheckArgs) -> anyhow::Result<ExitCode> {
    let (model_id, target) = match (&args.sim, &args.port, &args.tcp) {
        (Some(m), None, None) => {
            if let Some(other) = &args.model {
                if other != m {
                    bail!("--sim {m} and --model {other} name different models");
                }
            }
            (
                m.clone(),
                Target::Sim {
                    quirks: args.quirks.clone(),
                    pace: !args.no_pace,
                    delay: None,
                    log: args.sim_log.clone(),
                },
            )
        }
        (None, Some(p), None) => (
            args.model
                .clone()
                .context("--port needs --model (f510, a510, l510, e510, l510-legacy)")?,
            Target::Serial { path: p.clone() },
        ),
        (None, None, Some(a)) => (
            args.model
                .clone()
                .context("--tcp needs --model (f510, a510, l510, e510, l510-legacy)")?,
            Target::Tcp { addr: a.clone() },
        ),
        _ if args.list => (
            args.model.clone().unwrap_or_else(|| "f510".into()),
            Target::Sim {
                quirks: vec![],
                pace: true,
                delay: None,
                log: None,
            },
        ),
        _ => bail!(
            "say what to check: --sim MODEL, or --model MODEL with --port PATH or --tcp HOST:PORT"
        ),
    };
    let model = Arc::new(load_model(
        &model_id,
        args.model_file.as_deref(),
        args.address,
    )?);
    let is_sim = matches!(target, Target::Sim { .. });
    let modes = match args.mode.unwrap_or(if is_sim {
        ModesArg::Both
    } else {
        ModesArg::Rtu
    }) {
        ModesArg::Rtu => vec![Mode::Rtu],
        ModesArg::Ascii => vec![Mode::Ascii],
        ModesArg::Both => vec![Mode::Rtu, Mode::Ascii],
    };
    let line = args.line.settings();
    if modes.contains(&Mode::Rtu) && line.data_bits != 8 {
        bail!("RTU needs 8 data bits (-d 8)");
    }
    let other_address = args.other_address.unwrap_or_else(|| {
        let last = *model.addresses.end();
        if args.address != last {
            last
        } else {
            args.address - 1
        }
    });
    if other_address == args.address || other_address == 0 {
        bail!("--other-address must differ from the device's address and from 00 (broadcast)");
    }
    let timeout = Duration::from_millis(args.timeout);
    let options = Options {
        address: args.address,
        other_address,
        read_only: args.read_only,
        allow_motion: args.allow_motion,
        only: args.only.clone(),
        timing: MasterTiming {
            timeout,
            // Given: used as it is. Not given: derived from the device's measured
            // response time, at most the timeout.
            silence: Duration::from_millis(args.silence.unwrap_or(args.timeout)),
            derive_silence: args.silence.is_none(),
            quiet: Duration::from_millis(30),
            gap: Duration::from_millis(5).max(Duration::from_micros(line.t3_5_us())),
            retries: args.retries,
        },
        response_allowance: Duration::from_millis(args.response_allowance),
        gap_allowance: Duration::from_micros(args.gap_allowance.unwrap_or(20_000)),
        seed: args.seed,
        echo: args.echo,
        line: Some(line),
        allow_restart: args.allow_restart,
    };
    let config = SessionConfig {
        model,
        target,
        modes,
        line,
        options,
    };

    if args.list {
        let checks = session::list(&config);
        let mut out = std::io::stdout().lock();
        for (_, c) in &checks {
            let flags = match (c.writes, c.motion, c.restarts) {
                (_, true, _) => "motion",
                (_, _, true) => "restart",
                (true, false, false) => "writes",
                _ => "",
            };
            writeln!(out, "{:<44} {:<7} {}", c.id, flags, c.title)?;
            writeln!(out, "{:<44} {:<7} source: {}", "", "", c.source)?;
        }
        writeln!(out, "{} checks", checks.len())?;
        return Ok(ExitCode::SUCCESS);
    }

    if args.allow_motion && !is_sim {
        eprintln!(
            "WARNING: --allow-motion: checks will set the run bit (the motor turns at 10.00 Hz) and the external-fault bit of node {:02X}. Make sure the machine is safe to move. Starting in 5 s; Ctrl-C to abort.",
            args.address
        );
        std::thread::sleep(Duration::from_secs(5));
    }

    let stop = Arc::new(AtomicBool::new(false));
    {
        let stop = stop.clone();
        ctrlc::set_handler(move || stop.store(true, Ordering::Relaxed))
            .context("cannot install the Ctrl-C handler")?;
    }
    let total = session::list(&config).len() as u64;
    if total == 0 {
        bail!(
            "no check matches --only {}; `--list` shows the check ids",
            args.only.join(" --only ")
        );
    }
    let bar = if !args.quiet && std::io::stderr().is_terminal() {
        let b = indicatif::ProgressBar::new(total);
        b.set_style(
            indicatif::ProgressStyle::with_template("{bar:30} {pos}/{len} eta {eta} {wide_msg}")
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
        );
        Some(b)
    } else {
        None
    };
    let mut write_error: Option<anyhow::Error> = None;
    let output = args.output.clone();
    let format = args.format;
    let verbose = args.verbose;
    let mut on_result = |r: &Report| {
        if let Some(b) = &bar {
            b.set_position(r.results.len() as u64);
        }
        if let (Some(path), None) = (&output, &write_error) {
            let res = render(r, format, verbose).and_then(|s| {
                write_atomic(path, &s).with_context(|| format!("cannot write {}", path.display()))
            });
            if let Err(e) = res {
                write_error = Some(e);
            }
        }
    };
    let mut on_start = |mode: Mode, c: &conformance::runner::Check| {
        if let Some(b) = &bar {
            b.set_message(format!("{mode} {}", c.id));
        }
    };
    let report = session::run(&config, &stop, &mut on_start, &mut on_result)?;
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    if let Some(e) = write_error {
        return Err(e);
    }
    finish(&report, args.format, args.verbose, args.output.as_deref())
}

/// Writes the final report to `output` (a one-line summary on stderr) or stdout, and
/// gives the exit code.
pub fn finish(
    report: &Report,
    format: Format,
    verbose: bool,
    output: Option<&Path>,
) -> anyhow::Result<ExitCode> {
    let rendered = render(report, format, verbose)?;
    match output {
        Some(path) => {
            write_atomic(path, &rendered)
                .with_context(|| format!("cannot write {}", path.display()))?;
            let s = report.summary();
            eprintln!(
                "{} {}: {} pass, {} deviations, {} observations, {} skipped, {} errors{}; report in {}",
                s.total,
                if report.kind == conformance::report::ReportKind::Gate { "cases" } else { "checks" },
                s.pass,
                s.deviation,
                s.observation,
                s.skip,
                s.error,
                if report.complete { "" } else { " [INCOMPLETE]" },
                path.display()
            );
        }
        None => {
            let mut out = std::io::stdout().lock();
            out.write_all(rendered.as_bytes())?;
            out.flush()?;
        }
    }
    Ok(ExitCode::from(report.exit_code()))
}
