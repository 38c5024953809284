//! A real serial port, by the `serialport` crate (built without libudev), with the line
//! settings spelled as mbpoll spells them. It also opens the slave side of a
//! pseudo-terminal, which is how the runner reaches the in-process simulator.

use std::io::{Read, Write};
use std::time::Duration;

use super::{sleep_until, LineTags, LinkKind, Transport, TransportError};
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
    tags: Option<LineTags>,
    last_write: Option<std::time::Instant>,
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
            tags: None,
            last_write: None,
        })
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
    /// consecutive pieces; returns the gaps as written. A stall of the host inside a
    /// piece (a silence over t1.5 between two of its characters) marks the send broken.
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
        for (k, piece) in pieces.iter().enumerate() {
            if k > 0 {
                due += gap;
            }
            for (i, b) in piece.iter().enumerate() {
                sleep_until(due);
                let now = std::time::Instant::now();
                if let Some(p) = previous {
                    let silence = now.saturating_duration_since(p).saturating_sub(char_time);
                    if i == 0 {
                        gaps.push(silence);
                    } else if silence > t15 {
                        self.broken = true;
                    }
                }
                previous = Some(now);
                if let Some(tags) = &self.tags {
                    let silence = self.last_write.map_or(u32::MAX, |w| {
                        let us = now.saturating_duration_since(w).saturating_sub(char_time);
                        u32::try_from(us.as_micros()).unwrap_or(u32::MAX)
                    });
                    if let Ok(mut q) = tags.lock() {
                        q.push_back(silence);
                    }
                }
                self.last_write = Some(now);
                self.port
                    .write_all(std::slice::from_ref(b))
                    .and_then(|_| self.port.flush())
                    .map_err(|e| self.err("write", e))?;
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
        let mut gaps = Vec::new();
        let mut end: Option<std::time::Instant> = None;
        for p in pieces {
            if let Some(e) = end {
                sleep_until(e + gap);
                gaps.push(std::time::Instant::now().saturating_duration_since(e));
            }
            self.port
                .write_all(p)
                .and_then(|_| self.port.flush())
                .map_err(|e| self.err("write", e))?;
            end = Some(std::time::Instant::now());
        }
        Ok(gaps)
    }

    fn sent_at(&self) -> Option<std::time::Instant> {
        self.sent_at
    }

    fn send_was_broken(&self) -> bool {
        self.broken
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
            "{} {} {} {}{}{}{}",
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
