//! `conformance model learn`: a first device description drawn up from a live device
//! (reads only, unless --allow-write), written as a draft in the format of
//! `vectors/models` with every fact marked observed.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::{Duration, SystemTime};

use anyhow::{bail, Context};
use clap::Args;
use conformance::learn::ask::{frame_text, Evidence, LiveDevice};
use conformance::learn::map::MapConfig;
use conformance::learn::{draft, learn, LearnConfig, LearnError, Learned};
use conformance::runner::{EchoMode, Master, MasterTiming};
use conformance::scan::{probe, scan, ScanConfig};
use conformance::session::serial_kind;
use conformance::transport::serial::SerialTransport;
use conformance::transport::tcp::TcpTransport;
use conformance::transport::Transport;

use super::common::{parse_number, Number, RtsArgs};
use super::scan_cmd::{open_link, settings_to_try, LineLists};

const AFTER_HELP: &str = "\
What it does, in order:
  1. finds the line settings, mode and node as `conformance scan` does (-b -P -d -s -m
     and -a narrow the search; given all of them, one read confirms them);
  2. the register map: which holding registers of --range (default 0000H..FFFFH) the
     device serves to 03H, with a bounded search of multi-register reads: one read
     every --stride registers (default 16) where nothing is known, then each block
     grown by reads of the read limit and its edges found by binary search; a block
     shorter than the stride between two samples is not found (--stride 1 reads every
     register);
  3. the read limit, and the exceptions for a register outside the map, a count over
     the limit (and count 0), an unserved function (41H, as `check` sends it), and a
     read across two blocks the device will not read together;
  4. which of 04H and 08H (loop-back, test code 0000H) it serves; 06H and 10H only with
     --allow-write, which writes the first register of each block with the value just
     read, by 06H and by 10H, and reads it back;
  5. whether it keeps silent to a broadcast, another node (--other-address) and a bad
     checksum;
  6. its response time (median and p99), and an identification register: one that
     read the same twice and tells it from the five built-in models.
Every fact in the draft is marked `basis: observed` with the request that showed it (and
the reply). Progress and an estimate of the time left go to stderr on a terminal; the
number of requests and the time are printed at the end.

Ctrl-C (SIGTERM, SIGHUP) stops after the current request and writes the draft of what
was found so far (exit 2).

Examples:
  conformance model learn --port /dev/ttyUSB0 -a 1 -o draft.json
  conformance model learn --port /dev/ttyUSB0 -b 19200 -P none -m rtu -a 3 --allow-write -o draft.json
  conformance model learn --tcp 10.0.0.7:4001 -m rtu -a 1 --range 0000-2FFF -o draft.json
  conformance check --model-file draft.json --port /dev/ttyUSB0 --read-only   hold it to it

Exit codes: 0 the draft was written; 2 nothing to learn from (no device found, bad
arguments), or the learn stopped early (interrupted, the link failed, the device
stopped answering): the draft holds what was found.";

/// `conformance model learn`.
#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct LearnArgs {
    /// Serial port of the device.
    #[arg(
        long,
        value_name = "PATH",
        group = "target",
        required_unless_present = "tcp"
    )]
    port: Option<String>,
    /// A serial gateway carrying RTU or ASCII frames over TCP.
    #[arg(long, value_name = "HOST:PORT", group = "target")]
    tcp: Option<String>,
    #[command(flatten)]
    lines: LineLists,
    /// Node address of the device (default: the first found among 1..247).
    #[arg(short = 'a', long = "address", value_name = "N", value_parser = Number::<u8>::quiet())]
    address: Option<u8>,
    #[command(flatten)]
    rts: RtsArgs,
    /// Registers searched for the map, FIRST-LAST in hex (0000-2FFF).
    #[arg(long, value_name = "FIRST-LAST", default_value = "0000-FFFF", value_parser = parse_range)]
    range: (u16, u16),
    /// Registers between two samples of the map search (1 reads every register).
    #[arg(long, value_name = "N", default_value_t = 16, value_parser = clap::value_parser!(u16).range(1..=125))]
    stride: u16,
    /// The most requests in all (the map search stops at its share, the probes after it
    /// keep 200).
    #[arg(long, value_name = "N", default_value_t = 20_000)]
    max_requests: u64,
    /// Write the first register of each block with the value just read (06H, then 10H
    /// with one register) and read it back, to learn which functions and blocks take
    /// writes. Nothing else is ever written.
    #[arg(long)]
    allow_write: bool,
    /// A node address no device on the line has, for the other-address silence
    /// (default: F7H, or F6H for a device at F7H).
    #[arg(long, value_name = "N", value_parser = Number::<u8>::quiet())]
    other_address: Option<u8>,
    /// Milliseconds to wait for a reply.
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    timeout: u64,
    /// The draft's model id.
    #[arg(long, value_name = "ID", default_value = "learned")]
    id: String,
    /// Write the draft here.
    #[arg(short, long, value_name = "FILE")]
    output: PathBuf,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
}

/// "0000-2FFF" (hex, as registers are written) into its first and last register.
fn parse_range(text: &str) -> Result<(u16, u16), String> {
    let (a, b) = text
        .split_once('-')
        .ok_or_else(|| format!("{text:?}: write FIRST-LAST in hex (0000-2FFF)"))?;
    let hex = |s: &str| {
        let s = s.trim();
        let s = s.strip_suffix(['H', 'h']).unwrap_or(s);
        parse_number(&format!("0x{}", s.trim_start_matches("0x")), 0xFFFF)
            .map_err(|e| e.to_string())
    };
    let (a, b) = (hex(a)?, hex(b)?);
    if a > b {
        return Err(format!("{text:?}: the range runs backwards"));
    }
    Ok((a, b))
}

fn bar(quiet: bool) -> Option<indicatif::ProgressBar> {
    super::output::progress_bar(
        quiet,
        1,
        "{bar:30} {pos}/{len} requests, eta {eta} {wide_msg}",
    )
}

pub fn run(args: LearnArgs) -> anyhow::Result<ExitCode> {
    if !conformance::model::valid_model_id(&args.id) {
        bail!(
            "--id {:?}: a model id is {}",
            args.id,
            conformance::model::MODEL_ID_RULE
        );
    }
    let search = args.lines.search()?;
    args.rts.needs_port(args.port.as_deref())?;
    if args.address == Some(0) {
        bail!("-a 0 is the broadcast address, which is never answered");
    }
    let mut settings = settings_to_try(&search)?;
    let addresses: Vec<u8> = match args.address {
        Some(a) => vec![a],
        None => (1..=247).collect(),
    };
    let stop = super::interrupt::stop_flag()?;

    // 1. The line, the mode and the node, as scan finds them.
    let mut link = open_link(
        args.port.as_deref(),
        args.tcp.as_deref(),
        None,
        &mut settings,
        &args.rts,
        None,
        &addresses,
        !args.lines.modes.is_empty(),
    )?;
    // One setting and one node, all given: one try, which waits as long as any
    // request of the learn (scan's short windows are for sweeping many).
    let reply_window =
        (settings.len() == 1 && addresses.len() == 1).then(|| Duration::from_millis(args.timeout));
    let config = ScanConfig {
        settings,
        addresses: addresses.clone(),
        first: vec![addresses[0]],
        response: Duration::from_millis(10),
        reply_window,
        // As scan's default: one lost reply is not a missing device.
        retries: 1,
    };
    let progress = bar(args.quiet);
    let found = scan(link.as_mut(), &config, &stop, &mut |p| {
        if let Some(b) = &progress {
            b.set_length(p.total_us.max(1));
            b.set_position(p.done_us);
            b.set_message(format!("scan: {} node {:02X}H", p.setting, p.address));
        }
    });
    if let Some(b) = &progress {
        b.finish_and_clear();
    }
    let described = link.describe();
    drop(link);
    let found = found?;
    if found.stopped.is_some() {
        eprintln!(
            "learn interrupted while finding the device: nothing was learned, no draft written"
        );
        return Ok(ExitCode::from(2));
    }
    let Some(device) = found
        .found
        .iter()
        .find(|f| f.address == f.asked)
        .or(found.found.first())
    else {
        eprintln!(
            "no device answered on {described} ({} tries in {:.1} s): nothing to learn from; try `conformance scan` with a wider search",
            found.tries,
            found.elapsed.as_secs_f64()
        );
        return Ok(ExitCode::from(2));
    };
    let others: Vec<String> = found
        .found
        .iter()
        .filter(|f| f.address != device.address)
        .map(|f| format!("{:02X}H", f.address))
        .collect();
    let (line, mode, node) = (device.setting.line, device.setting.mode, device.address);
    eprintln!(
        "found node {node:02X}H at {line} {mode} on {described} ({} tries, {:.1} s){}",
        found.tries,
        found.elapsed.as_secs_f64(),
        if others.is_empty() {
            String::new()
        } else {
            format!("; also answering: {}", others.join(" "))
        }
    );

    // 2. The rest through the runner's master, at that setting.
    let transport: Box<dyn Transport> = match (&args.port, &args.tcp) {
        (Some(path), _) => Box::new(
            SerialTransport::open(path, line, serial_kind(path))?.with_rts(args.rts.control())?,
        ),
        (_, Some(addr)) => Box::new(TcpTransport::connect(addr, Duration::from_secs(2))?),
        _ => bail!("say where the line is: --port PATH or --tcp HOST:PORT"),
    };
    let link_name = transport.describe();
    let timeout = Duration::from_millis(args.timeout);
    let timing = MasterTiming {
        timeout,
        silence: timeout,
        derive_silence: true,
        quiet: Duration::from_millis(30),
        gap: Duration::from_millis(5).max(Duration::from_micros(line.t3_5_us())),
        // A device that ignores the frame after one to another node (libmodbus) gets it
        // again.
        retries: 1,
    };
    let master = Master::new(transport, mode, timing).with_echo(if device.echo {
        EchoMode::On
    } else {
        EchoMode::Auto
    });
    let mut live = LiveDevice::new(master);
    let map = MapConfig {
        first: args.range.0,
        last: args.range.1,
        stride: args.stride,
    };
    let mut learned = Learned::new(link_name, line.to_string(), mode, node, map);
    learned.scan = Some(Evidence {
        request: frame_text(mode, &probe::request(mode, device.asked)),
        reply: Some(frame_text(mode, &device.frame)),
    });
    if !others.is_empty() {
        learned.notes.push(format!(
            "The scan also heard node(s) {} at this setting (the device answers other addresses, or several devices share the line).",
            others.join(" ")
        ));
    }
    let cfg = LearnConfig {
        node,
        map,
        max_requests: args.max_requests,
        allow_write: args.allow_write,
        other_address: args
            .other_address
            .unwrap_or(if node == 0xF7 { 0xF6 } else { 0xF7 }),
    };
    if cfg.other_address == node || cfg.other_address == 0 {
        bail!("--other-address must differ from the device's address and from 00 (broadcast)");
    }
    let progress = bar(args.quiet);
    let result = learn(
        &mut live,
        &cfg,
        &stop,
        &mut |p| {
            if let Some(b) = &progress {
                b.set_length(p.requests + p.left.max(1));
                b.set_position(p.requests);
                b.set_message(p.doing.to_string());
            }
        },
        &mut learned,
    );
    if let Some(b) = &progress {
        b.finish_and_clear();
    }
    drop(live);

    // 3. The draft, whatever stopped the learn.
    let date = humantime::format_rfc3339_seconds(SystemTime::now()).to_string();
    let d = draft::draft(&learned, &args.id, &date[..10.min(date.len())]);
    std::fs::write(&args.output, serde_json::to_string_pretty(&d)? + "\n")
        .with_context(|| format!("cannot write the draft {}", args.output.display()))?;
    let m = &learned.map;
    eprintln!(
        "map: {} block(s) in {:04X}H..{:04X}H{}: {} requests (largest read {} registers)",
        m.blocks.len(),
        map.first,
        if m.complete {
            map.last
        } else {
            m.searched_to.unwrap_or(map.first)
        },
        if m.complete {
            ""
        } else {
            " (search cut short)"
        },
        m.requests,
        m.largest.as_ref().map_or(0, |(n, _)| *n)
    );
    for b in &m.blocks {
        eprintln!(
            "  {:04X}H..{:04X}H ({} registers)",
            b.first,
            b.last,
            u32::from(b.last) - u32::from(b.first) + 1
        );
    }
    if let Some((median, p99, _)) = &learned.response {
        eprintln!(
            "response time: median {:.1} ms, p99 {:.1} ms over {} replies",
            median.as_secs_f64() * 1000.0,
            p99.as_secs_f64() * 1000.0,
            learned.timed
        );
    }
    eprintln!(
        "learned in {} requests, {:.1} s; draft in {}",
        learned.requests,
        learned.elapsed.as_secs_f64(),
        args.output.display()
    );
    match result {
        Ok(()) => Ok(ExitCode::SUCCESS),
        Err(LearnError::Budget(n)) => {
            eprintln!("the request cap ({n}) was reached: the draft holds what was found");
            Ok(ExitCode::SUCCESS)
        }
        Err(e) => {
            eprintln!("learn stopped early: {e}; the draft holds what was found until then");
            Ok(ExitCode::from(2))
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ranges_are_hex() {
        assert_eq!(parse_range("0000-2FFF"), Ok((0, 0x2FFF)));
        assert_eq!(parse_range("2500H-252FH"), Ok((0x2500, 0x252F)));
        assert_eq!(parse_range("0x10-0x20"), Ok((0x10, 0x20)));
        assert!(parse_range("2FFF-0000").is_err());
        assert!(parse_range("0000").is_err());
        assert!(parse_range("0000-1FFFF").is_err());
    }
}
