//! `conformance simulate`: a simulated drive on a serial port, a pseudo-terminal or TCP.

use std::fs::File;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use conformance::codec::timing::LineSettings;
use conformance::codec::Mode;
use conformance::sim::mbap::{serve_gateway_recorded, GatewayConfig, NoReply};
use conformance::sim::{
    serve, Bus, LogFormat, PlantedQuirk, Responder, SimError, TrafficLog, QUIRK_HELP,
};
use conformance::transport::capture::{Captured, SharedRecorder};
use conformance::transport::serial::SerialTransport;
use conformance::transport::tcp::TcpTransport;
use conformance::transport::{LinkKind, Transport, TransportError};

use super::common::{load_model, parse_nodes, LineArgs, ModeArg, NodeList};
use super::link::{Framing, MBAP_NOT_ASCII};

fn quirk_help() -> String {
    let mut s = String::from("Fault injection (--quirk, repeatable):\n");
    for (q, what) in QUIRK_HELP {
        s.push_str(&format!("  {q:<22} {what}\n"));
    }
    s.push_str(
        "  QUIRK@NODE             the quirk on one node of -a 1,2,5 only (dead@2, slow=40@5)\n",
    );
    s.push_str("\nExamples:\n  conformance simulate --model f510 --pty\n  conformance simulate --model f510 --pty -a 1,2,5 --quirk dead@5   three drives on one bus\n  conformance simulate --model l510 --mode ascii --tcp 127.0.0.1:5020 --quirk late-reply=200\n  conformance simulate --model a510 --port /dev/ttyUSB0 -b 19200 -P none\n  conformance simulate --model e510 --pty --emulate-line -b 19200 -P odd -m ascii -a 17   a drive to find with `conformance scan`\n  conformance simulate --model f510 -a 3 --tcp 127.0.0.1:5502 --framing mbap\n");
    s.push_str("\nModbus TCP (--framing mbap): the drive behind a simulated Modbus TCP gateway. Several\nconnections at once (--connections, default 8) against one drive state, served one\nrequest at a time in arrival order, as a gateway's one serial line is. Unit id = the node\naddress (-a) is the drive; unit 0 is a broadcast (executed, never answered); any other\nunit id is a node nobody has: after --gateway-timeout the gateway answers exception 0BH\n(gateway target device failed to respond), or nothing with --gateway-no-reply silence.\nReplies a gateway's serial receiver would drop (wrong CRC, echo) do not cross.\n");
    s.push_str("\nExit codes: 0 stopped by Ctrl-C, SIGTERM or SIGHUP (the --link is removed); 2 the link\nor the log failed.");
    s
}

/// What the simulated gateway sends when the drive does not answer.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum GatewayNoReply {
    /// Exception 0BH (gateway target device failed to respond), after --gateway-timeout.
    Exception,
    /// Nothing.
    Silence,
}

/// Log format on stderr.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum LogFormatArg {
    /// One human line per frame.
    Text,
    /// JSON lines.
    Json,
}

#[derive(Debug, Args)]
#[command(after_help = quirk_help())]
pub struct SimulateArgs {
    /// Drive model: f510, a510, l510, e510, l510-legacy.
    #[arg(long, default_value = "f510")]
    model: String,
    /// Read the model from this file instead of the built-in one.
    #[arg(long, value_name = "FILE")]
    model_file: Option<PathBuf>,
    /// Node address of the drive: decimal as in mbpoll (a bare number is decimal), or hex
    /// with H suffix or 0x prefix (0AH, 0x0A). Several (1,2,5 or 1-4): one drive of the
    /// model at each, with its own registers and state, on one line (behind the simulated
    /// gateway of --framing mbap, unit id N is node N).
    #[arg(short = 'a', long = "address", value_name = "N[,N..]", value_parser = parse_nodes, default_value = "1")]
    nodes: NodeList,
    /// Transmission mode.
    #[arg(short = 'm', long, value_enum, default_value = "rtu")]
    mode: ModeArg,
    /// Serve on a serial port (a real RS-485 adapter).
    #[arg(long, value_name = "PATH", group = "where")]
    port: Option<String>,
    /// Serve on a new pseudo-terminal pair; its path is printed on stdout.
    #[arg(long, group = "where")]
    pty: bool,
    /// With --pty: also make a symbolic link to the slave at this path.
    #[arg(long, value_name = "PATH", requires = "pty")]
    link: Option<PathBuf>,
    /// With --pty: send at the line's character time (-b -P -d -s), so that timing is real.
    #[arg(long, requires = "pty")]
    pace: bool,
    /// With --pty: behave like a drive whose UART is set to -b -P -s: a master that opens
    /// the pty at other settings (its tcsetattr is seen on this side) gets garbage, as a
    /// real line gives it (the parity is inferred from the input flags masters set with
    /// it: see docs/src/identify-and-scan.md).
    #[arg(long, requires = "pty")]
    emulate_line: bool,
    /// Record every frame received and sent (seen from the drive's side: requests
    /// inbound, replies outbound) in this pcapng file; with --tcp, one interface a client,
    /// and with --framing mbap each connection's TCP stream under made-up Ethernet/IPv4/TCP
    /// headers, which Wireshark decodes as Modbus/TCP.
    #[arg(long, value_name = "FILE.pcapng")]
    capture: Option<PathBuf>,
    /// Serve over TCP at HOST:PORT: RTU or ASCII frames (as a serial server), or Modbus
    /// TCP with --framing mbap (as a Modbus TCP gateway with this drive behind it).
    #[arg(long, value_name = "HOST:PORT", group = "where")]
    tcp: Option<String>,
    /// With --tcp: rtu (the serial line's frames, the default) or mbap (Modbus TCP: MBAP
    /// header and PDU; several connections at once, one drive; see below).
    #[arg(long, value_enum, value_name = "rtu|mbap", requires = "tcp")]
    framing: Option<Framing>,
    /// With --framing mbap: what the gateway sends when the drive does not answer a
    /// unicast request (another unit id, a request the drive ignores): exception (0BH,
    /// after --gateway-timeout) or silence.
    #[arg(long, value_enum, default_value = "exception", requires = "framing")]
    gateway_no_reply: GatewayNoReply,
    /// With --framing mbap: milliseconds the gateway waits for the drive before it
    /// gives up (and answers 0BH).
    #[arg(long, value_name = "MS", default_value_t = 100, requires = "framing")]
    gateway_timeout: u64,
    /// With --framing mbap: connections served at once; one more is closed at once.
    #[arg(long, value_name = "N", default_value_t = 8, requires = "framing")]
    connections: usize,
    #[command(flatten)]
    line: LineArgs,
    /// Response delay in milliseconds (default: the model's response time, 10 ms, or t3.5
    /// of the line where that is longer: 16 ms at 2400 baud, 33 ms at 1200). A value given
    /// here is used as it is, even below t3.5 (to test a master's timing checks).
    #[arg(long, value_name = "MS")]
    delay: Option<u64>,
    /// Inject a fault; see the list below. Repeatable. QUIRK@NODE: on that node only.
    #[arg(long = "quirk", value_name = "QUIRK")]
    quirks: Vec<PlantedQuirk>,
    /// Also write the traffic log as JSON lines to this file.
    #[arg(long, value_name = "FILE")]
    log: Option<PathBuf>,
    /// Format of the traffic log on stderr.
    #[arg(long, value_enum, default_value = "text")]
    log_format: LogFormatArg,
    /// No traffic log on stderr.
    #[arg(short, long)]
    quiet: bool,
}

pub fn run(args: SimulateArgs) -> anyhow::Result<ExitCode> {
    let nodes = args.nodes.0.clone();
    let first = args.nodes.first();
    let model = Arc::new(load_model(&args.model, args.model_file.as_deref(), first)?);
    let mode: Mode = args.mode.into();
    let mbap = args.framing == Some(Framing::Mbap);
    if mbap && mode == Mode::Ascii {
        bail!("{MBAP_NOT_ASCII}");
    }
    let line = args.line.settings();
    if mode == Mode::Rtu && line.data_bits != 8 {
        bail!("RTU needs 8 data bits (-d 8)");
    }
    let delay = match args.delay {
        Some(ms) => Duration::from_millis(ms),
        None => model.response_delay(&line),
    };
    let paced = args.pace || args.port.is_some();
    let mut drive = Bus::of_model(&model, &nodes, delay, &args.quirks, line, paced)?;

    let mut log = TrafficLog::new();
    if !args.quiet {
        let f = match args.log_format {
            LogFormatArg::Text => LogFormat::Text,
            LogFormatArg::Json => LogFormat::Json,
        };
        log = log.with_sink(f, Box::new(std::io::stderr()));
    }
    if let Some(path) = &args.log {
        let file = File::create(path)
            .with_context(|| format!("cannot create the log file {}", path.display()))?;
        log = log.with_sink(LogFormat::Json, Box::new(std::io::BufWriter::new(file)));
    }

    let stop = super::interrupt::stop_flag_saying(super::interrupt::Stopping::Simulator)?;
    let quirks: Vec<String> = args.quirks.iter().map(|q| q.to_string()).collect();
    let banner = format!(
        "simulated {} ({}) at {}, {mode}, response delay {:.1} ms{}",
        model.id,
        model.manual,
        super::output::nodes_phrase(&nodes, ", "),
        delay.as_secs_f64() * 1000.0,
        if quirks.is_empty() {
            String::new()
        } else {
            format!(", quirks: {}", quirks.join(" "))
        }
    );

    args.line.rts.needs_port(args.port.as_deref())?;
    let capture = super::link::open_capture(args.capture.as_deref())?;
    let result = if let Some(path) = &args.port {
        let t = SerialTransport::open(path, line, LinkKind::Serial)?
            .with_rts(args.line.rts.control())?;
        log.message(&format!("{banner} on {}", t.describe()))?;
        run_recorded(t, capture.as_ref(), line, &mut drive, mode, &mut log, &stop)
    } else if args.pty {
        #[cfg(unix)]
        {
            let mut t = conformance::transport::pty::PtyMaster::open(args.pace.then_some(line))?;
            if args.emulate_line {
                t = t.with_line_emulation(line)?;
            }
            let path = t.slave_path().to_path_buf();
            // Removed when this scope ends: the serve loop's end on Ctrl-C, SIGTERM or
            // SIGHUP, and every error return.
            let _link = match &args.link {
                Some(link) => Some(PtyLink::make(link, &path)?),
                None => None,
            };
            let mut out = std::io::stdout();
            writeln!(out, "{}", path.display())?;
            out.flush()?;
            log.message(&format!("{banner} on {}", t.describe()))?;
            run_recorded(t, capture.as_ref(), line, &mut drive, mode, &mut log, &stop)
        }
        #[cfg(not(unix))]
        bail!("pseudo-terminals need a Unix system")
    } else if let (Some(addr), true) = (&args.tcp, mbap) {
        let listener = std::net::TcpListener::bind(addr)
            .with_context(|| format!("cannot listen on {addr}"))?;
        let config = GatewayConfig {
            no_reply: match args.gateway_no_reply {
                GatewayNoReply::Exception => NoReply::Exception,
                GatewayNoReply::Silence => NoReply::Silence,
            },
            target_timeout: Duration::from_millis(args.gateway_timeout),
            max_connections: args.connections.max(1),
        };
        log.message(&format!(
            "{banner} behind a Modbus TCP gateway (MBAP, unit{} {}) on tcp {}; up to {} connections; no reply: {}",
            if nodes.len() > 1 { "s" } else { "" },
            nodes.iter().map(u8::to_string).collect::<Vec<_>>().join(", "),
            listener
                .local_addr()
                .map(|a| a.to_string())
                .unwrap_or_default(),
            config.max_connections,
            match config.no_reply {
                NoReply::Exception => format!("exception 0BH after {} ms", args.gateway_timeout),
                NoReply::Silence => "silence".to_string(),
            }
        ))?;
        let stats = serve_gateway_recorded(&listener, drive, log, &config, &stop, capture.clone())?;
        super::link::close_capture(args.capture.as_deref(), capture.as_ref());
        if !args.quiet {
            eprintln!(
                "# stopped: {} connections ({} refused), {} requests, {} replies, {} gateway exceptions 0BH",
                stats.connections, stats.refused, stats.requests, stats.replies, stats.gateway_exceptions
            );
        }
        return Ok(ExitCode::SUCCESS);
    } else if let Some(addr) = &args.tcp {
        let listener = std::net::TcpListener::bind(addr)
            .with_context(|| format!("cannot listen on {addr}"))?;
        listener.set_nonblocking(true)?;
        log.message(&format!(
            "{banner} on tcp {}",
            listener
                .local_addr()
                .map(|a| a.to_string())
                .unwrap_or_default()
        ))?;
        serve_tcp(
            &listener,
            &mut drive,
            mode,
            line,
            capture.as_ref(),
            &mut log,
            &stop,
        )
    } else {
        bail!("say where to serve: --port PATH, --pty or --tcp HOST:PORT");
    };
    super::link::close_capture(args.capture.as_deref(), capture.as_ref());
    match result {
        Ok(()) => Ok(ExitCode::SUCCESS),
        Err(e) => Err(e.into()),
    }
}

/// The symbolic link of `--link` to the pseudo-terminal's slave, removed when dropped
/// (if it still points there: a link another simulator made since is left alone).
#[cfg(unix)]
struct PtyLink {
    link: PathBuf,
    target: PathBuf,
}

#[cfg(unix)]
impl PtyLink {
    /// Makes `link` point to `target`. A symbolic link already there (left by a simulator
    /// that was killed) is replaced; anything else is refused, never deleted.
    fn make(link: &std::path::Path, target: &std::path::Path) -> anyhow::Result<PtyLink> {
        super::common::point_link(
            link,
            target,
            "there is a file there that is not a symbolic link; it is not replaced (give another path)",
            "the old link",
        )?;
        Ok(PtyLink {
            link: link.to_path_buf(),
            target: target.to_path_buf(),
        })
    }
}

#[cfg(unix)]
impl Drop for PtyLink {
    fn drop(&mut self) {
        if std::fs::read_link(&self.link).is_ok_and(|t| t == self.target) {
            let _ = std::fs::remove_file(&self.link);
        }
    }
}

/// [`run_once`] on `t`, recorded on `capture` where one is asked for.
fn run_recorded<T: Transport>(
    t: T,
    capture: Option<&SharedRecorder>,
    line: LineSettings,
    drive: &mut dyn Responder,
    mode: Mode,
    log: &mut TrafficLog,
    stop: &AtomicBool,
) -> Result<(), SimError> {
    recorded(t, capture, mode, line, |t| {
        run_once(t, drive, mode, log, stop)
    })
}

/// `f` on `t`, recorded on `capture` where one is asked for (the recording closed when
/// `f` returns).
fn recorded<T: Transport, R>(
    mut t: T,
    capture: Option<&SharedRecorder>,
    mode: Mode,
    line: LineSettings,
    f: impl FnOnce(&mut dyn Transport) -> R,
) -> R {
    match capture {
        Some(rec) => f(&mut Captured::new(t, rec.clone(), mode, line)),
        None => f(&mut t),
    }
}

fn run_once(
    t: &mut dyn Transport,
    drive: &mut dyn Responder,
    mode: Mode,
    log: &mut TrafficLog,
    stop: &AtomicBool,
) -> Result<(), SimError> {
    let stats = serve(t, drive, mode, log, stop)?;
    log.message(&format!(
        "stopped: {} frames received, {} replies sent, {} bytes dropped",
        stats.frames, stats.replies, stats.dropped_bytes
    ))?;
    Ok(())
}

/// Serves one TCP client at a time, as a serial gateway does; a client that goes away is
/// logged and the next one is accepted.
fn serve_tcp(
    listener: &std::net::TcpListener,
    drive: &mut dyn Responder,
    mode: Mode,
    line: LineSettings,
    capture: Option<&SharedRecorder>,
    log: &mut TrafficLog,
    stop: &AtomicBool,
) -> Result<(), SimError> {
    while !stop.load(Ordering::Relaxed) {
        let stream = match listener.accept() {
            Ok((s, _)) => s,
            Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {
                std::thread::sleep(Duration::from_millis(20));
                continue;
            }
            Err(e) => return Err(SimError::Log(e)),
        };
        stream.set_nonblocking(false)?;
        let t = TcpTransport::from_stream(stream)?;
        log.message(&format!("client connected: {}", t.describe()))?;
        let served = recorded(t, capture, mode, line, |t| serve(t, drive, mode, log, stop));
        match served {
            Ok(_) => {}
            Err(SimError::Transport(TransportError::Closed { link })) => {
                log.message(&format!("client went away: {link}"))?;
            }
            Err(e) => return Err(e),
        }
    }
    Ok(())
}
