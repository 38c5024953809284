//! RTU frames a test writes onto a bus it plays or into a capture it makes, built by the
//! codec (so their CRC is the codec's).

use conformance::codec::pdu::{Message, Pdu, Registers};
use conformance::codec::Mode;

/// The RTU frame of `pdu` at `address`.
pub fn frame(address: u8, pdu: Pdu<'_>) -> Vec<u8> {
    Message { address, pdu }.to_frame_vec(Mode::Rtu).unwrap()
}

/// A 03H read of `count` registers from `start`.
pub fn read(address: u8, start: u16, count: u16) -> Vec<u8> {
    frame(address, Pdu::ReadRequest { start, count })
}

/// A 03H reply carrying `v`.
pub fn values(address: u8, v: &[u16]) -> Vec<u8> {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_be_bytes()).collect();
    frame(
        address,
        Pdu::ReadResponse {
            values: Registers::new(&bytes).unwrap(),
        },
    )
}

/// The exception reply `code` to `function`.
pub fn exception(address: u8, function: u8, code: u8) -> Vec<u8> {
    frame(address, Pdu::Exception { function, code })
}

/// A 06H write of `value` to `register` (and its echo).
pub fn write(address: u8, register: u16, value: u16) -> Vec<u8> {
    frame(address, Pdu::WriteSingle { register, value })
}
