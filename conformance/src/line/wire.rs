//! The pair of wires itself, bit by bit: who drives it when, what level it carries, and
//! what a receiver reads from it. Pure (no I/O, no clock): time is a bit index on the
//! line's bit clock, so every schedule and its damage are reproducible in a unit test.
//!
//! Each endpoint transmits through its own UART with a FIFO: the characters it writes go
//! out back to back from the moment they reach the line (or from the end of its previous
//! character), start bit, data bits least significant first, parity, stop bits
//! ([`crate::transport::uart::waveform`]). Nothing listens before talking, as on RS-485.
//! The line's level at a bit is the wired-AND of every driver's level (idle is 1), then
//! the noise, if any, flips it. One receiver (every listener hears the same pair) reads
//! the level as a UART does at bit resolution: a low level in idle is a start bit; the
//! data, the parity and the first stop bit are the following bits; a low stop bit is a
//! framing error, a wrong parity bit a parity error; then it hunts again. An endpoint
//! can be given its own receiver at other settings ([`Wire::set_receiver`]): it reads the
//! same level on its own bit clock ([`super::own_rx`]), as the UART of a listener set to
//! another baud rate or parity does, and what it reads is its alone ([`Event::Heard`]).

use std::collections::VecDeque;

use crate::codec::timing::{LineSettings, Parity};
use crate::rng::Rng;
use crate::transport::uart::waveform;

use super::own_rx::OwnRx;
use super::signal::read_char;
pub use super::signal::{
    Collision, Drivers, Event, Flip, Heard, LineChar, COLLISION_KEEP, MAX_ENDPOINTS,
};
use super::LineError;

#[derive(Debug, Clone, Copy)]
struct Char {
    start: u64,
    byte: u8,
    // Level at offset k from the start bit in bit k.
    frame: u16,
}

#[derive(Debug, Default)]
struct Sender {
    queue: VecDeque<Char>,
    free_at: u64,
}

#[derive(Debug)]
struct Rx {
    start: u64,
    sampled: u16,
    drivers: Drivers,
    multi: bool,
    flipped: bool,
}

#[derive(Debug)]
struct Open {
    start: u64,
    end: Option<u64>,
    endpoints: Drivers,
    chars: u64,
    line: Vec<u8>,
}

#[derive(Debug)]
struct Noise {
    threshold: u64,
    rng: Rng,
}

/// An emulated RS-485 pair with its endpoints' transmitters and one receiver.
#[derive(Debug)]
pub struct Wire {
    line: LineSettings,
    bits_per_char: u64,
    rx_len: u64,
    senders: Vec<Sender>,
    cur: u64,
    rx: Option<Rx>,
    open: Option<Open>,
    noise: Option<Noise>,
    own: Vec<Option<OwnRx>>,
}

impl Wire {
    /// A quiet line at `line` with `endpoints` transmitters (at most [`MAX_ENDPOINTS`]).
    pub fn new(line: LineSettings, endpoints: usize) -> Result<Self, LineError> {
        if endpoints > MAX_ENDPOINTS {
            return Err(LineError::TooManyEndpoints {
                asked: endpoints,
                max: MAX_ENDPOINTS,
            });
        }
        let data_bits = line.data_bits.clamp(5, 8);
        let line = LineSettings { data_bits, ..line };
        Ok(Wire {
            line,
            bits_per_char: u64::from(line.bits_per_char()),
            rx_len: 2 + u64::from(data_bits) + u64::from(line.parity != Parity::None),
            senders: (0..endpoints).map(|_| Sender::default()).collect(),
            cur: 0,
            rx: None,
            open: None,
            noise: None,
            own: (0..endpoints).map(|_| None).collect(),
        })
    }

    /// Flips each driven bit with probability `rate` (0..=1), drawn from `seed`. An idle
    /// line is not disturbed: its fail-safe bias holds it at 1.
    pub fn with_noise(mut self, rate: f64, seed: u64) -> Result<Self, LineError> {
        if !(0.0..=1.0).contains(&rate) {
            return Err(LineError::NoiseRate(rate));
        }
        self.noise = (rate > 0.0).then(|| Noise {
            // rate * 2^64, saturated: a draw below it flips.
            threshold: if rate >= 1.0 {
                u64::MAX
            } else {
                (rate * 18_446_744_073_709_551_616.0) as u64
            },
            rng: Rng::new(seed),
        });
        Ok(self)
    }

    /// The line settings (data bits clamped to 5..=8).
    pub fn line(&self) -> LineSettings {
        self.line
    }

    /// Bits from one start bit to the next, characters back to back.
    pub fn bits_per_char(&self) -> u64 {
        self.bits_per_char
    }

    /// Gives `endpoint` a receiver of its own at `line` (None: it hears the line's
    /// receiver, at the line's settings), starting from the present: a character it was
    /// in the middle of is lost, as when a program sets its port.
    pub fn set_receiver(
        &mut self,
        endpoint: usize,
        line: Option<LineSettings>,
    ) -> Result<(), LineError> {
        let count = self.own.len();
        let baud = self.line.baud;
        let cur = self.cur;
        let slot = self
            .own
            .get_mut(endpoint)
            .ok_or(LineError::NoSuchEndpoint { endpoint, count })?;
        *slot = line.map(|l| OwnRx::new(endpoint, l, baud, cur));
        Ok(())
    }

    /// The settings of `endpoint`'s own receiver, if it has one.
    pub fn receiver(&self, endpoint: usize) -> Option<LineSettings> {
        self.own.get(endpoint)?.as_ref().map(|r| r.line())
    }

    /// Bits before this one are decided: nothing written now can start before it.
    pub fn now(&self) -> u64 {
        self.cur
    }

    /// Puts `bytes` from `endpoint` on the line, the first at bit `at` (or when its
    /// transmitter is free, or the line's present, whichever is latest), the rest back to
    /// back; returns each character's start bit.
    pub fn transmit(
        &mut self,
        endpoint: usize,
        at: u64,
        bytes: &[u8],
    ) -> Result<Vec<u64>, LineError> {
        let count = self.senders.len();
        let line = self.line;
        let bpc = self.bits_per_char;
        let cur = self.cur;
        let s = self
            .senders
            .get_mut(endpoint)
            .ok_or(LineError::NoSuchEndpoint { endpoint, count })?;
        let mut starts = Vec::with_capacity(bytes.len());
        for &byte in bytes {
            let start = at.max(s.free_at).max(cur);
            let frame = waveform(&[byte], &line)
                .iter()
                .enumerate()
                .fold(0u16, |f, (k, &b)| f | (u16::from(b) << k));
            s.queue.push_back(Char { start, byte, frame });
            s.free_at = start + bpc;
            starts.push(start);
        }
        Ok(starts)
    }

    /// When the next character can be read off the line (a bit index after
    /// [`Wire::now`]), or None while nothing is on it or queued.
    pub fn next_due(&self) -> Option<u64> {
        let due = match &self.rx {
            Some(r) => Some(r.start + self.rx_len),
            None => self
                .senders
                .iter()
                .filter_map(|s| s.queue.front().map(|c| c.start + self.rx_len))
                .min(),
        };
        let own = self.own.iter().flatten().filter_map(|r| r.due()).min();
        due.into_iter()
            .chain(own)
            .min()
            .map(|d| d.max(self.cur + 1))
    }

    /// Whether anything is on the line or queued for it.
    pub fn busy(&self) -> bool {
        self.rx.is_some()
            || self.open.is_some()
            || self.senders.iter().any(|s| !s.queue.is_empty())
            || self.own.iter().flatten().any(|r| r.reading())
    }

    /// Runs the line up to bit `to` (exclusive), pushing what happened onto `out`.
    pub fn advance(&mut self, to: u64, out: &mut Vec<Event>) {
        let bpc = self.bits_per_char;
        while self.cur < to {
            let b = self.cur;
            let mut level = true;
            let mut drivers: Drivers = 0;
            let mut count = 0u32;
            let mut lowest: Option<(u8, u8)> = None;
            let mut next_start = u64::MAX;
            for (i, s) in self.senders.iter_mut().enumerate() {
                while s.queue.front().is_some_and(|c| c.start + bpc <= b) {
                    s.queue.pop_front();
                }
                if let Some(c) = s.queue.front() {
                    if c.start <= b {
                        let off = b - c.start;
                        level &= c.frame >> off & 1 == 1;
                        drivers |= 1 << i;
                        count += 1;
                        lowest.get_or_insert((c.byte, off as u8));
                    } else {
                        next_start = next_start.min(c.start);
                    }
                }
            }
            if count == 0 && self.rx.is_none() {
                if let Some(o) = self.open.as_mut() {
                    o.end.get_or_insert(b);
                }
                self.close_collision(out);
                // Idle: nothing happens until the next character starts.
                let next = next_start.min(to);
                for r in self.own.iter_mut().flatten() {
                    r.idle(next, out);
                }
                self.cur = next;
                continue;
            }
            let mut flipped = false;
            if let (Some(n), Some((byte, bit))) = (self.noise.as_mut(), lowest) {
                if n.rng.next_u64() < n.threshold {
                    level = !level;
                    flipped = true;
                    out.push(Event::Flip(Flip {
                        at: b,
                        drivers,
                        byte,
                        bit,
                    }));
                }
            }
            if count >= 2 {
                let o = self.open.get_or_insert(Open {
                    start: b,
                    end: None,
                    endpoints: 0,
                    chars: 0,
                    line: Vec::new(),
                });
                o.end = None;
                o.endpoints |= drivers;
            } else if let Some(o) = self.open.as_mut() {
                o.end.get_or_insert(b);
            }
            for r in self.own.iter_mut().flatten() {
                r.bit(b, level, drivers, count >= 2, flipped, out);
            }
            self.receive(b, level, drivers, count >= 2, flipped, out);
            self.cur = b + 1;
        }
        // Characters whose last bit has gone are off the queues.
        let cur = self.cur;
        for s in &mut self.senders {
            while s.queue.front().is_some_and(|c| c.start + bpc <= cur) {
                s.queue.pop_front();
            }
        }
    }

    fn receive(
        &mut self,
        b: u64,
        level: bool,
        drivers: Drivers,
        multi: bool,
        flipped: bool,
        out: &mut Vec<Event>,
    ) {
        let Some(r) = self.rx.as_mut() else {
            if !level {
                self.rx = Some(Rx {
                    start: b,
                    sampled: 0,
                    drivers,
                    multi,
                    flipped,
                });
            }
            return;
        };
        let off = b - r.start;
        r.sampled |= u16::from(level) << off;
        r.drivers |= drivers;
        r.multi |= multi;
        r.flipped |= flipped;
        if off + 1 < self.rx_len {
            return;
        }
        let (byte, error) = read_char(r.sampled, &self.line);
        let c = LineChar {
            start: r.start,
            end: b + 1,
            byte,
            error,
            drivers: r.drivers,
            damaged: r.multi || r.flipped || error.is_some(),
            collided: r.multi,
        };
        if r.multi {
            if let Some(o) = self.open.as_mut() {
                o.chars += 1;
                if o.line.len() < COLLISION_KEEP {
                    o.line.push(byte);
                }
            }
        }
        self.rx = None;
        out.push(Event::Char(c));
        self.close_collision(out);
    }

    /// Reports the collision once the overlap is over and its last character read.
    fn close_collision(&mut self, out: &mut Vec<Event>) {
        if self.rx.is_some() {
            return;
        }
        let Some(end) = self.open.as_ref().and_then(|o| o.end) else {
            return;
        };
        if let Some(o) = self.open.take() {
            out.push(Event::Collision(Collision {
                start: o.start,
                end,
                endpoints: o.endpoints,
                chars: o.chars,
                line: o.line,
            }));
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const REQUEST: [u8; 8] = [0x01, 0x03, 0x25, 0x2F, 0x00, 0x01, 0x7E, 0xC3];

    fn l8e1() -> LineSettings {
        LineSettings::new(9600, 8, Parity::Even, 1)
    }

    fn run(w: &mut Wire, to: u64) -> Vec<Event> {
        let mut out = Vec::new();
        w.advance(to, &mut out);
        out
    }

    /// The events of an 8E1 wire of `endpoints` on which each `(endpoint, at bit, bytes)`
    /// is sent, run to bit `to`.
    fn sent(endpoints: usize, sends: &[(usize, u64, &[u8])], to: u64) -> Vec<Event> {
        let mut w = Wire::new(l8e1(), endpoints).unwrap();
        for &(from, at, bytes) in sends {
            w.transmit(from, at, bytes).unwrap();
        }
        run(&mut w, to)
    }

    fn chars(events: &[Event]) -> Vec<&LineChar> {
        events
            .iter()
            .filter_map(|e| match e {
                Event::Char(c) => Some(c),
                _ => None,
            })
            .collect()
    }

    #[test]
    fn one_sender_is_read_whole_at_the_character_rate() {
        for line in [
            l8e1(),
            LineSettings::new(19_200, 8, Parity::None, 2),
            LineSettings::new(9600, 7, Parity::Odd, 1),
        ] {
            let mut w = Wire::new(line, 3).unwrap();
            let starts = w.transmit(1, 100, &REQUEST).unwrap();
            let bpc = u64::from(line.bits_per_char());
            assert!(starts.windows(2).all(|p| p[1] - p[0] == bpc), "{starts:?}");
            let ev = run(&mut w, 100 + 20 * bpc);
            let got = chars(&ev);
            let want: Vec<u8> = REQUEST
                .iter()
                .map(|b| if line.data_bits == 7 { b & 0x7F } else { *b })
                .collect();
            assert_eq!(got.iter().map(|c| c.byte).collect::<Vec<_>>(), want);
            assert!(
                got.iter().all(|c| !c.damaged && c.drivers == 0b10),
                "{got:?}"
            );
            assert_eq!(
                got.iter().map(|c| c.start).collect::<Vec<_>>(),
                starts,
                "read where they were sent"
            );
            assert!(!w.busy());
        }
    }

    #[test]
    fn a_second_write_queues_behind_the_first_and_a_late_one_leaves_a_gap() {
        let mut w = Wire::new(l8e1(), 2).unwrap();
        let a = w.transmit(0, 0, &[1, 2]).unwrap();
        let b = w.transmit(0, 5, &[3]).unwrap();
        assert_eq!((a, b), (vec![0, 11], vec![22]));
        run(&mut w, 100);
        assert_eq!(
            w.transmit(0, 50, &[4]).unwrap(),
            vec![100],
            "not in the past"
        );
    }

    #[test]
    fn nothing_is_read_before_its_last_bit_is_in() {
        let mut w = Wire::new(l8e1(), 2).unwrap();
        w.transmit(0, 0, &[0x55]).unwrap();
        // 8E1: start, 8 data, parity, stop: handed over after bit 10.
        assert_eq!(w.next_due(), Some(11));
        assert!(chars(&run(&mut w, 10)).is_empty());
        assert_eq!(chars(&run(&mut w, 11)).len(), 1);
        assert_eq!(w.next_due(), None);
    }

    #[test]
    fn two_writers_at_once_collide_and_the_line_is_their_wired_and() {
        let ev = sent(3, &[(0, 0, &[0x55, 0x0F]), (1, 0, &[0xAA, 0xF0])], 200);
        let got = chars(&ev);
        // Aligned, the AND of the data is 00H; the parity bits AND to 0 too (both even).
        assert_eq!(got.iter().map(|c| c.byte).collect::<Vec<_>>(), [0, 0]);
        assert!(got.iter().all(|c| c.damaged && c.drivers == 0b11));
        let col: Vec<_> = ev
            .iter()
            .filter_map(|e| match e {
                Event::Collision(c) => Some(c),
                _ => None,
            })
            .collect();
        assert_eq!(col.len(), 1, "{ev:?}");
        assert_eq!(
            (col[0].start, col[0].end, col[0].endpoints, col[0].chars),
            (0, 22, 0b11, 2)
        );
        assert_eq!(col[0].line, [0, 0]);
    }

    #[test]
    fn a_write_into_a_transmission_damages_its_tail_only() {
        // Endpoint 2 starts in the middle of the fifth character, off its bit grid.
        let late: &[u8] = &[0x01, 0x06, 0x25, 0x02];
        let ev = sent(3, &[(0, 0, &REQUEST), (2, 4 * 11 + 3, late)], 400);
        let got = chars(&ev);
        assert_eq!(
            got[..4].iter().map(|c| c.byte).collect::<Vec<_>>(),
            REQUEST[..4],
            "before the overlap the line is clean"
        );
        assert!(got[..4].iter().all(|c| !c.damaged && c.drivers == 1));
        assert!(got[4..].iter().any(|c| c.damaged));
        let bytes: Vec<u8> = got.iter().map(|c| c.byte).collect();
        assert_ne!(bytes, REQUEST);
        let col = ev
            .iter()
            .find_map(|e| match e {
                Event::Collision(c) => Some(c.clone()),
                _ => None,
            })
            .unwrap();
        assert_eq!(col.start, 47);
        assert_eq!(col.endpoints, 0b101);
        assert!(col.chars >= 3, "{col:?}");
    }

    #[test]
    fn one_sender_after_another_is_no_collision() {
        let ev = sent(2, &[(0, 0, &[1, 2]), (1, 22, &[3, 4])], 100);
        assert!(!ev.iter().any(|e| matches!(e, Event::Collision(_))));
        assert_eq!(
            chars(&ev).iter().map(|c| c.byte).collect::<Vec<_>>(),
            [1, 2, 3, 4]
        );
    }

    #[test]
    fn noise_is_reproducible_by_seed_and_leaves_an_idle_line_alone() {
        let flips = |seed: u64| {
            let mut w = Wire::new(l8e1(), 2)
                .unwrap()
                .with_noise(0.05, seed)
                .unwrap();
            let mut ev = Vec::new();
            for k in 0..10u64 {
                w.transmit(0, k * 1000, &REQUEST).unwrap();
                w.advance((k + 1) * 1000, &mut ev);
            }
            ev
        };
        let a = flips(7);
        assert_eq!(a, flips(7));
        assert_ne!(a, flips(8));
        let n = a.iter().filter(|e| matches!(e, Event::Flip(_))).count();
        // 880 driven bits at 5%: about 44.
        assert!((15..100).contains(&n), "{n}");
        // Flips fall on driven bits only: within a character of some frame.
        for e in &a {
            if let Event::Flip(f) = e {
                assert!(f.at % 1000 < 88 && f.bit < 11, "{f:?}");
            }
        }
        assert!(Wire::new(l8e1(), 2).unwrap().with_noise(1.5, 0).is_err());
        assert!(Wire::new(l8e1(), 65).is_err());
    }

    #[test]
    fn noise_at_rate_one_flips_every_driven_bit() {
        let mut w = Wire::new(l8e1(), 2).unwrap().with_noise(1.0, 0).unwrap();
        w.transmit(0, 0, &[0x00]).unwrap();
        let ev = run(&mut w, 30);
        // Every driven bit flips: the start bit reads idle, nothing starts until the
        // stop bit, flipped to 0, looks like a start bit.
        assert!(ev.iter().filter(|e| matches!(e, Event::Flip(_))).count() == 11);
        assert!(chars(&ev).iter().all(|c| c.damaged));
    }
}
