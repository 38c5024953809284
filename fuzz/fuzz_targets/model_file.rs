//! Fuzz target: see `conformance::model::fuzzing` for the laws it checks.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::model::fuzzing::model_file(data);
});
