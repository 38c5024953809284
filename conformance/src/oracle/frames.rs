//! The frame parsers' laws: RTU and ASCII frames in both directions, and the MBAP
//! codec on a stream.

use super::{with_scratch, Scratch, DIRECTIONS};
use crate::codec::{
    ascii_to_rtu, decode_ascii, decode_ascii_unchecked, decode_rtu, decode_rtu_unchecked,
    rtu_to_ascii, Direction, FrameError, Message, Mode, Unchecked, MAX_RTU_FRAME,
};

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

/// The checked and the unchecked decoder on one input, in either mode: where both decode,
/// the checksum (`sum`) is valid and the messages are the same; the unchecked one never
/// refuses what the checked one takes; where only the unchecked one decodes, the checksum
/// is wrong. The message, where both decode.
fn decoders_agree<'a, 'm>(
    checked: &'a Result<Message<'m>, FrameError>,
    unchecked: &Result<Unchecked<'_>, FrameError>,
    sum: &str,
) -> Option<&'a Message<'m>> {
    match (checked, unchecked) {
        (Ok(m), Ok(u)) => {
            assert!(u.checksum.is_valid(), "checked accepts a bad {sum}");
            assert_eq!(&u.message, m, "unchecked and checked decode differently");
            Some(m)
        }
        (Ok(_), Err(e)) => panic!("unchecked rejects what checked accepts: {e}"),
        (Err(_), Ok(u)) => {
            assert!(
                !u.checksum.is_valid(),
                "checked rejects a frame with a valid {sum} that unchecked decodes"
            );
            None
        }
        (Err(_), Err(_)) => None,
    }
}

/// RTU frame parser, both directions: never panics; a frame that decodes re-encodes to
/// exactly its bytes; the unchecked path agrees with the checked one; a frame that decodes
/// converts to ASCII and back unchanged.
pub fn rtu_frame(data: &[u8]) {
    let mut converted = false;
    for dir in DIRECTIONS {
        let checked = decode_rtu(data, dir);
        let unchecked = decode_rtu_unchecked(data, dir);
        if let Some(m) = decoders_agree(&checked, &unchecked, "CRC") {
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
                    let k = ascii_to_rtu(&s.ascii[..n], &mut s.rtu2).expect("and converts back");
                    assert_eq!(&s.rtu2[..k], data);
                }
            });
            converted = true;
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
            if let Some(m) = decoders_agree(&checked, &unchecked, "LRC") {
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
        });
    }
    assert_eq!(
        crate::codec::ascii::is_valid_frame(data),
        ascii_frame_valid(data),
        "the deframer's fast check disagrees with the parser"
    );
}

/// The parser's judgement of a whole ASCII frame: its view builds and its LRC checks.
pub(super) fn ascii_frame_valid(f: &[u8]) -> bool {
    crate::codec::AsciiFrame::new_checked(f)
        .and_then(|v| v.verify_lrc())
        .is_ok()
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
