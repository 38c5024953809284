//! `conformance fuzz` against the simulator: the clean simulator of every model gives no
//! finding in either mode; each planted firmware bug is found within a stated case
//! budget, with the right kind, minimized to a single frame (or the shortest sequence) that
//! replays; `conformance send` replays frames. Reports match the report schema.
//!
//! Case budgets (seed 1, unpaced): hang-on-byte-count within 300 cases, wrong-value-at
//! within 3000, overflow-after within 50. The clean runs send 300 cases per model and
//! mode by default (CI's time); set FUZZ_CASES (2000 was run before merging; 20000 for
//! the full run) for more.

mod common;
use common::{bin, report_of};

use std::time::Duration;

use serde_json::Value;

fn fuzz(dir: &std::path::Path, args: &[&str], limit: Duration) -> (Option<i32>, Value) {
    report_of("fuzz", dir, args, limit)
}

fn findings(v: &Value) -> Vec<Value> {
    v["fuzz"]["modes"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|m| m["findings"].as_array().unwrap().clone())
        .collect()
}

fn hex(s: &Value) -> Vec<u8> {
    conformance::codec::hex::parse_hex(s.as_str().unwrap()).unwrap()
}

fn clean(model: &str) {
    // A sample in the default run (CI's time); FUZZ_CASES=2000 or 20000 for more.
    let cases = std::env::var("FUZZ_CASES").unwrap_or_else(|_| "300".into());
    let dir = tempdir(&format!("clean-{model}"));
    let (code, v) = fuzz(
        &dir,
        &[
            "--sim",
            model,
            "--mode",
            "both",
            "--no-pace",
            "--cases",
            &cases,
        ],
        Duration::from_secs(1800),
    );
    let f = findings(&v);
    assert!(
        f.is_empty(),
        "{model}: findings on the clean simulator: {f:#?}"
    );
    assert_eq!(code, Some(0), "{model}: {}", v["stopped"]);
    assert_eq!(v["kind"], "fuzz");
    for m in v["fuzz"]["modes"].as_array().unwrap() {
        assert_eq!(m["cases"].as_u64().unwrap().to_string(), cases, "{model}");
        assert!(m["cases_per_s"].as_f64().unwrap() > 0.0);
    }
    assert_eq!(v["fuzz"]["modes"].as_array().unwrap().len(), 2);
}

fn tempdir(name: &str) -> std::path::PathBuf {
    let d = std::env::temp_dir().join(format!("fuzz-test-{}-{name}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

#[test]
fn clean_f510() {
    clean("f510");
}

#[test]
fn clean_a510() {
    clean("a510");
}

#[test]
fn clean_l510() {
    clean("l510");
}

#[test]
fn clean_e510() {
    clean("e510");
}

#[test]
fn clean_l510_legacy() {
    clean("l510-legacy");
}

#[test]
fn a_byte_count_over_the_data_is_found_as_a_hang_and_minimized_to_one_frame() {
    let dir = tempdir("hang");
    let (code, v) = fuzz(
        &dir,
        &[
            "--sim",
            "f510",
            "--quirk",
            "hang-on-byte-count",
            "--mode",
            "rtu",
            "--no-pace",
            "--cases",
            "300",
        ],
        Duration::from_secs(600),
    );
    assert_eq!(code, Some(1));
    let f = findings(&v);
    let hang = f
        .iter()
        .find(|x| x["kind"] == "hang" && x["function"] == "10")
        .unwrap_or_else(|| panic!("no 10H hang in {f:#?}"));
    let min = hang["minimized"].as_array().unwrap();
    assert_eq!(min.len(), 1, "{hang:#}");
    let frame = hex(&min[0]);
    assert_eq!(conformance::codec::crc::crc16(&frame), 0, "a valid CRC");
    assert_eq!(frame[1], 0x10);
    let data = frame.len() - 9;
    assert!(
        usize::from(frame[6]) > data,
        "byte count {} over {data} data bytes",
        frame[6]
    );
    assert!(frame.len() <= hang["frames"][0].as_str().unwrap().split(' ').count());
    assert_eq!(hang["reproduced"], true);
    // Silent for 5 s: it came back, and not before.
    let back = hang["recovery_ms"].as_f64().unwrap();
    assert!((4000.0..30000.0).contains(&back), "{back}");
    assert!(hang["replay"]
        .as_str()
        .unwrap()
        .starts_with("conformance send --sim f510 --quirk hang-on-byte-count"));
}

#[test]
fn a_flipped_bit_is_found_as_a_wrong_value_by_writing_back_what_was_read() {
    let dir = tempdir("wrong");
    let (code, v) = fuzz(
        &dir,
        &[
            "--sim",
            "f510",
            "--quirk",
            "wrong-value-at=0000H",
            "--mode",
            "rtu",
            "--no-pace",
            "--cases",
            "3000",
        ],
        Duration::from_secs(900),
    );
    assert!(matches!(code, Some(1 | 2)), "{code:?}");
    let f = findings(&v);
    let w = f
        .iter()
        .find(|x| x["kind"] == "wrong-value")
        .unwrap_or_else(|| panic!("no wrong value in {f:#?}"));
    // The shortest sequence: write back the value read, read it again.
    let min: Vec<Vec<u8>> = w["minimized"].as_array().unwrap().iter().map(hex).collect();
    assert_eq!(min.len(), 2, "{w:#}");
    assert_eq!(&min[0][..4], &[1, 6, 0, 0]);
    assert_eq!(&min[1][..6], &[1, 3, 0, 0, 0, 1]);
    assert_eq!(w["reproduced"], true);
    assert_eq!(
        findings(&v).iter().filter(|x| x["kind"] == "hang").count(),
        0
    );
}

#[test]
fn frames_back_to_back_overflowing_the_receiver_are_found_and_shortened() {
    let dir = tempdir("overflow");
    let (code, v) = fuzz(
        &dir,
        &[
            "--sim",
            "f510",
            "--quirk",
            "overflow-after=4",
            "--mode",
            "rtu",
            "--no-pace",
            "--cases",
            "50",
        ],
        Duration::from_secs(600),
    );
    assert_eq!(code, Some(1));
    let f = findings(&v);
    let o = f
        .iter()
        .find(|x| x["kind"] == "hang" && x["burst"] == true)
        .unwrap_or_else(|| panic!("no overflow in {f:#?}"));
    // The 4th frame less than t3.5 after the previous one trips it: 5 frames.
    assert_eq!(o["minimized"].as_array().unwrap().len(), 5, "{o:#}");
    assert_eq!(o["reproduced"], true);
    assert!(o["replay"].as_str().unwrap().contains("--burst"));
    let back = o["recovery_ms"].as_f64().unwrap();
    assert!(back >= 900.0, "{back}");
}

#[test]
fn send_prints_the_answer_and_the_prediction() {
    let out = std::process::Command::new(bin())
        .args([
            "send",
            "--sim",
            "f510",
            "--mode",
            "rtu",
            "--no-pace",
            "01 03 25 20 00 01 8E CC",
            "0110250C000102C796",
        ])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    assert_eq!(out.status.code(), Some(0), "{text}");
    assert!(
        text.contains("model: 01 03 25 20 00 01 8E CC -> normal 03H reply"),
        "{text}"
    );
    assert!(text.contains("as predicted"), "{text}");
    assert!(text.contains("received 01 03 02"), "{text}");
    // The malformed 10H: the model predicts its exception; the clean simulator sends it.
    assert!(text.contains("received 01 90 03"), "{text}");
    // A frame that is not hex: exit 2.
    let bad = std::process::Command::new(bin())
        .args(["send", "--sim", "f510", "--mode", "rtu", "01 0G"])
        .output()
        .unwrap();
    assert_eq!(bad.status.code(), Some(2));
}

#[test]
fn seeds_reproduce_and_safety_holds_with_writes_none() {
    let dir = tempdir("none");
    let (code, v) = fuzz(
        &dir,
        &[
            "--sim",
            "f510",
            "--mode",
            "ascii",
            "--no-pace",
            "--cases",
            "300",
            "--writes",
            "none",
        ],
        Duration::from_secs(600),
    );
    assert_eq!(code, Some(0));
    assert_eq!(v["fuzz"]["writes"], "none");
    // Nothing written, so nothing to restore.
    assert!(
        v["restore"].as_array().unwrap().is_empty(),
        "{}",
        v["restore"]
    );
}
