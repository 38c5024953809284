//! Arrival times on an emulated line: the simulator's paced pseudo-terminal.
//!
//! On a real port a UART hands over each character when its stop bit is in; on a
//! pseudo-terminal the simulator reads whatever the kernel has queued, when its thread
//! wakes. A thread that wakes late finds several characters at once: they did not arrive
//! together, they came a character time apart (the sender paces them) and waited. So each
//! character of a read of n is placed (n - 1 - i) character times before the read, and
//! never sooner than one character time after the one before it.
//!
//! The RTU deframer compares the time between arrivals with t1.5 and t3.5; the standard's
//! t1.5 and t3.5 are silences, measured from the end of one character to the start of
//! the next (Modbus over Serial Line V1.02, 2.5.1.1), one character time less than the
//! time between arrivals. The clock given to the deframer therefore runs one character
//! time behind per character received: the difference of two of its readings is the
//! silence between them.
//!
//! What arrival times cannot show: the kernel delivers a pseudo-terminal's bytes with a
//! few milliseconds of jitter of its own (measured: an 8-byte request at 19200 baud split
//! by a "silence" over t3.5 in 7 of 27 sends on a lightly loaded host), which no receiver
//! can tell from a silence. Where the sender is this suite's paced transport it tells the
//! silence it put before every character ([`crate::transport::LineTags`]), and those are
//! used instead; a frame then ends at a told silence of t3.5, or after t3.5 +
//! [`TOLD_SLACK`] of quiet with no told character still in the kernel (its silence is
//! queued before it is written, so a queue that is not empty means a character in
//! flight). Other senders (mbpoll, pymodbus on `simulate --pty --pace`)
//! get the estimate.

use std::time::{Duration, Instant};

/// Virtual time starts here, so that subtracting character times never underflows.
const OFFSET_US: u64 = 1 << 40;

/// After a character whose silence its sender told, how much longer than t3.5 the line
/// must be quiet (by this host's clock) before the frame is taken as ended: the kernel
/// may still be delivering the frame's last characters (the pseudo-terminal's own
/// jitter, a few milliseconds on a busy host). A later character's told silence ends it
/// at once.
pub const TOLD_SLACK: Duration = Duration::from_millis(4);

/// The arrival clock of one emulated line: the deframer's time, which advances by the
/// silence before each character (told by the sender, or estimated from arrivals).
#[derive(Debug, Clone)]
pub struct LineClock {
    char_us: u64,
    epoch: Instant,
    /// Deframer time of the last character.
    last_d: u64,
    /// Estimated arrival of the last character, on this host's clock (us since epoch).
    last_arrival_us: Option<u64>,
    /// Whether the last character's silence was told.
    told: bool,
}

impl LineClock {
    /// A clock for a line whose character time is `char_us` microseconds.
    pub fn new(char_us: u64, epoch: Instant) -> Self {
        LineClock {
            char_us,
            epoch,
            last_d: OFFSET_US,
            last_arrival_us: None,
            told: false,
        }
    }

    fn real_us(&self, at: Instant) -> u64 {
        u64::try_from(at.saturating_duration_since(self.epoch).as_micros()).unwrap_or(u64::MAX)
    }

    fn advance(&mut self, silence: u64) -> u64 {
        // A silence "as long as the line was idle" only has to end any frame.
        self.last_d = self.last_d.saturating_add(silence.min(OFFSET_US));
        self.last_d
    }

    /// The deframer's timestamps for `n` characters read together at `at`, in order,
    /// estimated from their arrival.
    pub fn arrivals(&mut self, at: Instant, n: usize) -> Vec<u64> {
        (0..n).map(|i| self.arrival(at, n - 1 - i, None)).collect()
    }

    /// The deframer's timestamp of one character read at `at` with `queued` more read
    /// with it after it; `told`: the silence before it as its sender put it on the line.
    pub fn arrival(&mut self, at: Instant, queued: usize, told: Option<u32>) -> u64 {
        let now = self.real_us(at);
        let queued = u64::try_from(queued).unwrap_or(u64::MAX);
        let mut a = now.saturating_sub(queued.saturating_mul(self.char_us));
        if let Some(last) = self.last_arrival_us {
            a = a.max(last.saturating_add(self.char_us));
        }
        let silence = match (told, self.last_arrival_us) {
            (Some(s), _) => u64::from(s),
            (None, Some(last)) => a.saturating_sub(last).saturating_sub(self.char_us),
            (None, None) => u64::MAX,
        };
        self.last_arrival_us = Some(a);
        self.told = told.is_some();
        self.advance(silence)
    }

    /// The deframer's time for `at`, with nothing received since the last character:
    /// the quiet since its arrival (less [`TOLD_SLACK`] after a told character).
    pub fn idle(&self, at: Instant) -> u64 {
        let quiet = self
            .last_arrival_us
            .map_or(0, |last| self.real_us(at).saturating_sub(last));
        let slack = if self.told {
            u64::try_from(TOLD_SLACK.as_micros()).unwrap_or(u64::MAX)
        } else {
            0
        };
        self.last_d.saturating_add(quiet.saturating_sub(slack))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::time::Duration;

    /// A clock of a 1 ms character, started now.
    fn clock() -> (Instant, LineClock) {
        let t0 = Instant::now();
        (t0, LineClock::new(1000, t0))
    }

    #[test]
    fn characters_at_line_rate_have_no_silence_between_them() {
        let (t0, mut c) = clock();
        let a = c.arrivals(t0 + Duration::from_millis(10), 1);
        let b = c.arrivals(t0 + Duration::from_millis(11), 1);
        assert_eq!(b[0] - a[0], 0);
        // 2.5 character times of silence after the second character.
        let d = c.arrivals(t0 + Duration::from_micros(14_500), 1);
        assert_eq!(d[0] - b[0], 2_500);
    }

    #[test]
    fn characters_read_together_are_spread_back_at_line_rate() {
        let (t0, mut c) = clock();
        let first = c.arrivals(t0 + Duration::from_millis(10), 1);
        // The reader woke 3 ms late: three characters queued, the last at 13 ms.
        let late = c.arrivals(t0 + Duration::from_millis(13), 3);
        assert_eq!(late, vec![first[0]; 3]);
        // Idle: the silence since the last character, as it is.
        assert_eq!(c.idle(t0 + Duration::from_millis(17)) - late[2], 4_000);
    }

    #[test]
    fn told_silences_win_over_arrival_times() {
        let (t0, mut c) = clock();
        let a = c.arrival(t0 + Duration::from_millis(10), 0, Some(u32::MAX));
        // Delivered 5 ms later by the kernel, but sent with 200 us of silence.
        let b = c.arrival(t0 + Duration::from_millis(15), 0, Some(200));
        assert_eq!(b - a, 200);
        // Quiet for t3.5 (3.5 ms) by this host's clock is not enough after a told
        // character: the frame ends only after the slack too.
        let slack = u64::try_from(TOLD_SLACK.as_micros()).unwrap();
        assert_eq!(c.idle(t0 + Duration::from_micros(18_500)) - b, 0);
        assert_eq!(
            c.idle(t0 + Duration::from_micros(18_500 + slack)) - b,
            3_500
        );
    }

    #[test]
    fn a_burst_faster_than_the_line_is_placed_at_line_rate() {
        let (t0, mut c) = clock();
        let a = c.arrivals(t0 + Duration::from_millis(10), 8);
        let b = c.arrivals(t0 + Duration::from_millis(10), 8);
        assert!(a.windows(2).all(|w| w[0] == w[1]));
        assert_eq!(b[0], a[7]);
    }
}
