//! Fuzz target: see `conformance::gate::master::fuzzing` for the laws it checks.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::gate::master::fuzzing::judge_any(data);
});
