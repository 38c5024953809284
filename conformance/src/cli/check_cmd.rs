//! `conformance check`: probe a real or simulated drive and report every deviation from
//! its manual's model.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::Args;
use conformance::codec::Mode;
use conformance::identify;
use conformance::report::Report;
use conformance::runner::Options;
use conformance::session::{self, SessionConfig};

use super::identify_cmd::{self, IdentifyTuning};
use super::link::{Resolved, SafetyArgs, TargetArgs};
use super::output::{finish, format_for, progress_bar, render, write_atomic};

const AFTER_HELP: &str = "\
Examples:
  conformance check --sim f510                          the whole suite against the simulator
  conformance check --model f510 --port /dev/ttyUSB0 -b 9600 -P even --mode rtu -a 1
  conformance check --model l510 --tcp 10.0.0.7:4001 --mode ascii --format junit -o report.xml
  conformance check --model f510 --tcp 10.0.0.8:502 --framing mbap --unit 3 -a 3
                                        through a Modbus TCP gateway (checksum, line-timing,
                                        echo and garbage checks SKIP: a gateway hides them)
  conformance check --sim a510 --quirk wrong-exception --only 'rtu.*'
  conformance check --sim f510 --format html -o report.html   a page for people
  conformance check --model auto --port /dev/ttyUSB0 -b 9600 -P even   identify, then check
  conformance check --model f510 --port /dev/ttyUSB0 -a 1,2,5   three drives on one bus: a
                                        section per node, broadcast checks once
  conformance check --sim f510 -a 1,2,5 --quirk dead@5          the same, simulated
  conformance report report.json --format html -o report.html (a saved JSON report)

Safety on a real drive: the run and external-fault bits are never set without
--allow-motion (which warns first). Every register a check writes is read first and
written back at the end, also after Ctrl-C or SIGTERM, and the restore is verified by
reading back; --read-only skips all writes.

Ctrl-C, SIGTERM (timeout, CI runners) and SIGHUP stop the run after the current check:
what was written is restored and the report (-o FILE is whole after every check) is
marked INCOMPLETE, exit 2.

A silent device passes nothing: a preflight read must be answered before the first
check (no answer: exit 2, with what was tried and what to try), and every silence is
followed by a liveness probe; a device that stops answering mid-run ends the run, and
every check left is an ERROR. A local echo (--echo) is stripped and shown on the link
line.

--model auto runs `conformance identify` first (reads only) and then the checks of the
model it names; the identification heads the report as the check 'identify'. Where it
names no single model (ambiguous, or none of the five), nothing is checked: exit 2, with
the evidence on stderr.

Several drives on one bus (-a 1,2,5 or 1-4, one model): each node gets the whole
suite in its own section (its results carry its address: JSON field node, one JUnit test
suite per node), then the checks of the whole bus (broadcast write and read, another
address; `--list` marks them bus) run once: the broadcast write is read back from
every node that answers, and each is restored. A node that does not answer ends its own
section (its checks left are ERROR) and the other nodes are still checked; the run is
then INCOMPLETE (exit 2). The other address (--other-address) must be on none of them.

Statuses: PASS; DEVIATION (the manual says X, the device did Y); OBSERVATION (the manual
is silent or contradicts itself: what the device did); SKIP (with the reason); ERROR (the
run could not tell: no valid answer). A read or write a check needs first (the value it
must restore) that the device refuses with an exception is the device's answer: a
DEVIATION where the manual serves the register, a SKIP where it predicts the exception.

Expectations (--expect FILE, TOML; `conformance expect --from run.json` writes one):
known results with a reason and a ticket. Expected deviations are reported apart from
new ones; a check expected to deviate that passes is an UNEXPECTED PASS (exit 1 with
--strict-expect); expired entries and entries that matched nothing are reported and do
not apply.
  conformance check --sim f510 --quirk wrong-exception -o run.json
  conformance expect --from run.json --reason \"known, ticket 123\" -o expect.toml
  conformance check --sim f510 --quirk wrong-exception --expect expect.toml     exit 0

Exit codes: 0 no deviations (with --expect: none that the file does not expect); 1
deviations found (with --expect: new ones, or with --strict-expect an unexpected pass); 2
the run could not complete (bad arguments or expectations file, the link failed or was
interrupted, a check could not tell, or a register could not be restored).";

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct CheckArgs {
    #[command(flatten)]
    target: TargetArgs,
    #[command(flatten)]
    report: super::expect_cmd::JudgedReportArgs,
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
    #[command(flatten)]
    safety: SafetyArgs,
    #[command(flatten)]
    identify: IdentifyTuning,
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
    /// For the suite's own tests: the first N runs of each check whose id matches
    /// PATTERN end as if this host had stalled (PATTERN:N).
    #[arg(long, value_name = "PATTERN:N", hide = true, value_parser = injected_stall)]
    inject_host_stall: Option<(String, u32)>,
    /// List every passing check and every exchange in the text report.
    #[arg(short, long)]
    verbose: bool,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
}

pub fn run(mut args: CheckArgs) -> anyhow::Result<ExitCode> {
    // `check` runs several drives on one bus (-a 1,2,5).
    args.target.several_nodes = true;
    let expect = args.report.expect.load()?;
    let several = args.target.nodes.0.len() > 1;
    let capture = if args.list {
        None
    } else {
        args.target.open_capture()?
    };
    let mut stop = None;
    let mut identified = None;
    let resolved = if args.target.model_is_auto() {
        if args.list {
            bail!("--list needs a model: --model auto identifies the device, and --list talks to none");
        }
        if args.target.model_file.is_some() {
            bail!("--model auto identifies among the five built-in models; --model-file names a model itself");
        }
        if several {
            bail!("--model auto identifies one drive: run `conformance identify -a N` for each node, then `check --model MODEL -a {}` (one model for the bus)", args.target.nodes.0.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(","));
        }
        let link = args.target.resolve_link(false, None)?;
        let config = identify_cmd::config(&args.target, link, &args.identify, capture.clone())?;
        let flag = super::interrupt::stop_flag()?;
        let t0 = std::time::Instant::now();
        let t0_wall = std::time::SystemTime::now();
        let id = identify_cmd::identify_device(&config, &flag, args.quiet)?;
        let took = t0.elapsed();
        stop = Some(flag);
        let model = match &id.verdict {
            identify::Verdict::One(m) => m.clone(),
            _ => {
                eprint!("{}", identify::render::text(&id));
                let why = format!(
                    "check --model auto: {}; nothing was checked. Give the model with --model, or see the evidence above.",
                    identify::render::headline(&id)
                );
                eprintln!("{why}");
                // A run with -o always leaves its report (issue 24: a test found none
                // after an identification a loaded host made fail): the identification,
                // as ERROR, and why nothing else ran.
                let l = args.target.line.settings();
                let report = Report {
                    started: humantime::format_rfc3339_seconds(t0_wall).to_string(),
                    finished: Some(
                        humantime::format_rfc3339_seconds(std::time::SystemTime::now()).to_string(),
                    ),
                    complete: false,
                    stopped: Some(why),
                    device: conformance::report::Device {
                        model: "auto".into(),
                        address: args.target.address(),
                        line: format!("{} baud {}{}{}", l.baud, l.data_bits, l.parity, l.stop_bits),
                        ..Default::default()
                    },
                    results: vec![identify::render::check_result(&id, took)],
                    ..Report::default()
                };
                // Without -o the evidence above is the whole answer (stdout stays empty).
                if let Some(path) = args.output.as_deref() {
                    let format = format_for(args.report.format, Some(path));
                    finish(&report, format, args.verbose, Some(path))?;
                }
                return Ok(ExitCode::from(2));
            }
        };
        if let Some(sim) = &config.sim_model {
            if sim.id != model {
                eprint!("{}", identify::render::text(&id));
                bail!(
                    "the simulator runs {} but the device was identified as {model}: the identification is wrong",
                    sim.id
                );
            }
        }
        eprintln!("identify: {}", identify::render::headline(&id));
        identified = Some(identify::render::check_result(&id, took));
        args.target
            .resolve_as(args.target.resolve_link(false, None)?, &model)?
    } else {
        args.target.resolve(args.list, None)?
    };
    let Resolved {
        model,
        target,
        modes,
        line: _,
        is_sim,
        other_address,
    } = resolved;
    let options = Options {
        address: args.target.address(),
        bus: args.target.nodes.0.clone(),
        other_address,
        read_only: args.read_only,
        allow_motion: args.safety.allow_motion,
        only: args.only.clone(),
        timing: args.target.timing(is_sim, 300),
        response_allowance: Duration::from_millis(args.response_allowance),
        gap_allowance: Duration::from_micros(args.gap_allowance.unwrap_or(20_000)),
        seed: args.seed,
        echo: args.target.echo,
        line: Some(args.target.line.settings()),
        allow_restart: args.safety.allow_restart,
        injected_stalls: args.inject_host_stall.clone(),
    };
    let config = SessionConfig {
        model,
        target,
        modes,
        line: args.target.line.settings(),
        options,
        capture: capture.clone(),
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
            // A check of the whole bus runs once however many nodes -a names.
            let flags = match (c.bus, flags) {
                (true, "") => "bus".to_string(),
                (true, f) => format!("{f},bus"),
                (false, f) => f.to_string(),
            };
            writeln!(out, "{:<44} {:<10} {}", c.id, flags, c.title)?;
            writeln!(out, "{:<44} {:<10} source: {}", "", "", c.source)?;
        }
        let nodes = config.options.bus.len();
        if nodes > 1 {
            writeln!(
                out,
                "{} checks; with {nodes} nodes: {} results (each node's checks, the bus checks once)",
                checks.len(),
                session::planned(&config)
            )?;
        } else {
            writeln!(out, "{} checks", checks.len())?;
        }
        return Ok(ExitCode::SUCCESS);
    }

    if args.safety.allow_motion && !is_sim {
        eprintln!(
            "WARNING: --allow-motion: checks will set the run bit (the motor turns at 10.00 Hz) and the external-fault bit of node{} {}. Make sure the machine is safe to move. Starting in 5 s; Ctrl-C to abort.",
            if several { "s" } else { "" },
            args.target.nodes.0.iter().map(|n| format!("{n:02X}H")).collect::<Vec<_>>().join(", ")
        );
        std::thread::sleep(Duration::from_secs(5));
    }

    let stop = match stop {
        Some(s) => s,
        None => super::interrupt::stop_flag()?,
    };
    let total = session::planned(&config);
    if total == 0 {
        bail!(
            "no check matches --only {}; `--list` shows the check ids",
            args.only.join(" --only ")
        );
    }
    let bar = progress_bar(
        args.quiet,
        total,
        "{bar:30} {pos}/{len} eta {eta} {wide_msg}",
    );
    let mut write_error: Option<anyhow::Error> = None;
    let output = args.output.clone();
    let format = format_for(args.report.format, args.output.as_deref());
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
        // Frames the check damages on purpose are commented with its id.
        if let Some(rec) = &capture {
            if let Ok(mut r) = rec.lock() {
                r.set_label(Some(format!("check {}", c.id)));
            }
        }
    };
    let mut report = session::run(&config, &stop, &mut on_start, &mut on_result)?;
    args.target.close_capture(capture.as_ref());
    if let Some(r) = identified {
        report.results.insert(0, r);
    }
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    if let Some(e) = write_error {
        return Err(e);
    }
    expect.apply(&mut report);
    finish(&report, format, args.verbose, args.output.as_deref())
}

/// Parses `--inject-host-stall PATTERN:N`.
fn injected_stall(s: &str) -> Result<(String, u32), String> {
    let (pattern, n) = s
        .rsplit_once(':')
        .ok_or_else(|| format!("expected PATTERN:N, found {s:?}"))?;
    let n = n
        .parse()
        .map_err(|e| format!("expected a count after ':' in {s:?}: {e}"))?;
    Ok((pattern.to_string(), n))
}

#[cfg(test)]
mod tests {
    use super::write_atomic;

    /// A FIFO stands for /dev/null and /dev/stdout: it is written through and stays a
    /// FIFO (a rename over it made a regular file of /dev/null once).
    #[cfg(unix)]
    #[test]
    fn a_path_that_is_no_regular_file_is_written_in_place() {
        use std::io::Read;
        use std::os::unix::fs::FileTypeExt;
        let dir = std::env::temp_dir().join(format!("write-atomic-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let fifo = dir.join("fifo");
        nix::unistd::mkfifo(&fifo, nix::sys::stat::Mode::S_IRWXU).unwrap();
        let f = fifo.clone();
        let reader = std::thread::spawn(move || {
            let mut s = String::new();
            std::fs::File::open(&f)
                .unwrap()
                .read_to_string(&mut s)
                .unwrap();
            s
        });
        write_atomic(&fifo, "report\n").unwrap();
        assert_eq!(reader.join().unwrap(), "report\n");
        assert!(std::fs::metadata(&fifo).unwrap().file_type().is_fifo());
        // A regular file is still replaced whole.
        let file = dir.join("r.txt");
        write_atomic(&file, "one").unwrap();
        write_atomic(&file, "two").unwrap();
        assert_eq!(std::fs::read_to_string(&file).unwrap(), "two");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
