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

/// What the listener read, with its time since the origin: bytes, or none (a read that
/// came back empty at that time).
pub type Heard = Vec<(Duration, Vec<u8>)>;

/// Listens on `tap` (since `origin`) until the traffic tells RTU from ASCII
/// ([`guess::guess`](super::guess::guess)): the mode and everything read so far, to be
/// replayed to the monitor; or why listening ended first.
pub fn listen_for_mode(
    tap: &mut dyn Tap,
    stop: &AtomicBool,
    duration: Option<Duration>,
    origin: Instant,
    line: crate::codec::timing::LineSettings,
) -> Result<Result<(crate::codec::Mode, Heard), Ended>, MonitorError> {
    use super::guess::{guess, why_not, Guess, GIVE_UP_AFTER};
    let poll = poll_interval(line);
    let mut buf = [0u8; 512];
    let mut heard: Heard = Vec::new();
    let mut bytes: Vec<u8> = Vec::new();
    // Bytes since the last guess: guessed at the end of a burst (a read that came back
    // empty), or once enough are held to give up, not on every read.
    let mut fresh = false;
    loop {
        if stop.load(Ordering::Relaxed) {
            return Ok(Err(Ended::Interrupted));
        }
        if duration.is_some_and(|d| origin.elapsed() >= d) {
            return Ok(Err(Ended::Duration));
        }
        let n = match tap.listen(&mut buf, poll) {
            Ok(n) => n,
            Err(e) => return Ok(Err(Ended::EndOfInput(e.to_string()))),
        };
        let at = origin.elapsed();
        if n == 0 {
            // Only the last empty read before bytes matters (the earliest they came).
            match heard.last_mut() {
                Some((t, b)) if b.is_empty() => *t = at,
                _ => heard.push((at, Vec::new())),
            }
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

/// [`run`] with the clock started at `origin`, and what was read before (by
/// [`listen_for_mode`]) fed first.
pub fn run_from(
    tap: &mut dyn Tap,
    monitor: &mut Monitor,
    stop: &AtomicBool,
    duration: Option<Duration>,
    origin: Instant,
    before: Heard,
    mut say: impl FnMut(Said<'_>),
) -> Result<Ended, MonitorError> {
    for (at, bytes) in before {
        if bytes.is_empty() {
            monitor.idle(at);
        } else {
            monitor.feed(at, &bytes);
        }
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
        match tap.listen(&mut buf, poll) {
            Ok(0) => monitor.idle(origin.elapsed()),
            Ok(n) => monitor.feed(origin.elapsed(), &buf[..n]),
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
    monitor.finish();
    say_new(monitor, &mut say);
    Ok(ended)
}
