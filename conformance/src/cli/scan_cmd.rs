//! `conformance scan`: find the devices on a line, their line settings, mode and node
//! addresses, with reads only.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use conformance::codec::timing::Parity;
use conformance::codec::Mode;
use conformance::scan::link::{FixedLink, ScanLink, SerialLink};
use conformance::scan::settings::{Search, Setting};
use conformance::scan::{report, scan, ScanConfig};
use conformance::session::serial_kind;
use conformance::transport::mbap::{MbapGateway, UnitMap};
use conformance::transport::serial::SerialTransport;
use conformance::transport::tcp::TcpTransport;
use conformance::transport::LinkKind;

use super::common::{parse_number, ModeArg, ParityArg, RtsArgs};
use super::link::Framing;
use super::output::progress_bar;

const AFTER_HELP: &str = "\
What it does: sends reads only (03H, one register: 252FH, the identification register
of the F510, A510, L510 and E510 manuals) and listens after each for a short reply
window: the response time (10 ms, the manuals'; t3.5 where longer), two character
times, and the link's slack (20 ms on a serial port for USB adapters' latency timers,
5 ms on a pseudo-terminal). One try costs at most: the request at the character time
+ t3.5 + the reply window (9600 8E1 RTU on a serial port: 9.2 + 4.0 + 32.3 ms).

Strategy, most likely first:
  1. every setting with node 01H (the manuals' default address): 48 tries by default;
  2. the rest of the address range, a tier of baud rates at a time (9600 and 19200;
     then 38400, 57600, 115200 and 4800; then 2400 and 1200): for each address,
     every setting of the tier, so that a device at a low address is found early;
  3. garbage after a request (bytes that deframe to no valid frame: a device talks at
     another speed or parity) drops that setting, and the address that drew it is
     tried next at every setting left;
  4. the first valid frame fixes the line's setting (one bus, one setting): the rest
     of the range is swept there only;
  5. there, each address that drew no valid frame is asked again after the sweep
     (--retries, default 1: a lost or damaged reply is not a missing device), bytes
     that made no frame are reported as noise, and the scan ends.
Settings searched by default: 9600, 19200, 38400, 57600, 115200, 4800, 2400, 1200
baud; parity even, none, odd; 8 data bits, 1 stop bit; RTU and ASCII (48 settings). A
UART checks only its first stop bit, so a device at 2 stop bits is found at 1 (give
-s 2 to scan with 2). Any of -b -P -d -s -m narrows the search to the values given
(repeat an option or separate values with commas: -b 9600,19200).

Through a gateway (--tcp: RTU or ASCII frames over TCP; with --framing mbap, a Modbus
TCP gateway, where the addresses swept are unit ids and the mode is RTU; each window
waits 250 ms more for the gateway's own 0BH: set --reply-window to its timeout) the serial line
is set in the gateway: line settings cannot be searched from here, only the node
addresses and the mode; -b -P -s set the windows.

Without hardware: `conformance simulate --pty --emulate-line -b 19200 -P odd -m ascii
-a 17` is a drive whose pseudo-terminal behaves like its line (a master at other
settings gets garbage).

Examples:
  conformance scan --port /dev/ttyUSB0                  the whole default search
  conformance scan --port /dev/ttyUSB0 -b 9600 -m rtu   one speed and mode: parity and addresses
  conformance scan --port /dev/ttyUSB0 -b 19200 -P even -m rtu --addresses 1-32 --format json
  conformance scan --tcp 10.0.0.7:4001 -m rtu --addresses 1-10
  conformance scan --tcp 10.0.0.8:502 --framing mbap --addresses 1-32

Exit codes: 0 a device was found; 1 nothing was found; 2 the scan could not run (bad
arguments, the port could not be opened or went away, or it was interrupted).";

/// What a Modbus TCP gateway may add to a reply window: its own wait for a unit that
/// does not answer before it says 0BH (`--reply-window` sets the whole window instead).
const MBAP_SLACK: Duration = Duration::from_millis(250);

/// Output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ScanFormat {
    /// A table for people.
    Text,
    /// JSON for machines.
    Json,
}

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct ScanArgs {
    /// Serial port of the line.
    #[arg(long, value_name = "PATH", group = "target")]
    port: Option<String>,
    /// A serial gateway carrying RTU or ASCII frames over TCP (line settings are set in
    /// the gateway: only addresses and modes are searched).
    #[arg(long, value_name = "HOST:PORT", group = "target")]
    tcp: Option<String>,
    /// How frames cross --tcp: rtu (the line's bytes, a transparent serial server) or
    /// mbap (Modbus TCP: the addresses swept are the gateway's unit ids; RTU only).
    #[arg(long, value_enum, requires = "tcp")]
    framing: Option<Framing>,
    #[command(flatten)]
    lines: LineLists,
    /// Node addresses to try: ranges and single addresses, comma-separated (1-247,
    /// 1-32, 17, 1,2,5); a bare number is decimal, hex with H suffix or 0x prefix.
    #[arg(long, value_name = "LIST", default_value = "1-247")]
    addresses: String,
    /// Milliseconds to wait for the first character of a reply after a request has
    /// left (default: derived, see below).
    #[arg(long, value_name = "MS")]
    reply_window: Option<u64>,
    /// The devices' response time in milliseconds (default 10, the manuals').
    #[arg(long, value_name = "MS", default_value_t = 10)]
    response_time: u64,
    /// At the line's setting, ask an address that drew no valid frame this many more
    /// times, after the sweep (a lost or damaged reply is not a missing device; each
    /// retry of a silent address costs one reply window).
    #[arg(long, value_name = "N", default_value_t = 1)]
    retries: u32,
    #[command(flatten)]
    rts: RtsArgs,
    /// Output format.
    #[arg(long, value_enum, default_value = "text")]
    format: ScanFormat,
    /// Write the result here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// No progress bar.
    #[arg(short, long)]
    quiet: bool,
    /// Record every try (requests, replies, garbage) in this pcapng file, one interface a
    /// setting (its mode and line settings in its description); through `--framing mbap`
    /// the TCP stream, under made-up headers (see the guide's "Captures" page).
    #[arg(long, value_name = "FILE.pcapng")]
    capture: Option<PathBuf>,
}

/// Parses "1-247", "17", "1,2,5-9" into addresses, in order, without repeats.
pub fn parse_addresses(text: &str) -> anyhow::Result<Vec<u8>> {
    let mut out: Vec<u8> = Vec::new();
    for part in text.split(',').map(str::trim).filter(|p| !p.is_empty()) {
        let (a, b) = match part.split_once('-') {
            Some((a, b)) => (a.trim(), b.trim()),
            None => (part, part),
        };
        let lo = parse_number(a, 0xFF).with_context(|| format!("--addresses {part:?}"))?;
        let hi = parse_number(b, 0xFF).with_context(|| format!("--addresses {part:?}"))?;
        if lo == 0 || hi == 0 {
            bail!("--addresses {part:?}: 0 is the broadcast address, which is never answered");
        }
        if lo > hi {
            bail!("--addresses {part:?}: the range runs backwards");
        }
        for a in lo..=hi {
            let a = u8::try_from(a).unwrap_or(u8::MAX);
            if !out.contains(&a) {
                out.push(a);
            }
        }
    }
    if out.is_empty() {
        bail!("--addresses {text:?} names no address");
    }
    Ok(out)
}

/// Writes addresses back as `--addresses` takes them: runs of consecutive ones as
/// "LO-HI", in the order given, comma-separated ("1-3,7,10-20").
pub fn address_ranges(addresses: &[u8]) -> String {
    let mut parts: Vec<String> = Vec::new();
    let mut i = 0;
    while i < addresses.len() {
        let lo = addresses[i];
        let mut hi = lo;
        while i + 1 < addresses.len() && hi.checked_add(1) == Some(addresses[i + 1]) {
            hi = addresses[i + 1];
            i += 1;
        }
        parts.push(if lo == hi {
            lo.to_string()
        } else {
            format!("{lo}-{hi}")
        });
        i += 1;
    }
    parts.join(",")
}

pub fn run(args: ScanArgs) -> anyhow::Result<ExitCode> {
    let addresses = parse_addresses(&args.addresses)?;
    let search = args.lines.search()?;
    args.rts.needs_port(args.port.as_deref())?;
    let mut settings = settings_to_try(&search)?;
    let capture = super::link::open_capture(args.capture.as_deref())?;
    let mut link = open_link(
        args.port.as_deref(),
        args.tcp.as_deref(),
        args.framing,
        &mut settings,
        &args.rts,
        capture.as_ref(),
        &addresses,
        !args.lines.modes.is_empty(),
    )?;
    let config = ScanConfig {
        settings,
        addresses,
        first: vec![1],
        response: Duration::from_millis(args.response_time),
        reply_window: args.reply_window.map(Duration::from_millis),
        retries: args.retries,
    };

    let stop = super::interrupt::stop_flag()?;
    // The same progress style as check and gate; the bar counts planned wire time, so
    // that the ETA weighs slow settings right.
    let bar = progress_bar(args.quiet, 1, "{bar:30} {percent}% eta {eta} {wide_msg}");
    let result = scan(link.as_mut(), &config, &stop, &mut |p| {
        if let Some(b) = &bar {
            b.set_length(p.total_us.max(1));
            b.set_position(p.done_us);
            b.set_message(format!(
                "{} node {:02X}H, {} found",
                p.setting, p.address, p.found
            ));
        }
    });
    if let Some(b) = &bar {
        b.finish_and_clear();
    }
    // The link (and the transport that records) is closed before the capture is
    // summed up, so that the frames it held are written.
    drop(link);
    super::link::close_capture(args.capture.as_deref(), capture.as_ref());
    let result = result?;
    let rendered = match args.format {
        ScanFormat::Text => report::text(&result),
        ScanFormat::Json => serde_json::to_string_pretty(&report::json(&result))? + "\n",
    };
    match &args.output {
        Some(path) => {
            std::fs::write(path, &rendered)
                .with_context(|| format!("cannot write {}", path.display()))?;
            eprintln!(
                "{} device(s) found in {:.1} s; result in {}",
                result.found.len(),
                result.elapsed.as_secs_f64(),
                path.display()
            );
        }
        None => {
            let mut out = std::io::stdout().lock();
            out.write_all(rendered.as_bytes())?;
            out.flush()?;
        }
    }
    if let Some(why) = &result.stopped {
        eprintln!("scan {why}: the result covers the tries made");
        return Ok(ExitCode::from(2));
    }
    Ok(if result.found.is_empty() {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}

/// The line settings and modes a search tries (`scan`, `model learn`), each a list.
#[derive(Debug, Args)]
pub(super) struct LineLists {
    /// Baud rates to try (default: 9600,19200,38400,57600,115200,4800,2400,1200).
    #[arg(short = 'b', long = "baud", value_delimiter = ',')]
    pub bauds: Vec<u32>,
    /// Parities to try (default: even,none,odd).
    #[arg(short = 'P', long = "parity", value_enum, value_delimiter = ',')]
    pub parities: Vec<ParityArg>,
    /// Data bits to try (default: 8; 7 is ASCII only).
    #[arg(short = 'd', long = "data-bits", value_delimiter = ',', value_parser = clap::value_parser!(u8).range(7..=8))]
    pub data_bits: Vec<u8>,
    /// Stop bits to try (default: 1; a UART checks only its first stop bit).
    #[arg(short = 's', long = "stop-bits", value_delimiter = ',', value_parser = clap::value_parser!(u8).range(1..=2))]
    pub stop_bits: Vec<u8>,
    /// Modes to try (default: rtu,ascii).
    #[arg(short = 'm', long = "mode", value_enum, value_delimiter = ',')]
    pub modes: Vec<ModeArg>,
}

impl LineLists {
    /// The search these lists ask for (empty lists: the search's defaults); refused
    /// where a baud rate is 0.
    pub(super) fn search(&self) -> anyhow::Result<Search> {
        if self.bauds.contains(&0) {
            bail!("-b 0 is no baud rate");
        }
        Ok(Search {
            bauds: self.bauds.clone(),
            parities: self
                .parities
                .iter()
                .map(|p| match p {
                    ParityArg::None => Parity::None,
                    ParityArg::Even => Parity::Even,
                    ParityArg::Odd => Parity::Odd,
                })
                .collect(),
            stop_bits: self.stop_bits.clone(),
            data_bits: self.data_bits.clone(),
            modes: self.modes.iter().map(|&m| Mode::from(m)).collect(),
        })
    }
}

/// The settings `search` tries (`scan`, `model learn`); refused where there are none.
pub(super) fn settings_to_try(search: &Search) -> anyhow::Result<Vec<Setting>> {
    let settings = search.settings();
    if settings.is_empty() {
        bail!("no setting to try: RTU needs 8 data bits (-d 8)");
    }
    Ok(settings)
}

/// The link a scan searches: a serial port at `port` (its line set per setting) or a
/// gateway at `tcp` (raw frames, or Modbus TCP with `framing` mbap, where `settings` is
/// narrowed to one line a mode); recorded on `capture`. `modes_given`: -m was given.
#[allow(clippy::too_many_arguments)]
pub(super) fn open_link(
    port: Option<&str>,
    tcp: Option<&str>,
    framing: Option<Framing>,
    settings: &mut Vec<Setting>,
    rts: &RtsArgs,
    capture: Option<&conformance::transport::capture::SharedRecorder>,
    addresses: &[u8],
    modes_given: bool,
) -> anyhow::Result<Box<dyn ScanLink>> {
    Ok(match (port, tcp) {
        (Some(path), None) => {
            let first = settings[0].line;
            let kind = serial_kind(path);
            let mut port = SerialTransport::open(path, first, kind)?.with_rts(rts.control())?;
            if kind == LinkKind::Pty {
                // A pseudo-terminal standing in for a line: requests take their wire
                // time, as on a real port.
                port = port.paced_peer();
            }
            let link = SerialLink::new(port, path);
            Box::new(match capture {
                Some(rec) => link.recorded(rec.clone()),
                None => link,
            })
        }
        (None, Some(addr)) => {
            // The gateway's line is its own: one setting a mode, for the windows.
            let line = settings[0].line;
            let mut modes: Vec<Mode> = Vec::new();
            for s in settings.iter() {
                if !modes.contains(&s.mode) {
                    modes.push(s.mode);
                }
            }
            *settings = modes
                .into_iter()
                .map(|mode| Setting { line, mode })
                .collect();
            if framing == Some(Framing::Mbap) {
                if settings.iter().any(|s| s.mode != Mode::Rtu) && modes_given {
                    bail!("--framing mbap carries RTU-equivalent PDUs only: there is no ASCII over Modbus TCP (drop -m ascii)");
                }
                settings.retain(|s| s.mode == Mode::Rtu);
                // Node n is unit n: the map of one node to itself is the identity.
                let mut t = MbapGateway::connect(addr, Duration::from_secs(2), UnitMap::new(1, 1))?;
                if let Some(rec) = capture {
                    t = t.with_capture(rec.clone());
                }
                // The gateway's own description names the one unit of a request; the
                // sweep's header names every unit id it tries.
                let described = format!(
                    "Modbus TCP gateway {} (MBAP, unit ids {} swept, each the node address)",
                    t.peer(),
                    address_ranges(addresses)
                );
                // A gateway answers a unit with no device with 0BH only after its own
                // serial timeout (often 100..1000 ms): the window waits for that answer,
                // so that it is not taken for the reply to the next unit's read.
                Box::new(FixedLink::new(Box::new(t), MBAP_SLACK).described_as(described))
            } else {
                let t = TcpTransport::connect(addr, Duration::from_secs(2))?;
                let link = FixedLink::new(Box::new(t), Duration::from_millis(20));
                Box::new(match capture {
                    Some(rec) => link.recorded(rec.clone()),
                    None => link,
                })
            }
        }
        _ => bail!("say where the line is: --port PATH or --tcp HOST:PORT"),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn address_lists() {
        assert_eq!(parse_addresses("1-3").unwrap(), [1, 2, 3]);
        assert_eq!(parse_addresses("17").unwrap(), [17]);
        assert_eq!(parse_addresses("1,2,5-6,2").unwrap(), [1, 2, 5, 6]);
        assert_eq!(parse_addresses("0AH-0x0B").unwrap(), [10, 11]);
        assert_eq!(parse_addresses("1-247").unwrap().len(), 247);
        assert!(parse_addresses("0-5").is_err());
        assert!(parse_addresses("9-3").is_err());
        assert!(parse_addresses("300").is_err());
        assert!(parse_addresses(",").is_err());
    }

    #[test]
    fn address_lists_written_back() {
        assert_eq!(address_ranges(&[10, 11, 12, 13]), "10-13");
        assert_eq!(address_ranges(&[17]), "17");
        assert_eq!(address_ranges(&[1, 2, 3, 7, 9, 10]), "1-3,7,9-10");
        assert_eq!(address_ranges(&[5, 1, 2, 255]), "5,1-2,255");
        for text in ["1-247", "3,1-2,9", "0AH-0x0B,200"] {
            let a = parse_addresses(text).unwrap();
            assert_eq!(parse_addresses(&address_ranges(&a)).unwrap(), a, "{text}");
        }
    }
}
