//! Fuzz target: see `conformance::oracle::capture_reader` for the laws it checks.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::oracle::capture_reader(data);
});
