//! The runner against a device that nobody here wrote: pymodbus's serial server, set up as
//! a generic holding-register device (no TECO registers, no TECO exception rules), on a
//! pseudo-terminal pair made by socat, checked as an F510. The run must complete, report
//! the deviations a generic device has from the F510 manual, and neither panic nor hang.

mod common;
use common::{bin, Kill};

use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

fn tool_or_skip(ok: bool, what: &str) -> bool {
    if ok {
        return true;
    }
    let msg = format!("SKIPPED: {what}");
    assert!(std::env::var_os("CI").is_none(), "{msg}");
    eprintln!("{msg}");
    false
}

fn wait_for(p: &Path) {
    let t0 = Instant::now();
    while !p.exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "{} did not appear",
            p.display()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

fn run(mode: &str) {
    let socat = Command::new("socat")
        .arg("-V")
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if !tool_or_skip(socat, "socat not installed (apt-get install socat)") {
        return;
    }
    let pymodbus = Command::new("python3")
        .args(["-c", "import pymodbus, serial"])
        .status()
        .is_ok_and(|s| s.success());
    if !tool_or_skip(
        pymodbus,
        "pymodbus not installed (pip install 'pymodbus[serial]==3.16.1')",
    ) {
        return;
    }
    let dir = std::env::temp_dir().join(format!("teco-generic-{mode}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let (a, b): (PathBuf, PathBuf) = (dir.join("ttyA"), dir.join("ttyB"));
    let _socat = Kill(
        Command::new("socat")
            .arg(format!("pty,raw,echo=0,link={}", a.display()))
            .arg(format!("pty,raw,echo=0,link={}", b.display()))
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    wait_for(&a);
    wait_for(&b);
    let server = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/interop/pymodbus_server.py"
    );
    let _server = Kill(
        Command::new("python3")
            .args([server, a.to_str().unwrap(), mode])
            .stderr(Stdio::null())
            .spawn()
            .unwrap(),
    );
    std::thread::sleep(Duration::from_millis(1500));
    let t0 = Instant::now();
    let mut check = Kill(
        Command::new(bin())
            .args([
                "check",
                "--model",
                "f510",
                "--port",
                b.to_str().unwrap(),
                "--mode",
                mode,
                "-P",
                "none",
            ])
            .args(["--timeout", "300", "--format", "json", "--quiet", "-o"])
            .arg(dir.join("report.json"))
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .unwrap(),
    );
    // Bounded: a hang is a failure, not a stalled CI job.
    let status = loop {
        if let Some(s) = check.0.try_wait().unwrap() {
            break s;
        }
        assert!(t0.elapsed() < Duration::from_secs(180), "the runner hangs");
        std::thread::sleep(Duration::from_millis(100));
    };
    let out = std::fs::read(dir.join("report.json")).unwrap();
    let mut err = Vec::new();
    std::io::Read::read_to_end(check.0.stderr.as_mut().unwrap(), &mut err).unwrap();
    let stderr = String::from_utf8_lossy(&err);
    assert!(!stderr.contains("panicked"), "{stderr}");
    let v: serde_json::Value =
        serde_json::from_slice(&out).unwrap_or_else(|e| panic!("{e}: {stderr}"));
    let schema = jsonschema::validator_for(
        &serde_json::from_str(include_str!("../../vectors/schema/report.schema.json")).unwrap(),
    )
    .unwrap();
    assert!(schema.is_valid(&v));
    assert_eq!(v["complete"], true, "{}", v["stopped"]);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    let deviations = v["summary"]["deviation"].as_u64().unwrap();
    assert!(
        deviations > 10,
        "a generic device cannot behave like a TECO drive: {}",
        v["summary"]
    );
    assert_eq!(status.code(), Some(1));
    // The device answers plain reads: the runner talked to it.
    assert!(
        v["summary"]["pass"].as_u64().unwrap() > 10,
        "{}",
        v["summary"]
    );
    eprintln!("{mode}: {} in {:?}", v["summary"], t0.elapsed());
    let _ = std::fs::remove_dir_all(&dir);
}

#[test]
fn a_generic_pymodbus_device_checked_as_f510_rtu() {
    run("rtu");
}

#[test]
fn a_generic_pymodbus_device_checked_as_f510_ascii() {
    run("ascii");
}
