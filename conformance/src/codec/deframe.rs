//! Streaming deframers: bytes as they arrive from a line in, frames and garbage out.
//!
//! Both deframers are bounded (an RTU frame is at most 256 bytes, an ASCII frame at most
//! 513 characters; garbage is reported in pieces of at most 256 bytes), never allocate,
//! and report through a callback so that events can borrow their internal buffers.
//!
//! Every [`Event::Frame`] has a valid checksum; everything else the line carried comes
//! out as [`Event::Corrupt`], [`Event::Incomplete`] or [`Event::Garbage`], with its bytes.

use super::crc::crc16;
use super::pdu::{function, Direction};
use super::timing::LineSettings;
use super::{ascii, MAX_ASCII_FRAME, MAX_RTU_FRAME};

/// What a deframer found in the stream.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Event<'a> {
    /// A complete frame whose checksum is valid.
    Frame(&'a [u8]),
    /// A delimited frame (by silence in RTU, by ':' .. CR LF in ASCII) that is not valid:
    /// wrong checksum, bad hex, too short or too long.
    Corrupt(&'a [u8]),
    /// A frame that was started and abandoned: a silence over t1.5 inside an RTU frame, a
    /// ':' restarting an ASCII frame, the inter-character timeout, or an overlong frame.
    Incomplete(&'a [u8]),
    /// Bytes that belong to no frame.
    Garbage(&'a [u8]),
}

impl Event<'_> {
    /// The bytes of the event.
    pub fn bytes(&self) -> &[u8] {
        match self {
            Event::Frame(b) | Event::Corrupt(b) | Event::Incomplete(b) | Event::Garbage(b) => b,
        }
    }
}

/// Garbage waiting to be reported, in pieces of at most 256 bytes.
struct GarbageBuf {
    buf: [u8; 256],
    len: usize,
}

impl GarbageBuf {
    const fn new() -> Self {
        GarbageBuf {
            buf: [0; 256],
            len: 0,
        }
    }

    fn push(&mut self, b: u8, emit: &mut impl FnMut(Event<'_>)) {
        if self.len == self.buf.len() {
            self.flush(emit);
        }
        self.buf[self.len] = b;
        self.len += 1;
    }

    fn push_slice(&mut self, mut bytes: &[u8], emit: &mut impl FnMut(Event<'_>)) {
        while !bytes.is_empty() {
            if self.len == self.buf.len() {
                self.flush(emit);
            }
            let take = (self.buf.len() - self.len).min(bytes.len());
            self.buf[self.len..self.len + take].copy_from_slice(&bytes[..take]);
            self.len += take;
            bytes = &bytes[take..];
        }
    }

    fn flush(&mut self, emit: &mut impl FnMut(Event<'_>)) {
        if self.len > 0 {
            emit(Event::Garbage(&self.buf[..self.len]));
            self.len = 0;
        }
    }
}

/// How an RTU deframer finds the end of a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RtuFraming {
    /// By the length that the function code implies for the direction; on a CRC failure
    /// slide one byte and try again. For links without timing (pseudo-terminals, TCP).
    /// Frames of functions whose length cannot be known (anything but 03H, 06H, 08H with
    /// four data bytes, 10H and exceptions) cannot be found this way and come out as garbage.
    ByLength,
    /// By silence: t3.5 ends a frame, more than t1.5 inside a frame makes it incomplete.
    /// Needs arrival times ([`RtuDeframer::push_at`]).
    BySilence(LineSettings),
}

const RTU_BUF: usize = 1024;

/// The length of the RTU frame starting at `head`, as its function code implies.
enum Implied {
    NeedMore,
    Unknown,
    Len(usize),
}

/// The length of the RTU frame that starts `head`, as its function code implies for
/// `direction`: `None` while `head` is too short to tell, or for a function whose length
/// only a silence can tell (anything but 03H, 06H, 08H with two data bytes, 10H and
/// exceptions). The rule the by-length deframer uses, for callers that split a capture.
pub fn rtu_frame_len(direction: Direction, head: &[u8]) -> Option<usize> {
    match implied_len(direction, head) {
        Implied::Len(n) => Some(n),
        Implied::NeedMore | Implied::Unknown => None,
    }
}

/// As [`rtu_frame_len`], and for the Modbus Application Protocol's other fixed-shape
/// functions a master may send a drive anyway (01H, 02H and 04H reads, 05H, 0FH; the
/// drives answer them with an exception, another device on the bus may serve them): the
/// rule of a listener that hears a whole bus, so that such a request read together with
/// its reply is still told apart from it. The deframer keeps to the drives' functions.
pub fn bus_rtu_frame_len(direction: Direction, head: &[u8]) -> Option<usize> {
    if let Some(n) = rtu_frame_len(direction, head) {
        return Some(n);
    }
    let &fc = head.get(1)?;
    match (direction, fc) {
        (Direction::Request, 0x01 | 0x02 | 0x04 | 0x05) | (Direction::Response, 0x05 | 0x0F) => {
            Some(8)
        }
        (Direction::Request, 0x0F) => head.get(6).map(|&n| 9 + usize::from(n)),
        (Direction::Response, 0x01 | 0x02 | 0x04) => head.get(2).map(|&n| 5 + usize::from(n)),
        _ => None,
    }
}

fn implied_len(direction: Direction, head: &[u8]) -> Implied {
    let Some(&fc) = head.get(1) else {
        return Implied::NeedMore;
    };
    use function::*;
    match (direction, fc) {
        (Direction::Response, f) if f & EXCEPTION_BIT != 0 => Implied::Len(5),
        (Direction::Request, READ_HOLDING_REGISTERS | WRITE_SINGLE_REGISTER | LOOP_BACK)
        | (Direction::Response, WRITE_SINGLE_REGISTER | LOOP_BACK | WRITE_MULTIPLE_REGISTERS) => {
            Implied::Len(8)
        }
        (Direction::Request, WRITE_MULTIPLE_REGISTERS) => match head.get(6) {
            Some(&n) => Implied::Len(9 + usize::from(n)),
            None => Implied::NeedMore,
        },
        (Direction::Response, READ_HOLDING_REGISTERS) => match head.get(2) {
            Some(&n) => Implied::Len(5 + usize::from(n)),
            None => Implied::NeedMore,
        },
        _ => Implied::Unknown,
    }
}

/// Streaming RTU deframer.
pub struct RtuDeframer {
    direction: Direction,
    framing: RtuFraming,
    buf: [u8; RTU_BUF],
    end: usize,
    garbage: GarbageBuf,
    last_rx_us: Option<u64>,
    broken: bool,
    overflow: bool,
    /// By silence: the line's t1.5 and t3.5 (us), worked out once.
    t15_us: u64,
    t35_us: u64,
}

impl RtuDeframer {
    /// A deframer for frames travelling in `direction`.
    pub fn new(direction: Direction, framing: RtuFraming) -> Self {
        RtuDeframer {
            direction,
            framing,
            buf: [0; RTU_BUF],
            end: 0,
            garbage: GarbageBuf::new(),
            last_rx_us: None,
            broken: false,
            overflow: false,
            t15_us: match framing {
                RtuFraming::BySilence(line) => line.t1_5_us(),
                RtuFraming::ByLength => 0,
            },
            t35_us: match framing {
                RtuFraming::BySilence(line) => line.t3_5_us(),
                RtuFraming::ByLength => 0,
            },
        }
    }

    /// Bytes received but not yet reported.
    pub fn pending(&self) -> usize {
        self.end + self.garbage.len
    }

    /// Whether nothing is held and no burst or broken frame is under way: the next bytes
    /// start afresh whatever their time.
    pub fn is_clear(&self) -> bool {
        self.end == 0 && self.garbage.len == 0 && !self.overflow && !self.broken
    }

    /// With [`RtuFraming::ByLength`]: whether the buffered bytes begin a frame whose length
    /// the function code gives (or will give) and whose rest has not arrived yet, so that
    /// the deframer is waiting for bytes rather than for a silence.
    pub fn awaiting_rest(&self) -> bool {
        if self.framing != RtuFraming::ByLength || self.end == 0 {
            return false;
        }
        match implied_len(self.direction, &self.buf[..self.end]) {
            // One byte has no function code yet. Alone, it may be the address of a frame
            // whose rest is on its way (a master or a USB adapter that sends the first
            // byte alone): wait for the rest as for any other frame; the next bytes slide
            // it out if it was garbage. After held garbage it is the tail of a burst the
            // length rule could not place (an unmodelled function): no frame is under way.
            Implied::NeedMore => self.end >= 2 || self.garbage.len == 0,
            Implied::Len(n) => n > self.end && n <= MAX_RTU_FRAME,
            Implied::Unknown => false,
        }
    }

    /// Whether the bytes held are exactly one whole frame by its checksum (four bytes at
    /// least, a valid CRC), whatever length its function code implies: on a link without
    /// timing, a burst that ends there is a frame whose length field disagrees with it.
    pub fn holds_checked_burst(&self) -> bool {
        let held = self.garbage.len + self.end;
        (4..=MAX_RTU_FRAME).contains(&held)
            && crate::codec::crc::crc16_update(
                crc16(&self.garbage.buf[..self.garbage.len]),
                &self.buf[..self.end],
            ) == 0
    }

    /// Feeds bytes that follow the previous ones without a silence.
    pub fn push(&mut self, input: &[u8], mut emit: impl FnMut(Event<'_>)) {
        match self.framing {
            RtuFraming::ByLength => self.push_by_length(input, &mut emit),
            RtuFraming::BySilence(_) => {
                let now = self.last_rx_us.unwrap_or(0);
                self.push_at(now, input, emit)
            }
        }
    }

    /// Feeds bytes that arrived at `now_us` (a monotonic clock in microseconds). With
    /// [`RtuFraming::BySilence`] the gap since the previous bytes decides whether they
    /// continue a frame; with [`RtuFraming::ByLength`] the time is ignored.
    pub fn push_at(&mut self, now_us: u64, input: &[u8], mut emit: impl FnMut(Event<'_>)) {
        let RtuFraming::BySilence(_) = self.framing else {
            return self.push_by_length(input, &mut emit);
        };
        if input.is_empty() {
            return;
        }
        if self.end > 0 || self.overflow {
            let gap = now_us.saturating_sub(self.last_rx_us.unwrap_or(now_us));
            if gap >= self.t35_us {
                self.close_silent_frame(&mut emit);
            } else if gap > self.t15_us {
                self.broken = true;
            }
        }
        let mut rest = input;
        if !self.overflow {
            let take = (MAX_RTU_FRAME - self.end).min(rest.len());
            self.buf[self.end..self.end + take].copy_from_slice(&rest[..take]);
            self.end += take;
            rest = &rest[take..];
            if !rest.is_empty() {
                // Longer than any frame: report what was buffered now, and the rest of
                // the burst, up to the next silence, as garbage.
                emit(Event::Corrupt(&self.buf[..self.end]));
                self.end = 0;
                self.overflow = true;
            }
        }
        for &b in rest {
            self.garbage.push(b, &mut emit);
        }
        self.last_rx_us = Some(now_us);
    }

    /// Tells the deframer that the line has been quiet up to `now_us`: with
    /// [`RtuFraming::BySilence`] a frame followed by t3.5 of silence is reported.
    pub fn idle(&mut self, now_us: u64, mut emit: impl FnMut(Event<'_>)) {
        if let RtuFraming::BySilence(_) = self.framing {
            if self.end > 0 || self.overflow {
                let gap = now_us.saturating_sub(self.last_rx_us.unwrap_or(now_us));
                if gap >= self.t35_us {
                    self.close_silent_frame(&mut emit);
                }
            }
        }
    }

    /// Reports everything buffered, as at the end of the stream or after a long silence.
    /// By length: complete frames still found in the buffer come out, the rest is garbage.
    pub fn flush(&mut self, mut emit: impl FnMut(Event<'_>)) {
        match self.framing {
            RtuFraming::BySilence(_) => self.close_silent_frame(&mut emit),
            RtuFraming::ByLength => {
                scan(
                    self.direction,
                    &mut self.garbage,
                    &self.buf[..self.end],
                    &mut emit,
                    true,
                );
                self.end = 0;
                self.garbage.flush(&mut emit);
            }
        }
    }

    /// With [`RtuFraming::ByLength`], when the link has gone quiet: the bytes held since
    /// the last event are one burst. If they carry a valid CRC they are one frame (of a
    /// function whose length the rule cannot tell: masters write a whole frame at once, so
    /// on links without timing a burst is a frame); otherwise they are reported as
    /// [`flush`](Self::flush) reports them. With [`RtuFraming::BySilence`] this is `flush`.
    pub fn end_burst(&mut self, mut emit: impl FnMut(Event<'_>)) {
        let held = self.garbage.len + self.end;
        if self.framing == RtuFraming::ByLength && (4..=MAX_RTU_FRAME).contains(&held) {
            // Held garbage and the buffered tail are contiguous: together the burst.
            let mut burst = [0u8; MAX_RTU_FRAME];
            burst[..self.garbage.len].copy_from_slice(&self.garbage.buf[..self.garbage.len]);
            burst[self.garbage.len..held].copy_from_slice(&self.buf[..self.end]);
            if crc16(&burst[..held]) == 0 {
                emit(Event::Frame(&burst[..held]));
                self.garbage.len = 0;
                self.end = 0;
                return;
            }
        }
        self.flush(emit)
    }

    fn close_silent_frame(&mut self, emit: &mut impl FnMut(Event<'_>)) {
        if self.overflow {
            self.garbage.flush(emit);
            self.overflow = false;
            self.broken = false;
            return;
        }
        if self.end == 0 {
            return;
        }
        let frame = &self.buf[..self.end];
        let event = if self.broken {
            Event::Incomplete(frame)
        } else if frame.len() >= 4 && crc16(frame) == 0 {
            Event::Frame(frame)
        } else {
            Event::Corrupt(frame)
        };
        emit(event);
        self.end = 0;
        self.broken = false;
    }

    fn push_by_length(&mut self, mut input: &[u8], emit: &mut impl FnMut(Event<'_>)) {
        while !input.is_empty() {
            if self.end == 0 {
                // Nothing buffered: decide straight from the input and keep only the
                // undecided tail, which is shorter than the frame it may start (<= 256).
                let used = scan(self.direction, &mut self.garbage, input, emit, false);
                let rest = &input[used..];
                debug_assert!(rest.len() < MAX_RTU_FRAME);
                let keep = rest.len().min(RTU_BUF);
                self.buf[..keep].copy_from_slice(&rest[..keep]);
                self.end = keep;
                return;
            }
            // Top up the buffered partial frame; once it is decided, the loop goes back to
            // the direct path.
            let take = (RTU_BUF - self.end).min(input.len());
            self.buf[self.end..self.end + take].copy_from_slice(&input[..take]);
            self.end += take;
            input = &input[take..];
            let used = scan(
                self.direction,
                &mut self.garbage,
                &self.buf[..self.end],
                emit,
                false,
            );
            self.buf.copy_within(used..self.end, 0);
            self.end -= used;
        }
    }
}

/// Takes every decision the bytes allow and returns how many bytes were decided (reported
/// as a frame or as garbage). With `at_end`, bytes that cannot complete a frame are garbage
/// instead of a reason to wait.
fn scan(
    direction: Direction,
    garbage: &mut GarbageBuf,
    data: &[u8],
    emit: &mut impl FnMut(Event<'_>),
    at_end: bool,
) -> usize {
    let mut pos = 0;
    while pos < data.len() {
        let avail = &data[pos..];
        let len = match implied_len(direction, avail) {
            Implied::Len(n) if n <= MAX_RTU_FRAME && n <= avail.len() => Some(n),
            Implied::Len(n) if n <= MAX_RTU_FRAME && !at_end => return pos,
            Implied::NeedMore if !at_end => return pos,
            _ => None,
        };
        match len {
            Some(n) if crc16(&avail[..n]) == 0 => {
                garbage.flush(emit);
                emit(Event::Frame(&avail[..n]));
                pos += n;
            }
            _ => {
                garbage.push(avail[0], emit);
                pos += 1;
            }
        }
    }
    pos
}

/// memchr pays off on long inputs; a serial line often delivers a byte at a time.
#[inline]
fn find1(a: u8, hay: &[u8]) -> Option<usize> {
    if hay.len() < 16 {
        hay.iter().position(|&c| c == a)
    } else {
        memchr::memchr(a, hay)
    }
}

#[inline]
fn find2(a: u8, b: u8, hay: &[u8]) -> Option<usize> {
    if hay.len() < 16 {
        hay.iter().position(|&c| c == a || c == b)
    } else {
        memchr::memchr2(a, b, hay)
    }
}

/// Default ASCII inter-character timeout: 1 s (Modbus over Serial Line, 2.5.2.1).
pub const ASCII_DEFAULT_TIMEOUT_US: u64 = 1_000_000;

/// Streaming ASCII deframer: ':' starts a frame, CR LF ends it, a ':' inside a frame
/// restarts it, an inter-character timeout abandons it.
pub struct AsciiDeframer {
    buf: [u8; MAX_ASCII_FRAME],
    len: usize,
    in_frame: bool,
    garbage: GarbageBuf,
    timeout_us: u64,
    last_rx_us: Option<u64>,
}

impl Default for AsciiDeframer {
    fn default() -> Self {
        Self::new(ASCII_DEFAULT_TIMEOUT_US)
    }
}

impl AsciiDeframer {
    /// A deframer that abandons a frame after `timeout_us` without a character.
    pub fn new(timeout_us: u64) -> Self {
        AsciiDeframer {
            buf: [0; MAX_ASCII_FRAME],
            len: 0,
            in_frame: false,
            garbage: GarbageBuf::new(),
            timeout_us,
            last_rx_us: None,
        }
    }

    /// Characters received but not yet reported.
    pub fn pending(&self) -> usize {
        self.len + self.garbage.len
    }

    /// Feeds characters without timing information.
    pub fn push(&mut self, mut input: &[u8], mut emit: impl FnMut(Event<'_>)) {
        let emit = &mut emit;
        while let Some(&first) = input.first() {
            if !self.in_frame {
                // Outside a frame everything up to the next ':' is garbage.
                match find1(ascii::START, input) {
                    None => {
                        self.garbage.push_slice(input, emit);
                        return;
                    }
                    Some(i) => {
                        self.garbage.push_slice(&input[..i], emit);
                        self.garbage.flush(emit);
                        input = &input[i..];
                        // Fast path: the whole frame is in the input; judge it in place.
                        if let Some(j) = find2(ascii::START, b'\n', &input[1..]) {
                            let end = j + 2;
                            if input[end - 1] == b'\n'
                                && input[end - 2] == b'\r'
                                && end <= MAX_ASCII_FRAME
                            {
                                let frame = &input[..end];
                                emit(if ascii::is_valid_frame(frame) {
                                    Event::Frame(frame)
                                } else {
                                    Event::Corrupt(frame)
                                });
                                input = &input[end..];
                                continue;
                            }
                        }
                        self.start_frame();
                        input = &input[1..];
                    }
                }
                continue;
            }
            if first == ascii::START {
                emit(Event::Incomplete(&self.buf[..self.len]));
                self.start_frame();
                input = &input[1..];
                continue;
            }
            // Copy the run up to the next ':' (excluded) or LF (included) in one go.
            let stop = find2(ascii::START, b'\n', input);
            let run = match stop {
                Some(i) if input[i] == b'\n' => i + 1,
                Some(i) => i,
                None => input.len(),
            };
            let room = MAX_ASCII_FRAME - self.len;
            if run > room {
                // The frame outgrows 513 characters: report it; what follows is garbage
                // up to the next ':'.
                self.buf[self.len..].copy_from_slice(&input[..room]);
                self.len = MAX_ASCII_FRAME;
                emit(Event::Incomplete(&self.buf[..self.len]));
                self.in_frame = false;
                self.len = 0;
                input = &input[room..];
                continue;
            }
            self.buf[self.len..self.len + run].copy_from_slice(&input[..run]);
            self.len += run;
            input = &input[run..];
            if self.len >= 2 && self.buf[self.len - 2..self.len] == ascii::END {
                let frame = &self.buf[..self.len];
                emit(if ascii::is_valid_frame(frame) {
                    Event::Frame(frame)
                } else {
                    Event::Corrupt(frame)
                });
                self.in_frame = false;
                self.len = 0;
            }
        }
    }

    fn start_frame(&mut self) {
        self.buf[0] = ascii::START;
        self.len = 1;
        self.in_frame = true;
    }

    /// Feeds characters that arrived at `now_us`; a frame left open longer than the
    /// timeout is reported as incomplete first.
    pub fn push_at(&mut self, now_us: u64, input: &[u8], mut emit: impl FnMut(Event<'_>)) {
        self.idle(now_us, &mut emit);
        if !input.is_empty() {
            self.last_rx_us = Some(now_us);
        }
        self.push(input, emit);
    }

    /// Tells the deframer that nothing arrived up to `now_us`.
    pub fn idle(&mut self, now_us: u64, mut emit: impl FnMut(Event<'_>)) {
        if self.in_frame {
            if let Some(last) = self.last_rx_us {
                if now_us.saturating_sub(last) > self.timeout_us {
                    emit(Event::Incomplete(&self.buf[..self.len]));
                    self.in_frame = false;
                    self.len = 0;
                }
            }
        }
    }

    /// Reports everything buffered, as at the end of the stream.
    pub fn flush(&mut self, mut emit: impl FnMut(Event<'_>)) {
        if self.in_frame {
            emit(Event::Incomplete(&self.buf[..self.len]));
            self.in_frame = false;
            self.len = 0;
        }
        self.garbage.flush(&mut emit);
    }
}

#[cfg(test)]
mod burst_tests {
    use super::*;

    #[test]
    fn a_quiet_burst_with_a_valid_crc_is_a_frame() {
        // Function 2BH: the length rule cannot tell its length.
        let mut f = vec![0x01, 0x2B, 0x0E, 0x01, 0x00];
        f.extend_from_slice(&crate::codec::CrcBytes::of(&f).wire());
        let mut d = RtuDeframer::new(Direction::Request, RtuFraming::ByLength);
        let mut events = Vec::new();
        d.push(&f, |e| events.push(format!("{e:?}")));
        assert!(events.is_empty(), "{events:?}");
        d.end_burst(|e| events.push(format!("{e:?}")));
        assert_eq!(events, [format!("{:?}", Event::Frame(&f))]);
        assert_eq!(d.pending(), 0);
        // Without a valid CRC the burst is garbage, reported once.
        let mut g = f.clone();
        g[2] ^= 1;
        let mut seen = 0;
        d.push(&g, |_| panic!("nothing before the burst ends"));
        d.end_burst(|e| {
            assert!(matches!(e, Event::Garbage(_)));
            seen += e.bytes().len();
        });
        assert_eq!(seen, g.len());
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::pdu::{Message, Pdu, Registers};
    use crate::codec::timing::Parity;

    #[derive(Debug, Clone, PartialEq, Eq)]
    enum Owned {
        Frame(Vec<u8>),
        Corrupt(Vec<u8>),
        Incomplete(Vec<u8>),
        Garbage(Vec<u8>),
    }

    fn own(e: Event<'_>) -> Owned {
        match e {
            Event::Frame(b) => Owned::Frame(b.to_vec()),
            Event::Corrupt(b) => Owned::Corrupt(b.to_vec()),
            Event::Incomplete(b) => Owned::Incomplete(b.to_vec()),
            Event::Garbage(b) => Owned::Garbage(b.to_vec()),
        }
    }

    /// Merges adjacent garbage events: how garbage is split into events is not a promise.
    fn normalise(events: Vec<Owned>) -> Vec<Owned> {
        let mut out: Vec<Owned> = Vec::new();
        for e in events {
            if let (Some(Owned::Garbage(prev)), Owned::Garbage(g)) = (out.last_mut(), &e) {
                prev.extend_from_slice(g);
                continue;
            }
            out.push(e);
        }
        out
    }

    fn rtu(m: Message<'_>) -> Vec<u8> {
        m.to_rtu_vec().unwrap()
    }

    fn responses() -> Vec<Vec<u8>> {
        vec![
            rtu(Message {
                address: 1,
                pdu: Pdu::ReadResponse {
                    values: Registers::new(&[0x17, 0x70]).unwrap(),
                },
            }),
            rtu(Message {
                address: 1,
                pdu: Pdu::WriteSingle {
                    register: 0x2502,
                    value: 0x1770,
                },
            }),
            rtu(Message {
                address: 2,
                pdu: Pdu::Exception {
                    function: 3,
                    code: 2,
                },
            }),
            rtu(Message {
                address: 1,
                pdu: Pdu::WriteMultipleResponse {
                    start: 0x2502,
                    count: 2,
                },
            }),
            rtu(Message {
                address: 1,
                pdu: Pdu::LoopBack {
                    test_code: 0,
                    data: &[0xA5, 0x37],
                },
            }),
        ]
    }

    #[test]
    fn rtu_by_length_same_events_for_every_chunk_size() {
        let frames = responses();
        let mut stream = Vec::new();
        stream.extend_from_slice(&frames[0]);
        stream.extend_from_slice(&frames[1]);
        stream.extend_from_slice(&[0xFF, 0x00, 0x42]); // garbage
        stream.extend_from_slice(&frames[2]);
        stream.extend_from_slice(&frames[3][..5]); // truncated frame
        stream.extend_from_slice(&frames[4]);
        stream.extend_from_slice(&frames[0]);

        let run = |chunk: usize| {
            let mut d = RtuDeframer::new(Direction::Response, RtuFraming::ByLength);
            let mut ev = Vec::new();
            for c in stream.chunks(chunk) {
                d.push(c, |e| ev.push(own(e)));
            }
            d.flush(|e| ev.push(own(e)));
            normalise(ev)
        };
        let want = vec![
            Owned::Frame(frames[0].clone()),
            Owned::Frame(frames[1].clone()),
            Owned::Garbage(vec![0xFF, 0x00, 0x42]),
            Owned::Frame(frames[2].clone()),
            Owned::Garbage(frames[3][..5].to_vec()),
            Owned::Frame(frames[4].clone()),
            Owned::Frame(frames[0].clone()),
        ];
        for chunk in 1..=stream.len() {
            assert_eq!(run(chunk), want, "chunk size {chunk}");
        }
    }

    #[test]
    fn rtu_by_length_garbage_is_bounded() {
        let mut d = RtuDeframer::new(Direction::Request, RtuFraming::ByLength);
        let mut max = 0;
        d.push(&[0x55; 5000], |e| max = max.max(e.bytes().len()));
        assert!(max <= 256);
        assert!(d.pending() <= RTU_BUF + 256);
    }

    #[test]
    fn rtu_by_silence() {
        let line = LineSettings::new(9600, 8, Parity::Even, 1); // t1.5 1719 us, t3.5 4011 us
        let frames = responses();
        let mut d = RtuDeframer::new(Direction::Response, RtuFraming::BySilence(line));
        let mut ev = Vec::new();
        // A frame in two pieces 1 ms apart (under t1.5), then silence.
        d.push_at(0, &frames[0][..3], |e| ev.push(own(e)));
        d.push_at(1_000, &frames[0][3..], |e| ev.push(own(e)));
        d.idle(3_000, |e| ev.push(own(e)));
        assert!(ev.is_empty(), "t3.5 has not elapsed yet");
        d.idle(6_000, |e| ev.push(own(e)));
        // A frame with a 2 ms gap inside (over t1.5): incomplete.
        d.push_at(20_000, &frames[1][..4], |e| ev.push(own(e)));
        d.push_at(22_000, &frames[1][4..], |e| ev.push(own(e)));
        // Next burst after 10 ms closes it; this one has a bad CRC.
        let mut bad = frames[2].clone();
        bad[4] ^= 0xFF;
        d.push_at(32_000, &bad, |e| ev.push(own(e)));
        d.flush(|e| ev.push(own(e)));
        assert_eq!(
            ev,
            vec![
                Owned::Frame(frames[0].clone()),
                Owned::Incomplete(frames[1].clone()),
                Owned::Corrupt(bad),
            ]
        );
    }

    #[test]
    fn rtu_by_silence_overlong_is_corrupt_and_bounded() {
        let line = LineSettings::new(9600, 8, Parity::None, 1);
        let mut d = RtuDeframer::new(Direction::Request, RtuFraming::BySilence(line));
        let mut ev = Vec::new();
        d.push_at(0, &[0x01; 300], |e| ev.push(own(e)));
        d.flush(|e| ev.push(own(e)));
        assert_eq!(
            ev,
            vec![
                Owned::Corrupt(vec![0x01; 256]),
                Owned::Garbage(vec![0x01; 44])
            ]
        );
    }

    #[test]
    fn ascii_same_events_for_every_chunk_size() {
        let a = b":010301230001D7\r\n".to_vec();
        let b = b":0106250217704B\r\n".to_vec();
        let mut bad = a.clone();
        bad[14] = b'9';
        let mut stream = Vec::new();
        stream.extend_from_slice(&a);
        stream.extend_from_slice(b"xy\r\n");
        stream.extend_from_slice(b":01030123"); // restarted by the next ':'
        stream.extend_from_slice(&b);
        stream.extend_from_slice(&bad);
        stream.extend_from_slice(b":0106"); // truncated at the end

        let want = vec![
            Owned::Frame(a.clone()),
            Owned::Garbage(b"xy\r\n".to_vec()),
            Owned::Incomplete(b":01030123".to_vec()),
            Owned::Frame(b.clone()),
            Owned::Corrupt(bad.clone()),
            Owned::Incomplete(b":0106".to_vec()),
        ];
        for chunk in 1..=stream.len() {
            let mut d = AsciiDeframer::default();
            let mut ev = Vec::new();
            for c in stream.chunks(chunk) {
                d.push(c, |e| ev.push(own(e)));
            }
            d.flush(|e| ev.push(own(e)));
            assert_eq!(normalise(ev), want, "chunk size {chunk}");
        }
    }

    #[test]
    fn ascii_timeout_and_overflow() {
        let mut d = AsciiDeframer::new(1_000_000);
        let mut ev = Vec::new();
        d.push_at(0, b":0103", |e| ev.push(own(e)));
        d.push_at(2_000_000, b"0123", |e| ev.push(own(e)));
        assert_eq!(ev, vec![Owned::Incomplete(b":0103".to_vec())]);

        let mut d = AsciiDeframer::default();
        let mut ev = Vec::new();
        let mut long = vec![b':'];
        long.extend(std::iter::repeat_n(b'0', 600));
        d.push(&long, |e| ev.push(own(e)));
        d.flush(|e| ev.push(own(e)));
        assert_eq!(ev.len(), 2);
        assert!(matches!(&ev[0], Owned::Incomplete(b) if b.len() == MAX_ASCII_FRAME));
        assert!(matches!(&ev[1], Owned::Garbage(b) if b.len() == 601 - MAX_ASCII_FRAME));
    }
}
