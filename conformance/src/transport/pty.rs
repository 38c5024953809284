//! Pseudo-terminal pairs: the simulator holds the master side and another program (the
//! runner, mbpoll, pymodbus) opens the slave path as if it were a serial port.
//!
//! The slave side is put in raw mode (no echo, no CR/LF translation, which would break
//! ASCII frames) and held open by this side too, so that the master does not see a hang-up
//! each time a client closes the slave. A pseudo-terminal has no baud rate: with pacing on,
//! [`PtyMaster::send`] writes one character per character time of the given line
//! settings, so that the receiver sees a line's timing.

use std::os::fd::{AsFd, OwnedFd};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use nix::errno::Errno;
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};

use super::{sleep_until, LineTags, LinkKind, Transport, TransportError};
use crate::codec::timing::LineSettings;

/// The master side of a pseudo-terminal pair.
pub struct PtyMaster {
    master: OwnedFd,
    // Held open so that the master never reads a hang-up while no client has it open.
    _slave: OwnedFd,
    slave_path: PathBuf,
    pace: Option<LineSettings>,
    late: PacingClock,
    tags: LineTags,
}

/// How late a paced sender's writes came against their schedule, at most, in
/// microseconds: on a busy host the thread that paces a line's characters wakes late, and
/// the gaps it leaves are the host's, not the device's. Shared with the other end's
/// transport so that a master can tell.
pub type PacingClock = std::sync::Arc<std::sync::atomic::AtomicU64>;

fn io(e: Errno) -> std::io::Error {
    std::io::Error::from_raw_os_error(e as i32)
}

impl PtyMaster {
    /// Opens a new pair; with `pace`, sends at that line's character time.
    pub fn open(pace: Option<LineSettings>) -> Result<Self, TransportError> {
        let open_err = |e: Errno| TransportError::Open {
            what: "a pseudo-terminal pair".into(),
            source: io(e),
        };
        let pair = nix::pty::openpty(None, None).map_err(open_err)?;
        let mut t = tcgetattr(&pair.slave).map_err(open_err)?;
        cfmakeraw(&mut t);
        tcsetattr(&pair.slave, SetArg::TCSANOW, &t).map_err(open_err)?;
        let slave_path = nix::unistd::ttyname(&pair.slave).map_err(open_err)?;
        Ok(PtyMaster {
            master: pair.master,
            _slave: pair.slave,
            slave_path,
            pace,
            late: PacingClock::default(),
            tags: LineTags::default(),
        })
    }

    /// How late this end's paced writes came, at most (shared; see [`PacingClock`]).
    pub fn pacing_clock(&self) -> PacingClock {
        self.late.clone()
    }

    /// The queue in which a sender on the slave side says what silences it put before
    /// its characters (see [`LineTags`]); read by this end's receiver when paced.
    pub fn line_tags(&self) -> LineTags {
        self.tags.clone()
    }

    /// The path another program opens as its serial port.
    pub fn slave_path(&self) -> &std::path::Path {
        &self.slave_path
    }

    fn err(&self, what: &'static str, e: Errno) -> TransportError {
        TransportError::Io {
            what,
            link: self.describe(),
            source: io(e),
        }
    }

    fn write_all(&self, mut bytes: &[u8]) -> Result<(), TransportError> {
        while !bytes.is_empty() {
            match nix::unistd::write(&self.master, bytes) {
                Ok(n) => bytes = &bytes[n..],
                Err(Errno::EINTR) => {}
                Err(Errno::EAGAIN) => std::thread::sleep(Duration::from_millis(1)),
                Err(e) => return Err(self.err("write", e)),
            }
        }
        Ok(())
    }
}

impl Transport for PtyMaster {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        match self.pace {
            None => self.write_all(bytes),
            Some(line) => {
                let char_time = Duration::from_micros(line.char_time_us());
                let start = Instant::now();
                for (i, b) in bytes.iter().enumerate() {
                    let i = u32::try_from(i).unwrap_or(u32::MAX);
                    let due = start + char_time * i;
                    sleep_until(due);
                    let late = u64::try_from(Instant::now().duration_since(due).as_micros())
                        .unwrap_or(u64::MAX);
                    self.late
                        .fetch_max(late, std::sync::atomic::Ordering::Relaxed);
                    self.write_all(std::slice::from_ref(b))?;
                }
                // The last character is on the line for one more character time.
                sleep_until(start + char_time * u32::try_from(bytes.len()).unwrap_or(u32::MAX));
                Ok(())
            }
        }
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        let ms = u16::try_from(timeout.as_millis()).unwrap_or(u16::MAX);
        let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLIN)];
        match poll(&mut fds, PollTimeout::from(ms)) {
            Ok(0) => return Ok(0),
            Ok(_) => {}
            Err(Errno::EINTR) => return Ok(0),
            Err(e) => return Err(self.err("poll", e)),
        }
        match nix::unistd::read(&self.master, buf) {
            Ok(0) => Err(TransportError::Closed {
                link: self.describe(),
            }),
            Ok(n) => Ok(n),
            Err(Errno::EINTR | Errno::EAGAIN) => Ok(0),
            Err(Errno::EIO) => Err(TransportError::Closed {
                link: self.describe(),
            }),
            Err(e) => Err(self.err("read", e)),
        }
    }

    fn discard_input(&mut self) -> Result<(), TransportError> {
        let mut buf = [0u8; 256];
        while self.recv(&mut buf, Duration::ZERO)? > 0 {}
        Ok(())
    }

    fn describe(&self) -> String {
        match self.pace {
            Some(l) => format!(
                "pty {} (paced at {} baud {}{}{})",
                self.slave_path.display(),
                l.baud,
                l.data_bits,
                l.parity,
                l.stop_bits
            ),
            None => format!("pty {}", self.slave_path.display()),
        }
    }

    fn kind(&self) -> LinkKind {
        LinkKind::Pty
    }

    fn line_timing(&self) -> Option<LineSettings> {
        self.pace
    }

    fn line_tags(&self) -> Option<LineTags> {
        self.pace.map(|_| self.tags.clone())
    }
}
