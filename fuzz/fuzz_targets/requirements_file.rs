//! Fuzz target: see `conformance::requirements::fuzzing` for the laws it checks.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::requirements::fuzzing::requirements_file(data);
});
