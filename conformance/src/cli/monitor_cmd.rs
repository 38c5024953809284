//! `conformance monitor`: listens to a bus that others drive, never sends a byte, and
//! judges both sides of every conversation against the drive's model.

use std::io::{IsTerminal, Write};
use std::path::PathBuf;
use std::process::ExitCode;

use std::time::{Duration, SystemTime};

use anyhow::Context;
use clap::{Args, ValueEnum};
use conformance::codec::timing::{LineSettings, Parity};
use conformance::codec::Mode;
use conformance::monitor::{self, Ended, Monitor, MonitorConfig, ReadOnlyPort, Tap};
use conformance::report::{Device, NodeInfo, Report, ReportKind, RunOptions};
use conformance::session::serial_kind;
use conformance::transport::capture::Captured;
use conformance::transport::serial::SerialTransport;

use super::check_cmd::{finish, Format};
use super::common::{load_model, parse_nodes, NodeList, ParityArg};

const AFTER_HELP: &str = "\
Examples:
  conformance monitor --port /dev/ttyUSB1 --model f510 -a 1,2 -b 9600 -P even
  conformance monitor --port /dev/ttyUSB1 --model a510 --mode ascii -d 7 --duration 1h --format html -o bus.html
  conformance monitor --port /dev/pts/7 --model f510 --quiet --format json -o bus.json   (a bus's third end)
  conformance monitor --capture-in run.pcapng --model f510 -b 9600 -P even   (a capture, offline)

Nothing is ever written to the port: it is read, and only read. Put a third adapter on the
RS-485 pair (or a third end of `conformance bus`) and leave the master and the drives as
they are.

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

Exit codes: 0 no deviation heard; 1 deviations; 2 could not run (bad arguments, the port
could not be opened).";

/// Transmission mode of the bus.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModeArg {
    /// RTU.
    Rtu,
    /// ASCII.
    Ascii,
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
    /// The drives' model: f510, a510, l510, e510, l510-legacy.
    #[arg(long, value_name = "MODEL")]
    model: String,
    /// A model file instead of a built-in model.
    #[arg(long, value_name = "FILE")]
    model_file: Option<PathBuf>,
    /// The nodes on the bus (requests to others must go unanswered); default: every node
    /// the master addresses.
    #[arg(short = 'a', long = "address", value_name = "N[,N..]", value_parser = parse_nodes)]
    nodes: Option<NodeList>,
    /// Baud rate.
    #[arg(short = 'b', long = "baud", default_value_t = 9600)]
    baud: u32,
    /// Parity.
    #[arg(short = 'P', long = "parity", value_enum, default_value = "even")]
    parity: ParityArg,
    /// Data bits (7 or 8; RTU needs 8).
    #[arg(short = 'd', long = "data-bits", default_value_t = 8, value_parser = clap::value_parser!(u8).range(7..=8))]
    data_bits: u8,
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
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    window: u64,
    /// Allowance over the manual's response time before a reply counts as late, ms (the
    /// tap adapter's latency is in it).
    #[arg(long, value_name = "MS", default_value_t = 20)]
    allowance: u64,
    /// Report format.
    #[arg(long, value_enum, default_value = "text")]
    format: Format,
    /// Write the report here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// No live lines.
    #[arg(short, long)]
    quiet: bool,
    /// Every result in the text report, passes too.
    #[arg(short, long)]
    verbose: bool,
}

pub fn run(args: MonitorArgs) -> anyhow::Result<ExitCode> {
    let mode = match args.mode {
        ModeArg::Rtu => Mode::Rtu,
        ModeArg::Ascii => Mode::Ascii,
    };
    if mode == Mode::Rtu && args.data_bits != 8 {
        anyhow::bail!("RTU needs 8 data bits (-d 8)");
    }
    let nodes = args.nodes.as_ref().map(|n| n.0.clone()).unwrap_or_default();
    let model = load_model(
        &args.model,
        args.model_file.as_deref(),
        nodes.first().copied().unwrap_or(1),
    )?;
    let parity = match args.parity {
        ParityArg::None => Parity::None,
        ParityArg::Even => Parity::Even,
        ParityArg::Odd => Parity::Odd,
    };
    let line = LineSettings::new(args.baud, args.data_bits, parity, args.stop_bits);
    let mut mon = Monitor::new(
        model,
        MonitorConfig {
            mode,
            line,
            nodes: nodes.clone(),
            window: Duration::from_millis(args.window),
            response_allowance: Duration::from_millis(args.allowance),
            gap_allowance: Duration::from_millis(args.allowance),
        },
    )?;
    let started = humantime::format_rfc3339_seconds(SystemTime::now()).to_string();
    let mut err = std::io::stderr();
    let color = err.is_terminal();
    let mut on_line = |l: &monitor::Line| {
        if !args.quiet {
            let _ = if color && l.status == conformance::judge::VerdictStatus::Deviation {
                writeln!(err, "\x1b[31m{l}\x1b[0m")
            } else {
                writeln!(err, "{l}")
            };
        }
    };
    let (source, ended) = match (&args.port, &args.capture_in) {
        (_, Some(path)) => {
            let data = std::fs::read(path)
                .with_context(|| format!("cannot read the capture {}", path.display()))?;
            let r = monitor::replay::replay(&data, &mut mon, &mut on_line)
                .with_context(|| format!("cannot judge the capture {}", path.display()))?;
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
            (format!("capture {}", path.display()), ended)
        }
        (Some(port), None) => listen(&args, port, line, mode, &mut mon, &mut on_line)?,
        (None, None) => anyhow::bail!("say what to listen to: --port PATH or --capture-in FILE"),
    };
    report(&args, mode, line, started, &mon, &source, &ended)
}

/// Listens on `port` until Ctrl-C, SIGTERM, `--duration` or the end of the input; returns
/// the port's description and why listening ended.
fn listen(
    args: &MonitorArgs,
    port: &str,
    line: LineSettings,
    mode: Mode,
    mon: &mut Monitor,
    on_line: &mut dyn FnMut(&monitor::Line),
) -> anyhow::Result<(String, String)> {
    let port = SerialTransport::open(port, line, serial_kind(port))
        .with_context(|| format!("cannot listen on {port}"))?;
    let capture = args
        .capture
        .as_deref()
        .map(super::link::open_capture)
        .transpose()?;
    let mut tap = match &capture {
        Some(rec) => ReadOnlyPort::new(Box::new(
            Captured::new(port, rec.clone(), mode, line).as_tap(),
        )),
        None => ReadOnlyPort::new(Box::new(port)),
    };
    // The one handler of every long command: Ctrl-C, SIGTERM and SIGHUP end the listening
    // and write the report.
    let stop = super::interrupt::stop_flag()?;
    if !args.quiet {
        eprintln!(
            "listening on {} ({mode}, {line}); nothing is sent. Ctrl-C ends and reports.",
            tap.describe()
        );
    }
    let ended = monitor::run(&mut tap, mon, &stop, args.duration, on_line)?;
    let ended = match ended {
        Ended::Duration => "--duration passed".to_string(),
        Ended::Interrupted => "interrupted (Ctrl-C or SIGTERM)".to_string(),
        Ended::EndOfInput(why) => format!("end of input ({why})"),
    };
    let described = tap.describe();
    // The last frame heard is written when the port is let go.
    drop(tap);
    if let (Some(path), Some(rec)) = (&args.capture, &capture) {
        super::link::close_capture(path, rec);
    }
    Ok((described, ended))
}

/// The report of what `mon` heard on `source`.
fn report(
    args: &MonitorArgs,
    mode: Mode,
    line: LineSettings,
    started: String,
    mon: &Monitor,
    source: &str,
    ended: &str,
) -> anyhow::Result<ExitCode> {
    let nodes = args.nodes.as_ref().map(|n| n.0.clone()).unwrap_or_default();
    let summary = mon.summary(source, ended);
    let heard: Vec<u8> = mon.nodes().keys().copied().filter(|n| *n != 0).collect();
    let report = Report {
        kind: ReportKind::Monitor,
        codec: None,
        started,
        finished: Some(humantime::format_rfc3339_seconds(SystemTime::now()).to_string()),
        complete: true,
        stopped: None,
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
            line: line.to_string(),
            identification: None,
            simulated: None,
            nodes: mon
                .nodes()
                .keys()
                .map(|&address| NodeInfo {
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
    };
    finish(&report, args.format, args.verbose, args.output.as_deref())
}
