//! Helpers shared by the integration tests that start the `conformance` binary or other
//! programs.
#![allow(dead_code)]

/// The `conformance` binary built for these tests.
pub fn bin() -> &'static str {
    env!("CARGO_BIN_EXE_conformance")
}

/// A child process that is killed and reaped when the guard goes, also when a test fails.
pub struct Kill(pub std::process::Child);

impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}
