//! The brisk path: fuzzing fast on a link without timing, and the guard that keeps speed
//! from changing a verdict.
//!
//! A pseudo-terminal or a TCP connection has no line: no t3.5 to keep between frames and
//! no character time. What costs time there is listening: for trailing bytes after a reply
//! that is already whole, and for a reply that must not come (a silence window, then a
//! liveness probe). The brisk path listens less:
//!
//! - a whole reply ends the exchange at once (the master's brisk listening: no settle
//!   time for trailing bytes);
//! - after a frame the model predicts silence for and whose end the receiver can tell by
//!   itself ([`delimited`]: an RTU frame as long as its function code implies, with a valid
//!   CRC; an ASCII frame with one ':', which the probe's ':' ends at the latest), the
//!   liveness probe goes at once: the
//!   link keeps the order of bytes and a device answers its requests in order, so the
//!   probe's reply must be the next bytes back, and any byte before it is the device
//!   answering the silent frame (sequencing);
//! - after a frame the receiver can only end by a quiet time (a length field that
//!   disagrees with the frame), the probe waits twice the longest answer delay measured on
//!   such frames on this link (the receiver's quiet time is part of that delay), and the
//!   full silence window until one has been measured;
//! - frames back to back are followed, after twice the longest response delay measured,
//!   by a probe whose reply cannot be mistaken for theirs (it reads two registers, they
//!   read one), and nothing but that reply may come back.
//!
//! **The guard.** Speed must neither make nor hide a finding. Every byte that arrives when
//! nothing is awaited is counted: the master reads what is waiting before each request
//! ([`Master::take_stray`](crate::runner::Master::take_stray)). A case whose exchanges met
//! such bytes, whose probe did not come back clean, or that gave a difference a late byte
//! could have made (a mismatch, a reply where silence was due, a wrong value) is sent again
//! with full windows, after the case before it (whose late end the bytes may be), once the
//! device answers; only those careful verdicts count. A missing reply and a hang are not
//! repeated: they were waited for the whole timeout, as on the careful path. After the last
//! case a full silence window is waited for anything still to come.

use std::time::Duration;

use super::cases::Step;
use super::observe::observe as observe_careful;
use super::state::{recover, Observed, State};
use crate::codec::crc::crc16;
use crate::codec::deframe::rtu_frame_len;
use crate::codec::pdu::{Direction, Pdu};
use crate::codec::{frame_parts, Mode, MAX_ASCII_FRAME};
use crate::model::Expectation;
use crate::runner::liveness::liveness_register;
use crate::runner::{Ctx, RunError};

/// The longest wait of the brisk path before a probe. The waits are twice a longest
/// delay measured, and one outlier (a host that stalled once under load) slows every later
/// case: in a 20,000-case run (l510, ASCII) every later burst slept for seconds before
/// this cap; a wait that is too short
/// costs a rerun with full windows, never a verdict. Measured here: the simulator's
/// framing delay on an unpaced pseudo-terminal, 1.6 ms on two busy cores.
pub const MAX_BRISK_WAIT: Duration = Duration::from_millis(10);

/// What the brisk path did in one mode.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GuardStats {
    /// Silences proven by sequencing (the probe sent at once).
    pub sequenced: u64,
    /// Silences proven by a probe after the measured framing delay.
    pub waited: u64,
    /// Frames back to back followed by the brisk probe.
    pub bursts: u64,
    /// Times cases were sent again with full windows.
    pub reruns: u64,
    /// Cases sent again (a rerun sends the case and the one before it).
    pub rerun_cases: u64,
    /// Bytes that arrived when nothing was awaited.
    pub stray_bytes: u64,
    /// Differences on the brisk path that did not show with full windows.
    pub unconfirmed: u64,
    /// Longest answer delay measured for frames the receiver ends by a quiet time.
    pub framing_delay: Duration,
}

impl GuardStats {
    /// One line for the report.
    pub fn describe(&self) -> String {
        format!(
            "brisk link: {} silences proven by sequence, {} after the measured framing delay ({:.1} ms), {} bursts; {} reruns with full windows ({} cases; {} late bytes; {} brisk differences not confirmed)",
            self.sequenced,
            self.waited,
            self.framing_delay.as_secs_f64() * 1e3,
            self.bursts,
            self.reruns,
            self.rerun_cases,
            self.stray_bytes,
            self.unconfirmed
        )
    }
}

/// Whether the receiver can tell where `frame` ends from its bytes alone: an RTU frame
/// with a valid CRC as long as its function code implies (a by-length receiver takes it
/// whole at its last byte), an ASCII frame from its ':' to its only CR LF.
pub fn delimited(mode: Mode, frame: &[u8]) -> bool {
    match mode {
        Mode::Rtu => {
            frame.len() >= 4
                && crc16(frame) == 0
                && rtu_frame_len(Direction::Request, frame) == Some(frame.len())
        }
        // The next frame's ':' ends it in any ASCII receiver, whether or not its CR LF
        // came: a receiver that takes a frame ending in CR or LF alone answers it before
        // the probe, which the probe's check sees.
        Mode::Ascii => {
            frame.len() <= MAX_ASCII_FRAME
                && frame.first() == Some(&b':')
                && !frame[1..].contains(&b':')
        }
    }
}

fn probe_frame(ctx: &Ctx<'_>, count: u16) -> Option<Vec<u8>> {
    let r = liveness_register(ctx.model, ctx.opts.address, ctx.mode)?;
    let f = ctx.frame(Pdu::ReadRequest { start: r, count });
    matches!(
        ctx.model.judge(ctx.opts.address, ctx.mode, &f).expect,
        Expectation::Read(ref p) if p.registers.len() == usize::from(count)
    )
    .then_some(f)
}

/// The register count of an 03H request (None: another function, or no frame).
fn read_count(mode: Mode, frame: &[u8]) -> Option<u16> {
    let b = frame_parts(mode, frame).ok()?.body;
    (b.len() == 6 && b[1] == crate::codec::pdu::function::READ_HOLDING_REGISTERS)
        .then(|| u16::from_be_bytes([b[4], b[5]]))
}

/// Whether `reply` is a normal 03H reply of this device with `count` registers: the
/// only frame that can answer the probe.
fn answers_probe(ctx: &Ctx<'_>, reply: &[u8], count: u16) -> bool {
    let n = 2 * usize::from(count);
    frame_parts(ctx.mode, reply).is_ok_and(|x| {
        x.checksum.is_valid()
            && x.body.len() == 3 + n
            && x.body[0] == ctx.opts.address
            && x.body[1] == crate::codec::pdu::function::READ_HOLDING_REGISTERS
            && usize::from(x.body[2]) == n
    })
}

/// Sends one case on the brisk path. The second value says whether its verdict is in
/// doubt (the case must be sent again with full windows before anything is concluded).
pub fn observe(
    ctx: &mut Ctx<'_>,
    step: &Step,
    state: &mut State,
    g: &mut GuardStats,
) -> Result<(Option<Observed>, bool), RunError> {
    if let Some(why) = &ctx.lost {
        return Err(RunError::DeviceLost(why.clone()));
    }
    let plain_line = ctx.echoes() == Some(false);
    match step {
        Step::Frame(frame) => {
            let mode = ctx.mode;
            let judgement = ctx.model.judge(ctx.opts.address, mode, frame);
            let delim = delimited(mode, frame);
            let wait = if delim {
                Some(Duration::ZERO)
            } else if !g.framing_delay.is_zero() {
                Some((g.framing_delay * 2).min(MAX_BRISK_WAIT))
            } else {
                None
            };
            // A probe whose reply cannot pass for an answer to the frame: where the frame
            // reads one register, the probe reads two, and the other way round.
            let count = if read_count(mode, frame) == Some(1) {
                2
            } else {
                1
            };
            let probe = probe_frame(ctx, count);
            match (judgement.expect.replies(), wait, probe, plain_line) {
                (false, Some(wait), Some(probe), true) => {
                    let ex = ctx.master_mut().exchange_listening(frame, wait)?;
                    ctx.liveness_probes += 1;
                    let p = ctx.master_mut().exchange_retrying(&probe, true, 0)?;
                    if delim {
                        g.sequenced += 1;
                    } else {
                        g.waited += 1;
                    }
                    let clean = ex.raw.is_empty()
                        && !p.echo
                        && p.leading.is_empty()
                        && p.trailing.is_empty()
                        && p.reply
                            .as_deref()
                            .is_some_and(|r| answers_probe(ctx, r, count));
                    Ok((None, !clean))
                }
                _ => {
                    let before = ctx.latencies.len();
                    let o = observe_careful(ctx, step, state)?;
                    if !delim {
                        // The receiver's quiet time shows in the delay of its answer.
                        if let Some(&t) = ctx.latencies.get(before) {
                            g.framing_delay = g.framing_delay.max(t);
                        }
                    }
                    Ok((o, false))
                }
            }
        }
        // Timing damage is sent only on a line with timing, where the brisk path is off;
        // should one come here, it takes the full windows of the timed path.
        Step::Timed(_) => observe_careful(ctx, step, state).map(|o| (o, false)),
        Step::Burst(frames) => {
            let probe = probe_frame(ctx, 2);
            let single_reads = frames.iter().all(|f| {
                matches!(
                    ctx.model.judge(ctx.opts.address, ctx.mode, f).expect,
                    Expectation::Read(ref p) if p.registers.len() == 1
                )
            });
            let (Some(probe), true, true) = (probe, single_reads, plain_line) else {
                return Ok((observe_careful(ctx, step, state)?, false));
            };
            g.bursts += 1;
            // What waits now is the late end of an earlier case: counted as stray.
            ctx.master_mut().drain_input()?;
            let stray_before = ctx.master_mut().take_stray();
            let pause = (ctx.master_mut().budget().max_response * 2).min(MAX_BRISK_WAIT);
            ctx.send_raw(&frames.concat(), pause)?;
            ctx.liveness_probes += 1;
            let p = ctx.master_mut().exchange_retrying(&probe, true, 0)?;
            // The answers to the burst, read before the probe went: expected, not stray.
            let _ = ctx.master_mut().take_stray();
            let probe_reply = p.reply.as_deref().is_some_and(|r| answers_probe(ctx, r, 2));
            let clean = stray_before == 0
                && probe_reply
                && !p.echo
                && p.leading.is_empty()
                && p.trailing.is_empty();
            Ok((None, !clean))
        }
    }
}

/// A periodic liveness probe on the brisk path: whether it was answered, and whether
/// only its reply came back.
pub fn periodic(ctx: &mut Ctx<'_>) -> Result<(bool, bool), RunError> {
    let Some(probe) = probe_frame(ctx, 1) else {
        return Ok((ctx.liveness()?, true));
    };
    ctx.liveness_probes += 1;
    let p = ctx.master_mut().exchange_retrying(&probe, true, 1)?;
    let answered = !p.after_echo().is_empty();
    let clean = p.reply.as_deref().is_some_and(|r| answers_probe(ctx, r, 1))
        && !p.echo
        && p.leading.is_empty()
        && p.trailing.is_empty();
    Ok((answered, clean))
}

/// Sends `steps` again with full windows, once the device answers: their careful
/// verdicts, in order (stopping at the first that lost the device).
pub fn rerun(
    ctx: &mut Ctx<'_>,
    steps: &[&Step],
    state: &mut State,
    g: &mut GuardStats,
    recover_wait: Duration,
) -> Vec<Result<Option<Observed>, RunError>> {
    g.reruns += 1;
    g.rerun_cases += steps.len() as u64;
    ctx.master_mut().set_brisk(false);
    let mut out = Vec::new();
    match recover(ctx, recover_wait) {
        Ok(Some(_)) => {}
        Ok(None) => {
            let why = format!(
                "the device did not answer within {:.1} s (--recover-wait) before a case was sent again with full windows",
                recover_wait.as_secs_f64()
            );
            ctx.lost = Some(why.clone());
            out.push(Err(RunError::DeviceLost(why)));
        }
        Err(e) => out.push(Err(e)),
    }
    if out.is_empty() {
        // Whatever is still to come from the brisk exchanges comes now, and is dropped.
        std::thread::sleep(ctx.silence_window());
        if let Err(e) = ctx.master_mut().drain_input() {
            out.push(Err(e.into()));
        }
    }
    if out.is_empty() {
        for step in steps {
            let r = observe_careful(ctx, step, state);
            let lost = r.is_err();
            out.push(r);
            if lost {
                break;
            }
        }
    }
    let _ = ctx.master_mut().take_stray();
    ctx.master_mut().set_brisk(true);
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::frame_of_body;

    #[test]
    fn frames_that_end_by_themselves() {
        let read = frame_of_body(Mode::Rtu, &[1, 3, 0x25, 0x20, 0, 1]).unwrap();
        assert!(delimited(Mode::Rtu, &read));
        let mut bad = read.clone();
        bad[7] ^= 1;
        assert!(
            !delimited(Mode::Rtu, &bad),
            "a wrong CRC: the receiver slides on"
        );
        // A byte count over the data: the receiver waits for bytes that never come.
        let short = frame_of_body(Mode::Rtu, &[1, 0x10, 0x25, 0x0C, 0, 1, 2]).unwrap();
        assert!(!delimited(Mode::Rtu, &short));
        // An unmodelled function: its end is a quiet time.
        let odd = frame_of_body(Mode::Rtu, &[1, 0x41, 0, 0]).unwrap();
        assert!(!delimited(Mode::Rtu, &odd));
        let ascii = frame_of_body(Mode::Ascii, &[1, 3, 0x25, 0x20, 0, 1]).unwrap();
        assert!(delimited(Mode::Ascii, &ascii));
        assert!(
            delimited(Mode::Ascii, &ascii[..ascii.len() - 1]),
            "no LF: the probe's ':' ends it"
        );
        let mut two = ascii.clone();
        two[3] = b':';
        assert!(!delimited(Mode::Ascii, &two), "a ':' restarts the frame");
    }
}
