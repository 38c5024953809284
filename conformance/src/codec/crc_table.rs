//! CRC-16/MODBUS by tables (slice-by-8): the portable path, any CPU, and the tail of
//! every carry-less path (see [`super::crc_clmul`]).

/// Reflected polynomial of CRC-16/MODBUS.
pub(super) const POLY: u16 = 0xA001;

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
pub(super) fn crc16_table_short(crc: u16, rest: &[u8]) -> u16 {
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
