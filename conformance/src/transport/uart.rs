//! What a UART makes of characters sent at other line settings: the bit-level model the
//! simulator's pseudo-terminal uses to behave like a drive set to one line (so that a
//! master at a wrong baud rate, parity or stop-bit count gets garbage, as on a real bus).
//!
//! The sender puts each character on the line as start bit (0), data bits least
//! significant first, the parity bit if any, and its stop bits (1), characters back to
//! back, the line idle (1) after the last one. The receiver works like a 16550: it hunts
//! for a low level (sampling at 1/16 of its bit time), checks that the start bit is still
//! low half a bit later, samples each data bit, the parity bit and the first stop bit in
//! their middles, and hunts again from the end of that stop bit. A receiver checks only
//! its first stop bit, so 8N1 and 8N2 understand each other; a low stop bit is a framing
//! error (also a break), a wrong parity bit a parity error.
//!
//! Pure: no I/O, no panic on any input; the output is bounded ([`MAX_CHARS`]).

use crate::codec::timing::{LineSettings, Parity};

/// At most this many characters come out of one call, whatever the input (a fast
/// receiver reads many characters out of one slow character).
pub const MAX_CHARS: usize = 4096;

/// What went wrong with a received character.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum CharError {
    /// The parity bit did not match the data.
    Parity,
    /// The stop bit was low (wrong baud rate, wrong frame length, or a break).
    Framing,
}

/// One character as the receiver's UART read it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Received {
    /// The data bits read (the low `data_bits` of the byte).
    pub byte: u8,
    /// A parity or framing error, if any.
    pub error: Option<CharError>,
}

/// What the receiving side does with a character that has an error; Linux's serial
/// drivers and line discipline decide it from the termios input flags.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorPolicy {
    /// Dropped (IGNPAR; also what a drive's UART does: it discards the character).
    Drop,
    /// Replaced by a 00H byte (INPCK without IGNPAR and PARMRK).
    Zero,
    /// Marked as FFH 00H and the character (INPCK and PARMRK).
    Mark,
    /// Passed as read (INPCK off: the errors are not checked).
    Pass,
}

/// The parity bit of `byte`'s low `data_bits` bits, if the line has one.
pub(crate) fn parity_bit(byte: u8, data_bits: u8, parity: Parity) -> Option<bool> {
    let mask = if data_bits >= 8 {
        0xFF
    } else {
        (1u8 << data_bits) - 1
    };
    let ones = (byte & mask).count_ones();
    match parity {
        Parity::None => None,
        // The parity bit makes the number of ones even (even parity) or odd (odd parity).
        Parity::Even => Some(!ones.is_multiple_of(2)),
        Parity::Odd => Some(ones.is_multiple_of(2)),
    }
}

/// The bits of `bytes` on a line with `line` settings, one entry a bit time.
pub(crate) fn waveform(bytes: &[u8], line: &LineSettings) -> Vec<bool> {
    let data_bits = line.data_bits.clamp(5, 8);
    let mut bits = Vec::with_capacity(bytes.len() * 12);
    for &b in bytes {
        bits.push(false);
        for i in 0..data_bits {
            bits.push(b >> i & 1 == 1);
        }
        if let Some(p) = parity_bit(b, data_bits, line.parity) {
            bits.push(p);
        }
        bits.extend(std::iter::repeat_n(
            true,
            usize::from(line.stop_bits.max(1)),
        ));
    }
    bits
}

/// The characters a receiver set to `receiver` reads from `bytes` sent at `sender`,
/// characters back to back. Equal settings give the bytes back, without errors.
pub fn transcode(bytes: &[u8], sender: &LineSettings, receiver: &LineSettings) -> Vec<Received> {
    let bits = waveform(bytes, sender);
    let sender_bit = 1.0 / f64::from(sender.baud.max(1));
    let receiver_bit = 1.0 / f64::from(receiver.baud.max(1));
    let end = bits.len() as f64 * sender_bit;
    // The level at time t (seconds from the first start bit); idle (1) outside.
    let level = |t: f64| -> bool {
        if t < 0.0 || t >= end {
            return true;
        }
        // Sampling at exactly a bit boundary takes the later bit, as a clock slightly
        // slower than the sender's would.
        let i = (t / sender_bit + 1e-9) as usize;
        bits.get(i).copied().unwrap_or(true)
    };
    let data_bits = receiver.data_bits.clamp(5, 8);
    let step = receiver_bit / 16.0;
    let mut out = Vec::new();
    let mut t = 0.0;
    while t < end && out.len() < MAX_CHARS {
        if level(t) {
            t += step;
            continue;
        }
        // A low level: a start bit if it is still low in its middle.
        let start = t;
        if level(start + receiver_bit / 2.0) {
            t = start + receiver_bit / 2.0;
            continue;
        }
        let sample = |k: u32| level(start + receiver_bit * (f64::from(k) + 0.5));
        let mut byte = 0u8;
        for i in 0..u32::from(data_bits) {
            if sample(1 + i) {
                byte |= 1 << i;
            }
        }
        let mut k = 1 + u32::from(data_bits);
        let mut error = None;
        if let Some(expected) = parity_bit(byte, data_bits, receiver.parity) {
            if sample(k) != expected {
                error = Some(CharError::Parity);
            }
            k += 1;
        }
        if !sample(k) {
            error = Some(CharError::Framing);
        }
        out.push(Received { byte, error });
        // Hunt again from the end of the first stop bit.
        t = start + receiver_bit * f64::from(k + 1);
    }
    out
}

/// The bytes a receiver with `policy` delivers from `chars`.
pub fn deliver(chars: &[Received], policy: ErrorPolicy) -> Vec<u8> {
    let mut out = Vec::with_capacity(chars.len());
    for &c in chars {
        deliver_into(c, policy, &mut out);
    }
    out
}

/// What a receiver with `policy` delivers of one character, appended to `out`.
pub fn deliver_into(c: Received, policy: ErrorPolicy, out: &mut Vec<u8>) {
    match (c.error, policy) {
        (None, _) | (Some(_), ErrorPolicy::Pass) => out.push(c.byte),
        (Some(_), ErrorPolicy::Drop) => {}
        (Some(_), ErrorPolicy::Zero) => out.push(0),
        (Some(_), ErrorPolicy::Mark) => out.extend_from_slice(&[0xFF, 0x00, c.byte]),
    }
}

/// Whether two ends at `a` and `b` understand each other's characters: same baud rate,
/// data bits and parity (stop bits need not match: a receiver checks only the first).
pub fn compatible(a: &LineSettings, b: &LineSettings) -> bool {
    a.baud == b.baud && a.data_bits == b.data_bits && a.parity == b.parity
}

#[cfg(test)]
mod tests {
    use super::*;

    const REQUEST: [u8; 8] = [0x11, 0x03, 0x25, 0x2F, 0x00, 0x01, 0x7E, 0x9A];

    fn l(baud: u32, parity: Parity, stop: u8) -> LineSettings {
        LineSettings::new(baud, 8, parity, stop)
    }

    #[test]
    fn equal_settings_carry_every_byte() {
        for line in [
            l(9600, Parity::Even, 1),
            l(19200, Parity::Odd, 1),
            l(115_200, Parity::None, 2),
        ] {
            let all: Vec<u8> = (0..=255).collect();
            let got = transcode(&all, &line, &line);
            assert_eq!(deliver(&got, ErrorPolicy::Drop), all, "{line}");
            assert!(got.iter().all(|c| c.error.is_none()));
        }
    }

    #[test]
    fn a_receiver_checks_only_its_first_stop_bit() {
        let one = l(9600, Parity::None, 1);
        let two = l(9600, Parity::None, 2);
        for (s, r) in [(one, two), (two, one)] {
            let got = transcode(&REQUEST, &s, &r);
            assert_eq!(deliver(&got, ErrorPolicy::Drop), REQUEST, "{s} -> {r}");
        }
    }

    #[test]
    fn a_wrong_baud_rate_gives_other_bytes_and_framing_errors() {
        let device = l(19200, Parity::Odd, 1);
        for baud in [1200, 2400, 4800, 9600, 38_400, 57_600, 115_200] {
            let got = transcode(&REQUEST, &l(baud, Parity::Odd, 1), &device);
            let bytes = deliver(&got, ErrorPolicy::Pass);
            assert_ne!(bytes, REQUEST, "{baud}");
            assert!(got.iter().any(|c| c.error.is_some()), "{baud}: {got:02X?}");
        }
    }

    #[test]
    fn a_wrong_parity_is_a_parity_or_framing_error() {
        let device = l(9600, Parity::Even, 1);
        let got = transcode(&REQUEST, &l(9600, Parity::Odd, 1), &device);
        // Every character has the opposite parity bit.
        assert!(
            got.iter().all(|c| c.error == Some(CharError::Parity)),
            "{got:?}"
        );
        assert!(deliver(&got, ErrorPolicy::Drop).is_empty());
        assert_eq!(deliver(&got, ErrorPolicy::Zero), vec![0; REQUEST.len()]);
        // No parity into even parity: the parity bit is read where the stop bit was, and
        // the stop bit where the next start bit is.
        let got = transcode(&REQUEST, &l(9600, Parity::None, 1), &device);
        assert!(got.iter().any(|c| c.error == Some(CharError::Framing)));
    }

    #[test]
    fn parity_bits_follow_the_definition() {
        // 03H has two ones: even parity adds 0, odd parity adds 1.
        assert_eq!(parity_bit(0x03, 8, Parity::Even), Some(false));
        assert_eq!(parity_bit(0x03, 8, Parity::Odd), Some(true));
        assert_eq!(parity_bit(0x01, 8, Parity::Even), Some(true));
        assert_eq!(parity_bit(0x81, 7, Parity::Even), Some(true));
        assert_eq!(parity_bit(0x81, 8, Parity::None), None);
    }

    #[test]
    fn a_break_is_a_framing_error_and_output_is_bounded() {
        // 00H at 1200 baud read at 115200: long low runs, many characters, all bounded.
        let zeros = [0u8; 600];
        let got = transcode(
            &zeros,
            &l(1200, Parity::Even, 1),
            &l(115_200, Parity::None, 1),
        );
        assert!(got.len() <= MAX_CHARS);
        assert!(got.iter().any(|c| c.error == Some(CharError::Framing)));
        assert_eq!(
            deliver(&got[..1], ErrorPolicy::Mark).len(),
            if got[0].error.is_some() { 3 } else { 1 }
        );
    }

    #[test]
    fn compatibility_ignores_stop_bits_only() {
        assert!(compatible(
            &l(9600, Parity::None, 1),
            &l(9600, Parity::None, 2)
        ));
        assert!(!compatible(
            &l(9600, Parity::None, 1),
            &l(9600, Parity::Even, 1)
        ));
        assert!(!compatible(
            &l(9600, Parity::None, 1),
            &l(19200, Parity::None, 1)
        ));
    }
}
