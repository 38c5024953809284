//! Fuzz target: see `conformance::oracle::rtu_frame` for the laws it checks.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::oracle::rtu_frame(data);
});
