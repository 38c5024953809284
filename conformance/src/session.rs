//! A whole conformance run: opens the target (a serial port, a TCP gateway, or the
//! simulator started in-process on a pseudo-terminal pair), runs the checks of each mode,
//! and builds the report. The command line and the tests both run sessions through here.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread;
use std::time::{Duration, SystemTime};

use crate::codec::timing::LineSettings;
use crate::codec::Mode;
use crate::model::DriveModel;
use crate::report::{Device, NodeInfo, Report, RunOptions};
use crate::runner::{
    run_mode, run_section, Check, CheckResult, Master, ModeBudget, Options, Progress, Section,
};
use crate::sim::{serve_with_gap, Bus, LogFormat, PlantedQuirk, TrafficLog};
use crate::transport::mbap::{MbapGateway, UnitMap};
use crate::transport::serial::SerialTransport;
use crate::transport::tcp::TcpTransport;
use crate::transport::{LinkKind, Transport, TransportError};
use crate::vectors::VectorSet;

/// What the run talks to.
#[derive(Debug, Clone)]
pub enum Target {
    /// A serial port.
    Serial {
        /// Device path.
        path: String,
        /// RS-485 direction control by RTS, if asked for.
        rts: Option<crate::transport::serial::RtsControl>,
    },
    /// A serial gateway at HOST:PORT.
    Tcp {
        /// HOST:PORT.
        addr: String,
    },
    /// A Modbus TCP gateway at HOST:PORT (MBAP framing), with the device at `unit`.
    Mbap {
        /// HOST:PORT.
        addr: String,
        /// The device's unit id (see [`crate::transport::mbap::UnitMap`]).
        unit: u8,
    },
    /// This suite's simulator, started in-process on a pseudo-terminal pair.
    Sim {
        /// Fault injection, on every node or on one (`QUIRK@NODE`).
        quirks: Vec<PlantedQuirk>,
        /// Send at the line's character time, so that timing checks measure something.
        pace: bool,
        /// Response delay (default: the model's response time).
        delay: Option<Duration>,
        /// Where to write the simulator's traffic log (JSON lines), if anywhere.
        log: Option<std::path::PathBuf>,
    },
}

/// Everything a session needs.
pub struct SessionConfig {
    /// The model.
    pub model: Arc<DriveModel>,
    /// The target.
    pub target: Target,
    /// Modes to run, in order.
    pub modes: Vec<Mode>,
    /// The serial line (also the simulator's pacing).
    pub line: LineSettings,
    /// Runner options.
    pub options: Options,
    /// Where every frame on the link is recorded (`--capture`), if anywhere.
    pub capture: Option<crate::transport::capture::SharedRecorder>,
}

/// Why a session could not start.
#[derive(Debug, thiserror::Error)]
pub enum SessionError {
    /// The target could not be opened.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The simulator's log could not be created.
    #[error("cannot create the simulator log {path}: {source}")]
    Log {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// Pseudo-terminals are not available.
    #[error("the simulator needs pseudo-terminals (a Unix system)")]
    NoPty,
    /// The simulated bus cannot be built as asked.
    #[error(transparent)]
    Bus(#[from] crate::sim::BusError),
}

fn now_rfc3339() -> String {
    humantime::format_rfc3339_seconds(SystemTime::now()).to_string()
}

/// The checks a session would run, per mode, without opening anything.
pub fn list(config: &SessionConfig) -> Vec<(Mode, Check)> {
    let vectors = VectorSet::builtin().ok();
    let file = vectors.as_ref().and_then(|v| v.file(&config.model.id));
    let mut out = Vec::new();
    for &mode in &config.modes {
        for c in crate::runner::plan(&config.model, file, mode, &config.options) {
            if crate::runner::selected(&c.id, &config.options.only) {
                out.push((mode, c));
            }
        }
    }
    out
}

/// How many results a session gives: its checks, and in a run of several nodes those
/// of each node plus the checks of the whole bus once (preflights not counted).
pub fn planned(config: &SessionConfig) -> u64 {
    let checks = list(config);
    let nodes = config.options.bus.len().max(1) as u64;
    if nodes < 2 {
        return checks.len() as u64;
    }
    checks
        .iter()
        .map(|(_, c)| if c.bus { 1 } else { nodes })
        .sum()
}

/// A simulator running in a thread on the master side of a pseudo-terminal pair; it
/// stops when this is dropped.
pub struct SimThread {
    stop: Arc<AtomicBool>,
    handle: Option<thread::JoinHandle<Result<(), String>>>,
}

impl Drop for SimThread {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(h) = self.handle.take() {
            let _ = h.join();
        }
    }
}

#[cfg(unix)]
fn start_sim(
    config: &SessionConfig,
    mode: Mode,
    quirks: &[PlantedQuirk],
    pace: bool,
    delay: Option<Duration>,
    log: Option<&std::path::Path>,
) -> Result<(SimThread, Box<dyn Transport>), SessionError> {
    use crate::transport::pty::PtyMaster;
    let mut master = PtyMaster::open(pace.then_some(config.line))?;
    let path = master.slave_path().to_string_lossy().into_owned();
    let clock = master.pacing_clock();
    let tags = master.line_tags();
    let starts = master.reply_start_queue();
    let delay = delay.unwrap_or_else(|| config.model.response_delay(&config.line));
    // One drive per node of the run, each with its own state, on one line.
    let nodes = bus_nodes(&config.options);
    let mut drive = Bus::of_model(&config.model, &nodes, delay, quirks, config.line, pace)?;
    let mut traffic = TrafficLog::new();
    if let Some(p) = log {
        let file = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(p)
            .map_err(|source| SessionError::Log {
                path: p.display().to_string(),
                source,
            })?;
        traffic = traffic.with_sink(LogFormat::Json, Box::new(std::io::BufWriter::new(file)));
    }
    let stop = Arc::new(AtomicBool::new(false));
    let s = stop.clone();
    // Told to answer at once on an unpaced link (the fuzzer, which writes every frame in
    // one write): a burst also ends as soon as nothing more is waiting.
    let prompt = !pace && delay.is_zero();
    let handle = thread::spawn(move || {
        serve_with_gap(
            &mut master,
            &mut drive,
            mode,
            &mut traffic,
            &s,
            prompt.then_some(Duration::ZERO),
        )
        .map(|_| ())
        .map_err(|e| e.to_string())
    });
    let mut client = SerialTransport::open(&path, config.line, LinkKind::Pty)?;
    if pace {
        client = client
            .paced_peer()
            .with_peer_clock(clock)
            .with_line_tags(tags)
            .with_reply_starts(starts);
    }
    Ok((
        SimThread {
            stop,
            handle: Some(handle),
        },
        Box::new(client),
    ))
}

struct Hooks<'a, 'b> {
    mode: Mode,
    report: &'a mut Report,
    on_start: &'a mut (dyn FnMut(Mode, &Check) + 'b),
    on_result: &'a mut (dyn FnMut(&Report) + 'b),
}

impl Progress for Hooks<'_, '_> {
    fn started(&mut self, check: &Check) {
        (self.on_start)(self.mode, check);
    }

    fn finished(&mut self, result: &CheckResult) {
        self.report.results.push(result.clone());
        (self.on_result)(self.report);
    }
}

/// The nodes of a run: its bus, or its one address.
fn bus_nodes(options: &Options) -> Vec<u8> {
    if options.bus.is_empty() {
        vec![options.address]
    } else {
        options.bus.clone()
    }
}

/// A "serial port" that is really a pseudo-terminal (socat's pty pairs, a simulator's
/// slave path) has no line timing; everything else is taken as a real line.
pub fn serial_kind(path: &str) -> LinkKind {
    match std::fs::canonicalize(path) {
        Ok(p) if p.starts_with("/dev/pts") => LinkKind::Pty,
        _ => LinkKind::Serial,
    }
}

/// Opens the target for `mode`: the serial port, the TCP gateway (raw frames or Modbus
/// TCP), or a simulator started
/// on a pseudo-terminal pair (stopped when the guard is dropped).
pub fn open(
    config: &SessionConfig,
    mode: Mode,
) -> Result<(Option<SimThread>, Box<dyn Transport>), SessionError> {
    // A Modbus TCP gateway records its TCP stream (MBAP under made-up TCP headers), not
    // RTU frames.
    if let (Target::Mbap { addr, unit }, Some(rec)) = (&config.target, &config.capture) {
        let g = MbapGateway::connect(
            addr,
            config.options.timing.timeout.max(Duration::from_secs(2)),
            UnitMap::new(config.options.address, *unit),
        )?
        .with_capture(rec.clone());
        return Ok((None, Box::new(g)));
    }
    let (sim, transport) = open_link(config, mode)?;
    let transport: Box<dyn Transport> = match &config.capture {
        // The capture holds a reply's parts together as long as the runner waits for them.
        Some(rec) => Box::new(
            crate::transport::capture::Captured::new(transport, rec.clone(), mode, config.line)
                .holding_frames_for(config.options.timing.timeout),
        ),
        None => transport,
    };
    Ok((sim, transport))
}

/// [`open`], with the link noted in the report's links of `mode`.
fn open_into(
    config: &SessionConfig,
    mode: Mode,
    report: &mut Report,
) -> Result<(Option<SimThread>, Box<dyn Transport>), SessionError> {
    let (sim, transport) = open(config, mode)?;
    report
        .device
        .links
        .insert(mode.to_string(), transport.describe());
    Ok((sim, transport))
}

/// [`open`] without the capture.
fn open_link(
    config: &SessionConfig,
    mode: Mode,
) -> Result<(Option<SimThread>, Box<dyn Transport>), SessionError> {
    Ok(match &config.target {
        Target::Serial { path, rts } => (
            None,
            Box::new(SerialTransport::open(path, config.line, serial_kind(path))?.with_rts(*rts)?),
        ),
        Target::Tcp { addr } => (
            None,
            Box::new(TcpTransport::connect(
                addr,
                config.options.timing.timeout.max(Duration::from_secs(2)),
            )?),
        ),
        Target::Mbap { addr, unit } => (
            None,
            Box::new(MbapGateway::connect(
                addr,
                config.options.timing.timeout.max(Duration::from_secs(2)),
                UnitMap::new(config.options.address, *unit),
            )?),
        ),
        #[cfg(unix)]
        Target::Sim {
            quirks,
            pace,
            delay,
            log,
        } => {
            let (s, t) = start_sim(config, mode, quirks, *pace, *delay, log.as_deref())?;
            (Some(s), t)
        }
        #[cfg(not(unix))]
        Target::Sim { .. } => return Err(SessionError::NoPty),
    })
}

/// The report's header for `config`.
fn header(config: &SessionConfig) -> Report {
    let l = config.line;
    Report {
        started: now_rfc3339(),
        device: Device {
            model: config.model.id.clone(),
            manual: config.model.manual.clone(),
            address: config.options.address,
            line: match &config.target {
                // The serial side is the gateway's: its settings are set there.
                Target::Mbap { .. } if config.options.bus.len() > 1 => {
                    "behind a Modbus TCP gateway (MBAP, each node's unit id is its address; the serial line's settings are the gateway's)".to_string()
                }
                Target::Mbap { unit, .. } => format!(
                    "behind a Modbus TCP gateway (MBAP, unit {unit}; the serial line's settings are the gateway's)"
                ),
                _ => format!("{} baud {}{}{}", l.baud, l.data_bits, l.parity, l.stop_bits),
            },
            simulated: match &config.target {
                // In a run of several nodes, a quirk planted on one node is told in its
                // node's entry.
                Target::Sim { quirks, .. } => Some(
                    quirks
                        .iter()
                        .filter(|q| q.node.is_none() || config.options.bus.len() < 2)
                        .map(|q| q.to_string())
                        .collect(),
                ),
                _ => None,
            },
            nodes: if config.options.bus.len() > 1 {
                config
                    .options
                    .bus
                    .iter()
                    .map(|&n| NodeInfo {
                        address: n,
                        quirks: match &config.target {
                            Target::Sim { quirks, .. } => quirks
                                .iter()
                                .filter(|q| q.node == Some(n))
                                .map(|q| q.quirk.to_string())
                                .collect(),
                            _ => Vec::new(),
                        },
                        ..NodeInfo::default()
                    })
                    .collect()
            } else {
                Vec::new()
            },
            description: Some(config.model.source.clone()),
            ..Device::default()
        },
        options: RunOptions {
            modes: config.modes.clone(),
            read_only: config.options.read_only,
            allow_motion: config.options.allow_motion,
            timeout_ms: u64::try_from(config.options.timing.timeout.as_millis())
                .unwrap_or(u64::MAX),
            retries: config.options.timing.retries,
            only: config.options.only.clone(),
            response_time_ms: Some(config.model.response_time_on(Some(&l)).as_secs_f64() * 1000.0),
            response_allowance_ms: Some(
                u64::try_from(config.options.response_allowance.as_millis()).unwrap_or(u64::MAX),
            ),
        },
        ..Report::default()
    }
}

/// Runs a fuzz campaign in each mode of `config` (see [`crate::fuzz`]); `progress` is
/// told the cases and findings so far. The report has one result per finding signature
/// and one per mode for the campaign.
pub fn fuzz(
    config: &SessionConfig,
    cfg: &crate::fuzz::FuzzConfig,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(Mode, u64, usize),
) -> Result<Report, SessionError> {
    let vectors = VectorSet::builtin().ok();
    let file = vectors.as_ref().and_then(|v| v.file(&config.model.id));
    let mut report = header(config);
    report.kind = crate::report::ReportKind::Fuzz;
    let mut summary = crate::fuzz::report::FuzzSummary {
        seed: cfg.seed,
        writes: cfg.writes.to_string(),
        modes: Vec::new(),
    };
    for &mode in &config.modes {
        if stop.load(Ordering::Relaxed) {
            report.stopped = Some("interrupted".into());
            break;
        }
        // The description leaves this mode out: nothing to fuzz in it.
        if !config.model.serves_mode(mode) {
            continue;
        }
        let (sim, transport) = open_into(config, mode, &mut report)?;
        let outcome = crate::fuzz::fuzz_mode(
            &config.model,
            file,
            mode,
            transport,
            &config.options,
            cfg,
            stop,
            &mut |n, f| progress(mode, n, f),
        );
        drop(sim);
        report
            .results
            .push(crate::fuzz::report::campaign_result(&outcome));
        if let Some(storm) = &outcome.storm {
            report.results.push(crate::fuzz::storm::result(mode, storm));
        }
        for f in &outcome.findings {
            report.results.push(crate::fuzz::report::finding_result(f));
        }
        report.restore.extend(outcome.restore.clone());
        let stopped = outcome.stopped.clone();
        summary.modes.push(outcome);
        if let Some(why) = stopped {
            report.stopped = Some(why);
            break;
        }
    }
    report.fuzz = Some(summary);
    report.complete = report.stopped.is_none();
    report.finished = Some(now_rfc3339());
    Ok(report)
}

/// Runs a session. `on_start` is called before each check (progress), `on_result` after
/// each with the report so far (incremental output). `stop` cuts the run short; what ran
/// is reported, marked incomplete, and changed registers are restored.
pub fn run(
    config: &SessionConfig,
    stop: &AtomicBool,
    on_start: &mut dyn FnMut(Mode, &Check),
    on_result: &mut dyn FnMut(&Report),
) -> Result<Report, SessionError> {
    let vectors = VectorSet::builtin().ok();
    let file = vectors.as_ref().and_then(|v| v.file(&config.model.id));
    let mut report = header(config);
    on_result(&report);
    for &mode in &config.modes {
        if stop.load(Ordering::Relaxed) {
            report.stopped = Some("interrupted".into());
            break;
        }
        // A mode the description leaves out is one SKIP: nothing is opened or sent.
        if !config.model.serves_mode(mode) {
            let check = crate::runner::checks::mode_not_served(&config.model, mode);
            on_start(mode, &check);
            let why = crate::runner::checks::mode_not_served_reason(&config.model, mode);
            let result = crate::runner::run::result_of(
                &check,
                mode,
                crate::runner::Verdict::skip(why),
                std::time::Duration::ZERO,
            );
            report.results.push(result);
            on_result(&report);
            continue;
        }
        let (sim, transport) = open_into(config, mode, &mut report)?;
        if config.options.bus.len() > 1 {
            if let Target::Mbap { addr, .. } = &config.target {
                report.device.links.insert(
                    mode.to_string(),
                    format!("Modbus TCP gateway {addr} (MBAP, unit id = node address)"),
                );
            }
            let fatal = run_bus(
                config,
                file,
                mode,
                transport,
                stop,
                &mut report,
                &mut *on_start,
                &mut *on_result,
            );
            drop(sim);
            if let Some(why) = fatal {
                report.stopped = Some(why);
                break;
            }
            continue;
        }
        let mode_run = {
            let mut hooks = Hooks {
                mode,
                report: &mut report,
                on_start: &mut *on_start,
                on_result: &mut *on_result,
            };
            run_mode(
                &config.model,
                file,
                mode,
                transport,
                &config.options,
                stop,
                &mut hooks,
            )
        };
        drop(sim);
        if mode_run.echo == Some(true) {
            note_echo(&mut report, mode);
        }
        if report.device.identification.is_none() {
            report.device.identification = mode_run.identification;
        }
        report.restore.extend(mode_run.restore);
        report.budget.insert(mode.to_string(), mode_run.budget);
        if let Some(why) = mode_run.stopped {
            report.stopped = Some(why);
            break;
        }
    }
    if report.stopped.is_none() {
        // Nodes that stopped answering: their checks left are ERRORs, the other nodes
        // were checked; the run is not whole.
        let lost: Vec<String> = report
            .device
            .nodes
            .iter()
            .filter_map(|n| {
                n.stopped
                    .as_ref()
                    .map(|w| format!("node {:02X}H: {w}", n.address))
            })
            .collect();
        if !lost.is_empty() {
            report.stopped = Some(format!("{}; the other nodes were checked", lost.join("; ")));
        }
    }
    report.complete = report.stopped.is_none();
    report.finished = Some(now_rfc3339());
    on_result(&report);
    Ok(report)
}

/// One mode of a run of several nodes on one bus: a section per node, then the checks of
/// the whole bus once, all over one master (the echo and response time it learns are the
/// bus's). A node that stops answering ends its own section only. Returns why the whole
/// run must stop (the link failed, or it was interrupted), if it must.
#[allow(clippy::too_many_arguments)]
fn run_bus(
    config: &SessionConfig,
    file: Option<&crate::vectors::VectorFile>,
    mode: Mode,
    transport: Box<dyn Transport>,
    stop: &AtomicBool,
    report: &mut Report,
    on_start: &mut dyn FnMut(Mode, &Check),
    on_result: &mut dyn FnMut(&Report),
) -> Option<String> {
    let mut master =
        Master::new(transport, mode, config.options.timing).with_echo(config.options.echo);
    // The last section's line figures (the master's so far), with the wall time and the
    // host's reruns of every section.
    let mut budget = ModeBudget::default();
    let mut answering: Vec<u8> = Vec::new();
    let sections = config
        .options
        .bus
        .iter()
        .map(|&n| (Section::Node, n))
        .chain(std::iter::once((Section::Bus, 0)));
    for (section, node) in sections {
        if stop.load(Ordering::Relaxed) {
            return Some("interrupted".into());
        }
        let opts = match section {
            Section::Bus => {
                // Broadcasts and the other address go once, with the read-backs and
                // liveness probes to the nodes that still answer.
                let Some(&first) = answering.first() else {
                    bus_not_run(config, file, mode, report, &mut *on_start, &mut *on_result);
                    break;
                };
                Options {
                    address: first,
                    bus: answering.clone(),
                    ..config.options.clone()
                }
            }
            _ => Options {
                address: node,
                ..config.options.clone()
            },
        };
        let (mut run, m) = {
            let mut hooks = Hooks {
                mode,
                report: &mut *report,
                on_start: &mut *on_start,
                on_result: &mut *on_result,
            };
            run_section(
                &config.model,
                file,
                mode,
                master,
                &opts,
                stop,
                &mut hooks,
                section,
            )
        };
        master = m;
        budget = ModeBudget {
            wall: budget.wall + run.budget.wall,
            host_reruns: budget.host_reruns + run.budget.host_reruns,
            ..run.budget
        };
        for r in &mut run.restore {
            r.node.get_or_insert(opts.address);
        }
        report.restore.append(&mut run.restore);
        if run.echo == Some(true) {
            note_echo(report, mode);
        }
        if section == Section::Node {
            if let Some(info) = report.device.nodes.iter_mut().find(|n| n.address == node) {
                if info.identification.is_none() {
                    info.identification = run.identification;
                }
                if run.lost {
                    let why = run.stopped.clone().unwrap_or_default();
                    info.stopped = Some(match info.stopped.take() {
                        Some(before) => format!("{before}; {mode}: {why}"),
                        None => format!("{mode}: {why}"),
                    });
                }
            }
            if report.device.identification.is_none() && node == config.options.address {
                report.device.identification = run.identification;
            }
        }
        match run.stopped {
            Some(why) if !run.lost => {
                report.budget.insert(mode.to_string(), budget);
                return Some(why);
            }
            Some(_) => {}
            None if section == Section::Node => answering.push(node),
            None => {}
        }
    }
    report.budget.insert(mode.to_string(), budget);
    None
}

/// Says on `mode`'s link line that the line echoes every request (once).
fn note_echo(report: &mut Report, mode: Mode) {
    const ECHO: &str = " (local echo: every request comes back before the reply; stripped)";
    if let Some(link) = report.device.links.get_mut(&mode.to_string()) {
        if !link.ends_with(ECHO) {
            link.push_str(ECHO);
        }
    }
}

/// The checks of the whole bus where no node answers: each an ERROR.
fn bus_not_run(
    config: &SessionConfig,
    file: Option<&crate::vectors::VectorFile>,
    mode: Mode,
    report: &mut Report,
    on_start: &mut dyn FnMut(Mode, &Check),
    on_result: &mut dyn FnMut(&Report),
) {
    for c in crate::runner::plan(&config.model, file, mode, &config.options) {
        if !c.bus || !crate::runner::selected(&c.id, &config.options.only) {
            continue;
        }
        on_start(mode, &c);
        report.results.push(crate::runner::run::result_of(
            &c,
            mode,
            crate::runner::Verdict::error(
                "not run: no node of the bus answers (see the nodes' preflights)",
            ),
            Duration::ZERO,
        ));
        on_result(report);
    }
}
