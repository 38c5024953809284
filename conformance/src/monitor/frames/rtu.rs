//! RTU from a tap: blocks cut at t3.5 of silence, split into frames by the length rule
//! and the checksum, each frame saying which rule ended it.

use std::borrow::Cow;
use std::time::Duration;

use crate::codec::crc::crc16;
use crate::codec::deframe::{bus_rtu_frame_len, Event};
use crate::codec::pdu::Direction;
use crate::codec::MAX_RTU_FRAME;

use super::{Carry, EndedBy, FrameStatus, Piece, TapFrame, TapFramer};

impl TapFramer {
    pub(super) fn push_rtu(
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
        self.pushing = Some(Piece {
            end: 0,
            at,
            low,
            since,
            side: self.side,
        });
        // Events during a push are the block the silence before these bytes closed
        // (or, past any frame's length, the block with these bytes: then nothing of it
        // is left held). Where no read proves that silence (the host read these bytes
        // late), a block that is no frame is held to be joined with them.
        let t35 = Duration::from_micros(self.t35_us);
        self.end_unproven = self.last_at.is_some_and(|l| since.saturating_sub(l) < t35);
        self.close_blocks(blocks, ends, EndedBy::Silence, out);
        self.pushing = None;
        self.end_unproven = false;
        if self.held == 0 {
            self.before_block = self.last_low;
        }
        // The bytes held are the deframer's: where the push closed a block past a
        // frame's length, part of these bytes went with it, and what is held now came
        // in this push (its pieces before were let go with the block).
        self.held = self.rtu.pending().min(MAX_RTU_FRAME * 4);
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
    pub(super) fn take_blocks(&mut self) -> (Vec<u8>, Vec<usize>) {
        (
            std::mem::take(&mut self.blocks),
            std::mem::take(&mut self.block_ends),
        )
    }

    /// Closes the block the deframer held, with the pieces recorded for it (which are
    /// then let go; their buffer is kept).
    pub(super) fn close_held(&mut self, block: &[u8], by: EndedBy, out: &mut Vec<TapFrame>) {
        let mut pieces = std::mem::take(&mut self.pieces);
        // A block of the bytes being pushed (past a frame's length): dated by their read,
        // as its first bytes or as the rest of it.
        if let (true, Some(p)) = (pieces.is_empty(), self.pushing.as_mut()) {
            let chars = Duration::from_micros(
                self.char_us
                    .saturating_mul(p.end.saturating_add(block.len()) as u64),
            );
            pieces.push(Piece {
                end: block.len(),
                low: (p.since + chars).min(p.at),
                ..*p
            });
            self.continued = p.end > 0;
            p.end = p.end.saturating_add(block.len());
        }
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
    pub(super) fn close_block(
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
        let shared0 = shared0 || std::mem::take(&mut self.continued);
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
        // When the read before piece `k` returned, and where the piece begins.
        let since_of = |k: usize| pieces.get(k).map_or(at(k), |p| p.since);
        let begin_of = |k: usize| {
            if k == 0 {
                0
            } else {
                pieces.get(k - 1).map_or(0, |p| p.end)
            }
        };
        let len_of = |k: usize| {
            pieces.get(k).map_or(0, |p| {
                p.end
                    .saturating_sub(if k == 0 { 0 } else { pieces[k - 1].end })
            })
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
                        end: (p.end - from).min(block.len() - from),
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
                    // The earliest its last byte can have come: no sooner than its
                    // piece's last byte allows, nor than the read before and the piece's
                    // characters up to it.
                    end_low: low(k1).min(
                        since_of(k1)
                            + Duration::from_micros(
                                char_us.saturating_mul(to.saturating_sub(begin_of(k1)) as u64),
                            ),
                    ),
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
}

pub(super) fn us(d: Duration) -> u64 {
    u64::try_from(d.as_micros()).unwrap_or(u64::MAX)
}

/// Adds the deframer's block `e` to `blocks`, its end to `ends`.
pub(super) fn add_block(blocks: &mut Vec<u8>, ends: &mut Vec<usize>, e: Event<'_>) {
    blocks.extend_from_slice(e.bytes());
    ends.push(blocks.len());
}

pub(super) fn block_of(e: Event<'_>) -> (Vec<u8>, FrameStatus) {
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
