//! Laws of the codec as functions of arbitrary bytes, shared by the fuzz targets (`fuzz/`)
//! and by the tests that replay their crash and regression inputs under plain
//! `cargo test`.
//!
//! Each function **panics when the codec breaks a law**: that is its purpose, as a test
//! oracle. Nothing in the codec calls these.

use crate::codec::crc::{crc16, crc16_reference, crc16_update, crc16_update_with, CrcPath};
use crate::codec::deframe::rtu_frame_len;
use crate::codec::timing::{LineSettings, Parity};
use crate::codec::{
    ascii_to_rtu, decode_ascii, decode_ascii_unchecked, decode_rtu, decode_rtu_unchecked,
    rtu_to_ascii, AsciiDeframer, Direction, Event, Message, Mode, RtuDeframer, RtuFraming,
    MAX_ASCII_FRAME, MAX_RTU_FRAME,
};

const DIRECTIONS: [Direction; 2] = [Direction::Request, Direction::Response];

/// Output buffers the oracles reuse: large arrays on the stack cost every execution an
/// AddressSanitizer fake-stack frame, and a `Vec` a heap allocation.
struct Scratch {
    rtu: [u8; MAX_RTU_FRAME],
    rtu2: [u8; MAX_RTU_FRAME],
    rtu3: [u8; MAX_RTU_FRAME],
    ascii: [u8; MAX_ASCII_FRAME],
    ascii2: [u8; MAX_ASCII_FRAME],
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Box<Scratch>> = std::cell::RefCell::new(Box::new(Scratch {
        rtu: [0; MAX_RTU_FRAME],
        rtu2: [0; MAX_RTU_FRAME],
        rtu3: [0; MAX_RTU_FRAME],
        ascii: [0; MAX_ASCII_FRAME],
        ascii2: [0; MAX_ASCII_FRAME],
    }));
}

fn with_scratch<R>(f: impl FnOnce(&mut Scratch) -> R) -> R {
    SCRATCH.with(|s| f(&mut s.borrow_mut()))
}

/// `emitted` is `data` with its letters upper-cased.
fn is_upper_of(emitted: &[u8], data: &[u8]) -> bool {
    emitted.len() == data.len()
        && emitted
            .iter()
            .zip(data)
            .all(|(e, d)| *e == d.to_ascii_uppercase())
}

/// The rest of the codec's view of a frame that decoded to `m` in `mode`: the frame view's
/// fields, the lengths every layer computes, the mode-generic entry points, re-addressing,
/// and the human forms (which must not panic). Run on frames that decode only, where it
/// costs little.
fn message_views(m: &Message<'_>, dir: Direction, mode: Mode, data: &[u8]) {
    use crate::codec::frame_len;
    let function = m.pdu.function_code();
    match mode {
        Mode::Rtu => {
            let v = crate::codec::RtuFrame::new_checked(data).expect("a decoded frame's view");
            assert_eq!((v.address(), v.function()), (m.address, function));
            assert_eq!(v.data(), &v.body()[2..]);
            assert_eq!(v.carried_crc(), v.computed_crc());
        }
        Mode::Ascii => {
            let v = crate::codec::AsciiFrame::new_checked(data).expect("a decoded frame's view");
            assert_eq!((v.address(), v.function()), (m.address, function));
            assert_eq!(v.binary_len(), m.body_len() + 1, "body and LRC");
            let hex = &data[1..data.len() - 2];
            assert_eq!(v.is_upper_case(), !hex.iter().any(u8::is_ascii_lowercase));
        }
    }
    assert_eq!(m.frame_len(mode), data.len());
    assert_eq!(frame_len(mode, m.body_len()), data.len());
    assert!(
        !matches!(m.pdu.direction(), Some(d) if d != dir),
        "layout of the other direction"
    );
    assert!(!m.pdu.name().is_empty());
    // The mode-generic entry points decode again and the human forms and owned frames
    // allocate: together they cost more than all the rest. One frame in eight, chosen by a
    // byte of the frame, so that mutants of any frame hit them.
    if data[data.len() / 2] & 7 == 0 {
        allocating_views(m, dir, mode, data);
    }
}

/// [`message_views`]' laws over the mode-generic decoders and the forms that allocate.
fn allocating_views(m: &Message<'_>, dir: Direction, mode: Mode, data: &[u8]) {
    use crate::codec::hex::Hex;
    use crate::codec::pdu::Pdu;
    use crate::codec::{decode, decode_unchecked, frame_of_body, readdressed};
    let mut scratch = [0u8; MAX_RTU_FRAME];
    assert_eq!(decode(mode, data, dir, &mut scratch).as_ref(), Ok(m));
    let mut scratch = [0u8; MAX_RTU_FRAME];
    let u = decode_unchecked(mode, data, dir, &mut scratch).expect("unchecked decodes");
    assert_eq!(&u.message, m);
    let fields = m.fields();
    assert_eq!(fields[0].0, "address");
    assert!(!m.to_string().is_empty() && !format!("{m:?}").is_empty());
    assert!(!dir.to_string().is_empty() && !format!("{:?}", Hex(data)).is_empty());
    if let Pdu::ReadResponse { values } = &m.pdu {
        assert_eq!(values.is_empty(), values.as_bytes().is_empty());
    }
    let mut body = [0u8; MAX_RTU_FRAME];
    let n = m.emit_body(&mut body).expect("the body emits");
    assert!(
        m.emit_body(&mut [0u8; MAX_RTU_FRAME][..n - 1]).is_err(),
        "short body buffer"
    );
    let k = m.pdu.data_len();
    assert!(k == 0 || m.pdu.emit_data(&mut [0u8; MAX_RTU_FRAME][..k - 1]).is_err());
    let again = frame_of_body(mode, &body[..n]).expect("a frame of the body");
    assert_eq!(again.len(), data.len());
    assert!(
        frame_of_body(mode, &body[..1]).is_err(),
        "a body without a function code"
    );
    let other = m.address.wrapping_add(1);
    let re = readdressed(mode, data, other).expect("a decoded frame re-addresses");
    let mut scratch = [0u8; MAX_RTU_FRAME];
    let r = decode(mode, &re, dir, &mut scratch).expect("the re-addressed frame decodes");
    assert_eq!((r.address, &r.pdu), (other, &m.pdu));
}

/// RTU frame parser, both directions: never panics; a frame that decodes re-encodes to
/// exactly its bytes; the unchecked path agrees with the checked one; a frame that decodes
/// converts to ASCII and back unchanged.
pub fn rtu_frame(data: &[u8]) {
    let mut converted = false;
    for dir in DIRECTIONS {
        let checked = decode_rtu(data, dir);
        let unchecked = decode_rtu_unchecked(data, dir);
        match (&checked, &unchecked) {
            (Ok(m), Ok(u)) => {
                assert!(u.checksum.is_valid(), "checked accepts a bad CRC");
                assert_eq!(&u.message, m, "unchecked and checked decode differently");
                message_views(m, dir, Mode::Rtu, data);
                with_scratch(|s| {
                    let n = m
                        .emit_rtu(&mut s.rtu)
                        .expect("a decoded message re-encodes");
                    assert_eq!(&s.rtu[..n], data, "emit(parse(x)) != x");
                    assert!(
                        m.emit_rtu(&mut s.rtu2[..n - 1]).is_err(),
                        "emit into a buffer one byte short"
                    );
                    // The conversion does not depend on the direction: once per frame.
                    if !converted {
                        let n = rtu_to_ascii(data, &mut s.ascii).expect("a valid frame converts");
                        let k =
                            ascii_to_rtu(&s.ascii[..n], &mut s.rtu2).expect("and converts back");
                        assert_eq!(&s.rtu2[..k], data);
                    }
                });
                converted = true;
            }
            (Ok(_), Err(e)) => panic!("unchecked rejects what checked accepts: {e}"),
            (Err(_), Ok(u)) => assert!(
                !u.checksum.is_valid(),
                "checked rejects a frame with a valid CRC that unchecked decodes"
            ),
            (Err(_), Err(_)) => {}
        }
    }
}

/// ASCII frame parser, both directions: never panics; a frame that decodes re-encodes to
/// its characters (upper-cased); conversion to RTU and back is the identity up to case;
/// the deframer's fast validity check agrees with the parser's.
pub fn ascii_frame(data: &[u8]) {
    let mut converted = false;
    for dir in DIRECTIONS {
        with_scratch(|s| {
            let Scratch {
                rtu,
                rtu2,
                rtu3,
                ascii,
                ascii2,
            } = s;
            let checked = decode_ascii(data, dir, rtu);
            let unchecked = decode_ascii_unchecked(data, dir, rtu2);
            match (&checked, &unchecked) {
                (Ok(m), Ok(u)) => {
                    assert!(u.checksum.is_valid(), "checked accepts a bad LRC");
                    assert_eq!(&u.message, m, "unchecked and checked decode differently");
                    let n = m.emit_ascii(ascii).expect("a decoded message re-encodes");
                    assert!(is_upper_of(&ascii[..n], data), "emit(parse(x)) != x");
                    assert!(
                        m.emit_ascii(&mut ascii2[..n - 1]).is_err(),
                        "emit into a buffer one byte short"
                    );
                    message_views(m, dir, Mode::Ascii, data);
                    if !converted {
                        let k = ascii_to_rtu(data, rtu3).expect("a valid frame converts");
                        assert!(
                            ascii_to_rtu(data, &mut rtu2[..k - 1]).is_err(),
                            "short buffer"
                        );
                        let n = rtu_to_ascii(&rtu3[..k], ascii2).expect("and converts back");
                        assert!(is_upper_of(&ascii2[..n], data), "ASCII -> RTU -> ASCII");
                    }
                    converted = true;
                }
                (Ok(_), Err(e)) => panic!("unchecked rejects what checked accepts: {e}"),
                (Err(_), Ok(u)) => assert!(
                    !u.checksum.is_valid(),
                    "checked rejects a frame with a valid LRC that unchecked decodes"
                ),
                (Err(_), Err(_)) => {}
            }
        });
    }
    assert_eq!(
        crate::codec::ascii::is_valid_frame(data),
        ascii_frame_valid(data),
        "the deframer's fast check disagrees with the parser"
    );
}

/// The parser's judgement of a whole ASCII frame: its view builds and its LRC checks.
fn ascii_frame_valid(f: &[u8]) -> bool {
    crate::codec::AsciiFrame::new_checked(f)
        .and_then(|v| v.verify_lrc())
        .is_ok()
}

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

/// The manuals' bitwise CRC loop, one byte at a time from register value 0, for every
/// byte value: the table of the oracle's byte-wise reference. Built from the manuals'
/// loop, not from the codec's tables.
const REFERENCE_TABLE: [u16; 256] = {
    let mut t = [0u16; 256];
    let mut i = 0;
    while i < 256 {
        let mut crc = i as u16;
        let mut bit = 0;
        while bit < 8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ 0xA001
            } else {
                crc >> 1
            };
            bit += 1;
        }
        t[i] = crc;
        i += 1;
    }
    t
};

/// The manuals' CRC, a byte per step instead of a bit: equal to [`crc16_reference`] for
/// every register value and byte (`reference_table_is_the_manual_loop` checks all 2^24).
fn crc16_bytewise(data: &[u8]) -> u16 {
    data.iter().fold(0xFFFF, |crc, &b| {
        (crc >> 8) ^ REFERENCE_TABLE[usize::from((crc ^ u16::from(b)) as u8)]
    })
}

/// Inputs up to this length are also checked against the manuals' bit loop itself.
const BITWISE_MAX: usize = 64;

/// CRC differential: the fast CRC, and every path this CPU can run forced (table,
/// PCLMULQDQ, AVX2 and AVX-512 VPCLMULQDQ), equals the manuals' reference, whole and in
/// pieces. The first two bytes choose the split; the input is also taken at every offset
/// 0..64 of itself, so each SIMD path sees every alignment. Short inputs are checked
/// against the manuals' bit loop itself; every input against the byte-at-a-time form of
/// the same loop, which is proven equal to it exhaustively by a unit test, at an eighth of
/// the cost.
pub fn crc_differential(data: &[u8]) {
    let reference = crc16_bytewise(data);
    if data.len() <= BITWISE_MAX {
        assert_eq!(crc16_reference(data), reference);
    }
    assert_eq!(crc16(data), reference);
    let split = data
        .get(..2)
        .map_or(0, |b| usize::from(u16::from_le_bytes([b[0], b[1]])))
        .min(data.len());
    let (a, b) = data.split_at(split);
    assert_eq!(crc16_update(crc16_update(0xFFFF, a), b), reference);
    for path in CrcPath::supported() {
        let name = path.name();
        assert_eq!(
            crc16_update_with(path, 0xFFFF, data),
            Some(reference),
            "{name}"
        );
        let first = crc16_update_with(path, 0xFFFF, a);
        let whole = first.and_then(|c| crc16_update_with(path, c, b));
        assert_eq!(whole, Some(reference), "{name} split at {split}");
        for offset in 1..data.len().min(64) {
            let tail = &data[offset..];
            assert_eq!(
                crc16_update_with(path, 0xFFFF, tail),
                Some(crc16_bytewise(tail)),
                "{name} at offset {offset}"
            );
        }
    }
}

/// Vector-file loader, and the hex reader on the same text: never panics on any text; a
/// file that loads verifies (in the
/// built-in set, in the place of its document's file) and renders without panicking, and
/// exports. The export maps each file on its own, so the file is exported alone: the
/// built-in files' export is the same on every run and is not repeated.
pub fn vector_loader(data: &[u8]) {
    use crate::vectors::{export::export_json, render, verify_vector, VectorFile, VectorSet};
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    hex_text(text);
    thread_local! {
        // The built-in set, and whether a run that panicked left a file swapped in.
        static BUILTIN: std::cell::RefCell<(VectorSet, bool)> = std::cell::RefCell::new((
            VectorSet::builtin().expect("the built-in vectors must load"),
            false,
        ));
    }
    BUILTIN.with_borrow_mut(|(set, dirty)| {
        if *dirty {
            *set = VectorSet::builtin().expect("the built-in vectors must load");
        }
        let Ok(file) = VectorFile::from_json("fuzz.json", text, &set.flags) else {
            return;
        };
        *dirty = true;
        let slot = set.files.iter().position(|f| f.document == file.document);
        let (i, displaced) = match slot {
            Some(i) => (i, Some(std::mem::replace(&mut set.files[i], file))),
            None => {
                set.files.push(file);
                (set.files.len() - 1, None)
            }
        };
        for v in &set.files[i].vectors {
            let _ = verify_vector(set, v);
            let _ = render(v);
        }
        let file = match displaced {
            Some(d) => std::mem::replace(&mut set.files[i], d),
            None => set.files.pop().expect("the file pushed above"),
        };
        let builtin_files = std::mem::replace(&mut set.files, vec![file]);
        let _ = export_json(set);
        set.files = builtin_files;
        *dirty = false;
    });
}

/// The hex reader for text typed by a person (vector files, the command line), on any
/// text: never panics; what it reads, printed canonically, reads back the same; an error
/// names a character or token that is where its column says.
fn hex_text(text: &str) {
    use crate::codec::hex::{parse_hex, Hex, HexError};
    match parse_hex(text) {
        Ok(bytes) => assert_eq!(
            parse_hex(&Hex(&bytes).to_string()).as_deref(),
            Ok(&bytes[..]),
            "hex printed canonically reads back"
        ),
        Err(HexError::BadChar { found, column }) => assert!(
            text.get(column - 1..).is_some_and(|t| t.starts_with(found)),
            "a bad character where its column says"
        ),
        Err(HexError::OddDigits { token, column }) => {
            assert!(token.len() % 2 == 1);
            assert!(
                text.get(column - 1..)
                    .is_some_and(|t| t.starts_with(&token)),
                "an odd token where its column says"
            );
        }
    }
}

/// An owned message, for generators (proptest, `arbitrary`) that cannot build the codec's
/// borrowed [`Message`](crate::codec::Message) directly.
#[derive(Debug, Clone, PartialEq, Eq, arbitrary::Arbitrary)]
pub enum OwnedPdu {
    /// 03H request.
    ReadRequest(u16, u16),
    /// 03H response.
    ReadResponse(Vec<u16>),
    /// 06H request or response.
    WriteSingle(u16, u16),
    /// 08H loop-back: test code and data.
    LoopBack(u16, Vec<u8>),
    /// 10H request.
    WriteMultipleRequest(u16, Vec<u16>),
    /// 10H response.
    WriteMultipleResponse(u16, u16),
    /// Exception: function (without 80H) and code.
    Exception(u8, u8),
    /// Unmodelled function and data.
    Other(u8, Vec<u8>),
}

/// An owned message: address and PDU, plus the wire bytes its borrowed form points into.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OwnedMessage {
    /// Node address.
    pub address: u8,
    /// The PDU.
    pub pdu: OwnedPdu,
    bytes: Vec<u8>,
}

impl OwnedMessage {
    /// Makes `pdu` fit `direction` and one frame: lengths are cut to what a 256-byte frame
    /// holds, an exception's function loses its 80H bit, an unmodelled function code that
    /// the direction would read as a modelled layout or an exception becomes 41H. Returns
    /// `None` for a layout that does not exist in `direction`.
    pub fn new(address: u8, pdu: OwnedPdu, direction: Direction) -> Option<OwnedMessage> {
        let pdu = match (direction, pdu) {
            (Direction::Request, OwnedPdu::ReadRequest(s, c)) => OwnedPdu::ReadRequest(s, c),
            (Direction::Response, OwnedPdu::ReadResponse(mut v)) => {
                v.truncate(125);
                OwnedPdu::ReadResponse(v)
            }
            (_, OwnedPdu::WriteSingle(r, v)) => OwnedPdu::WriteSingle(r, v),
            (_, OwnedPdu::LoopBack(t, mut d)) => {
                d.truncate(250);
                OwnedPdu::LoopBack(t, d)
            }
            (Direction::Request, OwnedPdu::WriteMultipleRequest(s, mut v)) => {
                v.truncate(123);
                OwnedPdu::WriteMultipleRequest(s, v)
            }
            (Direction::Response, OwnedPdu::WriteMultipleResponse(s, c)) => {
                OwnedPdu::WriteMultipleResponse(s, c)
            }
            (Direction::Response, OwnedPdu::Exception(f, c)) => OwnedPdu::Exception(f & 0x7F, c),
            (_, OwnedPdu::Other(f, mut d)) => {
                d.truncate(252);
                let modelled = [0x03, 0x06, 0x08, 0x10].contains(&f)
                    || (direction == Direction::Response && f & 0x80 != 0);
                OwnedPdu::Other(if modelled { 0x41 } else { f }, d)
            }
            _ => return None,
        };
        let bytes = match &pdu {
            OwnedPdu::ReadResponse(v) | OwnedPdu::WriteMultipleRequest(_, v) => {
                v.iter().flat_map(|x| x.to_be_bytes()).collect()
            }
            OwnedPdu::LoopBack(_, d) | OwnedPdu::Other(_, d) => d.clone(),
            _ => Vec::new(),
        };
        Some(OwnedMessage {
            address,
            pdu,
            bytes,
        })
    }

    /// The codec's borrowed message.
    pub fn message(&self) -> crate::codec::Message<'_> {
        use crate::codec::{Pdu, Registers};
        // `bytes` holds whole registers for the register variants (built in `new`).
        let regs = || Registers::new(&self.bytes).unwrap_or_else(|_| unreachable!());
        let pdu = match self.pdu {
            OwnedPdu::ReadRequest(start, count) => Pdu::ReadRequest { start, count },
            OwnedPdu::ReadResponse(_) => Pdu::ReadResponse { values: regs() },
            OwnedPdu::WriteSingle(register, value) => Pdu::WriteSingle { register, value },
            OwnedPdu::LoopBack(test_code, _) => Pdu::LoopBack {
                test_code,
                data: &self.bytes,
            },
            OwnedPdu::WriteMultipleRequest(start, _) => Pdu::WriteMultipleRequest {
                start,
                values: regs(),
            },
            OwnedPdu::WriteMultipleResponse(start, count) => {
                Pdu::WriteMultipleResponse { start, count }
            }
            OwnedPdu::Exception(function, code) => Pdu::Exception { function, code },
            OwnedPdu::Other(function, _) => Pdu::Other {
                function,
                data: &self.bytes,
            },
        };
        crate::codec::Message {
            address: self.address,
            pdu,
        }
    }
}

/// Round trip in both modes: emit, parse back, require equality; the ASCII and RTU forms
/// decode to the same message and convert into each other.
pub fn roundtrip(m: &OwnedMessage, direction: Direction) {
    let msg = m.message();
    with_scratch(|s| {
        let Scratch {
            rtu,
            rtu2,
            rtu3,
            ascii,
            ascii2,
        } = s;
        let nr = msg
            .emit_rtu(rtu)
            .expect("an OwnedMessage always fits a frame");
        let na = msg.emit_ascii(ascii).expect("and an ASCII frame");
        let (rtu, ascii) = (&rtu[..nr], &ascii[..na]);
        assert_eq!(decode_rtu(rtu, direction).expect("RTU parses back"), msg);
        assert_eq!(
            decode_ascii(ascii, direction, rtu2).expect("ASCII parses back"),
            msg
        );
        let n = rtu_to_ascii(rtu, ascii2).expect("RTU converts");
        assert_eq!(&ascii2[..n], ascii);
        let k = ascii_to_rtu(ascii, rtu3).expect("ASCII converts");
        assert_eq!(&rtu3[..k], rtu);
    });
}

/// [`roundtrip`] on a message built from raw fuzz bytes with `arbitrary` (as libFuzzer's
/// structured targets do), so crash inputs replay as plain bytes.
pub fn roundtrip_bytes(data: &[u8]) {
    use arbitrary::Arbitrary;
    let u = arbitrary::Unstructured::new(data);
    let Ok((address, response, pdu)) = <(u8, bool, OwnedPdu)>::arbitrary_take_rest(u) else {
        return;
    };
    let direction = if response {
        Direction::Response
    } else {
        Direction::Request
    };
    too_long_is_refused(address, &pdu);
    if let Some(m) = OwnedMessage::new(address, pdu, direction) {
        roundtrip(&m, direction);
    }
}

/// A message longer than a frame (before [`OwnedMessage::new`] cuts it) is refused by every
/// emitter with `TooLongToEncode`, never cut or wrapped.
fn too_long_is_refused(address: u8, pdu: &OwnedPdu) {
    use crate::codec::pdu::{Pdu, Registers};
    use crate::codec::FrameError;
    let too_long =
        |r: Result<usize, FrameError>| matches!(r, Err(FrameError::TooLongToEncode { .. }));
    let registers: Vec<u8>;
    let p = match pdu {
        OwnedPdu::LoopBack(_, d) | OwnedPdu::Other(_, d) if d.len() > 252 => Pdu::Other {
            function: 0x41,
            data: d,
        },
        OwnedPdu::ReadResponse(v) | OwnedPdu::WriteMultipleRequest(_, v) if v.len() > 127 => {
            registers = v.iter().flat_map(|x| x.to_be_bytes()).collect();
            let values = Registers::new(&registers).expect("whole registers");
            if matches!(pdu, OwnedPdu::ReadResponse(_)) {
                Pdu::ReadResponse { values }
            } else {
                Pdu::WriteMultipleRequest { start: 0, values }
            }
        }
        _ => return,
    };
    let m = Message { address, pdu: p };
    let mut out = vec![0u8; 2 * MAX_ASCII_FRAME];
    assert!(
        too_long(m.emit_rtu(&mut out)),
        "RTU emits a message over a frame"
    );
    assert!(
        too_long(m.emit_ascii(&mut out)),
        "ASCII emits a message over a frame"
    );
    assert!(too_long(m.emit_body(&mut out)), "a body over a frame");
    if !matches!(m.pdu, Pdu::Other { .. }) {
        // A byte count over 255 cannot be written.
        // A buffer that holds the data: a register list can be longer than any frame buffer.
        let mut data = vec![0u8; m.pdu.data_len()];
        assert!(
            too_long(m.pdu.emit_data(&mut data)),
            "data over a byte count"
        );
    }
}

/// An oracle: checks the laws on one input, panicking when one breaks.
pub type Oracle = fn(&[u8]);

/// The simulated drive of every model, in both modes, on arbitrary bytes taken as one
/// request frame (the first byte picks the model and the mode): never panics; does what
/// the model's judgement says (a reply exactly when the judgement expects one, none for
/// silence); every transmission is a valid frame of the mode, from the drive's node (or
/// from 00H only for a broadcast, which is never answered).
pub fn drive(data: &[u8]) {
    use std::sync::{Arc, OnceLock};
    static MODELS: OnceLock<Vec<Arc<crate::model::DriveModel>>> = OnceLock::new();
    let models = MODELS.get_or_init(|| {
        crate::model::MODELS
            .iter()
            .map(|m| Arc::new(crate::model::DriveModel::builtin(m).expect("built-in model")))
            .collect()
    });
    let Some((&sel, frame)) = data.split_first() else {
        return;
    };
    let model = &models[usize::from(sel & 0x7F) % models.len()];
    let mode = if sel & 0x80 == 0 {
        crate::codec::Mode::Rtu
    } else {
        crate::codec::Mode::Ascii
    };
    let mut d = crate::sim::Drive::new(model.clone(), 1, std::time::Duration::ZERO);
    let out = d.handle(mode, frame, std::time::Instant::now());
    assert_eq!(out.judgement, model.judge(1, mode, frame));
    assert_eq!(out.sends.len(), usize::from(out.judgement.expect.replies()));
    let mut scratch = [0u8; MAX_RTU_FRAME];
    for s in &out.sends {
        let reply = crate::codec::decode(mode, &s.bytes, Direction::Response, &mut scratch)
            .expect("the drive's reply is a valid frame");
        assert_eq!(reply.address, 1, "the reply comes from the drive's node");
    }
}

/// The MBAP codec on a stream of bytes (what a Modbus TCP gateway sends): frame after
/// frame as [`mbap::frame_status`] finds them, until the stream ends or breaks. For each:
/// a whole frame is 8..=260 bytes, its checked view and representation agree with the
/// header's bytes, and emitting the representation gives the same bytes back; a partial
/// frame never asks for more than the longest frame; an error is a header that a checked
/// view refuses too; nothing panics.
pub fn mbap_frame(data: &[u8]) {
    use crate::codec::mbap::{self, MbapFrame, MbapRepr, Status};
    let mut rest = data;
    let mut out = [0u8; mbap::MAX_ADU];
    loop {
        match mbap::frame_status(rest) {
            Ok(Status::Complete(n)) => {
                assert!((mbap::HEADER_LEN + 1..=mbap::MAX_ADU).contains(&n), "{n}");
                assert!(n <= rest.len());
                let view = MbapFrame::new_checked(&rest[..n]).expect("a whole frame's view");
                let repr = MbapRepr::parse(&view).expect("a whole frame parses");
                assert_eq!(view.protocol(), 0);
                assert_eq!(usize::from(view.length()), n - 6);
                assert_eq!(repr.pdu.len(), n - mbap::HEADER_LEN);
                assert_eq!(
                    (repr.transaction, repr.unit),
                    (view.transaction(), view.unit())
                );
                assert_eq!(repr.buffer_len(), n);
                let m = repr.emit(&mut out).expect("a parsed frame emits");
                assert_eq!(&out[..m], &rest[..n], "emit gives the bytes back");
                if let Some(code) = repr.gateway_exception() {
                    assert!(repr.pdu.len() == 2 && repr.pdu[0] & 0x80 != 0 && repr.pdu[1] == code);
                }
                let _ = (view.to_string(), repr.to_string());
                // A stream of exactly one frame is a checked frame; with more, it is not.
                assert_eq!(MbapFrame::new_checked(rest).is_ok(), n == rest.len());
                rest = &rest[n..];
            }
            Ok(Status::Partial(k)) => {
                assert!(
                    k >= 1 && rest.len() + k <= mbap::MAX_ADU,
                    "{} + {k}",
                    rest.len()
                );
                assert!(MbapFrame::new_checked(rest).is_err());
                return;
            }
            Err(e) => {
                assert!(MbapFrame::new_checked(rest).is_err(), "{e}");
                let _ = e.to_string();
                return;
            }
        }
    }
}

/// `model lint` on arbitrary text: it never panics; the same text gives the same
/// findings; every finding's line and column lie inside the text; and a text lint finds no
/// error in loads (lint is the stricter: it also refuses what the loader lets through, such
/// as a limit beyond the Modbus specification).
pub fn model_lint(data: &[u8]) {
    use crate::model::{lint, DriveModel};
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let findings = lint::lint("fuzz.json", text);
    assert_eq!(
        findings,
        lint::lint("fuzz.json", text),
        "lint is not deterministic"
    );
    let lines = text.split('\n').count();
    for f in &findings {
        assert!(
            (1..=lines).contains(&f.line) && f.column >= 1,
            "{f} lies outside the text ({lines} lines)"
        );
    }
    if !lint::has_errors(&findings) {
        if let Err(e) = DriveModel::from_json_unlinted("fuzz.json", text) {
            panic!("lint found no error, the loader refuses it: {e}");
        }
    }
}

/// The capture reader (pcap and pcapng) on arbitrary bytes: it never panics; every
/// packet is a slice of the input; the first error ends the packets and names an offset
/// inside the file; and the packets read, written again by the pcapng writer, read back
/// the same (bytes, interfaces, link types, flags, comments, times to the microsecond).
pub fn capture_reader(data: &[u8]) {
    use crate::capture::{read::ReadError, Interface, PacketMeta, PcapngWriter, Reader};
    let Ok(reader) = Reader::new(data) else {
        return;
    };
    let mut packets = Vec::new();
    let mut failed = false;
    for item in reader {
        assert!(!failed, "a packet after an error");
        match item {
            Ok(p) => {
                let start = p.data.as_ptr() as usize;
                let base = data.as_ptr() as usize;
                assert!(start >= base && start + p.data.len() <= base + data.len());
                // The writer takes packets under 16 MiB.
                if p.data.len() < 0x00FF_0000 {
                    packets.push(p);
                }
            }
            Err(e) => {
                let offset = match &e {
                    ReadError::NotACapture { .. } => 0,
                    ReadError::Truncated { offset, .. }
                    | ReadError::BadLength { offset, .. }
                    | ReadError::LengthMismatch { offset, .. }
                    | ReadError::BadByteOrder { offset, .. }
                    | ReadError::Version { offset, .. }
                    | ReadError::UnknownInterface { offset, .. }
                    | ReadError::PacketTooLong { offset, .. }
                    | ReadError::BadOption { offset, .. } => *offset,
                };
                assert!(offset < data.len() as u64 || data.is_empty(), "{e}");
                failed = true;
            }
        }
    }
    let mut w = PcapngWriter::new(Vec::new(), "oracle").expect("a Vec takes every write");
    let mut links: Vec<(u32, u16)> = Vec::new();
    for p in &packets {
        if !links.contains(&(p.interface, p.link_type)) {
            links.push((p.interface, p.link_type));
            w.add_interface(&Interface {
                link_type: p.link_type,
                name: String::new(),
                description: String::new(),
            })
            .expect("an interface");
        }
    }
    for p in &packets {
        let interface = links
            .iter()
            .position(|l| *l == (p.interface, p.link_type))
            .expect("described above") as u32;
        let meta = PacketMeta {
            interface,
            timestamp_us: p.timestamp_ns.unwrap_or(0) / 1000,
            flags: p.flags.unwrap_or(0),
            comment: p.comment.map(str::to_string),
        };
        w.write_packet(&meta, p.data)
            .expect("a packet read is a packet written");
    }
    let again = w.into_inner();
    let back: Vec<_> = Reader::new(&again)
        .expect("the writer's header")
        .collect::<Result<_, _>>()
        .expect("the writer's file reads back");
    assert_eq!(back.len(), packets.len());
    for (a, b) in packets.iter().zip(&back) {
        assert_eq!(a.data, b.data);
        assert_eq!(a.link_type, b.link_type);
        assert_eq!(a.flags.filter(|f| *f != 0), b.flags);
        assert_eq!(a.comment, b.comment);
        assert_eq!(
            b.timestamp_ns,
            Some(a.timestamp_ns.unwrap_or(0) / 1000 * 1000)
        );
    }
}

/// The fuzz targets by name, each with its oracle: the one list the fuzz crate, the seed
/// corpus writer and the regression replay share.
pub const TARGETS: [(&str, Oracle); 18] = [
    ("rtu_frame", rtu_frame),
    ("ascii_frame", ascii_frame),
    ("rtu_deframer", rtu_deframer),
    ("ascii_deframer", ascii_deframer),
    ("vector_loader", vector_loader),
    ("roundtrip", roundtrip_bytes),
    ("crc_differential", crc_differential),
    ("drive", drive),
    ("mbap_frame", mbap_frame),
    ("capture_reader", capture_reader),
    ("model_lint", model_lint),
    // Issue 37: the listener, the adapter protocols and the hand-written files; their
    // laws sit next to the code they check.
    ("monitor_stream", crate::monitor::fuzzing::monitor_stream),
    ("tap_framer", crate::monitor::fuzzing::tap_framer),
    ("line_search", crate::monitor::fuzzing::line_search),
    ("adapter_protocol", crate::gate::fuzzing::adapter_protocol),
    (
        "expectations_file",
        crate::expect::fuzzing::expectations_file,
    ),
    (
        "requirements_file",
        crate::requirements::fuzzing::requirements_file,
    ),
    ("model_file", crate::model::fuzzing::model_file),
];

#[cfg(test)]
mod tests {
    use super::*;

    /// The byte-wise reference is the manuals' bit loop: for every register value and
    /// every byte, one table step equals eight bit steps.
    #[test]
    fn reference_table_is_the_manual_loop() {
        for crc in 0..=u16::MAX {
            for b in 0..=255u8 {
                let mut bitwise = crc ^ u16::from(b);
                for _ in 0..8 {
                    bitwise = if bitwise & 1 != 0 {
                        (bitwise >> 1) ^ 0xA001
                    } else {
                        bitwise >> 1
                    };
                }
                let table = (crc >> 8) ^ REFERENCE_TABLE[usize::from((crc ^ u16::from(b)) as u8)];
                assert_eq!(table, bitwise, "register {crc:04X}, byte {b:02X}");
            }
        }
        assert_eq!(crc16_bytewise(b"123456789"), crc16_reference(b"123456789"));
    }

    #[test]
    fn messages_over_a_frame_are_refused() {
        too_long_is_refused(1, &OwnedPdu::Other(0x41, vec![0; 253]));
        too_long_is_refused(1, &OwnedPdu::LoopBack(0, vec![0; 300]));
        too_long_is_refused(1, &OwnedPdu::ReadResponse(vec![0; 128]));
        too_long_is_refused(1, &OwnedPdu::WriteMultipleRequest(0, vec![0; 200]));
    }

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
