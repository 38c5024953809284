//! An endpoint of the line inside this process: a simulated drive's link. The drive's
//! server loop ([`crate::sim::serve`]) reads and writes it as it would a paced
//! pseudo-terminal; the line knows when each character it hands over started, so it
//! tells the silence before each one ([`crate::transport::LineTags`]) and the drive
//! frames RTU by the line's own schedule, not by when its thread woke.
//!
//! The line's own thread can be late too (a busy host stalls it for milliseconds): a
//! drive that read three characters of a request, then nothing for longer than t3.5,
//! would end the frame there, although the rest is on the line and only waits for that
//! thread. So while the line is carrying characters, a read that found nothing waits
//! on (at most [`BUSY_WAIT`]) for them, and the drive sees quiet only when the line is.

use std::io::{Read, Write};
use std::os::fd::AsFd;
use std::os::unix::net::UnixStream;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

use nix::errno::Errno;
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};

use crate::codec::timing::{later, LineSettings};
use crate::transport::{sleep_until, LineTags, LinkKind, Transport, TransportError};

/// Longest a read waits past its timeout while the line is busy (so that a stop is
/// still seen on a line that never goes quiet).
pub const BUSY_WAIT: Duration = Duration::from_secs(1);

/// Whether the line is carrying characters (set by the line's thread).
pub(crate) type Busy = Arc<AtomicBool>;

/// The drive's side of an endpoint inside this process.
pub struct Station {
    name: String,
    sock: UnixStream,
    line: Option<LineSettings>,
    tags: LineTags,
    busy: Busy,
}

impl Station {
    /// A station and the line's side of it (its socket and the queue of told silences).
    pub(crate) fn pair(
        name: &str,
        line: Option<LineSettings>,
        busy: Busy,
    ) -> std::io::Result<(Station, UnixStream, LineTags)> {
        let (a, b) = UnixStream::pair()?;
        b.set_nonblocking(true)?;
        let tags = LineTags::default();
        Ok((
            Station {
                name: name.to_string(),
                sock: a,
                line,
                tags: tags.clone(),
                busy,
            },
            b,
            tags,
        ))
    }

    fn io(&self, what: &'static str, source: std::io::Error) -> TransportError {
        TransportError::Io {
            what,
            link: self.describe(),
            source,
        }
    }
}

impl Transport for Station {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        let start = Instant::now();
        match self.sock.write_all(bytes) {
            Ok(()) => {}
            Err(e) if e.kind() == std::io::ErrorKind::BrokenPipe => {
                return Err(TransportError::Closed {
                    link: self.describe(),
                })
            }
            Err(e) => return Err(self.io("write", e)),
        }
        // As a paced transport: back when the line would have carried them (unless a
        // collision or a queue delayed them, which the line knows and this side does not).
        if let Some(l) = self.line {
            let n = u32::try_from(bytes.len()).unwrap_or(u32::MAX);
            sleep_until(later(
                start,
                Duration::from_micros(l.char_time_us()).saturating_mul(n),
            ));
        }
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        let t0 = Instant::now();
        let mut wait = timeout;
        loop {
            let ms = u16::try_from(wait.as_millis()).unwrap_or(u16::MAX);
            let mut fds = [PollFd::new(self.sock.as_fd(), PollFlags::POLLIN)];
            match poll(&mut fds, PollTimeout::from(ms)) {
                Ok(0) | Err(Errno::EINTR) => {}
                Ok(_) => break,
                Err(e) => return Err(self.io("poll", std::io::Error::from_raw_os_error(e as i32))),
            }
            // Nothing yet: quiet only if the line is (see the module notes).
            if self.line.is_none()
                || !self.busy.load(Ordering::Acquire)
                || t0.elapsed() >= timeout.saturating_add(BUSY_WAIT)
            {
                return Ok(0);
            }
            wait = Duration::from_millis(1);
        }
        match self.sock.read(buf) {
            Ok(0) => Err(TransportError::Closed {
                link: self.describe(),
            }),
            Ok(n) => Ok(n),
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => Ok(0),
            Err(e) => Err(self.io("read", e)),
        }
    }

    fn discard_input(&mut self) -> Result<(), TransportError> {
        // Held while draining: the line pushes a character's silence and writes it under
        // this lock, so the queue and the bytes stay in step.
        let tags = self.tags.clone();
        let mut told = tags.lock().ok();
        let mut buf = [0u8; 256];
        while self.recv(&mut buf, Duration::ZERO)? > 0 {}
        if let Some(t) = told.as_mut() {
            t.clear();
        }
        Ok(())
    }

    fn describe(&self) -> String {
        match self.line {
            Some(l) => format!("endpoint {} of the emulated line at {l}", self.name),
            None => format!("endpoint {} of the emulated line (unpaced)", self.name),
        }
    }

    fn kind(&self) -> LinkKind {
        LinkKind::Memory
    }

    fn line_timing(&self) -> Option<LineSettings> {
        self.line
    }

    fn line_tags(&self) -> Option<LineTags> {
        self.line.map(|_| self.tags.clone())
    }
}
