//! The read-only port and the listening loop.
//!
//! A [`Tap`] can only be read: the monitor holds its port behind this trait, so no path
//! of the monitor can write to the bus. [`ReadOnlyPort`] wraps a transport and calls
//! nothing on it but [`Transport::recv`] and [`Transport::describe`].

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::{Line, Monitor, MonitorError};
use crate::transport::{Transport, TransportError};

/// A source of the bytes on the line, that cannot send.
pub trait Tap {
    /// Bytes received within `timeout` (0: none came).
    fn listen(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError>;
    /// The port, for reports.
    fn describe(&self) -> String;
}

/// A transport used for listening only.
pub struct ReadOnlyPort {
    port: Box<dyn Transport>,
}

impl ReadOnlyPort {
    /// Listens on `port`; nothing is ever written to it.
    pub fn new(port: Box<dyn Transport>) -> Self {
        ReadOnlyPort { port }
    }

    /// The port back (to listen on it through another wrapper: a capture).
    pub fn into_inner(self) -> Box<dyn Transport> {
        self.port
    }
}

impl Tap for ReadOnlyPort {
    fn listen(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        self.port.recv(buf, timeout)
    }

    fn describe(&self) -> String {
        self.port.describe()
    }
}

/// A serial port used for listening only, whose line settings can be changed (to find
/// the line's by listening: [`super::line_search`]). Nothing is ever written to it: it
/// calls nothing on the port but reading, setting the line and dropping what was read.
pub struct ReadOnlySerial {
    port: crate::transport::serial::SerialTransport,
}

impl ReadOnlySerial {
    /// Listens on `port`.
    pub fn new(port: crate::transport::serial::SerialTransport) -> Self {
        ReadOnlySerial { port }
    }

    /// The port back, at the settings last set.
    pub fn into_inner(self) -> crate::transport::serial::SerialTransport {
        self.port
    }
}

impl Tap for ReadOnlySerial {
    fn listen(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        self.port.recv(buf, timeout)
    }

    fn describe(&self) -> String {
        self.port.describe()
    }
}

/// A port whose line settings can be changed, for listening only.
pub trait Tunable: Tap {
    /// Sets the port to `line` and drops what it read before.
    fn set_line(&mut self, line: crate::codec::timing::LineSettings) -> Result<(), TransportError>;
}

impl Tunable for ReadOnlySerial {
    fn set_line(&mut self, line: crate::codec::timing::LineSettings) -> Result<(), TransportError> {
        self.port.set_line(line)?;
        self.port.discard_input()
    }
}

/// Why listening ended.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Ended {
    /// `--duration` passed.
    Duration,
    /// Ctrl-C or SIGTERM.
    Interrupted,
    /// The port closed or failed (the end of the input): why.
    EndOfInput(String),
}

/// Listens on `tap` until `stop` is set, `duration` passes or the input ends, feeding
/// `monitor` and handing every live line to `on_line`.
pub fn run(
    tap: &mut dyn Tap,
    monitor: &mut Monitor,
    stop: &AtomicBool,
    duration: Option<Duration>,
    mut on_line: impl FnMut(&Line),
) -> Result<Ended, MonitorError> {
    run_from(
        tap,
        monitor,
        stop,
        duration,
        Instant::now(),
        Vec::new(),
        |said| {
            if let Said::Line(l) = said {
                on_line(l)
            }
        },
    )
}

/// What the listener says as it goes: a line per exchange, or a notice about the tap
/// (made once).
#[derive(Debug, Clone, Copy)]
pub enum Said<'a> {
    /// An exchange, or a frame nobody asked for.
    Line(&'a Line),
    /// About the tap (its latency timer).
    Notice(&'a str),
    /// Every [`SUMMARY_EVERY`] of listening: per node, the counts and response times so
    /// far (for a terminal).
    Summary(&'a [String]),
}

/// How long listening goes on, at most, after `--duration` or a signal, for the frame
/// under way to end.
pub const DRAIN_AT_MOST: Duration = Duration::from_millis(250);

/// How often [`Said::Summary`] comes.
pub const SUMMARY_EVERY: Duration = Duration::from_secs(10);

/// Hands what the monitor made since the last call to `say`.
fn say_new(monitor: &mut Monitor, say: &mut impl FnMut(Said<'_>)) {
    for l in monitor.take_lines() {
        say(Said::Line(&l));
    }
    for n in monitor.take_notices() {
        say(Said::Notice(&n));
    }
}

/// How often the listener reads: about t1.5, so that t3.5 of silence is seen soon after
/// it passes (arrival times are taken when a read returns, as soon as bytes are there).
pub fn poll_interval(line: crate::codec::timing::LineSettings) -> Duration {
    Duration::from_micros(line.t1_5_us().clamp(500, 20_000))
}

/// Reads `tap` once, waiting up to `poll`, and dates the read (since `origin`): a read
/// with bytes when it returned, an empty one no later than `poll` after it began.
///
/// An empty read proves the line silent only until the port stopped waiting. A host too
/// busy to run the listener (or a process stopped and continued) between that and the
/// clock being read would date it later, and so prove a silence the line did not have:
/// the window of a request closed on a reply that was already there.
pub(super) fn read_dated(
    tap: &mut dyn Tap,
    buf: &mut [u8],
    poll: Duration,
    origin: Instant,
) -> Result<(Duration, usize), TransportError> {
    let asked = origin.elapsed();
    let n = tap.listen(buf, poll)?;
    let now = origin.elapsed();
    Ok((if n == 0 { now.min(asked + poll) } else { now }, n))
}

/// What the listener read, with its time since the origin: bytes, or none (a read that
/// came back empty at that time).
pub type Heard = Vec<(Duration, Vec<u8>)>;

/// Notes in `heard` that a read at `at` came back empty. Of a run of empty reads, the
/// first and the last are kept: the first says since when the line was quiet (t3.5 of
/// it before a frame says that the frame began in silence), the last the earliest the
/// next bytes came.
pub(super) fn quiet(heard: &mut Heard, at: Duration) {
    match heard.as_mut_slice() {
        [.., (_, a), (t, b)] if a.is_empty() && b.is_empty() => *t = at,
        _ => heard.push((at, Vec::new())),
    }
}

/// Reads `tap` once, for one poll of `line`, before listening is announced: what was
/// read, at its time since `origin` (an empty read is kept: it says the line was quiet
/// when listening began). Whoever is told "listening" then knows that the port has been
/// read, and that what it sends after is not taken for a frame already under way (see
/// `Entry`).
pub fn first_read(
    tap: &mut dyn Tap,
    origin: Instant,
    line: crate::codec::timing::LineSettings,
) -> Result<Heard, TransportError> {
    let mut buf = [0u8; 512];
    let (at, n) = read_dated(tap, &mut buf, poll_interval(line), origin)?;
    Ok(vec![(at, buf[..n].to_vec())])
}

/// Listens on `tap` (since `origin`) until the traffic tells RTU from ASCII
/// ([`guess::guess`](super::guess::guess)), after what was read `before`: the mode and
/// everything read so far, to be replayed to the monitor; or why listening ended first.
pub fn listen_for_mode(
    tap: &mut dyn Tap,
    stop: &AtomicBool,
    duration: Option<Duration>,
    origin: Instant,
    line: crate::codec::timing::LineSettings,
    before: Heard,
) -> Result<Result<(crate::codec::Mode, Heard), Ended>, MonitorError> {
    use super::guess::{guess, why_not, Guess, GIVE_UP_AFTER};
    let poll = poll_interval(line);
    let mut buf = [0u8; 512];
    let mut bytes: Vec<u8> = before.iter().flat_map(|(_, b)| b.iter().copied()).collect();
    // Bytes since the last guess: guessed at the end of a burst (a read that came back
    // empty), or once enough are held to give up, not on every read.
    let mut fresh = !bytes.is_empty();
    let mut heard: Heard = before;
    loop {
        if stop.load(Ordering::Relaxed) {
            return Ok(Err(Ended::Interrupted));
        }
        if duration.is_some_and(|d| origin.elapsed() >= d) {
            return Ok(Err(Ended::Duration));
        }
        let (at, n) = match read_dated(tap, &mut buf, poll, origin) {
            Ok(r) => r,
            Err(e) => return Ok(Err(Ended::EndOfInput(e.to_string()))),
        };
        if n == 0 {
            quiet(&mut heard, at);
        } else {
            heard.push((at, buf[..n].to_vec()));
            bytes.extend_from_slice(&buf[..n]);
            fresh = true;
        }
        if !fresh || (n > 0 && bytes.len() < GIVE_UP_AFTER) {
            continue;
        }
        fresh = false;
        let g = guess(&bytes);
        if let Guess::Mode(mode, _) = g {
            return Ok(Ok((mode, heard)));
        }
        if let Some(why) = why_not(&g, line) {
            return Err(MonitorError::NoMode(why));
        }
    }
}

/// Listening that begins while the line is busy hears the tail of a frame first, which
/// is no frame of either side: it is not judged. RTU: bytes read before any read came
/// back empty go, up to the first silence of t3.5 (a read that came back empty waited a
/// poll, at least t1.5, and a frame whose characters are that far apart is broken: what
/// follows begins a frame); ASCII: those before the first `:`. Said once, with the
/// bytes, as a notice. A capture that the monitor wrote says where its first packet was
/// read so ([`crate::capture::HEARD_MID_TRAFFIC`]), and [`super::replay`] applies the
/// same rule to it.
pub(super) struct Entry {
    mode: crate::codec::Mode,
    t3_5: Duration,
    // When the last byte dropped was read.
    last: Option<Duration>,
    synced: bool,
    dropped: usize,
    first: Vec<u8>,
}

impl Entry {
    pub(super) fn new(mode: crate::codec::Mode, line: crate::codec::timing::LineSettings) -> Self {
        Entry {
            mode,
            t3_5: Duration::from_micros(line.t3_5_us()),
            last: None,
            synced: false,
            dropped: 0,
            first: Vec::new(),
        }
    }

    /// The line was quiet up to `at`.
    pub(super) fn idle(&mut self, at: Duration) {
        if self.synced || self.mode == crate::codec::Mode::Ascii {
            return;
        }
        match self.last {
            // Quiet before anything was heard.
            None => self.synced = true,
            Some(l) if at.saturating_sub(l) >= self.t3_5 => self.synced = true,
            Some(_) => {}
        }
    }

    /// Of `bytes` read at `at`, those to judge.
    pub(super) fn take<'a>(&mut self, at: Duration, bytes: &'a [u8]) -> &'a [u8] {
        if self.synced {
            return bytes;
        }
        let keep = match self.mode {
            crate::codec::Mode::Ascii => bytes.iter().position(|&b| b == b':'),
            crate::codec::Mode::Rtu => None,
        };
        let drop = keep.unwrap_or(bytes.len());
        self.dropped += drop;
        let room = 16usize.saturating_sub(self.first.len());
        self.first.extend_from_slice(&bytes[..drop.min(room)]);
        self.last = Some(at);
        self.synced = keep.is_some();
        &bytes[drop..]
    }

    /// The notice, once bytes were dropped and judging began (or listening ended).
    pub(super) fn notice(&mut self, ended: bool) -> Option<String> {
        if self.dropped == 0 || !(self.synced || ended) {
            return None;
        }
        let n = std::mem::take(&mut self.dropped);
        Some(format!(
            "listening began in the middle of the traffic: the first {n} bytes, before {}, were not judged (the tail of a frame): {}{}",
            match self.mode {
                crate::codec::Mode::Rtu => "a silence of t3.5",
                crate::codec::Mode::Ascii => "a ':'",
            },
            crate::codec::hex::Hex(&self.first),
            if n > self.first.len() { " ..." } else { "" }
        ))
    }
}

/// [`run`] with the clock started at `origin`, and what was read before (by
/// [`listen_for_mode`] or [`super::line_search::listen_for_line`]) fed first. What came
/// before the first frame began is not judged (see [`Entry`]).
pub fn run_from(
    tap: &mut dyn Tap,
    monitor: &mut Monitor,
    stop: &AtomicBool,
    duration: Option<Duration>,
    origin: Instant,
    before: Heard,
    mut say: impl FnMut(Said<'_>),
) -> Result<Ended, MonitorError> {
    let mut entry = Entry::new(monitor.config().mode, monitor.config().line);
    let mut hear = |monitor: &mut Monitor, at: Duration, bytes: &[u8]| {
        if bytes.is_empty() {
            entry.idle(at);
            monitor.idle(at);
        } else {
            let bytes = entry.take(at, bytes);
            if bytes.is_empty() {
                monitor.idle(at);
            } else {
                monitor.feed(at, bytes);
            }
        }
        if let Some(n) = entry.notice(false) {
            monitor.notice(n);
        }
    };
    for (at, bytes) in before {
        hear(monitor, at, &bytes);
        say_new(monitor, &mut say);
    }
    let poll = poll_interval(monitor.config().line);
    let mut buf = [0u8; 512];
    let mut next_summary = origin.elapsed() + SUMMARY_EVERY;
    let ended = loop {
        if stop.load(Ordering::Relaxed) {
            break Ended::Interrupted;
        }
        let now = origin.elapsed();
        if duration.is_some_and(|d| now >= d) {
            break Ended::Duration;
        }
        match read_dated(tap, &mut buf, poll, origin) {
            Ok((at, n)) => hear(monitor, at, &buf[..n]),
            Err(e) => break Ended::EndOfInput(e.to_string()),
        }
        say_new(monitor, &mut say);
        if origin.elapsed() >= next_summary {
            next_summary += SUMMARY_EVERY;
            let lines = monitor.summary("", "").node_lines();
            if !lines.is_empty() {
                say(Said::Summary(&lines));
            }
        }
    };
    // Stopped by the clock or a signal while a frame may be arriving: listen on until the
    // frame under way has ended and the line has been quiet for t3.5 after it (at most
    // DRAIN_AT_MOST), so that the last frame is heard whole rather than cut. The framer
    // holds the start of a frame cut short (a sender, or a host handing its bytes over,
    // late by more than t3.5 inside it) for its rest (`CARRY_HOLD`), and listening goes
    // on while it does. A quiet line is not asked for: a master polling back to back
    // leaves t3.5 between frames and no longer, and a frame the limit cuts anyway is not
    // judged ([`Monitor::finish`]).
    if matches!(ended, Ended::Duration | Ended::Interrupted) {
        let quiet = Duration::from_micros(monitor.config().line.t3_5_us());
        let until = origin.elapsed() + DRAIN_AT_MOST;
        let mut last = origin.elapsed();
        while origin.elapsed() < until {
            match read_dated(tap, &mut buf, poll, origin) {
                Ok((at, 0)) => {
                    hear(monitor, at, &[]);
                    if at.saturating_sub(last) >= quiet && !monitor.frame_under_way() {
                        break;
                    }
                }
                Ok((at, n)) => {
                    last = at;
                    hear(monitor, last, &buf[..n]);
                }
                Err(_) => break,
            }
        }
        say_new(monitor, &mut say);
    }
    if let Some(n) = entry.notice(true) {
        monitor.notice(n);
    }
    monitor.finish();
    say_new(monitor, &mut say);
    Ok(ended)
}
