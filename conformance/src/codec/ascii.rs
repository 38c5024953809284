//! ASCII framing: ':' then address, function, data and LRC as hex pairs, then CR LF.
//!
//! Emitting writes upper-case hex, as Modbus over Serial Line (2.5.2.1) requires. Parsing
//! **accepts lower-case hex too**: a master or slave that sends it is still understood,
//! and [`AsciiFrame::is_upper_case`] lets a conformance check report it as a deviation
//! rather than as an unreadable frame.

use super::error::FrameError;
use super::hex::{decode_nibble, encode_byte, nibble_or_ff};
use super::lrc::lrc;
use super::pdu::{Direction, Message};
use super::{Checksum, Unchecked, MAX_ASCII_FRAME, MAX_RTU_FRAME};

/// Smallest ASCII frame: ':' + 2 address + 2 function + 2 LRC characters + CR LF.
pub const MIN_ASCII_FRAME: usize = 9;

/// Start character.
pub const START: u8 = b':';
/// End characters.
pub const END: [u8; 2] = [b'\r', b'\n'];

/// Room for the binary content (address through LRC) of the longest ASCII frame.
pub type Scratch = [u8; MAX_RTU_FRAME];

/// A view over the characters of one ASCII frame. Construction checks the delimiters,
/// the length and that every character between them is a hex digit; the LRC is checked
/// by [`verify_lrc`](Self::verify_lrc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct AsciiFrame<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> AsciiFrame<T> {
    /// Wraps `buffer` after checking ':', CR LF, the length (9..=513) and the hex digits.
    pub fn new_checked(buffer: T) -> Result<Self, FrameError> {
        let b = buffer.as_ref();
        let len = b.len();
        if let Some(&first) = b.first() {
            if first != START {
                return Err(FrameError::AsciiNoStart { found: first });
            }
        }
        if len < MIN_ASCII_FRAME {
            return Err(FrameError::AsciiTooShort { len });
        }
        if len > MAX_ASCII_FRAME {
            return Err(FrameError::AsciiTooLong { len });
        }
        let tail = [b[len - 2], b[len - 1]];
        if tail != END {
            return Err(FrameError::AsciiNoEnd { found: tail });
        }
        let hex = &b[1..len - 2];
        if let Some(i) = hex.iter().position(|&c| decode_nibble(c).is_none()) {
            return Err(FrameError::AsciiBadChar {
                found: hex[i],
                offset: i + 1,
            });
        }
        if hex.len() % 2 != 0 {
            return Err(FrameError::AsciiOddLength { count: hex.len() });
        }
        Ok(AsciiFrame { buffer })
    }

    /// All characters of the frame.
    pub fn as_bytes(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    /// The hex characters between ':' and CR LF.
    fn hex(&self) -> &[u8] {
        let b = self.as_bytes();
        &b[1..b.len() - 2]
    }

    fn byte_at(&self, i: usize) -> u8 {
        let h = self.hex();
        // new_checked guarantees hex digits and an even count.
        decode_nibble(h[2 * i]).unwrap_or(0) << 4 | decode_nibble(h[2 * i + 1]).unwrap_or(0)
    }

    /// Number of binary bytes carried, LRC included.
    pub fn binary_len(&self) -> usize {
        self.hex().len() / 2
    }

    /// Node address.
    pub fn address(&self) -> u8 {
        self.byte_at(0)
    }

    /// Function byte.
    pub fn function(&self) -> u8 {
        self.byte_at(1)
    }

    /// The LRC the frame carries.
    pub fn carried_lrc(&self) -> u8 {
        self.byte_at(self.binary_len() - 1)
    }

    /// Whether every hex digit is upper case, as the serial-line specification requires.
    pub fn is_upper_case(&self) -> bool {
        !self.hex().iter().any(u8::is_ascii_lowercase)
    }

    /// Decodes the hex into `out` and returns the body (address, function, data), without
    /// the LRC.
    pub fn body_into<'b>(&self, out: &'b mut Scratch) -> &'b [u8] {
        let n = self.binary_len();
        for (i, slot) in out.iter_mut().enumerate().take(n) {
            *slot = self.byte_at(i);
        }
        &out[..n - 1]
    }

    /// The carried and computed LRC.
    pub fn checksum(&self) -> Checksum {
        let mut scratch = [0u8; MAX_RTU_FRAME];
        let body = self.body_into(&mut scratch);
        Checksum::Lrc {
            carried: self.carried_lrc(),
            computed: lrc(body),
        }
    }

    /// `Ok` when the carried LRC is right.
    pub fn verify_lrc(&self) -> Result<(), FrameError> {
        self.checksum().verify()
    }
}

/// Whether `frame` is a complete ASCII frame with a valid LRC: the same verdict as
/// `AsciiFrame::new_checked(frame).and_then(|f| f.verify_lrc()).is_ok()`, in one pass and
/// without a scratch buffer (the deframer's hot path).
pub fn is_valid_frame(frame: &[u8]) -> bool {
    let len = frame.len();
    if !(MIN_ASCII_FRAME..=MAX_ASCII_FRAME).contains(&len)
        || frame[0] != START
        || frame[len - 2..] != END
        || !(len - 3).is_multiple_of(2)
    {
        return false;
    }
    let mut sum = 0u8;
    for pair in frame[1..len - 2].chunks_exact(2) {
        match (decode_nibble(pair[0]), decode_nibble(pair[1])) {
            (Some(h), Some(l)) => sum = sum.wrapping_add(h << 4 | l),
            _ => return false,
        }
    }
    // The LRC makes the sum of all bytes, itself included, zero.
    sum == 0
}

/// Decodes an ASCII frame, checking delimiters, hex, LRC and every count field. The binary
/// bytes are written into `scratch`, which the returned message borrows.
#[inline(always)]
pub fn decode_ascii<'b>(
    frame: &[u8],
    direction: Direction,
    scratch: &'b mut Scratch,
) -> Result<Message<'b>, FrameError> {
    let u = decode_ascii_unchecked(frame, direction, scratch)?;
    u.checksum.verify()?;
    Ok(u.message)
}

/// Decodes an ASCII frame without rejecting a wrong LRC (see
/// [`decode_rtu_unchecked`](super::decode_rtu_unchecked)).
#[inline(always)]
pub fn decode_ascii_unchecked<'b>(
    frame: &[u8],
    direction: Direction,
    scratch: &'b mut Scratch,
) -> Result<Unchecked<'b>, FrameError> {
    if let Some((n, sum)) = decode_hex_fast(frame, scratch) {
        let scratch: &'b Scratch = scratch;
        let carried = scratch[n - 1];
        // The sum of all bytes, the LRC included, minus the LRC is the sum of the body.
        let computed = carried.wrapping_sub(sum);
        let message = Message::parse_body(&scratch[..n - 1], direction)?;
        return Ok(Unchecked {
            message,
            checksum: Checksum::Lrc { carried, computed },
        });
    }
    // A malformed frame: the checks one by one, for the error that says what is wrong.
    let view = AsciiFrame::new_checked(frame)?;
    let carried = view.carried_lrc();
    let body = view.body_into(scratch);
    let checksum = Checksum::Lrc {
        carried,
        computed: lrc(body),
    };
    let message = Message::parse_body(body, direction)?;
    Ok(Unchecked { message, checksum })
}

/// The common case in one pass: a well-formed frame's hex decoded into `scratch`.
/// Returns the number of bytes decoded (LRC included) and their 8-bit sum, or `None`
/// when the frame is malformed in any way [`AsciiFrame::new_checked`] rejects.
#[inline(always)]
fn decode_hex_fast(frame: &[u8], scratch: &mut Scratch) -> Option<(usize, u8)> {
    let len = frame.len();
    if !(MIN_ASCII_FRAME..=MAX_ASCII_FRAME).contains(&len)
        || frame[0] != START
        || frame[len - 2..] != END
        || !(len - 3).is_multiple_of(2)
    {
        return None;
    }
    let hex = &frame[1..len - 2];
    #[cfg(target_arch = "x86_64")]
    {
        super::hex_sse2::decode(hex, scratch)
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        decode_hex_swar(hex, scratch)
    }
}

/// [`decode_hex_fast`]'s hex step without SSE2: eight characters at a time in a 64-bit
/// word. Used on targets other than x86-64, and tested against the SSE2 path there.
#[cfg_attr(target_arch = "x86_64", allow(dead_code))]
#[inline(always)]
fn decode_hex_swar(hex: &[u8], scratch: &mut Scratch) -> Option<(usize, u8)> {
    let word_at = |at: usize| -> Option<u64> {
        let c: &[u8; 8] = hex.get(at..at + 8)?.try_into().ok()?;
        Some(u64::from_le_bytes(*c))
    };
    if hex.len() < 8 {
        // Only the shortest frame (address, function, LRC): pair by pair.
        let mut bad = 0u8;
        let mut sum = 0u8;
        for (slot, pair) in scratch.iter_mut().zip(hex.chunks_exact(2)) {
            let (h, l) = (nibble_or_ff(pair[0]), nibble_or_ff(pair[1]));
            bad |= h | l;
            let b = h << 4 | l;
            *slot = b;
            sum = sum.wrapping_add(b);
        }
        return (bad & 0xF0 == 0).then_some((hex.len() / 2, sum));
    }
    // Eight characters (four bytes) at a time; at most 510 characters, so `zip` never
    // runs out of scratch.
    let whole = hex.len() / 8;
    let mut sums = 0u64;
    for (i, out) in scratch.chunks_exact_mut(4).take(whole).enumerate() {
        let (bytes, lanes) = hex8(word_at(8 * i)?)?;
        out.copy_from_slice(&bytes.to_le_bytes());
        sums += lanes;
    }
    // The last 2, 4 or 6 characters: the last eight, overlapping pairs already decoded,
    // which are written again with the same values and left out of the sum.
    let rest = hex.len() % 8;
    if rest != 0 {
        let (bytes, lanes) = hex8(word_at(hex.len() - 8)?)?;
        let again = (8 - rest) / 2;
        let at = 4 * whole - again;
        scratch
            .get_mut(at..at + 4)?
            .copy_from_slice(&bytes.to_le_bytes());
        sums += lanes & (u64::MAX << (16 * again));
    }
    // Four 16-bit lanes, each at most 64 x 255: their total lands in the top lane without
    // a carry from below.
    let sum = (sums.wrapping_mul(0x0001_0001_0001_0001) >> 48) as u8;
    Some((hex.len() / 2, sum))
}

/// Eight hex characters (upper or lower case), read little-endian into `w`, as the four
/// bytes they spell (first pair in the low byte) and those bytes in the low halves of
/// four 16-bit lanes (for summing); `None` if any character is not a hex digit.
///
/// SWAR: with every byte below 80H, adding 80H - k to a byte sets its top bit exactly
/// when the byte is at least k, and no carry crosses bytes.
#[inline(always)]
fn hex8(w: u64) -> Option<(u32, u64)> {
    const ONES: u64 = 0x0101_0101_0101_0101;
    const TOPS: u64 = 0x8080_8080_8080_8080;
    const LOW_BYTES: u64 = 0x00FF_00FF_00FF_00FF;
    let at_least = |v: u64, k: u8| (v + u64::from(0x80 - k) * ONES) & TOPS;
    if w & TOPS != 0 {
        return None;
    }
    // Setting bit 5 turns 'A'..'F' into 'a'..'f' and leaves digits as they are; no other
    // byte becomes a letter a..f that way (only 41H..46H and 61H..66H end in 61H..66H).
    let folded = w | (0x20 * ONES);
    let digit = at_least(w, b'0') & !at_least(w, b'9' + 1);
    let letter = at_least(folded, b'a') & !at_least(folded, b'f' + 1);
    if digit | letter != TOPS {
        return None;
    }
    // A digit's value is its low nibble; a letter's (bit 6 set) is its low nibble + 9.
    let nibbles = (w & (0x0F * ONES)) + ((w >> 6) & ONES) * 9;
    // Each 16-bit lane holds one pair: high nibble in its low byte, low nibble above.
    let lanes = ((nibbles & LOW_BYTES) << 4) | ((nibbles >> 8) & LOW_BYTES);
    let packed = (lanes | (lanes >> 8)) & 0x0000_FFFF_0000_FFFF;
    let packed = (packed | (packed >> 16)) & 0xFFFF_FFFF;
    Some((packed as u32, lanes))
}

/// Writes ':' + hex of `body` + LRC + CR LF into `out`; returns the length.
fn emit_ascii_body(body: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    let n = ascii_len_of_body(body.len());
    if out.len() < n {
        return Err(FrameError::BufferTooSmall {
            needed: n,
            available: out.len(),
        });
    }
    out[0] = START;
    let mut at = 1;
    for &b in body.iter().chain(std::iter::once(&lrc(body))) {
        out[at..at + 2].copy_from_slice(&encode_byte(b));
        at += 2;
    }
    out[at..at + 2].copy_from_slice(&END);
    Ok(n)
}

fn ascii_len_of_body(body_len: usize) -> usize {
    1 + 2 * (body_len + 1) + 2
}

impl Message<'_> {
    /// Length of the ASCII frame of this message.
    pub fn ascii_len(&self) -> usize {
        ascii_len_of_body(self.body_len())
    }

    /// Writes the ASCII frame (upper-case hex, LRC computed) into `out`; returns its length.
    pub fn emit_ascii(&self, out: &mut [u8]) -> Result<usize, FrameError> {
        let mut body = [0u8; MAX_RTU_FRAME];
        let n = self.emit_body(&mut body)?;
        emit_ascii_body(&body[..n], out)
    }

    /// The ASCII frame as a new vector (a convenience for tests and the command line).
    pub fn to_ascii_vec(&self) -> Result<Vec<u8>, FrameError> {
        let mut buf = [0u8; MAX_ASCII_FRAME];
        let n = self.emit_ascii(&mut buf)?;
        Ok(buf[..n].to_vec())
    }
}

/// Converts a valid RTU frame to the ASCII frame of the same message (LRC computed).
/// The CRC is checked first: a corrupt frame is not converted.
pub fn rtu_to_ascii(rtu: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    let view = super::rtu::RtuFrame::new_checked(rtu)?;
    view.verify_crc()?;
    emit_ascii_body(view.body(), out)
}

/// Converts a valid ASCII frame to the RTU frame of the same message (CRC computed).
/// The LRC is checked first: a corrupt frame is not converted.
pub fn ascii_to_rtu(ascii: &[u8], out: &mut [u8]) -> Result<usize, FrameError> {
    let view = AsciiFrame::new_checked(ascii)?;
    view.verify_lrc()?;
    let mut scratch = [0u8; MAX_RTU_FRAME];
    let body = view.body_into(&mut scratch);
    let n = body.len() + 2;
    if out.len() < n {
        return Err(FrameError::BufferTooSmall {
            needed: n,
            available: out.len(),
        });
    }
    out[..body.len()].copy_from_slice(body);
    out[body.len()..n].copy_from_slice(&super::crc::CrcBytes::of(body).wire());
    Ok(n)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::pdu::Pdu;

    /// F510 manual 1.0.3, 03H, ASCII command message: ':' 01 03 0123 0001 LRC CR LF.
    const F510_READ_ASCII: &[u8] = b":010301230001D7\r\n";

    /// The hex step of the fast decode, byte by byte: the bytes and their sum, or None.
    fn hex_slow(hex: &[u8]) -> Option<(Vec<u8>, u8)> {
        let bytes: Option<Vec<u8>> = hex
            .chunks_exact(2)
            .map(|p| Some(decode_nibble(p[0])? << 4 | decode_nibble(p[1])?))
            .collect();
        let bytes = bytes?;
        let sum = bytes.iter().fold(0u8, |a, &b| a.wrapping_add(b));
        Some((bytes, sum))
    }

    /// Every even length 2..=64 and 510, every position given every kind of character
    /// (each byte value at the first, last and one middle position; a spread of values
    /// everywhere): the vector path (x86-64), the SWAR path and the byte-by-byte decode
    /// agree on the bytes, the sum and the rejection.
    #[test]
    fn hex_paths_agree() {
        let mut rng = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            rng ^= rng << 13;
            rng ^= rng >> 7;
            rng ^= rng << 17;
            rng
        };
        const HEX: &[u8] = b"0123456789ABCDEFabcdef";
        let mut lens: Vec<usize> = (2..=64).step_by(2).collect();
        lens.push(510);
        let mut checked = 0;
        for &n in &lens {
            for trial in 0..40 {
                let mut hex: Vec<u8> = (0..n)
                    .map(|_| HEX[(next() % HEX.len() as u64) as usize])
                    .collect();
                let spots = [0, n / 2, n - 1, (next() % n as u64) as usize];
                let values: Vec<u8> = if trial < 4 {
                    (0..=255).collect()
                } else {
                    vec![(next() & 0xFF) as u8]
                };
                for v in values {
                    let at = spots[trial % 4];
                    let keep = hex[at];
                    if trial > 0 {
                        hex[at] = v;
                    }
                    let want = hex_slow(&hex);
                    let mut s1 = [0u8; MAX_RTU_FRAME];
                    let swar =
                        decode_hex_swar(&hex, &mut s1).map(|(k, sum)| (s1[..k].to_vec(), sum));
                    assert_eq!(swar, want, "swar, hex {:?}", String::from_utf8_lossy(&hex));
                    #[cfg(target_arch = "x86_64")]
                    {
                        let mut s2 = [0u8; MAX_RTU_FRAME];
                        let sse = crate::codec::hex_sse2::decode(&hex, &mut s2)
                            .map(|(k, sum)| (s2[..k].to_vec(), sum));
                        assert_eq!(sse, want, "sse2, hex {:?}", String::from_utf8_lossy(&hex));
                    }
                    checked += 1;
                    hex[at] = keep;
                }
            }
        }
        assert!(checked > 30_000, "{checked}");
    }

    #[test]
    fn deconstruct() {
        let f = AsciiFrame::new_checked(F510_READ_ASCII).unwrap();
        assert_eq!(f.address(), 1);
        assert_eq!(f.function(), 3);
        assert_eq!(f.binary_len(), 7);
        assert_eq!(f.carried_lrc(), 0xD7);
        assert!(f.verify_lrc().is_ok());
        assert!(f.is_upper_case());
    }

    #[test]
    fn parse_and_emit() {
        let mut s = [0u8; MAX_RTU_FRAME];
        let m = decode_ascii(F510_READ_ASCII, Direction::Request, &mut s).unwrap();
        assert_eq!(
            m.pdu,
            Pdu::ReadRequest {
                start: 0x0123,
                count: 1
            }
        );
        assert_eq!(m.to_ascii_vec().unwrap(), F510_READ_ASCII);
    }

    #[test]
    fn lower_case_is_accepted_but_visible() {
        let f = b":0106250217704b\r\n".to_vec();
        let view = AsciiFrame::new_checked(&f[..]).unwrap();
        assert!(!view.is_upper_case());
        let mut s = [0u8; MAX_RTU_FRAME];
        let m = decode_ascii(&f, Direction::Request, &mut s).unwrap();
        assert_eq!(m.to_ascii_vec().unwrap(), b":0106250217704B\r\n");
    }

    #[test]
    fn wrong_lrc_is_rejected_and_explained() {
        let f = b":010301230001D8\r\n";
        let mut s = [0u8; MAX_RTU_FRAME];
        assert_eq!(
            decode_ascii(f, Direction::Request, &mut s).unwrap_err(),
            FrameError::LrcMismatch {
                carried: 0xD8,
                computed: 0xD7
            }
        );
        let mut s = [0u8; MAX_RTU_FRAME];
        let u = decode_ascii_unchecked(f, Direction::Request, &mut s).unwrap();
        assert!(!u.checksum.is_valid());
    }

    #[test]
    fn malformed_frames_say_what_is_wrong() {
        let mut s = [0u8; MAX_RTU_FRAME];
        let mut d = |f: &[u8]| decode_ascii(f, Direction::Request, &mut s).unwrap_err();
        assert_eq!(
            d(b"010301230001D8\r\n"),
            FrameError::AsciiNoStart { found: b'0' }
        );
        assert_eq!(d(b":0103\r\n"), FrameError::AsciiTooShort { len: 7 });
        assert_eq!(
            d(b":010301230001D7\n\r"),
            FrameError::AsciiNoEnd {
                found: [b'\n', b'\r']
            }
        );
        assert_eq!(
            d(b":0103012300G1D8\r\n"),
            FrameError::AsciiBadChar {
                found: b'G',
                offset: 11
            }
        );
        assert_eq!(
            d(b":010301230001D\r\n"),
            FrameError::AsciiOddLength { count: 13 }
        );
        assert_eq!(d(&[b':'; 600]), FrameError::AsciiTooLong { len: 600 });
        assert_eq!(d(b":"), FrameError::AsciiTooShort { len: 1 });
        assert_eq!(d(b""), FrameError::AsciiTooShort { len: 0 });
    }

    /// The one-pass decode agrees with the checks one by one: on every valid frame of
    /// 1..=40 bytes, and on each of them with any one character replaced by any byte.
    #[test]
    fn fast_hex_decode_agrees_with_the_checked_view() {
        let agree = |frame: &[u8]| {
            let mut fast = [0u8; MAX_RTU_FRAME];
            let got = decode_hex_fast(frame, &mut fast);
            match AsciiFrame::new_checked(frame) {
                Ok(view) => {
                    let (n, sum) = got.unwrap_or_else(|| panic!("rejected {frame:?}"));
                    let mut slow = [0u8; MAX_RTU_FRAME];
                    let body = view.body_into(&mut slow);
                    assert_eq!(n, view.binary_len());
                    assert_eq!(&fast[..n - 1], body, "{frame:?}");
                    assert_eq!(fast[n - 1], view.carried_lrc());
                    assert_eq!(sum, lrc(body).wrapping_neg().wrapping_add(fast[n - 1]));
                }
                Err(_) => assert_eq!(got, None, "accepted {frame:?}"),
            }
        };
        let mut state: u32 = 0x1234_5678;
        for n in 1..=40usize {
            let body: Vec<u8> = (0..n)
                .map(|_| {
                    state = state.wrapping_mul(1_664_525).wrapping_add(1_013_904_223);
                    (state >> 24) as u8
                })
                .collect();
            let mut frame = vec![START];
            for &b in body.iter().chain(std::iter::once(&lrc(&body))) {
                frame.extend_from_slice(&encode_byte(b));
            }
            frame.extend_from_slice(&END);
            agree(&frame);
            agree(&frame.to_ascii_lowercase());
            agree(&frame[..frame.len() - 1]);
            for at in 0..frame.len() {
                for c in 0..=255u8 {
                    let mut f = frame.clone();
                    f[at] = c;
                    agree(&f);
                }
            }
        }
    }

    #[test]
    fn conversions_both_ways() {
        let rtu = [0x01, 0x03, 0x01, 0x23, 0x00, 0x01, 0x74, 0x3C];
        let mut a = [0u8; MAX_ASCII_FRAME];
        let n = rtu_to_ascii(&rtu, &mut a).unwrap();
        assert_eq!(&a[..n], F510_READ_ASCII);
        let mut r = [0u8; MAX_RTU_FRAME];
        let n = ascii_to_rtu(F510_READ_ASCII, &mut r).unwrap();
        assert_eq!(&r[..n], rtu);
        // A corrupt frame is not converted.
        let mut bad = rtu;
        bad[7] ^= 1;
        assert!(matches!(
            rtu_to_ascii(&bad, &mut a),
            Err(FrameError::CrcMismatch { .. })
        ));
    }
}
