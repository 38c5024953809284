//! A real serial port, by the `serialport` crate (built without libudev), with the line
//! settings spelled as mbpoll spells them. It also opens the slave side of a
//! pseudo-terminal, which is how the runner reaches the in-process simulator.

use std::io::{Read, Write};
use std::time::Duration;

use super::{sleep_until, LinkKind, Transport, TransportError};
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
        let char_time = Duration::from_micros(self.line.char_time_us());
        let t15 = Duration::from_micros(self.line.t1_5_us());
        let start = std::time::Instant::now();
        self.broken = false;
        let mut previous: Option<std::time::Instant> = None;
        for (i, b) in bytes.iter().enumerate() {
            sleep_until(start + char_time * u32::try_from(i).unwrap_or(u32::MAX));
            let now = std::time::Instant::now();
            if previous.is_some_and(|p| now.duration_since(p) > char_time + t15) {
                self.broken = true;
            }
            previous = Some(now);
            self.port
                .write_all(std::slice::from_ref(b))
                .and_then(|_| self.port.flush())
                .map_err(|e| self.err("write", e))?;
        }
        // The last character is on the line for one more character time, counted from
        // when it was written (a busy host may write it late, or wake late from here).
        let end = (start + char_time * u32::try_from(bytes.len()).unwrap_or(u32::MAX))
            .max(std::time::Instant::now() + char_time);
        self.sent_at = Some(end);
        sleep_until(end);
        Ok(())
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
