//! The codec's error type.

use super::direction::Direction;
use super::hex::Hex;

/// Why bytes are not a valid frame, or a message cannot be encoded.
///
/// Every message says what was expected and what was found; checksums and bytes are in hex.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FrameError {
    /// Fewer than four bytes: no room for address, function and CRC.
    #[error("RTU frame too short: {len} bytes, need at least 4 (address, function, 2 CRC bytes)")]
    RtuTooShort {
        /// Bytes given.
        len: usize,
    },
    /// More than 256 bytes (Modbus over Serial Line, 2.5.1).
    #[error("RTU frame too long: {len} bytes, at most 256")]
    RtuTooLong {
        /// Bytes given.
        len: usize,
    },
    /// The CRC carried by the frame is not the CRC of its contents.
    #[error("CRC mismatch: frame carries {carried:04X}, computed {computed:04X}")]
    CrcMismatch {
        /// The CRC value the frame carries (its last two bytes, low byte first).
        carried: u16,
        /// The CRC computed over address, function and data.
        computed: u16,
    },
    /// Fewer than nine characters: ':', address, function, LRC, CR LF.
    #[error("ASCII frame too short: {len} characters, need at least 9 (':' + address, function, LRC as hex + CR LF)")]
    AsciiTooShort {
        /// Characters given.
        len: usize,
    },
    /// More than 513 characters (Modbus over Serial Line, 2.5.2.1).
    #[error("ASCII frame too long: {len} characters, at most 513")]
    AsciiTooLong {
        /// Characters given.
        len: usize,
    },
    /// The first character is not ':'.
    #[error("ASCII frame must start with ':' (3A), found {found:02X}")]
    AsciiNoStart {
        /// The first byte.
        found: u8,
    },
    /// The frame does not end with CR LF.
    #[error("ASCII frame must end with CR LF (0D 0A), found {}", Hex(found))]
    AsciiNoEnd {
        /// The last two bytes.
        found: [u8; 2],
    },
    /// An odd number of characters between ':' and CR LF.
    #[error(
        "ASCII frame has {count} characters between ':' and CR LF; hex pairs need an even number"
    )]
    AsciiOddLength {
        /// Characters between the delimiters.
        count: usize,
    },
    /// A character between ':' and CR LF that is not a hex digit.
    #[error("ASCII frame has non-hex character {found:02X} at offset {offset}")]
    AsciiBadChar {
        /// The offending byte.
        found: u8,
        /// Its offset from the start of the frame (the ':' is offset 0).
        offset: usize,
    },
    /// The LRC carried by the frame is not the LRC of its contents.
    #[error("LRC mismatch: frame carries {carried:02X}, computed {computed:02X}")]
    LrcMismatch {
        /// The LRC the frame carries.
        carried: u8,
        /// The LRC computed over address, function and data.
        computed: u8,
    },
    /// The data of a modelled function has the wrong length.
    #[error("function {function:02X} {direction}: data must be {expected} bytes, found {found}")]
    DataLength {
        /// Function code.
        function: u8,
        /// Direction the frame was parsed in.
        direction: Direction,
        /// Required data length, as a phrase ("4", "at least 5").
        expected: &'static str,
        /// Data bytes present.
        found: usize,
    },
    /// A byte-count field disagrees with the bytes that follow it.
    #[error("function {function:02X} {direction}: byte count field is {byte_count:02X} ({byte_count}), but {found} data bytes follow it")]
    ByteCount {
        /// Function code.
        function: u8,
        /// Direction the frame was parsed in.
        direction: Direction,
        /// The byte-count field.
        byte_count: u8,
        /// Bytes that follow the field.
        found: usize,
    },
    /// A register count disagrees with the byte count (10H request).
    #[error("function 10 request: register count {count:04X} ({count}) needs byte count {expected}, field is {byte_count:02X} ({byte_count})")]
    CountMismatch {
        /// The register-count field.
        count: u16,
        /// The byte-count field.
        byte_count: u8,
        /// Twice the register count.
        expected: u32,
    },
    /// Register data is two bytes a register.
    #[error("register data must be an even number of bytes, found {len}")]
    OddRegisterBytes {
        /// Bytes given.
        len: usize,
    },
    /// An exception response's code field is missing or followed by more bytes.
    #[error("exception response {function:02X}: must carry exactly 1 exception-code byte, found {found}")]
    ExceptionLength {
        /// The function byte (with 80H set).
        function: u8,
        /// Data bytes present.
        found: usize,
    },
    /// The message is too long for one frame (a byte-count field holds at most 255, an
    /// RTU frame at most 256 bytes).
    #[error("message needs a {needed}-byte RTU frame; at most {max}")]
    TooLongToEncode {
        /// Bytes the RTU frame would need.
        needed: usize,
        /// The limit.
        max: usize,
    },
    /// The caller's output buffer is too small.
    #[error("output buffer too small: {needed} bytes needed, {available} available")]
    BufferTooSmall {
        /// Bytes needed.
        needed: usize,
        /// Bytes available.
        available: usize,
    },
}
