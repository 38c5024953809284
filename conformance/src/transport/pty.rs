//! Pseudo-terminal pairs: the simulator holds the master side and another program (the
//! runner, mbpoll, pymodbus) opens the slave path as if it were a serial port.
//!
//! The slave side is put in raw mode (no echo, no CR/LF translation, which would break
//! ASCII frames) and held open by this side too, so that the master does not see a hang-up
//! each time a client closes the slave. A pseudo-terminal has no baud rate: with pacing on,
//! [`PtyMaster::send`] writes one character per character time of the given line
//! settings, so that the receiver sees a line's timing.
//!
//! Line emulation ([`PtyMaster::with_line_emulation`]): on Linux the termios of a pair is
//! the slave's, and this side reads what the other program set with tcsetattr: the baud
//! rate, PARODD, CSTOPB and the input flags INPCK, IGNPAR, PARMRK. The pty driver clears
//! PARENB and forces CS8, so the parity is inferred from the flags masters set with it
//! (PARODD: odd; INPCK without PARODD: even, as the serialport crate and libmodbus set
//! them; neither: none; pyserial's even parity, which leaves INPCK off, looks like none)
//! and the data bits are taken as this side's. Where the other end's settings differ
//! from this side's, what it sends is read as a drive's UART at this side's settings
//! would read it ([`super::uart::transcode`]; characters with errors are dropped), and
//! what this side sends reaches it as its UART would deliver it (errors handled as its
//! input flags say). A peer whose input and output baud rates differ is not emulated.

use std::os::fd::{AsFd, OwnedFd};
use std::path::PathBuf;
use std::time::{Duration, Instant};

use nix::errno::Errno;
use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};

use super::uart::{self, ErrorPolicy};
use super::{sleep_until, LineTags, LinkKind, Transport, TransportError};
use crate::codec::timing::{LineSettings, Parity};

/// The master side of a pseudo-terminal pair.
pub struct PtyMaster {
    master: OwnedFd,
    // Held open so that the master never reads a hang-up while no client has it open.
    _slave: OwnedFd,
    slave_path: PathBuf,
    pace: Option<LineSettings>,
    late: PacingClock,
    tags: LineTags,
    reply_starts: super::ReplyStarts,
    emulate: Option<LineSettings>,
    // A second handle on the slave, for its baud rate: masters that set any rate
    // (serialport) use BOTHER and termios2, which only TCGETS2 reads back.
    probe: Option<serialport::TTYPort>,
    // Characters read through the emulation that did not fit the caller's buffer.
    pending: std::collections::VecDeque<u8>,
}

/// The other end of a pseudo-terminal pair as its termios describes it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PeerLine {
    /// Baud rate, parity (inferred, see the module notes) and stop bits; data bits are
    /// not carried by a pty and are this side's.
    pub line: LineSettings,
    /// What its line discipline does with a character that has an error.
    pub policy: ErrorPolicy,
}

/// The peer's line from its baud rate and raw termios flags: see the module notes for
/// what a pty carries.
#[cfg(target_os = "linux")]
pub fn peer_line_of(baud: u32, t: &libc::termios, data_bits: u8) -> PeerLine {
    let c = t.c_cflag;
    let i = t.c_iflag;
    let parity = if c & libc::PARENB != 0 {
        if c & libc::PARODD != 0 {
            Parity::Odd
        } else {
            Parity::Even
        }
    } else if c & libc::PARODD != 0 {
        Parity::Odd
    } else if i & libc::INPCK != 0 {
        Parity::Even
    } else {
        Parity::None
    };
    let stop_bits = if c & libc::CSTOPB != 0 { 2 } else { 1 };
    // Linux's serial drivers flag errors only with INPCK; IGNPAR then drops the character,
    // PARMRK marks it, otherwise it becomes 00H.
    let policy = if i & libc::INPCK == 0 {
        ErrorPolicy::Pass
    } else if i & libc::IGNPAR != 0 {
        ErrorPolicy::Drop
    } else if i & libc::PARMRK != 0 {
        ErrorPolicy::Mark
    } else {
        ErrorPolicy::Zero
    };
    PeerLine {
        line: LineSettings::new(baud, data_bits, parity, stop_bits),
        policy,
    }
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
        // Not inherited by a program this process starts (a monitor given the slave's
        // path): an inherited master keeps the line up after this end is dropped, and
        // the program never sees the end of its input.
        for fd in [&pair.master, &pair.slave] {
            nix::fcntl::fcntl(
                fd,
                nix::fcntl::FcntlArg::F_SETFD(nix::fcntl::FdFlag::FD_CLOEXEC),
            )
            .map_err(open_err)?;
        }
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
            emulate: None,
            probe: None,
            pending: std::collections::VecDeque::new(),
            tags: LineTags::default(),
            reply_starts: super::ReplyStarts::default(),
        })
    }

    /// Behaves like a drive whose UART is set to `line`: a peer at other settings (as
    /// its termios says) gets what a real line would give it (see the module notes).
    pub fn with_line_emulation(mut self, line: LineSettings) -> Result<Self, TransportError> {
        let path = self.slave_path.to_string_lossy().into_owned();
        let open_err = |e: serialport::Error| TransportError::Open {
            what: format!("{path} (to read the other end's line settings)"),
            source: e.into(),
        };
        // Opened before any client: the settings it sets are the client's to change.
        let probe = serialport::new(&path, line.baud)
            .exclusive(false)
            .open_native()
            .map_err(open_err)?;
        // Not locked either: the client (the serialport crate takes an exclusive flock)
        // must be able to open the slave.
        {
            use std::os::fd::AsRawFd;
            #[allow(deprecated)]
            nix::fcntl::flock(probe.as_raw_fd(), nix::fcntl::FlockArg::Unlock)
                .map_err(|e| open_err(serialport::Error::from(io(e))))?;
        }
        self.probe = Some(probe);
        self.emulate = Some(line);
        Ok(self)
    }

    /// The other end's line, as its termios says (Linux); None where it cannot be read
    /// or names no standard baud rate.
    pub fn peer_line(&self) -> Option<PeerLine> {
        #[cfg(target_os = "linux")]
        {
            use serialport::SerialPort;
            let baud = self.probe.as_ref()?.baud_rate().ok()?;
            let t = tcgetattr(&self._slave).ok()?;
            let raw: libc::termios = t.into();
            let data_bits = self.emulate.or(self.pace).map_or(8, |l| l.data_bits);
            Some(peer_line_of(baud, &raw, data_bits))
        }
        #[cfg(not(target_os = "linux"))]
        {
            None
        }
    }

    /// With emulation on and a peer at other settings: the peer and this side's line.
    fn mismatch(&self) -> Option<(PeerLine, LineSettings)> {
        let own = self.emulate?;
        let peer = self.peer_line()?;
        if peer.line == own {
            return None;
        }
        Some((peer, own))
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

    /// The queue in which a simulator on this end says when it began each reply (see
    /// [`super::ReplyStarts`]), for the master on the slave side; kept when paced.
    pub fn reply_start_queue(&self) -> super::ReplyStarts {
        self.reply_starts.clone()
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

    fn take_pending(&mut self, buf: &mut [u8]) -> usize {
        let n = self.pending.len().min(buf.len());
        for (d, s) in buf.iter_mut().zip(self.pending.drain(..n)) {
            *d = s;
        }
        n
    }

    fn recv_raw(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
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

impl AsFd for PtyMaster {
    /// The master side, for a caller that waits on several pairs at once (the emulated
    /// line).
    fn as_fd(&self) -> std::os::fd::BorrowedFd<'_> {
        self.master.as_fd()
    }
}

impl Transport for PtyMaster {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        if let Some((peer, own)) = self.mismatch() {
            // What the peer's UART makes of this side's characters; it takes the time
            // this side's characters take.
            let garbled = uart::deliver(&uart::transcode(bytes, &own, &peer.line), peer.policy);
            let start = Instant::now();
            if self.pace.is_some() {
                let n = u32::try_from(bytes.len()).unwrap_or(u32::MAX);
                sleep_until(start + Duration::from_micros(own.char_time_us()) * n);
            }
            return self.write_all(&garbled);
        }
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
        if !self.pending.is_empty() {
            return Ok(self.take_pending(buf));
        }
        let n = self.recv_raw(buf, timeout)?;
        if n == 0 {
            return Ok(0);
        }
        let Some((peer, own)) = self.mismatch() else {
            return Ok(n);
        };
        // A drive's UART discards the characters it read with errors.
        let chars = uart::transcode(&buf[..n], &peer.line, &own);
        self.pending
            .extend(uart::deliver(&chars, ErrorPolicy::Drop));
        Ok(self.take_pending(buf))
    }

    fn discard_input(&mut self) -> Result<(), TransportError> {
        self.pending.clear();
        let mut buf = [0u8; 256];
        while self.recv_raw(&mut buf, Duration::ZERO)? > 0 {}
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
        .to_string()
            + &self.emulate.map_or(String::new(), |l| {
                format!(" (a drive's UART at {l}: a master at other settings gets garbage)")
            })
    }

    fn kind(&self) -> LinkKind {
        LinkKind::Pty
    }

    fn line_timing(&self) -> Option<LineSettings> {
        self.pace
    }

    fn reply_starts(&self) -> Option<super::ReplyStarts> {
        self.pace.map(|_| self.reply_starts.clone())
    }

    fn line_tags(&self) -> Option<LineTags> {
        self.pace.map(|_| self.tags.clone())
    }
}
