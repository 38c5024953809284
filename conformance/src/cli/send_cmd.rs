//! `conformance send`: sends raw frames given in hex to a device and prints what comes
//! back, with arrival times and what the model predicts. The fuzzer's reproducers are
//! command lines of this command; it is useful on its own for field debugging.

use std::io::Write;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::{bail, Context};
use clap::Args;
use conformance::codec::crc::crc16_frame_ok;
use conformance::codec::hex::{parse_hex, Hex};
use conformance::codec::Mode;
use conformance::judge::{describe_reply, explain_invalid, show};
use conformance::runner::Master;
use conformance::session::{self, SessionConfig};

use super::link::TargetArgs;

const AFTER_HELP: &str = "\
Examples:
  conformance send --sim f510 --mode rtu '010325200001 8ECC'      one frame (spaces are free
                                                   inside one quoted argument)
  conformance send --sim f510 --mode rtu 0103252000018ECC 010325210001DF0C   two frames
  conformance send --model f510 --port /dev/ttyUSB0 -b 9600 -P even --mode ascii ':010325200001B6\\r\\n'
  conformance send --sim f510 --quirk overflow-after=3 --mode rtu --burst F1 F2 F3 F4
  conformance send --sim f510 --mode rtu --split 3 --gap 2900us 0103252000018ECC
  conformance send --model f510 --tcp 10.0.0.8:502 --framing mbap 0103252000018ECC
                    (an RTU frame, sent as its PDU in MBAP; its CRC must be valid)

Each argument is one frame: hex bytes (RTU, or ASCII characters in hex), spaces free inside
it (quote it), or in ASCII mode the text itself from ':' with \\r and \\n written as
escapes. Frames are sent as given (the checksum is not fixed), each after t3.5 of silence;
with --burst all in one write, back to back. With --split POS[,POS...] --gap TIME the
frames go out as one transmission cut after byte POS (counted over all the frames) with
TIME of silence at each cut: timing damage, on a link with line timing only (a real port,
or the simulator without --no-pace). The model
predicts by the silence: under t1.5 one frame; between t1.5 and t3.5 an incomplete frame
(silence); t3.5 or more, fragments judged one by one; frames cut only where they end, with
less than t3.5, one frame with a wrong CRC (silence; a decision of the model).

Exit codes: 0 every answer was the model's prediction; 1 an answer differed; 2 the
frames or the link could not be used.";

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct SendArgs {
    #[command(flatten)]
    target: TargetArgs,
    /// Send all frames in one write, without t3.5 between them.
    #[arg(long, conflicts_with = "split")]
    burst: bool,
    /// Cut the transmission after these byte positions (counted over all the frames,
    /// which go out as one transmission), with --gap of silence at each cut.
    #[arg(long, value_name = "POS,...", value_delimiter = ',', requires = "gap")]
    split: Vec<usize>,
    /// The silence at each --split cut, with a unit (2900us, 3ms; a bare number is
    /// seconds, as in every duration option).
    #[arg(long, value_name = "TIME", requires = "split", value_parser = super::common::parse_duration)]
    gap: Option<Duration>,
    /// The frames, one per argument (spaces inside a quoted argument are free).
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

/// A note for each pair of arguments that are two bad RTU frames but one good one
/// together: most likely one frame written with a space and not quoted. They are still
/// sent as given (a replayed sequence may mean it).
fn split_frame_notes(texts: &[String], frames: &[Vec<u8>]) -> Vec<String> {
    let mut notes = Vec::new();
    for i in 1..frames.len() {
        let (a, b) = (&frames[i - 1], &frames[i]);
        let joined: Vec<u8> = a.iter().chain(b).copied().collect();
        if !crc16_frame_ok(a) && !crc16_frame_ok(b) && crc16_frame_ok(&joined) {
            notes.push(format!(
                "note: arguments {i} and {} ({} and {}) are each a frame with a wrong CRC, but one frame with a good CRC together: each argument is one frame; to send one, quote it as one argument ('{} {}')",
                i + 1,
                texts[i - 1].trim(),
                texts[i].trim(),
                texts[i - 1].trim(),
                texts[i].trim()
            ));
        }
    }
    notes
}

pub fn run(args: SendArgs) -> anyhow::Result<ExitCode> {
    let resolved = args.target.resolve(false, None)?;
    let (model, mode) = (resolved.model.clone(), resolved.modes[0]);
    if args.burst && matches!(resolved.target, session::Target::Mbap { .. }) {
        bail!("--burst sends frames back to back without t3.5 between them: line timing that a Modbus TCP gateway does not carry (--framing mbap sends one PDU at a time)");
    }
    let mut frames = Vec::new();
    for f in &args.frames {
        frames.push(parse_frame(mode, f)?);
    }
    if frames.is_empty() {
        bail!("no frame to send");
    }
    if mode == Mode::Rtu {
        for note in split_frame_notes(&args.frames, &frames) {
            eprintln!("{note}");
        }
    }
    let config = args
        .target
        .plain_session(resolved, mode, vec![args.target.address()], true)?;
    let (_sim, transport) = session::open(&config, mode)?;
    let mut out = std::io::stdout().lock();
    writeln!(out, "link: {}", transport.describe())?;
    let mut master =
        Master::new(transport, mode, config.options.timing).with_echo(args.target.echo);
    if let Some(gap) = args.gap {
        return send_split(
            &mut out,
            &mut master,
            &model,
            &config,
            &frames,
            &args.split,
            gap,
        );
    }
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
        for note in &ex.link_notes {
            writeln!(out, "link: {note}")?;
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
            let c = conformance::judge::Judge::new(&model).differences(
                &j,
                &ex.conversation(mode, config.options.address),
                None,
            );
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

/// `--split --gap`: the frames as one transmission with silences at the cuts.
fn send_split(
    out: &mut impl Write,
    master: &mut Master<dyn conformance::transport::Transport>,
    model: &conformance::model::DriveModel,
    config: &SessionConfig,
    frames: &[Vec<u8>],
    cuts: &[usize],
    gap: Duration,
) -> anyhow::Result<ExitCode> {
    use conformance::fuzz::timing::{classify, predict_for, Timed};
    let Some(line) = master.transport().line_timing() else {
        bail!(
            "--split needs a link with line timing (a serial port, or the simulator without --no-pace): {} carries no silence the device can measure",
            master.transport().describe()
        );
    };
    let mode = master.mode();
    let whole = frames.concat();
    if let Some(c) = cuts.iter().find(|&&c| c == 0 || c >= whole.len()) {
        bail!(
            "--split {c}: a cut must fall inside the {} bytes sent",
            whole.len()
        );
    }
    let gap_us = u64::try_from(gap.as_micros()).unwrap_or(u64::MAX);
    let t = Timed {
        damage: classify(&line, frames, cuts, gap_us),
        frames: frames.to_vec(),
        cuts: cuts.to_vec(),
        gap_us,
        // The host must keep the silence within a fifth of it (at least 100 us).
        tolerance_us: (gap_us / 5).max(100),
    };
    let j = predict_for(model, config.options.address, mode, &t);
    writeln!(
        out,
        "model: {} cut after {:?} with {} us of silence (t1.5 = {} us, t3.5 = {} us: {}) -> {} ({})",
        show(mode, &whole),
        cuts,
        gap_us,
        line.t1_5_us(),
        line.t3_5_us(),
        t.damage.class(),
        j.expect.describe(),
        j.detail
    )?;
    let (ex, sent) = master.exchange_split(
        &whole,
        cuts,
        gap,
        Duration::from_micros(t.tolerance_us),
        j.expect.replies(),
    )?;
    let shown: Vec<String> = sent.iter().map(|g| format!("{}", g.as_micros())).collect();
    writeln!(
        out,
        "sent {} in {} pieces, silences as sent: {} us{}",
        show(mode, &whole),
        cuts.len() + 1,
        shown.join(", "),
        if master.broken_requests() > 0 {
            format!(
                " ({} send(s) repeated: the host moved a silence or stalled)",
                master.broken_requests()
            )
        } else {
            String::new()
        }
    )?;
    for c in &ex.chunks {
        writeln!(
            out,
            "  +{:.3} ms received {}",
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
    writeln!(out, "device: {answer}")?;
    let c = conformance::judge::Judge::new(model).differences(
        &j,
        &ex.conversation(mode, config.options.address),
        None,
    );
    for f in &c.findings {
        writeln!(out, "differs: {}", f.text)?;
    }
    if c.findings.is_empty() {
        writeln!(out, "as predicted")?;
    }
    Ok(ExitCode::from(if c.findings.is_empty() { 0 } else { 1 }))
}
