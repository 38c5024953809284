//! Frames from a tap: bytes as a listening adapter delivers them, with their arrival
//! times, in; frames of either direction out, each saying which rule ended it.
//!
//! RTU: the codec's deframer ([`RtuDeframer`] with [`RtuFraming::BySilence`]) cuts the
//! stream at t3.5 of silence; inside such a block the length rule of the codec
//! ([`bus_rtu_frame_len`]: a request's length follows from its function and byte count, a
//! reply's from its function and byte count too) splits frames that came without t3.5
//! between them, or that a tap adapter delivered together. ASCII: the codec's
//! [`AsciiDeframer`], ':' to CR LF.
//!
//! Times: the tap sees when a piece of bytes arrived, not when each byte was on the line.
//! A silence is measured between two pieces only (less the character times of the bytes
//! of the later piece); between two frames delivered in one piece it is unknown.
//!
//! Reads at one moment are one read: a piece pushed at the time of the piece before it
//! (no time passed between them: the host read twice before it looked at the clock, or a
//! capture has two packets with one timestamp) joins it, and the two are dated as one
//! read's bytes. So a read is framed at the next call that shows time has passed (a
//! piece at a later time, [`TapFramer::idle`], [`TapFramer::finish`]), at most
//! [`STAGE_BYTES`] bytes at a time. Without this, the bytes of the first of two such
//! reads would be dated later than the same bytes read at once (a read's bytes are dated
//! back from its time, one character time a byte), and prove silences the line need not
//! have had.
//!
//! Splitting RTU blocks into frames (by silence, length and checksum) is `rtu.rs`.

use std::time::Duration;

use crate::codec::deframe::{AsciiDeframer, RtuDeframer, RtuFraming};
use crate::codec::pdu::Direction;
use crate::codec::timing::LineSettings;
use crate::codec::{Mode, MAX_RTU_FRAME};

mod rtu;

use rtu::{add_block, block_of, us};

/// The rule that ended a frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EndedBy {
    /// t3.5 of silence after it (RTU).
    Silence,
    /// Its length, from its function code and byte count (RTU); bytes followed it
    /// without t3.5 of silence, or in the same piece from the tap.
    Length,
    /// CR LF (ASCII).
    CrLf,
    /// The end of the input.
    EndOfInput,
}

impl EndedBy {
    /// The rule, as the live lines and reports spell it.
    pub fn key(self) -> &'static str {
        match self {
            EndedBy::Silence => "t3.5",
            EndedBy::Length => "length",
            EndedBy::CrLf => "CR LF",
            EndedBy::EndOfInput => "end of input",
        }
    }
}

/// What the bytes are.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum FrameStatus {
    /// A frame with a valid CRC or LRC.
    Valid,
    /// Delimited bytes that are no valid frame (a wrong checksum, bad hex, too short).
    Corrupt,
    /// A frame with a silence over t1.5 inside it (RTU), or abandoned (ASCII).
    Incomplete,
}

/// One frame (or block of bytes that is none) seen on the line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct TapFrame {
    /// The bytes.
    pub bytes: Vec<u8>,
    /// Valid, corrupt or incomplete.
    pub status: FrameStatus,
    /// The rule that ended it.
    pub ended_by: EndedBy,
    /// When its first byte arrived, where it began a piece from the tap.
    pub start: Option<Duration>,
    /// When its last byte arrived (was read).
    pub end: Duration,
    /// The earliest its last byte can have arrived (see `Piece`).
    pub end_low: Duration,
    /// The silence before it, where it began a piece from the tap that followed the
    /// previous bytes (less the character times of that piece).
    pub silence_before: Option<Duration>,
    /// The largest silence between two of its bytes that came in different pieces.
    pub max_gap: Option<Duration>,
    /// The sender its first byte came from, where the source knows (a capture's
    /// interface and direction flags): an opaque id, of which only whether two frames
    /// share it matters (see [`Monitor::set_side`](super::Monitor::set_side)).
    pub side: Option<u64>,
}

impl TapFrame {
    /// The earliest its first byte can have arrived: no later than it was read
    /// ([`start`](Self::start), else [`end`](Self::end)), and no sooner than its last
    /// byte ([`end_low`](Self::end_low)) less one character each `char_us` before it. A
    /// listener whose host was busy (it read late) reads a frame later than it came;
    /// this is how early the reads allow it to have been. Pairing and the late-reply rule
    /// give a frame that benefit of the doubt.
    pub fn earliest_start(&self, char_us: u64) -> Duration {
        let before = char_us.saturating_mul(self.bytes.len().saturating_sub(1) as u64);
        self.end_low
            .saturating_sub(Duration::from_micros(before))
            .min(self.start.unwrap_or(self.end))
    }
}

/// A piece of bytes from the tap: where it ends in the block, when it was read, and the
/// earliest its last byte can have arrived.
///
/// A read returns what came since the read before it; a busy host reads late, and then
/// the bytes look later than they were. None of a piece's bytes was there when the read
/// before it returned (`since`), and the line carries them one character time each, so
/// its last byte came no sooner than `since` + its characters (and no later than `at`).
/// A silence measured from that earliest end is the longest the reads allow: a finding
/// on it (t3.5 missed, a gap inside a frame) is one the reads prove, not one a late read
/// made up.
///
/// A gap inside a frame is the other way round: the line was silent at least from the
/// read that returned the bytes before it to the read before the bytes after it, which
/// came back without them (`since`). A gap judged on that is one the reads prove long.
#[derive(Debug, Clone, Copy)]
struct Piece {
    end: usize,
    at: Duration,
    low: Duration,
    since: Duration,
    /// The side it came from, where the source knows (a capture's direction flags).
    side: Option<u64>,
}

/// The most bytes of reads at one moment held before they are framed as one read (a
/// live read's buffer); the bytes past it are framed as another read at that moment.
pub const STAGE_BYTES: usize = 512;

/// How long the start of a frame cut short waits for its rest.
pub const CARRY_HOLD: Duration = Duration::from_millis(50);

/// The start of a frame cut short, with its pieces' times.
#[derive(Debug, Clone)]
struct Carry {
    bytes: Vec<u8>,
    pieces: Vec<Piece>,
    /// When the last byte before it came.
    before: Option<Duration>,
    /// Whether its first byte began a piece.
    begins: bool,
    last: Duration,
}

/// Splits the tap's stream into frames.
pub struct TapFramer {
    mode: Mode,
    rtu: RtuDeframer,
    ascii: AsciiDeframer,
    /// Pieces of the RTU block the deframer holds (at most one per byte of a frame).
    pieces: Vec<Piece>,
    /// Bytes of the block held (mirrors the deframer's buffer).
    held: usize,
    /// The earliest the last byte before the held block can have come (see [`Piece`]).
    before_block: Option<Duration>,
    last_at: Option<Duration>,
    /// The earliest the last byte read so far can have come.
    last_low: Option<Duration>,
    /// The side of the bytes being pushed, where known.
    side: Option<u64>,
    /// The block being closed ended at a silence no read proves (a late read).
    end_unproven: bool,
    /// When the last read returned, with bytes or without.
    last_poll: Option<Duration>,
    /// RTU: the start of a frame cut short by a silence (its length says more bytes are
    /// due), held for [`CARRY_HOLD`] in case the rest follows: a listener that was late to
    /// read the rest sees a silence the line did not have.
    carry: Option<Carry>,
    /// ASCII: when the ':' of the frame under way came, whether it began its piece, and
    /// the silence before that piece.
    colon: Option<(Duration, bool, Option<Duration>)>,
    /// The deframer's blocks of one call, end to end, and where each ends (kept between
    /// calls: no allocation per block).
    blocks: Vec<u8>,
    block_ends: Vec<usize>,
    /// The buffers of the last carry given up or joined, for the next one.
    spare_bytes: Vec<u8>,
    spare_pieces: Vec<Piece>,
    /// The line's character time, t1.5 and t3.5 (us), worked out once.
    char_us: u64,
    t15_us: u64,
    t35_us: u64,
    /// Set by [`TapFramer::push_packet`] where feeding its packet in two pieces would
    /// have cut the first byte off as a block of its own (the rest came over t3.5 after
    /// it) and held it as a carry: the deframer holds the whole packet instead, read at
    /// this time (us). Until the block is closed, or bytes join it (see
    /// [`TapFramer::split_first_byte`]), both ways give the same frames.
    split_first: Option<u64>,
    /// RTU, while a read is pushed: its piece, `end` counting its bytes that blocks
    /// closed during the push took. A block that the push closes past a frame's length
    /// is made of these bytes, and has no piece of its own yet.
    pushing: Option<Piece>,
    /// The block being closed does not begin a read (it is the rest of one).
    continued: bool,
    /// The read not framed yet (see the module notes): its bytes, its time and its side.
    staged: Vec<u8>,
    staged_at: Duration,
    staged_side: Option<u64>,
}

impl TapFramer {
    /// A framer for `mode` on `line`.
    pub fn new(mode: Mode, line: LineSettings) -> Self {
        TapFramer {
            mode,
            rtu: RtuDeframer::new(Direction::Request, RtuFraming::BySilence(line)),
            ascii: AsciiDeframer::default(),
            pieces: Vec::new(),
            held: 0,
            before_block: None,
            last_at: None,
            last_low: None,
            side: None,
            end_unproven: false,
            last_poll: None,
            carry: None,
            colon: None,
            blocks: Vec::new(),
            block_ends: Vec::new(),
            spare_bytes: Vec::new(),
            spare_pieces: Vec::new(),
            pushing: None,
            continued: false,
            char_us: line.char_time_us(),
            t15_us: line.t1_5_us(),
            t35_us: line.t3_5_us(),
            split_first: None,
            staged: Vec::new(),
            staged_at: Duration::ZERO,
            staged_side: None,
        }
    }

    /// Closes each block the deframer reported into `blocks`/`block_ends` (see
    /// [`TapFramer::close_held`]), then keeps the buffers for the next call.
    fn close_blocks(
        &mut self,
        blocks: Vec<u8>,
        mut ends: Vec<usize>,
        by: EndedBy,
        out: &mut Vec<TapFrame>,
    ) {
        let mut from = 0;
        for &to in &ends {
            self.close_held(&blocks[from..to], by, out);
            from = to;
        }
        ends.clear();
        let mut blocks = blocks;
        blocks.clear();
        self.blocks = blocks;
        self.block_ends = ends;
    }

    /// Bytes held now: the deframers' buffers and a frame cut short held for its rest.
    /// Bounded whatever the input (the deframers' buffers are fixed, a carry is at most a
    /// frame's start).
    pub fn held_bytes(&self) -> usize {
        self.rtu.pending()
            + self.ascii.pending()
            + self.carry.as_ref().map_or(0, |c| c.bytes.len())
            + self.staged.len()
    }

    /// Pieces of the held block whose times are kept (at most one per byte held), and
    /// the read not framed yet.
    pub fn held_pieces(&self) -> usize {
        self.pieces.len()
            + self.carry.as_ref().map_or(0, |c| c.pieces.len())
            + usize::from(!self.staged.is_empty())
    }

    /// The side the next pieces come from (`None`: unknown, a tap).
    pub fn set_side(&mut self, side: Option<u64>) {
        self.side = side;
    }

    /// Feeds a piece of bytes that arrived at `at` (since the listener's origin). It is
    /// framed once a later call shows that time has passed: until then, bytes at the same
    /// time (and from the same side) join it as one read's (see the module notes).
    pub fn push(&mut self, at: Duration, mut bytes: &[u8], out: &mut Vec<TapFrame>) {
        if !self.staged.is_empty() && (self.staged_at != at || self.staged_side != self.side) {
            self.settle(out);
        }
        while !bytes.is_empty() {
            let (now, rest) = bytes.split_at((STAGE_BYTES - self.staged.len()).min(bytes.len()));
            if self.staged.is_empty() {
                self.staged_at = at;
                self.staged_side = self.side;
            }
            self.staged.extend_from_slice(now);
            bytes = rest;
            if self.staged.len() == STAGE_BYTES {
                self.settle(out);
            }
        }
    }

    /// Frames the read held by [`TapFramer::push`], if any: time has passed since it.
    pub fn settle(&mut self, out: &mut Vec<TapFrame>) {
        if self.staged.is_empty() {
            return;
        }
        let bytes = std::mem::take(&mut self.staged);
        let side = std::mem::replace(&mut self.side, self.staged_side);
        self.push_read(self.staged_at, &bytes, out);
        self.side = side;
        self.staged = bytes;
        self.staged.clear();
    }

    /// Frames one read: `bytes` that arrived at `at`.
    fn push_read(&mut self, at: Duration, bytes: &[u8], out: &mut Vec<TapFrame>) {
        if bytes.is_empty() {
            return;
        }
        let chars = Duration::from_micros(self.char_us * bytes.len() as u64);
        let low = self.last_poll.map_or(at, |p| (p + chars).min(at));
        let since = self.last_poll.map_or(at, |p| p.min(at));
        match self.mode {
            Mode::Rtu => self.push_rtu(at, low, since, bytes, out),
            Mode::Ascii => self.push_ascii(at, bytes, out),
        }
        self.last_at = Some(at);
        self.last_low = Some(low);
        self.last_poll = Some(self.last_poll.map_or(at, |p| p.max(at)));
    }

    /// Feeds one whole packet from a capture: its first byte arrived at `first_at`, its
    /// last at `end_at`. The frames are those of `push(first_at, &bytes[..1])` then
    /// `push(end_at, &bytes[1..])` (response times are measured to the first byte, the
    /// packet ends when its last byte came), without cutting the packet in two and
    /// joining it again where nothing is held before it.
    pub fn push_packet(
        &mut self,
        first_at: Duration,
        end_at: Duration,
        bytes: &[u8],
        out: &mut Vec<TapFrame>,
    ) {
        self.settle(out);
        if !self.takes_whole(bytes) {
            let (head, rest) = bytes.split_at(1.min(bytes.len()));
            self.push(first_at, head, out);
            self.push(end_at, rest, out);
            return;
        }
        // The first byte as `push` takes it (nothing is held: it closes nothing, expires
        // no carry and starts the block).
        let char = Duration::from_micros(self.char_us);
        let low0 = self
            .last_poll
            .map_or(first_at, |p| (p + char).min(first_at));
        let since0 = self.last_poll.map_or(first_at, |p| p.min(first_at));
        let poll0 = self.last_poll.map_or(first_at, |p| p.max(first_at));
        let n = bytes.len();
        // The rest as `push` takes it.
        let chars = Duration::from_micros(self.char_us * (n - 1) as u64);
        let low1 = (poll0 + chars).min(end_at);
        let since1 = poll0.min(end_at);
        let (first_us, end_us) = (us(first_at), us(end_at));
        let split = end_us.saturating_sub(first_us) >= self.t35_us;
        if split {
            // The deframer would close the first byte as a block of its own, and
            // `close_block` would hold it as a carry (`starts_frame`: its address is one
            // of a node, checked in `takes_whole`). Held whole instead.
            self.rtu.push_at(end_us, bytes, |_| {});
            self.split_first = Some(end_us);
        } else {
            self.rtu.push_at(first_us, &bytes[..1], |_| {});
            self.rtu.push_at(end_us, &bytes[1..], |_| {});
        }
        self.before_block = self.last_low;
        self.pieces.push(Piece {
            end: 1,
            at: first_at,
            low: low0,
            since: since0,
            side: self.side,
        });
        self.pieces.push(Piece {
            end: n,
            at: end_at,
            low: low1,
            since: since1,
            side: self.side,
        });
        self.held = n;
        self.last_at = Some(end_at);
        self.last_low = Some(low1);
        self.last_poll = Some(poll0.max(end_at));
    }

    /// Whether [`TapFramer::push_packet`] takes `bytes` whole: RTU, nothing held (no
    /// block, no carry), a packet of 2 to [`MAX_RTU_FRAME`] bytes whose first byte is a
    /// node's address (or the broadcast address). Otherwise it feeds two pieces. (A read
    /// held by [`TapFramer::push`] is framed first: see [`TapFramer::settle`].)
    pub fn takes_whole(&self, bytes: &[u8]) -> bool {
        self.staged.is_empty()
            && self.mode == Mode::Rtu
            && (2..=MAX_RTU_FRAME).contains(&bytes.len())
            && bytes[0] <= 247
            && self.rtu.is_clear()
            && self.carry.is_none()
            && self.held == 0
            && self.pieces.is_empty()
            && self.split_first.is_none()
    }

    /// Where [`TapFramer::push_packet`] held a packet whole that two pieces would have
    /// left as a carried first byte and a block of the rest, and bytes now join that
    /// block: the state two pieces leave is made, so that what follows (a block past a
    /// frame's length, above all) goes as it would have.
    fn split_first_byte(&mut self) {
        let Some(end_us) = self.split_first.take() else {
            return;
        };
        let mut whole = std::mem::take(&mut self.blocks);
        whole.clear();
        self.rtu.flush(|e| whole.extend_from_slice(e.bytes()));
        if whole.is_empty() || self.pieces.len() != 2 {
            // Not the state `push_packet` left (cannot happen): nothing to undo.
            self.rtu.push_at(end_us, &whole, |_| {});
            whole.clear();
            self.blocks = whole;
            return;
        }
        self.rtu.push_at(end_us, &whole[1..], |_| {});
        let p0 = self.pieces.remove(0);
        for p in &mut self.pieces {
            p.end -= 1;
        }
        self.held = self.held.saturating_sub(1);
        let mut bytes = std::mem::take(&mut self.spare_bytes);
        bytes.clear();
        bytes.push(whole[0]);
        let mut pieces = std::mem::take(&mut self.spare_pieces);
        pieces.clear();
        pieces.push(p0);
        self.carry = Some(Carry {
            bytes,
            pieces,
            before: self.before_block,
            begins: true,
            last: p0.at,
        });
        self.before_block = Some(p0.low);
        whole.clear();
        self.blocks = whole;
    }

    /// Tells the framer that nothing came up to `now`: an RTU block followed by t3.5 of
    /// silence ends.
    pub fn idle(&mut self, now: Duration, out: &mut Vec<TapFrame>) {
        self.settle(out);
        self.last_poll = Some(self.last_poll.map_or(now, |p| p.max(now)));
        if self.mode == Mode::Rtu {
            let (mut blocks, mut ends) = self.take_blocks();
            self.rtu
                .idle(us(now), |e| add_block(&mut blocks, &mut ends, e));
            self.close_blocks(blocks, ends, EndedBy::Silence, out);
            if self.rtu.pending() == 0 {
                self.expire_carry(now, out);
            }
        }
    }

    /// Gives up the start of a frame held for its rest once the reads prove the line
    /// silent for [`CARRY_HOLD`] after it (`proven`: the last read that came back
    /// empty); a late read proves nothing.
    fn expire_carry(&mut self, proven: Duration, out: &mut Vec<TapFrame>) {
        if self
            .carry
            .as_ref()
            .is_some_and(|c| proven.saturating_sub(c.last) > CARRY_HOLD)
        {
            self.close_block(&[], &[], None, EndedBy::Silence, false, out);
        }
    }

    /// Ends the stream: everything held comes out.
    pub fn finish(&mut self, out: &mut Vec<TapFrame>) {
        self.settle(out);
        match self.mode {
            Mode::Rtu => {
                let mut blocks = Vec::new();
                self.rtu.flush(|e| blocks.push(block_of(e)));
                for (b, _) in blocks {
                    let pieces = std::mem::take(&mut self.pieces);
                    let before = self.before_block.take();
                    self.held = 0;
                    self.split_first = None;
                    self.close_block(&b, &pieces, before, EndedBy::EndOfInput, false, out);
                }
                if self.carry.is_some() {
                    self.close_block(&[], &[], None, EndedBy::EndOfInput, false, out);
                }
            }
            Mode::Ascii => {
                let at = self.last_at.unwrap_or_default();
                let mut events = Vec::new();
                self.ascii.flush(|e| events.push(block_of(e)));
                for (bytes, status) in events {
                    self.ascii_frame(at, bytes, status, EndedBy::EndOfInput, out);
                }
            }
        }
    }

    fn push_ascii(&mut self, at: Duration, bytes: &[u8], out: &mut Vec<TapFrame>) {
        let chars = Duration::from_micros(self.char_us * bytes.len() as u64);
        let mut first = true;
        let mut rest = bytes;
        while !rest.is_empty() {
            // At most one frame's end per push, so that each frame gets this piece's time.
            let cut = rest
                .iter()
                .position(|&b| b == b'\n')
                .map_or(rest.len(), |i| i + 1);
            let (seg, tail) = rest.split_at(cut);
            // The last ':' starts the frame under way (an earlier one is abandoned).
            if let Some(c) = seg.iter().rposition(|&b| b == b':') {
                let begins_piece = first && c == 0;
                let silence = if begins_piece {
                    self.last_at
                        .map(|p| at.saturating_sub(p).saturating_sub(chars))
                } else {
                    None
                };
                self.colon = Some((at, begins_piece, silence));
            }
            first = false;
            let mut events = Vec::new();
            self.ascii.push(seg, |e| events.push(block_of(e)));
            for (b, status) in events {
                self.ascii_frame(at, b, status, EndedBy::CrLf, out);
            }
            rest = tail;
        }
    }

    fn ascii_frame(
        &mut self,
        at: Duration,
        bytes: Vec<u8>,
        status: FrameStatus,
        by: EndedBy,
        out: &mut Vec<TapFrame>,
    ) {
        let (start, begins_piece, silence) = match self.colon.take() {
            Some((t, begins, silence)) => (Some(t), begins, silence),
            None => (None, false, None),
        };
        out.push(TapFrame {
            bytes,
            status,
            ended_by: by,
            start: if begins_piece { start } else { None },
            end: at,
            end_low: at,
            silence_before: silence,
            max_gap: None,
            side: self.side,
        });
    }
}

#[cfg(test)]
mod tests;
