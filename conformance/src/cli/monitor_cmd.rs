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
use conformance::transport::serial::SerialTransport;

use super::check_cmd::{finish, format_for, Format, FORMAT_DEFAULT};
use super::common::{load_model, parse_nodes, NodeList, ParityArg};

const AFTER_HELP: &str = "\
Examples:
  conformance monitor --port /dev/ttyUSB1 --model f510 -a 1,2 -b 9600 -P even
  conformance monitor --port /dev/ttyUSB1 --model a510 --mode ascii -d 7 --duration 1h --format html -o bus.html
  conformance monitor --port /dev/pts/7 --model f510 --quiet --format json -o bus.json   (a bus's third end)
  conformance monitor --port /dev/ttyUSB1 --model e510 --mode auto   RTU or ASCII, told from the traffic

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
    /// Told from the traffic: two valid frames of one mode (nothing is sent).
    Auto,
}

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct MonitorArgs {
    /// The serial port (or pseudo-terminal) to listen on.
    #[arg(long, value_name = "PATH")]
    port: String,
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
    #[arg(long, value_enum, help = FORMAT_DEFAULT)]
    format: Option<Format>,
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
    let asked = match args.mode {
        ModeArg::Rtu => Some(Mode::Rtu),
        ModeArg::Ascii => Some(Mode::Ascii),
        ModeArg::Auto => None,
    };
    if asked == Some(Mode::Rtu) && args.data_bits != 8 {
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
    let port = SerialTransport::open(&args.port, line, serial_kind(&args.port))
        .with_context(|| format!("cannot listen on {}", args.port))?;
    let mut tap = ReadOnlyPort::new(Box::new(port));
    // The one handler of every long command: Ctrl-C, SIGTERM and SIGHUP end the listening
    // and write the report.
    let stop = super::interrupt::stop_flag()?;
    let started = humantime::format_rfc3339_seconds(SystemTime::now()).to_string();
    let origin = Instant::now();
    let (mode, before) = match asked {
        Some(m) => (m, Vec::new()),
        None => {
            if !args.quiet {
                eprintln!(
                    "listening on {} ({line}) to tell RTU from ASCII; nothing is sent.",
                    tap.describe()
                );
            }
            match monitor::listen_for_mode(&mut tap, &stop, args.duration, origin, line)? {
                Ok((m, heard)) => {
                    if !args.quiet {
                        let n: usize = heard.iter().map(|(_, b)| b.len()).sum();
                        eprintln!("--mode auto: {m} (two valid {m} frames in the first {n} bytes)");
                    }
                    (m, heard)
                }
                Err(ended) => anyhow::bail!(
                    "--mode auto: listening ended ({}) before two valid frames told RTU from ASCII; nothing was judged",
                    describe_end(&ended)
                ),
            }
        }
    };
    if mode == Mode::Rtu && args.data_bits != 8 {
        anyhow::bail!("RTU needs 8 data bits (-d 8)");
    }
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
    if !args.quiet {
        eprintln!(
            "listening on {} ({mode}, {line}); nothing is sent. Ctrl-C ends and reports.",
            tap.describe()
        );
    }
    let mut log = match &args.log {
        Some(p) => Some((
            std::io::LineWriter::new(
                std::fs::File::create(p)
                    .with_context(|| format!("cannot write the log {}", p.display()))?,
            ),
            p,
        )),
        None => None,
    };
    let mut log_failed: Option<anyhow::Error> = None;
    let mut err = std::io::stderr();
    let color = err.is_terminal();
    let usb = usb_name(&args.port);
    let ended = monitor::run_from(
        &mut tap,
        &mut mon,
        &stop,
        args.duration,
        origin,
        before,
        |said| match said {
            monitor::Said::Line(l) => {
                if let (Some((w, p)), None) = (log.as_mut(), log_failed.as_ref()) {
                    if let Err(e) = writeln!(w, "{}", l.to_json()) {
                        log_failed = Some(
                            anyhow::Error::new(e)
                                .context(format!("cannot write the log {}", p.display())),
                        );
                    }
                }
                if !args.quiet {
                    let _ = if color && l.status == conformance::judge::VerdictStatus::Deviation {
                        writeln!(err, "\x1b[31m{l}\x1b[0m")
                    } else {
                        writeln!(err, "{l}")
                    };
                }
            }
            // On a terminal only: a pipe or a file gets the lines and the report.
            monitor::Said::Summary(lines) => {
                if color && !args.quiet {
                    let _ = writeln!(err, "\x1b[2m-- so far:");
                    for l in lines {
                        let _ = writeln!(err, "   {l}");
                    }
                    let _ = write!(err, "\x1b[0m");
                }
            }
            // Said even with --quiet: it changes what the report can be trusted for.
            monitor::Said::Notice(n) => {
                let n = match &usb {
                    Some(name) => n.replace("ttyUSBn", name),
                    None => n.to_string(),
                };
                let _ = writeln!(err, "notice: {n}");
            }
        },
    )?;
    let ended = describe_end(&ended);
    let summary = mon.summary(&tap.describe(), &ended);
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
                format!("{} (listened, never written)", tap.describe()),
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
    let code = finish(
        &report,
        format_for(args.format, args.output.as_deref()),
        args.verbose,
        args.output.as_deref(),
    )?;
    // The report is written first: a log that failed loses no verdict.
    if let Some(e) = log_failed {
        eprintln!("error: {e:#}");
        return Ok(ExitCode::from(2));
    }
    Ok(code)
}
