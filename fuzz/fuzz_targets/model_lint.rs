//! Fuzz target: see `conformance::oracle::model_lint` for the laws it checks.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::oracle::model_lint(data);
});
