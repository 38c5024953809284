//! The codec: pure functions over bytes, no I/O.
//!
//! Layers, lowest first: [`crc`] and [`lrc`] (checksums), [`hex`] (the one hex codec),
//! [`pdu`] (typed messages), [`rtu`] and [`ascii`] (frames as views, decode and emit,
//! conversion), [`deframe`] (streaming), [`timing`] (serial-line intervals); [`mbap`] is the
//! Modbus TCP header a gateway puts in front of a PDU in place of address and checksum.
//!
//! Every function here is total: any input gives a value or a typed [`FrameError`], never
//! a panic, and nothing allocates in proportion to a length field read from the input.

pub mod ascii;
pub mod crc;
pub mod crc_clmul;
pub mod crc_table;
pub mod deframe;
pub mod direction;
pub mod error;
pub mod hex;
#[cfg(target_arch = "x86_64")]
mod hex_sse2;
pub mod lrc;
pub mod mbap;
pub mod pdu;
pub mod rtu;
pub mod timing;

pub use ascii::{ascii_to_rtu, decode_ascii, decode_ascii_unchecked, rtu_to_ascii, AsciiFrame};
pub use crc::{crc16, crc16_reference, CrcBytes};
pub use deframe::{AsciiDeframer, Event, RtuDeframer, RtuFraming};
pub use error::FrameError;
pub use lrc::lrc;
pub use pdu::{Direction, Message, Pdu, Registers};
pub use rtu::{decode_rtu, decode_rtu_unchecked, RtuFrame};

/// Longest RTU frame: 256 bytes (Modbus over Serial Line V1.02, 2.5.1).
pub const MAX_RTU_FRAME: usize = 256;
/// Longest ASCII frame: 513 characters (Modbus over Serial Line V1.02, 2.5.2.1).
pub const MAX_ASCII_FRAME: usize = 513;

/// Which framing a frame uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Mode {
    /// Binary with CRC-16.
    Rtu,
    /// Hex characters with LRC.
    Ascii,
}

impl Mode {
    /// The mode as files and check ids spell it (`rtu`, `ascii`: what `Display` writes);
    /// None for anything else.
    pub fn from_key(key: &str) -> Option<Mode> {
        match key {
            "rtu" => Some(Mode::Rtu),
            "ascii" => Some(Mode::Ascii),
            _ => None,
        }
    }
}

impl std::fmt::Display for Mode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Mode::Rtu => "rtu",
            Mode::Ascii => "ascii",
        })
    }
}

/// The checksum a frame carries and the one computed over its contents.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Checksum {
    /// RTU: CRC-16/MODBUS values (as numbers; on the wire low byte first).
    Crc {
        /// Carried by the frame.
        carried: u16,
        /// Computed over address, function and data.
        computed: u16,
    },
    /// ASCII: LRC values.
    Lrc {
        /// Carried by the frame.
        carried: u8,
        /// Computed over address, function and data.
        computed: u8,
    },
}

impl Checksum {
    /// Whether the carried checksum equals the computed one.
    pub fn is_valid(&self) -> bool {
        match *self {
            Checksum::Crc { carried, computed } => carried == computed,
            Checksum::Lrc { carried, computed } => carried == computed,
        }
    }

    /// `Ok` when valid, else the mismatch error.
    pub fn verify(&self) -> Result<(), FrameError> {
        match *self {
            Checksum::Crc { carried, computed } if carried != computed => {
                Err(FrameError::CrcMismatch { carried, computed })
            }
            Checksum::Lrc { carried, computed } if carried != computed => {
                Err(FrameError::LrcMismatch { carried, computed })
            }
            _ => Ok(()),
        }
    }
}

impl std::fmt::Display for Checksum {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match *self {
            Checksum::Crc { carried, computed } if carried == computed => {
                write!(f, "CRC {carried:04X} ok")
            }
            Checksum::Crc { carried, computed } => write!(
                f,
                "CRC mismatch: frame carries {carried:04X}, computed {computed:04X} (sent as {})",
                hex::Hex(&CrcBytes { value: computed }.wire())
            ),
            Checksum::Lrc { carried, computed } if carried == computed => {
                write!(f, "LRC {carried:02X} ok")
            }
            Checksum::Lrc { carried, computed } => {
                write!(
                    f,
                    "LRC mismatch: frame carries {carried:02X}, computed {computed:02X}"
                )
            }
        }
    }
}

/// A message decoded without rejecting its checksum, with the checksum's verdict.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Unchecked<'a> {
    /// The decoded message.
    pub message: Message<'a>,
    /// Carried and computed checksum.
    pub checksum: Checksum,
}

/// Decodes one frame in either mode, checked. `scratch` holds the binary form of an ASCII
/// frame (unused for RTU).
pub fn decode<'a>(
    mode: Mode,
    frame: &'a [u8],
    direction: Direction,
    scratch: &'a mut ascii::Scratch,
) -> Result<Message<'a>, FrameError> {
    match mode {
        Mode::Rtu => decode_rtu(frame, direction),
        Mode::Ascii => decode_ascii(frame, direction, scratch),
    }
}

/// Decodes one frame in either mode without rejecting its checksum.
pub fn decode_unchecked<'a>(
    mode: Mode,
    frame: &'a [u8],
    direction: Direction,
    scratch: &'a mut ascii::Scratch,
) -> Result<Unchecked<'a>, FrameError> {
    match mode {
        Mode::Rtu => decode_rtu_unchecked(frame, direction),
        Mode::Ascii => decode_ascii_unchecked(frame, direction, scratch),
    }
}

impl Message<'_> {
    /// Length of the frame of this message in `mode` (bytes in RTU, characters in ASCII).
    pub fn frame_len(&self, mode: Mode) -> usize {
        match mode {
            Mode::Rtu => self.rtu_len(),
            Mode::Ascii => self.ascii_len(),
        }
    }

    /// The frame of this message in `mode`, as a new vector.
    pub fn to_frame_vec(&self, mode: Mode) -> Result<Vec<u8>, FrameError> {
        match mode {
            Mode::Rtu => self.to_rtu_vec(),
            Mode::Ascii => self.to_ascii_vec(),
        }
    }
}

/// Address, function and data of a frame, with its checksum.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameParts {
    /// Address, function and data.
    pub body: Vec<u8>,
    /// Carried and computed checksum.
    pub checksum: Checksum,
}

/// Splits a complete frame into body and checksum, checking its framing (not its
/// checksum, nor its fields).
pub fn frame_parts(mode: Mode, bytes: &[u8]) -> Result<FrameParts, FrameError> {
    match mode {
        Mode::Rtu => {
            let f = rtu::RtuFrame::new_checked(bytes)?;
            Ok(FrameParts {
                body: f.body().to_vec(),
                checksum: f.checksum(),
            })
        }
        Mode::Ascii => {
            let f = ascii::AsciiFrame::new_checked(bytes)?;
            let mut scratch = [0u8; MAX_RTU_FRAME];
            Ok(FrameParts {
                body: f.body_into(&mut scratch).to_vec(),
                checksum: f.checksum(),
            })
        }
    }
}

/// Length of an 03H response carrying `n` registers: bytes in RTU, characters in ASCII.
pub fn read_response_len(mode: Mode, n: u16) -> usize {
    frame_len(mode, 3 + 2 * usize::from(n))
}

/// Length of a 10H request carrying `n` registers: bytes in RTU, characters in ASCII.
pub fn write_request_len(mode: Mode, n: u16) -> usize {
    frame_len(mode, 7 + 2 * usize::from(n))
}

/// Length of the frame of a body (address, function, data) of `body` bytes: two CRC bytes
/// in RTU; ':', two characters a byte and for the LRC, and CR LF in ASCII.
pub fn frame_len(mode: Mode, body: usize) -> usize {
    match mode {
        Mode::Rtu => body + 2,
        Mode::Ascii => 1 + 2 * (body + 1) + 2,
    }
}

/// The frame of a body (address, function, data) in `mode`, whatever the function: its
/// checksum computed, as emit writes it.
pub fn frame_of_body(mode: Mode, body: &[u8]) -> Result<Vec<u8>, FrameError> {
    match body {
        [address, function, data @ ..] => Message {
            address: *address,
            pdu: Pdu::Other {
                function: *function,
                data,
            },
        }
        .to_frame_vec(mode),
        _ => Err(FrameError::RtuTooShort {
            len: body.len() + 2,
        }),
    }
}

/// The same frame addressed to `address`, with its checksum computed anew.
pub fn readdressed(mode: Mode, frame: &[u8], address: u8) -> Result<Vec<u8>, FrameError> {
    let mut body = frame_parts(mode, frame)?.body;
    body[0] = address;
    frame_of_body(mode, &body)
}
