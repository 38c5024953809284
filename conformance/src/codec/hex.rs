//! Hexadecimal: the one place that turns bytes into hex text and back.
//!
//! Used by the ASCII frame codec (upper-case pairs on emit), by error messages and reports
//! (`01 03 02 17 70`), and by the command line and vector files (parsing what people type).

use std::fmt;

const UPPER: &[u8; 16] = b"0123456789ABCDEF";

/// The two upper-case hex characters of `byte`, high nibble first.
#[inline]
pub fn encode_byte(byte: u8) -> [u8; 2] {
    [
        UPPER[usize::from(byte >> 4)],
        UPPER[usize::from(byte & 0x0F)],
    ]
}

/// Value of every byte as a hex digit, upper or lower case; 0xFF for anything else.
static NIBBLE: [u8; 256] = {
    let mut t = [0xFFu8; 256];
    let mut c = 0;
    while c < 256 {
        t[c] = match c as u8 {
            b'0'..=b'9' => c as u8 - b'0',
            b'A'..=b'F' => c as u8 - b'A' + 10,
            b'a'..=b'f' => c as u8 - b'a' + 10,
            _ => 0xFF,
        };
        c += 1;
    }
    t
};

/// The value of one hex character, upper or lower case; FFH for anything else (any value
/// with a bit above the low four set is not a digit), so a loop can check a whole run of
/// characters at once by ORing these together.
#[inline(always)]
pub(crate) fn nibble_or_ff(c: u8) -> u8 {
    NIBBLE[usize::from(c)]
}

/// The value of one hex character, upper or lower case; `None` for anything else.
#[inline]
pub fn decode_nibble(c: u8) -> Option<u8> {
    match NIBBLE[usize::from(c)] {
        0xFF => None,
        v => Some(v),
    }
}

/// Displays bytes as upper-case hex pairs separated by single spaces (`01 03 02 17 70`),
/// without allocating.
#[derive(Clone, Copy)]
pub struct Hex<'a>(pub &'a [u8]);

impl fmt::Display for Hex<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        for (i, b) in self.0.iter().enumerate() {
            if i > 0 {
                f.write_str(" ")?;
            }
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

impl fmt::Debug for Hex<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        fmt::Display::fmt(self, f)
    }
}

/// Why a hex string typed by a person could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum HexError {
    /// A character that is neither a hex digit nor a separator.
    #[error("invalid hex character {found:?} at column {column}")]
    BadChar {
        /// The offending character.
        found: char,
        /// 1-based column in the input.
        column: usize,
    },
    /// A run of hex digits with an odd length, which cannot be split into bytes.
    #[error("hex token {token:?} at column {column} has an odd number of digits")]
    OddDigits {
        /// The token as typed.
        token: String,
        /// 1-based column in the input.
        column: usize,
    },
}

/// Parses hex typed by a person: `01 03 01 23`, `01030123`, `0x01,0x03`, `01H 03H` (the
/// manuals' notation), upper or lower case. Tokens are separated by white space, commas
/// or colons; a token of several pairs (`0103`) is split into bytes.
pub fn parse_hex(input: &str) -> Result<Vec<u8>, HexError> {
    let mut out = Vec::with_capacity(input.len() / 2);
    let bytes = input.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        let c = bytes[i];
        if c.is_ascii_whitespace() || c == b',' || c == b':' {
            i += 1;
            continue;
        }
        let start = i;
        while i < bytes.len()
            && !(bytes[i].is_ascii_whitespace() || bytes[i] == b',' || bytes[i] == b':')
        {
            i += 1;
        }
        let mut token = &input[start..i];
        let mut column = start + 1;
        if let Some(rest) = token
            .strip_prefix("0x")
            .or_else(|| token.strip_prefix("0X"))
        {
            token = rest;
            column += 2;
        }
        if let Some(rest) = token.strip_suffix('H').or_else(|| token.strip_suffix('h')) {
            if !rest.is_empty() {
                token = rest;
            }
        }
        for (k, ch) in token.char_indices() {
            if !ch.is_ascii_hexdigit() {
                return Err(HexError::BadChar {
                    found: ch,
                    column: column + k,
                });
            }
        }
        if !token.len().is_multiple_of(2) {
            return Err(HexError::OddDigits {
                token: token.to_string(),
                column,
            });
        }
        for pair in token.as_bytes().chunks_exact(2) {
            // Both digits were checked above.
            let hi = decode_nibble(pair[0]).unwrap_or(0);
            let lo = decode_nibble(pair[1]).unwrap_or(0);
            out.push(hi << 4 | lo);
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn display_is_spaced_upper_case() {
        assert_eq!(Hex(&[0x01, 0xaf, 0x00]).to_string(), "01 AF 00");
        assert_eq!(Hex(&[]).to_string(), "");
    }

    #[test]
    fn encode_and_decode_every_byte() {
        for b in 0..=255u8 {
            let [h, l] = encode_byte(b);
            assert!(h.is_ascii_uppercase() || h.is_ascii_digit());
            assert_eq!(
                decode_nibble(h).unwrap() << 4 | decode_nibble(l).unwrap(),
                b
            );
            let lower = [h.to_ascii_lowercase(), l.to_ascii_lowercase()];
            assert_eq!(
                decode_nibble(lower[0]).unwrap() << 4 | decode_nibble(lower[1]).unwrap(),
                b
            );
        }
        assert_eq!(decode_nibble(b'g'), None);
        assert_eq!(decode_nibble(b':'), None);
    }

    #[test]
    fn parse_accepts_the_usual_spellings() {
        let want = vec![0x01, 0x03, 0x01, 0x23];
        for s in [
            "01 03 01 23",
            "01030123",
            "0x01,0x03,0x01,0x23",
            "01H 03H 01H 23H",
            " 01 03\n0123 ",
        ] {
            assert_eq!(parse_hex(s).unwrap(), want, "{s}");
        }
    }

    #[test]
    fn parse_reports_column_of_bad_input() {
        assert_eq!(
            parse_hex("01 0G").unwrap_err(),
            HexError::BadChar {
                found: 'G',
                column: 5
            }
        );
        assert!(matches!(
            parse_hex("01 234"),
            Err(HexError::OddDigits { column: 4, .. })
        ));
    }
}
