//! Fuzz target: see `conformance::oracle::crc_differential` for the laws it checks (every
//! CRC path this CPU can run, forced, against the manuals' bitwise reference).
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::oracle::crc_differential(data);
});
