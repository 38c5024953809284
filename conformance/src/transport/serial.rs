//! A real serial port, by the `serialport` crate (built without libudev), with the line
//! settings spelled as mbpoll spells them. It also opens the slave side of a
//! pseudo-terminal, which is how the runner reaches the in-process simulator.
//!
//! RS-485 direction control ([`SerialTransport::with_rts`]): adapters whose driver enable
//! (DE/RE of a MAX485) hangs on RTS need RTS raised while this side transmits and dropped
//! as soon as the last bit has left, or the drive's reply collides with a transmitter that
//! is still on. [`send_with_rts`] raises RTS, writes, waits with tcdrain until the port
//! says the output is sent, waits one more character time (tcdrain of USB adapters
//! returns when the bytes left the host, not the wire) plus the extra delay asked for,
//! and drops RTS. Adapters with automatic direction control (most FTDI and CH340 RS-485
//! adapters) need none of it. A pseudo-terminal has no modem lines (TIOCMBIS is ENOTTY).

use std::io::{Read, Write};
use std::time::Duration;

use super::{send_gapped, sleep_until, LineTags, LinkKind, Transport, TransportError};
use crate::codec::timing::{LineSettings, Parity};

/// An open serial port.
pub struct SerialTransport {
    port: Box<dyn serialport::SerialPort>,
    path: String,
    line: LineSettings,
    kind: LinkKind,
    paced: bool,
    sent_at: Option<std::time::Instant>,
    broken: bool,
    peer_clock: Option<std::sync::Arc<std::sync::atomic::AtomicU64>>,
    rts: Option<RtsControl>,
    tags: Option<LineTags>,
    last_write: Option<std::time::Instant>,
    stall_inside: Option<(usize, Duration)>,
    reply_starts: Option<super::ReplyStarts>,
}

/// RS-485 direction control by the RTS line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub struct RtsControl {
    /// Extra time RTS stays up after the last character has left (mbpoll and libmodbus
    /// call it the RTS delay).
    pub extra: Duration,
}

/// The port calls that direction control makes, so that a test can record their order.
pub trait PortControl {
    /// Sets RTS high (`true`: transmitter on) or low.
    fn set_rts(&mut self, high: bool) -> std::io::Result<()>;
    /// Writes all of `bytes` to the port's output queue.
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()>;
    /// Waits until the output queue has been transmitted (tcdrain).
    fn drain(&mut self) -> std::io::Result<()>;
    /// Waits `d`.
    fn sleep(&mut self, d: Duration);
}

/// Sends `bytes` with RTS up: RTS on, write, drain, one character time and `rts.extra`,
/// RTS off. RTS is dropped also when the write fails, so that the bus is not held.
pub fn send_with_rts(
    port: &mut dyn PortControl,
    bytes: &[u8],
    char_time: Duration,
    rts: RtsControl,
) -> std::io::Result<()> {
    port.set_rts(true)?;
    let sent = port.write_all(bytes).and_then(|_| port.drain());
    if sent.is_ok() {
        port.sleep(char_time + rts.extra);
    }
    let off = port.set_rts(false);
    sent.and(off)
}

struct Port<'a>(&'a mut dyn serialport::SerialPort);

impl PortControl for Port<'_> {
    fn set_rts(&mut self, high: bool) -> std::io::Result<()> {
        self.0.write_request_to_send(high).map_err(Into::into)
    }
    fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
        self.0.write_all(bytes)
    }
    fn drain(&mut self) -> std::io::Result<()> {
        // serialport's flush is tcdrain on Unix.
        self.0.flush()
    }
    fn sleep(&mut self, d: Duration) {
        sleep_until(std::time::Instant::now() + d);
    }
}

fn serial_settings(
    line: &LineSettings,
) -> (
    serialport::DataBits,
    serialport::Parity,
    serialport::StopBits,
) {
    let data_bits = match line.data_bits {
        5 => serialport::DataBits::Five,
        6 => serialport::DataBits::Six,
        7 => serialport::DataBits::Seven,
        _ => serialport::DataBits::Eight,
    };
    let parity = match line.parity {
        Parity::None => serialport::Parity::None,
        Parity::Even => serialport::Parity::Even,
        Parity::Odd => serialport::Parity::Odd,
    };
    let stop_bits = if line.stop_bits == 2 {
        serialport::StopBits::Two
    } else {
        serialport::StopBits::One
    };
    (data_bits, parity, stop_bits)
}

impl SerialTransport {
    /// Opens `path` with `line` settings. `kind` says whether it is a real port
    /// ([`LinkKind::Serial`]) or a pseudo-terminal's slave ([`LinkKind::Pty`]), whose
    /// timing is not a line's.
    pub fn open(path: &str, line: LineSettings, kind: LinkKind) -> Result<Self, TransportError> {
        let open_err = |e: serialport::Error| TransportError::Open {
            what: path.to_string(),
            source: e.into(),
        };
        let (data_bits, parity, stop_bits) = serial_settings(&line);
        let port = serialport::new(path, line.baud)
            .data_bits(data_bits)
            .parity(parity)
            .stop_bits(stop_bits)
            .flow_control(serialport::FlowControl::None)
            .timeout(Duration::from_millis(10))
            .open()
            .map_err(open_err)?;
        Ok(SerialTransport {
            port,
            path: path.to_string(),
            line,
            kind,
            paced: false,
            sent_at: None,
            broken: false,
            peer_clock: None,
            rts: None,
            tags: None,
            last_write: None,
            stall_inside: None,
            reply_starts: None,
        })
    }

    /// Drives RTS for RS-485 direction control (see the module notes); RTS is dropped
    /// (receive) at once. Fails where the port has no RTS line (a pseudo-terminal).
    pub fn with_rts(mut self, rts: Option<RtsControl>) -> Result<Self, TransportError> {
        if rts.is_some() {
            self.port.write_request_to_send(false).map_err(|e| {
                let source: std::io::Error = e.into();
                TransportError::Open {
                    what: format!(
                        "{} with RTS direction control (the port has no RTS line it can drive: {source})",
                        self.path
                    ),
                    source,
                }
            })?;
        }
        self.rts = rts;
        Ok(self)
    }

    /// Sets other line settings on the open port (a scan tries one after the other).
    pub fn set_line(&mut self, line: LineSettings) -> Result<(), TransportError> {
        let (data_bits, parity, stop_bits) = serial_settings(&line);
        let r = self
            .port
            .set_baud_rate(line.baud)
            .and_then(|_| self.port.set_data_bits(data_bits))
            .and_then(|_| self.port.set_parity(parity))
            .and_then(|_| self.port.set_stop_bits(stop_bits));
        r.map_err(|e| self.err("set line settings", e.into()))?;
        self.line = line;
        Ok(())
    }

    /// The line settings the port is set to.
    pub fn line(&self) -> LineSettings {
        self.line
    }

    /// Declares that this pseudo-terminal stands in for a line: the other end sends at the
    /// line's character time (the simulator with pacing), and so does this end, so that
    /// arrival times and request times are a line's timing.
    pub fn paced_peer(mut self) -> Self {
        self.paced = true;
        self
    }

    /// Shares the pacing clock of the other end (the simulator's pseudo-terminal), so
    /// that [`Transport::peer_lateness`] can say which gaps the host made.
    pub fn with_peer_clock(mut self, clock: std::sync::Arc<std::sync::atomic::AtomicU64>) -> Self {
        self.peer_clock = Some(clock);
        self
    }

    /// Sends `pieces` at the line's character time with `gap` of silence between
    /// consecutive pieces; returns the gaps as written.
    ///
    /// Where the other end is told the silences ([`Self::with_line_tags`]), a piece is
    /// one write to a UART: its characters' silences are queued before its first
    /// character leaves, each 0 after the first, so a host stall inside the piece only
    /// delays characters the receiver knows to be in flight, and the frame stays whole,
    /// as a real port's transmitter keeps it (issue 33: a stall over t1.5 while pacing
    /// broke the request on the emulated line, and the runner sent it again or gave up).
    /// Without tags a stall inside a piece (a silence over t1.5 between two of its
    /// characters) is on the line, and marks the send broken.
    fn paced_pieces(
        &mut self,
        pieces: &[&[u8]],
        gap: Duration,
    ) -> Result<Vec<Duration>, TransportError> {
        let char_time = Duration::from_micros(self.line.char_time_us());
        let t15 = Duration::from_micros(self.line.t1_5_us());
        self.broken = false;
        let mut gaps = Vec::new();
        let mut due = std::time::Instant::now();
        let mut previous: Option<std::time::Instant> = None;
        let mut previous_written: Option<std::time::Instant> = None;
        for (k, piece) in pieces.iter().enumerate() {
            if k > 0 {
                due += gap;
            }
            for (i, b) in piece.iter().enumerate() {
                sleep_until(due);
                if let Some((at, stall)) = self.stall_inside {
                    if at == i && k == 0 {
                        self.stall_inside = None;
                        std::thread::sleep(stall);
                    }
                }
                let now = std::time::Instant::now();
                if let Some(p) = previous {
                    let silence = now.saturating_duration_since(p).saturating_sub(char_time);
                    if i == 0 {
                        gaps.push(silence);
                    } else if silence > t15 && self.tags.is_none() {
                        self.broken = true;
                    }
                }
                previous = Some(now);
                if i == 0 {
                    self.tell_piece(now, char_time, piece.len());
                }
                self.last_write = Some(std::time::Instant::now());
                if let Err(e) = self
                    .port
                    .write_all(std::slice::from_ref(b))
                    .and_then(|_| self.port.flush())
                {
                    // The characters not written are not in flight.
                    self.untell(piece.len() - i);
                    return Err(self.err("write", e));
                }
                // A stall between the clock's reading above and the write (the thread
                // preempted there) is on the line too: judged again by when the write
                // returned.
                let written = std::time::Instant::now();
                if let Some(p) = previous_written {
                    let silence = written
                        .saturating_duration_since(p)
                        .saturating_sub(char_time);
                    if i > 0 && silence > t15 && self.tags.is_none() {
                        self.broken = true;
                    }
                }
                previous_written = Some(written);
                due += char_time;
            }
        }
        // The last character is on the line for one more character time, counted from
        // when it was written (a busy host may write it late, or wake late from here).
        let end = due.max(previous.map_or(due, |p| p + char_time));
        self.sent_at = Some(end);
        sleep_until(end);
        Ok(gaps)
    }

    /// Queues, for the receiver, the silences before the `n` characters of a piece whose
    /// first character leaves at `now`: the silence since the last character written,
    /// then none (a UART sends a piece's characters back to back).
    fn tell_piece(&self, now: std::time::Instant, char_time: Duration, n: usize) {
        let Some(tags) = &self.tags else { return };
        let silence = self.last_write.map_or(u32::MAX, |w| {
            let us = now.saturating_duration_since(w).saturating_sub(char_time);
            u32::try_from(us.as_micros()).unwrap_or(u32::MAX)
        });
        if let Ok(mut q) = tags.lock() {
            q.push_back(silence);
            q.extend(std::iter::repeat_n(0, n.saturating_sub(1)));
        }
    }

    /// Takes back the silences of the last `n` characters queued, which were not written.
    fn untell(&self, n: usize) {
        if let Some(Ok(mut q)) = self.tags.as_ref().map(|t| t.lock()) {
            let keep = q.len().saturating_sub(n);
            q.truncate(keep);
        }
    }

    /// For the suite's own tests: the next send stalls this host for `stall` before the
    /// character at index `at` of its first piece leaves, as a busy scheduler does.
    #[doc(hidden)]
    pub fn stall_inside_next_send(&mut self, at: usize, stall: Duration) {
        self.stall_inside = Some((at, stall));
    }

    /// Reads, from the simulator at the other end, when it began each reply (see
    /// [`super::ReplyStarts`]).
    pub fn with_reply_starts(mut self, starts: super::ReplyStarts) -> Self {
        self.reply_starts = Some(starts);
        self
    }

    /// Says, for every character this paced end writes, the silence before it (as it
    /// left this host) to the simulator at the other end (see [`LineTags`]).
    pub fn with_line_tags(mut self, tags: LineTags) -> Self {
        self.tags = Some(tags);
        self
    }

    fn err(&self, what: &'static str, source: std::io::Error) -> TransportError {
        match source.kind() {
            std::io::ErrorKind::BrokenPipe | std::io::ErrorKind::UnexpectedEof => {
                TransportError::Closed {
                    link: self.describe(),
                }
            }
            _ => TransportError::Io {
                what,
                link: self.describe(),
                source,
            },
        }
    }
}

impl Transport for SerialTransport {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        if let Some(rts) = self.rts {
            let char_time = Duration::from_micros(self.line.char_time_us());
            return send_with_rts(&mut Port(self.port.as_mut()), bytes, char_time, rts)
                .map_err(|e| self.err("write", e));
        }
        if !self.paced || self.kind == LinkKind::Serial {
            return self
                .port
                .write_all(bytes)
                .and_then(|_| self.port.flush())
                .map_err(|e| self.err("write", e));
        }
        // A pseudo-terminal standing in for a line: this end sends at the line's
        // character time too, so that a request takes its time on the wire.
        self.paced_pieces(&[bytes], Duration::ZERO).map(|_| ())
    }

    fn send_pieces(
        &mut self,
        pieces: &[&[u8]],
        gap: Duration,
    ) -> Result<Vec<Duration>, TransportError> {
        if self.paced && self.kind != LinkKind::Serial {
            return self.paced_pieces(pieces, gap);
        }
        // A real port: each piece written and drained (tcdrain: the UART has sent it;
        // a USB adapter may still hold it for its latency timer, which the gaps
        // returned cannot see), then the gap slept.
        send_gapped(pieces, gap, |p| {
            self.port
                .write_all(p)
                .and_then(|_| self.port.flush())
                .map_err(|e| self.err("write", e))?;
            Ok(std::time::Instant::now())
        })
    }

    fn sent_at(&self) -> Option<std::time::Instant> {
        self.sent_at
    }

    fn send_was_broken(&self) -> bool {
        self.broken
    }

    fn peer_reply_starts(&self) -> Option<super::ReplyStarts> {
        self.reply_starts.clone()
    }

    fn peer_lateness(&self) -> Option<Duration> {
        self.peer_clock
            .as_ref()
            .map(|c| Duration::from_micros(c.load(std::sync::atomic::Ordering::Relaxed)))
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        // serialport treats a zero timeout as "block"; a microsecond is "don't wait".
        let t = timeout.max(Duration::from_micros(1));
        self.port
            .set_timeout(t)
            .map_err(|e| self.err("set timeout", e.into()))?;
        match self.port.read(buf) {
            Ok(0) => Err(TransportError::Closed {
                link: self.describe(),
            }),
            Ok(n) => Ok(n),
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => Ok(0),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(0),
            Err(e) => Err(self.err("read", e)),
        }
    }

    fn discard_input(&mut self) -> Result<(), TransportError> {
        self.port
            .clear(serialport::ClearBuffer::Input)
            .map_err(|e| self.err("clear", e.into()))
    }

    fn describe(&self) -> String {
        let l = self.line;
        format!(
            "{} {} {} {}{}{}{}{}",
            self.kind,
            self.path,
            l.baud,
            l.data_bits,
            l.parity,
            l.stop_bits,
            if self.paced && self.kind != LinkKind::Serial {
                " (both ends send at the line's character time)"
            } else {
                ""
            },
            match self.rts {
                Some(r) => format!(
                    " (RTS direction control, RTS dropped {} us after the last character)",
                    self.line.char_time_us()
                        + u64::try_from(r.extra.as_micros()).unwrap_or(u64::MAX)
                ),
                None => String::new(),
            }
        )
    }

    fn kind(&self) -> LinkKind {
        self.kind
    }

    fn line_timing(&self) -> Option<LineSettings> {
        (self.kind == LinkKind::Serial || self.paced).then_some(self.line)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Records the calls direction control makes.
    #[derive(Default)]
    struct Recorder {
        calls: Vec<String>,
        fail_write: bool,
    }

    impl PortControl for Recorder {
        fn set_rts(&mut self, high: bool) -> std::io::Result<()> {
            self.calls
                .push(format!("rts {}", if high { "on" } else { "off" }));
            Ok(())
        }
        fn write_all(&mut self, bytes: &[u8]) -> std::io::Result<()> {
            self.calls.push(format!("write {}", bytes.len()));
            if self.fail_write {
                return Err(std::io::Error::other("unplugged"));
            }
            Ok(())
        }
        fn drain(&mut self) -> std::io::Result<()> {
            self.calls.push("drain".into());
            Ok(())
        }
        fn sleep(&mut self, d: Duration) {
            self.calls.push(format!("sleep {} us", d.as_micros()));
        }
    }

    #[test]
    fn rts_is_up_while_sending_and_dropped_a_character_after_the_drain() {
        let line = LineSettings::new(9600, 8, Parity::Even, 1);
        let ct = Duration::from_micros(line.char_time_us());
        let mut r = Recorder::default();
        send_with_rts(
            &mut r,
            &[1, 3, 0, 0, 0, 1, 0x84, 0x0A],
            ct,
            RtsControl::default(),
        )
        .unwrap();
        assert_eq!(
            r.calls,
            ["rts on", "write 8", "drain", "sleep 1146 us", "rts off"]
        );
        // --rts-delay adds its microseconds before RTS drops.
        let mut r = Recorder::default();
        let rts = RtsControl {
            extra: Duration::from_micros(500),
        };
        send_with_rts(&mut r, &[1, 2], ct, rts).unwrap();
        assert_eq!(
            r.calls,
            ["rts on", "write 2", "drain", "sleep 1646 us", "rts off"]
        );
    }

    #[test]
    fn rts_is_dropped_when_the_write_fails() {
        let mut r = Recorder {
            fail_write: true,
            ..Recorder::default()
        };
        let e = send_with_rts(
            &mut r,
            &[1],
            Duration::from_micros(100),
            RtsControl::default(),
        )
        .unwrap_err();
        assert_eq!(e.to_string(), "unplugged");
        assert_eq!(r.calls, ["rts on", "write 1", "rts off"]);
    }
}
