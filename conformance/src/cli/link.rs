//! The options `check`, `fuzz` and `send` share: what to talk to (the simulator, a
//! serial port, a TCP gateway carrying raw frames or Modbus TCP), the model, the serial
//! line, the modes, the node address, echo and timing; and the safety switches.

use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use conformance::codec::timing::LineSettings;
use conformance::codec::Mode;
use conformance::model::DriveModel;
use conformance::runner::{EchoMode, MasterTiming};
use conformance::session::Target;
use conformance::sim::PlantedQuirk;
use conformance::transport::capture::{Recorder, SharedRecorder};

use super::common::{load_model, parse_nodes, LineArgs, NodeList, Number};

/// Modes to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModesArg {
    /// RTU only.
    Rtu,
    /// ASCII only.
    Ascii,
    /// RTU, then ASCII (the simulator is restarted in each mode; a real drive is in one).
    Both,
}

/// How frames cross a TCP connection.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Framing {
    /// The serial line's own bytes (RTU or ASCII frames with their checksum), as a
    /// transparent serial server carries them.
    Rtu,
    /// Modbus TCP: a 7-byte MBAP header (transaction id, protocol id 0, length, unit id)
    /// and the PDU, no checksum, as a Modbus TCP gateway to RS-485 speaks it. RTU-
    /// equivalent PDUs only: there is no ASCII over MBAP.
    Mbap,
}

/// Why `--mode ascii` (or both) cannot go through MBAP.
pub const MBAP_NOT_ASCII: &str = "--framing mbap carries the PDU only (Modbus TCP has no ASCII mode: a gateway speaks RTU or ASCII on its serial side, set in the gateway); use --mode rtu (the default for --tcp)";

/// The device and the link to it.
#[derive(Debug, Args)]
pub struct TargetArgs {
    /// Run against this suite's simulator of MODEL, started in-process on a
    /// pseudo-terminal pair (no hardware needed). Bare `--sim` with --model-file FILE:
    /// the simulator serves that description.
    #[arg(long, value_name = "MODEL", group = "target", num_args = 0..=1, default_missing_value = "")]
    pub sim: Option<String>,
    /// Drive model of the device: f510, a510, l510, e510, l510-legacy; with `check`, also
    /// auto: identify the model from the device's answers to reads first (see
    /// `conformance identify --help`), then run that model's checks.
    #[arg(long, value_name = "MODEL")]
    pub model: Option<String>,
    /// Read the model from this description (a model file) instead of a built-in one:
    /// --model is then not needed, the model id is the file's. `identify` takes several
    /// (each one more candidate); the other commands take one.
    #[arg(long, value_name = "FILE")]
    pub model_file: Option<Vec<PathBuf>>,
    /// Serial port of the device.
    #[arg(long, value_name = "PATH", group = "target")]
    pub port: Option<String>,
    /// A gateway at HOST:PORT: a serial server carrying RTU or ASCII frames over TCP
    /// (--framing rtu, the default), or a Modbus TCP gateway (--framing mbap).
    #[arg(long, value_name = "HOST:PORT", group = "target")]
    pub tcp: Option<String>,
    /// With --tcp: rtu (the serial line's bytes, checksum included) or mbap (Modbus TCP:
    /// MBAP header and PDU, as a Modbus TCP gateway to RS-485 speaks). Through mbap the
    /// checksum, line-timing, echo and garbage checks cannot be seen and are SKIP.
    #[arg(long, value_enum, value_name = "rtu|mbap", requires = "tcp")]
    pub framing: Option<Framing>,
    /// With --framing mbap: the unit id the gateway routes to the device (default: the
    /// node address -a). Decimal, or hex with H suffix or 0x prefix. 1..=255; 0 is the
    /// broadcast.
    #[arg(long, value_name = "N", value_parser = Number::<u8>::quiet(), requires = "framing")]
    pub unit: Option<u8>,
    #[command(flatten)]
    pub line: LineArgs,
    /// Transmission mode (default: rtu for a device, both for --sim).
    #[arg(short = 'm', long, value_enum)]
    pub mode: Option<ModesArg>,
    /// Node address of the device: decimal as in mbpoll (a bare number is decimal), or hex
    /// with H suffix or 0x prefix (0AH, 0x0A). `check` takes several drives on one bus:
    /// 1,2,5 or 1-4 (one report, a section per node; the broadcast checks run once).
    #[arg(short = 'a', long = "address", value_name = "N[,N..]", value_parser = parse_nodes, default_value = "1")]
    pub nodes: NodeList,
    /// Set by a command that runs several nodes (`check`); the others refuse a list.
    #[arg(skip)]
    pub several_nodes: bool,
    /// A node address no device on the line has, for the other-address cases (default:
    /// the model's highest address, or the one below the device's). A bare number is
    /// decimal; hex with H suffix or 0x prefix (F7H, 0xF7).
    #[arg(long, value_parser = Number::<u8>::quiet())]
    pub other_address: Option<u8>,
    /// Local echo of every request (a 2-wire RS-485 adapter whose receiver hears its own
    /// transmission): auto learns it from the preflight read, on expects it, off trusts
    /// that there is none. An echo is stripped and the reply awaited for the whole
    /// response window; it is reported on the link line, not as a deviation.
    #[arg(long, value_name = "auto|on|off", default_value = "auto")]
    pub echo: EchoMode,
    /// Milliseconds to wait for a reply.
    #[arg(long, value_name = "MS", default_value_t = 1000)]
    pub timeout: u64,
    /// Milliseconds to listen where no reply is expected (broadcast, bad CRC, ...);
    /// default: derived from the device's measured response time (twice the longest
    /// reply delay, plus t3.5 and 20 ms, at least 50 ms, at most the timeout).
    #[arg(long, value_name = "MS")]
    pub silence: Option<u64>,
    /// Resend a request this many times when no byte comes back.
    #[arg(long, value_name = "N", default_value_t = 0)]
    pub retries: u32,
    /// With --sim: inject a fault into the simulator (see `conformance simulate --help`);
    /// QUIRK@NODE plants it on one node of `-a 1,2,5` only (dead@2, slow=40@5).
    #[arg(long = "quirk", value_name = "QUIRK", requires = "sim")]
    pub quirks: Vec<PlantedQuirk>,
    /// With --sim: do not pace the simulator at the line's character time (the link then
    /// has no timing). With `fuzz`, the simulator also answers at once: its response
    /// delay (max(10 ms, t3.5 + one character)) is a property of a timed line.
    #[arg(long, requires = "sim")]
    pub no_pace: bool,
    /// With --sim: write the simulator's traffic log (JSON lines) to this file.
    #[arg(long, value_name = "FILE", requires = "sim")]
    pub sim_log: Option<PathBuf>,
    /// Record every frame sent and received, damaged ones included, with its time and
    /// direction, in this pcapng file (Wireshark and tshark open it; see the guide's
    /// "Captures" page for the Modbus RTU decoding).
    #[arg(long, value_name = "FILE.pcapng")]
    pub capture: Option<PathBuf>,
}

/// Creates the capture file `path` (`--capture`), where one is asked for: a pcapng
/// section naming this program.
pub fn open_capture(path: Option<&std::path::Path>) -> anyhow::Result<Option<SharedRecorder>> {
    let Some(path) = path else {
        return Ok(None);
    };
    let file = std::fs::File::create(path)
        .with_context(|| format!("cannot create the capture {}", path.display()))?;
    let app = format!("conformance {}", env!("CARGO_PKG_VERSION"));
    let rec = Recorder::new(Box::new(file), &app)
        .with_context(|| format!("cannot write the capture {}", path.display()))?;
    Ok(Some(rec.shared()))
}

/// Says on stderr what the capture `path` holds, or why it stopped (nothing where no
/// capture was made).
pub fn close_capture(path: Option<&std::path::Path>, rec: Option<&SharedRecorder>) {
    let (Some(path), Some(Ok(r))) = (path, rec.map(|r| r.lock())) else {
        return;
    };
    match r.error() {
        Some(e) => eprintln!(
            "warning: the capture {} stopped after {} frames: {e}",
            path.display(),
            r.packets()
        ),
        None => eprintln!("capture: {} frames in {}", r.packets(), path.display()),
    }
}

/// The safety switches of a real drive.
#[derive(Debug, Args)]
pub struct SafetyArgs {
    /// Allow writes to the run and external-fault bits (the motor may turn).
    #[arg(long)]
    pub allow_motion: bool,
    /// Allow the 08H sub-functions that restart the device's communications (0001H) or
    /// make it stop answering (0004H, Force Listen Only Mode, then 0001H).
    #[arg(long)]
    pub allow_restart: bool,
}

/// The target resolved: the model, what to open, the modes and the line.
pub struct Resolved {
    /// The model.
    pub model: Arc<DriveModel>,
    /// What to open.
    pub target: Target,
    /// Modes, in order.
    pub modes: Vec<Mode>,
    /// The line.
    pub line: LineSettings,
    /// Whether it is the simulator.
    pub is_sim: bool,
    /// An address no device has.
    pub other_address: u8,
}

/// The `--model` value that asks for the model to be found by `identify` first.
pub const AUTO: &str = "auto";

/// The target resolved without a model: what to open, the modes and the line.
pub struct Link {
    /// The model named by `--sim` or `--model`, if any (`auto` included).
    pub named: Option<String>,
    /// What to open.
    pub target: Target,
    /// Modes, in order.
    pub modes: Vec<Mode>,
    /// The line.
    pub line: LineSettings,
    /// Whether it is the simulator.
    pub is_sim: bool,
}

impl TargetArgs {
    /// Creates the `--capture` file, if one was asked for.
    pub fn open_capture(&self) -> anyhow::Result<Option<SharedRecorder>> {
        open_capture(self.capture.as_deref())
    }

    /// Says on stderr what the capture holds, or why it stopped.
    pub fn close_capture(&self, rec: Option<&SharedRecorder>) {
        close_capture(self.capture.as_deref(), rec);
    }

    /// The node address (the first, where `check` was given several).
    pub fn address(&self) -> u8 {
        self.nodes.first()
    }

    /// Whether `--model auto` was given: the model is identified from the device first.
    pub fn model_is_auto(&self) -> bool {
        self.model.as_deref() == Some(AUTO)
    }

    /// What to open, the modes and the line, without loading a model; `fallback` gives a
    /// target where none is named (for `--list`).
    pub fn resolve_link(
        &self,
        fallback: bool,
        sim_delay: Option<Duration>,
    ) -> anyhow::Result<Link> {
        self.line.rts.needs_port(self.port.as_deref())?;
        if self.nodes.0.len() > 1 && !self.several_nodes {
            bail!(
                "-a {}: this command talks to one node; several drives on one bus are for `check` (-a 1,2,5)",
                self.nodes.0.iter().map(|n| n.to_string()).collect::<Vec<_>>().join(",")
            );
        }
        let (named, target) = match (&self.sim, &self.port, &self.tcp) {
            (Some(m), None, None) => {
                if m.is_empty() && self.model_file.is_none() {
                    bail!("--sim needs a MODEL (f510, a510, l510, e510, l510-legacy), or --model-file FILE");
                }
                if let Some(other) = &self.model {
                    if other != m && other != AUTO && !m.is_empty() {
                        bail!("--sim {m} and --model {other} name different models");
                    }
                }
                (
                    Some(m.clone()),
                    Target::Sim {
                        quirks: self.quirks.clone(),
                        pace: !self.no_pace,
                        delay: sim_delay,
                        log: self.sim_log.clone(),
                    },
                )
            }
            (None, Some(p), None) => (
                self.model.clone(),
                Target::Serial {
                    path: p.clone(),
                    rts: self.line.rts.control(),
                },
            ),
            (None, None, Some(a)) => (self.model.clone(), self.tcp_target(a)?),
            _ if fallback => (
                Some(self.model.clone().unwrap_or_else(|| "f510".into())),
                Target::Sim {
                    quirks: vec![],
                    pace: true,
                    delay: None,
                    log: None,
                },
            ),
            _ => bail!(
                "say what to talk to: --sim MODEL, or --model MODEL with --port PATH or --tcp HOST:PORT"
            ),
        };
        let is_sim = matches!(target, Target::Sim { .. });
        let modes = match self.mode.unwrap_or(if is_sim {
            ModesArg::Both
        } else {
            ModesArg::Rtu
        }) {
            ModesArg::Rtu => vec![Mode::Rtu],
            ModesArg::Ascii => vec![Mode::Ascii],
            ModesArg::Both => vec![Mode::Rtu, Mode::Ascii],
        };
        if matches!(target, Target::Mbap { .. }) && modes.contains(&Mode::Ascii) {
            bail!("{MBAP_NOT_ASCII}");
        }
        let line = self.line.settings();
        if modes.contains(&Mode::Rtu) && line.data_bits != 8 {
            bail!("RTU needs 8 data bits (-d 8)");
        }
        Ok(Link {
            named,
            target,
            modes,
            line,
            is_sim,
        })
    }

    /// The model, target, modes and line; `fallback` gives a target where none is named
    /// (for `--list`).
    pub fn resolve(&self, fallback: bool, sim_delay: Option<Duration>) -> anyhow::Result<Resolved> {
        let link = self.resolve_link(fallback, sim_delay)?;
        let model_id = match (&link.named, &link.target) {
            _ if self.model_is_auto() => bail!(
                "--model auto is for `check` (it runs `identify` first); give the model (f510, a510, l510, e510, l510-legacy)"
            ),
            (Some(m), _) => m.clone(),
            // The description names its model: its id is taken from the file.
            (None, _) if self.model_file().is_some() => {
                let model = self.load_file_model()?;
                return self.resolve_with(link, model);
            }
            (None, Target::Tcp { .. }) => {
                bail!("--tcp needs --model (f510, a510, l510, e510, l510-legacy) or --model-file FILE")
            }
            (None, _) => bail!(
                "--port needs --model (f510, a510, l510, e510, l510-legacy) or --model-file FILE"
            ),
        };
        self.resolve_as(link, &model_id)
    }

    /// The one `--model-file` of a command that takes one; an error where it was given
    /// several times (only `identify` takes several).
    pub fn model_file(&self) -> Option<&std::path::Path> {
        self.model_file
            .as_deref()
            .and_then(|f| f.first())
            .map(PathBuf::as_path)
    }

    /// The `--model-file` given, refused where it was given more than once.
    fn load_file_model(&self) -> anyhow::Result<DriveModel> {
        let files = self.model_file.as_deref().unwrap_or_default();
        if files.len() > 1 {
            bail!(
                "--model-file is given {} times: this command takes one description (identify takes several, as candidates)",
                files.len()
            );
        }
        load_model("", self.model_file(), self.address())
    }

    /// [`TargetArgs::resolve`] with the model `model_id` (an identified one) for `link`.
    pub fn resolve_as(&self, link: Link, model_id: &str) -> anyhow::Result<Resolved> {
        let model = match self.model_file() {
            Some(_) => self.load_file_model()?,
            None => load_model(model_id, None, self.address())?,
        };
        self.resolve_with(link, model)
    }

    /// [`TargetArgs::resolve`] with `model`, loaded, for `link`.
    fn resolve_with(&self, link: Link, model: DriveModel) -> anyhow::Result<Resolved> {
        let Link {
            target,
            modes,
            line,
            is_sim,
            ..
        } = link;
        let model = Arc::new(model);
        let nodes = &self.nodes.0;
        // The highest address the model allows that no node of the run has.
        let other_address = match self.other_address {
            Some(a) => a,
            None => (1..=*model.addresses.end())
                .rev()
                .find(|a| !nodes.contains(a))
                .unwrap_or(0),
        };
        if nodes.contains(&other_address) || other_address == 0 {
            bail!("--other-address must differ from the device's address (every node of -a) and from 00 (broadcast)");
        }
        Ok(Resolved {
            model,
            target,
            modes,
            line,
            is_sim,
            other_address,
        })
    }

    /// The TCP target: raw frames, or Modbus TCP with its unit id.
    fn tcp_target(&self, addr: &str) -> anyhow::Result<Target> {
        match self.framing.unwrap_or(Framing::Rtu) {
            Framing::Rtu => {
                if self.unit.is_some() {
                    bail!("--unit is the unit id of Modbus TCP: it needs --framing mbap");
                }
                Ok(Target::Tcp { addr: addr.into() })
            }
            Framing::Mbap => {
                if self.unit.is_some() && self.nodes.0.len() > 1 {
                    bail!("--unit maps one node to a unit id; with several nodes (-a 1,2,5) each node's unit id is its address: leave --unit out");
                }
                let unit = self.unit.unwrap_or(self.address());
                if unit == 0 {
                    bail!("--unit 0 is the broadcast unit id of a Modbus TCP gateway: no device answers it; give the device's unit id (default: the node address -a)");
                }
                if self.echo == EchoMode::On {
                    bail!("--echo on: a Modbus TCP gateway does not echo requests (the echo of a 2-wire line stays behind it); use --echo auto or off");
                }
                Ok(Target::Mbap {
                    addr: addr.into(),
                    unit,
                })
            }
        }
    }

    /// The master's timing. A `--silence` given is used as it is; otherwise the silence
    /// window is derived from the device's measured response time, at most the timeout
    /// (`is_sim` and `sim_silence` no longer change it: the derived window is shorter).
    pub fn timing(&self, is_sim: bool, sim_silence: u64) -> MasterTiming {
        let _ = (is_sim, sim_silence);
        let line = self.line.settings();
        MasterTiming {
            timeout: Duration::from_millis(self.timeout),
            silence: Duration::from_millis(self.silence.unwrap_or(self.timeout)),
            derive_silence: self.silence.is_none(),
            quiet: Duration::from_millis(30),
            gap: Duration::from_millis(5).max(Duration::from_micros(line.t3_5_us())),
            retries: self.retries,
        }
    }

    /// The session of a command that talks to one link in one mode with the runner's
    /// usual allowances and no checks of its own (`send`, `watch`, `params`): the nodes of
    /// `bus` (the first is the one addressed), writes only where `read_only` is false,
    /// never motion or a restart.
    pub fn plain_session(
        &self,
        resolved: Resolved,
        mode: Mode,
        bus: Vec<u8>,
        read_only: bool,
    ) -> anyhow::Result<conformance::session::SessionConfig> {
        let Resolved {
            model,
            target,
            line,
            is_sim,
            other_address,
            ..
        } = resolved;
        let options = conformance::runner::Options {
            address: bus.first().copied().unwrap_or(1),
            bus,
            other_address,
            read_only,
            allow_motion: false,
            only: Vec::new(),
            timing: self.timing(is_sim, 300),
            response_allowance: Duration::from_millis(20),
            gap_allowance: Duration::from_millis(20),
            seed: 0,
            echo: self.echo,
            line: Some(self.line.settings()),
            allow_restart: false,
            injected_stalls: None,
        };
        Ok(conformance::session::SessionConfig {
            model,
            target,
            modes: vec![mode],
            line,
            options,
            capture: self.open_capture()?,
        })
    }

    /// The option that names the model again: the description file where one was given
    /// (a model it describes is no built-in), else `--model ID`.
    fn model_option(&self, model: &str) -> String {
        match self.model_file() {
            Some(f) => format!("--model-file {}", f.display()),
            None => format!("--model {model}"),
        }
    }

    /// The options that name this target again, for a replay command line.
    pub fn replay_prefix(&self, command: &str, model: &str) -> String {
        let mut s = format!("conformance {command}");
        match (&self.sim, &self.port, &self.tcp) {
            // A bare --sim serves the description given.
            (Some(m), _, _) if m.is_empty() => {
                s.push_str(&format!(" --sim {}", self.model_option(model)))
            }
            (Some(m), _, _) => {
                s.push_str(&format!(" --sim {m}"));
                for q in &self.quirks {
                    s.push_str(&format!(" --quirk {q}"));
                }
                if self.no_pace {
                    s.push_str(" --no-pace");
                }
                if let Some(f) = self.model_file() {
                    s.push_str(&format!(" --model-file {}", f.display()));
                }
            }
            (_, Some(p), _) => s.push_str(&format!(" {} --port {p}", self.model_option(model))),
            (_, _, Some(t)) => {
                s.push_str(&format!(" {} --tcp {t}", self.model_option(model)));
                if self.framing == Some(Framing::Mbap) {
                    s.push_str(&format!(
                        " --framing mbap --unit {}",
                        self.unit.unwrap_or(self.address())
                    ));
                }
            }
            _ => {}
        }
        let l = &self.line;
        s.push_str(&format!(
            " -b {} -P {} -d {} -s {} -a {}",
            l.baud,
            format!("{:?}", l.parity).to_lowercase(),
            l.data_bits,
            l.stop_bits,
            self.address()
        ));
        s
    }
}

#[cfg(test)]
mod model_file_tests {
    use super::*;
    use clap::Parser;

    #[derive(Debug, Parser)]
    struct T {
        #[command(flatten)]
        target: TargetArgs,
    }

    fn target(args: &[&str]) -> TargetArgs {
        T::parse_from(std::iter::once("t").chain(args.iter().copied())).target
    }

    #[test]
    fn a_replay_names_the_description_not_its_id() {
        let t = target(&["--model-file", "x100.json", "--port", "/dev/ttyUSB0"]);
        assert_eq!(
            t.replay_prefix("send", "acme-x100"),
            "conformance send --model-file x100.json --port /dev/ttyUSB0 -b 9600 -P even -d 8 -s 1 -a 1"
        );
        let t = target(&["--sim", "f510", "--model-file", "x100.json"]);
        assert!(t
            .replay_prefix("send", "acme-x100")
            .starts_with("conformance send --sim f510 --model-file x100.json -b"));
        let t = target(&["--model", "f510", "--tcp", "h:1"]);
        assert!(t
            .replay_prefix("send", "f510")
            .starts_with("conformance send --model f510 --tcp h:1 -b"));
    }
}
