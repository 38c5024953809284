//! Structure-aware fuzz target: an arbitrary message (built with `arbitrary`) is emitted
//! in RTU and ASCII, parsed back and converted both ways
//! (`conformance::oracle::roundtrip_bytes`).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::oracle::roundtrip_bytes(data);
});
