//! The CRC's law: every path this CPU can run equals the manuals' loop.

use crate::codec::crc::{crc16, crc16_reference, crc16_update, crc16_update_with, CrcPath};

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
}
