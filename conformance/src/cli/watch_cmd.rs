//! `conformance watch`: polls named registers of one or more drives with 03H reads only,
//! shows them as the manual names them, and judges every value as it changes. The
//! terminal side: the options, the loop, the redraw, the rows, the summary and the exit
//! code. The plan, the table and the judging are the library's `watch` room.

use std::fs::File;
use std::io::{BufWriter, IsTerminal, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::Ordering;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use conformance::codec::Mode;
use conformance::report::watch::{csv_header, csv_row, json_row, summary, table_text, LINK_FAILED};
use conformance::report::watch_html;
use conformance::runner::Master;
use conformance::session;
use conformance::watch::{plan, resolve, Watcher};

use super::common::parse_duration;
use super::interrupt::{stop_flag_saying, Stopping};
use super::link::{ModesArg, TargetArgs};
use super::output::write_atomic;

const AFTER_HELP: &str = "\
Examples:
  conformance watch --sim f510                         the monitor block and the status word
  conformance watch --model f510 --port /dev/ttyUSB0 -b 9600 -P even 'output freq' 2502H
  conformance watch --model f510 --port /dev/ttyUSB0 -a 1,2,5 monitor --interval 1s
  conformance watch --sim f510 --duration 10s --format csv > run.csv
  conformance watch --sim f510 --duration 1m -o trend.html
  conformance watch --model-file x100.json --tcp 10.0.0.8:4001 commands --format jsonl

What to watch: each argument is a register number (2520H, 0x2520; a bare number is
decimal), a register's name as the model prints it (case-insensitive; a unique prefix
will do; an ambiguous one is refused with the candidates), or a block (monitor, command,
a description's block). Default: the monitor block and the status word. The registers
are read with the fewest 03H reads the model allows (registers per read, one group per
read); nothing is ever written.

Output: on a terminal, a table redrawn in place after each poll: register, name, raw
value, value in its unit, the set bits by name; marks: * changed, ! out of the model's
range, R a reserved bit set; per node the round trip (last, median, p99) and the counts
of timeouts, CRC errors, exceptions, values out of range and reserved bits. Piped, or
with --format csv|jsonl: one row per node and poll, with a timestamp (columns: see the
guide, Watching a drive). -o FILE.html: a report with a trend chart per register, at the
end. The summary goes to stderr.

Exit codes: 0 no exception and no value out of range (also when stopped by Ctrl-C,
SIGTERM or SIGHUP, after the summary); 1 an exception or a value out of the model's
range was seen; 2 the link failed or could not be opened, or bad arguments.";

/// Output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum WatchFormat {
    /// The table, redrawn in place on a terminal.
    Text,
    /// One CSV row per node and poll (RFC 4180).
    Csv,
    /// One JSON object per line, per node and poll.
    Jsonl,
    /// A report with a trend chart per register, written at the end.
    Html,
}

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct WatchArgs {
    #[command(flatten)]
    target: TargetArgs,
    /// Registers, names or blocks to watch (default: the monitor block and the status
    /// word).
    #[arg(value_name = "REGISTER|NAME|BLOCK")]
    names: Vec<String>,
    /// Time from one poll's start to the next (with a unit: 200ms, 1s; a bare number is
    /// seconds).
    #[arg(long, value_name = "TIME", default_value = "200ms", value_parser = parse_duration)]
    interval: Duration,
    /// Stop after this long (default: until Ctrl-C or SIGTERM).
    #[arg(long, value_name = "TIME", value_parser = parse_duration)]
    duration: Option<Duration>,
    /// Stop after this many polls of every node (at least 1).
    #[arg(short = 'c', long, value_name = "N",
          value_parser = clap::value_parser!(u64).range(1..))]
    count: Option<u64>,
    /// Output format. Default: the one -o's extension names (.csv, .jsonl, .html), else
    /// text on a terminal and csv when piped.
    #[arg(long, value_enum)]
    format: Option<WatchFormat>,
    /// Write the rows (csv, jsonl) or the report (html) here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
}

/// The format asked for, else -o's extension's, else text on a terminal, csv piped.
fn format_for(args: &WatchArgs, terminal: bool) -> WatchFormat {
    let by_extension = || {
        let ext = args
            .output
            .as_deref()?
            .extension()?
            .to_str()?
            .to_ascii_lowercase();
        Some(match ext.as_str() {
            "html" | "htm" => WatchFormat::Html,
            "csv" => WatchFormat::Csv,
            "jsonl" | "json" | "ndjson" => WatchFormat::Jsonl,
            "txt" => WatchFormat::Text,
            _ => return None,
        })
    };
    args.format.or_else(by_extension).unwrap_or(if terminal {
        WatchFormat::Text
    } else {
        WatchFormat::Csv
    })
}

/// Where the rows go.
enum Sink {
    Stdout,
    File(BufWriter<File>),
    /// The HTML report is written at the end; no rows.
    None,
}

impl Sink {
    fn write(&mut self, text: &str) -> std::io::Result<()> {
        match self {
            Sink::Stdout => {
                let mut o = std::io::stdout().lock();
                o.write_all(text.as_bytes())?;
                o.flush()
            }
            Sink::File(f) => {
                f.write_all(text.as_bytes())?;
                f.flush()
            }
            Sink::None => Ok(()),
        }
    }
}

pub fn run(mut args: WatchArgs) -> anyhow::Result<ExitCode> {
    args.target.several_nodes = true;
    if args.interval.is_zero() {
        bail!(
            "--interval must be more than 0 (a drive needs time to answer; 200ms is the default)"
        );
    }
    let resolved = args.target.resolve(false, None)?;
    let (model, is_sim, modes) = (
        resolved.model.clone(),
        resolved.is_sim,
        resolved.modes.clone(),
    );
    if args.target.mode == Some(ModesArg::Both) {
        bail!("--mode both: a watch polls in one mode; give --mode rtu or --mode ascii");
    }
    // The simulator's default is both modes (for `check`); a watch polls in RTU unless told.
    let mode = if is_sim && args.target.mode.is_none() {
        Mode::Rtu
    } else {
        modes[0]
    };
    let nodes = args.target.nodes.0.clone();
    let registers = resolve(&model, &args.names)?;
    let plan = plan(&model, nodes[0], mode, &registers)?;
    let terminal = std::io::stdout().is_terminal();
    let format = format_for(&args, terminal);
    let mut sink = match (format, &args.output) {
        (WatchFormat::Html, _) => Sink::None,
        (_, Some(p)) => Sink::File(BufWriter::new(
            File::create(p).with_context(|| format!("cannot create {}", p.display()))?,
        )),
        (_, None) => Sink::Stdout,
    };
    if format == WatchFormat::Html && args.output.is_none() && terminal {
        bail!("--format html writes a page: give -o FILE.html (or pipe stdout)");
    }
    // The live table goes to a terminal whenever the rows or the report go elsewhere.
    let live = terminal && (format == WatchFormat::Text || args.output.is_some());
    let config = args
        .target
        .plain_session(resolved, mode, nodes.clone(), true)?;
    let stop = stop_flag_saying(Stopping::Watching)?;
    let (_sim, transport) = match session::open(&config, mode) {
        Ok(t) => t,
        Err(e) => {
            eprintln!("error: the link could not be opened: {e}");
            return Ok(ExitCode::from(2));
        }
    };
    eprintln!(
        "watch: {} in {mode}, {}, {} register{} in {} read{} per poll, every {} ms; only 03H reads are sent",
        transport.describe(),
        super::output::nodes_phrase(&nodes, ","),
        plan.registers.len(),
        if plan.registers.len() == 1 { "" } else { "s" },
        plan.reads.len(),
        if plan.reads.len() == 1 { "" } else { "s" },
        args.interval.as_millis()
    );
    let mut master =
        Master::new(transport, mode, config.options.timing).with_echo(args.target.echo);
    let mut watcher = Watcher::new(model.clone(), mode, plan, &nodes)?;
    if format == WatchFormat::Csv {
        sink.write(&csv_header(&watcher))?;
    }
    let deadline = args.duration.map(|d| Instant::now() + d);
    let mut next = Instant::now();
    let mut rounds = 0u64;
    let mut link_failed = None;
    let ended = 'watch: loop {
        if stop.load(Ordering::Relaxed) {
            break "interrupted";
        }
        if deadline.is_some_and(|d| Instant::now() >= d) {
            break "--duration";
        }
        if args.count.is_some_and(|c| rounds >= c) {
            break "--count";
        }
        for i in 0..nodes.len() {
            let poll = match watcher.poll(i, &mut master) {
                Ok(p) => p,
                Err(e) => {
                    link_failed = Some(e);
                    break 'watch LINK_FAILED;
                }
            };
            match format {
                WatchFormat::Csv => sink.write(&csv_row(&watcher, &poll))?,
                WatchFormat::Jsonl => sink.write(&format!("{}\n", json_row(&watcher, &poll)))?,
                WatchFormat::Text | WatchFormat::Html => {}
            }
        }
        rounds += 1;
        if live {
            // Cursor home and clear: the table redraws in place.
            let mut o = std::io::stdout().lock();
            write!(o, "\x1b[H\x1b[2J{}", table_text(&watcher))?;
            o.flush()?;
        } else if format == WatchFormat::Text {
            sink.write(&format!("{}\n", table_text(&watcher)))?;
        }
        next += args.interval;
        let now = Instant::now();
        if next < now {
            // A poll that took longer than the interval: the next starts at once.
            next = now;
        }
        let until = deadline.map_or(next, |d| d.min(next));
        while Instant::now() < until && !stop.load(Ordering::Relaxed) {
            std::thread::sleep((until - Instant::now()).min(Duration::from_millis(20)));
        }
    };
    args.target.close_capture(config.capture.as_ref());
    if let Sink::File(f) = &mut sink {
        f.flush()?;
    }
    if let (WatchFormat::Html, Some(p)) = (format, &args.output) {
        write_atomic(p, &watch_html(&watcher, ended))
            .with_context(|| format!("cannot write {}", p.display()))?;
        eprintln!("report: {}", p.display());
    } else if format == WatchFormat::Html {
        sink = Sink::Stdout;
        sink.write(&watch_html(&watcher, ended))?;
    }
    eprint!("{}", summary(&watcher, ended));
    if let Some(e) = link_failed {
        eprintln!("error: {e}");
        return Ok(ExitCode::from(2));
    }
    Ok(ExitCode::from(if watcher.found() { 1 } else { 0 }))
}
