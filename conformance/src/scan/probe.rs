//! One try of a scan: the read request, how long to listen for its reply, and what the
//! bytes heard mean.

use std::time::Duration;

use crate::codec::deframe::{AsciiDeframer, Event, RtuDeframer, RtuFraming};
use crate::codec::pdu::Direction;
use crate::codec::timing::LineSettings;
use crate::codec::{frame_of_body, frame_parts, read_response_len, Mode};

use super::settings::Setting;

/// The register a scan reads: 252FH, the identification register ("F510 check",
/// "A510 check", "L510 identification", "E510 check") of the four manuals (the legacy
/// L510 document reserves it; a device that has no such register answers an exception,
/// which is found all the same).
pub const ID_REGISTER: u16 = 0x252F;

/// The read request (03H, one register at [`ID_REGISTER`]) to `address` in `mode`.
pub fn request(mode: Mode, address: u8) -> Vec<u8> {
    let [hi, lo] = ID_REGISTER.to_be_bytes();
    // A body of six bytes always has a frame.
    frame_of_body(mode, &[address, 0x03, hi, lo, 0x00, 0x01]).unwrap_or_default()
}

/// How long one try listens, for one setting.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Windows {
    /// The request on the wire: its characters at the line's character time.
    pub request: Duration,
    /// t3.5 of the line.
    pub t3_5: Duration,
    /// After the request has left: how long to wait for the first character of a reply
    /// (the response time, two character times, and the link's slack).
    pub reply: Duration,
    /// After a first character: how long the whole reply may take (its characters, t3.5,
    /// and the slack).
    pub rest: Duration,
}

impl Windows {
    /// The windows of `setting`, for a device whose response time is `response` (the
    /// manuals': 10 ms; t3.5 where that is longer), on a link that adds up to `slack`
    /// (a USB adapter's latency timer, the host's scheduler). `reply` replaces the
    /// derived reply window where given.
    pub fn of(
        setting: &Setting,
        response: Duration,
        slack: Duration,
        reply: Option<Duration>,
    ) -> Self {
        let l: &LineSettings = &setting.line;
        let ct = Duration::from_micros(l.char_time_us());
        let t3_5 = Duration::from_micros(l.t3_5_us());
        let req_len = u32::try_from(request(setting.mode, 1).len()).unwrap_or(u32::MAX);
        let rep_len = u32::try_from(read_response_len(setting.mode, 1)).unwrap_or(u32::MAX);
        Windows {
            request: ct * req_len,
            t3_5,
            reply: reply.unwrap_or(response.max(t3_5) + ct * 2 + slack),
            rest: ct * rep_len + t3_5 + slack,
        }
    }

    /// The wire-time bound of one silent try: the request at the character time, t3.5,
    /// and the reply window.
    pub fn bound(&self) -> Duration {
        self.request + self.t3_5 + self.reply
    }
}

/// What a device answered.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Answer {
    /// A normal reply carrying the register's value.
    Value(u16),
    /// An exception reply with this code.
    Exception(u8),
    /// Another valid frame (another function, another length).
    Other,
}

impl Answer {
    /// "value 0510H", "exception 02H", "another frame".
    pub fn describe(&self) -> String {
        match self {
            Answer::Value(v) => format!("reply, 252FH = {v:04X}H"),
            Answer::Exception(c) => format!("exception {c:02X}H"),
            Answer::Other => "another frame".into(),
        }
    }
}

/// A valid frame heard.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Heard {
    /// Its node address.
    pub address: u8,
    /// What it says.
    pub answer: Answer,
    /// The frame's bytes.
    pub frame: Vec<u8>,
}

/// What one try heard: valid frames, and the bytes that made none.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Sifted {
    /// Valid frames (the local echo of the request is not one).
    pub frames: Vec<Heard>,
    /// Bytes that deframe to no valid frame.
    pub garbage: Vec<u8>,
    /// Whether the request came back first (a 2-wire adapter's local echo).
    pub echo: bool,
}

/// Most garbage bytes kept for a report.
pub const GARBAGE_KEPT: usize = 64;

fn answer_of(mode: Mode, frame: &[u8]) -> Option<Heard> {
    let parts = frame_parts(mode, frame).ok()?;
    let body = parts.body;
    let (&address, rest) = body.split_first()?;
    let answer = match rest {
        [0x03, 2, hi, lo] => Answer::Value(u16::from_be_bytes([*hi, *lo])),
        [0x83, code] => Answer::Exception(*code),
        _ => Answer::Other,
    };
    Some(Heard {
        address,
        answer,
        frame: frame.to_vec(),
    })
}

/// Sorts the bytes heard after `request` in `mode` into valid frames and garbage. A
/// prefix equal to the request is its local echo. Bounded: the deframers keep at most a
/// frame, and at most [`GARBAGE_KEPT`] garbage bytes are kept.
pub fn sift(mode: Mode, request: &[u8], bytes: &[u8]) -> Sifted {
    let mut out = Sifted::default();
    let mut rest = bytes;
    if !request.is_empty() && rest.starts_with(request) {
        out.echo = true;
        rest = &rest[request.len()..];
    }
    let mut on_event = |e: Event<'_>| match e {
        Event::Frame(f) => {
            if let Some(h) = answer_of(mode, f) {
                out.frames.push(h);
            }
        }
        other => {
            let b = other.bytes();
            let room = GARBAGE_KEPT.saturating_sub(out.garbage.len());
            out.garbage.extend_from_slice(&b[..b.len().min(room)]);
            if b.len() > room {
                // Count the rest without keeping it: one marker byte is enough to say
                // there was garbage.
                if out.garbage.is_empty() {
                    out.garbage.push(b[0]);
                }
            }
        }
    };
    match mode {
        Mode::Rtu => {
            let mut d = RtuDeframer::new(Direction::Response, RtuFraming::ByLength);
            d.push(rest, &mut on_event);
            d.flush(&mut on_event);
        }
        Mode::Ascii => {
            let mut d = AsciiDeframer::default();
            d.push(rest, &mut on_event);
            d.flush(&mut on_event);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::timing::Parity;

    #[test]
    fn the_request_reads_the_identification_register() {
        let body = [0x11, 0x03, 0x25, 0x2F, 0x00, 0x01];
        let mut rtu = body.to_vec();
        rtu.extend_from_slice(&crate::codec::crc16(&body).to_le_bytes());
        assert_eq!(request(Mode::Rtu, 0x11), rtu);
        assert_eq!(request(Mode::Ascii, 0x11), b":1103252F000197\r\n");
    }

    #[test]
    fn sifting_finds_replies_exceptions_echo_and_garbage() {
        let req = request(Mode::Rtu, 1);
        let reply = frame_of_body(Mode::Rtu, &[1, 0x03, 2, 0x05, 0x10]).unwrap();
        let s = sift(Mode::Rtu, &req, &reply);
        assert_eq!(s.frames.len(), 1);
        assert_eq!(s.frames[0].answer, Answer::Value(0x0510));
        assert!(s.garbage.is_empty() && !s.echo);

        let exc = frame_of_body(Mode::Rtu, &[1, 0x83, 2]).unwrap();
        let mut heard = req.clone();
        heard.extend_from_slice(&[0xF0, 0x00, 0x17]);
        heard.extend_from_slice(&exc);
        let s = sift(Mode::Rtu, &req, &heard);
        assert!(s.echo);
        assert_eq!(s.frames[0].answer, Answer::Exception(2));
        assert!(!s.garbage.is_empty());

        let s = sift(Mode::Rtu, &req, &[0x00, 0xE0, 0x1C, 0x00, 0xFF]);
        assert!(s.frames.is_empty());
        assert!(!s.garbage.is_empty());

        let areq = request(Mode::Ascii, 0x11);
        let s = sift(Mode::Ascii, &areq, b":1103020E518B\r\n");
        assert_eq!(s.frames[0].address, 0x11);
        assert_eq!(s.frames[0].answer, Answer::Value(0x0E51));
        let s = sift(Mode::Ascii, &areq, b"\x00\x8f:11");
        assert!(s.frames.is_empty() && !s.garbage.is_empty());
    }

    #[test]
    fn windows_follow_the_line() {
        let s = Setting {
            line: LineSettings::new(9600, 8, Parity::Even, 1),
            mode: Mode::Rtu,
        };
        let w = Windows::of(
            &s,
            Duration::from_millis(10),
            Duration::from_millis(5),
            None,
        );
        assert_eq!(w.request, Duration::from_micros(8 * 1146));
        assert_eq!(w.t3_5, Duration::from_micros(4011));
        assert_eq!(w.reply, Duration::from_micros(10_000 + 2 * 1146 + 5000));
        assert_eq!(
            w.bound(),
            Duration::from_micros(8 * 1146 + 4011 + 10_000 + 2 * 1146 + 5000)
        );
        // At 1200 baud t3.5 (32 ms) is longer than the manual's 10 ms.
        let s = Setting {
            line: LineSettings::new(1200, 8, Parity::Even, 1),
            mode: Mode::Ascii,
        };
        let w = Windows::of(&s, Duration::from_millis(10), Duration::ZERO, None);
        assert_eq!(w.reply, w.t3_5 + Duration::from_micros(2 * 9167));
    }
}
