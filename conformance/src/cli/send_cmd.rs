//! `conformance send`: sends raw frames given in hex to a device and prints what comes
//! back, with arrival times and what the model predicts. The fuzzer's reproducers are
//! command lines of this command; it is useful on its own for field debugging.

use std::io::Write;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::Args;
use conformance::codec::hex::{parse_hex, Hex};
use conformance::codec::Mode;
use conformance::runner::compare::{describe_reply, explain_invalid, show};
use conformance::runner::{Master, Options};
use conformance::session::{self, SessionConfig};

use super::link::{Resolved, TargetArgs};

const AFTER_HELP: &str = "\
Examples:
  conformance send --sim f510 --mode rtu 010325200001 8ECC        (spaces are free)
  conformance send --sim f510 --mode rtu '01 03 25 20 00 01 8E CC'
  conformance send --model f510 --port /dev/ttyUSB0 -b 9600 -P even --mode ascii ':010325200001B6\\r\\n'
  conformance send --sim f510 --quirk overflow-after=3 --mode rtu --burst F1 F2 F3 F4

A frame is hex bytes (RTU, or ASCII characters in hex), or in ASCII mode the text itself
from ':' with \\r and \\n written as escapes. Frames are sent as given (the checksum is not
fixed), each after t3.5 of silence; with --burst all in one write, back to back.

Exit codes: 0 every answer was the model's prediction; 1 an answer differed; 2 the
frames or the link could not be used.";

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct SendArgs {
    #[command(flatten)]
    target: TargetArgs,
    /// Send all frames in one write, without t3.5 between them.
    #[arg(long)]
    burst: bool,
    /// The frames.
    #[arg(value_name = "FRAME", required = true)]
    frames: Vec<String>,
}

fn parse_frame(mode: Mode, text: &str) -> anyhow::Result<Vec<u8>> {
    let t = text.trim();
    if mode == Mode::Ascii && t.starts_with(':') {
        return Ok(t.replace("\\r", "\r").replace("\\n", "\n").into_bytes());
    }
    parse_hex(t).with_context(|| format!("{t:?} is not a frame in hex"))
}

pub fn run(args: SendArgs) -> anyhow::Result<ExitCode> {
    let Resolved {
        model,
        target,
        modes,
        line,
        is_sim,
        other_address,
    } = args.target.resolve(false, None)?;
    let mode = modes[0];
    let mut frames = Vec::new();
    for f in &args.frames {
        frames.push(parse_frame(mode, f)?);
    }
    if frames.is_empty() {
        bail!("no frame to send");
    }
    let options = Options {
        address: args.target.address,
        other_address,
        read_only: true,
        allow_motion: false,
        only: Vec::new(),
        timing: args.target.timing(is_sim, 300),
        response_allowance: Duration::from_millis(20),
        gap_allowance: Duration::from_millis(20),
        seed: 0,
        echo: args.target.echo,
        line: Some(args.target.line.settings()),
        allow_restart: false,
    };
    let config = SessionConfig {
        model: model.clone(),
        target,
        modes: vec![mode],
        line,
        options,
    };
    let (_sim, transport) = session::open(&config, mode)?;
    let mut out = std::io::stdout().lock();
    writeln!(out, "link: {}", transport.describe())?;
    let mut master =
        Master::new(transport, mode, config.options.timing).with_echo(args.target.echo);
    let sends: Vec<Vec<u8>> = if args.burst {
        vec![frames.concat()]
    } else {
        frames.clone()
    };
    let mut differs = false;
    let started = std::time::Instant::now();
    for (i, frame) in sends.iter().enumerate() {
        let judged: Vec<&Vec<u8>> = if args.burst {
            frames.iter().collect()
        } else {
            vec![frame]
        };
        let mut replies = false;
        for f in &judged {
            let j = model.judge(config.options.address, mode, f);
            replies |= j.expect.replies();
            writeln!(
                out,
                "model: {} -> {} ({})",
                show(mode, f),
                j.expect.describe(),
                j.detail
            )?;
        }
        let at = started.elapsed();
        let ex = master.exchange(frame, replies)?;
        writeln!(
            out,
            "[{:>9.3} ms] sent {}{}",
            at.as_secs_f64() * 1e3,
            show(mode, frame),
            if args.burst { " (back to back)" } else { "" }
        )?;
        for c in &ex.chunks {
            writeln!(
                out,
                "[{:>9.3} ms]   +{:.3} ms received {}",
                (at + c.at).as_secs_f64() * 1e3,
                c.at.as_secs_f64() * 1e3,
                Hex(&c.bytes)
            )?;
        }
        let answer = match &ex.reply {
            Some(r) => describe_reply(mode, r),
            None if ex.after_echo().is_empty() => {
                format!("no reply within {} ms", ex.listened.as_millis())
            }
            None => explain_invalid(mode, ex.after_echo()),
        };
        writeln!(
            out,
            "device: {answer}{}",
            if ex.echo {
                " (after the local echo)"
            } else {
                ""
            }
        )?;
        if !args.burst {
            let j = model.judge(config.options.address, mode, frame);
            let c = conformance::runner::compare::differences(&model, mode, &j, &ex, None);
            for f in &c.findings {
                differs = true;
                writeln!(out, "differs: {}", f.text)?;
            }
            if c.findings.is_empty() {
                writeln!(out, "as predicted")?;
            }
        }
        let _ = i;
    }
    Ok(ExitCode::from(if differs { 1 } else { 0 }))
}
