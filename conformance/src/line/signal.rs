//! What the wire carries and what its receivers report, shared by the wire
//! ([`super::wire`]) and the endpoints' own receivers ([`super::own_rx`]): the
//! characters read, collisions, flipped bits, and how a UART reads one character from
//! the levels it sampled.

use crate::codec::timing::{LineSettings, Parity};
use crate::transport::uart::{parity_bit, CharError};

/// Most endpoints a line carries (each is one bit of a driver mask).
pub const MAX_ENDPOINTS: usize = 64;

/// Most line characters a collision record keeps (the count goes on).
pub const COLLISION_KEEP: usize = 256;

/// A set of endpoints, one bit each (bit i: endpoint i).
pub type Drivers = u64;

/// One character as the receiver read it from the line.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct LineChar {
    /// Bit index of its start bit.
    pub start: u64,
    /// Bit index just after its first stop bit (when a UART hands it over).
    pub end: u64,
    /// The data bits read.
    pub byte: u8,
    /// A parity or framing error.
    pub error: Option<CharError>,
    /// Who drove the line during it: they do not hear it (their receivers are off while
    /// they transmit), unless they echo.
    pub drivers: Drivers,
    /// Whether it was read from a collision or a flipped bit, or with an error: not
    /// necessarily what anyone sent.
    pub damaged: bool,
    /// Whether two endpoints drove the line during it.
    pub collided: bool,
}

/// One character as an endpoint's own receiver ([`Wire::set_receiver`]) read it: for
/// that endpoint only.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Heard {
    /// The endpoint.
    pub endpoint: usize,
    /// The line bit in which its start bit began.
    pub start: u64,
    /// The data bits read.
    pub byte: u8,
    /// A parity or framing error.
    pub error: Option<CharError>,
    /// Who drove the line during it.
    pub drivers: Drivers,
    /// Read from a collision or a flipped bit, or with an error.
    pub damaged: bool,
}

/// Two or more endpoints drove the line at once.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Collision {
    /// Bit index of the first bit driven by two.
    pub start: u64,
    /// Bit index after the last bit driven by two.
    pub end: u64,
    /// Every endpoint that drove during it.
    pub endpoints: Drivers,
    /// Characters the receiver read with a bit driven by two.
    pub chars: u64,
    /// The first [`COLLISION_KEEP`] of them, as the listeners got them.
    pub line: Vec<u8>,
}

/// The noise flipped one bit.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Flip {
    /// Bit index on the line.
    pub at: u64,
    /// Who drove it.
    pub drivers: Drivers,
    /// The lowest driver's character: what it sent and which of its bits (0: start bit).
    pub byte: u8,
    /// Which bit of that character (0: the start bit).
    pub bit: u8,
}

/// The character in `sampled` (bit k: the level sampled at bit k of the character,
/// from its start bit to its first stop bit) at `line`'s settings: its data bits, and
/// a parity error or (a low stop bit) a framing error.
pub(super) fn read_char(sampled: u16, line: &LineSettings) -> (u8, Option<CharError>) {
    let data_bits = line.data_bits;
    let mask = if data_bits >= 8 {
        0xFF
    } else {
        (1u16 << data_bits) - 1
    };
    let byte = (sampled >> 1 & mask) as u8;
    let mut error = None;
    if let Some(p) = parity_bit(byte, data_bits, line.parity) {
        if (sampled >> (1 + data_bits) & 1 == 1) != p {
            error = Some(CharError::Parity);
        }
    }
    let stop = 1 + u32::from(data_bits) + u32::from(line.parity != Parity::None);
    if sampled >> stop & 1 == 0 {
        error = Some(CharError::Framing);
    }
    (byte, error)
}

/// What the line did, in bit order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Event {
    /// A character read (deliver it to every endpoint not among its drivers that has no
    /// receiver of its own).
    Char(LineChar),
    /// A character an endpoint's own receiver read.
    Heard(Heard),
    /// A collision ended (reported once its last character is read).
    Collision(Collision),
    /// A bit flipped by the noise.
    Flip(Flip),
}
