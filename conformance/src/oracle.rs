//! Laws of the codec as functions of arbitrary bytes, shared by the fuzz targets (`fuzz/`)
//! and by the tests that replay their crash and regression inputs under plain
//! `cargo test`.
//!
//! Each function **panics when the codec breaks a law**: that is its purpose, as a test
//! oracle. Nothing in the codec calls these.

use crate::codec::crc::{crc16, crc16_reference, crc16_update, crc16_update_with, CrcPath};
use crate::codec::timing::{LineSettings, Parity};
use crate::codec::{
    ascii_to_rtu, decode_ascii, decode_ascii_unchecked, decode_rtu, decode_rtu_unchecked,
    rtu_to_ascii, AsciiDeframer, Direction, Event, RtuDeframer, RtuFraming, MAX_ASCII_FRAME,
    MAX_RTU_FRAME,
};

const DIRECTIONS: [Direction; 2] = [Direction::Request, Direction::Response];

/// RTU frame parser, both directions: never panics; a frame that decodes re-encodes to
/// exactly its bytes; the unchecked path agrees with the checked one; a frame that decodes
/// converts to ASCII and back unchanged.
pub fn rtu_frame(data: &[u8]) {
    for dir in DIRECTIONS {
        let checked = decode_rtu(data, dir);
        let unchecked = decode_rtu_unchecked(data, dir);
        if let Ok(m) = &checked {
            let again = m.to_rtu_vec().expect("a decoded message re-encodes");
            assert_eq!(again, data, "emit(parse(x)) != x");
            let u = unchecked
                .as_ref()
                .expect("unchecked accepts what checked accepts");
            assert!(u.checksum.is_valid());
            assert_eq!(&u.message, m);
            let mut a = [0u8; MAX_ASCII_FRAME];
            let n = rtu_to_ascii(data, &mut a).expect("a valid frame converts");
            let mut r = [0u8; MAX_RTU_FRAME];
            let k = ascii_to_rtu(&a[..n], &mut r).expect("and converts back");
            assert_eq!(&r[..k], data);
        }
        if let Ok(u) = &unchecked {
            assert_eq!(checked.is_ok(), u.checksum.is_valid());
        }
    }
}

/// ASCII frame parser, both directions: never panics; a frame that decodes re-encodes to
/// its characters (upper-cased); conversion to RTU and back is the identity up to case.
pub fn ascii_frame(data: &[u8]) {
    for dir in DIRECTIONS {
        let mut s1 = [0u8; MAX_RTU_FRAME];
        let mut s2 = [0u8; MAX_RTU_FRAME];
        let checked = decode_ascii(data, dir, &mut s1);
        let unchecked = decode_ascii_unchecked(data, dir, &mut s2);
        if let Ok(m) = &checked {
            let again = m.to_ascii_vec().expect("a decoded message re-encodes");
            assert_eq!(again, data.to_ascii_uppercase(), "emit(parse(x)) != x");
            let u = unchecked
                .as_ref()
                .expect("unchecked accepts what checked accepts");
            assert_eq!(&u.message, m);
            let mut r = [0u8; MAX_RTU_FRAME];
            let k = ascii_to_rtu(data, &mut r).expect("a valid frame converts");
            let mut a = [0u8; MAX_ASCII_FRAME];
            let n = rtu_to_ascii(&r[..k], &mut a).expect("and converts back");
            assert_eq!(&a[..n], &data.to_ascii_uppercase()[..]);
        }
        if let Ok(u) = &unchecked {
            assert_eq!(checked.is_ok(), u.checksum.is_valid());
        }
    }
    let slow = crate::codec::AsciiFrame::new_checked(data).and_then(|f| f.verify_lrc());
    assert_eq!(
        crate::codec::ascii::is_valid_frame(data),
        slow.is_ok(),
        "the deframer's fast check disagrees with the parser"
    );
}

/// Splits fuzz input into a control byte and the stream; the control byte chooses the
/// chunk size (1..=64) so the fuzzer explores chunkings too.
fn control(data: &[u8]) -> (usize, &[u8]) {
    match data.split_first() {
        Some((c, rest)) => (usize::from(c % 64) + 1, rest),
        None => (1, data),
    }
}

fn check_events(events: &mut Vec<(bool, usize)>, mode_rtu: bool) -> impl FnMut(Event<'_>) + '_ {
    move |e| {
        if let Event::Frame(f) = e {
            if mode_rtu {
                assert!(f.len() >= 4 && f.len() <= MAX_RTU_FRAME);
                assert_eq!(crc16(f), 0, "a frame event with a bad CRC");
            } else {
                let ok = decode_ascii_unchecked(f, Direction::Request, &mut [0u8; MAX_RTU_FRAME])
                    .map(|u| u.checksum.is_valid())
                    .or_else(|_| {
                        decode_ascii_unchecked(f, Direction::Response, &mut [0u8; MAX_RTU_FRAME])
                            .map(|u| u.checksum.is_valid())
                    })
                    .unwrap_or_else(|_| {
                        crate::codec::AsciiFrame::new_checked(f)
                            .map(|v| v.verify_lrc().is_ok())
                            .unwrap_or(false)
                    });
                assert!(ok, "a frame event with a bad LRC");
            }
        }
        assert!(
            e.bytes().len() <= MAX_ASCII_FRAME,
            "an event larger than any frame"
        );
        events.push((matches!(e, Event::Frame(_)), e.bytes().len()));
    }
}

/// RTU stream deframer, by length in both directions and by silence: never panics; every
/// frame event has a valid CRC; every byte is reported exactly once; the events do not
/// depend on the chunking.
pub fn rtu_deframer(data: &[u8]) {
    let (chunk, stream) = control(data);
    for dir in DIRECTIONS {
        let mut whole = Vec::new();
        let mut d = RtuDeframer::new(dir, RtuFraming::ByLength);
        d.push(stream, check_events(&mut whole, true));
        d.flush(check_events(&mut whole, true));
        let mut parts = Vec::new();
        let mut d = RtuDeframer::new(dir, RtuFraming::ByLength);
        for c in stream.chunks(chunk) {
            d.push(c, check_events(&mut parts, true));
        }
        d.flush(check_events(&mut parts, true));
        let total: usize = whole.iter().map(|e| e.1).sum();
        assert_eq!(total, stream.len(), "bytes lost or duplicated");
        let frames = |v: &Vec<(bool, usize)>| v.iter().filter(|e| e.0).count();
        assert_eq!(
            frames(&whole),
            frames(&parts),
            "chunking changed the frames"
        );
    }
    // By length with bursts: each chunk is a burst that ends on a quiet link (as the
    // simulator on a pty sees it); every byte still comes out once, frames with valid CRCs.
    for dir in DIRECTIONS {
        let mut bursts = Vec::new();
        let mut d = RtuDeframer::new(dir, RtuFraming::ByLength);
        for c in stream.chunks(chunk) {
            d.push(c, check_events(&mut bursts, true));
            d.end_burst(check_events(&mut bursts, true));
        }
        let total: usize = bursts.iter().map(|e| e.1).sum();
        assert_eq!(total, stream.len(), "bytes lost or duplicated (bursts)");
    }
    // By silence: each chunk arrives 1 ms after the previous one (9600 8E1: t1.5 = 1.7 ms,
    // t3.5 = 4 ms), with a 10 ms pause after every fourth.
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let mut d = RtuDeframer::new(Direction::Request, RtuFraming::BySilence(line));
    let mut events = Vec::new();
    let mut now = 0u64;
    for (i, c) in stream.chunks(chunk).enumerate() {
        now += if i % 4 == 3 { 10_000 } else { 1_000 };
        d.push_at(now, c, check_events(&mut events, true));
    }
    d.idle(now + 100_000, check_events(&mut events, true));
    let total: usize = events.iter().map(|e| e.1).sum();
    assert_eq!(total, stream.len(), "bytes lost or duplicated (by silence)");
}

/// ASCII stream deframer: never panics; every frame event has a valid LRC; every byte is
/// reported exactly once; the events do not depend on the chunking.
pub fn ascii_deframer(data: &[u8]) {
    let (chunk, stream) = control(data);
    let mut whole = Vec::new();
    let mut d = AsciiDeframer::default();
    d.push(stream, check_events(&mut whole, false));
    d.flush(check_events(&mut whole, false));
    let mut parts = Vec::new();
    let mut d = AsciiDeframer::default();
    for (i, c) in stream.chunks(chunk).enumerate() {
        d.push_at(i as u64 * 1_000, c, check_events(&mut parts, false));
    }
    d.flush(check_events(&mut parts, false));
    let total: usize = whole.iter().map(|e| e.1).sum();
    assert_eq!(total, stream.len(), "bytes lost or duplicated");
    let frames = |v: &Vec<(bool, usize)>| v.iter().filter(|e| e.0).count();
    assert_eq!(
        frames(&whole),
        frames(&parts),
        "chunking changed the frames"
    );
}

/// CRC differential: the fast CRC, and every path this CPU can run forced (table,
/// PCLMULQDQ, AVX-512), equals the manuals' reference, whole and in pieces. The first two
/// bytes choose the split; the input is also taken at every offset 0..64 of itself, so
/// each SIMD path sees every alignment.
pub fn crc_differential(data: &[u8]) {
    let reference = crc16_reference(data);
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
                Some(crc16_reference(tail)),
                "{name} at offset {offset}"
            );
        }
    }
}

/// Vector-file loader: never panics on any text; a file that loads verifies without
/// panicking and exports.
pub fn vector_loader(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    static BUILTIN: std::sync::OnceLock<crate::vectors::VectorSet> = std::sync::OnceLock::new();
    let builtin = BUILTIN.get_or_init(|| {
        crate::vectors::VectorSet::builtin().expect("the built-in vectors must load")
    });
    if let Ok(file) = crate::vectors::VectorFile::from_json("fuzz.json", text, &builtin.flags) {
        let mut set = builtin.clone();
        set.files.retain(|f| f.document != file.document);
        set.files.push(file.clone());
        for v in &file.vectors {
            let _ = crate::vectors::verify_vector(&set, v);
            let _ = crate::vectors::render(v);
        }
        let _ = crate::vectors::export::export_json(&set);
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
    let rtu = msg
        .to_rtu_vec()
        .expect("an OwnedMessage always fits a frame");
    let ascii = msg.to_ascii_vec().expect("and an ASCII frame");
    assert_eq!(decode_rtu(&rtu, direction).expect("RTU parses back"), msg);
    let mut s = [0u8; MAX_RTU_FRAME];
    assert_eq!(
        decode_ascii(&ascii, direction, &mut s).expect("ASCII parses back"),
        msg
    );
    let mut a = [0u8; MAX_ASCII_FRAME];
    let n = rtu_to_ascii(&rtu, &mut a).expect("RTU converts");
    assert_eq!(&a[..n], &ascii[..]);
    let mut r = [0u8; MAX_RTU_FRAME];
    let k = ascii_to_rtu(&ascii, &mut r).expect("ASCII converts");
    assert_eq!(&r[..k], &rtu[..]);
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
    if let Some(m) = OwnedMessage::new(address, pdu, direction) {
        roundtrip(&m, direction);
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

/// The fuzz targets by name, each with its oracle: the one list the fuzz crate, the seed
/// corpus writer and the regression replay share.
pub const TARGETS: [(&str, Oracle); 8] = [
    ("rtu_frame", rtu_frame),
    ("ascii_frame", ascii_frame),
    ("rtu_deframer", rtu_deframer),
    ("ascii_deframer", ascii_deframer),
    ("vector_loader", vector_loader),
    ("roundtrip", roundtrip_bytes),
    ("crc_differential", crc_differential),
    ("drive", drive),
];
