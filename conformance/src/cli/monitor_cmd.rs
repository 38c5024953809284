//! `conformance monitor`: listens to a bus that others drive, never sends a byte, and
//! judges both sides of every conversation against the drive's model.

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use std::time::{Duration, Instant, SystemTime};

use anyhow::Context;
use clap::{Args, ValueEnum};
use conformance::codec::timing::{LineSettings, Parity};
use conformance::codec::Mode;
use conformance::monitor::{self, Ended, Monitor, MonitorConfig, ReadOnlyPort, Tap};
use conformance::report::{Device, NodeInfo, Report, ReportKind, RunOptions};
use conformance::session::serial_kind;
use conformance::transport::capture::Captured;
use conformance::transport::serial::SerialTransport;

use super::common::{load_model, parse_nodes, NodeList, ParityArg};
use super::output::{finish, format_for};

const AFTER_HELP: &str = "\
Examples:
  conformance monitor --port /dev/ttyUSB1 --model f510 -a 1,2 -b 9600 -P even
  conformance monitor --port /dev/ttyUSB1 --model a510 --mode ascii -d 7 --duration 1h --format html -o bus.html
  conformance monitor --port /dev/pts/7 --model f510 --quiet --format json -o bus.json   (a bus's third end)
  conformance monitor --port /dev/ttyUSB1 --model e510 --mode auto   RTU or ASCII, told from the traffic
  conformance monitor --port /dev/ttyUSB1 --model f510   no -b: the baud rate and parity found by listening
  conformance monitor --capture-in run.pcapng --model f510 -b 9600 -P even   (a capture, offline)

Nothing is ever written to the port: it is read, and only read. Put a third adapter on the
RS-485 pair (or a third end of `conformance bus`) and leave the master and the drives as
they are.

Line settings: with no -b, the monitor finds them by listening. It sets the port to one
setting after another (each baud rate: 9600, 19200, 38400, 57600, 115200, 4800, 2400,
1200; even parity, then odd, then none, as a receiver without parity reads a line with
parity whole; 8 data bits, then 7 where the mode may be ASCII; -P and -d narrow it) until
the traffic at one is two valid frames in a row, and judges from there what it heard at
it. Stop bits cannot be told by listening (a UART checks only its first): -s is kept. On
`conformance bus`, give the bus --emulate-line, so that a port at other settings hears
what a UART at them would.

Frames: RTU frames end at t3.5 of silence, or by their length (a request's length follows
from its function and byte count, a reply's from its own), and each live line's frame
says which; a silence over t1.5 inside a frame makes it incomplete. ASCII frames run from
':' to CR LF. Each request is paired with at most one reply within --window; a 06H or
08H reply is a copy of its request, told apart by order and time (the line says so).

Judged, the drive: each reply against the model's prediction (exception codes, counts,
lengths; values only where an earlier write heard on the bus set them), its response time
against the manual's (with --allowance), gaps inside replies, replies to broadcasts and
to nodes not on the bus (-a). The master: the function is served, the registers are in
the map, counts within the model's limits, broadcasts are writes only, CRC/LRC, t3.5 of
silence before each request, no request while a reply is due, retries. Where the manual
does not settle a point, the finding is an observation, as in `check`.

Live, one line per exchange on stderr (time, ms since the previous frame, node, function,
meaning with the model's register names, CRC status, response time, verdict); --quiet
turns it off. At the end (Ctrl-C, SIGTERM, --duration, or the end of the input) the report
goes to stdout or -o, in any format, with per-node statistics.

--expect FILE accepts known deviations by result id (<mode>.nodeNN.drive.<kind>): they
are reported apart and do not make the exit code 1.

Exit codes: 0 no deviation heard (with --expect: none the file does not expect); 1
deviations; 2 could not run (bad arguments, the port
could not be opened).";

/// Transmission mode of the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModeArg {
    /// RTU.
    Rtu,
    /// ASCII.
    Ascii,
    /// Told from the traffic: two valid frames of one mode (nothing is sent).
    Auto,
}

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct MonitorArgs {
    /// The serial port (or pseudo-terminal) to listen on.
    #[arg(
        long,
        value_name = "PATH",
        required_unless_present = "capture_in",
        conflicts_with = "capture_in"
    )]
    port: Option<String>,
    /// Judge a capture instead of a port: pcap or pcapng (this suite's `--capture`, or a
    /// serial sniffer's under a user link type 147..162), each packet at its own time.
    #[arg(long, value_name = "FILE")]
    capture_in: Option<PathBuf>,
    /// With --port: also record every frame heard in this pcapng file (no direction: a
    /// tap hears both sides on one wire).
    #[arg(long, value_name = "FILE.pcapng", conflicts_with = "capture_in")]
    capture: Option<PathBuf>,
    /// The drives' model: f510, a510, l510, e510, l510-legacy (or --model-file).
    #[arg(long, value_name = "MODEL", required_unless_present = "model_file")]
    model: Option<String>,
    /// A description (model file) instead of a built-in model; --model is then not
    /// needed, the model id is the file's.
    #[arg(long, value_name = "FILE")]
    model_file: Option<PathBuf>,
    /// The nodes on the bus (requests to others must go unanswered); default: every node
    /// the master addresses.
    #[arg(short = 'a', long = "address", value_name = "N[,N..]", value_parser = parse_nodes)]
    nodes: Option<NodeList>,
    /// Baud rate. Default: found by listening (with --port; see "Line settings" below),
    /// 9600 with --capture-in.
    #[arg(short = 'b', long = "baud")]
    baud: Option<u32>,
    /// Parity. Default: with no -b, found by listening; even otherwise.
    #[arg(short = 'P', long = "parity", value_enum)]
    parity: Option<ParityArg>,
    /// Data bits (7 or 8; RTU needs 8). Default 8; with no -b, 8 then 7 where the mode may
    /// be ASCII.
    #[arg(short = 'd', long = "data-bits", value_parser = clap::value_parser!(u8).range(7..=8))]
    data_bits: Option<u8>,
    /// Stop bits (1 or 2).
    #[arg(short = 's', long = "stop-bits", default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    stop_bits: u8,
    /// RTU or ASCII.
    #[arg(short = 'm', long, value_enum, default_value = "rtu")]
    mode: ModeArg,
    /// Stop after this long (a bare number is seconds: 90; or 30s, 10m, 24h); default:
    /// until Ctrl-C, SIGTERM or the end of the input.
    #[arg(long, value_name = "T", value_parser = super::common::parse_duration)]
    duration: Option<std::time::Duration>,
    /// How long after a request its reply may come, ms.
    #[arg(long, value_name = "MS", default_value_t = MonitorConfig::WINDOW_MS)]
    window: u64,
    /// Allowance over the manual's response time before a reply counts as late, ms (the
    /// tap adapter's latency is in it).
    #[arg(long, value_name = "MS", default_value_t = MonitorConfig::ALLOWANCE_MS)]
    allowance: u64,
    #[command(flatten)]
    report: super::expect_cmd::JudgedReportArgs,
    /// Write the report here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// Also write every exchange heard to FILE as JSON lines (time, silence before, node,
    /// function, the request and what came back in hex, the meaning, the response time,
    /// the verdict and its findings), flushed line by line.
    #[arg(long, value_name = "FILE")]
    log: Option<PathBuf>,
    /// No live lines.
    #[arg(short, long)]
    quiet: bool,
    /// Every result in the text report, passes too.
    #[arg(short, long)]
    verbose: bool,
}

/// `ttyUSB3` for /dev/ttyUSB3 (a USB serial adapter, whose latency timer sysfs holds).
fn usb_name(port: &str) -> Option<String> {
    let name = std::path::Path::new(port).file_name()?.to_str()?;
    (name.starts_with("ttyUSB") && name.len() > 6 && name[6..].bytes().all(|b| b.is_ascii_digit()))
        .then(|| name.to_string())
}

/// Why listening ended, in the report's words.
fn describe_end(ended: &Ended) -> String {
    match ended {
        Ended::Duration => "--duration passed".to_string(),
        Ended::Interrupted => "interrupted (Ctrl-C or SIGTERM)".to_string(),
        Ended::EndOfInput(why) => format!("end of input ({why})"),
    }
}

pub fn run(args: MonitorArgs) -> anyhow::Result<ExitCode> {
    // An invalid expectations file stops the command before it listens (it is read
    // again for the report).
    args.report.expect.load()?;
    let asked = match args.mode {
        ModeArg::Rtu => Some(Mode::Rtu),
        ModeArg::Ascii => Some(Mode::Ascii),
        ModeArg::Auto => None,
    };
    if asked == Some(Mode::Rtu) && args.data_bits.is_some_and(|d| d != 8) {
        anyhow::bail!("RTU needs 8 data bits (-d 8)");
    }
    let nodes = args.nodes.as_ref().map(|n| n.0.clone()).unwrap_or_default();
    let model = load_model(
        args.model.as_deref().unwrap_or_default(),
        args.model_file.as_deref(),
        nodes.first().copied().unwrap_or(1),
    )?;
    let parity = args.parity.map(|p| match p {
        ParityArg::None => Parity::None,
        ParityArg::Even => Parity::Even,
        ParityArg::Odd => Parity::Odd,
    });
    // The line given; with no -b on a port, a starting point the search replaces.
    let line = LineSettings::new(
        args.baud.unwrap_or(9600),
        args.data_bits.unwrap_or(8),
        parity.unwrap_or(Parity::Even),
        args.stop_bits,
    );
    let started = humantime::format_rfc3339_seconds(SystemTime::now()).to_string();
    let now = || humantime::format_rfc3339_seconds(SystemTime::now()).to_string();
    let mut out = Out::new(&args)?;
    let new_monitor = |mode: Mode, line: LineSettings| -> anyhow::Result<Monitor> {
        if mode == Mode::Rtu && line.data_bits != 8 {
            anyhow::bail!("RTU needs 8 data bits (-d 8)");
        }
        let mut mon = Monitor::new(
            model.clone(),
            MonitorConfig {
                mode,
                line,
                nodes: nodes.clone(),
                window: Duration::from_millis(args.window),
                response_allowance: Duration::from_millis(args.allowance),
                gap_allowance: Duration::from_millis(args.allowance),
            },
        )?;
        // Nobody reads live lines with --quiet and no --log: not making them is faster.
        mon.set_live(!args.quiet || args.log.is_some());
        Ok(mon)
    };
    let (mode, mon, line, source, ended, when) = match (&args.port, &args.capture_in) {
        (_, Some(path)) => {
            // Read a part at a time (a buffer that stays in the cache), not whole.
            let open = || {
                std::fs::File::open(path)
                    .with_context(|| format!("cannot read the capture {}", path.display()))
            };
            let mode = match asked {
                Some(m) => m,
                None => {
                    let m = told(monitor::replay::guess_mode_from(open()?)?, line)?;
                    out.say(monitor::Said::Notice(&format!(
                        "--mode auto: {m} (two valid {m} frames at the start of the capture)"
                    )));
                    m
                }
            };
            let mut mon = new_monitor(mode, line)?;
            if args.baud.is_none() {
                // In the report too, as the settings found by listening are.
                let n = format!(
                    "no -b: the capture's timing is judged at {line} (a capture does not say its line's settings; give -b and -P)"
                );
                out.say(monitor::Said::Notice(&n));
                mon.notice(n);
                mon.take_notices();
            }
            let r = monitor::replay::replay_from(open()?, &mut mon, |l| {
                out.say(monitor::Said::Line(l))
            })
            .with_context(|| format!("cannot judge the capture {}", path.display()))?;
            if r.broken_by_host > 0 {
                let n = format!(
                    "{} frame(s) marked in the capture as broken by its writer's host as they left (a stall inside them; sent again): not judged",
                    r.broken_by_host
                );
                out.say(monitor::Said::Notice(&n));
                mon.notice(n);
                mon.take_notices();
            }
            if r.late_on_host > 0 {
                let n = format!(
                    "{} repl(ies) marked in the capture as begun late by the host of the simulator its writer ran (a busy host; by up to {:.1} ms): judged at the time they were due",
                    r.late_on_host,
                    r.most_late_on_host.as_secs_f64() * 1000.0
                );
                out.say(monitor::Said::Notice(&n));
                mon.notice(n);
                mon.take_notices();
            }
            let ended = match &r.stopped {
                Some(e) => {
                    eprintln!(
                        "warning: {}: {e}; the packets before it were judged",
                        path.display()
                    );
                    format!(
                        "end of the capture, cut short after {} packets ({e})",
                        r.packets
                    )
                }
                None => format!("end of the capture ({} packets)", r.packets),
            };
            let when = match r.first_ns {
                // The bus was heard when the capture was taken, not now.
                Some(ns) => {
                    let first = SystemTime::UNIX_EPOCH + Duration::from_nanos(ns);
                    When {
                        started: humantime::format_rfc3339_millis(first).to_string(),
                        finished: humantime::format_rfc3339_millis(first + r.span).to_string(),
                        listened: None,
                        searched: None,
                    }
                }
                None => {
                    let n = format!(
                        "the capture {}: the run's start and end are those of the analysis",
                        if r.packets == 0 {
                            "holds no packet"
                        } else {
                            "gives its packets no times"
                        }
                    );
                    out.say(monitor::Said::Notice(&n));
                    mon.notice(n);
                    mon.take_notices();
                    When {
                        started,
                        finished: now(),
                        listened: None,
                        searched: None,
                    }
                }
            };
            (
                mode,
                mon,
                line,
                format!("capture {}", path.display()),
                ended,
                when,
            )
        }
        (Some(port), None) => match listen(&args, port, line, asked, &new_monitor, &mut out) {
            Ok((mode, mon, line, source, ended, listened, searched)) => {
                let when = When {
                    started,
                    finished: now(),
                    listened: Some(listened),
                    searched,
                };
                (mode, mon, line, source, ended, when)
            }
            // With -o, a search that found no setting (interrupted, --duration, or none
            // gave frames) still writes its report: what each setting heard, and why it
            // stopped; then the error, exit 2 (issue 33: it wrote nothing).
            Err(e) => {
                if let (Some(nf), Some(_)) = (e.downcast_ref::<SearchFailed>(), &args.output) {
                    let mode = asked.unwrap_or(Mode::Rtu);
                    let mut mon = new_monitor(mode, line)?;
                    mon.notice(nf.0.clone());
                    let source = format!("port {port}");
                    let when = When {
                        started,
                        finished: now(),
                        listened: None,
                        searched: None,
                    };
                    report(
                        &args,
                        mode,
                        line,
                        when,
                        &mon,
                        &source,
                        "no line setting found by listening",
                        Some(&nf.0),
                    )?;
                }
                return Err(e);
            }
        },
        (None, None) => anyhow::bail!("say what to listen to: --port PATH or --capture-in FILE"),
    };
    let code = report(&args, mode, line, when, &mon, &source, &ended, None)?;
    // The report is written first: a log that failed loses no verdict.
    if let Some(e) = out.log_failed {
        eprintln!("error: {e:#}");
        return Ok(ExitCode::from(2));
    }
    Ok(code)
}

/// When the bus was heard, for the report: a port's listening (the search for its
/// settings included), or a capture's first packet to the end of its last.
struct When {
    started: String,
    finished: String,
    /// On a port: from the start to the end of the listening.
    listened: Option<Duration>,
    /// Its first part, spent finding the line's settings or the mode.
    searched: Option<Duration>,
}

/// The mode `--mode auto` was told, or why it was not.
fn told(g: monitor::guess::Guess, line: LineSettings) -> anyhow::Result<Mode> {
    if let monitor::guess::Guess::Mode(m, _) = g {
        return Ok(m);
    }
    match monitor::guess::why_not(&g, line) {
        Some(why) => anyhow::bail!("--mode auto: {why}"),
        None => anyhow::bail!(
            "--mode auto: too little traffic to tell RTU from ASCII (two valid frames of one mode are needed); say --mode rtu or --mode ascii"
        ),
    }
}

/// Where what the monitor says goes: live lines to stderr (and `--log`), the rolling
/// summary to a terminal, notices always.
struct Out<'a> {
    args: &'a MonitorArgs,
    err: std::io::Stderr,
    color: bool,
    usb: Option<String>,
    log: Option<(std::io::LineWriter<std::fs::File>, &'a std::path::Path)>,
    log_failed: Option<anyhow::Error>,
}

impl<'a> Out<'a> {
    fn new(args: &'a MonitorArgs) -> anyhow::Result<Out<'a>> {
        let log = match &args.log {
            Some(p) => Some((
                std::io::LineWriter::new(
                    std::fs::File::create(p)
                        .with_context(|| format!("cannot write the log {}", p.display()))?,
                ),
                p.as_path(),
            )),
            None => None,
        };
        let err = std::io::stderr();
        Ok(Out {
            args,
            color: err.is_terminal(),
            err,
            usb: args.port.as_deref().and_then(usb_name),
            log,
            log_failed: None,
        })
    }

    fn say(&mut self, said: monitor::Said<'_>) {
        match said {
            monitor::Said::Line(l) => {
                if let (Some((w, p)), None) = (self.log.as_mut(), self.log_failed.as_ref()) {
                    if let Err(e) = writeln!(w, "{}", l.to_json()) {
                        self.log_failed = Some(
                            anyhow::Error::new(e)
                                .context(format!("cannot write the log {}", p.display())),
                        );
                    }
                }
                if !self.args.quiet {
                    let _ =
                        if self.color && l.status == conformance::judge::VerdictStatus::Deviation {
                            writeln!(self.err, "\x1b[31m{l}\x1b[0m")
                        } else {
                            writeln!(self.err, "{l}")
                        };
                }
            }
            // On a terminal only: a pipe or a file gets the lines and the report.
            monitor::Said::Summary(lines) => {
                if self.color && !self.args.quiet {
                    let _ = writeln!(self.err, "\x1b[2m-- so far:");
                    for l in lines {
                        let _ = writeln!(self.err, "   {l}");
                    }
                    let _ = write!(self.err, "\x1b[0m");
                }
            }
            // Said even with --quiet: it changes what the report can be trusted for.
            monitor::Said::Notice(n) => {
                let n = match &self.usb {
                    Some(name) => n.replace("ttyUSBn", name),
                    None => n.to_string(),
                };
                let _ = writeln!(self.err, "notice: {n}");
            }
        }
    }
}

/// Listens on `port` (finding the line's settings first with no `-b`, and telling the
/// mode with `--mode auto`) until Ctrl-C, SIGTERM, `--duration` or the end of the input:
/// the mode, the monitor, the line, the port's description, why listening ended, how long
/// it listened and how long of that it took to find the settings or the mode.
fn listen(
    args: &MonitorArgs,
    port: &str,
    line: LineSettings,
    asked: Option<Mode>,
    new_monitor: &dyn Fn(Mode, LineSettings) -> anyhow::Result<Monitor>,
    out: &mut Out<'_>,
) -> anyhow::Result<Listened> {
    let serial = SerialTransport::open(port, line, serial_kind(port))
        .with_context(|| format!("cannot listen on {port}"))?;
    // The one handler of every long command: Ctrl-C, SIGTERM and SIGHUP end the listening
    // and write the report.
    let stop = super::interrupt::stop_flag_saying(super::interrupt::Stopping::Listening)?;
    let origin = Instant::now();
    let mut found_notice = None;
    let mut searched = None;
    let (line, told, serial) = if args.baud.is_some() {
        (line, None, serial)
    } else {
        let settings = monitor::line_search::candidates(
            &[],
            &args
                .parity
                .map(|_| line.parity)
                .into_iter()
                .collect::<Vec<_>>(),
            args.data_bits,
            args.stop_bits,
            asked,
        );
        let mut probe = monitor::ReadOnlySerial::new(serial);
        if !args.quiet {
            eprintln!(
                "no -b: finding the line's settings by listening on {} ({} settings to try); nothing is sent.",
                probe.describe(),
                settings.len()
            );
        }
        let quiet = args.quiet;
        let r = monitor::line_search::listen_for_line(
            &mut probe,
            &settings,
            asked,
            &stop,
            args.duration,
            origin,
            |s| {
                if !quiet {
                    eprintln!("  {s}");
                }
            },
        )
        .map_err(|e| anyhow::anyhow!("finding the line's settings: {e}"))?;
        match r {
            Ok(found) => {
                searched = Some(origin.elapsed());
                let said = found.describe();
                out.say(monitor::Said::Notice(&said));
                found_notice = Some(said);
                (
                    found.line,
                    Some((found.mode, found.heard)),
                    probe.into_inner(),
                )
            }
            Err(nf) => {
                return Err(SearchFailed(format!(
                    "{}; nothing was judged (give -b and -P)",
                    nf.describe()
                ))
                .into())
            }
        }
    };
    let port: Box<dyn conformance::transport::Transport> = Box::new(serial);
    let (mode, mut before, port) = match (asked, told) {
        // The search found the mode too (it looks for either unless one is asked).
        (_, Some((m, heard))) => (m, heard, port),
        (Some(m), None) => (m, Vec::new(), port),
        (None, None) => {
            let mut probe = ReadOnlyPort::new(port);
            let first = read_before_announcing(&mut probe, origin, line)?;
            if !args.quiet {
                eprintln!(
                    "listening on {} ({line}) to tell RTU from ASCII; nothing is sent.",
                    probe.describe()
                );
            }
            let told =
                monitor::listen_for_mode(&mut probe, &stop, args.duration, origin, line, first)
                    .map_err(|e| anyhow::anyhow!("--mode auto: {e}"))?;
            match told {
                Ok((m, heard)) => {
                    searched = Some(origin.elapsed());
                    if !args.quiet {
                        let n: usize = heard.iter().map(|(_, b)| b.len()).sum();
                        eprintln!("--mode auto: {m} (two valid {m} frames in the first {n} bytes)");
                    }
                    let port = probe.into_inner();
                    (m, heard, port)
                }
                Err(ended) => anyhow::bail!(
                    "--mode auto: listening ended ({}) before two valid frames told RTU from ASCII; nothing was judged",
                    describe_end(&ended)
                ),
            }
        }
    };
    let mut mon = new_monitor(mode, line)?;
    if let Some(n) = found_notice {
        mon.notice(n);
        // Said above already, as soon as it was found.
        mon.take_notices();
    }
    let capture = super::link::open_capture(args.capture.as_deref())?;
    let mut tap = match &capture {
        Some(rec) => ReadOnlyPort::new(Box::new(
            Captured::new(port, rec.clone(), mode, line).as_tap(),
        )),
        None => ReadOnlyPort::new(port),
    };
    // Unless the port was read already (the mode or the line told by listening), one read
    // before saying "listening": what is sent after the announcement is then not taken
    // for the tail of a frame under way when listening began.
    if before.is_empty() {
        before = read_before_announcing(&mut tap, origin, line)?;
    }
    if !args.quiet {
        eprintln!(
            "listening on {} ({mode}, {line}); nothing is sent. Ctrl-C ends and reports.",
            tap.describe()
        );
    }
    let ended = monitor::run_from(
        &mut tap,
        &mut mon,
        &stop,
        args.duration,
        origin,
        before,
        |said| out.say(said),
    )?;
    let listened = origin.elapsed();
    let ended = describe_end(&ended);
    let described = tap.describe();
    // The last frame heard is written when the port is let go.
    drop(tap);
    super::link::close_capture(args.capture.as_deref(), capture.as_ref());
    Ok((mode, mon, line, described, ended, listened, searched))
}

/// What [`listen`] heard: the mode, the monitor, the line, the port, why it ended, how
/// long it listened and the part of that the search took.
type Listened = (
    Mode,
    Monitor,
    LineSettings,
    String,
    String,
    Duration,
    Option<Duration>,
);

/// The port read once, for a poll, before listening is announced.
fn read_before_announcing(
    tap: &mut dyn monitor::Tap,
    origin: Instant,
    line: LineSettings,
) -> anyhow::Result<monitor::tap::Heard> {
    monitor::first_read(tap, origin, line)
        .map_err(|e| anyhow::anyhow!("cannot read {}: {e}", tap.describe()))
}

/// A search for the line's settings that found none: why, with what each setting heard.
#[derive(Debug)]
struct SearchFailed(String);

impl std::fmt::Display for SearchFailed {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for SearchFailed {}

/// The report of what `mon` heard on `source`; of a listening that stopped before it could
/// judge, `stopped` says why: the report says so, and its line is the one it was given, or
/// none found.
#[allow(clippy::too_many_arguments)]
fn report(
    args: &MonitorArgs,
    mode: Mode,
    line: LineSettings,
    when: When,
    mon: &Monitor,
    source: &str,
    ended: &str,
    stopped: Option<&str>,
) -> anyhow::Result<ExitCode> {
    let nodes = args.nodes.as_ref().map(|n| n.0.clone()).unwrap_or_default();
    let mut summary = mon.summary(source, ended);
    if let Some(l) = when.listened {
        summary.listened = l;
    }
    summary.searched = when.searched;
    let heard: Vec<u8> = mon.nodes().keys().copied().filter(|n| *n != 0).collect();
    // The nodes of -a, heard or not (a node that never answered is news), and every node
    // heard.
    let mut on_bus: Vec<u8> = mon
        .nodes()
        .keys()
        .copied()
        .chain(nodes.iter().copied())
        .collect();
    on_bus.sort_unstable();
    on_bus.dedup();
    let mut report = Report {
        kind: ReportKind::Monitor,
        codec: None,
        started: when.started,
        finished: Some(when.finished),
        complete: stopped.is_none(),
        stopped: stopped.map(str::to_string),
        device: Device {
            model: mon.model().id.clone(),
            manual: mon.model().manual.clone(),
            address: heard.first().or(nodes.first()).copied().unwrap_or(1),
            links: [(
                mode.to_string(),
                format!("{source} (listened, never written)"),
            )]
            .into_iter()
            .collect(),
            line: match (stopped, args.baud) {
                (Some(_), None) => "none found by listening".to_string(),
                _ => line.to_string(),
            },
            identification: None,
            simulated: None,
            description: Some(mon.model().source.clone()),
            nodes: on_bus
                .into_iter()
                .map(|address| NodeInfo {
                    address,
                    ..NodeInfo::default()
                })
                .collect(),
        },
        options: RunOptions {
            modes: vec![mode],
            read_only: true,
            timeout_ms: args.window,
            response_time_ms: Some(
                mon.model().response_time_on(Some(&line)).as_secs_f64() * 1000.0,
            ),
            response_allowance_ms: Some(args.allowance),
            ..RunOptions::default()
        },
        results: mon.results(),
        restore: Vec::new(),
        budget: Default::default(),
        fuzz: None,
        monitor: Some(summary),
        expect: None,
        master: None,
    };
    args.report.expect.load()?.apply(&mut report);
    finish(
        &report,
        format_for(args.report.format, args.output.as_deref()),
        args.verbose,
        args.output.as_deref(),
    )
}
