//! `conformance bus`: an emulated multi-drop RS-485 line with pseudo-terminals for
//! masters, listeners and devices, and simulated drives on it.

use std::fs::File;
use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::Ordering;
use std::sync::Arc;
use std::time::{Duration, Instant};

use anyhow::{bail, Context};
use clap::Args;
use conformance::codec::Mode;
use conformance::line::{EmulatedLine, Endpoint, LineConfig, LineLog};
use conformance::sim::{serve, Bus, PlantedQuirk, TrafficLog, QUIRK_HELP};

use super::common::{load_model, parse_nodes, LineArgs, ModeArg, NodeList};

fn bus_help() -> String {
    let mut s = String::from(
        "Endpoints and names: the pseudo-terminals are endpoints 0..N-1, named by their number.\n\
         Each --link NAME=PATH names the next endpoint not yet named (the first --link is\n\
         endpoint 0, the second endpoint 1, ...) and makes PATH a symbolic link to it; a NAME\n\
         that is a number links that endpoint and keeps its number as its name. Simulated\n\
         drives (-a) are endpoints after those, named drive<NODE> (drive1, drive5). One line\n\
         per pseudo-terminal on stdout, in endpoint order: NAME PTY-PATH [LINK-PATH].\n\n\
         The line: every byte written on an endpoint reaches every other endpoint when its\n\
         last bit is in, at the line's character time (-b -P -d -s); the writer does not hear\n\
         itself (an RS-485 transceiver's receiver is off while it drives; --echo NAME turns it\n\
         on for one endpoint, as on two-wire adapters that echo). Two endpoints writing at\n\
         once collide: listeners get the wired-AND of both bit streams, as a UART reads it\n\
         (other bytes, parity and framing errors), and the log records who collided and\n\
         for how long. --noise flips bits driven on the line, reproducibly by --seed.\n\
         --no-pace: bytes go through at once (a plain N-way bridge, no collisions).\n\
         --emulate-line: each pseudo-terminal endpoint hears the line as a UART at the\n\
         settings its program set would (a listener at another baud rate or parity hears\n\
         garbage; `monitor` with no -b finds the line's settings this way, as on copper).\n\
         An endpoint nobody reads keeps what it was sent (the pseudo-terminal buffers it)\n\
         until its buffer is full; then bytes for it are dropped (logged as an overrun).\n\n",
    );
    s.push_str("Fault injection on the simulated drives (--quirk, as simulate):\n");
    for (q, what) in QUIRK_HELP {
        s.push_str(&format!("  {q:<22} {what}\n"));
    }
    s.push_str("  QUIRK@NODE             on that node only (dead@2, slow=40@5)\n");
    s.push_str(
        "\nExamples:\n  \
         conformance bus --link master=/tmp/master --link tap=/tmp/tap --model f510 -a 1\n    \
         a master, a listener and a simulated F510 on one 9600 8E1 line:\n    \
         mbpoll -m rtu -b 9600 -P even -a 1 -t 4:hex -r 9520 -1 /tmp/master\n  \
         conformance bus -n 3 --link a=/tmp/a --link b=/tmp/b --log bus.jsonl --duration 60s\n  \
         conformance bus --link m=/tmp/m --model f510 -a 1,2,5 --quirk answer-every-address@2\n    \
         (nodes 1 and 5 and 2 answer at once: a collision on every request)\n  \
         conformance bus -n 2 --noise 1e-3 --seed 7 --log noisy.jsonl\n  \
         conformance bus -n 2 --no-pace   (a bridge, like socat pty pty)\n  \
         conformance bus --link m=/tmp/m --link tap=/tmp/tap -a 1 -b 19200 -P odd --emulate-line\n    \
         then `conformance monitor --port /tmp/tap --model f510` finds 19200 8O1 by listening\n",
    );
    s.push_str(
        "\nLog (--log FILE, JSON lines): start (line, endpoints), tx (from, hex, t_us and each\n\
         character's at_us: the line's schedule, us since start), collision (endpoints, t_us,\n\
         end_us, chars, line_hex), noise (from, byte, bit), damaged (a character read with a\n\
         flipped bit or an error), overrun (to), settings (--emulate-line: endpoint, line,\n\
         hears), stop (totals).\n",
    );
    s.push_str(
        "\nExit codes: 0 stopped by Ctrl-C, SIGTERM or --duration (links removed); 2 could not\n\
         run (arguments, a pseudo-terminal, a link, the log) or a simulated drive failed.",
    );
    s
}

/// One `--link NAME=PATH`.
#[derive(Debug, Clone)]
pub struct LinkArg {
    name: String,
    path: PathBuf,
}

fn parse_link(text: &str) -> Result<LinkArg, String> {
    let (name, path) = text
        .split_once('=')
        .ok_or_else(|| format!("{text:?}: expected NAME=PATH (master=/tmp/master)"))?;
    if name.is_empty() || name.chars().any(|c| c.is_whitespace() || c == '=') {
        return Err(format!(
            "{name:?}: an endpoint name is one word without '=' (master, tap, 0)"
        ));
    }
    if path.is_empty() {
        return Err(format!("{text:?}: no path after '='"));
    }
    Ok(LinkArg {
        name: name.to_string(),
        path: PathBuf::from(path),
    })
}

#[derive(Debug, Args)]
#[command(after_help = bus_help())]
pub struct BusArgs {
    /// Pseudo-terminals to make (default: one per --link, at least 2).
    #[arg(short = 'n', long, value_name = "N")]
    endpoints: Option<usize>,
    /// Name an endpoint and link PATH to its pseudo-terminal (see "Endpoints and names"
    /// below). Repeatable.
    #[arg(long = "link", value_name = "NAME=PATH", value_parser = parse_link)]
    links: Vec<LinkArg>,
    /// Local echo on endpoint NAME: it hears its own bytes. Repeatable.
    #[arg(long = "echo", value_name = "NAME")]
    echo: Vec<String>,
    #[command(flatten)]
    line: LineArgs,
    /// Probability that a bit driven on the line flips (0 to 1; 1e-4 is one a ~900
    /// characters at 8E1).
    #[arg(long, value_name = "RATE", default_value_t = 0.0)]
    noise: f64,
    /// Seed of the noise.
    #[arg(long, value_name = "N", default_value_t = 1)]
    seed: u64,
    /// Bytes go through at once: no character time, no collisions.
    #[arg(long)]
    no_pace: bool,
    /// Each pseudo-terminal endpoint hears the line through a UART at the settings its
    /// program set on its port, as a real one would: a listener at another baud rate or
    /// parity hears garbage and errors. A pty carries the baud rate, stop bits, PARODD and
    /// the input flags, not PARENB or the data bits: even parity is read from INPCK (set
    /// with parity by serialport-rs and libmodbus, not by pyserial), and the data bits
    /// are the line's. Endpoints send at the line's settings.
    #[arg(long, conflicts_with = "no_pace")]
    emulate_line: bool,
    /// Stop after this long (a bare number is seconds: 90; or 30s, 5min); default: until
    /// Ctrl-C or SIGTERM.
    #[arg(long, value_name = "T", value_parser = super::common::parse_duration)]
    duration: Option<Duration>,
    /// Write the line's log as JSON lines to this file.
    #[arg(long, value_name = "FILE")]
    log: Option<PathBuf>,
    /// Record the line as a pcapng capture: one interface per endpoint with what it sent,
    /// one for what listeners read from collisions and damaged characters; frames under
    /// the link type of --mode (147 RTU, 148 ASCII).
    #[arg(long, value_name = "FILE.pcapng")]
    capture: Option<PathBuf>,
    /// No log on stderr.
    #[arg(short, long)]
    quiet: bool,
    /// Simulated drives of this model on the line (f510, a510, l510, e510, l510-legacy);
    /// with -a, f510 by default.
    #[arg(long)]
    model: Option<String>,
    /// Read the model of the simulated drives from this file.
    #[arg(long, value_name = "FILE")]
    model_file: Option<PathBuf>,
    /// Node addresses of the simulated drives (1,2,5 or 1-4; decimal, or hex with H or
    /// 0x); each is an endpoint of its own. With --model alone: 1.
    #[arg(short = 'a', long = "address", value_name = "N[,N..]", value_parser = parse_nodes)]
    nodes: Option<NodeList>,
    /// Transmission mode of the simulated drives.
    #[arg(short = 'm', long, value_enum, default_value = "rtu")]
    mode: ModeArg,
    /// Response delay of the simulated drives in milliseconds (default: the model's, or
    /// t3.5 where that is longer).
    #[arg(long, value_name = "MS")]
    delay: Option<u64>,
    /// Fault injection on the simulated drives; see below. QUIRK@NODE: that node only.
    #[arg(long = "quirk", value_name = "QUIRK")]
    quirks: Vec<PlantedQuirk>,
}

/// Symbolic links made for the endpoints, removed when the command ends.
struct Links(Vec<PathBuf>);

impl Links {
    fn make(&mut self, target: &std::path::Path, link: &std::path::Path) -> anyhow::Result<()> {
        super::common::point_link(
            link,
            target,
            "a file that is not a symbolic link is there; not replaced",
            "the link",
        )?;
        self.0.push(link.to_path_buf());
        Ok(())
    }
}

impl Drop for Links {
    fn drop(&mut self) {
        for l in &self.0 {
            let _ = std::fs::remove_file(l);
        }
    }
}

/// The pseudo-terminal endpoints' names and links, by the rule in the help.
fn name_endpoints(
    n: Option<usize>,
    links: &[LinkArg],
) -> anyhow::Result<Vec<(String, Option<PathBuf>)>> {
    let n = n.unwrap_or(links.len().max(2));
    if n == 0 {
        bail!("--endpoints 0: a line needs at least one pseudo-terminal");
    }
    let mut out: Vec<(Option<String>, Option<PathBuf>)> = vec![(None, None); n];
    for l in links {
        if let Ok(k) = l.name.parse::<usize>() {
            let slot = out
                .get_mut(k)
                .with_context(|| format!("--link {k}=...: there are endpoints 0..{}", n - 1))?;
            if slot.1.is_some() {
                bail!("--link {k}=...: endpoint {k} is linked twice");
            }
            slot.1 = Some(l.path.clone());
        }
    }
    for l in links.iter().filter(|l| l.name.parse::<usize>().is_err()) {
        let Some(slot) = out.iter_mut().find(|s| s.0.is_none() && s.1.is_none()) else {
            bail!(
                "--link {}=...: {} links for {n} endpoints (give --endpoints)",
                l.name,
                links.len()
            );
        };
        *slot = (Some(l.name.clone()), Some(l.path.clone()));
    }
    Ok(out
        .into_iter()
        .enumerate()
        .map(|(i, (name, path))| (name.unwrap_or_else(|| i.to_string()), path))
        .collect())
}

pub fn run(args: BusArgs) -> anyhow::Result<ExitCode> {
    if args.line.rts.rts {
        bail!("--rts drives a serial port's RTS line; the emulated line has none");
    }
    let line = args.line.settings();
    let mode: Mode = args.mode.into();
    let paced = !args.no_pace;
    let config = LineConfig {
        line,
        paced,
        noise: args.noise,
        seed: args.seed,
        emulate: args.emulate_line,
    };
    let names = name_endpoints(args.endpoints, &args.links)?;
    let mut endpoints = Vec::new();
    for (name, _) in &names {
        let e = Endpoint::pty(name)?;
        endpoints.push(if args.emulate_line {
            e.with_line_emulation(line)?
        } else {
            e
        });
    }

    // Simulated drives: one endpoint each, so that two of them answering at once collide.
    let mut drives = Vec::new();
    let want_drives = args.model.is_some() || args.model_file.is_some() || args.nodes.is_some();
    if want_drives {
        let nodes = args.nodes.clone().unwrap_or(NodeList(vec![1]));
        if mode == Mode::Rtu && line.data_bits != 8 {
            bail!("RTU needs 8 data bits (-d 8)");
        }
        let model_id = args.model.as_deref().unwrap_or("f510");
        let model = Arc::new(load_model(
            model_id,
            args.model_file.as_deref(),
            nodes.first(),
        )?);
        let delay = match args.delay {
            Some(ms) => Duration::from_millis(ms),
            None => model.response_delay(&line),
        };
        conformance::sim::bus::check_planted(&args.quirks, &nodes.0)?;
        for &n in &nodes.0 {
            let planted: Vec<PlantedQuirk> = args
                .quirks
                .iter()
                .filter(|p| p.node.is_none_or(|q| q == n))
                .copied()
                .collect();
            let bus = Bus::of_model(&model, &[n], delay, &planted, line, paced)?;
            let quirks: Vec<String> = planted.iter().map(|q| q.quirk.to_string()).collect();
            let device = format!(
                "{} node {n:02X}H, {mode}{}",
                model.id,
                if quirks.is_empty() {
                    String::new()
                } else {
                    format!(", quirks: {}", quirks.join(" "))
                }
            );
            let (endpoint, station) =
                Endpoint::station(&format!("drive{n}"), &device, paced.then_some(line))?;
            endpoints.push(endpoint);
            drives.push((n, bus, station));
        }
    }
    for e in &args.echo {
        if !endpoints.iter().any(|x| x.name() == e) {
            bail!("--echo {e}: no endpoint of that name");
        }
    }
    let endpoints: Vec<Endpoint> = endpoints
        .into_iter()
        .map(|x| {
            let echo = args.echo.iter().any(|e| e == x.name());
            x.with_echo(echo)
        })
        .collect();
    let mut emulated = EmulatedLine::new(config, endpoints)?;

    // Before the paths are printed: a script may signal the bus as soon as it has them.
    // (The one handler of every long command: Ctrl-C, SIGTERM and SIGHUP set this flag.)
    let stop = super::interrupt::stop_flag_saying(super::interrupt::Stopping::Bus)?;
    let mut links = Links(Vec::new());
    let mut out = std::io::stdout();
    for (e, (_, link)) in emulated.endpoints().iter().zip(&names) {
        let Some(path) = e.path() else { continue };
        match link {
            Some(l) => {
                links.make(path, l)?;
                writeln!(out, "{} {} {}", e.name(), path.display(), l.display())?;
            }
            None => writeln!(out, "{} {}", e.name(), path.display())?,
        }
    }
    out.flush()?;

    let mut log = LineLog::new();
    if !args.quiet {
        log = log.with_text(Box::new(std::io::stderr()));
    }
    if let Some(path) = &args.log {
        let file = File::create(path)
            .with_context(|| format!("cannot create the log file {}", path.display()))?;
        log = log.with_json(Box::new(std::io::BufWriter::new(file)));
    }
    if let Some(path) = &args.capture {
        let file = File::create(path)
            .with_context(|| format!("cannot create the capture {}", path.display()))?;
        log = log
            .with_capture(Box::new(file), mode)
            .with_context(|| format!("cannot write the capture {}", path.display()))?;
    }

    let threads: Vec<_> = drives
        .into_iter()
        .map(|(n, mut bus, mut station)| {
            let stop = stop.clone();
            std::thread::Builder::new()
                .name(format!("drive{n}"))
                .spawn(move || {
                    let r = serve(&mut station, &mut bus, mode, &mut TrafficLog::new(), &stop);
                    // A drive that fails stops the line: its endpoint would be dead.
                    stop.store(true, Ordering::Relaxed);
                    r.map_err(|e| anyhow::anyhow!("simulated drive at node {n}: {e}"))
                })
        })
        .collect::<Result<_, _>>()
        .context("cannot start a simulated drive")?;

    let until = args.duration.map(|d| Instant::now() + d);
    let result = emulated.run(&mut log, &stop, until);
    stop.store(true, Ordering::Relaxed);
    let mut failed = None;
    for t in threads {
        match t.join() {
            Ok(Ok(_)) => {}
            Ok(Err(e)) => failed = failed.or(Some(e)),
            Err(_) => failed = failed.or(Some(anyhow::anyhow!("a simulated drive panicked"))),
        }
    }
    drop(links);
    result?;
    if let Some(e) = failed {
        return Err(e);
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn links(v: &[&str]) -> Vec<LinkArg> {
        v.iter().map(|t| parse_link(t).unwrap()).collect()
    }

    #[test]
    fn names_follow_the_links_in_order_and_numbers_keep_theirs() {
        let n = name_endpoints(None, &links(&["master=/tmp/m", "tap=/tmp/t"])).unwrap();
        assert_eq!(
            n,
            [
                ("master".into(), Some("/tmp/m".into())),
                ("tap".into(), Some("/tmp/t".into()))
            ]
        );
        let n = name_endpoints(Some(4), &links(&["1=/tmp/one", "m=/tmp/m", "t=/tmp/t"])).unwrap();
        let got: Vec<&str> = n.iter().map(|(s, _)| s.as_str()).collect();
        assert_eq!(got, ["m", "1", "t", "3"]);
        assert_eq!(n[1].1.as_deref(), Some(std::path::Path::new("/tmp/one")));
        assert_eq!(name_endpoints(None, &[]).unwrap().len(), 2);
        assert!(name_endpoints(Some(1), &links(&["a=/x", "b=/y"])).is_err());
        assert!(name_endpoints(Some(2), &links(&["5=/x"])).is_err());
        assert!(parse_link("noequals").is_err());
        assert!(parse_link("a b=/x").is_err());
        assert!(parse_link("a=").is_err());
    }
}
