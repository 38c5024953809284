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

/// Prints `SKIPPED: <what>` and returns false when `ok` is false (panics under CI).
pub fn tool_or_skip(ok: bool, what: &str) -> bool {
    ok || missing(what)
}

/// Waits (at most 10 s) for a path to appear.
pub fn wait_for(p: &std::path::Path) {
    let t0 = std::time::Instant::now();
    while !p.exists() {
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(10),
            "{} did not appear",
            p.display()
        );
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
}

/// A socat pseudo-terminal pair linked at `dir/ttyA` and `dir/ttyB`: a line between a
/// device under test (on A) and the runner (on B).
pub fn socat_pair(dir: &std::path::Path) -> (Kill, std::path::PathBuf, std::path::PathBuf) {
    let (a, b) = (dir.join("ttyA"), dir.join("ttyB"));
    let socat = Kill(
        std::process::Command::new("socat")
            .arg(format!("pty,raw,echo=0,link={}", a.display()))
            .arg(format!("pty,raw,echo=0,link={}", b.display()))
            .stderr(std::process::Stdio::null())
            .spawn()
            .unwrap(),
    );
    wait_for(&a);
    wait_for(&b);
    (socat, a, b)
}

/// Runs `conformance check ARGS --format json -o dir/check.json` with a bound on its
/// time (a hang is a failure, not a stalled CI job), asserts it did not panic and that
/// the report matches its schema; returns the exit code and the report.
pub fn check_device(
    dir: &std::path::Path,
    args: &[&str],
    limit: std::time::Duration,
) -> (Option<i32>, serde_json::Value) {
    report_of("check", dir, args, limit)
}

/// Runs `conformance COMMAND ARGS --format json -o DIR/COMMAND.json` (check or fuzz),
/// bounded by `limit`, and returns its exit code and the report, checked against the
/// report schema.
pub fn report_of(
    command: &str,
    dir: &std::path::Path,
    args: &[&str],
    limit: std::time::Duration,
) -> (Option<i32>, serde_json::Value) {
    let report = dir.join(format!("{command}.json"));
    let t0 = std::time::Instant::now();
    let mut run = Kill(
        std::process::Command::new(bin())
            .arg(command)
            .args(args)
            .args(["--format", "json", "--quiet", "-o"])
            .arg(&report)
            .stdout(std::process::Stdio::null())
            .stderr(std::process::Stdio::piped())
            .spawn()
            .unwrap(),
    );
    let exit = loop {
        if let Some(s) = run.0.try_wait().unwrap() {
            break s;
        }
        assert!(t0.elapsed() < limit, "conformance {command} hangs");
        std::thread::sleep(std::time::Duration::from_millis(100));
    };
    let mut err = Vec::new();
    std::io::Read::read_to_end(run.0.stderr.as_mut().unwrap(), &mut err).unwrap();
    let stderr = String::from_utf8_lossy(&err);
    assert!(!stderr.contains("panicked"), "{stderr}");
    let out = std::fs::read(&report).unwrap();
    let v: serde_json::Value =
        serde_json::from_slice(&out).unwrap_or_else(|e| panic!("{e}: {stderr}"));
    let schema = jsonschema::validator_for(
        &serde_json::from_str(include_str!("../../../vectors/schema/report.schema.json")).unwrap(),
    )
    .unwrap();
    assert!(schema.is_valid(&v), "the report does not match its schema");
    (exit.code(), v)
}

/// Waits (at most 30 s) until a device on `port` answers the runner's preflight in `mode`
/// (a slow-starting server, such as pymodbus on a busy machine, is not a dead device).
pub fn wait_until_answers(port: &std::path::Path, mode: &str, line: &[&str]) {
    let t0 = std::time::Instant::now();
    loop {
        let o = std::process::Command::new(bin())
            .args(["check", "--model", "f510", "--mode", mode, "--port"])
            .arg(port)
            .args(line)
            .args(["--only", "identification", "--timeout", "300", "--quiet"])
            .output()
            .unwrap();
        if o.status.code() != Some(2) {
            return;
        }
        assert!(
            t0.elapsed() < std::time::Duration::from_secs(30),
            "the device on {} does not answer: {}",
            port.display(),
            String::from_utf8_lossy(&o.stdout)
        );
        std::thread::sleep(std::time::Duration::from_millis(200));
    }
}
