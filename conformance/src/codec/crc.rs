//! CRC-16/MODBUS: the checksum of RTU frames.
//!
//! Parameters: polynomial 8005H reflected (A001H), initial value FFFFH, no final XOR.
//! The check value over the ASCII string `123456789` is 4B37H.
//!
//! # Byte order on the wire, and the manuals' labels
//!
//! The CRC is transmitted **low-order byte first**. The TECO manuals say so in prose
//! ("CRC value: 1241 Hex, the high-order byte should be set to 41hex and low-order byte
//! 12hex") but label the *first transmitted* byte "High" in their example tables: the F510
//! RTU request `01 03 01 23 00 01 74 3C` is printed as "CRC-16 High 74H, Low 3CH", while
//! the CRC value is 3C74H. So a vector's `printed` bytes are in transmission order, and
//! the byte the manual calls "High" is the low byte of [`crc16`]'s result.
//! [`CrcBytes`] holds that mapping in one place.
//!
//! The slice-by-8 tables are in [`super::crc_table`], the carry-less paths and the
//! dispatcher that chooses among them in [`super::crc_clmul`]; this file is the API.

pub use super::crc_clmul::CrcPath;
pub use super::crc_table::crc16_update_table;
use super::crc_table::{crc16_table_short, crc16_table_u64, POLY};

/// The manuals' bitwise algorithm, step for step (F510 manual 1.0.1, "CRC Check"):
/// load FFFFH; XOR each byte into the low byte; eight times shift right, XOR A001H when
/// the bit shifted out was 1.
///
/// This is the reference that every faster implementation is tested against. It is slow
/// (eight branches a byte); use [`crc16`] everywhere else.
pub fn crc16_reference(data: &[u8]) -> u16 {
    let mut crc: u16 = 0xFFFF;
    for &byte in data {
        crc ^= u16::from(byte);
        for _ in 0..8 {
            if crc & 0x0001 != 0 {
                crc = (crc >> 1) ^ POLY;
            } else {
                crc >>= 1;
            }
        }
    }
    crc
}

/// CRC-16/MODBUS of `data`: the fast implementation used by the codec.
///
/// The path is chosen by length and by the CPU's tier (its widest path, detected once, at
/// the first call): the table (eight bytes a step) for short inputs, carry-less
/// multiplication folding (PCLMULQDQ) from 16 or 64 bytes and, where the CPU has VPCLMULQDQ,
/// 256-bit (AVX2) or 512-bit (AVX-512) folding for longer ones, from thresholds measured
/// per tier (`codec::crc_clmul::Thresholds`). `CONFORMANCE_CRC_PATH` caps the tier (see
/// `codec::crc_clmul::PATH_ENV`). Every path equals [`crc16_reference`] on every input
/// (unit- and property-tested path by path, and a differential fuzz target).
#[inline]
pub fn crc16(data: &[u8]) -> u16 {
    crc16_update(0xFFFF, data)
}

/// Continues a CRC-16/MODBUS computation from register value `crc` over `data`, so a
/// frame can be checksummed in pieces. Start from FFFFH.
#[inline]
pub fn crc16_update(crc: u16, data: &[u8]) -> u16 {
    if data.len() >= super::crc_clmul::MIN_LEN {
        if let Some(c) = super::crc_clmul::crc16_update(crc, data) {
            return c;
        }
    }
    crc16_update_table(crc, data)
}

/// Whether `frame` (a body followed by its CRC, low byte first, as RTU carries it) has a
/// right CRC: the register after the body *and* its CRC is zero (CRC-16/MODBUS has no
/// final XOR, so appending the CRC clears the register). For the frames a poll is made
/// of (4..=8 bytes: every 03H/06H/08H request, and short replies) this is one table step
/// over one word, without splitting off the CRC or comparing; the carried and computed
/// values are only needed when it fails.
#[inline(always)]
pub fn crc16_frame_ok(frame: &[u8]) -> bool {
    match <&[u8; 8]>::try_from(frame).ok() {
        Some(word) => crc16_table_u64(0xFFFF, u64::from_le_bytes(*word)) == 0,
        None if frame.len() < 8 => crc16_table_short(0xFFFF, frame) == 0,
        None => crc16_long_frame_ok(frame),
    }
}

/// [`crc16_frame_ok`] for frames over eight bytes, out of line so that the short path
/// stays small where it is inlined.
#[inline(never)]
fn crc16_long_frame_ok(frame: &[u8]) -> bool {
    crc16_update(0xFFFF, frame) == 0
}

/// The dispatcher's tier on this CPU: the widest path [`crc16`] takes for long inputs
/// (detected, capped by `CONFORMANCE_CRC_PATH`).
#[doc(hidden)]
pub fn crc16_tier() -> CrcPath {
    super::crc_clmul::tier()
}

/// The path [`crc16`] and [`crc16_update`] take for an input of `len` bytes on this CPU:
/// what the benches report as the path that ran.
#[doc(hidden)]
pub fn crc16_path(len: usize) -> CrcPath {
    super::crc_clmul::path_for(crc16_tier(), len)
}

/// [`crc16_update`] by the given path, on any length (a SIMD path hands inputs shorter
/// than its registers to a narrower path); `None` when this CPU cannot run it.
#[doc(hidden)]
pub fn crc16_update_with(path: CrcPath, crc: u16, data: &[u8]) -> Option<u16> {
    match path {
        CrcPath::Table => Some(crc16_update_table(crc, data)),
        CrcPath::Pclmul => super::crc_clmul::crc16_pclmul(crc, data),
        CrcPath::Avx2 => super::crc_clmul::crc16_avx2(crc, data),
        CrcPath::Avx512 => super::crc_clmul::crc16_avx512(crc, data),
    }
}

/// A CRC value and its two bytes in transmission order.
///
/// `first` is what the manuals label "High" in their tables, though it is the low-order
/// byte of the value (see the module documentation).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct CrcBytes {
    /// The 16-bit CRC value as computed.
    pub value: u16,
}

impl CrcBytes {
    /// The CRC of `data`.
    pub fn of(data: &[u8]) -> Self {
        CrcBytes { value: crc16(data) }
    }

    /// Reads a CRC from the two bytes as transmitted (low byte first).
    pub fn from_wire(bytes: [u8; 2]) -> Self {
        CrcBytes {
            value: u16::from_le_bytes(bytes),
        }
    }

    /// The two bytes in transmission order: low-order byte first.
    pub fn wire(self) -> [u8; 2] {
        self.value.to_le_bytes()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn check_value() {
        assert_eq!(crc16_reference(b"123456789"), 0x4B37);
        assert_eq!(crc16(b"123456789"), 0x4B37);
    }

    #[test]
    fn empty_input_is_initial_value() {
        assert_eq!(crc16(&[]), 0xFFFF);
        assert_eq!(crc16_reference(&[]), 0xFFFF);
    }

    #[test]
    fn f510_read_request_example() {
        // F510 manual 1.0.3, Read Holding Register [03H], RTU command: CRC "High 74H Low 3CH".
        let body = [0x01, 0x03, 0x01, 0x23, 0x00, 0x01];
        let crc = CrcBytes::of(&body);
        assert_eq!(crc.value, 0x3C74);
        assert_eq!(crc.wire(), [0x74, 0x3C]);
    }

    #[test]
    fn manual_byte_order_sentence() {
        // "CRC value: 1241 Hex, the high-order byte should be set to 41hex and low-order
        // byte 12hex": the first byte sent is 41H, the value's low byte.
        assert_eq!(CrcBytes { value: 0x1241 }.wire(), [0x41, 0x12]);
        assert_eq!(CrcBytes::from_wire([0x41, 0x12]).value, 0x1241);
    }

    #[test]
    fn every_path_equals_reference_for_every_length_0_to_2100() {
        // A deterministic xorshift stream: several random inputs of every length.
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state as u8
        };
        for len in 0..=2100 {
            let rounds = if len <= 300 { 8 } else { 1 };
            for _ in 0..rounds {
                let data: Vec<u8> = (0..len).map(|_| next()).collect();
                let want = crc16_reference(&data);
                assert_eq!(crc16(&data), want, "len {len}: {data:02X?}");
                for path in CrcPath::supported() {
                    assert_eq!(
                        crc16_update_with(path, 0xFFFF, &data),
                        Some(want),
                        "{} len {len}: {data:02X?}",
                        path.name()
                    );
                }
            }
        }
    }

    #[test]
    fn update_in_pieces_equals_whole() {
        let data: Vec<u8> = (0..=255u8).collect();
        for split in 0..data.len() {
            let (a, b) = data.split_at(split);
            assert_eq!(crc16_update(crc16_update(0xFFFF, a), b), crc16(&data));
        }
    }

    #[test]
    fn residue_of_frame_with_crc_is_zero() {
        let mut frame = vec![0x01, 0x06, 0x25, 0x02, 0x17, 0x70];
        frame.extend_from_slice(&CrcBytes::of(&frame).wire());
        assert_eq!(frame[6..], [0x2D, 0x12]);
        assert_eq!(crc16(&frame), 0);
    }
}
