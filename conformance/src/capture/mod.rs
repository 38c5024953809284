//! Capture files: the line as it was, every frame with its time and direction, in the
//! formats Wireshark, tshark and the serial sniffers read (pcapng, and classic pcap for
//! reading back other tools' files).
//!
//! A codec layer: it writes to any [`std::io::Write`] and reads from a byte slice; it
//! opens no file and reads no clock.
//!
//! - [`write::PcapngWriter`]: a Section Header Block, one Interface Description Block per
//!   link (its description names the port, mode and line settings; timestamps in
//!   microseconds), then one Enhanced Packet Block per frame, with its exact bytes, the
//!   time of its first byte, its direction and link-layer error bits in `epb_flags`, and a
//!   comment on frames damaged on purpose. Every block is written whole with one
//!   `write_all` and flushed, so a run cut short leaves a file that ends on a block
//!   boundary, which readers accept.
//! - [`read::Reader`]: pcap (both byte orders, microsecond and nanosecond timestamps) and
//!   pcapng (both byte orders, `if_tsresol`, several interfaces, several sections). A
//!   corrupt or truncated file is a [`read::ReadError`] naming the byte offset and the
//!   block. It never allocates by a length field: every length is checked against the
//!   bytes present, and packets are borrowed slices of the input.
//!
//! Link types (see docs/src/capture.md for what tshark makes of each):
//! RTU frames go under [`LINKTYPE_USER0`] (147), which Wireshark decodes as Modbus RTU
//! once its user DLT table maps 147 to `mbrtu` (what the open serial sniffers do);
//! ASCII frames under [`LINKTYPE_USER1`] (148), as the characters were sent: Wireshark has
//! no Modbus ASCII dissector, and a translation to RTU would not be the line's bytes.
//! Modbus TCP (MBAP) conversations go under Ethernet (1), with made-up Ethernet, IPv4 and
//! TCP headers around the stream's bytes ([`tcp`]).

pub mod read;
pub mod tcp;
pub mod write;

#[cfg(test)]
mod tests;

pub use read::{Packet, ReadError, Reader, ReaderState};
pub use write::{Interface, PacketMeta, PcapngWriter, WriteError};

/// Private-use link type 147 ("User 0"): RTU frames, as the open serial sniffers write
/// them; Wireshark's user DLT table maps it to the `mbrtu` dissector.
pub const LINKTYPE_USER0: u16 = 147;
/// Private-use link type 148 ("User 1"): ASCII frames, the characters as sent.
pub const LINKTYPE_USER1: u16 = 148;
/// SEL RTAC serial (250): a 12-byte header of time, event type and control lines before
/// the data.
pub const LINKTYPE_RTAC_SERIAL: u16 = 250;
/// Wireshark's exported PDU (252): tags (one names the dissector), then the data.
pub const LINKTYPE_WIRESHARK_UPPER_PDU: u16 = 252;

/// `epb_flags` bits 0-1: the direction, seen from the side that wrote the capture.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Direction {
    /// Received (01).
    Inbound,
    /// Sent (10).
    Outbound,
}

/// `epb_flags` value of an inbound packet.
pub const FLAG_INBOUND: u32 = 0b01;
/// `epb_flags` value of an outbound packet.
pub const FLAG_OUTBOUND: u32 = 0b10;
/// `epb_flags` bit 24: the link layer's CRC error (here: the RTU CRC is wrong).
pub const FLAG_CRC_ERROR: u32 = 1 << 24;
/// `epb_flags` bit 27: wrong inter-frame gap (here: a silence over t1.5 inside the frame,
/// or less than t3.5 before it).
pub const FLAG_WRONG_GAP: u32 = 1 << 27;

/// The words that begin the comment (after the label of the check, if any) of a frame
/// that the host writing the capture broke as it sent it: it stalled while pacing the
/// frame onto an emulated line (a silence over t1.5 inside it), so a receiver that frames
/// by silence dropped it, and the frame was sent again. Such a packet also carries
/// [`FLAG_WRONG_GAP`]. A reader judging the line takes it as its writer says: not a
/// request that was due a reply (see [`broken_by_host`]).
pub const BROKEN_BY_HOST: &str = "broken by the host as it left";

/// Whether a packet with `flags` and `comment` is one its writer marked as broken by its
/// own host as it sent it ([`BROKEN_BY_HOST`]).
pub fn broken_by_host(flags: Option<u32>, comment: Option<&str>) -> bool {
    flags.is_some_and(|f| f & FLAG_WRONG_GAP != 0 && f & 0b11 == FLAG_OUTBOUND)
        && comment.is_some_and(|c| c.contains(BROKEN_BY_HOST))
}

/// The comment a capture of this suite's master side puts on a reply that the
/// simulator at the other end of its emulated line began late because this host was busy
/// (the simulator said when it began: `transport::ReplyStarts`), followed by ": N us".
/// A reader judges such a reply at the time it was due ([`late_on_host`]).
pub const LATE_ON_HOST: &str = "begun late by the host of the simulator";

/// The words in the comment of a tap's first packet read before any read came
/// back empty (`monitor --capture` that began listening while the line was busy): it may
/// begin inside a frame. The live monitor judged none of it up to the first silence of
/// t3.5 (ASCII: up to the first ':'), and a reader of the file does the same
/// ([`heard_mid_traffic`]). A sniffer's file has no such packet: its first is judged.
pub const HEARD_MID_TRAFFIC: &str = "read before the line was heard quiet";

/// Whether a packet's `comment` marks it as read before the line was heard quiet
/// ([`HEARD_MID_TRAFFIC`]).
pub fn heard_mid_traffic(comment: Option<&str>) -> bool {
    comment.is_some_and(|c| c.contains(HEARD_MID_TRAFFIC))
}

/// How late a packet's comment says its writer's host made the simulator begin it
/// ([`LATE_ON_HOST`]); None for any other packet.
pub fn late_on_host(comment: Option<&str>) -> Option<std::time::Duration> {
    let c = comment?;
    let rest = &c[c.find(LATE_ON_HOST)? + LATE_ON_HOST.len()..];
    let digits = rest.strip_prefix(": ")?;
    let end = digits.find(" us")?;
    digits[..end]
        .parse::<u64>()
        .ok()
        .map(std::time::Duration::from_micros)
}

impl Direction {
    /// The `epb_flags` bits of this direction.
    pub fn flag(self) -> u32 {
        match self {
            Direction::Inbound => FLAG_INBOUND,
            Direction::Outbound => FLAG_OUTBOUND,
        }
    }

    /// The direction `epb_flags` says, if any (00 is "not known", 11 is undefined).
    pub fn from_flags(flags: u32) -> Option<Direction> {
        match flags & 0b11 {
            FLAG_INBOUND => Some(Direction::Inbound),
            FLAG_OUTBOUND => Some(Direction::Outbound),
            _ => None,
        }
    }
}

/// The link type that carries frames of `mode` in this suite's captures.
pub fn link_type_of(mode: crate::codec::Mode) -> u16 {
    match mode {
        crate::codec::Mode::Rtu => LINKTYPE_USER0,
        crate::codec::Mode::Ascii => LINKTYPE_USER1,
    }
}
