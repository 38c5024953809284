//! The runner against a device that nobody here wrote: pymodbus's serial server, set up as
//! a generic holding-register device (no TECO registers, no TECO exception rules), on a
//! pseudo-terminal pair (tests/common's `pty_pair`), checked as an F510. The run must complete, report
//! the deviations a generic device has from the F510 manual, and neither panic nor hang.

mod common;
use common::pymodbus_serial_server;

use std::time::Duration;

fn run(mode: &str) {
    let dir = std::env::temp_dir().join(format!("teco-generic-{mode}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let Some(peer) = pymodbus_serial_server(&dir, mode) else {
        return;
    };
    let b = &peer.port;
    let t0 = std::time::Instant::now();
    let (exit, v) = common::check_device(
        &dir,
        &[
            "--model",
            "f510",
            "--port",
            b.to_str().unwrap(),
            "--mode",
            mode,
            "-P",
            "none",
            "--timeout",
            "300",
        ],
        Duration::from_secs(180),
    );
    assert_eq!(v["complete"], true, "{}", v["stopped"]);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    let deviations = v["summary"]["deviation"].as_u64().unwrap();
    assert!(
        deviations > 10,
        "a generic device cannot behave like a TECO drive: {}",
        v["summary"]
    );
    assert_eq!(exit, Some(1));
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

/// `conformance fuzz` against pymodbus's generic server, a short budget: it completes
/// (exit 0 or 1, never 2, never a panic), and every finding is of a kind a generic
/// server explains (see `explained`).
fn fuzz(mode: &str) {
    let dir = std::env::temp_dir().join(format!("teco-generic-fuzz-{mode}-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let Some(peer) = pymodbus_serial_server(&dir, mode) else {
        return;
    };
    let b = &peer.port;
    let (exit, v) = common::report_of(
        "fuzz",
        &dir,
        &[
            "--model",
            "f510",
            "--port",
            b.to_str().unwrap(),
            "--mode",
            mode,
            "-P",
            "none",
            "--timeout",
            "500",
            "--cases",
            "150",
            "--no-minimize",
        ],
        Duration::from_secs(300),
    );
    // pymodbus 3.16.1's serial server stops answering for good after one frame of a
    // function it does not know (reproduced by hand with `conformance send`: after
    // `81 43 10 24 00 01 DE CE`, a frame to node 81H with function 43H and a valid CRC,
    // no request is answered any more, minutes later either; its RTU framer cannot size
    // the frame and never resynchronises). Its ASCII server likewise after one damaged
    // frame, `:0103250600 01D` with a 00H byte in place of an LRC digit, then CR LF. That
    // is the one way the run may end with exit 2: a hang that did not come back, on an
    // unserved function or a frame pymodbus cannot frame.
    assert!(
        matches!(exit, Some(0..=2)),
        "exit {exit:?}: {}",
        v["stopped"]
    );
    for m in v["fuzz"]["modes"].as_array().unwrap() {
        for f in m["findings"].as_array().unwrap() {
            let sig = f["signature"].as_str().unwrap();
            let hang_for_good = f["kind"] == "hang"
                && f["recovery_ms"].is_null()
                && (!matches!(f["function"].as_str().unwrap(), "03" | "06" | "08" | "10")
                    || matches!(
                        f["field_class"].as_str().unwrap(),
                        "unframed" | "bad-checksum"
                    ));
            assert!(
                explained(sig) || hang_for_good,
                "unexplained finding on pymodbus: {f:#}"
            );
        }
    }
    if exit == Some(2) {
        let stopped = v["stopped"].as_str().unwrap();
        assert!(stopped.contains("did not come back"), "{stopped}");
        let last = v["fuzz"]["modes"][0]["findings"]
            .as_array()
            .unwrap()
            .iter()
            .rfind(|f| f["kind"] == "hang")
            .unwrap_or_else(|| panic!("exit 2 without a hang: {stopped}"));
        assert!(last["recovery_ms"].is_null(), "{last:#}");
    }
    eprintln!(
        "pymodbus fuzz {mode}: {:?}",
        v["fuzz"]["modes"][0]["findings"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| format!("{} x{}", f["signature"], f["count"]))
            .collect::<Vec<_>>()
    );
    let _ = std::fs::remove_dir_all(&dir);
}

/// The kinds of finding a generic pymodbus server has against the F510 model, each
/// checked by hand on the wire: it serves every register 0000H..FFFEH (reads past the
/// F510 map get data: `register-value`, `byte-count`, `reply-instead-of-exception`); it
/// answers broadcasts and other nodes (`reply-to-broadcast`, `reply-to-other-address`);
/// its exception codes differ from the TECO ones (`exception-code`), it answers some
/// requests the model refuses and refuses some it serves (`exception-instead-of-reply`),
/// it answers nothing to functions and frames it does not take (`no-reply-*`), answers an
/// over-long read with `01 80 01 80 00`, a frame without CRC (`invalid-frame`), answers
/// a request it cannot decode with exception function 80H instead of the request's
/// function with its bit 7 set (`function`, e.g. to a short 0FH request), and
/// copies 08H test data as it comes (`loop-back-data`, `sub-function`); a write it takes
/// reads back as written, not as the TECO register would (`value-of-*`).
fn explained(sig: &str) -> bool {
    let field = sig.rsplit('.').next().unwrap_or("");
    let kind = sig.split('.').nth(1).unwrap_or("");
    match kind {
        "mismatch" => matches!(
            field,
            "register-value"
                | "byte-count"
                | "reply-instead-of-exception"
                | "exception-instead-of-reply"
                | "exception-code"
                | "invalid-frame"
                | "loop-back-data"
                | "sub-function"
                | "register-address"
                | "register-count"
                | "written-value"
                | "length"
                | "function"
        ),
        "unexpected-reply" => field.starts_with("reply-to-"),
        "no-reply" => field.starts_with("no-reply-for-"),
        "wrong-value" => field.starts_with("value-of-"),
        _ => false,
    }
}

#[test]
fn a_generic_pymodbus_device_fuzzed_as_f510_rtu() {
    fuzz("rtu");
}

#[test]
fn a_generic_pymodbus_device_fuzzed_as_f510_ascii() {
    fuzz("ascii");
}
