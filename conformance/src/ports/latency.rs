//! What a USB adapter's latency timer does to RTU framing.
//!
//! An FTDI adapter (and others with the same design) holds the bytes it receives until
//! its buffer fills or its latency timer runs out, then sends them to the computer in one
//! USB packet. A reply therefore reaches the computer in bursts up to the timer apart, and
//! up to the timer late. RTU ends a frame on a silence of t3.5 (4.01 ms at 9600 baud,
//! 1.75 ms above 19200): with a timer of t3.5 or more, the silences the computer sees are
//! the adapter's, not the line's. The default of 16 ms is above t3.5 at every rate; 1 ms,
//! the smallest the driver takes, is below it at every rate.

use std::path::Path;

use serde::Serialize;

use crate::codec::timing::{LineSettings, Parity};

/// The rates `conformance ports` explains the timer at.
pub const BAUDS: [u32; 4] = [9600, 19200, 38400, 115200];

/// The timer that keeps bursts shorter than t3.5 at every rate: the driver's smallest.
pub const ADVISED_MS: u32 = 1;

/// The timer against t3.5 at one rate.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct RateEffect {
    /// Bits per second.
    pub baud: u32,
    /// t3.5 at this rate, in microseconds (for 11-bit characters, 8E1 or 8N2, the RTU
    /// character the specification gives).
    pub t3_5_us: u64,
    /// The timer as a multiple of t3.5.
    pub times_t3_5: f64,
    /// Whether the timer is t3.5 or longer: a silence the computer sees inside a reply
    /// can then be the adapter's, and anything on this computer that frames by timing
    /// (a master, a monitor) can cut a frame in two or join two.
    pub breaks_framing: bool,
}

/// The effect of a timer of `ms` milliseconds at each of [`BAUDS`].
pub fn effects(ms: u32) -> Vec<RateEffect> {
    BAUDS
        .iter()
        .map(|&baud| {
            let t3_5_us = LineSettings::new(baud, 8, Parity::Even, 1).t3_5_us();
            let timer_us = u64::from(ms) * 1000;
            RateEffect {
                baud,
                t3_5_us,
                times_t3_5: timer_us as f64 / t3_5_us as f64,
                breaks_framing: timer_us >= t3_5_us,
            }
        })
        .collect()
}

/// The one command that sets the timer in `file` to [`ADVISED_MS`] (until the adapter
/// is plugged in again).
pub fn set_command(file: &Path) -> String {
    format!("echo {ADVISED_MS} | sudo tee {}", file.display())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sixteen_ms_breaks_framing_at_every_rate_and_one_ms_at_none() {
        let e = effects(16);
        assert_eq!(
            e.iter().map(|r| r.t3_5_us).collect::<Vec<_>>(),
            [4011, 2006, 1750, 1750]
        );
        assert!(e.iter().all(|r| r.breaks_framing));
        assert!((e[0].times_t3_5 - 3.99).abs() < 0.01, "{}", e[0].times_t3_5);
        assert!(effects(ADVISED_MS).iter().all(|r| !r.breaks_framing));
        // 2 ms is under t3.5 at 9600 and 19200 only.
        let two: Vec<bool> = effects(2).iter().map(|r| r.breaks_framing).collect();
        assert_eq!(two, [false, false, true, true]);
    }
}
