//! The command line, run as a user would run it.

use std::process::Command;

fn conformance(args: &[&str]) -> (i32, String) {
    let out = Command::new(env!("CARGO_BIN_EXE_conformance"))
        .args(args)
        .output()
        .expect("binary runs");
    let text =
        String::from_utf8_lossy(&out.stdout).to_string() + &String::from_utf8_lossy(&out.stderr);
    (out.status.code().unwrap_or(-1), text)
}

#[test]
fn decode_reports_the_f510_read_response_crc_erratum() {
    // F510 manual 1.0.3, 03H normal response as printed.
    let (code, out) = conformance(&["decode", "--rtu", "--response", "01 03 02 17 70 AF 82"]);
    assert_eq!(code, 1, "{out}");
    assert!(
        out.contains("CRC mismatch: frame carries 82AF, computed 50B6"),
        "{out}"
    );
    assert!(out.contains("values          [1770]"), "{out}");
    assert!(out.contains("01 03 02 17 70 B6 50"), "{out}");
}

#[test]
fn decode_valid_rtu_and_ascii() {
    let (code, out) = conformance(&["decode", "--rtu", "--request", "0103012300 01743C"]);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("start           0123"), "{out}");
    let (code, out) = conformance(&["decode", ":010301230001D7"]);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("LRC D7 ok"), "{out}");
    let (code, out) = conformance(&[
        "decode",
        "--ascii",
        "3A 30 31 30 33 30 31 32 33 30 30 30 31 44 37 0D 0A",
    ]);
    assert_eq!(code, 0, "{out}");
}

#[test]
fn decode_rejects_bad_input_with_exit_2() {
    let (code, out) = conformance(&["decode", "--rtu", "01 0G"]);
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("invalid hex character 'G'"), "{out}");
    let (code, out) = conformance(&["decode", "--rtu", "01 03"]);
    assert_eq!(code, 2, "{out}");
    assert!(out.contains("too short"), "{out}");
}

#[test]
fn encode_builds_both_modes() {
    let (code, out) = conformance(&[
        "encode",
        "--address",
        "1",
        "write",
        "--register",
        "0x2502",
        "--value",
        "0x1770",
    ]);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("RTU    01 06 25 02 17 70 2D 12"), "{out}");
    assert!(out.contains(r#"":0106250217704B\r\n""#), "{out}");
    let (code, out) = conformance(&["encode", "exception", "--function", "0x83", "--code", "2"]);
    assert_eq!(code, 2, "{out}");
}

#[test]
fn vectors_verify_passes_and_export_is_json() {
    let (code, out) = conformance(&["vectors", "verify"]);
    assert_eq!(code, 0, "{out}");
    let (code, out) = conformance(&["vectors", "export", "--format", "json"]);
    assert_eq!(code, 0);
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    assert!(v["number_of_vectors"].as_u64().unwrap() >= 155);
    let (code, out) = conformance(&["vectors", "list", "--model", "f510", "--verdict", "erratum"]);
    assert_eq!(code, 0, "{out}");
    assert!(out.contains("f510.03.rtu.response"), "{out}");
}
