//! Fuzz target: see `conformance::gate::fuzzing` for the laws it checks.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    conformance::gate::fuzzing::adapter_protocol(data);
});
