//! Fuzz target: see `conformance::monitor::fuzzing` for the laws it checks.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::monitor::fuzzing::line_search(data);
});
