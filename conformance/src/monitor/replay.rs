//! Judging a capture offline (`monitor --capture-in FILE`): each packet of a pcap or
//! pcapng file is fed to the [`Monitor`] at its own time, as if a tap had heard it.
//!
//! The packets' times are those of their first byte (pcapng's and pcap's convention); the
//! monitor is told that the line was silent up to then ([`Monitor::idle`]) and is fed the
//! bytes one at a time, each when its last bit arrived at the line's settings (the first
//! byte's time plus one character time per byte), as a tap reading promptly hands them
//! over: the monitor measures response times and gaps from arrival times. Directions are not needed:
//! a tap hears both sides on one wire, and the monitor tells requests from replies by
//! itself, so captures from single-direction taps and from other sniffers (no direction
//! flags) are judged the same way.

use std::time::Duration;

use super::{Line, Monitor};
use crate::capture::{self, Packet, ReadError, Reader};

/// Why a capture cannot be judged.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The file is not a capture, or is corrupt before its first packet.
    #[error(transparent)]
    Read(#[from] ReadError),
    /// The file could not be read.
    #[error("reading the capture: {0}")]
    Io(#[from] std::io::Error),
    /// A packet under a link type that carries no serial line's bytes.
    #[error("packet {index} is on interface {interface} of link type {link_type}: expected a serial line's bytes under a user link type (147..=162) or SEL RTAC serial (250)")]
    LinkType {
        /// The packet's index, from 0.
        index: u64,
        /// Its interface.
        interface: u32,
        /// Its link type.
        link_type: u16,
    },
}

/// What a replay went through.
#[derive(Debug, Default)]
pub struct Replayed {
    /// Packets fed.
    pub packets: u64,
    /// Bytes fed.
    pub bytes: u64,
    /// The span from the first packet to the end of the last.
    pub span: Duration,
    /// The first packet's time, nanoseconds since the Unix epoch, where the capture gives
    /// it: with [`Replayed::span`], when the bus was heard (not when it was judged).
    pub first_ns: Option<u64>,
    /// A fault after the first packets (a file cut short): what was read before it was
    /// judged.
    pub stopped: Option<ReadError>,
    /// Packets its writer marked as broken by its own host as they left, and sent again
    /// ([`capture::broken_by_host`]): read, not judged.
    pub broken_by_host: u64,
    /// Replies its writer marked as begun late by its own host (the simulator it ran,
    /// starved: [`capture::late_on_host`]), judged at the time they were due.
    pub late_on_host: u64,
    /// The most any of them was late.
    pub most_late_on_host: Duration,
}

/// The line's bytes in a packet of `link_type`, if it carries them.
fn payload(link_type: u16, data: &[u8]) -> Option<&[u8]> {
    match link_type {
        147..=162 => Some(data),
        // SEL RTAC serial: a 12-byte header (time, event type, control lines, footer).
        capture::LINKTYPE_RTAC_SERIAL => data.get(12..),
        _ => None,
    }
}

/// What the capture's first bytes tell of its mode (`monitor --capture-in --mode auto`):
/// [`guess`](super::guess::guess) over its packets' bytes, as they come, until it decides
/// or the capture ends.
pub fn guess_mode(data: &[u8]) -> Result<super::guess::Guess, ReplayError> {
    use super::guess::{guess, Guess, GIVE_UP_AFTER};
    let mut bytes = Vec::new();
    for item in Reader::new(data)? {
        let Ok(p) = item else { break };
        let Some(b) = payload(p.link_type, p.data) else {
            continue;
        };
        let room = GIVE_UP_AFTER.saturating_sub(bytes.len());
        bytes.extend_from_slice(&b[..b.len().min(room)]);
        let g = guess(&bytes);
        if g != Guess::Undecided {
            return Ok(g);
        }
    }
    Ok(guess(&bytes))
}

/// Feeds every packet of the capture `data` to `monitor`, then ends it
/// ([`Monitor::finish`]); every live line goes to `on_line`.
pub fn replay(
    data: &[u8],
    monitor: &mut Monitor,
    on_line: impl FnMut(&Line),
) -> Result<Replayed, ReplayError> {
    replay_with(data, monitor, true, on_line)
}

/// [`replay`] feeding each packet in two pieces (the first byte, then the rest), as it
/// did before [`Monitor::feed_packet`]: the tests hold the two to the same verdicts.
#[cfg(test)]
pub(crate) fn replay_in_two_pieces(
    data: &[u8],
    monitor: &mut Monitor,
    on_line: impl FnMut(&Line),
) -> Result<Replayed, ReplayError> {
    replay_with(data, monitor, false, on_line)
}

/// [`replay`], each packet whole or in two pieces.
fn replay_with(
    data: &[u8],
    monitor: &mut Monitor,
    whole: bool,
    mut on_line: impl FnMut(&Line),
) -> Result<Replayed, ReplayError> {
    let mut feeder = Feeder::new(monitor, whole);
    for item in Reader::new(data)? {
        match item {
            Ok(p) => feeder.packet(monitor, &p, &mut on_line)?,
            Err(e) => {
                feeder.out.stopped = Some(e);
                break;
            }
        }
    }
    Ok(feeder.finish(monitor, &mut on_line))
}

/// The bytes [`replay_from`] reads from its source at a time (the buffer grows past it
/// only for a block longer than that, as far as the file holds its bytes).
pub const READ_CHUNK: usize = 256 * 1024;

/// [`replay`] of a capture read from `source` (a file) a part at a time, rather than
/// read whole first: the same packets, the same verdicts and the same fault where one
/// is found (its offset counted from the start of the file), with a buffer of about
/// [`READ_CHUNK`] bytes that stays in the cache.
pub fn replay_from(
    source: impl std::io::Read,
    monitor: &mut Monitor,
    on_line: impl FnMut(&Line),
) -> Result<Replayed, ReplayError> {
    replay_chunked(source, READ_CHUNK, monitor, on_line)
}

/// [`replay_from`], reading `chunk` bytes at a time (the tests cut files everywhere).
pub(crate) fn replay_chunked(
    source: impl std::io::Read,
    chunk: usize,
    monitor: &mut Monitor,
    mut on_line: impl FnMut(&Line),
) -> Result<Replayed, ReplayError> {
    let mut feeder = Feeder::new(monitor, true);
    let stopped = stream_packets(source, chunk, |p| {
        feeder.packet(monitor, p, &mut on_line).map(|()| true)
    })?;
    feeder.out.stopped = stopped;
    Ok(feeder.finish(monitor, &mut on_line))
}

/// [`guess_mode`] of a capture read from `source` a part at a time (only as far as it
/// takes to decide).
pub fn guess_mode_from(source: impl std::io::Read) -> Result<super::guess::Guess, ReplayError> {
    guess_mode_chunked(source, READ_CHUNK)
}

pub(crate) fn guess_mode_chunked(
    source: impl std::io::Read,
    chunk: usize,
) -> Result<super::guess::Guess, ReplayError> {
    use super::guess::{guess, Guess, GIVE_UP_AFTER};
    let mut bytes = Vec::new();
    let mut decided = None;
    stream_packets(source, chunk, |p| {
        let Some(b) = payload(p.link_type, p.data) else {
            return Ok(true);
        };
        let room = GIVE_UP_AFTER.saturating_sub(bytes.len());
        bytes.extend_from_slice(&b[..b.len().min(room)]);
        let g = guess(&bytes);
        if g != Guess::Undecided {
            decided = Some(g);
            return Ok(false);
        }
        Ok(true)
    })?;
    Ok(decided.unwrap_or_else(|| guess(&bytes)))
}

/// Each packet of the capture read from `source` (`chunk` bytes at a time) to `each`,
/// in file order, until it says to stop (`false`) or fails; the read fault that ended
/// the packets, if one did (its offset from the start of the file), as [`Reader`] gives
/// it over the whole file.
fn stream_packets(
    mut source: impl std::io::Read,
    chunk: usize,
    mut each: impl FnMut(&Packet<'_>) -> Result<bool, ReplayError>,
) -> Result<Option<ReadError>, ReplayError> {
    let chunk = chunk.max(1);
    let mut buf: Vec<u8> = Vec::new();
    let mut eof = fill(&mut source, &mut buf, chunk)?;
    // Where the buffer begins in the file.
    let mut base = 0u64;
    let mut state = None;
    loop {
        let mut reader = match state.take() {
            Some(s) => Reader::resume(&buf, s),
            None => match Reader::new(&buf) {
                Ok(r) => r,
                Err(e) if e.is_truncated() && !eof => {
                    eof = fill(&mut source, &mut buf, chunk)?;
                    continue;
                }
                Err(e) => return Err(e.into()),
            },
        };
        loop {
            match reader.next() {
                Some(Ok(p)) => {
                    if !each(&p)? {
                        return Ok(None);
                    }
                }
                // The buffer ends before the file does: read on from this block.
                None if !eof => break,
                Some(Err(e)) if e.is_truncated() && !eof => break,
                None => return Ok(None),
                Some(Err(e)) => return Ok(Some(e.at_base(base))),
            }
        }
        let used = usize::try_from(reader.offset())
            .unwrap_or(buf.len())
            .min(buf.len());
        state = Some(reader.into_state());
        buf.drain(..used);
        base += used as u64;
        eof = fill(&mut source, &mut buf, chunk)?;
    }
}

/// Reads up to `chunk` more bytes of `source` onto `buf`; whether the source ended.
fn fill(
    source: &mut impl std::io::Read,
    buf: &mut Vec<u8>,
    chunk: usize,
) -> Result<bool, std::io::Error> {
    let want = buf.len() + chunk;
    buf.reserve(chunk);
    while buf.len() < want {
        let n = buf.len();
        buf.resize(want, 0);
        match source.read(&mut buf[n..]) {
            Ok(0) => {
                buf.truncate(n);
                return Ok(true);
            }
            Ok(k) => buf.truncate(n + k),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => buf.truncate(n),
            Err(e) => {
                buf.truncate(n);
                return Err(e);
            }
        }
    }
    Ok(false)
}

/// Feeds packets to a monitor as [`replay`] does, one at a time.
struct Feeder {
    char: Duration,
    out: Replayed,
    origin: Option<u64>,
    last: u64,
    /// Each packet whole ([`Monitor::feed_packet`]), or in two pieces (tests).
    whole: bool,
    /// The live monitor's rule for bytes heard before the line was heard quiet.
    entry: super::tap::Entry,
}

impl Feeder {
    fn new(monitor: &Monitor, whole: bool) -> Self {
        Feeder {
            char: Duration::from_micros(monitor.config().line.char_time_us()),
            out: Replayed::default(),
            origin: None,
            last: 0,
            whole,
            entry: super::tap::Entry::new(monitor.config().mode, monitor.config().line),
        }
    }

    fn packet(
        &mut self,
        monitor: &mut Monitor,
        p: &Packet<'_>,
        on_line: &mut impl FnMut(&Line),
    ) -> Result<(), ReplayError> {
        let Some(bytes) = payload(p.link_type, p.data) else {
            return Err(ReplayError::LinkType {
                index: self.out.packets,
                interface: p.interface,
                link_type: p.link_type,
            });
        };
        // A packet without a time (a Simple Packet Block) came after the one before.
        let ts = p.timestamp_ns.unwrap_or(self.last).max(self.last);
        if self.origin.is_none() && self.out.first_ns.is_none() {
            self.out.first_ns = p.timestamp_ns;
        }
        // A frame the writer's host broke as it sent it (a stall inside it) was dropped
        // by its receiver and sent again: the copy that follows is the request the
        // device answered, as the writer (`check`) judged it. Judged, this one would be
        // a request left unanswered and the copy a retry.
        if capture::broken_by_host(p.flags, p.comment) {
            self.out.broken_by_host += 1;
            self.out.packets += 1;
            self.out.bytes += bytes.len() as u64;
            return Ok(());
        }
        let t0 = *self.origin.get_or_insert(ts);
        let mut first = Duration::from_nanos(ts - t0);
        // A reply the writer's host made its simulator begin late is judged when it was
        // due, as the writer (`check`) judged it: the lateness was the host's, not the
        // drive's. Never before the end of what came before it.
        if let Some(late) = capture::late_on_host(p.comment) {
            self.out.late_on_host += 1;
            self.out.most_late_on_host = self.out.most_late_on_host.max(late);
            first = first.saturating_sub(late).max(self.out.span);
        }
        monitor.idle(first);
        // A capture begins with the line quiet, unless its writer (a monitor that began
        // listening while the line was busy) marked its first packet: then, as the live
        // monitor did, its bytes are not judged up to the first silence of t3.5 (ASCII:
        // up to the first ':'). Packets are apart by silences, each proved here.
        if self.out.packets > 0 || !capture::heard_mid_traffic(p.comment) {
            self.entry.idle(first);
        }
        // Where the capture gives directions, they settle which frame answers which: a
        // direction is the packet's on its own interface (a bus capture's endpoints).
        monitor.set_side(super::capture_side(p.interface, p.direction));
        // The first byte when its last bit arrived (response times and silences are
        // measured to it), the rest when the packet's last byte did: no silence inside a
        // packet can be proven, and the framer needs no byte-by-byte clock for that.
        let char = self.char;
        let end = first + char * bytes.len() as u32;
        let kept = self.entry.take(end, bytes);
        let first = first + char * (bytes.len() - kept.len()) as u32;
        if kept.is_empty() {
            monitor.idle(end);
        } else if self.whole {
            monitor.feed_packet(first + char, end, kept);
        } else {
            let (head, rest) = kept.split_at(1.min(kept.len()));
            monitor.feed(first + char, head);
            monitor.feed(end, rest);
        }
        if let Some(n) = self.entry.notice(false) {
            monitor.notice(n);
        }
        for l in monitor.take_lines() {
            on_line(&l);
        }
        self.last = ts;
        self.out.packets += 1;
        self.out.bytes += bytes.len() as u64;
        self.out.span = end;
        Ok(())
    }

    fn finish(mut self, monitor: &mut Monitor, on_line: &mut impl FnMut(&Line)) -> Replayed {
        if let Some(n) = self.entry.notice(true) {
            monitor.notice(n);
        }
        monitor.finish();
        for l in monitor.take_lines() {
            on_line(&l);
        }
        self.out
    }
}
