//! Fuzz target: see `conformance::oracle::ascii_deframer` for the laws it checks.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::oracle::ascii_deframer(data);
});
