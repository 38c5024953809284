//! The line settings a scan tries, most likely first, and what narrows them.
//!
//! The four manuals' Modbus chapters name no factory line setting; the F510 manual names
//! 9600 bps as the speed to set for its other protocols (09-02), and the Modbus over
//! Serial Line specification (2.5.1) makes 8E1 the default format and 19200 the usual
//! second speed. So: 9600 and 19200 first, then the faster rates, then the slow ones
//! (whose tries cost the most); even parity, then none, then odd; RTU, then ASCII.

use std::fmt;

use crate::codec::timing::{LineSettings, Parity};
use crate::codec::Mode;

/// Baud rates tried when none is given, most likely first.
pub const BAUDS: [u32; 8] = [9600, 19_200, 38_400, 57_600, 115_200, 4800, 2400, 1200];

/// Parities tried when none is given, most likely first.
pub const PARITIES: [Parity; 3] = [Parity::Even, Parity::None, Parity::Odd];

/// One line setting and mode a scan tries.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct Setting {
    /// Baud rate, data bits, parity, stop bits.
    pub line: LineSettings,
    /// RTU or ASCII.
    pub mode: Mode,
}

impl fmt::Display for Setting {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} {}", self.line, self.mode)
    }
}

/// What to search; an empty list means "the defaults".
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Search {
    /// Baud rates (default [`BAUDS`]).
    pub bauds: Vec<u32>,
    /// Parities (default [`PARITIES`]).
    pub parities: Vec<Parity>,
    /// Stop bits (default 1 only: a UART checks only its first stop bit, so a device set
    /// to 2 stop bits understands 1 and its replies are read with 1).
    pub stop_bits: Vec<u8>,
    /// Data bits (default 8; 7 is ASCII only).
    pub data_bits: Vec<u8>,
    /// Modes (default RTU, then ASCII).
    pub modes: Vec<Mode>,
}

impl Search {
    /// The settings to try, most likely first: baud rate, then parity, stop bits, data
    /// bits and mode. RTU with 7 data bits does not exist and is left out.
    pub fn settings(&self) -> Vec<Setting> {
        fn or<T: Copy>(given: &[T], default: &[T]) -> Vec<T> {
            if given.is_empty() {
                default.to_vec()
            } else {
                given.to_vec()
            }
        }
        let mut out = Vec::new();
        for baud in or(&self.bauds, &BAUDS) {
            for parity in or(&self.parities, &PARITIES) {
                for stop in or(&self.stop_bits, &[1]) {
                    for data in or(&self.data_bits, &[8]) {
                        for mode in or(&self.modes, &[Mode::Rtu, Mode::Ascii]) {
                            if mode == Mode::Rtu && data != 8 {
                                continue;
                            }
                            out.push(Setting {
                                line: LineSettings::new(baud, data, parity, stop),
                                mode,
                            });
                        }
                    }
                }
            }
        }
        out
    }
}

/// The tier of a baud rate: 0 for the commonest (9600, 19200, and any rate given that is
/// not in [`BAUDS`]), 1 for the fast ones and 4800, 2 for 2400 and 1200. The full address
/// sweep runs tier by tier, every setting of a tier for one address before the next.
pub fn tier(baud: u32) -> usize {
    match baud {
        38_400 | 57_600 | 115_200 | 4800 => 1,
        2400 | 1200 => 2,
        _ => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_default_search_is_most_likely_first() {
        let s = Search::default().settings();
        assert_eq!(s.len(), 8 * 3 * 2);
        assert_eq!(s[0].to_string(), "9600 8E1 rtu");
        assert_eq!(s[1].to_string(), "9600 8E1 ascii");
        assert_eq!(s[2].to_string(), "9600 8N1 rtu");
        assert_eq!(s[6].to_string(), "19200 8E1 rtu");
        assert_eq!(s.last().unwrap().to_string(), "1200 8O1 ascii");
    }

    #[test]
    fn a_given_option_narrows_the_search() {
        let s = Search {
            bauds: vec![19_200],
            modes: vec![Mode::Ascii],
            ..Search::default()
        }
        .settings();
        let names: Vec<String> = s.iter().map(|s| s.to_string()).collect();
        assert_eq!(
            names,
            ["19200 8E1 ascii", "19200 8N1 ascii", "19200 8O1 ascii"]
        );
        // 7 data bits: ASCII only.
        let s = Search {
            bauds: vec![9600],
            parities: vec![Parity::Even],
            data_bits: vec![7],
            ..Search::default()
        }
        .settings();
        assert_eq!(s.len(), 1);
        assert_eq!(s[0].to_string(), "9600 7E1 ascii");
    }

    #[test]
    fn tiers() {
        assert_eq!(tier(9600), 0);
        assert_eq!(tier(19_200), 0);
        assert_eq!(tier(250_000), 0);
        assert_eq!(tier(115_200), 1);
        assert_eq!(tier(1200), 2);
    }
}
