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
use crate::capture::{self, ReadError, Reader};

/// Why a capture cannot be judged.
#[derive(Debug, thiserror::Error)]
pub enum ReplayError {
    /// The file is not a capture, or is corrupt before its first packet.
    #[error(transparent)]
    Read(#[from] ReadError),
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
    /// The span from the first packet to the last.
    pub span: Duration,
    /// A fault after the first packets (a file cut short): what was read before it was
    /// judged.
    pub stopped: Option<ReadError>,
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
    replay_with(data, monitor, on_line, true)
}

/// [`replay`] feeding each packet in two pieces (the first byte, then the rest), as it
/// did before [`Monitor::feed_packet`]: the tests hold the two to the same verdicts.
#[cfg(test)]
pub(crate) fn replay_in_two_pieces(
    data: &[u8],
    monitor: &mut Monitor,
    on_line: impl FnMut(&Line),
) -> Result<Replayed, ReplayError> {
    replay_with(data, monitor, on_line, false)
}

fn replay_with(
    data: &[u8],
    monitor: &mut Monitor,
    mut on_line: impl FnMut(&Line),
    whole: bool,
) -> Result<Replayed, ReplayError> {
    let reader = Reader::new(data)?;
    let char = Duration::from_micros(monitor.config().line.char_time_us());
    let mut out = Replayed::default();
    let mut origin: Option<u64> = None;
    let mut last = 0u64;
    for item in reader {
        let p = match item {
            Ok(p) => p,
            Err(e) => {
                out.stopped = Some(e);
                break;
            }
        };
        let Some(bytes) = payload(p.link_type, p.data) else {
            return Err(ReplayError::LinkType {
                index: out.packets,
                interface: p.interface,
                link_type: p.link_type,
            });
        };
        // A packet without a time (a Simple Packet Block) came after the one before.
        let ts = p.timestamp_ns.unwrap_or(last).max(last);
        let t0 = *origin.get_or_insert(ts);
        let first = Duration::from_nanos(ts - t0);
        monitor.idle(first);
        // Where the capture gives directions, they settle which frame answers which.
        monitor.set_side(p.direction.map(|d| d == capture::Direction::Outbound));
        // The first byte when its last bit arrived (response times and silences are
        // measured to it), the rest when the packet's last byte did: no silence inside a
        // packet can be proven, and the framer needs no byte-by-byte clock for that.
        let end = first + char * bytes.len() as u32;
        if whole {
            monitor.feed_packet(first + char, end, bytes);
        } else {
            let (head, rest) = bytes.split_at(1.min(bytes.len()));
            monitor.feed(first + char, head);
            monitor.feed(end, rest);
        }
        for l in monitor.take_lines() {
            on_line(&l);
        }
        last = ts;
        out.packets += 1;
        out.bytes += bytes.len() as u64;
        out.span = end;
    }
    monitor.finish();
    for l in monitor.take_lines() {
        on_line(&l);
    }
    Ok(out)
}
