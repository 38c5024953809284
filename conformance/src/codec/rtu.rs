//! RTU framing: address, function, data, CRC-16 (low byte first).
//!
//! [`RtuFrame`] is a zero-copy view that knows where each field is; [`decode_rtu`] and
//! [`Message::emit_rtu`] go between bytes and a typed [`Message`].

use super::crc::{crc16, crc16_frame_ok, CrcBytes};
use super::error::FrameError;
use super::pdu::{Direction, Message};
use super::{Checksum, Unchecked, MAX_RTU_FRAME};

/// Field offsets, named once.
mod field {
    pub const ADDRESS: usize = 0;
    pub const FUNCTION: usize = 1;
    pub const DATA_START: usize = 2;
    /// Length of the CRC at the end of the frame.
    pub const CRC_LEN: usize = 2;
}

/// Smallest RTU frame: address, function, two CRC bytes.
pub const MIN_RTU_FRAME: usize = 4;

/// A view over the bytes of one RTU frame. Construction checks the length, so accessors
/// cannot index out of bounds; the CRC is checked by [`verify_crc`](Self::verify_crc).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RtuFrame<T: AsRef<[u8]>> {
    buffer: T,
}

impl<T: AsRef<[u8]>> RtuFrame<T> {
    /// Wraps `buffer` after checking that its length is 4..=256 bytes.
    #[inline]
    pub fn new_checked(buffer: T) -> Result<Self, FrameError> {
        let len = buffer.as_ref().len();
        if len < MIN_RTU_FRAME {
            return Err(FrameError::RtuTooShort { len });
        }
        if len > MAX_RTU_FRAME {
            return Err(FrameError::RtuTooLong { len });
        }
        Ok(RtuFrame { buffer })
    }

    /// All bytes of the frame.
    #[inline]
    pub fn as_bytes(&self) -> &[u8] {
        self.buffer.as_ref()
    }

    /// Node address.
    pub fn address(&self) -> u8 {
        self.as_bytes()[field::ADDRESS]
    }

    /// Function byte.
    pub fn function(&self) -> u8 {
        self.as_bytes()[field::FUNCTION]
    }

    /// Address, function and data: what the CRC covers.
    #[inline]
    pub fn body(&self) -> &[u8] {
        let b = self.as_bytes();
        &b[..b.len() - field::CRC_LEN]
    }

    /// Data between function and CRC.
    pub fn data(&self) -> &[u8] {
        &self.body()[field::DATA_START..]
    }

    /// The CRC the frame carries.
    #[inline]
    pub fn carried_crc(&self) -> u16 {
        let b = self.as_bytes();
        CrcBytes::from_wire([b[b.len() - 2], b[b.len() - 1]]).value
    }

    /// The CRC of the frame's body.
    #[inline]
    pub fn computed_crc(&self) -> u16 {
        crc16(self.body())
    }

    /// The carried and computed CRC.
    pub fn checksum(&self) -> Checksum {
        Checksum::Crc {
            carried: self.carried_crc(),
            computed: self.computed_crc(),
        }
    }

    /// `Ok` when the carried CRC is right.
    pub fn verify_crc(&self) -> Result<(), FrameError> {
        self.checksum().verify()
    }
}

impl<'a> RtuFrame<&'a [u8]> {
    /// Address, function and data, borrowed for as long as the underlying bytes.
    #[inline]
    pub fn into_body(self) -> &'a [u8] {
        let b = self.buffer;
        &b[..b.len() - field::CRC_LEN]
    }
}

/// Decodes an RTU frame, checking its length, CRC and every count field.
#[inline(always)]
pub fn decode_rtu(frame: &[u8], direction: Direction) -> Result<Message<'_>, FrameError> {
    let view = RtuFrame::new_checked(frame)?;
    if !crc16_frame_ok(frame) {
        return Err(crc_mismatch(&view));
    }
    Message::parse_body(view.into_body(), direction)
}

/// The error of a frame whose CRC is wrong, with both values (out of the hot path).
#[cold]
#[inline(never)]
fn crc_mismatch(view: &RtuFrame<&[u8]>) -> FrameError {
    FrameError::CrcMismatch {
        carried: view.carried_crc(),
        computed: view.computed_crc(),
    }
}

/// Decodes an RTU frame without rejecting a wrong CRC: the message is returned with the
/// carried and computed CRC, so a frame such as a manual's misprinted example can be read
/// and explained. Length and count fields are still checked.
pub fn decode_rtu_unchecked(
    frame: &[u8],
    direction: Direction,
) -> Result<Unchecked<'_>, FrameError> {
    let view = RtuFrame::new_checked(frame)?;
    let checksum = view.checksum();
    let message = Message::parse_body(view.into_body(), direction)?;
    Ok(Unchecked { message, checksum })
}

impl Message<'_> {
    /// Length of the RTU frame of this message.
    pub fn rtu_len(&self) -> usize {
        self.body_len() + field::CRC_LEN
    }

    /// Writes the RTU frame (CRC computed) into `out`; returns its length.
    pub fn emit_rtu(&self, out: &mut [u8]) -> Result<usize, FrameError> {
        let n = self.rtu_len();
        if n > MAX_RTU_FRAME {
            return Err(FrameError::TooLongToEncode {
                needed: n,
                max: MAX_RTU_FRAME,
            });
        }
        if out.len() < n {
            return Err(FrameError::BufferTooSmall {
                needed: n,
                available: out.len(),
            });
        }
        let body = self.emit_body(out)?;
        let crc = CrcBytes::of(&out[..body]).wire();
        out[body..body + 2].copy_from_slice(&crc);
        Ok(n)
    }

    /// The RTU frame as a new vector (a convenience for tests and the command line).
    pub fn to_rtu_vec(&self) -> Result<Vec<u8>, FrameError> {
        let mut buf = [0u8; MAX_RTU_FRAME];
        let n = self.emit_rtu(&mut buf)?;
        Ok(buf[..n].to_vec())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::pdu::{Pdu, Registers};

    // Frames below are consistent examples printed in the manuals.
    /// F510 manual 1.0.3, 03H, RTU command message.
    static F510_READ_REQUEST: [u8; 8] = [0x01, 0x03, 0x01, 0x23, 0x00, 0x01, 0x74, 0x3C];
    /// A510 manual, 06H, RTU command message.
    static A510_WRITE_REQUEST: [u8; 8] = [0x01, 0x06, 0x25, 0x02, 0x17, 0x70, 0x2D, 0x12];

    #[test]
    fn deconstruct() {
        let f = RtuFrame::new_checked(&F510_READ_REQUEST[..]).unwrap();
        assert_eq!(f.address(), 0x01);
        assert_eq!(f.function(), 0x03);
        assert_eq!(f.data(), &[0x01, 0x23, 0x00, 0x01]);
        assert_eq!(f.carried_crc(), 0x3C74);
        assert_eq!(f.computed_crc(), 0x3C74);
        assert!(f.verify_crc().is_ok());
    }

    #[test]
    fn parse_and_emit_read_request() {
        let m = decode_rtu(&F510_READ_REQUEST, Direction::Request).unwrap();
        assert_eq!(
            m,
            Message {
                address: 1,
                pdu: Pdu::ReadRequest {
                    start: 0x0123,
                    count: 1
                }
            }
        );
        assert_eq!(m.to_rtu_vec().unwrap(), F510_READ_REQUEST);
    }

    #[test]
    fn parse_and_emit_write_single() {
        for dir in [Direction::Request, Direction::Response] {
            let m = decode_rtu(&A510_WRITE_REQUEST, dir).unwrap();
            assert_eq!(
                m.pdu,
                Pdu::WriteSingle {
                    register: 0x2502,
                    value: 0x1770
                }
            );
            assert_eq!(m.to_rtu_vec().unwrap(), A510_WRITE_REQUEST);
        }
    }

    #[test]
    fn read_response_with_wrong_crc_is_rejected_and_explained() {
        // F510 manual 1.0.3, 03H, RTU normal response as printed: CRC "AFH 82H".
        let printed = [0x01, 0x03, 0x02, 0x17, 0x70, 0xAF, 0x82];
        let err = decode_rtu(&printed, Direction::Response).unwrap_err();
        assert_eq!(
            err,
            FrameError::CrcMismatch {
                carried: 0x82AF,
                computed: 0x50B6
            }
        );
        assert_eq!(
            err.to_string(),
            "CRC mismatch: frame carries 82AF, computed 50B6"
        );
        let u = decode_rtu_unchecked(&printed, Direction::Response).unwrap();
        assert_eq!(
            u.message.pdu,
            Pdu::ReadResponse {
                values: Registers::new(&[0x17, 0x70]).unwrap()
            }
        );
        assert!(!u.checksum.is_valid());
        assert_eq!(
            u.message.to_rtu_vec().unwrap(),
            [0x01, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50]
        );
    }

    #[test]
    fn direction_changes_layout() {
        // 03 response for 2 registers is 9 bytes; read as a request its data is 5 bytes.
        let resp = Message {
            address: 1,
            pdu: Pdu::ReadResponse {
                values: Registers::new(&[0, 1, 0, 2]).unwrap(),
            },
        }
        .to_rtu_vec()
        .unwrap();
        assert!(decode_rtu(&resp, Direction::Response).is_ok());
        assert!(matches!(
            decode_rtu(&resp, Direction::Request),
            Err(FrameError::DataLength {
                function: 3,
                found: 5,
                ..
            })
        ));
    }

    /// The RTU bytes of `pdu` to `address`, after checking that they decode back to the
    /// same message in each of `directions`.
    fn round_trip(address: u8, pdu: Pdu<'_>, directions: &[Direction]) -> Vec<u8> {
        let message = Message { address, pdu };
        let bytes = message.to_rtu_vec().unwrap();
        for &d in directions {
            assert_eq!(decode_rtu(&bytes, d).unwrap(), message, "{d:?}");
        }
        bytes
    }

    #[test]
    fn write_multiple_both_directions() {
        let values = Registers::new(&[0x17, 0x70, 0x00, 0x00]).unwrap();
        let request = Pdu::WriteMultipleRequest {
            start: 0x2502,
            values,
        };
        let bytes = round_trip(1, request, &[Direction::Request]);
        assert_eq!(
            &bytes[..9],
            &[0x01, 0x10, 0x25, 0x02, 0x00, 0x02, 0x04, 0x17, 0x70]
        );
        let response = Pdu::WriteMultipleResponse {
            start: 0x2502,
            count: 2,
        };
        round_trip(1, response, &[Direction::Response]);
    }

    #[test]
    fn count_fields_are_checked() {
        // 10H request whose count (3) disagrees with its byte count (4).
        let mut f = vec![
            0x01, 0x10, 0x25, 0x02, 0x00, 0x03, 0x04, 0x17, 0x70, 0x00, 0x00,
        ];
        f.extend_from_slice(&CrcBytes::of(&f).wire());
        assert_eq!(
            decode_rtu(&f, Direction::Request).unwrap_err(),
            FrameError::CountMismatch {
                count: 3,
                byte_count: 4,
                expected: 6
            }
        );
        // 03 response whose byte count (4) exceeds the bytes present (2).
        let mut f = vec![0x01, 0x03, 0x04, 0x17, 0x70];
        f.extend_from_slice(&CrcBytes::of(&f).wire());
        assert!(matches!(
            decode_rtu(&f, Direction::Response).unwrap_err(),
            FrameError::ByteCount {
                byte_count: 4,
                found: 2,
                ..
            }
        ));
    }

    #[test]
    fn loop_back_and_exception_and_other() {
        let loop_back = Pdu::LoopBack {
            test_code: 0,
            data: &[0xA5, 0x37],
        };
        let bytes = round_trip(1, loop_back, &[Direction::Request, Direction::Response]);
        assert_eq!(bytes.len(), 8);

        let exception = Pdu::Exception {
            function: 3,
            code: 2,
        };
        let bytes = round_trip(2, exception, &[Direction::Response]);
        assert_eq!(&bytes[..3], &[0x02, 0x83, 0x02]);
        // In the request direction the same bytes are an unmodelled function 83H.
        assert_eq!(
            decode_rtu(&bytes, Direction::Request).unwrap().pdu,
            Pdu::Other {
                function: 0x83,
                data: &[0x02]
            }
        );

        let other = Message {
            address: 1,
            pdu: Pdu::Other {
                function: 0x2B,
                data: &[0x0E, 1, 0],
            },
        };
        let bytes = other.to_rtu_vec().unwrap();
        assert_eq!(decode_rtu(&bytes, Direction::Response).unwrap(), other);
    }

    #[test]
    fn lengths_are_bounded() {
        assert_eq!(
            decode_rtu(&[1, 3, 0], Direction::Request).unwrap_err(),
            FrameError::RtuTooShort { len: 3 }
        );
        assert_eq!(
            decode_rtu(&[0; 257], Direction::Request).unwrap_err(),
            FrameError::RtuTooLong { len: 257 }
        );
        let big = [0u8; 254];
        let m = Message {
            address: 1,
            pdu: Pdu::Other {
                function: 0x41,
                data: &big,
            },
        };
        assert_eq!(
            m.to_rtu_vec().unwrap_err(),
            FrameError::TooLongToEncode {
                needed: 258,
                max: 256
            }
        );
    }

    #[test]
    fn a_read_request_and_a_write_multiple_response_show_the_same_fields() {
        let fields = |pdu| Message { address: 1, pdu }.fields();
        assert_eq!(
            fields(Pdu::ReadRequest {
                start: 0x2502,
                count: 2
            }),
            [
                ("address", "01".to_string()),
                ("function", "03 read holding registers request".to_string()),
                ("start", "2502".to_string()),
                ("count", "2".to_string()),
            ]
        );
        assert_eq!(
            fields(Pdu::WriteMultipleResponse {
                start: 0x2502,
                count: 2
            })[2..],
            [("start", "2502".to_string()), ("count", "2".to_string())]
        );
    }
}
