//! How `learn` talks to the device: one request at a time through a [`Device`] (the
//! runner's master on a live link, or a fake in the tests), counted, bounded by a
//! request cap and the stop flag, and each answer sorted into what it means.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::codec::hex::Hex;
use crate::codec::{frame_of_body, frame_parts, Mode};
use crate::runner::Master;
use crate::transport::{Transport, TransportError};

use super::LearnError;

/// What one request drew: the frames as they went and came, for the draft's evidence.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Heard {
    /// The request frame as sent.
    pub request: Vec<u8>,
    /// The reply frame (valid checksum), if one came.
    pub reply: Option<Vec<u8>>,
    /// Bytes heard that made no reply (garbage, a frame without a valid checksum).
    pub stray: usize,
    /// From the end of the request to the first byte of the reply.
    pub latency: Option<Duration>,
}

/// A device `learn` can ask: one request, and what came back.
pub trait Device {
    /// The transmission mode frames are sent in.
    fn mode(&self) -> Mode;
    /// Sends `frame` as it is and collects the answer; `expect_reply` false listens for
    /// a silence window only (a broadcast, another node, a bad checksum).
    fn exchange(&mut self, frame: &[u8], expect_reply: bool) -> Result<Heard, TransportError>;
}

/// The runner's master as a [`Device`]: the same echo handling, silence window and
/// late-reply settling as `check`.
pub struct LiveDevice<T: Transport + ?Sized> {
    master: Master<T>,
}

impl<T: Transport + ?Sized> LiveDevice<T> {
    /// Asks through `master`.
    pub fn new(master: Master<T>) -> Self {
        LiveDevice { master }
    }

    /// The master, for the link's description and echo.
    pub fn master(&self) -> &Master<T> {
        &self.master
    }
}

impl<T: Transport + ?Sized> Device for LiveDevice<T> {
    fn mode(&self) -> Mode {
        self.master.mode()
    }

    fn exchange(&mut self, frame: &[u8], expect_reply: bool) -> Result<Heard, TransportError> {
        let ex = self.master.exchange(frame, expect_reply)?;
        let stray = ex
            .after_echo()
            .len()
            .saturating_sub(ex.reply.as_ref().map_or(0, Vec::len));
        // As the runner measures a response delay: the first byte arrives one character
        // after the reply starts.
        let ct = self
            .master
            .transport()
            .line_timing()
            .map_or(Duration::ZERO, |l| Duration::from_micros(l.char_time_us()));
        Ok(Heard {
            request: ex.request,
            latency: ex
                .reply
                .as_ref()
                .and(ex.first_byte)
                .map(|t| t.saturating_sub(ct)),
            reply: ex.reply,
            stray,
        })
    }
}

/// What an answer means, for the search.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Answer {
    /// A normal reply of the request's function: its data (after address and function).
    Data(Vec<u8>),
    /// An exception reply with this code.
    Exception(u8),
    /// Nothing came back.
    Silent,
    /// Bytes came back that answer nothing (garbage, a frame with a bad checksum, a
    /// frame of another node or function).
    Other,
}

impl Answer {
    /// "reply", "exception 02H", "no reply", "no valid reply".
    pub fn describe(&self) -> String {
        match self {
            Answer::Data(_) => "reply".into(),
            Answer::Exception(c) => format!("exception {c:02X}H"),
            Answer::Silent => "no reply".into(),
            Answer::Other => "no valid reply".into(),
        }
    }
}

/// A request and its reply as the draft cites them: RTU frames in hex ("01 03 00 00 00
/// 01 84 0A"), ASCII frames as their characters without CR LF.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Evidence {
    /// The request.
    pub request: String,
    /// The reply, if one came.
    pub reply: Option<String>,
}

/// One frame as the draft writes it.
pub fn frame_text(mode: Mode, frame: &[u8]) -> String {
    match mode {
        Mode::Rtu => Hex(frame).to_string(),
        Mode::Ascii => String::from_utf8_lossy(frame)
            .trim_end_matches(['\r', '\n'])
            .to_string(),
    }
}

/// Progress of a learn: requests made, an estimate of those left, and what it does.
#[derive(Debug, Clone, Copy)]
pub struct Progress<'a> {
    /// Requests made so far.
    pub requests: u64,
    /// Requests still expected (an estimate: the map search does not know its blocks).
    pub left: u64,
    /// Time since the learn started.
    pub elapsed: Duration,
    /// What is being learned ("map 2500H", "exceptions").
    pub doing: &'a str,
}

/// The one way every part of `learn` asks: counts the requests, stops at the cap or
/// when the stop flag is set, keeps the response times, and reports progress.
pub struct Asker<'a> {
    device: &'a mut dyn Device,
    node: u8,
    stop: &'a AtomicBool,
    max_requests: u64,
    requests: u64,
    started: Instant,
    latencies: Vec<(Duration, Evidence)>,
    progress: &'a mut dyn FnMut(Progress<'_>),
    /// Requests still expected, set by the part that runs.
    pub left: u64,
    /// What the part that runs is doing.
    pub doing: String,
}

impl<'a> Asker<'a> {
    /// Asks node `node` of `device`, at most `max_requests` times.
    pub fn new(
        device: &'a mut dyn Device,
        node: u8,
        stop: &'a AtomicBool,
        max_requests: u64,
        progress: &'a mut dyn FnMut(Progress<'_>),
    ) -> Self {
        Asker {
            device,
            node,
            stop,
            max_requests,
            requests: 0,
            started: Instant::now(),
            latencies: Vec::new(),
            progress,
            left: 0,
            doing: String::new(),
        }
    }

    /// The node asked.
    pub fn node(&self) -> u8 {
        self.node
    }

    /// The mode.
    pub fn mode(&self) -> Mode {
        self.device.mode()
    }

    /// Requests made.
    pub fn requests(&self) -> u64 {
        self.requests
    }

    /// Sets the cap on requests (the map search runs under a lower one).
    pub fn set_cap(&mut self, max_requests: u64) {
        self.max_requests = max_requests;
    }

    /// Requests that may still be made under the cap.
    pub fn budget(&self) -> u64 {
        self.max_requests.saturating_sub(self.requests)
    }

    /// Time since the first request.
    pub fn elapsed(&self) -> Duration {
        self.started.elapsed()
    }

    /// Response times of the replies so far, each with the exchange it was measured on.
    pub fn latencies(&self) -> &[(Duration, Evidence)] {
        &self.latencies
    }

    /// Sends the request of `body` (address, function, data) with its checksum.
    pub fn ask(
        &mut self,
        body: &[u8],
        expect_reply: bool,
    ) -> Result<(Answer, Evidence), LearnError> {
        let mode = self.mode();
        let frame = frame_of_body(mode, body).map_err(|e| LearnError::Frame(e.to_string()))?;
        self.ask_frame(&frame, expect_reply)
    }

    /// Sends `frame` as it is (a damaged one too) and sorts its answer.
    pub fn ask_frame(
        &mut self,
        frame: &[u8],
        expect_reply: bool,
    ) -> Result<(Answer, Evidence), LearnError> {
        if self.stop.load(Ordering::Relaxed) {
            return Err(LearnError::Interrupted);
        }
        if self.requests >= self.max_requests {
            return Err(LearnError::Budget(self.max_requests));
        }
        (self.progress)(Progress {
            requests: self.requests,
            left: self.left,
            elapsed: self.started.elapsed(),
            doing: &self.doing,
        });
        self.left = self.left.saturating_sub(1);
        self.requests += 1;
        let mode = self.mode();
        let heard = self.device.exchange(frame, expect_reply)?;
        let evidence = Evidence {
            request: frame_text(mode, &heard.request),
            reply: heard.reply.as_ref().map(|r| frame_text(mode, r)),
        };
        let answer = sort(mode, frame, &heard);
        // Only replies to requests that wait for one are timed: a broadcast's or another
        // node's answer is a fault of its own, not the device's response time.
        if let (true, Some(t), Answer::Data(_) | Answer::Exception(_)) =
            (expect_reply, heard.latency, &answer)
        {
            self.latencies.push((t, evidence.clone()));
        }
        Ok((answer, evidence))
    }
}

/// What `heard` means as the answer to `request`: the reply of its node and function (or
/// that function's exception), else silence or something else.
pub fn sort(mode: Mode, request: &[u8], heard: &Heard) -> Answer {
    let Some(reply) = &heard.reply else {
        return if heard.stray == 0 {
            Answer::Silent
        } else {
            Answer::Other
        };
    };
    let (Ok(req), Ok(rep)) = (frame_parts(mode, request), frame_parts(mode, reply)) else {
        return Answer::Other;
    };
    match (req.body.as_slice(), rep.body.as_slice()) {
        ([a, f, ..], [b, g, code]) if a == b && *g == f | 0x80 => Answer::Exception(*code),
        ([a, f, ..], [b, g, data @ ..]) if a == b && f == g => Answer::Data(data.to_vec()),
        _ => Answer::Other,
    }
}

/// The registers of an 03H reply's data (byte count, then the values), if the count is
/// `count` registers.
pub fn registers(data: &[u8], count: u16) -> Option<Vec<u16>> {
    let (&n, values) = data.split_first()?;
    if usize::from(n) != values.len() || values.len() != 2 * usize::from(count) {
        return None;
    }
    Some(
        values
            .chunks_exact(2)
            .map(|w| u16::from_be_bytes([w[0], w[1]]))
            .collect(),
    )
}

/// Median and 99th percentile of `times` (nearest rank), or None for none.
pub fn median_p99(times: &[Duration]) -> Option<(Duration, Duration)> {
    if times.is_empty() {
        return None;
    }
    let mut t = times.to_vec();
    t.sort();
    let rank = |p: usize| t[(t.len() * p).div_ceil(100).clamp(1, t.len()) - 1];
    Some((t[(t.len() - 1) / 2], rank(99)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_are_sorted_by_node_and_function() {
        let req = frame_of_body(Mode::Rtu, &[1, 3, 0, 0, 0, 1]).unwrap();
        let heard = |reply: Option<&[u8]>, stray| Heard {
            request: req.clone(),
            reply: reply.map(|b| frame_of_body(Mode::Rtu, b).unwrap()),
            stray,
            latency: None,
        };
        assert_eq!(
            sort(Mode::Rtu, &req, &heard(Some(&[1, 3, 2, 0x12, 0x34]), 0)),
            Answer::Data(vec![2, 0x12, 0x34])
        );
        assert_eq!(
            sort(Mode::Rtu, &req, &heard(Some(&[1, 0x83, 2]), 0)),
            Answer::Exception(2)
        );
        // Another node's reply answers nothing.
        assert_eq!(
            sort(Mode::Rtu, &req, &heard(Some(&[2, 3, 2, 0, 0]), 0)),
            Answer::Other
        );
        assert_eq!(sort(Mode::Rtu, &req, &heard(None, 0)), Answer::Silent);
        assert_eq!(sort(Mode::Rtu, &req, &heard(None, 3)), Answer::Other);
        assert_eq!(registers(&[2, 0x12, 0x34], 1), Some(vec![0x1234]));
        assert_eq!(registers(&[4, 0x12, 0x34], 1), None);
    }

    #[test]
    fn median_and_p99_by_nearest_rank() {
        let ms = |v: &[u64]| {
            v.iter()
                .map(|&m| Duration::from_millis(m))
                .collect::<Vec<_>>()
        };
        assert_eq!(median_p99(&[]), None);
        let (m, p) = median_p99(&ms(&[5])).unwrap();
        assert_eq!((m, p), (Duration::from_millis(5), Duration::from_millis(5)));
        let hundred: Vec<u64> = (1..=100).collect();
        let (m, p) = median_p99(&ms(&hundred)).unwrap();
        assert_eq!(
            (m, p),
            (Duration::from_millis(50), Duration::from_millis(99))
        );
    }
}
