//! Owned messages, for the generators that cannot build the codec's borrowed ones, and
//! the law that what is encoded decodes to itself.

use super::with_scratch;
use crate::codec::{
    ascii_to_rtu, decode_ascii, decode_rtu, rtu_to_ascii, Direction, Message, MAX_ASCII_FRAME,
};

/// An owned message, for generators (proptest, `arbitrary`) that cannot build the codec's
/// borrowed [`Message`](crate::codec::Message) directly.
#[derive(Debug, Clone, PartialEq, Eq, arbitrary::Arbitrary)]
pub enum OwnedPdu {
    /// 03H request.
    ReadRequest(u16, u16),
    /// 03H response.
    ReadResponse(Vec<u16>),
    /// 06H request or response.
    WriteSingle(u16, u16),
    /// 08H loop-back: test code and data.
    LoopBack(u16, Vec<u8>),
    /// 10H request.
    WriteMultipleRequest(u16, Vec<u16>),
    /// 10H response.
    WriteMultipleResponse(u16, u16),
    /// Exception: function (without 80H) and code.
    Exception(u8, u8),
    /// Unmodelled function and data.
    Other(u8, Vec<u8>),
}

/// An owned message: address and PDU, plus the wire bytes its borrowed form points into.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct OwnedMessage {
    /// Node address.
    pub address: u8,
    /// The PDU.
    pub pdu: OwnedPdu,
    bytes: Vec<u8>,
}

impl OwnedMessage {
    /// Makes `pdu` fit `direction` and one frame: lengths are cut to what a 256-byte frame
    /// holds, an exception's function loses its 80H bit, an unmodelled function code that
    /// the direction would read as a modelled layout or an exception becomes 41H. Returns
    /// `None` for a layout that does not exist in `direction`.
    pub fn new(address: u8, pdu: OwnedPdu, direction: Direction) -> Option<OwnedMessage> {
        let pdu = match (direction, pdu) {
            (Direction::Request, OwnedPdu::ReadRequest(s, c)) => OwnedPdu::ReadRequest(s, c),
            (Direction::Response, OwnedPdu::ReadResponse(mut v)) => {
                v.truncate(125);
                OwnedPdu::ReadResponse(v)
            }
            (_, OwnedPdu::WriteSingle(r, v)) => OwnedPdu::WriteSingle(r, v),
            (_, OwnedPdu::LoopBack(t, mut d)) => {
                d.truncate(250);
                OwnedPdu::LoopBack(t, d)
            }
            (Direction::Request, OwnedPdu::WriteMultipleRequest(s, mut v)) => {
                v.truncate(123);
                OwnedPdu::WriteMultipleRequest(s, v)
            }
            (Direction::Response, OwnedPdu::WriteMultipleResponse(s, c)) => {
                OwnedPdu::WriteMultipleResponse(s, c)
            }
            (Direction::Response, OwnedPdu::Exception(f, c)) => OwnedPdu::Exception(f & 0x7F, c),
            (_, OwnedPdu::Other(f, mut d)) => {
                d.truncate(252);
                let modelled = [0x03, 0x06, 0x08, 0x10].contains(&f)
                    || (direction == Direction::Response && f & 0x80 != 0);
                OwnedPdu::Other(if modelled { 0x41 } else { f }, d)
            }
            _ => return None,
        };
        let bytes = match &pdu {
            OwnedPdu::ReadResponse(v) | OwnedPdu::WriteMultipleRequest(_, v) => {
                v.iter().flat_map(|x| x.to_be_bytes()).collect()
            }
            OwnedPdu::LoopBack(_, d) | OwnedPdu::Other(_, d) => d.clone(),
            _ => Vec::new(),
        };
        Some(OwnedMessage {
            address,
            pdu,
            bytes,
        })
    }

    /// The codec's borrowed message.
    pub fn message(&self) -> crate::codec::Message<'_> {
        use crate::codec::{Pdu, Registers};
        // `bytes` holds whole registers for the register variants (built in `new`).
        let regs = || Registers::new(&self.bytes).unwrap_or_else(|_| unreachable!());
        let pdu = match self.pdu {
            OwnedPdu::ReadRequest(start, count) => Pdu::ReadRequest { start, count },
            OwnedPdu::ReadResponse(_) => Pdu::ReadResponse { values: regs() },
            OwnedPdu::WriteSingle(register, value) => Pdu::WriteSingle { register, value },
            OwnedPdu::LoopBack(test_code, _) => Pdu::LoopBack {
                test_code,
                data: &self.bytes,
            },
            OwnedPdu::WriteMultipleRequest(start, _) => Pdu::WriteMultipleRequest {
                start,
                values: regs(),
            },
            OwnedPdu::WriteMultipleResponse(start, count) => {
                Pdu::WriteMultipleResponse { start, count }
            }
            OwnedPdu::Exception(function, code) => Pdu::Exception { function, code },
            OwnedPdu::Other(function, _) => Pdu::Other {
                function,
                data: &self.bytes,
            },
        };
        crate::codec::Message {
            address: self.address,
            pdu,
        }
    }
}

/// Round trip in both modes: emit, parse back, require equality; the ASCII and RTU forms
/// decode to the same message and convert into each other.
pub fn roundtrip(m: &OwnedMessage, direction: Direction) {
    let msg = m.message();
    with_scratch(|s| {
        let nr = msg
            .emit_rtu(&mut s.rtu)
            .expect("an OwnedMessage always fits a frame");
        let na = msg.emit_ascii(&mut s.ascii).expect("and an ASCII frame");
        let (rtu, ascii) = (&s.rtu[..nr], &s.ascii[..na]);
        assert_eq!(decode_rtu(rtu, direction).expect("RTU parses back"), msg);
        assert_eq!(
            decode_ascii(ascii, direction, &mut s.rtu2).expect("ASCII parses back"),
            msg
        );
        let n = rtu_to_ascii(rtu, &mut s.ascii2).expect("RTU converts");
        assert_eq!(&s.ascii2[..n], ascii);
        let k = ascii_to_rtu(ascii, &mut s.rtu3).expect("ASCII converts");
        assert_eq!(&s.rtu3[..k], rtu);
    });
}

/// [`roundtrip`] on a message built from raw fuzz bytes with `arbitrary` (as libFuzzer's
/// structured targets do), so crash inputs replay as plain bytes.
pub fn roundtrip_bytes(data: &[u8]) {
    use arbitrary::Arbitrary;
    let u = arbitrary::Unstructured::new(data);
    let Ok((address, response, pdu)) = <(u8, bool, OwnedPdu)>::arbitrary_take_rest(u) else {
        return;
    };
    let direction = if response {
        Direction::Response
    } else {
        Direction::Request
    };
    too_long_is_refused(address, &pdu);
    if let Some(m) = OwnedMessage::new(address, pdu, direction) {
        roundtrip(&m, direction);
    }
}

/// A message longer than a frame (before [`OwnedMessage::new`] cuts it) is refused by every
/// emitter with `TooLongToEncode`, never cut or wrapped.
fn too_long_is_refused(address: u8, pdu: &OwnedPdu) {
    use crate::codec::pdu::{Pdu, Registers};
    use crate::codec::FrameError;
    let too_long =
        |r: Result<usize, FrameError>| matches!(r, Err(FrameError::TooLongToEncode { .. }));
    let registers: Vec<u8>;
    let p = match pdu {
        OwnedPdu::LoopBack(_, d) | OwnedPdu::Other(_, d) if d.len() > 252 => Pdu::Other {
            function: 0x41,
            data: d,
        },
        OwnedPdu::ReadResponse(v) | OwnedPdu::WriteMultipleRequest(_, v) if v.len() > 127 => {
            registers = v.iter().flat_map(|x| x.to_be_bytes()).collect();
            let values = Registers::new(&registers).expect("whole registers");
            if matches!(pdu, OwnedPdu::ReadResponse(_)) {
                Pdu::ReadResponse { values }
            } else {
                Pdu::WriteMultipleRequest { start: 0, values }
            }
        }
        _ => return,
    };
    let m = Message { address, pdu: p };
    let mut out = vec![0u8; 2 * MAX_ASCII_FRAME];
    assert!(
        too_long(m.emit_rtu(&mut out)),
        "RTU emits a message over a frame"
    );
    assert!(
        too_long(m.emit_ascii(&mut out)),
        "ASCII emits a message over a frame"
    );
    assert!(too_long(m.emit_body(&mut out)), "a body over a frame");
    if !matches!(m.pdu, Pdu::Other { .. }) {
        // A byte count over 255 cannot be written.
        // A buffer that holds the data: a register list can be longer than any frame buffer.
        let mut data = vec![0u8; m.pdu.data_len()];
        assert!(
            too_long(m.pdu.emit_data(&mut data)),
            "data over a byte count"
        );
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn messages_over_a_frame_are_refused() {
        too_long_is_refused(1, &OwnedPdu::Other(0x41, vec![0; 253]));
        too_long_is_refused(1, &OwnedPdu::LoopBack(0, vec![0; 300]));
        too_long_is_refused(1, &OwnedPdu::ReadResponse(vec![0; 128]));
        too_long_is_refused(1, &OwnedPdu::WriteMultipleRequest(0, vec![0; 200]));
    }
}
