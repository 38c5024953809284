//! An endpoint's own receiver, set to other line settings than the line's: what a
//! listener whose program set its port to another baud rate, parity or stop-bit count
//! reads from the pair (`bus --emulate-line`). Pure, like [`super::wire`].
//!
//! It reads the line's level as a 16550 does, on its own bit clock, the same way as
//! [`crate::transport::uart::transcode`] reads one sender's characters: a low level in
//! idle is a start bit if it is still low half a bit later; the data bits, the parity bit
//! and the first stop bit are sampled in their middles; a low stop bit is a framing
//! error, a wrong parity bit a parity error; it hunts again from the end of that stop
//! bit. Here the level is the wire's, bit by bit (the wired-AND of every driver, with
//! the noise), so a listener at the wrong settings also reads collisions and gaps as its
//! UART would.
//!
//! Time is exact: in units of 1/(2·B·r) s, B the line's baud rate and r the receiver's,
//! line bit b spans [2r·b, 2r·(b+1)) and the receiver's sample k of a character that
//! starts at s falls at s + (2k+1)·B.

use super::signal::{read_char, Drivers, Event, Heard};
use crate::codec::timing::{LineSettings, Parity};

#[derive(Debug, Clone, Copy)]
enum State {
    /// Waiting for a low level at or after this time.
    Hunt { from: u128 },
    /// Reading a character that started at `start`; `k` samples taken.
    Read {
        start: u128,
        k: u32,
        sampled: u16,
        drivers: Drivers,
        multi: bool,
        flipped: bool,
    },
}

/// One endpoint's receiver at its own settings.
#[derive(Debug, Clone)]
pub(super) struct OwnRx {
    endpoint: usize,
    line: LineSettings,
    // 2r: a line bit in time units.
    line_bit: u128,
    // B: half a receiver bit in time units.
    half_bit: u128,
    // Start bit, data bits, parity bit, first stop bit.
    samples: u32,
    state: State,
}

impl OwnRx {
    /// A receiver for `endpoint` at `line` (data bits clamped to 5..=8) on a line at
    /// `line_baud`, hunting from line bit `from`.
    pub(super) fn new(endpoint: usize, line: LineSettings, line_baud: u32, from: u64) -> Self {
        let data_bits = line.data_bits.clamp(5, 8);
        let line = LineSettings { data_bits, ..line };
        let line_bit = 2 * u128::from(line.baud.max(1));
        OwnRx {
            endpoint,
            line,
            line_bit,
            half_bit: u128::from(line_baud.max(1)),
            samples: 2 + u32::from(data_bits) + u32::from(line.parity != Parity::None),
            state: State::Hunt {
                from: u128::from(from) * line_bit,
            },
        }
    }

    /// Its settings.
    pub(super) fn line(&self) -> LineSettings {
        self.line
    }

    fn sample_at(&self, start: u128, k: u32) -> u128 {
        start + (2 * u128::from(k) + 1) * self.half_bit
    }

    /// The line bit after which the character it is reading is whole, if it is reading
    /// one.
    pub(super) fn due(&self) -> Option<u64> {
        match self.state {
            State::Hunt { .. } => None,
            State::Read { start, .. } => {
                let last = self.sample_at(start, self.samples - 1);
                Some(u64::try_from(last / self.line_bit + 1).unwrap_or(u64::MAX))
            }
        }
    }

    /// Whether it is in the middle of a character.
    pub(super) fn reading(&self) -> bool {
        matches!(self.state, State::Read { .. })
    }

    /// Line bit `b` carried `level`, driven by `drivers` (`multi`: by two or more;
    /// `flipped`: by the noise).
    pub(super) fn bit(
        &mut self,
        b: u64,
        level: bool,
        drivers: Drivers,
        multi: bool,
        flipped: bool,
        out: &mut Vec<Event>,
    ) {
        let lo = u128::from(b) * self.line_bit;
        let hi = lo + self.line_bit;
        loop {
            match self.state {
                State::Hunt { from } => {
                    let start = from.max(lo);
                    if level || start >= hi {
                        return;
                    }
                    self.state = State::Read {
                        start,
                        k: 0,
                        sampled: 0,
                        drivers: 0,
                        multi: false,
                        flipped: false,
                    };
                }
                State::Read { start, k, .. } => {
                    let t = self.sample_at(start, k);
                    if t >= hi {
                        return;
                    }
                    self.sample(t, level, drivers, multi, flipped, out);
                }
            }
        }
    }

    /// The line idled (level 1, nobody driving) up to line bit `to` (exclusive).
    pub(super) fn idle(&mut self, to: u64, out: &mut Vec<Event>) {
        let hi = u128::from(to) * self.line_bit;
        while let State::Read { start, k, .. } = self.state {
            let t = self.sample_at(start, k);
            if t >= hi {
                return;
            }
            self.sample(t, true, 0, false, false, out);
        }
    }

    /// Takes sample `k` (at time `t`) of the character being read.
    fn sample(&mut self, t: u128, level: bool, d: Drivers, m: bool, f: bool, out: &mut Vec<Event>) {
        let State::Read {
            start,
            k,
            sampled,
            drivers,
            multi,
            flipped,
        } = self.state
        else {
            return;
        };
        if k == 0 && level {
            // High in the middle of the start bit: a glitch, not a character.
            self.state = State::Hunt { from: t };
            return;
        }
        let sampled = sampled | u16::from(level) << k;
        let (drivers, multi, flipped) = (drivers | d, multi || m, flipped || f);
        if k + 1 < self.samples {
            self.state = State::Read {
                start,
                k: k + 1,
                sampled,
                drivers,
                multi,
                flipped,
            };
            return;
        }
        let (byte, error) = read_char(sampled, &self.line);
        out.push(Event::Heard(Heard {
            endpoint: self.endpoint,
            start: u64::try_from(start / self.line_bit).unwrap_or(u64::MAX),
            byte,
            error,
            drivers,
            damaged: multi || flipped || error.is_some(),
        }));
        // Hunts again from the end of the first stop bit.
        self.state = State::Hunt {
            from: t + self.half_bit,
        };
    }
}

#[cfg(test)]
mod tests {
    use super::super::wire::{Event, Wire};
    use crate::codec::timing::{LineSettings, Parity};
    use crate::transport::uart::{parity_bit, transcode, CharError};

    const REQUEST: [u8; 8] = [0x01, 0x03, 0x25, 0x2F, 0x00, 0x01, 0x7E, 0xC3];

    /// What endpoint 1 hears when endpoint 0 sends `bytes` on a line at `line`, endpoint
    /// 1's receiver set to `own`: (byte, error) each.
    fn heard(line: LineSettings, own: LineSettings, bytes: &[u8]) -> Vec<(u8, Option<CharError>)> {
        let mut w = Wire::new(line, 2).unwrap();
        w.set_receiver(1, Some(own)).unwrap();
        assert_eq!(w.receiver(1), Some(own));
        w.transmit(0, 10, bytes).unwrap();
        let mut ev = Vec::new();
        let mut to = 0;
        while let Some(due) = w.next_due() {
            to = due;
            w.advance(due, &mut ev);
        }
        w.advance(to + 1000, &mut ev);
        assert!(!w.busy());
        ev.iter()
            .filter_map(|e| match e {
                Event::Heard(h) => {
                    assert_eq!(h.endpoint, 1);
                    assert_eq!(h.drivers, 0b01);
                    Some((h.byte, h.error))
                }
                _ => None,
            })
            .collect()
    }

    fn l(baud: u32, parity: Parity) -> LineSettings {
        LineSettings::new(baud, 8, parity, 1)
    }

    #[test]
    fn at_the_lines_settings_it_reads_what_was_sent() {
        for line in [
            l(9600, Parity::Even),
            l(19_200, Parity::None),
            l(1200, Parity::Odd),
        ] {
            let got = heard(line, line, &REQUEST);
            let want: Vec<_> = REQUEST.iter().map(|&b| (b, None)).collect();
            assert_eq!(got, want, "{line}");
        }
    }

    #[test]
    fn without_parity_on_an_even_parity_line_the_bytes_are_right_and_some_stop_bits_low() {
        // 8N1 reads the parity bit as its stop bit: low (a framing error) for the bytes
        // with an even number of ones; the real stop bit then looks like idle.
        let got = heard(l(9600, Parity::Even), l(9600, Parity::None), &REQUEST);
        let want: Vec<_> = REQUEST
            .iter()
            .map(|&b| {
                let p = parity_bit(b, 8, Parity::Even).unwrap();
                (b, (!p).then_some(CharError::Framing))
            })
            .collect();
        assert_eq!(got, want);
        assert!(want.iter().any(|c| c.1.is_some()) && want.iter().any(|c| c.1.is_none()));
    }

    #[test]
    fn even_parity_on_an_odd_parity_line_sees_every_parity_bit_wrong() {
        let got = heard(l(9600, Parity::Odd), l(9600, Parity::Even), &REQUEST);
        assert_eq!(got.len(), REQUEST.len());
        for (&(b, e), &sent) in got.iter().zip(&REQUEST) {
            assert_eq!((b, e), (sent, Some(CharError::Parity)));
        }
    }

    #[test]
    fn at_another_baud_rate_it_reads_what_a_uart_would() {
        // Whole ratios put every edge on the one-sixteenth grid of the byte-string model,
        // so the two models must agree exactly.
        for own in [
            l(19_200, Parity::Even),
            l(4800, Parity::Even),
            l(38_400, Parity::None),
        ] {
            let line = l(9600, Parity::Even);
            let got = heard(line, own, &REQUEST);
            let want: Vec<_> = transcode(&REQUEST, &line, &own)
                .iter()
                .map(|c| (c.byte, c.error))
                .collect();
            assert_eq!(got, want, "{own}");
            let bytes: Vec<u8> = got.iter().map(|c| c.0).collect();
            assert_ne!(bytes, REQUEST, "{own}");
        }
    }

    #[test]
    fn the_others_hear_the_line_and_a_receiver_can_be_taken_back() {
        let line = l(9600, Parity::Even);
        let mut w = Wire::new(line, 3).unwrap();
        w.set_receiver(2, Some(l(19_200, Parity::Even))).unwrap();
        w.set_receiver(2, None).unwrap();
        assert_eq!(w.receiver(2), None);
        w.set_receiver(1, Some(l(19_200, Parity::Even))).unwrap();
        assert!(w.set_receiver(3, None).is_err());
        w.transmit(0, 0, &REQUEST).unwrap();
        let mut ev = Vec::new();
        w.advance(10_000, &mut ev);
        let chars = ev.iter().filter(|e| matches!(e, Event::Char(_))).count();
        let own = ev.iter().filter(|e| matches!(e, Event::Heard(_))).count();
        assert_eq!(chars, REQUEST.len());
        assert!(own > 0);
    }
}
