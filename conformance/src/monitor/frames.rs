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

use std::borrow::Cow;
use std::time::Duration;

use crate::codec::crc::crc16;
use crate::codec::deframe::{bus_rtu_frame_len, AsciiDeframer, Event, RtuDeframer, RtuFraming};
use crate::codec::pdu::Direction;
use crate::codec::timing::LineSettings;
use crate::codec::{Mode, MAX_RTU_FRAME};

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
            char_us: line.char_time_us(),
            t15_us: line.t1_5_us(),
            t35_us: line.t3_5_us(),
            split_first: None,
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
        self.rtu.pending() + self.ascii.pending() + self.carry.as_ref().map_or(0, |c| c.bytes.len())
    }

    /// Pieces of the held block whose times are kept (at most one per byte held).
    pub fn held_pieces(&self) -> usize {
        self.pieces.len() + self.carry.as_ref().map_or(0, |c| c.pieces.len())
    }

    /// The side the next pieces come from (`None`: unknown, a tap).
    pub fn set_side(&mut self, side: Option<u64>) {
        self.side = side;
    }

    /// Feeds a piece of bytes that arrived at `at` (since the listener's origin).
    pub fn push(&mut self, at: Duration, bytes: &[u8], out: &mut Vec<TapFrame>) {
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
    /// node's address (or the broadcast address). Otherwise it feeds two pieces.
    pub fn takes_whole(&self, bytes: &[u8]) -> bool {
        self.mode == Mode::Rtu
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

    fn push_rtu(
        &mut self,
        at: Duration,
        low: Duration,
        since: Duration,
        bytes: &[u8],
        out: &mut Vec<TapFrame>,
    ) {
        if self.rtu.pending() == 0 {
            self.expire_carry(since, out);
        }
        if let Some(end_us) = self.split_first {
            if us(at).saturating_sub(end_us) < self.t35_us {
                self.split_first_byte();
            }
        }
        let (mut blocks, mut ends) = self.take_blocks();
        self.rtu
            .push_at(us(at), bytes, |e| add_block(&mut blocks, &mut ends, e));
        // Events during a push are the block the silence before these bytes closed
        // (or, past any frame's length, the block with these bytes: then nothing of it
        // is left held). Where no read proves that silence (the host read these bytes
        // late), a block that is no frame is held to be joined with them.
        let t35 = Duration::from_micros(self.t35_us);
        self.end_unproven = self.last_at.is_some_and(|l| since.saturating_sub(l) < t35);
        self.close_blocks(blocks, ends, EndedBy::Silence, out);
        self.end_unproven = false;
        if self.held == 0 {
            self.before_block = self.last_low;
        }
        self.held = (self.held + bytes.len()).min(MAX_RTU_FRAME * 4);
        if self.pieces.len() < MAX_RTU_FRAME * 4 {
            self.pieces.push(Piece {
                end: self.held,
                at,
                low,
                since,
                side: self.side,
            });
        }
        if self.rtu.pending() == 0 {
            self.pieces.clear();
            self.held = 0;
        }
    }

    /// The buffers for the deframer's blocks of one call, empty.
    fn take_blocks(&mut self) -> (Vec<u8>, Vec<usize>) {
        (
            std::mem::take(&mut self.blocks),
            std::mem::take(&mut self.block_ends),
        )
    }

    /// Closes the block the deframer held, with the pieces recorded for it (which are
    /// then let go; their buffer is kept).
    fn close_held(&mut self, block: &[u8], by: EndedBy, out: &mut Vec<TapFrame>) {
        let mut pieces = std::mem::take(&mut self.pieces);
        let before = self.before_block.take();
        self.held = 0;
        self.split_first = None;
        self.close_block(block, &pieces, before, by, true, out);
        pieces.clear();
        if self.pieces.is_empty() {
            self.pieces = pieces;
        }
    }

    /// Splits a silence-delimited block into frames (after the start of a frame cut short
    /// before it, if one is held); with `may_carry`, a last part that only starts a frame
    /// is held for its rest.
    fn close_block(
        &mut self,
        block: &[u8],
        pieces: &[Piece],
        before: Option<Duration>,
        by: EndedBy,
        may_carry: bool,
        out: &mut Vec<TapFrame>,
    ) {
        let (block, pieces, before, shared0): (Cow<'_, [u8]>, Cow<'_, [Piece]>, _, _) =
            match self.carry.take() {
                None => (Cow::Borrowed(block), Cow::Borrowed(pieces), before, false),
                Some(c) => {
                    let n = c.bytes.len();
                    let mut joined = c.bytes;
                    joined.extend_from_slice(block);
                    let mut ps = c.pieces;
                    ps.extend(pieces.iter().map(|p| Piece {
                        end: p.end + n,
                        ..*p
                    }));
                    (Cow::Owned(joined), Cow::Owned(ps), c.before, !c.begins)
                }
            };
        let char_us = self.char_us;
        // The arrival time of the piece holding byte `i`, and whether byte `i` begins it.
        let piece_of = |i: usize| -> (usize, bool) {
            let k = pieces
                .iter()
                .position(|p| p.end > i)
                .unwrap_or(pieces.len().saturating_sub(1));
            let begin = if k == 0 { 0 } else { pieces[k - 1].end };
            (k, begin == i && !(i == 0 && shared0))
        };
        let at = |k: usize| {
            pieces
                .get(k)
                .map_or(self.last_at.unwrap_or_default(), |p| p.at)
        };
        // The earliest the last byte of piece `k` can have come.
        let low = |k: usize| pieces.get(k).map_or(at(k), |p| p.low);
        let len_of = |k: usize| {
            pieces
                .get(k)
                .map_or(0, |p| p.end - if k == 0 { 0 } else { pieces[k - 1].end })
        };
        let silence_into = |k: usize, prev: Option<Duration>| -> Option<Duration> {
            let prev = prev?;
            let chars = Duration::from_micros(char_us * len_of(k) as u64);
            Some(at(k).saturating_sub(prev).saturating_sub(chars))
        };
        let mut pos = 0;
        while pos < block.len() {
            let (s, n, status) = split_next(&block[pos..]);
            // Bytes before a frame: a block of their own, and a frame of their own where
            // their CRC holds (a function the length rule does not know, 04H or 41H,
            // followed at once by a reply: the reply is found by its length first).
            let head = &block[pos..pos + s];
            // A CRC that checks over more bytes than any frame has is chance (1 in 65,536
            // blocks of noise), not a frame.
            let before_status = if (4..=MAX_RTU_FRAME).contains(&head.len()) && crc16(head) == 0 {
                FrameStatus::Valid
            } else {
                FrameStatus::Corrupt
            };
            let parts: [(usize, usize, FrameStatus); 2] =
                [(pos, s, before_status), (pos + s, n, status)];
            for (from, len, status) in parts {
                if len == 0 {
                    continue;
                }
                let to = from + len;
                let (k0, begins) = piece_of(from);
                // A carry is the start of one frame: never more bytes than a frame has
                // (a line that never falls silent would otherwise grow it for ever, each
                // block joined to the carry before it and carried again).
                if may_carry
                    && to == block.len()
                    && len <= MAX_RTU_FRAME
                    && status != FrameStatus::Valid
                    && (starts_frame(&block[from..]) || self.end_unproven)
                {
                    let prev = if k0 == 0 { before } else { Some(low(k0 - 1)) };
                    // In the buffers of the carry before (no allocation per carry).
                    let mut bytes = std::mem::take(&mut self.spare_bytes);
                    bytes.clear();
                    bytes.extend_from_slice(&block[from..]);
                    let mut held = std::mem::take(&mut self.spare_pieces);
                    held.clear();
                    held.extend(pieces.iter().filter(|p| p.end > from).map(|p| Piece {
                        end: p.end - from,
                        ..*p
                    }));
                    self.carry = Some(Carry {
                        bytes,
                        pieces: held,
                        before: prev,
                        begins,
                        last: at(piece_of(to - 1).0),
                    });
                    continue;
                }
                let (k1, _) = piece_of(to - 1);
                let prev = if k0 == 0 { before } else { Some(low(k0 - 1)) };
                let silence_before = if begins { silence_into(k0, prev) } else { None };
                // The silence the reads prove between two pieces: from the read that
                // returned the one to the read before the other, less one character
                // (the first byte after may have begun just before that read).
                let max_gap = (k0 + 1..=k1)
                    .map(|k| {
                        let since = pieces.get(k).map_or(at(k), |p| p.since);
                        since
                            .saturating_sub(at(k - 1))
                            .saturating_sub(Duration::from_micros(char_us))
                    })
                    .max();
                let gap_broken = max_gap.is_some_and(|g| g.as_micros() > u128::from(self.t15_us));
                let status = if status == FrameStatus::Valid || !gap_broken {
                    status
                } else {
                    FrameStatus::Incomplete
                };
                out.push(TapFrame {
                    bytes: block[from..to].to_vec(),
                    status,
                    ended_by: if to == block.len() {
                        by
                    } else {
                        EndedBy::Length
                    },
                    start: begins.then(|| at(k0)),
                    end: at(k1),
                    end_low: low(k1),
                    silence_before,
                    max_gap,
                    side: pieces.get(k0).and_then(|p| p.side),
                });
            }
            pos += s + n;
        }
        // A carry's buffers are kept for the next one.
        if let Cow::Owned(b) = block {
            if self.spare_bytes.capacity() == 0 {
                self.spare_bytes = b;
            }
        }
        if let Cow::Owned(p) = pieces {
            if self.spare_pieces.capacity() == 0 {
                self.spare_pieces = p;
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

fn us(d: Duration) -> u64 {
    u64::try_from(d.as_micros()).unwrap_or(u64::MAX)
}

/// Adds the deframer's block `e` to `blocks`, its end to `ends`.
fn add_block(blocks: &mut Vec<u8>, ends: &mut Vec<usize>, e: Event<'_>) {
    blocks.extend_from_slice(e.bytes());
    ends.push(blocks.len());
}

fn block_of(e: Event<'_>) -> (Vec<u8>, FrameStatus) {
    let status = match e {
        Event::Frame(_) => FrameStatus::Valid,
        Event::Corrupt(_) | Event::Garbage(_) => FrameStatus::Corrupt,
        Event::Incomplete(_) => FrameStatus::Incomplete,
    };
    (e.bytes().to_vec(), status)
}

/// Whether `bytes` are the start of a frame whose length (by either direction's rule)
/// says more bytes are due.
fn starts_frame(bytes: &[u8]) -> bool {
    if bytes.len() < 3 {
        return !bytes.is_empty() && bytes[0] <= 247;
    }
    [Direction::Request, Direction::Response]
        .into_iter()
        .any(|d| bus_rtu_frame_len(d, bytes).is_some_and(|n| n > bytes.len() && n <= MAX_RTU_FRAME))
}

/// The next frame in `rest` of a silence-delimited block: (bytes before it that are
/// none, its length, its status). A frame is found by the length rule of either
/// direction with a valid CRC, or is the whole rest with a valid CRC; bytes where no
/// frame starts are skipped one at a time, as the codec's by-length deframer does.
fn split_next(rest: &[u8]) -> (usize, usize, FrameStatus) {
    // A CRC that checks over more bytes than a frame has is chance, not a frame.
    let checks = |b: &[u8]| (4..=MAX_RTU_FRAME).contains(&b.len()) && crc16(b) == 0;
    let whole_ok = || checks(rest);
    for skip in 0..rest.len() {
        let head = &rest[skip..];
        for dir in [Direction::Response, Direction::Request] {
            if let Some(n) = bus_rtu_frame_len(dir, head) {
                if n <= head.len() && n >= 4 && crc16(&head[..n]) == 0 {
                    return (skip, n, FrameStatus::Valid);
                }
            }
        }
        if skip == 0 && whole_ok() {
            return (0, rest.len(), FrameStatus::Valid);
        }
        if checks(head) {
            return (skip, head.len(), FrameStatus::Valid);
        }
    }
    (0, rest.len(), FrameStatus::Corrupt)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::timing::Parity;

    fn ms(n: u64) -> Duration {
        Duration::from_millis(n)
    }

    fn framer() -> TapFramer {
        TapFramer::new(Mode::Rtu, LineSettings::new(9600, 8, Parity::Even, 1))
    }

    fn read_frame() -> Vec<u8> {
        crate::codec::pdu::Message {
            address: 1,
            pdu: crate::codec::pdu::Pdu::ReadRequest {
                start: 0x2520,
                count: 1,
            },
        }
        .to_frame_vec(Mode::Rtu)
        .unwrap()
    }

    fn reply_frame() -> Vec<u8> {
        crate::codec::pdu::Message {
            address: 1,
            pdu: crate::codec::pdu::Pdu::ReadResponse {
                values: crate::codec::pdu::Registers::new(&[0x12, 0x34]).unwrap(),
            },
        }
        .to_frame_vec(Mode::Rtu)
        .unwrap()
    }

    #[test]
    fn silence_ends_frames_and_is_measured_between_pieces() {
        let mut f = framer();
        let mut out = Vec::new();
        f.push(ms(0), &read_frame(), &mut out);
        f.push(ms(100), &reply_frame(), &mut out);
        f.idle(ms(200), &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        assert!(out
            .iter()
            .all(|t| t.status == FrameStatus::Valid && t.ended_by == EndedBy::Silence));
        assert_eq!(out[1].start, Some(ms(100)));
        let s = out[1].silence_before.unwrap();
        assert!(s > ms(90) && s < ms(100), "{s:?}");
    }

    #[test]
    fn length_splits_frames_delivered_together_and_their_silence_is_unknown() {
        let mut f = framer();
        let mut out = Vec::new();
        f.push(ms(0), &[read_frame(), reply_frame()].concat(), &mut out);
        f.idle(ms(100), &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        assert_eq!(out[0].ended_by, EndedBy::Length);
        assert_eq!(out[1].ended_by, EndedBy::Silence);
        assert_eq!(out[1].bytes, reply_frame());
        assert_eq!(out[1].silence_before, None);
        assert_eq!(out[1].start, None);
    }

    /// A 04H request (not served by the drives: answered with exception 01H or 02H) read
    /// together with the start of its reply, the rest in the next read, no silence seen
    /// between (a stalled host, a tap's latency timer): still two frames, both valid.
    #[test]
    fn a_request_of_a_function_the_drives_do_not_serve_is_split_from_its_reply() {
        let req = [0x01, 0x04, 0x25, 0x20, 0x00, 0x01, 0x3B, 0x0C];
        let rep = [0x01, 0x84, 0x02, 0xC2, 0xC1];
        assert_eq!(crc16(&req), 0);
        assert_eq!(crc16(&rep), 0);
        for cut in [8, 9, 10, 12] {
            let all = [&req[..], &rep[..]].concat();
            let mut f = framer();
            let mut out = Vec::new();
            f.push(ms(0), &all[..cut], &mut out);
            f.push(Duration::from_micros(1500), &all[cut..], &mut out);
            f.idle(ms(100), &mut out);
            let got: Vec<(&[u8], FrameStatus)> =
                out.iter().map(|t| (&t.bytes[..], t.status)).collect();
            assert_eq!(
                got,
                [
                    (&req[..], FrameStatus::Valid),
                    (&rep[..], FrameStatus::Valid)
                ],
                "cut at {cut}: {out:?}"
            );
        }
        // Replies of those functions by their byte count, requests of 0FH by theirs.
        assert_eq!(bus_rtu_frame_len(Direction::Response, &[1, 4, 6]), Some(11));
        assert_eq!(
            bus_rtu_frame_len(Direction::Request, &[1, 0x0F, 0, 0, 0, 9, 2]),
            Some(11)
        );
        assert_eq!(bus_rtu_frame_len(Direction::Request, &[1, 0x2B]), None);
    }

    #[test]
    fn a_gap_over_t15_inside_makes_a_corrupt_block_incomplete() {
        let mut f = framer();
        let mut out = Vec::new();
        let r = read_frame();
        f.push(ms(0), &r[..3], &mut out);
        // Nothing at 3.4 ms (the listener polls), the next byte read at 3.5 ms: a
        // silence of at least 3.4 ms less one character (2.3 ms), over t1.5 (1.7 ms) and
        // under t3.5 (4.0 ms).
        f.idle(Duration::from_micros(3400), &mut out);
        f.push(Duration::from_micros(3500), &r[3..4], &mut out);
        f.idle(ms(50), &mut out);
        // Its length says 4 more bytes are due: held a while for them, then given up.
        assert!(out.is_empty(), "{out:?}");
        f.idle(ms(100), &mut out);
        assert_eq!(out.len(), 1);
        assert_eq!(out[0].status, FrameStatus::Incomplete);
        assert_eq!(out[0].bytes, r[..4]);
    }

    #[test]
    fn a_frame_whose_rest_a_late_reader_got_later_is_joined_by_its_length() {
        let mut f = framer();
        let mut out = Vec::new();
        let r = reply_frame();
        f.push(ms(0), &read_frame(), &mut out);
        // The listener polls: nothing a millisecond before each piece.
        f.idle(ms(99), &mut out);
        f.push(ms(100), &r[..3], &mut out);
        // 20 ms later (over t3.5): the deframer ends a block, the length joins it.
        f.idle(ms(119), &mut out);
        f.push(ms(120), &r[3..], &mut out);
        f.idle(ms(300), &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        assert_eq!(out[1].bytes, r);
        assert_eq!(out[1].status, FrameStatus::Valid);
        assert_eq!(out[1].start, Some(ms(100)));
        let gap = out[1].max_gap.unwrap();
        assert!(gap > ms(15) && gap <= ms(20), "{gap:?}");
    }

    /// libmodbus's server answers 0.5 ms after a request: a 04H request (a function
    /// whose length the length rule does not know) and its exception reply come as one
    /// block. The reply is found by its length; the request before it keeps its valid CRC.
    #[test]
    fn a_frame_of_a_function_of_unknown_length_glued_to_its_reply_is_a_frame() {
        let mut f = framer();
        let mut out = Vec::new();
        let request = [0x01, 0x04, 0x25, 0x20, 0x00, 0x01, 0x3B, 0x0C];
        let reply = [0x01, 0x84, 0x02, 0xC2, 0xC1];
        f.push(ms(0), &[&request[..], &reply[..]].concat(), &mut out);
        f.idle(ms(50), &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        assert_eq!(out[0].bytes, request);
        assert_eq!(out[0].status, FrameStatus::Valid);
        assert_eq!(out[1].bytes, reply);
        assert_eq!(out[1].status, FrameStatus::Valid);
    }

    /// A listener that read the rest of a frame late, with no read between: the reads
    /// prove no silence inside it, and it is not cut (nor its reply called gappy).
    #[test]
    fn a_late_read_inside_a_frame_proves_no_gap() {
        let mut f = framer();
        let mut out = Vec::new();
        let r = reply_frame();
        f.idle(ms(99), &mut out);
        f.push(ms(100), &r[..2], &mut out);
        // Read 30 ms later, no read in between (the host was busy).
        f.push(ms(130), &r[2..], &mut out);
        f.idle(ms(300), &mut out);
        assert_eq!(out.len(), 1, "{out:?}");
        assert_eq!(out[0].status, FrameStatus::Valid);
        assert_eq!(out[0].max_gap, Some(Duration::ZERO));
    }

    /// Seen with pymodbus's server under load: the listener read the first 3 bytes of a
    /// request of a function of unknown length, then nothing for 30 ms (the host
    /// was busy), then the rest with the reply. No read proved a silence after the 3
    /// bytes: they are joined with the rest, not called a malformed request.
    #[test]
    fn a_frame_of_unknown_length_read_in_two_late_pieces_is_one_frame() {
        let mut f = framer();
        let mut out = Vec::new();
        // Function 41H (user-defined: no length rule knows it; 04H, first seen here,
        // now has one) and its exception reply.
        let with_crc = |body: &[u8]| {
            let mut v = body.to_vec();
            v.extend_from_slice(&crc16(body).to_le_bytes());
            v
        };
        let request = with_crc(&[0x01, 0x41, 0x25, 0x20, 0x00, 0x01]);
        let reply = with_crc(&[0x01, 0xC1, 0x01]);
        assert!(bus_rtu_frame_len(Direction::Request, &request).is_none());
        f.idle(ms(9), &mut out);
        f.push(ms(10), &request[..3], &mut out);
        f.push(ms(40), &[&request[3..], &reply[..]].concat(), &mut out);
        f.idle(ms(300), &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        assert_eq!(out[0].bytes, request);
        assert_eq!(out[0].status, FrameStatus::Valid);
        assert_eq!(out[1].bytes, reply);
        // The same bytes with reads that prove the silence (the listener polled at 20
        // and 30 ms): the 3 bytes are a block of their own.
        let mut f = framer();
        let mut out = Vec::new();
        f.idle(ms(9), &mut out);
        f.push(ms(10), &request[..3], &mut out);
        f.idle(ms(20), &mut out);
        f.idle(ms(30), &mut out);
        f.idle(ms(39), &mut out);
        f.push(ms(40), &request[3..], &mut out);
        f.idle(ms(300), &mut out);
        assert_eq!(out[0].bytes, request[..3], "{out:?}");
        assert_ne!(out[0].status, FrameStatus::Valid);
    }

    #[test]
    fn garbage_before_a_frame_comes_out_on_its_own() {
        let mut f = framer();
        let mut out = Vec::new();
        f.push(
            ms(0),
            &[&[0xFF, 0x00][..], &reply_frame()].concat(),
            &mut out,
        );
        f.idle(ms(50), &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        assert_eq!(out[0].status, FrameStatus::Corrupt);
        assert_eq!(out[0].bytes, [0xFF, 0x00]);
        assert_eq!(out[1].bytes, reply_frame());
    }

    #[test]
    fn ascii_frames_run_from_colon_to_crlf() {
        let mut f = TapFramer::new(Mode::Ascii, LineSettings::new(9600, 7, Parity::Even, 1));
        let mut out = Vec::new();
        f.push(ms(0), b":010325200001B6\r\n", &mut out);
        f.push(ms(100), b":0103021234B4\r", &mut out);
        f.push(ms(101), b"\n", &mut out);
        assert_eq!(out.len(), 2, "{out:?}");
        assert_eq!(out[1].ended_by, EndedBy::CrLf);
        assert_eq!(out[1].start, Some(ms(100)));
        assert_eq!(out[1].end, ms(101));
    }
}
