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

/// Writes straight to the process's stderr, past the test harness's output capture, so
/// that a SKIPPED line is seen in a normal `cargo test` run.
pub fn note(line: &str) {
    use std::io::Write;
    let _ = writeln!(std::io::stderr(), "{line}");
}

/// Reports a missing tool: panics when the environment variable `CI` is set (CI installs
/// every tool the tests use), otherwise prints `SKIPPED: <what>` and returns false so
/// that the test can return.
pub fn missing(what: &str) -> bool {
    if std::env::var_os("CI").is_some() {
        panic!("FAILED: {what} (CI is set, so a missing tool is an error)");
    }
    note(&format!("SKIPPED: {what}"));
    false
}
