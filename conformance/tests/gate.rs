//! The gate: the reference adapter (this suite's codec) passes; a deliberately broken one
//! (it accepts every CRC) is caught; adapters that crash, hang or babble are reported as
//! ERRORs case by case and the gate carries on; the pymodbus adapter completes; a broken
//! variant of the minimalmodbus adapter (it mends every checksum) is caught; a response that
//! answers no valid request may be refused.

mod common;
use common::gate::{gate_json, schema_valid, status_of};
use common::{bin, python, Peer, Ran, Run};

fn gate(codec: &str, extra: &[&str]) -> (Ran, serde_json::Value) {
    gate_json("--codec", codec, extra)
}

fn reference() -> String {
    format!("{} adapter", bin())
}

#[test]
fn the_reference_adapter_passes_every_case() {
    let (o, v) = gate(&reference(), &["--count", "2000"]);
    assert_eq!(o.code, Some(0), "{}", o.stderr);
    assert_eq!(v["kind"], "gate");
    assert_eq!(v["summary"]["deviation"], 0);
    assert_eq!(v["summary"]["error"], 0);
    assert!(
        v["summary"]["pass"].as_u64().unwrap() > 2400,
        "{}",
        v["summary"]
    );
    // Incomplete frames of the manuals are skipped as printed.
    assert_eq!(status_of(&v, "vector.f510.03.ascii.request.decode"), "skip");
    assert_eq!(
        status_of(&v, "vector.f510.03.ascii.request.corrected.decode"),
        "pass"
    );
    schema_valid(&v);
}

#[test]
fn an_adapter_that_accepts_every_crc_is_caught() {
    let (o, v) = gate(&format!("{} --break accept-bad-checksum", reference()), &[]);
    assert_eq!(o.code, Some(1));
    // Every checksum erratum of the manuals is a deviation.
    for id in [
        "vector.f510.03.rtu.response.decode",
        "vector.a510.10.rtu.request.decode",
        "vector.l510-legacy.08.ascii.exception.decode",
    ] {
        assert_eq!(status_of(&v, id), "deviation", "{id}");
    }
    // Consistent frames still pass.
    assert_eq!(status_of(&v, "vector.f510.03.rtu.request.decode"), "pass");
    let devs: Vec<&serde_json::Value> = v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["status"] == "deviation")
        .collect();
    assert!(devs.len() > 50, "{}", devs.len());
    assert!(devs.iter().all(|c| c["summary"]
        .as_str()
        .unwrap()
        .contains("accepted a frame that must be rejected")));
    // The differential cases print a reproducible command.
    let diff = devs
        .iter()
        .find(|c| c["id"].as_str().unwrap().starts_with("diff."))
        .unwrap();
    assert!(
        diff["summary"]
            .as_str()
            .unwrap()
            .contains("reproduce: conformance decode --"),
        "{diff}"
    );
    schema_valid(&v);
}

const HELLO: &str = r#"{"id":0,"ok":true,"protocol":1,"adapter":"test","implementation":"test","version":"0","supports":["crc","lrc","decode","encode"]}"#;

#[test]
fn an_adapter_that_exits_is_restarted_once_then_the_run_is_incomplete() {
    // Answers the handshake, then exits on the first request.
    let crashy = format!("read l; echo '{HELLO}'; read l; exit 3");
    let (o, v) = gate(&crashy, &["--no-vectors", "--count", "4"]);
    assert_eq!(o.code, Some(2));
    assert_eq!(v["complete"], false);
    let incidents = v["codec"]["incidents"].as_array().unwrap();
    assert_eq!(incidents.len(), 2, "{incidents:?}");
    assert!(incidents[0].as_str().unwrap().contains("restarted"));
    assert!(incidents[1].as_str().unwrap().contains("not restarted"));
    assert!(v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .all(|c| c["status"] == "error"));
    schema_valid(&v);
}

#[test]
fn malformed_and_missing_answers_are_errors_case_by_case() {
    // Answers the handshake, then nonsense; the gate carries on through every case.
    let babbler = format!("read l; echo '{HELLO}'; while read l; do echo 'this is not json'; done");
    let (o, v) = gate(&babbler, &["--no-vectors", "--count", "5"]);
    assert_eq!(o.code, Some(2));
    let checks = v["checks"].as_array().unwrap();
    assert_eq!(checks.len(), 5);
    assert!(checks
        .iter()
        .all(|c| c["status"] == "error"
            && c["summary"].as_str().unwrap().contains("malformed answer")));
    assert_eq!(v["complete"], true);
    // An adapter that never answers: timeouts, each an error, and the gate ends.
    let mute = format!("read l; echo '{HELLO}'; sleep 30");
    let t0 = std::time::Instant::now();
    let (_, v) = gate(&mute, &["--no-vectors", "--count", "2", "--timeout", "200"]);
    assert!(t0.elapsed() < std::time::Duration::from_secs(10));
    assert!(v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .all(|c| c["status"] == "error"));
    // An adapter that refuses the protocol stops the gate with exit code 2.
    let o = Run::words("gate --codec")
        .arg(r#"read l; echo '{"id":1,"ok":false,"error":"protocol 2 only"}'"#)
        .run();
    assert_eq!(o.code, Some(2));
    assert!(o.stderr.contains("handshake failed"));
}

/// adapters/NAME/adapter.py, where `peer` (the library it drives) is installed; None
/// (after SKIPPED) where it is not.
fn adapter_for(peer: Peer, name: &str) -> Option<String> {
    common::need(peer).then(|| {
        format!(
            "{}/../adapters/{name}/adapter.py",
            env!("CARGO_MANIFEST_DIR")
        )
    })
}

#[test]
fn the_pymodbus_adapter_completes_and_its_deviations_are_reported() {
    let Some(adapter) = adapter_for(Peer::Pymodbus, "pymodbus") else {
        return;
    };
    let adapter = adapter.as_str();
    let (o, v) = gate(&format!("{} {adapter}", python()), &["--count", "300"]);
    assert_eq!(v["codec"]["implementation"], "pymodbus");
    assert_eq!(v["complete"], true);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    // Every golden vector: pymodbus agrees with the manuals' consistent frames.
    for c in v["checks"].as_array().unwrap() {
        if c["id"].as_str().unwrap().starts_with("vector.")
            && c["id"].as_str().unwrap().ends_with(".decode")
        {
            assert_ne!(c["status"], "deviation", "{c}");
        }
    }
    // The differential cases find what pymodbus 3.16.1 accepts and should not.
    assert!(v["summary"]["deviation"].as_u64().unwrap() > 0);
    assert_eq!(o.code, Some(1));
    schema_valid(&v);
}

#[test]
fn a_broken_minimalmodbus_adapter_that_accepts_every_checksum_is_caught() {
    let Some(adapter) = adapter_for(Peer::Minimalmodbus, "minimalmodbus") else {
        return;
    };
    let adapter = adapter.as_str();
    // The F510 manual's 03H response as printed has a wrong CRC: minimalmodbus refuses it.
    let erratum = "vector.f510.03.rtu.response.decode";
    let (o, v) = gate(&format!("{} {adapter}", python()), &["--only", erratum]);
    assert_eq!(o.code, Some(0), "{}", v["summary"]);
    assert_eq!(status_of(&v, erratum), "pass");
    // The broken variant mends every checksum before minimalmodbus sees it.
    let (o, v) = gate(
        &format!(
            "MINIMALMODBUS_ADAPTER_BREAK=accept-bad-checksum {} {adapter}",
            python()
        ),
        &["--count", "200"],
    );
    assert_eq!(o.code, Some(1), "{}", v["summary"]);
    assert_eq!(v["complete"], true);
    assert!(v["codec"]["adapter"]
        .as_str()
        .unwrap()
        .contains("broken: accept-bad-checksum"));
    let erratum_case = common::check_of(&v, erratum);
    assert_eq!(erratum_case["status"], "deviation", "{erratum_case}");
    assert!(erratum_case["summary"]
        .as_str()
        .unwrap()
        .contains("accepted a frame that must be rejected"));
    // Corrupted differential frames, in both modes, are caught as accepted.
    let caught: Vec<&str> = v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| {
            c["status"] == "deviation"
                && c["id"].as_str().unwrap().starts_with("diff.")
                && c["summary"]
                    .as_str()
                    .unwrap()
                    .starts_with("accepted a frame that must be rejected")
        })
        .map(|c| c["title"].as_str().unwrap())
        .collect();
    assert!(
        caught.iter().any(|t| t.contains(" rtu ")) && caught.iter().any(|t| t.contains(" ascii ")),
        "{caught:#?}"
    );
    schema_valid(&v);
}

#[test]
fn an_adapter_that_starts_slowly_gets_longer_than_the_case_timeout_for_its_hello() {
    // An interpreter importing a large library on a loaded machine: 2.5 s before the hello,
    // then quick answers. The per-case timeout (500 ms) does not apply to the handshake.
    let slow = format!(
        r#"sleep 2.5; read l; echo '{HELLO}'; sed -u -E 's/.*"id":([0-9]+).*/{{"id":\1,"ok":true,"accepted":false,"reason":"no"}}/'"#
    );
    let (o, v) = gate(&slow, &["--no-vectors", "--count", "3", "--timeout", "500"]);
    assert_ne!(o.code, Some(2), "{}", o.stderr);
    assert_eq!(v["complete"], true);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    assert_eq!(v["summary"]["total"], 3);
}

#[test]
fn an_adapter_that_rejects_every_frame_may_reject_responses_that_answer_no_request() {
    // Rejects every frame: the gate must not count a refused read response of 0
    // registers (or a write response for 0 or over 123) as a deviation, since no valid
    // request has such an answer; it still counts refused valid frames.
    let rejecter = format!(
        r#"read l; echo '{HELLO}'; sed -u -E 's/.*"id":([0-9]+).*/{{"id":\1,"ok":true,"accepted":false,"reason":"no"}}/'"#
    );
    let (_, v) = gate(&rejecter, &["--no-vectors", "--count", "1500"]);
    let checks = v["checks"].as_array().unwrap();
    let answers_no_request: Vec<&serde_json::Value> = checks
        .iter()
        .filter(|c| {
            c["exchanges"][0]["predicted"]
                .as_str()
                .unwrap_or("")
                .contains("answers no valid request")
        })
        .collect();
    assert!(!answers_no_request.is_empty());
    assert!(
        answers_no_request.iter().all(|c| c["status"] == "pass"),
        "{answers_no_request:#?}"
    );
    assert!(checks.iter().any(|c| c["status"] == "deviation"
        && c["summary"]
            .as_str()
            .unwrap()
            .starts_with("rejected a valid frame")));
}

#[test]
fn the_libmodbus_adapter_drives_libmodbus_over_a_pty_and_completes() {
    let Some(adapter) = adapter_for(Peer::Libmodbus, "libmodbus") else {
        return;
    };
    let adapter = adapter.as_str();
    let (o, v) = gate(
        &format!("{} {adapter}", python()),
        &["--only", "vector.f510.*.rtu.*", "--timeout", "5000"],
    );
    assert_eq!(v["codec"]["implementation"], "libmodbus");
    assert_eq!(v["complete"], true);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    // The manual's 03H request goes through modbus_receive, and modbus_reply answers it.
    let read = common::check_of(&v, "vector.f510.03.rtu.request.decode");
    assert_eq!(read["status"], "pass", "{read}");
    assert!(read["exchanges"][0]["actual"]
        .as_str()
        .unwrap()
        .contains("modbus_reply answers 01 03"));
    // Its wrong-CRC response as printed is refused by libmodbus's client.
    assert_eq!(status_of(&v, "vector.f510.03.rtu.response.decode"), "pass");
    // libmodbus 3.1.6 sizes an 08H request wrongly and refuses it as "Invalid CRC".
    let loop_back = common::check_of(&v, "vector.f510.08.rtu.request.decode");
    assert_eq!(loop_back["status"], "deviation");
    assert!(loop_back["summary"]
        .as_str()
        .unwrap()
        .contains("Invalid CRC"));
    assert_eq!(o.code, Some(1));
    schema_valid(&v);
}
