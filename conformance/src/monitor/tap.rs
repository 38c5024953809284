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
    let origin = Instant::now();
    let line = monitor.config().line;
    // Poll at about t1.5 so that t3.5 of silence is seen soon after it passes; arrival
    // times are taken when a read returns, which is as soon as bytes are there.
    let poll = Duration::from_micros(line.t1_5_us().clamp(500, 20_000));
    let mut buf = [0u8; 512];
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
        for l in monitor.take_lines() {
            on_line(&l);
        }
    };
    monitor.finish();
    for l in monitor.take_lines() {
        on_line(&l);
    }
    Ok(ended)
}
