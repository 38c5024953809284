//! `monitor --mode auto`: RTU or ASCII, told from the traffic itself, without sending.
//!
//! ASCII frames are printable: `:`, an even number of hex digits, CR LF, and a valid LRC.
//! RTU frames are binary, their length follows from their header, and they carry a
//! CRC-16 that random bytes match once in 65536. The guess waits for [`FRAMES_NEEDED`]
//! valid frames of one kind (RTU: one right after the other, as a request and its reply
//! are heard), and gives up after [`GIVE_UP_AFTER`] bytes with neither. A line read with the wrong data bits shows ASCII frames only once
//! bit 7 is cleared (7E1 read as 8N1): that is said, with what to set.

use crate::codec::deframe::rtu_frame_len;
use crate::codec::pdu::Direction;
use crate::codec::{self, Mode};

/// Valid frames of one kind before the guess is made.
pub const FRAMES_NEEDED: usize = 2;

/// Bytes heard with no verdict before the guess gives up.
pub const GIVE_UP_AFTER: usize = 4096;

/// What the traffic so far says.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Guess {
    /// Not enough yet.
    Undecided,
    /// The mode, and how many valid frames of it were seen.
    Mode(Mode, usize),
    /// ASCII frames, but only with bit 7 of every byte cleared: the port reads 8 data
    /// bits of a 7-bit line (its parity bit lands in bit 7).
    AsciiSevenBits(usize),
    /// Neither after [`GIVE_UP_AFTER`] bytes: the first bytes heard.
    Neither(Vec<u8>),
}

/// Valid ASCII frames (`:` .. CR LF, hex, LRC) in `bytes`.
fn ascii_frames(bytes: &[u8]) -> usize {
    let mut n = 0;
    let mut rest = bytes;
    while let Some(start) = rest.iter().position(|&b| b == b':') {
        rest = &rest[start..];
        let Some(end) = rest.windows(2).position(|w| w == b"\r\n") else {
            break;
        };
        let frame = &rest[..end + 2];
        if codec::frame_parts(Mode::Ascii, frame).is_ok_and(|p| p.checksum.is_valid()) {
            n += 1;
        }
        rest = &rest[end + 2..];
    }
    n
}

/// The longest run of valid RTU frames one right after the other in `bytes` (a request
/// and its reply): each frame's length from its function and byte count (the length
/// rule), its CRC holding. By chance a CRC holds once in 65536; two frames in a row, with
/// the lengths their headers give, do not come out of noise.
fn rtu_frames(bytes: &[u8]) -> usize {
    let frame_at = |i: usize| -> Option<usize> {
        let head = &bytes[i..];
        [Direction::Request, Direction::Response]
            .into_iter()
            .filter_map(|d| rtu_frame_len(d, head))
            .find(|&n| {
                (4..=head.len()).contains(&n)
                    && codec::frame_parts(Mode::Rtu, &head[..n])
                        .is_ok_and(|p| p.checksum.is_valid())
            })
    };
    let mut best = 0;
    for start in 0..bytes.len() {
        let (mut i, mut run) = (start, 0);
        while let Some(n) = frame_at(i) {
            run += 1;
            i += n;
        }
        best = best.max(run);
        if best >= FRAMES_NEEDED {
            break;
        }
    }
    best
}

/// The guess from everything heard so far.
pub fn guess(heard: &[u8]) -> Guess {
    let ascii = ascii_frames(heard);
    if ascii >= FRAMES_NEEDED {
        return Guess::Mode(Mode::Ascii, ascii);
    }
    let rtu = rtu_frames(heard);
    if rtu >= FRAMES_NEEDED {
        return Guess::Mode(Mode::Rtu, rtu);
    }
    let masked: Vec<u8> = heard.iter().map(|b| b & 0x7F).collect();
    let seven = ascii_frames(&masked);
    if seven >= FRAMES_NEEDED {
        return Guess::AsciiSevenBits(seven);
    }
    if heard.len() >= GIVE_UP_AFTER {
        return Guess::Neither(heard[..heard.len().min(32)].to_vec());
    }
    Guess::Undecided
}

/// Why `guess` settled on no mode, in words for the user (`None`: it settled on one, or
/// is still undecided).
pub fn why_not(g: &Guess, line: crate::codec::timing::LineSettings) -> Option<String> {
    match g {
        Guess::Mode(..) | Guess::Undecided => None,
        Guess::AsciiSevenBits(n) => Some(format!(
            "{n} Modbus ASCII frames, but only with bit 7 of every byte cleared: the line has 7 data bits and was read as {line}; use --mode ascii -d 7 -P even (or -P odd)"
        )),
        Guess::Neither(first) => Some(format!(
            "no Modbus RTU or ASCII frame in the first {GIVE_UP_AFTER} bytes at {line}: {} ...; the line settings (-b, -P, -d, -s) may not be the line's",
            crate::codec::hex::Hex(first)
        )),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::pdu::{Message, Pdu};

    /// The same read of 2520H twice, in `mode`.
    fn frames(mode: Mode) -> Vec<u8> {
        let pdu = Pdu::ReadRequest {
            start: 0x2520,
            count: 1,
        };
        Message { address: 1, pdu }
            .to_frame_vec(mode)
            .unwrap()
            .repeat(2)
    }

    #[test]
    fn two_valid_frames_tell_the_mode() {
        assert_eq!(guess(&frames(Mode::Rtu)), Guess::Mode(Mode::Rtu, 2));
        assert_eq!(guess(&frames(Mode::Ascii)), Guess::Mode(Mode::Ascii, 2));
        // One frame is not enough.
        let one = &frames(Mode::Rtu)[..8];
        assert_eq!(guess(one), Guess::Undecided);
    }

    #[test]
    fn ascii_read_with_its_parity_bit_in_bit_7_is_named() {
        // 7E1 read as 8 bits: even parity sets bit 7 on characters with an odd count.
        let heard: Vec<u8> = frames(Mode::Ascii)
            .iter()
            .map(|&b| {
                if (b & 0x7F).count_ones() % 2 == 1 {
                    b | 0x80
                } else {
                    b
                }
            })
            .collect();
        assert_eq!(guess(&heard), Guess::AsciiSevenBits(2));
    }

    #[test]
    fn noise_is_neither_and_names_its_first_bytes() {
        let mut x: u32 = 12345;
        let noise: Vec<u8> = (0..GIVE_UP_AFTER)
            .map(|_| {
                x = x.wrapping_mul(1_103_515_245).wrapping_add(12345);
                (x >> 24) as u8
            })
            .collect();
        match guess(&noise) {
            Guess::Neither(first) => assert_eq!(first, noise[..32]),
            g => panic!("{g:?}"),
        }
    }
}
