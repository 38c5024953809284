//! The runner against a device that nobody here wrote: pymodbus's serial server, set up as
//! a generic holding-register device (no TECO registers, no TECO exception rules), on a
//! pseudo-terminal pair (tests/common's `pty_pair`), checked as an F510. The run must complete, report
//! the deviations a generic device has from the F510 manual, and neither panic nor hang.
//!
//! Exit codes a gate can trust (issue 28): a device that refuses a register a check must
//! read (or write) first answers, so the check is a DEVIATION (the manual serves the
//! register), not an ERROR, and the run exits 1, not 2. Shown against pymodbus without
//! the registers from 1000H up, and against the simulator serving a model with registers
//! taken out, which reaches every check that reads or writes first.

mod common;
use common::{check_of, line, pymodbus_serial_server, Scratch, SerialPeer};

use std::time::Duration;

/// The options that reach `peer` in `mode` (no parity) as an F510, then the words of
/// `extra`.
fn as_f510<'a>(peer: &'a SerialPeer, mode: &'a str, extra: &'a str) -> Vec<&'a str> {
    line(&[
        "--model f510 --port",
        peer.port.to_str().unwrap(),
        "--mode",
        mode,
        "-P none",
        extra,
    ])
}

fn run(mode: &str) {
    let dir = Scratch::new(&format!("generic-{mode}"));
    let Some(peer) = pymodbus_serial_server(&dir, mode) else {
        return;
    };
    let t0 = std::time::Instant::now();
    let (exit, v) = common::check_device(
        &dir,
        &as_f510(&peer, mode, "--timeout 300"),
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
    let dir = Scratch::new(&format!("generic-fuzz-{mode}"));
    let Some(peer) = pymodbus_serial_server(&dir, mode) else {
        return;
    };
    let (exit, v) = common::report_of(
        "fuzz",
        &dir,
        &as_f510(&peer, mode, "--timeout 500 --cases 150 --no-minimize"),
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
    common::generic_server_explains(
        kind,
        field,
        &[
            "invalid-frame",
            "loop-back-data",
            "sub-function",
            "length",
            "function",
        ],
    )
}

#[test]
fn a_generic_pymodbus_device_fuzzed_as_f510_rtu() {
    fuzz("rtu");
}

#[test]
fn a_generic_pymodbus_device_fuzzed_as_f510_ascii() {
    fuzz("ascii");
}

/// The case: a generic server with no registers from 1000H up, checked as an
/// F510. The write checks of groups 16..24 cannot read their register first; the device
/// refused it with exception 02H, which is evidence: DEVIATION, and the run exits 1.
#[test]
fn a_generic_device_without_registers_from_1000h_up_deviates_and_exits_1() {
    let dir = Scratch::new("generic-short");
    let Some(peer) = common::pymodbus_serial_with(&dir, "rtu", "1", 0x1000) else {
        return;
    };
    let (exit, v) = common::check_device(
        &dir,
        &line(&[
            "--model f510 --port",
            peer.port.to_str().unwrap(),
            "--mode rtu -P none --timeout 300 --only rtu.write.group-*",
        ]),
        Duration::from_secs(120),
    );
    assert_eq!(v["complete"], true, "{}", v["stopped"]);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    assert_eq!(exit, Some(1), "{}", v["summary"]);
    for g in [16, 17, 18, 20, 21, 22, 23, 24] {
        let c = check_of(&v, &format!("rtu.write.group-{g}"));
        assert_eq!(c["status"], "deviation", "{c}");
        let s = c["summary"].as_str().unwrap();
        assert!(
            s.starts_with(&format!("cannot read {g:02X}00H first: "))
                && s.contains("refused it with exception 02H"),
            "{s}"
        );
    }
    // The registers it has still pass.
    assert_eq!(check_of(&v, "rtu.write.group-1")["status"], "pass");
}

/// The F510 model with `edit` applied, written to `dir/name`: the simulator serves it,
/// the runner checks against the real F510 model.
fn edited_model(
    dir: &std::path::Path,
    name: &str,
    edit: impl FnOnce(&mut serde_json::Value),
) -> std::path::PathBuf {
    let mut m: serde_json::Value =
        serde_json::from_str(include_str!("../../vectors/models/f510.json")).unwrap();
    edit(&mut m);
    let path = dir.join(name);
    std::fs::write(&path, serde_json::to_string(&m).unwrap()).unwrap();
    path
}

/// `check --model f510` against the simulator serving `model`.
fn check_sim_model(
    dir: &std::path::Path,
    model: &std::path::Path,
    only: &[&str],
) -> (Option<i32>, serde_json::Value) {
    let (_sim, port) = common::sim_pty(&["--model-file", model.to_str().unwrap()]);
    let mut args = vec![
        "--model",
        "f510",
        "--port",
        &port,
        "--mode",
        "rtu",
        "--allow-motion",
    ];
    for o in only {
        args.extend(["--only", o]);
    }
    common::check_device(dir, &args, Duration::from_secs(120))
}

/// Every check that reads a register first (the value it restores) against a drive whose
/// registers are missing: each is a DEVIATION naming the register and the exception, none
/// an ERROR, and the run exits 1.
#[test]
fn a_refused_read_before_a_check_is_a_deviation_not_an_error() {
    let dir = Scratch::new("generic-gap");
    // Without group 0 (0000H..), groups 16 and up (1000H..) and the command group
    // (2500H..251FH: operation, frequency command, the two-word register).
    let model = edited_model(&dir, "gap.json", |m| {
        m["parameter_groups"]
            .as_array_mut()
            .unwrap()
            .retain(|g| (1..16).contains(&g["group"].as_u64().unwrap()));
        m["groups"]
            .as_array_mut()
            .unwrap()
            .retain(|g| g["name"] != "command");
        m["registers"].as_array_mut().unwrap().retain(|r| {
            let a = u16::from_str_radix(r["register"].as_str().unwrap(), 16).unwrap();
            !(0x2500..0x2520).contains(&a)
        });
    });
    let setups = [
        ("rtu.write.group-16", "cannot read 1000H first: "),
        ("rtu.write.frequency-command", "cannot read 2502H first: "),
        ("rtu.write.frequency-max", "cannot read 2502H first: "),
        (
            "rtu.write.out-of-range",
            "cannot read 2502H first (so that a write could be undone): ",
        ),
        ("rtu.write.two-word", "cannot read 2510H first: "),
        (
            "rtu.write-count.limit",
            "cannot read the values to write back first: ",
        ),
        ("rtu.broadcast.write", "cannot read 2502H first: "),
        ("rtu.motion.run-stop", "cannot read 2501H first: "),
        ("rtu.motion.external-fault", "cannot read 2501H first: "),
    ];
    let only: Vec<&str> = setups.iter().map(|(id, _)| *id).collect();
    let (exit, v) = check_sim_model(&dir, &model, &only);
    assert_eq!(v["complete"], true, "{}", v["stopped"]);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    assert_eq!(exit, Some(1));
    assert_eq!(v["exit_code"], 1);
    for (id, lead) in setups {
        let c = check_of(&v, id);
        assert_eq!(c["status"], "deviation", "{c}");
        let s = c["summary"].as_str().unwrap();
        assert!(s.starts_with(lead), "{id}: {s}");
        assert!(
            s.contains("the manual serves it, the device refused it with exception 02H"),
            "{id}: {s}"
        );
        // The refused exchange is in the report, with the model's prediction.
        let e = &c["exchanges"][0];
        assert!(
            e["received"].as_str().unwrap().starts_with("01 83 02"),
            "{id}: {e}"
        );
    }
}

/// A write a check needs first (the run check's 10.00 Hz) that the device refuses is a
/// DEVIATION too.
#[test]
fn a_refused_write_before_a_check_is_a_deviation_not_an_error() {
    let dir = Scratch::new("generic-ro");
    let model = edited_model(&dir, "ro.json", |m| {
        for r in m["registers"].as_array_mut().unwrap() {
            if r["register"] == "2502" {
                let o = r.as_object_mut().unwrap();
                o.insert("access".into(), "read-only".into());
                o.remove("max");
                o.remove("resolution");
            }
        }
    });
    let (exit, v) = check_sim_model(&dir, &model, &["rtu.motion.run-stop"]);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    assert_eq!(exit, Some(1));
    let c = check_of(&v, "rtu.motion.run-stop");
    assert_eq!(c["status"], "deviation", "{c}");
    let s = c["summary"].as_str().unwrap();
    assert!(
        s.starts_with("cannot write 03E8H (10.00 Hz) to 2502H first: the manual serves it, the device refused it with exception"),
        "{s}"
    );
}
