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

/// Reflected polynomial of CRC-16/MODBUS.
const POLY: u16 = 0xA001;

/// `TABLES[k][b]` is the CRC register contribution of byte `b` followed by `k` zero bytes,
/// which lets [`crc16`] consume eight bytes per step (slice-by-8).
static TABLES: [[u16; 256]; 8] = build_tables();

const fn build_tables() -> [[u16; 256]; 8] {
    let mut tables = [[0u16; 256]; 8];
    let mut b = 0;
    while b < 256 {
        let mut crc = b as u16;
        let mut i = 0;
        while i < 8 {
            crc = if crc & 1 != 0 {
                (crc >> 1) ^ POLY
            } else {
                crc >> 1
            };
            i += 1;
        }
        tables[0][b] = crc;
        b += 1;
    }
    let mut k = 1;
    while k < 8 {
        let mut b = 0;
        while b < 256 {
            let prev = tables[k - 1][b];
            tables[k][b] = (prev >> 8) ^ tables[0][(prev & 0xFF) as usize];
            b += 1;
        }
        k += 1;
    }
    tables
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

/// The portable table-driven CRC (slice-by-8), whatever the CPU: the fallback of
/// [`crc16_update`], public so it can be benchmarked and tested on its own.
#[inline]
pub fn crc16_update_table(crc: u16, data: &[u8]) -> u16 {
    let (words, rest) = data.split_at(data.len() & !7);
    let crc = if words.is_empty() {
        crc
    } else {
        crc16_table_words(crc, words)
    };
    crc16_table_short(crc, rest)
}

/// Slice-by-8 over whole eight-byte words (out of line: it loops).
#[inline(never)]
fn crc16_table_words(mut crc: u16, words: &[u8]) -> u16 {
    for c in words.chunks_exact(8) {
        let word = u64::from_le_bytes([c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7]]);
        crc = crc16_table_u64(crc, word);
    }
    crc
}

/// The CRC over fewer than eight bytes (`rest.len() < 8`), inlined where it is used: an
/// RTU request body is six bytes.
#[inline(always)]
fn crc16_table_short(crc: u16, rest: &[u8]) -> u16 {
    let n = rest.len();
    // Two to seven bytes in one step, as slice-by-8 does eight, without a loop that waits
    // for each byte: with the register XORed into the
    // first two bytes, the register becomes zero, and leading zero bytes then change
    // nothing; so the bytes go to the top of a word and the eight-byte step finishes it.
    // The two loads below overlap where n is not 2 or 4 (an overlapping byte is ORed in
    // twice, harmlessly).
    let word = match n {
        0 => return crc,
        1 => return (crc >> 8) ^ TABLES[0][usize::from((crc ^ u16::from(rest[0])) & 0xFF)],
        2 | 3 => {
            let first = u16::from_le_bytes([rest[0], rest[1]]);
            let last = u16::from_le_bytes([rest[n - 2], rest[n - 1]]);
            u64::from(first) | u64::from(last) << (8 * (n - 2))
        }
        _ => {
            let first = u32::from_le_bytes([rest[0], rest[1], rest[2], rest[3]]);
            let last = u32::from_le_bytes([rest[n - 4], rest[n - 3], rest[n - 2], rest[n - 1]]);
            u64::from(first) | u64::from(last) << (8 * (n - 4))
        }
    };
    crc16_table_u64(0, (word ^ u64::from(crc)) << (64 - 8 * n))
}

/// One slice-by-8 step: the register after eight bytes, `word` read little-endian.
#[inline(always)]
pub(super) fn crc16_table_u64(crc: u16, word: u64) -> u16 {
    let w = word ^ u64::from(crc);
    let b = |i: u32| usize::from((w >> (8 * i)) as u8);
    TABLES[7][b(0)]
        ^ TABLES[6][b(1)]
        ^ TABLES[5][b(2)]
        ^ TABLES[4][b(3)]
        ^ TABLES[3][b(4)]
        ^ TABLES[2][b(5)]
        ^ TABLES[1][b(6)]
        ^ TABLES[0][b(7)]
}

/// One implementation of CRC-16/MODBUS, so tests, the fuzz target and benches can force
/// each path this CPU supports; [`crc16`] chooses among them by itself. Ordered from the
/// narrowest to the widest, which is also the order of the dispatcher's tiers.
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum CrcPath {
    /// Slice-by-8 tables, any CPU.
    Table,
    /// PCLMULQDQ folding, 128-bit lanes (x86-64).
    Pclmul,
    /// VPCLMULQDQ folding, 256-bit registers (x86-64 with AVX2, with or without AVX-512).
    Avx2,
    /// VPCLMULQDQ folding, 512-bit registers (x86-64 with AVX-512).
    Avx512,
}

impl CrcPath {
    /// Every path, supported here or not, narrowest first.
    pub const ALL: [CrcPath; 4] = [
        CrcPath::Table,
        CrcPath::Pclmul,
        CrcPath::Avx2,
        CrcPath::Avx512,
    ];

    /// Whether this CPU can run the path.
    pub fn available(self) -> bool {
        match self {
            CrcPath::Table => true,
            CrcPath::Pclmul => super::crc_clmul::pclmul_available(),
            CrcPath::Avx2 => super::crc_clmul::avx2_available(),
            CrcPath::Avx512 => super::crc_clmul::avx512_available(),
        }
    }

    /// The paths this CPU can run.
    pub fn supported() -> impl Iterator<Item = CrcPath> {
        Self::ALL.into_iter().filter(|p| p.available())
    }

    /// A short name, for test messages, bench ids and `CONFORMANCE_CRC_PATH`.
    pub const fn name(self) -> &'static str {
        match self {
            CrcPath::Table => "table",
            CrcPath::Pclmul => "pclmul",
            CrcPath::Avx2 => "avx2",
            CrcPath::Avx512 => "avx512",
        }
    }

    /// The path of a [`name`](Self::name), `None` for any other text.
    pub fn from_name(name: &str) -> Option<CrcPath> {
        Self::ALL.into_iter().find(|p| p.name() == name)
    }

    /// The shortest input this path's own kernel folds: [`crc16_update_with`] hands a
    /// shorter one to a narrower path (the width of one register; 0 for the table).
    pub const fn min_len(self) -> usize {
        match self {
            CrcPath::Table => 0,
            CrcPath::Pclmul => 16,
            CrcPath::Avx2 => 32,
            CrcPath::Avx512 => 64,
        }
    }
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
