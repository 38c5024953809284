//! Recording a link as a pcapng capture (`--capture FILE.pcapng`).
//!
//! [`Recorder`] owns the file: one interface per link opened (a run in both modes opens
//! two), and the label of what is running now (a check id), for the comments on frames
//! damaged on purpose. [`Captured`] wraps any [`Transport`] and records, on the
//! recorder it shares:
//!
//! - each `send` as one outbound packet, stamped with the time it started; each piece of a
//!   `send_pieces` as its own packet (the pieces after the first flagged "wrong
//!   inter-frame gap", bit 27): a receiver that frames by silence sees them so;
//! - received bytes grouped into inbound packets: a packet ends where the line was silent
//!   for the frame gap (t3.5, at least 5 ms, as the master frames) or where this side
//!   sends. On a link whose timing is the host's (a pseudo-terminal, TCP) a silence
//!   inside a frame whose length its function tells (and whose checksum is not right
//!   yet) is the host's delivery, not the line's: the frame is held whole unless the
//!   silence passes the master's timeout ([`Captured::holding_frames_for`]; [`HOST_STALL`] by default). A
//!   packet's time is that of the read that brought its first bytes, less their
//!   transmission time where the line's timing is known, and never before the end of the
//!   last frame sent (a reply cannot begin before its request ended).
//!
//! An outbound packet's time is when its first character went on the line: where the
//! transport knows when the last one left ([`Transport::sent_at`], a paced link), that
//! less the frame's transmission time.
//!
//! Each packet whose checksum is wrong (RTU CRC, ASCII LRC or delimiters) carries the
//! CRC-error bit (24); an outbound one also a comment naming the label (the check) that
//! damaged it. Bytes waiting when the caller discards input (a late reply it gave up on)
//! are read into the capture first, then dropped.
//! A write to the file that fails stops the recording and is reported once, at the end
//! ([`Recorder::error`]): the run itself goes on.
//!
//! The wrapper is `captured.rs`; a Modbus TCP connection, recorded as Ethernet frames, is
//! `tcp.rs`.

use std::io::Write;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use crate::capture::{self, Interface, PacketMeta, PcapngWriter};

mod captured;
mod tcp;

pub use captured::Captured;
pub use tcp::TcpRecording;

/// A reply the simulator began this much later than due, or more, is marked in the
/// capture as late by this host ([`capture::LATE_ON_HOST`]): less is the pacing's jitter.
pub const LATE_NOTED: Duration = Duration::from_millis(1);

/// The longest silence inside a frame that a host's delivery is taken to cause on a link
/// without the line's timing.
pub const HOST_STALL: Duration = Duration::from_millis(200);

/// The capture file of a run, shared by the links it opens.
pub struct Recorder {
    writer: Option<PcapngWriter<Box<dyn Write + Send>>>,
    origin: Instant,
    origin_us: u64,
    label: Option<String>,
    error: Option<String>,
    packets: u64,
}

/// A recorder shared by the transports of a run and the command that labels the checks.
pub type SharedRecorder = Arc<Mutex<Recorder>>;

impl Recorder {
    /// Starts a capture on `sink` (a section header naming `application`).
    pub fn new(
        sink: Box<dyn Write + Send>,
        application: &str,
    ) -> Result<Self, capture::WriteError> {
        let origin_us = SystemTime::now()
            .duration_since(SystemTime::UNIX_EPOCH)
            .map(|d| d.as_micros() as u64)
            .unwrap_or(0);
        Ok(Recorder {
            writer: Some(PcapngWriter::new(sink, application)?),
            origin: Instant::now(),
            origin_us,
            label: None,
            error: None,
            packets: 0,
        })
    }

    /// Shares it.
    pub fn shared(self) -> SharedRecorder {
        Arc::new(Mutex::new(self))
    }

    /// What runs now (a check id, a fuzz case), named in the comment of frames it damages
    /// on purpose; None between checks.
    pub fn set_label(&mut self, label: Option<String>) {
        self.label = label;
    }

    /// The first write that failed, if one did (the recording stopped there).
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    /// Packets written.
    pub fn packets(&self) -> u64 {
        self.packets
    }

    /// Describes a link; None once the recording failed.
    fn interface(&mut self, iface: &Interface) -> Option<u32> {
        let w = self.writer.as_mut()?;
        match w.add_interface(iface) {
            Ok(i) => Some(i),
            Err(e) => {
                self.fail(e);
                None
            }
        }
    }

    fn fail(&mut self, e: capture::WriteError) {
        self.error.get_or_insert_with(|| e.to_string());
        self.writer = None;
    }

    /// Writes one packet that started at `at`, with a comment: why it is damaged (after
    /// the label of what runs now), or else a note as it is.
    fn record(
        &mut self,
        interface: u32,
        at: Instant,
        bytes: &[u8],
        flags: u32,
        why: Option<&str>,
        note: Option<&str>,
    ) {
        let comment = match (why, &self.label) {
            (Some(why), Some(label)) => Some(format!("{label}: {why}")),
            (Some(why), None) => Some(why.to_string()),
            _ => None,
        };
        // Both where a whole ASCII frame is also marked (a reply begun late by the host).
        let comment = match (comment, note) {
            (Some(c), Some(n)) => Some(format!("{c}; {n}")),
            (c, n) => c.or_else(|| n.map(str::to_string)),
        };
        // A packet dated back from its read may begin before the recording did (a tap's
        // first read, a backlog): its time is then before the origin, not at it.
        let timestamp_us = match at.checked_duration_since(self.origin) {
            Some(since) => self.origin_us + since.as_micros() as u64,
            None => self
                .origin_us
                .saturating_sub(self.origin.duration_since(at).as_micros() as u64),
        };
        let meta = PacketMeta {
            interface,
            timestamp_us,
            flags,
            comment,
        };
        let Some(w) = self.writer.as_mut() else {
            return;
        };
        match w.write_packet(&meta, bytes) {
            Ok(()) => self.packets += 1,
            Err(e) => self.fail(e),
        }
    }
}

#[cfg(test)]
mod tests;
