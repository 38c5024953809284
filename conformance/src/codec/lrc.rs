//! LRC: the checksum of ASCII frames.
//!
//! The two's complement of the 8-bit sum of the binary bytes from the address through the
//! data (not the ':' and not the CR LF), sent as two upper-case hex characters.

/// LRC of the binary bytes `data` (address, function, data).
pub fn lrc(data: &[u8]) -> u8 {
    data.iter()
        .fold(0u8, |sum, &b| sum.wrapping_add(b))
        .wrapping_neg()
}

/// The two ASCII characters that carry `lrc` on the wire, upper case.
pub fn lrc_chars(lrc: u8) -> [u8; 2] {
    super::hex::encode_byte(lrc)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn manual_worked_example() {
        // F510/A510/L510 manuals 1.0.1, "Checksum Calculation, LRC":
        // 01H + 03H + 01H + 00H + 0AH = 0FH; two's complement F1H; sent as 46H 31H.
        let data = [0x01, 0x03, 0x01, 0x00, 0x0A];
        assert_eq!(data.iter().map(|&b| u32::from(b)).sum::<u32>(), 0x0F);
        assert_eq!(lrc(&data), 0xF1);
        assert_eq!(lrc_chars(lrc(&data)), [0x46, 0x31]);
        assert_eq!(&lrc_chars(0xF1), b"F1");
    }

    #[test]
    fn appending_lrc_makes_sum_zero() {
        let data = [0x01, 0x03, 0x25, 0x20, 0x00, 0x10];
        let sum = data.iter().fold(lrc(&data), |s, &b| s.wrapping_add(b));
        assert_eq!(sum, 0);
    }

    #[test]
    fn empty_and_wrapping() {
        assert_eq!(lrc(&[]), 0);
        assert_eq!(lrc(&[0xFF, 0x01]), 0x00);
        assert_eq!(lrc(&[0x80, 0x80, 0x01]), 0xFF);
    }
}
