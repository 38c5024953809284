//! The endpoints around one [`Wire`] and the loop that carries their bytes.
//!
//! An endpoint is a pseudo-terminal pair ([`PtyMaster`], opened unpaced: the line paces,
//! not each endpoint; a paced [`PtyMaster`] sleeps a character time per character in its
//! writer, which cannot serve several listeners at once) whose slave a program opens, or
//! a [`Station`] inside this process. One thread waits for input on all of them and for
//! the moment the next character is in; bytes read are put on the wire at the bit they
//! arrived, the wire is run up to the present, and every character read off it is
//! written to each endpoint that hears it. A listener that does not read loses bytes, as
//! a UART that overruns does (logged), and never stalls the line.

use std::os::fd::{AsFd, BorrowedFd};
use std::os::unix::net::UnixStream;
use std::path::Path;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use nix::errno::Errno;
use nix::fcntl::{fcntl, FcntlArg, OFlag};
use nix::poll::{PollFd, PollFlags};

use super::log::{hex, EndpointInfo, LineLog, Record};
use super::station::Station;
use super::wire::{Event, Wire};
use super::LineError;
use crate::codec::timing::{later, LineSettings};
use crate::transport::pty::{PeerLine, PtyMaster};
use crate::transport::uart::{self, CharError, ErrorPolicy, Received};
use crate::transport::LineTags;

/// Longest wait for input when nothing is due: how soon a stop is seen.
const IDLE_WAIT: Duration = Duration::from_millis(50);

/// How the line runs.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LineConfig {
    /// Baud rate, data bits, parity and stop bits: the character time and each
    /// character's bits.
    pub line: LineSettings,
    /// Whether bytes go at the line's character time (with collisions), or at once.
    pub paced: bool,
    /// Probability that a driven bit flips (0: no noise).
    pub noise: f64,
    /// Seed of the noise.
    pub seed: u64,
    /// Whether each pseudo-terminal endpoint hears the line through a UART at the
    /// settings its program set on its port (paced only; see [`Endpoint::pty`]).
    pub emulate: bool,
}

enum Port {
    Pty {
        pty: PtyMaster,
        // With line emulation: the settings its program set, as last read.
        peer: Option<PeerLine>,
    },
    Station {
        sock: UnixStream,
        tags: LineTags,
        busy: super::station::Busy,
    },
}

/// One endpoint of the line.
pub struct Endpoint {
    name: String,
    port: Port,
    echo: bool,
    device: Option<String>,
}

fn io_err(name: &str, what: &'static str, e: Errno) -> LineError {
    LineError::Io {
        name: name.to_string(),
        what,
        source: std::io::Error::from_raw_os_error(e as i32),
    }
}

impl Endpoint {
    /// A new pseudo-terminal pair named `name`; a program opens its slave
    /// ([`Endpoint::path`]) as a serial port.
    pub fn pty(name: &str) -> Result<Endpoint, LineError> {
        let pty = PtyMaster::open(None).map_err(|e| LineError::Io {
            name: name.to_string(),
            what: "opening a pseudo-terminal",
            source: std::io::Error::other(e.to_string()),
        })?;
        // Never block the line on one endpoint: a full buffer is an overrun.
        fcntl(pty.as_fd(), FcntlArg::F_SETFL(OFlag::O_NONBLOCK))
            .map_err(|e| io_err(name, "fcntl O_NONBLOCK", e))?;
        Ok(Endpoint {
            name: name.to_string(),
            port: Port::Pty { pty, peer: None },
            echo: false,
            device: None,
        })
    }

    /// An endpoint inside this process for `device` (what sits there, for the log), and
    /// the [`Station`] it is reached by; `line` when the line is paced.
    pub fn station(
        name: &str,
        device: &str,
        line: Option<LineSettings>,
    ) -> Result<(Endpoint, Station), LineError> {
        let busy = super::station::Busy::default();
        let (station, sock, tags) =
            Station::pair(name, line, busy.clone()).map_err(|e| LineError::Io {
                name: name.to_string(),
                what: "making a socket pair",
                source: e,
            })?;
        Ok((
            Endpoint {
                name: name.to_string(),
                port: Port::Station { sock, tags, busy },
                echo: false,
                device: Some(device.to_string()),
            },
            station,
        ))
    }

    /// With line emulation at `line` (a pseudo-terminal only; a station is a drive set to
    /// the line): its program's port settings are read as `simulate --emulate-line` reads
    /// them ([`PtyMaster::with_line_emulation`]: the baud rate, PARODD, CSTOPB and the
    /// input flags; a pty carries neither PARENB nor the data bits, so the parity is
    /// inferred from INPCK and PARODD and the data bits are the line's), and where they
    /// differ from the line's it hears what a UART at those settings reads off the pair,
    /// characters with errors handled as its input flags say.
    pub fn with_line_emulation(self, line: LineSettings) -> Result<Self, LineError> {
        let Endpoint {
            name,
            port,
            echo,
            device,
        } = self;
        let port = match port {
            Port::Pty { pty, .. } => Port::Pty {
                pty: pty.with_line_emulation(line).map_err(|e| LineError::Io {
                    name: name.clone(),
                    what: "opening the pseudo-terminal to read its settings",
                    source: std::io::Error::other(e.to_string()),
                })?,
                peer: None,
            },
            station => station,
        };
        Ok(Endpoint {
            name,
            port,
            echo,
            device,
        })
    }

    /// The settings its program set, as last read, with line emulation.
    fn peer(&self) -> Option<PeerLine> {
        match &self.port {
            Port::Pty { peer, .. } => *peer,
            Port::Station { .. } => None,
        }
    }

    /// With local echo: the endpoint hears the line while it drives it (its own bytes,
    /// or the damage of a collision), as on a two-wire adapter whose receiver stays on.
    pub fn with_echo(mut self, echo: bool) -> Self {
        self.echo = echo;
        self
    }

    /// Its name.
    pub fn name(&self) -> &str {
        &self.name
    }

    /// The path a program opens, for a pseudo-terminal.
    pub fn path(&self) -> Option<&Path> {
        match &self.port {
            Port::Pty { pty, .. } => Some(pty.slave_path()),
            Port::Station { .. } => None,
        }
    }

    fn fd(&self) -> BorrowedFd<'_> {
        match &self.port {
            Port::Pty { pty, .. } => pty.as_fd(),
            Port::Station { sock, .. } => sock.as_fd(),
        }
    }

    /// Reads what is waiting; None when a station's drive went away.
    fn read(&mut self, buf: &mut [u8]) -> Result<Option<usize>, LineError> {
        let r = nix::unistd::read(self.fd(), buf);
        match (r, &self.port) {
            (Ok(0), Port::Station { .. }) => Ok(None),
            (Ok(n), _) => Ok(Some(n)),
            // A pty whose slave is not open (never here: the pair holds it) reads EIO.
            (Err(Errno::EAGAIN | Errno::EINTR | Errno::EIO), _) => Ok(Some(0)),
            (Err(e), _) => Err(io_err(&self.name, "read", e)),
        }
    }

    /// Writes `bytes` (with, for a station, the silence before each); returns how many
    /// could not be taken.
    fn write(&mut self, bytes: &[u8], silences: &[u32]) -> Result<usize, LineError> {
        let name = self.name.clone();
        let put = |fd: BorrowedFd<'_>| -> Result<usize, LineError> {
            let mut done = 0;
            while done < bytes.len() {
                match nix::unistd::write(fd, &bytes[done..]) {
                    Ok(0) | Err(Errno::EAGAIN) => break,
                    Ok(n) => done += n,
                    Err(Errno::EINTR) => {}
                    Err(e) => return Err(io_err(&name, "write", e)),
                }
            }
            Ok(done)
        };
        match &self.port {
            Port::Pty { pty, .. } => Ok(bytes.len() - put(pty.as_fd())?),
            Port::Station { sock, tags, .. } => {
                // The silences go first, under the lock the station drains under.
                let mut told = tags.lock().ok();
                if let Some(t) = told.as_mut() {
                    t.extend(silences);
                }
                // A drive that went away takes nothing: nobody to tell.
                let done: usize = put(sock.as_fd()).unwrap_or_default();
                if let Some(t) = told.as_mut() {
                    for _ in done..silences.len() {
                        t.pop_back();
                    }
                }
                Ok(bytes.len() - done)
            }
        }
    }
}

/// What the line carried.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LineStats {
    /// Characters read off the line.
    pub chars: u64,
    /// Collisions.
    pub collisions: u64,
    /// Bits flipped by the noise.
    pub flips: u64,
    /// Bytes dropped for endpoints that did not read.
    pub dropped: u64,
    /// Runs of characters handed to their listeners more than t1.5 late (a busy host).
    pub late: u64,
}

/// A run of characters handed to their listeners late: when the first ended on the
/// line (µs), how many, and the most one was late (µs).
#[derive(Debug, Clone, Copy)]
struct LateRun {
    t_us: u64,
    chars: u64,
    by_us: u64,
}

/// An emulated multi-drop RS-485 line and its endpoints (see the module notes).
pub struct EmulatedLine {
    config: LineConfig,
    endpoints: Vec<Endpoint>,
    wire: Wire,
    epoch: Instant,
    // Per endpoint: the bit after the last character handed to it (told silences).
    last_end: Vec<Option<u64>>,
    overrun: Vec<bool>,
    closed: Vec<bool>,
    out: Vec<(Vec<u8>, Vec<u32>)>,
    stats: LineStats,
    late: Option<LateRun>,
}

impl EmulatedLine {
    /// A line with `endpoints` (distinct names, at most
    /// [`super::wire::MAX_ENDPOINTS`]).
    pub fn new(config: LineConfig, endpoints: Vec<Endpoint>) -> Result<Self, LineError> {
        for (i, e) in endpoints.iter().enumerate() {
            if endpoints[..i].iter().any(|o| o.name == e.name) {
                return Err(LineError::SameName(e.name.clone()));
            }
        }
        let n = endpoints.len();
        let wire = Wire::new(config.line, n)?.with_noise(config.noise, config.seed)?;
        Ok(EmulatedLine {
            config,
            endpoints,
            wire,
            epoch: Instant::now(),
            last_end: vec![None; n],
            overrun: vec![false; n],
            closed: vec![false; n],
            out: vec![(Vec::new(), Vec::new()); n],
            stats: LineStats::default(),
            late: None,
        })
    }

    /// The endpoints, in index order.
    pub fn endpoints(&self) -> &[Endpoint] {
        &self.endpoints
    }

    fn us_of(&self, bits: u64) -> u64 {
        let baud = u128::from(self.config.line.baud.max(1));
        u64::try_from(u128::from(bits) * 1_000_000 / baud).unwrap_or(u64::MAX)
    }

    /// A log time for bit `bit`: the line's schedule when paced; unpaced the wire's bits
    /// are virtual, and the time is now.
    fn t_us(&self, bit: u64) -> u64 {
        if self.config.paced {
            self.us_of(bit)
        } else {
            u64::try_from(self.epoch.elapsed().as_micros()).unwrap_or(u64::MAX)
        }
    }

    fn bit_at(&self, at: Instant) -> u64 {
        let us = at.saturating_duration_since(self.epoch).as_micros();
        u64::try_from(us * u128::from(self.config.line.baud.max(1)) / 1_000_000).unwrap_or(u64::MAX)
    }

    fn instant_of(&self, bit: u64) -> Instant {
        let baud = u128::from(self.config.line.baud.max(1));
        let us = (u128::from(bit) * 1_000_000).div_ceil(baud);
        later(
            self.epoch,
            Duration::from_micros(u64::try_from(us).unwrap_or(u64::MAX)),
        )
    }

    /// Carries bytes until `stop` is set or `until` passes; writes the log as it goes.
    pub fn run(
        &mut self,
        log: &mut LineLog,
        stop: &AtomicBool,
        until: Option<Instant>,
    ) -> Result<LineStats, LineError> {
        self.epoch = Instant::now();
        log.record(&Record::Start {
            t_us: 0,
            line: self.config.line.to_string(),
            char_us: self.config.line.char_time_us(),
            paced: self.config.paced,
            noise: self.config.noise,
            seed: self.config.seed,
            endpoints: self
                .endpoints
                .iter()
                .map(|e| EndpointInfo {
                    name: e.name.clone(),
                    path: e.path().map(|p| p.display().to_string()),
                    device: e.device.clone(),
                    echo: e.echo,
                })
                .collect(),
        })?;
        log.flush()?;
        let mut buf = vec![0u8; 4096];
        let mut events = Vec::new();
        while !stop.load(Ordering::Relaxed) && until.is_none_or(|u| Instant::now() < u) {
            let now = Instant::now();
            let mut wait = match (self.config.paced, self.wire.next_due()) {
                (true, Some(due)) => self.instant_of(due).saturating_duration_since(now),
                _ => IDLE_WAIT,
            };
            wait = wait.min(IDLE_WAIT);
            if let Some(u) = until {
                wait = wait.min(u.saturating_duration_since(now));
            }
            let ready = self.ready(wait)?;
            if self.config.emulate && self.config.paced {
                self.sync_receivers(log)?;
            }
            for i in ready {
                match self.endpoints[i].read(&mut buf)? {
                    None => self.closed[i] = true,
                    Some(0) => {}
                    Some(n) => self.put(i, &buf[..n], &mut events, log)?,
                }
            }
            if self.config.paced {
                let to = self.bit_at(Instant::now());
                self.wire.advance(to, &mut events);
            }
            self.deliver(&mut events, log)?;
            let busy = self.wire.busy();
            for e in &self.endpoints {
                if let Port::Station { busy: b, .. } = &e.port {
                    b.store(busy, Ordering::Release);
                }
            }
            if !busy {
                log.flush()?;
            }
        }
        self.end_late_run(log)?;
        let t_us = u64::try_from(self.epoch.elapsed().as_micros()).unwrap_or(u64::MAX);
        let s = self.stats;
        log.record(&Record::Stop {
            t_us,
            chars: s.chars,
            collisions: s.collisions,
            flips: s.flips,
            dropped: s.dropped,
            late: s.late,
        })?;
        log.flush()?;
        Ok(s)
    }

    /// Reads each emulated endpoint's port settings; gives an endpoint whose settings
    /// its UART could not read the line with a receiver of its own (logged when they
    /// change).
    fn sync_receivers(&mut self, log: &mut LineLog) -> Result<(), LineError> {
        let line = self.config.line;
        let t_us = self.t_us(self.wire.now());
        for i in 0..self.endpoints.len() {
            let Port::Pty { pty, peer } = &mut self.endpoints[i].port else {
                continue;
            };
            let now = pty.peer_line();
            if now == *peer {
                continue;
            }
            *peer = now;
            let own = now
                .filter(|p| !uart::compatible(&p.line, &line))
                .map(|p| p.line);
            self.wire.set_receiver(i, own)?;
            log.record(&Record::Settings {
                t_us,
                endpoint: self.endpoints[i].name.clone(),
                line: now.map_or_else(|| "unknown".to_string(), |p| p.line.to_string()),
                hears: if own.is_some() {
                    "its own UART"
                } else {
                    "the line"
                },
            })?;
        }
        Ok(())
    }

    /// The endpoints with input, after waiting at most `wait` for one.
    fn ready(&self, wait: Duration) -> Result<Vec<usize>, LineError> {
        let open: Vec<usize> = (0..self.endpoints.len())
            .filter(|&i| !self.closed[i])
            .collect();
        let mut fds: Vec<PollFd<'_>> = open
            .iter()
            .map(|&i| PollFd::new(self.endpoints[i].fd(), PollFlags::POLLIN))
            .collect();
        let r = {
            #[cfg(any(target_os = "linux", target_os = "android", target_os = "freebsd"))]
            {
                let ts = nix::sys::time::TimeSpec::from_duration(wait);
                nix::poll::ppoll(&mut fds, Some(ts), None)
            }
            #[cfg(not(any(target_os = "linux", target_os = "android", target_os = "freebsd")))]
            {
                let ms = u16::try_from(wait.as_micros().div_ceil(1000)).unwrap_or(u16::MAX);
                nix::poll::poll(&mut fds, nix::poll::PollTimeout::from(ms))
            }
        };
        match r {
            Ok(0) | Err(Errno::EINTR) => return Ok(Vec::new()),
            Ok(_) => {}
            Err(e) => return Err(io_err("(all)", "poll", e)),
        }
        Ok(open
            .iter()
            .zip(&fds)
            .filter(|(_, f)| {
                f.revents().is_some_and(|r| {
                    r.intersects(PollFlags::POLLIN | PollFlags::POLLHUP | PollFlags::POLLERR)
                })
            })
            .map(|(&i, _)| i)
            .collect())
    }

    /// Puts bytes written on endpoint `i` on the line.
    fn put(
        &mut self,
        i: usize,
        bytes: &[u8],
        events: &mut Vec<Event>,
        log: &mut LineLog,
    ) -> Result<(), LineError> {
        let from = self.endpoints[i].name.clone();
        if self.config.paced {
            let at = self.bit_at(Instant::now());
            let starts = self.wire.transmit(i, at, bytes)?;
            let at_us: Vec<u64> = starts.iter().map(|&b| self.us_of(b)).collect();
            log.record(&Record::Tx {
                t_us: at_us.first().copied().unwrap_or(0),
                from,
                hex: hex(bytes),
                at_us: Some(at_us),
            })
        } else {
            // A bridge: the wire's own clock runs ahead as far as the bytes need.
            let starts = self.wire.transmit(i, self.wire.now(), bytes)?;
            let last = starts.last().copied().unwrap_or(self.wire.now());
            self.wire
                .advance(last + 2 * self.wire.bits_per_char(), events);
            log.record(&Record::Tx {
                t_us: u64::try_from(self.epoch.elapsed().as_micros()).unwrap_or(u64::MAX),
                from,
                hex: hex(bytes),
                at_us: None,
            })
        }
    }

    /// Queues a character that started at line bit `start` for endpoint `i`, with the
    /// silence before it; one read with an error goes as its input flags say (with line
    /// emulation; as read otherwise).
    fn hand(&mut self, i: usize, start: u64, byte: u8, error: Option<CharError>) {
        let bpc = self.wire.bits_per_char();
        let silence = self.last_end[i].map_or(u32::MAX, |end| {
            let bits = start.saturating_sub(end);
            let baud = u64::from(self.config.line.baud.max(1));
            u32::try_from(bits.saturating_mul(1_000_000) / baud).unwrap_or(u32::MAX)
        });
        self.last_end[i] = Some(start + bpc);
        let policy = self.endpoints[i]
            .peer()
            .map_or(ErrorPolicy::Pass, |p| p.policy);
        let out = &mut self.out[i];
        let before = out.0.len();
        uart::deliver_into(Received { byte, error }, policy, &mut out.0);
        for k in before..out.0.len() {
            out.1.push(if k == before { silence } else { 0 });
        }
    }

    /// Logs the run of late characters, if one is open.
    fn end_late_run(&mut self, log: &mut LineLog) -> Result<(), LineError> {
        if let Some(r) = self.late.take() {
            self.stats.late += 1;
            log.record(&Record::Late {
                t_us: r.t_us,
                chars: r.chars,
                by_us: r.by_us,
            })?;
        }
        Ok(())
    }

    /// Paced: notes whether the character that ended on the line at bit `end` reaches
    /// its listeners (`now`) more than t1.5 after that; a run of such characters is
    /// logged once, when one comes in time again (or the line stops).
    fn note_lateness(
        &mut self,
        end: u64,
        now: Instant,
        log: &mut LineLog,
    ) -> Result<(), LineError> {
        if !self.config.paced {
            return Ok(());
        }
        let late = now.saturating_duration_since(self.instant_of(end));
        let by_us = u64::try_from(late.as_micros()).unwrap_or(u64::MAX);
        if by_us <= self.config.line.t1_5_us() {
            return self.end_late_run(log);
        }
        let t_us = self.us_of(end);
        let r = self.late.get_or_insert(LateRun {
            t_us,
            chars: 0,
            by_us: 0,
        });
        r.chars += 1;
        r.by_us = r.by_us.max(by_us);
        Ok(())
    }

    /// Hands the characters read off the line to their listeners; logs the rest.
    fn deliver(&mut self, events: &mut Vec<Event>, log: &mut LineLog) -> Result<(), LineError> {
        let now = Instant::now();
        let bpc = self.wire.bits_per_char();
        let names = |mask: u64, eps: &[Endpoint]| -> Vec<String> {
            eps.iter()
                .enumerate()
                .filter(|(i, _)| mask >> i & 1 == 1)
                .map(|(_, e)| e.name.clone())
                .collect()
        };
        for e in events.drain(..) {
            match e {
                Event::Char(c) => {
                    self.stats.chars += 1;
                    self.note_lateness(c.start + bpc, now, log)?;
                    for i in 0..self.endpoints.len() {
                        let ep = &self.endpoints[i];
                        if self.closed[i]
                            || (c.drivers >> i & 1 == 1 && !ep.echo)
                            || self.wire.receiver(i).is_some()
                        {
                            continue;
                        }
                        self.hand(i, c.start, c.byte, c.error);
                    }
                    if c.damaged && !c.collided {
                        let t_us = self.t_us(c.start);
                        log.record(&Record::Damaged {
                            t_us,
                            hex: hex(&[c.byte]),
                            error: c.error.map(|e| match e {
                                CharError::Parity => "parity",
                                CharError::Framing => "framing",
                            }),
                        })?;
                    }
                }
                Event::Heard(h) => {
                    let i = h.endpoint;
                    let hears = self
                        .endpoints
                        .get(i)
                        .is_some_and(|ep| !self.closed[i] && (h.drivers >> i & 1 == 0 || ep.echo));
                    if hears {
                        self.hand(i, h.start, h.byte, h.error);
                    }
                }
                Event::Collision(c) => {
                    self.stats.collisions += 1;
                    log.record(&Record::Collision {
                        t_us: self.us_of(c.start),
                        end_us: self.us_of(c.end),
                        endpoints: names(c.endpoints, &self.endpoints),
                        chars: c.chars,
                        line_hex: hex(&c.line),
                    })?;
                }
                Event::Flip(f) => {
                    self.stats.flips += 1;
                    log.record(&Record::Noise {
                        t_us: self.t_us(f.at),
                        from: names(f.drivers, &self.endpoints),
                        byte: hex(&[f.byte]),
                        bit: f.bit,
                    })?;
                }
            }
        }
        let t_us = u64::try_from(self.epoch.elapsed().as_micros()).unwrap_or(u64::MAX);
        for i in 0..self.endpoints.len() {
            if self.out[i].0.is_empty() {
                continue;
            }
            let (bytes, silences) = std::mem::take(&mut self.out[i]);
            let dropped = self.endpoints[i].write(&bytes, &silences)?;
            if dropped > 0 {
                self.stats.dropped += dropped as u64;
                if !self.overrun[i] {
                    log.record(&Record::Overrun {
                        t_us,
                        to: self.endpoints[i].name.clone(),
                        dropped: dropped as u64,
                    })?;
                }
            }
            self.overrun[i] = dropped > 0;
            // Keep the buffers' capacity.
            self.out[i] = (bytes, silences);
            self.out[i].0.clear();
            self.out[i].1.clear();
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::timing::Parity;
    use std::sync::{Arc, Mutex};

    /// A writer the test reads back.
    #[derive(Clone, Default)]
    struct Shared(Arc<Mutex<Vec<u8>>>);

    impl std::io::Write for Shared {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    /// Characters handed over more than t1.5 after they ended on the line make one `late`
    /// record per run of them (with how many and the worst), written when one comes in
    /// time again or the line stops; characters in time make none; unpaced, none.
    #[test]
    fn characters_handed_over_late_are_logged_once_per_run() {
        // 9600 8E1: a character is 11 bits, 1146 us; t1.5 is 1719 us.
        let line = LineSettings::new(9600, 8, Parity::Even, 1);
        let config = |paced| LineConfig {
            line,
            paced,
            noise: 0.0,
            seed: 1,
            emulate: false,
        };
        let out = Shared::default();
        let mut log = LineLog::new().with_json(Box::new(out.clone()));
        let mut l = EmulatedLine::new(config(true), Vec::new()).unwrap();
        let at = |l: &EmulatedLine, bit: u64, late_us: u64| {
            l.instant_of(bit) + Duration::from_micros(late_us)
        };
        // In time, then two late (2 ms and 5 ms), then in time again, then one late left
        // open when the line stops.
        for (bit, late) in [
            (11, 100),
            (22, 2_000),
            (33, 5_000),
            (44, 1_700),
            (55, 9_000),
        ] {
            let now = at(&l, bit, late);
            l.note_lateness(bit, now, &mut log).unwrap();
        }
        l.end_late_run(&mut log).unwrap();
        let text = String::from_utf8(out.0.lock().unwrap().clone()).unwrap();
        let records: Vec<serde_json::Value> = text
            .lines()
            .map(|r| serde_json::from_str(r).unwrap())
            .collect();
        assert_eq!(records.len(), 2, "{text}");
        assert_eq!(records[0]["event"], "late");
        assert_eq!(records[0]["chars"], 2);
        assert_eq!(records[0]["t_us"], l.us_of(22));
        assert!(
            (4_999..=5_001).contains(&records[0]["by_us"].as_u64().unwrap()),
            "{text}"
        );
        assert_eq!(records[1]["chars"], 1);
        assert_eq!(l.stats.late, 2);
        // Unpaced: bytes go at once, there is no schedule to be late for.
        let out = Shared::default();
        let mut log = LineLog::new().with_json(Box::new(out.clone()));
        let mut u = EmulatedLine::new(config(false), Vec::new()).unwrap();
        let now = at(&u, 11, 50_000);
        u.note_lateness(11, now, &mut log).unwrap();
        u.end_late_run(&mut log).unwrap();
        assert!(out.0.lock().unwrap().is_empty());
    }
}
