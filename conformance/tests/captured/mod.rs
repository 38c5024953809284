//! What the capture tests share (tests/capture.rs, tests/capture_sim_bus.rs): a `check`
//! run captured, the packets of a capture, tshark's reading of one, and `monitor
//! --capture-in`'s.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use std::sync::OnceLock;

use conformance::capture::{Direction, Reader};
use serde_json::Value;

use super::common::{self, Run, Scratch, TSHARK_USER_DLT as USER_DLT};

/// The folder of this binary's runs (kept for the process: the whole run's capture is
/// read by several tests).
pub fn dir() -> &'static Path {
    static DIR: OnceLock<Scratch> = OnceLock::new();
    DIR.get_or_init(|| Scratch::new("runs"))
}

/// A run of `check --sim f510 --mode MODE` with `extra` arguments, captured: the
/// capture's path and the JSON report.
pub fn captured_check(name: &str, mode: &str, extra: &[&str]) -> (PathBuf, Value) {
    let (cap, out, report) = captured(
        name,
        Run::words("check --sim f510 --mode")
            .arg(mode)
            .arg("--quiet")
            .args(extra),
    );
    let stderr = out.stderr.as_str();
    assert!(stderr.contains("capture: "), "{stderr}");
    // Exit 0, or 2 where only this host stalled sending a request (an ERROR, never
    // judged: a busy machine), with no deviation either way.
    assert_eq!(report["summary"]["deviation"], 0, "{stderr}");
    errors_are_host_stalls(&report);
    assert!(matches!(out.code, Some(0 | 2)), "{stderr}");
    (cap, report)
}

/// `run` (a `check`) captured to `name`.pcapng with its JSON report `name`.json in
/// [`dir`]: the capture's path, what the run left, and the report.
pub fn captured(name: &str, run: Run) -> (PathBuf, common::Ran, Value) {
    let d = dir();
    let cap = d.join(format!("{name}.pcapng"));
    let json = d.join(format!("{name}.json"));
    let out = run
        .arg("--capture")
        .arg(&cap)
        .args(["--format", "json", "-o"])
        .arg(&json)
        .run();
    let report: Value = serde_json::from_str(
        &std::fs::read_to_string(&json).unwrap_or_else(|e| panic!("{e}: {out}")),
    )
    .unwrap();
    (cap, out, report)
}

/// The whole RTU suite, once for every test of this file.
pub fn whole_run() -> &'static (PathBuf, Value) {
    static RUN: OnceLock<(PathBuf, Value)> = OnceLock::new();
    RUN.get_or_init(|| captured_check("whole", "rtu", &[]))
}

/// One packet of a capture, owned.
pub struct Frame {
    pub interface: u32,
    pub link_type: u16,
    pub direction: Option<Direction>,
    pub flags: u32,
    pub comment: Option<String>,
    pub bytes: Vec<u8>,
}

impl Frame {
    /// Whether the frame went out of the port the capture was made on (a master's
    /// request, as the suite sent it).
    pub fn sent(&self) -> bool {
        self.direction == Some(Direction::Outbound)
    }

    /// Whether the frame came in on that port (a device's reply).
    pub fn received(&self) -> bool {
        self.direction == Some(Direction::Inbound)
    }
}

/// The packets of the capture at `path`.
pub fn frames(path: &Path) -> Vec<Frame> {
    let data = std::fs::read(path).unwrap();
    Reader::new(&data)
        .unwrap()
        .map(|p| {
            let p = p.unwrap();
            Frame {
                interface: p.interface,
                link_type: p.link_type,
                direction: p.direction,
                flags: p.flags.unwrap_or(0),
                comment: p.comment.map(str::to_string),
                bytes: p.data.to_vec(),
            }
        })
        .collect()
}

/// Whether the capture marks `f` as a send this host broke as it left (sent again).
pub fn broken_by_host(f: &Frame) -> bool {
    conformance::capture::broken_by_host(Some(f.flags), f.comment.as_deref())
}

/// The frames `monitor --capture-in` judges: all but the sends this host broke (it reads
/// those as not sent, as `check` did).
pub fn judged(frames: &[Frame]) -> Vec<&Frame> {
    frames.iter().filter(|f| !broken_by_host(f)).collect()
}

/// The bytes of a report's hex ("01 03 ...").
pub fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

/// Every exchange's request in the report, with the check it belongs to, in order.
pub fn requests(report: &Value) -> Vec<(String, Vec<u8>)> {
    report["checks"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|c| {
            let id = c["id"].as_str().unwrap().to_string();
            c["exchanges"]
                .as_array()
                .unwrap()
                .iter()
                .filter_map(|e| e["request"].as_str().map(hex))
                .map(move |r| (id.clone(), r))
                .collect::<Vec<_>>()
        })
        .collect()
}

/// Whether `b` is an RTU frame whose CRC checks.
pub fn crc_ok(b: &[u8]) -> bool {
    b.len() >= 4 && conformance::codec::crc::crc16_frame_ok(b)
}

/// tshark's fields for every frame of `cap`, one row per frame (of a field that occurs
/// several times in a frame, the first).
pub fn tshark(cap: &Path, fields: &[&str]) -> Vec<Vec<String>> {
    tshark_occurrences(cap, fields, "f")
}

/// [`tshark`], with `occurrence` "f" (first), "l" (last) or "a" (all, comma-separated).
pub fn tshark_occurrences(cap: &Path, fields: &[&str], occurrence: &str) -> Vec<Vec<String>> {
    let fields = fields.iter().flat_map(|f| ["-e", f]);
    let out = Run::program("tshark", ["-r"])
        .arg(cap)
        .args(["-o", USER_DLT, "-o", "mbrtu.crc_verification:TRUE"])
        .args(["-T", "fields", "-E", "separator=/t", "-E"])
        .arg(format!("occurrence={occurrence}"))
        .args(fields)
        .run()
        .ok();
    out.stdout
        .lines()
        .map(|l| l.split('\t').map(str::to_string).collect())
        .collect()
}

/// `monitor --capture-in CAP EXTRA` writing `<dir>/NAME.monitor.json`: its exit, its
/// report (Null where it wrote none) and its stderr.
pub fn monitor_capture(cap: &Path, name: &str, extra: &[&str]) -> (Option<i32>, Value, String) {
    let json = dir().join(format!("{name}.monitor.json"));
    let out = Run::words("monitor --model f510 --quiet --capture-in")
        .arg(cap)
        .args(extra)
        .args(["--format", "json", "-o"])
        .arg(&json)
        .run();
    let stderr = out.stderr.clone();
    let report = std::fs::read_to_string(&json)
        .ok()
        .and_then(|s| serde_json::from_str(&s).ok())
        .unwrap_or(Value::Null);
    (out.code, report, stderr)
}

/// Node `address` of a monitor report (it must have it).
#[allow(unused_imports)] // capture_sim_bus reads no node
pub use common::monitor_node as node;

/// Kinds of finding per node of a monitor report, leaving out the drive's timing (a
/// capture made by a program on a busy host has its host's timing, not the line's).
pub fn kinds_by_node(r: &Value) -> Vec<(String, u64, Vec<String>)> {
    r["monitor"]["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            let mut kinds: Vec<String> = n["errors"]
                .as_object()
                .map(|o| o.keys().cloned().collect())
                .unwrap_or_default();
            kinds.retain(|k| !super::common::agree::TIMING_KINDS.contains(&k.as_str()));
            (
                n["address"].as_str().unwrap().to_string(),
                n["replies"].as_u64().unwrap_or(0),
                kinds,
            )
        })
        .collect()
}

/// Asserts that every ERROR of a `check` report is a request this host could not send
/// (a busy machine), never anything the device did.
pub fn errors_are_host_stalls(report: &Value) {
    for c in report["checks"].as_array().unwrap() {
        if c["status"] == "error" {
            let why = c["summary"].as_str().unwrap();
            assert!(
                why.contains("could not send the request"),
                "{}: {why}",
                c["id"]
            );
        }
    }
}
