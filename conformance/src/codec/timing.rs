//! Serial-line timing: character time and the RTU silent intervals t1.5 and t3.5.
//!
//! Modbus over Serial Line V1.02, 2.5.1.1: an RTU frame ends at a silence of at least 3.5
//! character times; a silence of more than 1.5 character times inside a frame makes the
//! frame incomplete. Above 19200 baud the fixed values 750 us (t1.5) and 1750 us (t3.5)
//! are used.

use std::fmt;
use std::time::{Duration, Instant};

/// `at + d`, or the latest instant the clock can hold after `at` where the sum overflows:
/// a deadline set from an option or a peer's answer (a timeout of years, "no limit") is
/// only ever far away, never a panic.
pub fn later(at: Instant, d: Duration) -> Instant {
    let mut d = d;
    loop {
        if let Some(t) = at.checked_add(d) {
            return t;
        }
        d /= 2;
    }
}

/// Parity of the serial line.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Parity {
    /// No parity bit.
    None,
    /// Even parity.
    Even,
    /// Odd parity.
    Odd,
}

impl Parity {
    /// The parity as the command line spells it (`-P none|even|odd`, as mbpoll does).
    pub fn name(self) -> &'static str {
        match self {
            Parity::None => "none",
            Parity::Even => "even",
            Parity::Odd => "odd",
        }
    }
}

impl fmt::Display for Parity {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Parity::None => "N",
            Parity::Even => "E",
            Parity::Odd => "O",
        })
    }
}

/// Settings of a serial line that determine its timing.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub struct LineSettings {
    /// Bits per second.
    pub baud: u32,
    /// Data bits a character (8 for RTU, 7 or 8 for ASCII).
    pub data_bits: u8,
    /// Parity.
    pub parity: Parity,
    /// Stop bits (1 or 2).
    pub stop_bits: u8,
}

impl LineSettings {
    /// 9600 baud, 8 data bits, no parity, 1 stop bit.
    pub const fn new(baud: u32, data_bits: u8, parity: Parity, stop_bits: u8) -> Self {
        LineSettings {
            baud,
            data_bits,
            parity,
            stop_bits,
        }
    }

    /// Bits on the line for one character: start bit, data bits, parity bit if any, stop
    /// bits (11 for 8E1 and 8N2, 10 for 8N1).
    pub fn bits_per_char(&self) -> u32 {
        1 + u32::from(self.data_bits)
            + u32::from(self.parity != Parity::None)
            + u32::from(self.stop_bits)
    }

    /// Time of one character, in microseconds (rounded up). A baud rate of 0 is treated
    /// as 1 so the result stays finite.
    pub fn char_time_us(&self) -> u64 {
        let baud = u64::from(self.baud.max(1));
        (u64::from(self.bits_per_char()) * 1_000_000).div_ceil(baud)
    }

    /// t1.5: the longest silence allowed between two characters of one frame, in us.
    pub fn t1_5_us(&self) -> u64 {
        if self.baud > 19_200 {
            750
        } else {
            (u64::from(self.bits_per_char()) * 1_500_000).div_ceil(u64::from(self.baud.max(1)))
        }
    }

    /// t3.5: the silence that ends a frame, in us.
    pub fn t3_5_us(&self) -> u64 {
        if self.baud > 19_200 {
            1_750
        } else {
            (u64::from(self.bits_per_char()) * 3_500_000).div_ceil(u64::from(self.baud.max(1)))
        }
    }
}

impl fmt::Display for LineSettings {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{} {}{}{}",
            self.baud, self.data_bits, self.parity, self.stop_bits
        )
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_deadline_beyond_the_clock_is_far_away_not_a_panic() {
        let now = std::time::Instant::now();
        assert_eq!(
            later(now, Duration::from_millis(5)),
            now + Duration::from_millis(5)
        );
        for d in [Duration::MAX, Duration::from_millis(u64::MAX)] {
            assert!(later(now, d) > now + Duration::from_secs(3600 * 24 * 365));
        }
    }

    #[test]
    fn bits_per_char() {
        assert_eq!(
            LineSettings::new(9600, 8, Parity::Even, 1).bits_per_char(),
            11
        );
        assert_eq!(
            LineSettings::new(9600, 8, Parity::None, 2).bits_per_char(),
            11
        );
        assert_eq!(
            LineSettings::new(9600, 8, Parity::None, 1).bits_per_char(),
            10
        );
        assert_eq!(
            LineSettings::new(9600, 7, Parity::Even, 1).bits_per_char(),
            10
        );
    }

    #[test]
    fn intervals_at_9600_8e1() {
        let l = LineSettings::new(9600, 8, Parity::Even, 1);
        assert_eq!(l.char_time_us(), 1146); // 11 bits / 9600 = 1145.8 us
        assert_eq!(l.t1_5_us(), 1719);
        assert_eq!(l.t3_5_us(), 4011);
        assert_eq!(l.to_string(), "9600 8E1");
    }

    #[test]
    fn fixed_intervals_above_19200() {
        let l = LineSettings::new(38_400, 8, Parity::None, 1);
        assert_eq!(l.t1_5_us(), 750);
        assert_eq!(l.t3_5_us(), 1750);
        let l = LineSettings::new(19_200, 8, Parity::Even, 1);
        assert_eq!(l.t3_5_us(), 2006);
    }

    #[test]
    fn zero_baud_does_not_divide_by_zero() {
        let l = LineSettings::new(0, 8, Parity::None, 1);
        assert!(l.t3_5_us() > 0);
    }
}
