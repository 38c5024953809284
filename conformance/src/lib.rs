//! Conformance and fuzz test suite for the Modbus serial protocol (RTU and ASCII) of the
//! TECO F510, A510, L510 and E510 AC drives.
//!
//! Layers, lowest first; a lower layer never uses a higher one:
//! - [`codec`]: CRC, LRC, frames, messages, streaming deframers. Pure, no I/O.
//! - [`vectors`]: the manuals' example frames as golden vectors (data under `vectors/`),
//!   checked by the codec.
// `unsafe` is allowed in one module only: codec::crc_clmul (SIMD intrinsics).
#![deny(unsafe_code)]
#![warn(missing_docs)]

pub mod codec;
pub mod oracle;
pub mod vectors;
