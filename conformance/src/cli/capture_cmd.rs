//! `conformance capture synth`: the capture of a day of a bus, made in minutes, with its
//! truth beside it (see the `daybus` module).

use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, Instant};

use anyhow::Context;
use clap::{Args, Subcommand};
use conformance::codec::timing::{LineSettings, Parity};
use conformance::daybus::{self, DayConfig};

use super::common::{load_model, parse_duration, ParityArg};

/// `conformance capture ...`.
#[derive(Debug, Args)]
pub struct CaptureArgs {
    #[command(subcommand)]
    command: CaptureCommand,
}

#[derive(Debug, Subcommand)]
enum CaptureCommand {
    /// Write the capture (pcapng, RTU, as a tap hears it) of a master polling drives for
    /// hours, with rare faults planted at known times, and its truth (per-node counts and
    /// the faults, JSON) beside it: what `monitor --capture-in` must find.
    #[command(after_help = SYNTH_HELP)]
    Synth(SynthArgs),
}

const SYNTH_HELP: &str = "The traffic: a poll cycle over the drives (status block 2520H x5 every cycle, monitor block 2526H x8 every fourth, now and then 06H and 10H writes of the frequency command and run/stop, a parameter block, a read answered with an exception, a broadcast), each drive answering after its own delay with jitter, longer pauses at night. The faults, a few an hour and at least one of each: noise bursts, collisions that garble a reply, a drive silent for a minute, a master restarting in the middle of a request.\n\nExample:\n  conformance capture synth --duration 24h --baud 115200 --drives 8 --seed 1 -o day.pcapng\n  conformance monitor --capture-in day.pcapng --model f510 -b 115200 --quiet --format json -o day.json\n  (then day.json's monitor.nodes equal day.pcapng.truth.json's nodes)\n\nExit codes: 0 written; 2 could not run (arguments, the file).";

/// `capture synth`.
#[derive(Debug, Args)]
pub struct SynthArgs {
    /// How long the bus runs (a bare number is seconds: 90; or 30s, 10m, 24h).
    #[arg(long, value_name = "T", value_parser = parse_duration, default_value = "1h")]
    duration: Duration,
    /// Baud rate (300 to 1000000: a bus's timing is derived from it).
    #[arg(short = 'b', long = "baud", default_value_t = 115_200,
          value_parser = clap::value_parser!(u32).range(300..=1_000_000))]
    baud: u32,
    /// Parity.
    #[arg(short = 'P', long = "parity", value_enum, default_value = "even")]
    parity: ParityArg,
    /// How many drives, at nodes 1..N.
    #[arg(long, default_value_t = 8, value_parser = clap::value_parser!(u8).range(1..=32))]
    drives: u8,
    /// The seed of every choice: the same seed writes the same file.
    #[arg(long, default_value_t = 1)]
    seed: u64,
    /// The drives' model.
    #[arg(long, default_value = "f510")]
    model: String,
    /// The capture to write.
    #[arg(short, long, value_name = "FILE.pcapng")]
    output: PathBuf,
    /// Where the truth goes (default: the capture's name with .truth.json added).
    #[arg(long, value_name = "FILE.json")]
    truth: Option<PathBuf>,
    /// Say nothing on stderr.
    #[arg(short, long)]
    quiet: bool,
}

/// A sink whose `flush` waits for the end: the pcapng writer flushes every block (so
/// that a recording cut short ends on a block boundary), which a file of millions of
/// packets that nobody reads while it is written does not need.
struct FlushAtEnd<W: Write>(BufWriter<W>);

impl<W: Write> Write for FlushAtEnd<W> {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.write(buf)
    }
    fn write_all(&mut self, buf: &[u8]) -> std::io::Result<()> {
        self.0.write_all(buf)
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

/// Runs `capture`.
pub fn run(args: CaptureArgs) -> anyhow::Result<ExitCode> {
    match args.command {
        CaptureCommand::Synth(a) => synth(a),
    }
}

fn synth(a: SynthArgs) -> anyhow::Result<ExitCode> {
    let model = load_model(&a.model, None, 1)?;
    let parity = match a.parity {
        ParityArg::None => Parity::None,
        ParityArg::Even => Parity::Even,
        ParityArg::Odd => Parity::Odd,
    };
    let cfg = DayConfig {
        span: a.duration,
        line: LineSettings::new(a.baud, 8, parity, 1),
        drives: a.drives,
        seed: a.seed,
        // 2026-01-01 00:00:00 UTC: a fixed day, so that the same seed writes the same file.
        start_unix_us: 1_767_225_600_000_000,
    };
    let truth_path = a.truth.clone().unwrap_or_else(|| {
        let mut p = a.output.clone().into_os_string();
        p.push(".truth.json");
        PathBuf::from(p)
    });
    // Written beside its place and renamed when whole: a file of the name is never half
    // a capture.
    let partial = {
        let mut p = a.output.clone().into_os_string();
        p.push(".partial");
        PathBuf::from(p)
    };
    let started = Instant::now();
    let file = File::create(&partial).with_context(|| format!("creating {}", partial.display()))?;
    let (truth, sink) = daybus::generate(&cfg, model, FlushAtEnd(BufWriter::new(file)))
        .with_context(|| format!("writing {}", partial.display()))?;
    sink.0
        .into_inner()
        .map_err(|e| e.into_error())
        .and_then(|f| f.sync_all())
        .with_context(|| format!("writing {}", partial.display()))?;
    std::fs::rename(&partial, &a.output)
        .with_context(|| format!("renaming {} to {}", partial.display(), a.output.display()))?;
    let json = serde_json::to_string_pretty(&truth)?;
    std::fs::write(&truth_path, json + "\n")
        .with_context(|| format!("writing {}", truth_path.display()))?;
    if !a.quiet {
        eprintln!(
            "{}: {} packets, {} bytes carried, {:.0} s of bus ({} faults planted) in {:.1} s; truth in {}",
            a.output.display(),
            truth.packets,
            truth.bytes,
            truth.heard_s,
            truth.faults.len(),
            started.elapsed().as_secs_f64(),
            truth_path.display()
        );
    }
    Ok(ExitCode::SUCCESS)
}
