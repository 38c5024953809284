//! Transports: one trait for every link a drive can sit behind, so the simulator and the
//! runner use the same ones.
//!
//! - [`serial::SerialTransport`]: a real serial port (RS-485 adapter), by the `serialport`
//!   crate; the only link whose timing is the line's.
//! - [`pty::PtyMaster`] (Unix): the master side of a pseudo-terminal pair; another program
//!   opens the slave path as if it were a serial port. Optionally paced at the line's
//!   character time, so that timing checks have something real to measure.
//! - [`tcp::TcpTransport`]: RTU or ASCII frames over TCP, as serial gateways carry them.
//! - [`mbap::MbapGateway`]: a Modbus TCP gateway (MBAP framing, unit id): takes RTU frames
//!   and hands back RTU frames, as if it were the serial line behind the gateway; it can
//!   carry whole valid frames only ([`Transport::frames_only`]).
//! - [`memory::MemoryEnd`]: an in-memory pair, for tests.
//! - [`capture::Captured`]: any of them, with every frame sent and received recorded in a
//!   pcapng capture (`--capture`).
//! - [`uart`]: what a UART reads from characters sent at other line settings (the
//!   simulator's pseudo-terminal emulates a drive's line with it).
//!
//! Reads wait at most the timeout they are given and return 0 when nothing arrived; a
//! closed link is [`TransportError::Closed`], never a silent empty read.

pub mod capture;
pub mod mbap;
pub mod memory;
#[cfg(unix)]
pub mod pty;
pub mod serial;
pub mod tcp;
pub mod uart;

use std::fmt;
use std::time::Duration;

use crate::codec::timing::LineSettings;

/// What kind of link a transport is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LinkKind {
    /// A real serial port.
    Serial,
    /// A pseudo-terminal.
    Pty,
    /// A TCP connection.
    Tcp,
    /// An in-memory pair.
    Memory,
    /// A Modbus TCP gateway (MBAP framing): PDUs cross, not the serial line's bytes.
    Mbap,
}

impl fmt::Display for LinkKind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            LinkKind::Serial => "serial",
            LinkKind::Pty => "pty",
            LinkKind::Tcp => "tcp",
            LinkKind::Memory => "memory",
            LinkKind::Mbap => "mbap",
        })
    }
}

/// Why a transport failed.
#[derive(Debug, thiserror::Error)]
pub enum TransportError {
    /// The link could not be opened.
    #[error("cannot open {what}: {source}")]
    Open {
        /// The port, path or address.
        what: String,
        /// The cause.
        source: std::io::Error,
    },
    /// A read or write failed.
    #[error("{what} failed on {link}: {source}")]
    Io {
        /// "read" or "write".
        what: &'static str,
        /// The link.
        link: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The other end went away (adapter unplugged, connection closed, pty closed).
    #[error("{link}: the other end closed the link")]
    Closed {
        /// The link.
        link: String,
    },
    /// A Modbus TCP gateway sent what is not Modbus TCP (protocol id, length), or a reply
    /// that belongs to no request (transaction id) or to another unit.
    #[error("{link}: {source}")]
    Mbap {
        /// The link.
        link: String,
        /// What was wrong, with the header in hex.
        source: crate::codec::mbap::MbapError,
    },
    /// A request this host paces onto an emulated line (the simulator's pseudo-terminal)
    /// that it could not put there whole: every send of it had a silence over t1.5
    /// inside it as it left (the host stalled while pacing it), so the receiver, which
    /// frames by silence, never saw the request. Nothing the other end did can be judged
    /// from that exchange; the run goes on.
    #[error("{link}: could not send the request {request} whole: the host stalled {sends} times while pacing it (a silence over t1.5 inside it as it left this host, each time); nothing about the device can be judged from it")]
    Stalled {
        /// The link.
        link: String,
        /// The request, in hex (at most the first 64 bytes).
        request: String,
        /// How many times it was sent, each broken.
        sends: u32,
    },
    /// On a pseudo-terminal (the other end is a program on this host): the answer to a
    /// request came only after the timeout, every time it was sent, and the other end
    /// answered at once when probed. A busy host delays the program, not the device's
    /// line: nothing about the device can be judged from it.
    #[error("{link}: the answer to {request} came only after the {timeout_ms} ms timeout, {times} times, while the other end answered its liveness probe: on a pseudo-terminal the other end is a program on this host, which a busy host delays; nothing about the device can be judged from it")]
    LateOnHost {
        /// The link.
        link: String,
        /// The request, in hex (at most the first 64 bytes).
        request: String,
        /// How many times it was sent.
        times: u32,
        /// The timeout.
        timeout_ms: u64,
    },
    /// Bytes a link that carries whole frames only (a Modbus TCP gateway) cannot send:
    /// not one RTU frame with a valid CRC.
    #[error("{link}: cannot send {bytes}: {why}")]
    NotCarried {
        /// The link.
        link: String,
        /// The bytes, in hex (at most the first 64).
        bytes: String,
        /// Why not.
        why: String,
    },
}

/// The silences an emulated line's sender put before its characters, in order, in
/// microseconds (saturated at `u32::MAX` for "the line was idle"), one per character
/// written. A pseudo-terminal delivers bytes through the kernel with a few milliseconds
/// of jitter of its own, which no receiver can tell from a silence; where the sender is
/// this suite's paced transport, it says what it put on the line, and the simulator
/// frames by that (see [`crate::sim::line_clock`]). A sender pushes the silence before
/// it writes the character, so a reader always finds it.
pub type LineTags = std::sync::Arc<std::sync::Mutex<std::collections::VecDeque<u32>>>;

/// When an emulated line's simulator began to write each reply, and how long after the
/// end of the request it meant to begin (its drive's response time, planted lateness
/// included), oldest first; at most [`REPLY_STARTS_KEPT`]. A simulator starved by a busy
/// host begins late, and a master starved reads late: where the simulator says when it
/// began, a capture of the master's side records the reply at the time the emulated line
/// carried it, and how late this host made it (see `transport::capture`).
pub type ReplyStarts = std::sync::Arc<std::sync::Mutex<std::collections::VecDeque<ReplyStart>>>;

/// How many reply starts a [`ReplyStarts`] queue keeps (the oldest are dropped).
pub const REPLY_STARTS_KEPT: usize = 64;

/// One reply a simulator began to write (see [`ReplyStarts`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct ReplyStart {
    /// When its first character was written.
    pub at: std::time::Instant,
    /// How long after the end of the request the simulator meant to begin it.
    pub after: Duration,
}

/// Adds `start` to `queue`, dropping the oldest beyond [`REPLY_STARTS_KEPT`].
pub fn push_reply_start(queue: &ReplyStarts, start: ReplyStart) {
    if let Ok(mut q) = queue.lock() {
        q.push_back(start);
        while q.len() > REPLY_STARTS_KEPT {
            q.pop_front();
        }
    }
}

/// A bidirectional byte link to a drive or a master.
pub trait Transport: Send {
    /// Sends `bytes`; with pacing, returns after the line would have carried them.
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError>;

    /// Waits at most `timeout` for input and returns how many bytes were put in `buf`;
    /// 0 means nothing arrived in time.
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError>;

    /// Drops input received but not yet read.
    fn discard_input(&mut self) -> Result<(), TransportError>;

    /// "serial /dev/ttyUSB0 9600 8E1", "pty /dev/pts/3", "tcp 127.0.0.1:5020".
    fn describe(&self) -> String;

    /// The kind of link.
    fn kind(&self) -> LinkKind;

    /// When the last character of the last `send` left the line, where the transport
    /// knows better than the clock read after `send` returns (a paced pseudo-terminal
    /// computes it from the time of its last write). None: read the clock.
    fn sent_at(&self) -> Option<std::time::Instant> {
        None
    }

    /// Where the other end is an emulated line paced by this host (the simulator): how
    /// late its paced writes came, at most. Gaps up to that long are the host's. None
    /// where the other end is a real device.
    fn peer_lateness(&self) -> Option<Duration> {
        None
    }

    /// Whether the last `send`, paced by this host, left a gap over t1.5 between two of
    /// its characters (the host stalled): the frame on the line is not the one sent.
    fn send_was_broken(&self) -> bool {
        false
    }

    /// The line settings whose timing the link reproduces: a real serial port, or a
    /// pseudo-terminal paced at the line's character time. `None` where bytes arrive with
    /// the host's timing only.
    fn line_timing(&self) -> Option<LineSettings>;

    /// Where this is the receiving end of an emulated line whose sender says what
    /// silences it put on it (see [`LineTags`]): the queue to take them from.
    fn line_tags(&self) -> Option<LineTags> {
        None
    }

    /// The end of an emulated line that a simulator writes its replies to: the queue in
    /// which it says when it began each one (see [`ReplyStarts`]).
    fn reply_starts(&self) -> Option<ReplyStarts> {
        None
    }

    /// The other end of that line (the master's): the same queue, to read.
    fn peer_reply_starts(&self) -> Option<ReplyStarts> {
        None
    }

    /// Sends `pieces` as one transmission with `gap` of silence between consecutive
    /// pieces (from the end of one piece's last character to the start of the next
    /// one's first), for timing damage: a gap inside a frame, two frames without t3.5.
    /// Returns the gaps as they left this host, in order; the caller judges whether they
    /// stayed near `gap` (a host that stalls moves them) and sends again if not. Only
    /// links with line timing can carry a gap that means anything; elsewhere the default
    /// sends the pieces one after the other with a sleep between them.
    fn send_pieces(
        &mut self,
        pieces: &[&[u8]],
        gap: std::time::Duration,
    ) -> Result<Vec<std::time::Duration>, TransportError> {
        send_gapped(pieces, gap, |p| {
            self.send(p)?;
            Ok(self.sent_at().unwrap_or_else(std::time::Instant::now))
        })
    }

    /// Where the link carries whole valid frames only, re-framed (a Modbus TCP gateway:
    /// the PDU crosses, not the serial line's bytes): why the line itself cannot be seen,
    /// the reason every check and fuzz case that needs it is skipped with. None: the bytes
    /// sent are the bytes on the line.
    fn frames_only(&self) -> Option<&'static str> {
        None
    }

    /// What the link itself said since the last call, in place of or beside the device's
    /// bytes: a gateway's exception 0AH/0BH (handed up as silence: the serial line was
    /// silent), a late or second reply dropped. Empty for a plain line.
    fn take_notes(&mut self) -> Vec<String> {
        Vec::new()
    }
}

impl<T: Transport + ?Sized> Transport for Box<T> {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        (**self).send(bytes)
    }
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        (**self).recv(buf, timeout)
    }
    fn discard_input(&mut self) -> Result<(), TransportError> {
        (**self).discard_input()
    }
    fn describe(&self) -> String {
        (**self).describe()
    }
    fn kind(&self) -> LinkKind {
        (**self).kind()
    }
    fn line_timing(&self) -> Option<LineSettings> {
        (**self).line_timing()
    }
    fn sent_at(&self) -> Option<std::time::Instant> {
        (**self).sent_at()
    }
    fn peer_lateness(&self) -> Option<Duration> {
        (**self).peer_lateness()
    }
    fn send_was_broken(&self) -> bool {
        (**self).send_was_broken()
    }
    fn send_pieces(
        &mut self,
        pieces: &[&[u8]],
        gap: std::time::Duration,
    ) -> Result<Vec<std::time::Duration>, TransportError> {
        (**self).send_pieces(pieces, gap)
    }
    fn line_tags(&self) -> Option<LineTags> {
        (**self).line_tags()
    }
    fn reply_starts(&self) -> Option<ReplyStarts> {
        (**self).reply_starts()
    }
    fn peer_reply_starts(&self) -> Option<ReplyStarts> {
        (**self).peer_reply_starts()
    }
    fn frames_only(&self) -> Option<&'static str> {
        (**self).frames_only()
    }
    fn take_notes(&mut self) -> Vec<String> {
        (**self).take_notes()
    }
}

/// Sends `pieces` by `send`, which says when the piece it sent ended, sleeping `gap` from
/// that end before the next; returns the gaps as they left this host (the sleep may
/// overrun it), for [`Transport::send_pieces`].
pub(crate) fn send_gapped(
    pieces: &[&[u8]],
    gap: Duration,
    mut send: impl FnMut(&[u8]) -> Result<std::time::Instant, TransportError>,
) -> Result<Vec<Duration>, TransportError> {
    let mut gaps = Vec::new();
    let mut end: Option<std::time::Instant> = None;
    for p in pieces {
        if let Some(e) = end {
            sleep_until(e + gap);
            gaps.push(std::time::Instant::now().saturating_duration_since(e));
        }
        end = Some(send(p)?);
    }
    Ok(gaps)
}

/// Sleeps until `deadline`, in short steps at the end so that pacing at a character time
/// of about a millisecond stays accurate.
pub(crate) fn sleep_until(deadline: std::time::Instant) {
    loop {
        let now = std::time::Instant::now();
        if now >= deadline {
            return;
        }
        let left = deadline - now;
        if left > Duration::from_micros(300) {
            std::thread::sleep(left - Duration::from_micros(200));
        } else {
            std::hint::spin_loop();
        }
    }
}
