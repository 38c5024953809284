//! `conformance fuzz`: malformed and hostile traffic against a real or simulated drive,
//! every answer predicted by the model (see the library's `fuzz` module).

use std::io::IsTerminal;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::bail;
use clap::Args;
use conformance::codec::Mode;
use conformance::fuzz::{FuzzConfig, Writes};
use conformance::runner::Options;
use conformance::session::{self, SessionConfig};

use super::common::parse_duration;
use super::link::{SafetyArgs, TargetArgs};
use super::output::{finish, format_for};

const AFTER_HELP: &str = "\
Examples:
  conformance fuzz --sim f510                                   15 s per mode (RTU, then ASCII)
  conformance fuzz --sim f510 --duration 10m --mode rtu         a longer campaign
  conformance fuzz --sim f510 --quirk hang-on-byte-count --cases 500 --mode rtu
  conformance fuzz --model f510 --port /dev/ttyUSB0 -b 9600 -P even -a 1 --duration 10m
  conformance fuzz --model l510 --tcp 10.0.0.7:4001 --writes none --format json -o fuzz.json
  conformance fuzz --sim f510 --storm --mode rtu -b 19200       the storm test
  conformance fuzz --sim f510 --quirk ignore-t15 --mode rtu     timing damage (paced links)
  conformance fuzz --model f510 --tcp 10.0.0.8:502 --framing mbap --unit 3 -a 3
                    through a Modbus TCP gateway: damaged and back-to-back cases are not sent

Every case is judged by the model: a reply other than the predicted one, a reply where
silence is predicted, silence where a reply is predicted (the device answering the
liveness probe right after), a read that does not return a value the device confirmed
writing, and a hang (the device does not answer its liveness probes; it is waited for
with --recover-wait and the time it took to come back is reported) are findings. Each is
replayed smaller until it is the shortest frame or sequence that still reproduces it,
grouped by signature (mode.kind.function.field: the field of the difference, such as
exception-code, register-value, reply-to-broadcast, value-of-0000H, or for a hang what was
odd about the request, such as byte-count-over-data) with a count and the case classes
that found it, and printed with the `conformance send` command that replays it.

Speed on a link without timing (--no-pace, a pseudo-terminal, TCP): a whole reply ends an
exchange at once; after a frame the model predicts silence for, the liveness probe goes
at once, and its reply must be the next bytes back (anything before it is the device
answering the silent frame). Bytes that come when nothing is awaited are counted, and the
case they may belong to is sent again with full windows before anything is concluded
(--full-windows turns this off). The campaign line reports what this path did.

Timing damage (RTU on a line with timing: a real port, or the simulator's paced
pseudo-terminal; not on --no-pace or TCP, and the report says why): a silence between
t1.5 and t3.5 inside a frame (must be discarded), a frame split at every position with a
silence under t1.5 (answered) or over t3.5 (two fragments: silence), and two frames
without t3.5 between them (one frame with a wrong CRC by the standard: silence; a device
that answers the first is an observation). Classes timing.gap-in-frame,
timing.split-under-t15, timing.split-over-t35, timing.no-t35.

Storm test (--storm, instead of the cases): the device's own requests at line rate (t3.5
between frames, no more) interleaved with reads for another node (--other-address), that
node's replies, and broadcast reads (which must get no answer); with --writes any also
writes to the other node and broadcast writes (every drive on the bus executes them: the
value written is the one this device returned, journalled and restored for this device
only). Every own request must be answered within the manual's response time (at least
t3.5, plus one character and 20 ms for the host), none lost, none answered wrongly, and
nothing else answered. The report gives the response times under load against the idle
line (min/median/p95/p99/max) and fails the fuzz.<mode>.storm test case otherwise.

Safety on a real drive: --writes preserving (the default) sends a write only to this
device and only with the value the device just returned for that register; --writes none
sends no write; --writes any writes anything (with a warning; every register is
journalled and restored at the end, also after Ctrl-C or SIGTERM). Parameter group 09 (the
communication parameters) is never written; the run and external-fault register only
with --allow-motion; 08H sub-functions 0001H and 0004H only with --allow-restart.

Ctrl-C, SIGTERM (timeout, CI runners) and SIGHUP stop the campaign after the current
case: what was written is restored and the whole report is written, marked INCOMPLETE
(exit 2).

--expect FILE accepts known findings by their signature (signature = \"rtu.mismatch.03H.*\"):
they are reported apart and do not make the exit code 1.

Exit codes: 0 no finding (with --expect: none the file does not expect); 1 findings; 2
the run could not run or complete (no answer to the preflight, the link failed, a hung
device did not come back, a register could not be restored).";

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct FuzzArgs {
    #[command(flatten)]
    target: TargetArgs,
    #[command(flatten)]
    safety: SafetyArgs,
    /// Which writes may be sent: none, preserving (only the value just read, to this
    /// device), any.
    #[arg(long, value_name = "none|preserving|any", default_value = "preserving")]
    writes: Writes,
    /// Seed of the cases: the same seed gives the same cases.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// Cases per mode. With neither --cases nor --duration a campaign runs 15 s per mode
    /// (a first look: about 150 cases a mode at 9600 baud); give --duration or --cases for
    /// a real one.
    #[arg(long, value_name = "N")]
    cases: Option<u64>,
    /// Time per mode: a bare number is seconds (90), or with a unit (30s, 10m, 1h);
    /// with --cases, whichever comes first. Default 15s when --cases is not given (the
    /// time spent minimizing findings is not counted).
    #[arg(long, value_name = "TIME", value_parser = parse_duration)]
    duration: Option<Duration>,
    /// A liveness probe at least every K cases (besides the one after every silence).
    #[arg(long, value_name = "K", default_value_t = 50)]
    probe_every: u64,
    /// How long to wait for a device that stopped answering to come back (a bare number
    /// is seconds; or 500ms, 1m).
    #[arg(long, value_name = "TIME", default_value = "10s", value_parser = parse_duration)]
    recover_wait: Duration,
    /// Do not minimize findings by replaying.
    #[arg(long)]
    no_minimize: bool,
    /// On a link without timing (a pseudo-terminal, TCP), wait the full windows on every
    /// exchange as on a timed line, instead of the brisk path (which proves silences by
    /// sequence and repeats with full windows any case that late bytes put in doubt).
    #[arg(long)]
    full_windows: bool,
    #[command(flatten)]
    report: super::expect_cmd::JudgedReportArgs,
    /// Write the report here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Run the storm test instead of the cases: own requests at line rate among other
    /// nodes' traffic and broadcasts (see below).
    #[arg(long)]
    storm: bool,
    /// Frames in the storm test, per mode.
    #[arg(long, value_name = "N", default_value_t = 1000, requires = "storm")]
    storm_frames: u64,
    /// Own requests sent on the idle line first, the reference response times.
    #[arg(long, value_name = "N", default_value_t = 50, requires = "storm")]
    storm_idle: u64,
    /// List every exchange in the text report.
    #[arg(short, long)]
    verbose: bool,
    /// No progress: neither the bar on a terminal nor the lines (every 10 s) when stderr
    /// is not a terminal.
    #[arg(short, long)]
    quiet: bool,
}

/// Without --cases and --duration: a campaign a user can sit through.
const DEFAULT_DURATION: Duration = Duration::from_secs(15);

/// How often a progress line is printed when stderr is not a terminal.
const PLAIN_EVERY: Duration = Duration::from_secs(10);

/// Progress as plain lines, for a stderr that is a pipe or a CI log (no bar to redraw):
/// one line when a mode's cases start, one every [`PLAIN_EVERY`], and one when they end.
struct PlainProgress {
    mode: Option<Mode>,
    started: Instant,
    printed: Instant,
    /// When the last case ended (a mode's closing line is printed later, after its
    /// findings were minimized and the next mode has begun).
    last: Instant,
    cases: u64,
    findings: usize,
}

impl PlainProgress {
    fn new() -> Self {
        PlainProgress {
            mode: None,
            started: Instant::now(),
            printed: Instant::now(),
            last: Instant::now(),
            cases: 0,
            findings: 0,
        }
    }

    fn line(&self, mode: Mode, what: &str) {
        let secs = self.last.duration_since(self.started).as_secs_f64();
        eprintln!(
            "fuzz {mode}: {what}{} cases in {secs:.0} s, {:.1} cases/s, {} finding(s)",
            self.cases,
            self.cases as f64 / secs.max(1e-3),
            self.findings
        );
    }

    fn update(&mut self, mode: Mode, cases: u64, findings: usize) {
        if self.mode != Some(mode) {
            self.end();
            self.mode = Some(mode);
            self.started = Instant::now();
            self.printed = Instant::now();
            eprintln!("fuzz {mode}: started");
        }
        self.cases = cases;
        self.findings = findings;
        self.last = Instant::now();
        if self.printed.elapsed() >= PLAIN_EVERY {
            self.printed = Instant::now();
            self.line(mode, "");
        }
    }

    /// The closing line of the mode under way, if any.
    fn end(&mut self) {
        if let Some(mode) = self.mode.take() {
            self.line(mode, "done: ");
        }
    }
}

pub fn run(args: FuzzArgs) -> anyhow::Result<ExitCode> {
    let expect = args.report.expect.load()?;
    // Unpaced, the simulator answers at once (the fuzzer measures the device's answers,
    // not its timing).
    let sim_delay = args.target.no_pace.then_some(Duration::ZERO);
    let resolved = args.target.resolve(false, sim_delay)?;
    let (is_sim, other_address) = (resolved.is_sim, resolved.other_address);
    let sim_silence = if args.target.no_pace {
        8
    } else {
        (resolved.model.response_delay(&resolved.line).as_millis() as u64 + 40).max(60)
    };
    let options = Options {
        address: args.target.address(),
        bus: vec![args.target.address()],
        other_address,
        read_only: args.writes == Writes::None,
        allow_motion: args.safety.allow_motion,
        only: Vec::new(),
        timing: {
            let mut t = args.target.timing(is_sim, sim_silence);
            if is_sim && args.target.no_pace {
                // The unpaced simulator answers at once and in one piece. An unpaced
                // pseudo-terminal has no line, so no t3.5 to keep between frames (the
                // simulator frames RTU by length there).
                t.quiet = Duration::from_millis(3);
                t.gap = Duration::ZERO;
            }
            t
        },
        response_allowance: Duration::from_millis(20),
        gap_allowance: Duration::from_millis(20),
        seed: args.seed,
        echo: args.target.echo,
        line: Some(args.target.line.settings()),
        allow_restart: args.safety.allow_restart,
        injected_stalls: None,
    };
    let (cases, duration) = match (args.cases, args.duration) {
        (None, None) => (None, Some(DEFAULT_DURATION)),
        other => other,
    };
    if cases == Some(0) {
        bail!("--cases 0: nothing to send");
    }
    let cfg = FuzzConfig {
        seed: args.seed,
        cases,
        duration,
        writes: args.writes,
        probe_every: args.probe_every.max(1),
        recover_wait: args.recover_wait,
        minimize: !args.no_minimize,
        replay: args.target.replay_prefix("send", &resolved.model.id),
        storm: args.storm.then_some(conformance::fuzz::storm::StormConfig {
            frames: args.storm_frames,
            idle: args.storm_idle,
        }),
        full_windows: args.full_windows,
    };
    if args.storm && args.writes == Writes::Any {
        eprintln!(
            "WARNING: --storm --writes any sends broadcast writes (node 00H) and writes to node {:02X}: every drive on the bus executes a broadcast write, and only this drive's value is preserved, journalled and restored.",
            other_address
        );
    }
    if !is_sim && (args.writes == Writes::Any || args.safety.allow_motion) {
        eprintln!(
            "WARNING: --writes {}{}: the fuzzer will write values the drive did not hold{} at node {:02X}; every register written is journalled and restored at the end. Starting in 5 s; Ctrl-C to abort.",
            args.writes,
            if args.safety.allow_motion { " --allow-motion" } else { "" },
            if args.safety.allow_motion { " and may set the run bit (the motor may turn)" } else { "" },
            args.target.address()
        );
        std::thread::sleep(Duration::from_secs(5));
    }
    let config = SessionConfig {
        model: resolved.model,
        target: resolved.target,
        modes: resolved.modes,
        line: resolved.line,
        options,
        capture: args.target.open_capture()?,
    };
    let stop = super::interrupt::stop_flag()?;
    let terminal = std::io::stderr().is_terminal();
    let bar = (!args.quiet && terminal).then(|| {
        let (b, template) = match cases {
            Some(n) => (
                indicatif::ProgressBar::new(n),
                "{bar:30} {pos}/{len} {wide_msg}",
            ),
            // A campaign of a duration: the cases count up, the time is the bound.
            None => (
                indicatif::ProgressBar::new_spinner(),
                "{spinner} {pos} cases, {elapsed} {wide_msg}",
            ),
        };
        super::output::styled(b, template)
    });
    let mut plain = (!args.quiet && !terminal).then(PlainProgress::new);
    let mut started = Instant::now();
    let mut last_mode = None;
    // Frames a fuzz case damages on purpose are commented with how far the campaign was.
    let capture = config.capture.clone();
    if let Some(Ok(mut r)) = capture.as_ref().map(|c| c.lock()) {
        r.set_label(Some("fuzz, the first case".into()));
    }
    let mut progress = |mode: Mode, n: u64, findings: usize| {
        if let Some(Ok(mut r)) = capture.as_ref().map(|c| c.lock()) {
            r.set_label(Some(format!("fuzz {mode}, the case after {n} done")));
        }
        if last_mode != Some(mode) {
            last_mode = Some(mode);
            started = Instant::now();
        }
        if let Some(b) = &bar {
            b.set_position(n);
            b.set_message(format!(
                "{mode}: {:.0} cases/s, {findings} finding(s)",
                n as f64 / started.elapsed().as_secs_f64().max(1e-3)
            ));
        }
        if let Some(p) = plain.as_mut() {
            p.update(mode, n, findings);
        }
    };
    let mut report = session::fuzz(&config, &cfg, &stop, &mut progress)?;
    args.target.close_capture(config.capture.as_ref());
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    if let Some(p) = plain.as_mut() {
        p.end();
    }
    expect.apply(&mut report);
    finish(
        &report,
        format_for(args.report.format, args.output.as_deref()),
        args.verbose,
        args.output.as_deref(),
    )
}
