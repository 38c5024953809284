//! Fuzz target: see `conformance::expect::fuzzing` for the laws it checks.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::expect::fuzzing::expectations_file(data);
});
