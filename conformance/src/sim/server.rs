//! The simulator's loop: read the transport, deframe requests with the codec's streaming
//! deframers, answer through [`Drive::handle`] after its delay, log everything.
//!
//! Framing: on a real serial port RTU frames end at t3.5 of silence (Modbus over Serial
//! Line 2.5.1.1), and so they do on a pseudo-terminal paced at the line's character time
//! (an emulated line: the arrival times are rebuilt by [`LineClock`], and a frame with
//! a silence over t1.5 inside it is discarded, as the standard wants). Unpaced
//! pseudo-terminals and TCP have no line timing, so RTU frames are found
//! by the length their function code implies; a burst whose length cannot be known that
//! way (an unmodelled function) is taken as one frame once the link has been quiet for
//! [`BURST_GAP`], if its CRC is valid: masters write a whole frame at once, so a burst
//! is a frame. The start of a frame whose length is known waits [`PARTIAL_TIMEOUT`]
//! for its rest, so a master that writes a frame in pieces is still answered. ASCII frames run from ':' to CR LF everywhere. Garbage, partial and
//! oversized frames are logged and dropped; the next good frame is answered.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::bus::Responder;
use super::drive::SendKind;
use super::line_clock::LineClock;
use super::log::{Dir, TrafficLog};
use crate::codec::deframe::{AsciiDeframer, Event, RtuDeframer, RtuFraming};
use crate::codec::pdu::Direction;
use crate::codec::Mode;
use crate::transport::{sleep_until, LinkKind, Transport, TransportError};

/// Quiet time after which a burst on a link without timing is judged (RTU).
pub const BURST_GAP: Duration = Duration::from_millis(5);

/// Quiet time after which the start of a frame whose length is known, with its rest
/// missing, is dropped (RTU on links without timing), as the ASCII inter-character
/// timeout does (Modbus over Serial Line V1.02, 2.5.2.1: 1 s).
pub const PARTIAL_TIMEOUT: Duration = Duration::from_secs(1);

/// Why the simulator stopped.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    /// The link failed or closed.
    #[error(transparent)]
    Transport(#[from] TransportError),
    /// The traffic log could not be written.
    #[error("cannot write the traffic log: {0}")]
    Log(#[from] std::io::Error),
}

/// What the simulator saw and did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct ServeStats {
    /// Valid frames received (any address).
    pub frames: u64,
    /// Replies sent.
    pub replies: u64,
    /// Bytes dropped as garbage, corrupt or incomplete frames.
    pub dropped_bytes: u64,
}

enum Deframer {
    Rtu(Box<RtuDeframer>, bool),
    Ascii(Box<AsciiDeframer>),
}

#[derive(Debug)]
enum Owned {
    Frame(Vec<u8>),
    Dropped(&'static str, Vec<u8>),
}

fn own(e: Event<'_>) -> Owned {
    match e {
        Event::Frame(b) => Owned::Frame(b.to_vec()),
        Event::Corrupt(b) => Owned::Dropped("corrupt", b.to_vec()),
        Event::Incomplete(b) => Owned::Dropped("incomplete", b.to_vec()),
        Event::Garbage(b) => Owned::Dropped("garbage", b.to_vec()),
    }
}

/// Serves `drive` (one [`super::Drive`], or a [`super::Bus`] of them) in `mode` on
/// `transport` until `stop` is set or the link fails.
pub fn serve<T: Transport + ?Sized, R: Responder + ?Sized>(
    transport: &mut T,
    drive: &mut R,
    mode: Mode,
    log: &mut TrafficLog,
    stop: &AtomicBool,
) -> Result<ServeStats, SimError> {
    serve_with_gap(transport, drive, mode, log, stop, None)
}

/// [`serve`], with the quiet time that ends a burst on a link without timing (RTU)
/// instead of [`BURST_GAP`]. Zero: a burst ends as soon as nothing more is waiting, for
/// a master known to write every frame in one write (on a pseudo-terminal a write
/// arrives whole), such as the fuzzer on an unpaced link; a master that writes a frame
/// in pieces may then have a piece of an unmodelled function taken as garbage.
pub fn serve_with_gap<T: Transport + ?Sized, R: Responder + ?Sized>(
    transport: &mut T,
    drive: &mut R,
    mode: Mode,
    log: &mut TrafficLog,
    stop: &AtomicBool,
    gap: Option<Duration>,
) -> Result<ServeStats, SimError> {
    let line = transport.line_timing();
    // A paced pseudo-terminal, or an endpoint of the emulated line (which tells its
    // silences): arrival times rebuilt at the line's rate.
    let emulated = transport.kind() == LinkKind::Pty || transport.line_tags().is_some();
    let mut clock = match (emulated, line, mode) {
        (true, Some(l), Mode::Rtu) => Some(LineClock::new(l.char_time_us(), Instant::now())),
        _ => None,
    };
    let ignore_t15 = drive.ignores_t15();
    // What the sender says it put on the line, where it says (this suite's runner).
    let tags = clock.as_ref().and_then(|_| transport.line_tags());
    let reply_starts = transport.reply_starts();
    let mut deframer = match (mode, line) {
        (Mode::Rtu, Some(l)) => Deframer::Rtu(
            Box::new(RtuDeframer::new(
                Direction::Request,
                RtuFraming::BySilence(l),
            )),
            false,
        ),
        (Mode::Rtu, None) => Deframer::Rtu(
            Box::new(RtuDeframer::new(Direction::Request, RtuFraming::ByLength)),
            true,
        ),
        (Mode::Ascii, _) => Deframer::Ascii(Box::default()),
    };
    // On a link that has a line's timing but is framed by length (a paced
    // pseudo-terminal), bytes come a character time apart: a burst of an unmodelled
    // function ends at t3.5 of quiet, not before.
    let burst_gap = match (transport.line_timing(), gap) {
        (Some(l), _) => BURST_GAP.max(Duration::from_micros(l.t3_5_us() + 2_000)),
        (None, Some(g)) => g,
        (None, None) => BURST_GAP,
    };
    let poll = match line {
        Some(_) => Duration::from_millis(1),
        None => Duration::from_millis(2),
    };
    let epoch = Instant::now();
    let mut stats = ServeStats::default();
    let mut buf = [0u8; 512];
    let mut last_rx: Option<Instant> = None;
    while !stop.load(Ordering::Relaxed) {
        // Bytes held that a quiet time shorter than the poll will end: look again at once.
        let held = matches!(&deframer, Deframer::Rtu(d, true)
            if d.pending() > 0 && (!d.awaiting_rest() || d.holds_checked_burst()));
        let n = transport.recv(&mut buf, if held { poll.min(burst_gap) } else { poll })?;
        let now = Instant::now();
        let now_us = u64::try_from(now.duration_since(epoch).as_micros()).unwrap_or(u64::MAX);
        let mut events = Vec::new();
        let mut ended_at: Option<Instant> = None;
        match &mut deframer {
            Deframer::Rtu(d, _) if clock.is_some() => {
                // An emulated line: a frame ends with its last character, found t3.5 later.
                ended_at = last_rx;
                if let Some(c) = clock.as_mut() {
                    if n > 0 {
                        let mut told = tags.as_ref().and_then(|t| t.lock().ok());
                        for (i, b) in buf[..n].iter().enumerate() {
                            let silence = told.as_mut().and_then(|q| q.pop_front());
                            let at = c.arrival(now, n - 1 - i, silence);
                            d.push_at(at, std::slice::from_ref(b), |e| events.push(own(e)));
                        }
                    } else {
                        // A told silence queued for a character not read yet: the
                        // sender wrote it and the kernel is still delivering it, so the
                        // frame is not over, however quiet the line looks from here.
                        let in_flight = tags
                            .as_ref()
                            .and_then(|t| t.lock().ok().map(|q| !q.is_empty()))
                            .unwrap_or(false);
                        if !in_flight {
                            d.idle(c.idle(now), |e| events.push(own(e)));
                        }
                    }
                }
            }
            Deframer::Rtu(d, by_length) => {
                if n > 0 {
                    d.push_at(now_us, &buf[..n], |e| events.push(own(e)));
                } else {
                    d.idle(now_us, |e| events.push(own(e)));
                    let quiet_for = last_rx.map(|t| now.duration_since(t)).unwrap_or_default();
                    // A frame whose length is known waits for its rest up to the partial
                    // timeout; anything else is judged after the burst gap.
                    // A burst that carries a valid CRC is one frame, also when its
                    // length field promises more (a master writes a whole frame at once).
                    let due = if d.awaiting_rest() {
                        quiet_for >= PARTIAL_TIMEOUT
                            || (quiet_for >= burst_gap && d.holds_checked_burst())
                    } else {
                        quiet_for >= burst_gap
                    };
                    if *by_length && due && d.pending() > 0 {
                        // The frame ended with its last byte, not when the quiet was seen.
                        ended_at = last_rx;
                        d.end_burst(|e| events.push(own(e)));
                    }
                }
            }
            Deframer::Ascii(d) => {
                if n > 0 {
                    d.push_at(now_us, &buf[..n], |e| events.push(own(e)));
                } else {
                    d.idle(now_us, |e| events.push(own(e)));
                }
            }
        }
        if n > 0 {
            last_rx = Some(now);
        }
        drive.tick(now);
        for e in events {
            let e = match e {
                // The planted ignore-t15 bug: a frame broken by a silence over t1.5 is
                // taken whole when its checksum holds.
                Owned::Dropped("incomplete", bytes)
                    if ignore_t15 && bytes.len() >= 4 && crate::codec::crc::crc16(&bytes) == 0 =>
                {
                    log.record(
                        Dir::In,
                        "incomplete",
                        &bytes,
                        "quirk ignore-t15: taken whole despite a silence over t1.5 inside it",
                    )?;
                    Owned::Frame(bytes)
                }
                e => e,
            };
            match e {
                Owned::Dropped(kind, bytes) => {
                    stats.dropped_bytes += bytes.len() as u64;
                    log.record(Dir::In, kind, &bytes, "dropped")?;
                }
                Owned::Frame(bytes) => {
                    stats.frames += 1;
                    // On an emulated line the frame is found t3.5 (or more) after its
                    // end; the drive's clock is the end.
                    let at = match clock {
                        Some(_) => ended_at.unwrap_or(now),
                        None => now,
                    };
                    let outcome = drive.handle(mode, &bytes, at);
                    let mut note = format!(
                        "{}: {}",
                        outcome.judgement.expect.describe(),
                        outcome.judgement.detail
                    );
                    for q in &outcome.notes {
                        note.push_str("; ");
                        note.push_str(q);
                    }
                    log.record(Dir::In, "frame", &bytes, &note)?;
                    let end = ended_at.unwrap_or(now);
                    for s in outcome.sends {
                        sleep_until(end + s.after);
                        if let (Some(q), SendKind::Reply) = (&reply_starts, &s.kind) {
                            crate::transport::push_reply_start(
                                q,
                                crate::transport::ReplyStart {
                                    at: Instant::now(),
                                    after: s.after,
                                },
                            );
                        }
                        transport.send(&s.bytes)?;
                        let kind = match s.kind {
                            SendKind::Echo => "echo",
                            SendKind::Reply => {
                                stats.replies += 1;
                                "reply"
                            }
                        };
                        log.record(Dir::Out, kind, &s.bytes, "")?;
                    }
                }
            }
        }
    }
    Ok(stats)
}
