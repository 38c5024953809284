//! The streaming deframers' laws, on a stream fed in the chunks, bursts and silences
//! that the input's first byte chooses.

use super::frames::ascii_frame_valid;
use super::DIRECTIONS;
use crate::codec::crc::crc16;
use crate::codec::deframe::rtu_frame_len;
use crate::codec::timing::{LineSettings, Parity};
use crate::codec::{
    AsciiDeframer, Direction, Event, RtuDeframer, RtuFraming, MAX_ASCII_FRAME, MAX_RTU_FRAME,
};

/// How a deframer oracle feeds its stream, read from the first input byte (the control
/// byte) so that the fuzzer explores the feeding as it explores the bytes:
///
/// - bits 0-1: the largest chunk, 1, 8, 64 or 300 bytes (over one RTU frame);
/// - bit 2: the direction of the RTU frames (request or response);
/// - bit 3: also feed the chunks as bursts (RTU) or with gaps over the timeout (ASCII);
/// - bit 4: also feed the chunks with silences between them (RTU, by silence);
/// - bits 5-7, with the stream length: the seed of the chunk sizes and silences.
///
/// Chunk sizes are drawn from that seed, so one input tries one chunking, not all; every
/// law is checked on every input, for the feeding that input chose.
#[derive(Debug, Clone, Copy)]
struct Feed {
    max_chunk: u32,
    direction: Direction,
    bursts: bool,
    silences: bool,
    seed: u32,
}

fn feed(data: &[u8]) -> (Feed, &[u8]) {
    let (c, stream) = match data.split_first() {
        Some((&c, rest)) => (c, rest),
        None => (0, data),
    };
    let f = Feed {
        max_chunk: [1, 8, 64, 300][usize::from(c & 3)],
        direction: DIRECTIONS[usize::from(c >> 2 & 1)],
        bursts: c & 8 != 0,
        silences: c & 16 != 0,
        seed: (u32::from(c >> 5) << 24 ^ stream.len() as u32).wrapping_mul(0x9E37_79B9) | 1,
    };
    (f, stream)
}

/// The chunks of `stream` that `f` chooses, each with a draw for its timing.
struct Chunks<'a> {
    rest: &'a [u8],
    state: u32,
    max: u32,
}

impl<'a> Chunks<'a> {
    fn new(f: &Feed, stream: &'a [u8]) -> Self {
        Chunks {
            rest: stream,
            state: f.seed,
            max: f.max_chunk,
        }
    }
}

impl<'a> Iterator for Chunks<'a> {
    type Item = (&'a [u8], u32);
    fn next(&mut self) -> Option<Self::Item> {
        if self.rest.is_empty() {
            return None;
        }
        // xorshift32: cheap, and a function of the input only.
        let mut x = self.state;
        x ^= x << 13;
        x ^= x >> 17;
        x ^= x << 5;
        self.state = x;
        let n = (1 + x % self.max) as usize;
        let (chunk, rest) = self.rest.split_at(n.min(self.rest.len()));
        self.rest = rest;
        Some((chunk, x >> 16))
    }
}

/// What a deframer reported: bytes, frames, and a hash of the frames in order.
#[derive(Debug, Default, PartialEq, Eq)]
struct Tally {
    bytes: usize,
    frames: usize,
    hash: u64,
}

impl Tally {
    /// Checks each event as it comes (a frame event carries a valid checksum; no event is
    /// larger than a frame) and counts it.
    fn sink(&mut self, rtu: bool) -> impl FnMut(Event<'_>) + '_ {
        move |e| {
            if let Event::Frame(f) = e {
                if rtu {
                    assert!(f.len() >= 4 && f.len() <= MAX_RTU_FRAME);
                    assert_eq!(crc16(f), 0, "a frame event with a bad CRC");
                } else {
                    assert!(ascii_frame_valid(f), "a frame event with a bad LRC");
                }
                self.frames += 1;
                // FNV-1a over the frame and its length: the frames, in order.
                let mut h = self.hash ^ f.len() as u64;
                for &b in f {
                    h = (h ^ u64::from(b)).wrapping_mul(0x100_0000_01B3);
                }
                self.hash = h.wrapping_mul(0x100_0000_01B3);
            }
            assert!(
                e.bytes().len() <= MAX_ASCII_FRAME,
                "an event larger than any frame"
            );
            self.bytes += e.bytes().len();
        }
    }
}

/// RTU stream deframer: never panics; every frame event has a valid CRC; every byte is
/// reported exactly once; chunking does not change the frames (by length, the whole
/// stream at once against the chunks); fed as bursts that end on a quiet link, or by
/// silence with gaps under t1.5, between t1.5 and t3.5 and over t3.5, every byte still
/// comes out once in frames with valid CRCs. [`Feed`] says which direction, chunking and
/// feedings one input checks.
pub fn rtu_deframer(data: &[u8]) {
    let (f, stream) = feed(data);
    let dir = f.direction;
    let mut whole = Tally::default();
    let mut d = Box::new(RtuDeframer::new(dir, RtuFraming::ByLength));
    d.push(stream, |e| {
        if let Event::Frame(fr) = e {
            // By length, a frame is as long as its function code says.
            assert_eq!(rtu_frame_len(dir, fr), Some(fr.len()), "frame length");
        }
        whole.sink(true)(e)
    });
    d.flush(whole.sink(true));
    assert_eq!(whole.bytes, stream.len(), "bytes lost or duplicated");
    assert_eq!(d.pending(), 0, "bytes held after a flush");
    // One byte has no function code: no length yet.
    assert_eq!(rtu_frame_len(dir, &stream[..stream.len().min(1)]), None);
    let mut parts = Tally::default();
    *d = RtuDeframer::new(dir, RtuFraming::ByLength);
    let mut pushed = 0;
    for (c, _) in Chunks::new(&f, stream) {
        d.push(c, parts.sink(true));
        pushed += c.len();
        // Every byte is either reported or held.
        assert_eq!(
            parts.bytes + d.pending(),
            pushed,
            "bytes lost or duplicated"
        );
        assert!(
            !d.awaiting_rest() || d.pending() > 0,
            "awaiting with nothing held"
        );
    }
    d.flush(parts.sink(true));
    assert_eq!(whole, parts, "chunking changed the frames");
    if f.bursts {
        // Each chunk is a burst that ends on a quiet link (as the simulator on a pty sees
        // it).
        let mut bursts = Tally::default();
        *d = RtuDeframer::new(dir, RtuFraming::ByLength);
        for (c, _) in Chunks::new(&f, stream) {
            d.push(c, bursts.sink(true));
            d.end_burst(bursts.sink(true));
        }
        assert_eq!(
            bursts.bytes,
            stream.len(),
            "bytes lost or duplicated (bursts)"
        );
    }
    if f.silences {
        // A line chosen by the seed; gaps under t1.5 (inside a frame), between t1.5 and
        // t3.5 (a broken frame), over t3.5 (a new frame), or none (push without a time).
        let line = line_of(f.seed);
        let (t15, t35) = (line.t1_5_us(), line.t3_5_us());
        let mut silent = Tally::default();
        *d = RtuDeframer::new(dir, RtuFraming::BySilence(line));
        let mut now = 0u64;
        for (c, draw) in Chunks::new(&f, stream) {
            if draw & 7 == 7 {
                d.push(c, silent.sink(true));
                continue;
            }
            now += [t15 / 2, t15 / 2, (t15 + t35) / 2, 2 * t35][(draw & 3) as usize];
            d.push_at(now, c, silent.sink(true));
        }
        d.idle(now + 2 * t35, silent.sink(true));
        d.flush(silent.sink(true));
        assert_eq!(
            silent.bytes,
            stream.len(),
            "bytes lost or duplicated (by silence)"
        );
        assert_eq!(d.pending(), 0, "bytes held after a flush");
    }
}

/// A serial line drawn from `seed`: any of the usual rates, parity and stop bits.
fn line_of(seed: u32) -> LineSettings {
    const BAUDS: [u32; 8] = [1200, 2400, 4800, 9600, 19_200, 38_400, 57_600, 115_200];
    let parity = [Parity::None, Parity::Even, Parity::Odd][(seed >> 8) as usize % 3];
    let line = LineSettings::new(
        BAUDS[(seed >> 4) as usize % 8],
        8,
        parity,
        1 + (seed & 1) as u8,
    );
    assert!(line.t1_5_us() < line.t3_5_us() && line.char_time_us() > 0);
    assert!(!line.to_string().is_empty());
    line
}

/// ASCII stream deframer: never panics; every frame event has a valid LRC; every byte is
/// reported exactly once; chunking does not change the frames (the whole stream at once
/// against the chunks, 1 ms apart); with gaps over the inter-character timeout every byte
/// still comes out once in frames with valid LRCs. [`Feed`] says which chunking and
/// feedings one input checks.
pub fn ascii_deframer(data: &[u8]) {
    let (f, stream) = feed(data);
    let mut whole = Tally::default();
    let mut d = Box::new(AsciiDeframer::default());
    d.push(stream, whole.sink(false));
    d.flush(whole.sink(false));
    assert_eq!(whole.bytes, stream.len(), "bytes lost or duplicated");
    let mut parts = Tally::default();
    *d = AsciiDeframer::default();
    let mut pushed = 0;
    for (i, (c, _)) in Chunks::new(&f, stream).enumerate() {
        d.push_at(i as u64 * 1_000, c, parts.sink(false));
        pushed += c.len();
        assert_eq!(
            parts.bytes + d.pending(),
            pushed,
            "bytes lost or duplicated"
        );
    }
    d.flush(parts.sink(false));
    assert_eq!(d.pending(), 0, "bytes held after a flush");
    assert_eq!(whole, parts, "chunking changed the frames");
    if f.bursts {
        // A 5 ms timeout, chunks 1 ms or 10 ms apart: some frames are abandoned.
        let mut timed = Tally::default();
        *d = AsciiDeframer::new(5_000);
        let mut now = 0u64;
        for (c, draw) in Chunks::new(&f, stream) {
            now += if draw & 3 == 3 { 10_000 } else { 1_000 };
            if draw & 4 != 0 {
                d.idle(now, timed.sink(false));
            }
            d.push_at(now, c, timed.sink(false));
        }
        d.flush(timed.sink(false));
        assert_eq!(
            timed.bytes,
            stream.len(),
            "bytes lost or duplicated (timeouts)"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The control byte's feedings: every chunk is non-empty, at most the chosen size, and
    /// together they are the stream.
    #[test]
    fn chunks_cover_the_stream() {
        let stream: Vec<u8> = (0..=255).cycle().take(1000).collect();
        for c in 0..=255u8 {
            let mut data = vec![c];
            data.extend_from_slice(&stream);
            let (f, s) = feed(&data);
            let mut joined = Vec::new();
            for (chunk, _) in Chunks::new(&f, s) {
                assert!(!chunk.is_empty() && chunk.len() <= f.max_chunk as usize);
                joined.extend_from_slice(chunk);
            }
            assert_eq!(joined, stream);
        }
    }
}
