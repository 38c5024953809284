//! Modbus TCP framing: the MBAP header (Modbus Application Protocol header) in front of a
//! PDU, as Modbus TCP gateways to RS-485 speak it on their Ethernet side.
//!
//! MODBUS Messaging on TCP/IP Implementation Guide V1.0b, 3.1.3 and 4.1: seven bytes,
//!
//! | bytes | field          | meaning                                                  |
//! |-------|----------------|----------------------------------------------------------|
//! | 0..2  | transaction id | chosen by the client, copied into the reply              |
//! | 2..4  | protocol id    | 0 for Modbus                                             |
//! | 4..6  | length         | bytes that follow: the unit id and the PDU               |
//! | 6     | unit id        | the serial node behind a gateway, copied into the reply  |
//!
//! then the PDU (function and data), without the serial line's address and checksum:
//! TCP carries its own. An ADU is at most 260 bytes (7 + a PDU of at most 253), so the
//! length field is 2..=254 ([`MAX_LENGTH`]); anything else is rejected from the header
//! alone, before a byte of the body is awaited, so no buffer is ever sized by it.
//!
//! As the RTU and ASCII codecs: [`MbapFrame`] is a view whose construction checks the
//! buffer so that accessors cannot panic, [`MbapRepr`] is the meaning (parse verifies,
//! emit writes), and [`frame_status`] is the streaming question "is a whole frame in
//! yet?" that says "need more" rather than guess.

use std::fmt;

use super::hex::Hex;

/// Field offsets, named once.
mod field {
    use std::ops::Range;
    pub const TRANSACTION: Range<usize> = 0..2;
    pub const PROTOCOL: Range<usize> = 2..4;
    pub const LENGTH: Range<usize> = 4..6;
    pub const UNIT: usize = 6;
    pub const PDU: usize = 7;
}

/// Length of the MBAP header: transaction, protocol, length, unit.
pub const HEADER_LEN: usize = 7;
/// Longest PDU: 253 bytes (the serial line's 256-byte frame less address and CRC).
pub const MAX_PDU: usize = 253;
/// Largest length field: the unit id and the longest PDU.
pub const MAX_LENGTH: u16 = 1 + MAX_PDU as u16;
/// Smallest length field: the unit id and a function code.
pub const MIN_LENGTH: u16 = 2;
/// Longest MBAP frame (ADU): 260 bytes.
pub const MAX_ADU: usize = HEADER_LEN + MAX_PDU;
/// The protocol id of Modbus.
pub const MODBUS_PROTOCOL: u16 = 0;

/// The header bytes an error is about (up to seven), printed in hex.
#[derive(Clone, Copy, PartialEq, Eq)]
pub struct HeaderBytes {
    bytes: [u8; HEADER_LEN],
    len: u8,
}

impl HeaderBytes {
    /// The first (up to seven) bytes of `buf`.
    pub fn of(buf: &[u8]) -> Self {
        let mut bytes = [0u8; HEADER_LEN];
        let n = buf.len().min(HEADER_LEN);
        bytes[..n].copy_from_slice(&buf[..n]);
        HeaderBytes {
            bytes,
            len: n as u8,
        }
    }

    /// The bytes.
    pub fn as_bytes(&self) -> &[u8] {
        &self.bytes[..usize::from(self.len)]
    }
}

impl fmt::Display for HeaderBytes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        Hex(self.as_bytes()).fmt(f)
    }
}

impl fmt::Debug for HeaderBytes {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "HeaderBytes({self})")
    }
}

/// Why bytes are not an MBAP frame, or a reply does not belong to its request. Every
/// message carries the header in hex.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum MbapError {
    /// Fewer than seven bytes where a whole header was needed.
    #[error("MBAP header truncated: {} bytes ({header}), need 7 (transaction, protocol, length, unit)", header.as_bytes().len())]
    Truncated {
        /// The bytes there were.
        header: HeaderBytes,
    },
    /// The protocol id is not 0.
    #[error("MBAP header {header}: protocol id {protocol:04X}H, Modbus is 0000H")]
    Protocol {
        /// The protocol id.
        protocol: u16,
        /// The header.
        header: HeaderBytes,
    },
    /// The length field is outside 2..=254.
    #[error("MBAP header {header}: length field {length} ({length:04X}H), must be 2..=254 (the unit id and a PDU of 1..=253 bytes)")]
    Length {
        /// The length field.
        length: u16,
        /// The header.
        header: HeaderBytes,
    },
    /// The buffer does not hold as many bytes as the length field says.
    #[error("MBAP header {header}: length field {length} says {expected} bytes in all, the frame has {actual}")]
    LengthMismatch {
        /// The length field.
        length: u16,
        /// Bytes the length field implies (six plus it).
        expected: usize,
        /// Bytes there are.
        actual: usize,
        /// The header.
        header: HeaderBytes,
    },
    /// A PDU that is empty or longer than 253 bytes cannot be sent.
    #[error("a PDU of {len} bytes cannot be framed: MBAP carries 1..=253")]
    PduLength {
        /// Bytes of the PDU.
        len: usize,
    },
    /// The caller's output buffer is too small.
    #[error("output buffer too small: {needed} bytes needed, {available} available")]
    BufferTooSmall {
        /// Bytes needed.
        needed: usize,
        /// Bytes available.
        available: usize,
    },
    /// A reply whose transaction id no request of this connection carried.
    #[error("MBAP reply header {header}: transaction id {got:04X}H, but the request waiting for a reply is {}; no request of this connection had {got:04X}H", match expected { Some(t) => format!("{t:04X}H"), None => "none".to_string() })]
    Transaction {
        /// The transaction id of the request waiting for its reply, if any.
        expected: Option<u16>,
        /// The transaction id of the reply.
        got: u16,
        /// The reply's header.
        header: HeaderBytes,
    },
    /// A reply to the right transaction but from another unit id.
    #[error(
        "MBAP reply header {header}: unit id {got:02X}H, the request went to unit {expected:02X}H"
    )]
    Unit {
        /// The request's unit id.
        expected: u8,
        /// The reply's unit id.
        got: u8,
        /// The reply's header.
        header: HeaderBytes,
    },
}

/// What the bytes at the start of a stream are so far.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Status {
    /// A whole frame of this many bytes (more may follow it).
    Complete(usize),
    /// The start of a frame: at least this many more bytes are needed.
    Partial(usize),
}

/// Whether `stream` starts with a whole MBAP frame. The header is judged as soon as its
/// protocol and length fields are in, so a wrong one is an error at once and no caller
/// waits for (or buffers) a body whose length comes from a bad header.
pub fn frame_status(stream: &[u8]) -> Result<Status, MbapError> {
    let have = stream.len();
    if have >= field::PROTOCOL.end {
        let protocol = word(stream, field::PROTOCOL);
        if protocol != MODBUS_PROTOCOL {
            return Err(MbapError::Protocol {
                protocol,
                header: HeaderBytes::of(stream),
            });
        }
    }
    if have < field::LENGTH.end {
        return Ok(Status::Partial(HEADER_LEN - have));
    }
    let length = word(stream, field::LENGTH);
    if !(MIN_LENGTH..=MAX_LENGTH).contains(&length) {
        return Err(MbapError::Length {
            length,
            header: HeaderBytes::of(stream),
        });
    }
    let total = field::LENGTH.end + usize::from(length);
    Ok(if have >= total {
        Status::Complete(total)
    } else {
        Status::Partial(total - have)
    })
}

fn word(b: &[u8], r: std::ops::Range<usize>) -> u16 {
    u16::from_be_bytes([b[r.start], b[r.start + 1]])
}

/// A view over the bytes of one MBAP frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MbapFrame<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> MbapFrame<T> {
    /// Wraps `buffer` without any check; accessors may panic on a short buffer. For
    /// building a frame in a buffer known to be long enough (see [`MbapRepr::emit`]).
    pub fn new_unchecked(buffer: T) -> Self {
        MbapFrame { buffer }
    }

    /// Wraps `buffer` after checking that it is exactly one frame: a whole header, the
    /// Modbus protocol id, a length field of 2..=254 that counts the bytes after it.
    pub fn new_checked(buffer: T) -> Result<Self, MbapError> {
        let b = buffer.as_ref();
        if b.len() < HEADER_LEN {
            return Err(MbapError::Truncated {
                header: HeaderBytes::of(b),
            });
        }
        match frame_status(b)? {
            Status::Complete(n) if n == b.len() => Ok(MbapFrame { buffer }),
            _ => {
                let length = word(b, field::LENGTH);
                Err(MbapError::LengthMismatch {
                    length,
                    expected: field::LENGTH.end + usize::from(length),
                    actual: b.len(),
                    header: HeaderBytes::of(b),
                })
            }
        }
    }

    /// All bytes of the frame.
    pub fn as_bytes(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    /// The transaction id.
    pub fn transaction(&self) -> u16 {
        word(self.as_bytes(), field::TRANSACTION)
    }

    /// The protocol id (0 for Modbus).
    pub fn protocol(&self) -> u16 {
        word(self.as_bytes(), field::PROTOCOL)
    }

    /// The length field: bytes after it (unit id and PDU).
    pub fn length(&self) -> u16 {
        word(self.as_bytes(), field::LENGTH)
    }

    /// The unit id.
    pub fn unit(&self) -> u8 {
        self.as_bytes()[field::UNIT]
    }

    /// The header, for messages.
    pub fn header(&self) -> HeaderBytes {
        HeaderBytes::of(self.as_bytes())
    }

    /// The PDU: function and data.
    pub fn pdu(&self) -> &[u8] {
        &self.as_bytes()[field::PDU..]
    }
}

impl<T: AsRef<[u8]> + AsMut<[u8]>> MbapFrame<T> {
    fn put_word(&mut self, r: std::ops::Range<usize>, v: u16) {
        self.buffer.as_mut()[r].copy_from_slice(&v.to_be_bytes());
    }

    /// Sets the transaction id.
    pub fn set_transaction(&mut self, v: u16) {
        self.put_word(field::TRANSACTION, v);
    }

    /// Sets the protocol id.
    pub fn set_protocol(&mut self, v: u16) {
        self.put_word(field::PROTOCOL, v);
    }

    /// Sets the length field.
    pub fn set_length(&mut self, v: u16) {
        self.put_word(field::LENGTH, v);
    }

    /// Sets the unit id.
    pub fn set_unit(&mut self, v: u8) {
        self.buffer.as_mut()[field::UNIT] = v;
    }

    /// The PDU, to write.
    pub fn pdu_mut(&mut self) -> &mut [u8] {
        &mut self.buffer.as_mut()[field::PDU..]
    }
}

impl<T: AsRef<[u8]>> fmt::Display for MbapFrame<T> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "MBAP transaction {:04X}H protocol {:04X}H length {} unit {:02X}H: {}",
            self.transaction(),
            self.protocol(),
            self.length(),
            self.unit(),
            Hex(self.pdu())
        )
    }
}

/// The meaning of an MBAP frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MbapRepr<'a> {
    /// The transaction id.
    pub transaction: u16,
    /// The unit id.
    pub unit: u8,
    /// The PDU: function and data (1..=253 bytes).
    pub pdu: &'a [u8],
}

impl<'a> MbapRepr<'a> {
    /// Parses a checked frame.
    pub fn parse(frame: &MbapFrame<&'a [u8]>) -> Result<Self, MbapError> {
        let b: &'a [u8] = frame.buffer;
        // new_checked guarantees it; a frame made unchecked is checked here.
        MbapFrame::new_checked(b)?;
        Ok(MbapRepr {
            transaction: frame.transaction(),
            unit: frame.unit(),
            pdu: &b[field::PDU..],
        })
    }

    /// Bytes of the frame.
    pub fn buffer_len(&self) -> usize {
        HEADER_LEN + self.pdu.len()
    }

    /// Writes the frame into the start of `out`; returns its length.
    pub fn emit(&self, out: &mut [u8]) -> Result<usize, MbapError> {
        if self.pdu.is_empty() || self.pdu.len() > MAX_PDU {
            return Err(MbapError::PduLength {
                len: self.pdu.len(),
            });
        }
        let n = self.buffer_len();
        if out.len() < n {
            return Err(MbapError::BufferTooSmall {
                needed: n,
                available: out.len(),
            });
        }
        let mut f = MbapFrame::new_unchecked(&mut out[..n]);
        f.set_transaction(self.transaction);
        f.set_protocol(MODBUS_PROTOCOL);
        f.set_length(1 + self.pdu.len() as u16);
        f.set_unit(self.unit);
        f.pdu_mut().copy_from_slice(self.pdu);
        Ok(n)
    }

    /// Whether the PDU is the exception reply of a gateway: 0AH (gateway path
    /// unavailable) or 0BH (gateway target device failed to respond), which a gateway
    /// sends in place of its serial device's reply (Modbus application protocol V1.1b3,
    /// 7). The code, if so.
    pub fn gateway_exception(&self) -> Option<u8> {
        match self.pdu {
            [f, code @ (GATEWAY_PATH_UNAVAILABLE | GATEWAY_TARGET_FAILED)] if f & 0x80 != 0 => {
                Some(*code)
            }
            _ => None,
        }
    }
}

impl fmt::Display for MbapRepr<'_> {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "MBAP transaction {:04X}H unit {:02X}H: {}",
            self.transaction,
            self.unit,
            Hex(self.pdu)
        )
    }
}

/// Exception 0AH: the gateway has no path to the target (misconfigured or overloaded).
pub const GATEWAY_PATH_UNAVAILABLE: u8 = 0x0A;
/// Exception 0BH: the gateway's target device did not respond.
pub const GATEWAY_TARGET_FAILED: u8 = 0x0B;

/// The name of a gateway exception code.
pub fn gateway_exception_name(code: u8) -> &'static str {
    match code {
        GATEWAY_PATH_UNAVAILABLE => "gateway path unavailable",
        GATEWAY_TARGET_FAILED => "gateway target device failed to respond",
        _ => "not a gateway exception",
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A read of one register at 2520H from unit 01H, transaction 0001H.
    static READ_REQUEST: [u8; 12] = [
        0x00, 0x01, 0x00, 0x00, 0x00, 0x06, 0x01, 0x03, 0x25, 0x20, 0x00, 0x01,
    ];
    /// Its reply: 0004H.
    static READ_REPLY: [u8; 11] = [
        0x00, 0x01, 0x00, 0x00, 0x00, 0x05, 0x01, 0x03, 0x02, 0x00, 0x04,
    ];
    /// A gateway's 0BH for an 03H request to unit 07H.
    static GATEWAY_0B: [u8; 9] = [0x12, 0x34, 0x00, 0x00, 0x00, 0x03, 0x07, 0x83, 0x0B];

    #[test]
    fn deconstruct() {
        let f = MbapFrame::new_checked(&READ_REQUEST[..]).unwrap();
        assert_eq!(f.transaction(), 1);
        assert_eq!(f.protocol(), 0);
        assert_eq!(f.length(), 6);
        assert_eq!(f.unit(), 1);
        assert_eq!(f.pdu(), &[0x03, 0x25, 0x20, 0x00, 0x01]);
        assert_eq!(
            f.to_string(),
            "MBAP transaction 0001H protocol 0000H length 6 unit 01H: 03 25 20 00 01"
        );
    }

    #[test]
    fn construct() {
        let mut buf = [0xFFu8; 11];
        let mut f = MbapFrame::new_unchecked(&mut buf[..]);
        f.set_transaction(1);
        f.set_protocol(0);
        f.set_length(5);
        f.set_unit(1);
        f.pdu_mut().copy_from_slice(&[0x03, 0x02, 0x00, 0x04]);
        assert_eq!(buf, READ_REPLY);
    }

    #[test]
    fn parse() {
        let r = MbapRepr::parse(&MbapFrame::new_checked(&READ_REPLY[..]).unwrap()).unwrap();
        assert_eq!(
            r,
            MbapRepr {
                transaction: 1,
                unit: 1,
                pdu: &[0x03, 0x02, 0x00, 0x04]
            }
        );
        assert_eq!(r.gateway_exception(), None);
        let g = MbapRepr::parse(&MbapFrame::new_checked(&GATEWAY_0B[..]).unwrap()).unwrap();
        assert_eq!(g.gateway_exception(), Some(GATEWAY_TARGET_FAILED));
        assert_eq!(g.to_string(), "MBAP transaction 1234H unit 07H: 83 0B");
        // 0BH without the exception bit is data, not a gateway's exception.
        let mut not = GATEWAY_0B;
        not[7] = 0x03;
        let n = MbapRepr::parse(&MbapFrame::new_checked(&not[..]).unwrap()).unwrap();
        assert_eq!(n.gateway_exception(), None);
    }

    #[test]
    fn emit() {
        let r = MbapRepr {
            transaction: 1,
            unit: 1,
            pdu: &[0x03, 0x25, 0x20, 0x00, 0x01],
        };
        assert_eq!(r.buffer_len(), READ_REQUEST.len());
        let mut out = [0u8; MAX_ADU];
        let n = r.emit(&mut out).unwrap();
        assert_eq!(&out[..n], &READ_REQUEST);
        assert_eq!(
            r.emit(&mut out[..5]),
            Err(MbapError::BufferTooSmall {
                needed: 12,
                available: 5
            })
        );
        let long = [0u8; MAX_PDU + 1];
        let too_long = MbapRepr { pdu: &long, ..r };
        assert_eq!(
            too_long.emit(&mut out),
            Err(MbapError::PduLength { len: 254 })
        );
        let longest = MbapRepr {
            pdu: &long[..MAX_PDU],
            ..r
        };
        assert_eq!(longest.emit(&mut out), Ok(MAX_ADU));
        assert_eq!(
            MbapFrame::new_checked(&out[..]).unwrap().length(),
            MAX_LENGTH
        );
        let empty = MbapRepr { pdu: &[], ..r };
        assert_eq!(empty.emit(&mut out), Err(MbapError::PduLength { len: 0 }));
    }

    #[test]
    fn a_truncated_header_is_an_error_with_its_bytes() {
        let e = MbapFrame::new_checked(&READ_REQUEST[..5]).unwrap_err();
        assert_eq!(
            e,
            MbapError::Truncated {
                header: HeaderBytes::of(&READ_REQUEST[..5])
            }
        );
        assert!(e.to_string().contains("5 bytes (00 01 00 00 00)"), "{e}");
        // Streaming: a truncated header is a partial frame, not an error.
        assert_eq!(frame_status(&READ_REQUEST[..5]), Ok(Status::Partial(2)));
        assert_eq!(frame_status(&[]), Ok(Status::Partial(7)));
    }

    #[test]
    fn a_protocol_id_other_than_0_is_rejected_as_soon_as_it_is_in() {
        let mut b = READ_REQUEST;
        b[3] = 0x01;
        let e = frame_status(&b[..4]).unwrap_err();
        assert!(matches!(e, MbapError::Protocol { protocol: 1, .. }));
        let e = MbapFrame::new_checked(&b[..]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "MBAP header 00 01 00 01 00 06 01: protocol id 0001H, Modbus is 0000H"
        );
    }

    #[test]
    fn a_length_field_out_of_bounds_is_rejected_from_the_header_alone() {
        // 0xFFFF bytes announced: rejected with six bytes in, nothing awaited.
        let e = frame_status(&[0, 1, 0, 0, 0xFF, 0xFF]).unwrap_err();
        assert_eq!(
            e.to_string(),
            "MBAP header 00 01 00 00 FF FF: length field 65535 (FFFFH), must be 2..=254 (the unit id and a PDU of 1..=253 bytes)"
        );
        // 255: one over the bound.
        assert!(matches!(
            frame_status(&[0, 1, 0, 0, 0, 255, 1]),
            Err(MbapError::Length { length: 255, .. })
        ));
        // 254 is the longest frame: a partial one, waiting for its 253-byte PDU.
        assert_eq!(
            frame_status(&[0, 1, 0, 0, 0, 254, 1]),
            Ok(Status::Partial(253))
        );
        // 0 and 1: no room for a function code.
        for l in [0u8, 1] {
            assert!(matches!(
                frame_status(&[0, 1, 0, 0, 0, l, 1]),
                Err(MbapError::Length { .. })
            ));
        }
    }

    #[test]
    fn a_length_that_disagrees_with_the_bytes_is_a_mismatch() {
        // One byte short of what the length says.
        let e = MbapFrame::new_checked(&READ_REQUEST[..11]).unwrap_err();
        assert_eq!(
            e,
            MbapError::LengthMismatch {
                length: 6,
                expected: 12,
                actual: 11,
                header: HeaderBytes::of(&READ_REQUEST),
            }
        );
        assert_eq!(
            e.to_string(),
            "MBAP header 00 01 00 00 00 06 01: length field 6 says 12 bytes in all, the frame has 11"
        );
        // One byte over: a whole frame and the start of the next is no frame.
        let mut long = READ_REQUEST.to_vec();
        long.push(0);
        assert!(matches!(
            MbapFrame::new_checked(&long[..]),
            Err(MbapError::LengthMismatch { actual: 13, .. })
        ));
        // In a stream, the same bytes are a whole frame and one to spare.
        assert_eq!(frame_status(&long), Ok(Status::Complete(12)));
    }

    #[test]
    fn reply_matching_errors_print_the_header() {
        let e = MbapError::Transaction {
            expected: Some(2),
            got: 0x1234,
            header: HeaderBytes::of(&GATEWAY_0B),
        };
        assert!(e.to_string().starts_with(
            "MBAP reply header 12 34 00 00 00 03 07: transaction id 1234H, but the request waiting for a reply is 0002H"
        ));
        let e = MbapError::Unit {
            expected: 1,
            got: 7,
            header: HeaderBytes::of(&GATEWAY_0B),
        };
        assert_eq!(
            e.to_string(),
            "MBAP reply header 12 34 00 00 00 03 07: unit id 07H, the request went to unit 01H"
        );
    }
}
