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
/// Carry-less multiplication folding (PCLMULQDQ) for 64 bytes and more where the CPU has
/// it, table-driven (eight bytes a step) otherwise; equal to [`crc16_reference`] on every
/// input (unit- and property-tested, and a differential fuzz target).
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

/// The portable table-driven CRC (slice-by-8), whatever the CPU: the fallback of
/// [`crc16_update`], public so it can be benchmarked and tested on its own.
pub fn crc16_update_table(mut crc: u16, data: &[u8]) -> u16 {
    let mut chunks = data.chunks_exact(8);
    for c in &mut chunks {
        let lo = crc ^ u16::from_le_bytes([c[0], c[1]]);
        crc = TABLES[7][usize::from(lo & 0xFF)]
            ^ TABLES[6][usize::from(lo >> 8)]
            ^ TABLES[5][usize::from(c[2])]
            ^ TABLES[4][usize::from(c[3])]
            ^ TABLES[3][usize::from(c[4])]
            ^ TABLES[2][usize::from(c[5])]
            ^ TABLES[1][usize::from(c[6])]
            ^ TABLES[0][usize::from(c[7])];
    }
    for &byte in chunks.remainder() {
        crc = (crc >> 8) ^ TABLES[0][usize::from((crc ^ u16::from(byte)) & 0xFF)];
    }
    crc
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
    fn fast_equals_reference_for_every_length_0_to_300() {
        // A deterministic xorshift stream: several random inputs of every length.
        let mut state: u64 = 0x9E37_79B9_7F4A_7C15;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state as u8
        };
        for len in 0..=300 {
            for _ in 0..8 {
                let data: Vec<u8> = (0..len).map(|_| next()).collect();
                assert_eq!(
                    crc16(&data),
                    crc16_reference(&data),
                    "len {len}: {data:02X?}"
                );
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
