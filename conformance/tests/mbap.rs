//! Modbus TCP gateways (`--tcp HOST:PORT --framing mbap --unit N`), against peers nobody
//! here wrote and against this suite's own simulated gateway:
//!
//! - mbpoll (libmodbus, `-m tcp`) reads and writes `simulate --framing mbap`, and gets the
//!   gateway's 0BH for a unit id with no drive;
//! - pymodbus's `ModbusTcpClient` does the same (tests/interop/pymodbus_tcp_master.py);
//! - `check --framing mbap` runs to completion against pymodbus's generic TCP server
//!   (tests/interop/pymodbus_tcp_server.py), with the checks a gateway hides SKIP;
//! - `check --framing mbap` against `simulate --framing mbap` has no deviation, and
//!   `fuzz` through it finds nothing and sends no case a gateway cannot carry;
//! - the command line refuses what MBAP cannot do (ASCII, --burst, --echo on, unit 0).
//!
//! A missing tool prints `SKIPPED: ...` and returns, except under `CI`, where it fails.

mod common;
use common::{
    check_device, line, need, pymodbus_tcp_server, python, report_of, GatewaySim, Peer, Run,
    Scratch,
};

use std::process::{Command, Stdio};
use std::time::Duration;

/// The reason every check a gateway hides is skipped with.
const HIDDEN: &str =
    "not visible through a Modbus TCP gateway (MBAP carries no CRC/LRC and no line timing)";

fn run(cmd: &mut Command) -> (bool, String, String) {
    let o = cmd.stdin(Stdio::null()).output().unwrap();
    (
        o.status.success(),
        String::from_utf8_lossy(&o.stdout).into_owned(),
        String::from_utf8_lossy(&o.stderr).into_owned(),
    )
}

/// One mbpoll poll over Modbus TCP: `-m tcp -p PORT -a UNIT`, zero-based references.
fn mbpoll(sim: &GatewaySim, unit: u8, opts: &[&str], values: &[&str]) -> (bool, String, String) {
    run(Command::new("mbpoll")
        .args(["-m", "tcp", "-p", sim.port(), "-a", &unit.to_string()])
        .args(["-0", "-1", "-o", "1"])
        .args(opts)
        .arg("127.0.0.1")
        .args(values))
}

/// The values of mbpoll's `[ref]: value` lines.
fn mbpoll_values(stdout: &str) -> Vec<String> {
    stdout
        .lines()
        .filter_map(|l| {
            let rest = l.trim().strip_prefix('[')?;
            Some(rest.split_once("]:")?.1.trim().to_string())
        })
        .collect()
}

#[test]
fn mbpoll_reads_and_writes_through_mbap() {
    if !need(Peer::Mbpoll) {
        return;
    }
    let sim = GatewaySim::start("f510", 3, &["--gateway-timeout", "50"]);
    // The identification register 252FH of an F510 reads 0510H.
    let (ok, out, err) = mbpoll(&sim, 3, &["-t", "4:hex", "-r", "0x252F"], &[]);
    assert!(ok, "{out}{err}");
    assert_eq!(mbpoll_values(&out), ["0x0510"], "{out}");
    // 06H write of the frequency command, then read back (decimal reference 9474 = 2502H).
    let (ok, out, err) = mbpoll(&sim, 3, &["-t", "4", "-r", "9474"], &["1234"]);
    assert!(ok, "{out}{err}");
    let (ok, out, err) = mbpoll(&sim, 3, &["-t", "4", "-r", "9474"], &[]);
    assert!(ok, "{out}{err}");
    assert_eq!(mbpoll_values(&out), ["1234"], "{out}");
    // 10H of two registers 2501H..2502H, read back.
    let (ok, out, err) = mbpoll(&sim, 3, &["-t", "4", "-r", "9473"], &["0", "777"]);
    assert!(ok, "{out}{err}");
    let (ok, out, _) = mbpoll(&sim, 3, &["-t", "4", "-r", "9473", "-c", "2"], &[]);
    assert!(ok);
    assert_eq!(mbpoll_values(&out), ["0", "777"], "{out}");
    // A register not in the map: the drive's exception 02H crosses the gateway.
    let (ok, _, err) = mbpoll(&sim, 3, &["-t", "4", "-r", "57"], &[]);
    assert!(!ok);
    assert!(err.contains("Illegal data address"), "{err}");
    // Unit 7: no drive behind the gateway; the gateway says so with 0BH.
    let (ok, _, err) = mbpoll(&sim, 7, &["-t", "4", "-r", "9519"], &[]);
    assert!(!ok);
    assert!(
        err.to_lowercase().contains("failed to respond"),
        "libmodbus's text for 0BH: {err}"
    );
}

#[test]
fn pymodbus_tcp_client_against_the_simulated_gateway() {
    if !need(Peer::Pymodbus) {
        return;
    }
    let sim = GatewaySim::start("f510", 1, &["--gateway-timeout", "50"]);
    let script = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/interop/pymodbus_tcp_master.py"
    );
    let (ok, out, err) =
        run(Command::new(python()).args([script, "127.0.0.1", sim.port(), "1", "--absent", "7"]));
    assert!(ok, "{out}{err}");
    // Every operation ran and passed (the script checks the values).
    let ops: Vec<serde_json::Value> = out
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    assert_eq!(ops.len(), 8, "{out}");
    assert!(ops.iter().all(|o| o["ok"] == true), "{out}");
}

fn statuses<'a>(v: &'a serde_json::Value, status: &str) -> Vec<&'a serde_json::Value> {
    v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["status"] == status)
        .collect()
}

/// The checks a gateway hides are SKIP with the reason.
fn assert_hidden_checks_skipped(v: &serde_json::Value) {
    let skipped = statuses(v, "skip");
    for id in [
        "rtu.bad-crc",
        "rtu.garbage-then-frame",
        "rtu.partial-then-frame",
        "rtu.line-timing",
    ] {
        let c = skipped
            .iter()
            .find(|c| c["id"] == id)
            .unwrap_or_else(|| panic!("{id} is not SKIP"));
        assert_eq!(c["summary"], HIDDEN, "{id}");
    }
    let rt = skipped
        .iter()
        .find(|c| c["id"] == "rtu.response-time")
        .expect("response-time is SKIP through a gateway");
    assert!(
        rt["summary"].as_str().unwrap().contains(HIDDEN),
        "{}",
        rt["summary"]
    );
}

#[test]
fn check_through_mbap_against_pymodbus_tcp_server() {
    let Some((_server, addr)) = pymodbus_tcp_server(1) else {
        return;
    };
    let dir = Scratch::new("mbap-pymodbus");
    let (exit, v) = check_device(
        &dir,
        &line(&["--model f510 --tcp", &addr, "--framing mbap --timeout 500"]),
        Duration::from_secs(180),
    );
    assert_eq!(v["complete"], true, "{}", v["stopped"]);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    assert!(
        v["device"]["links"]["rtu"]
            .as_str()
            .unwrap()
            .starts_with("Modbus TCP gateway 127.0.0.1:"),
        "{}",
        v["device"]["links"]
    );
    assert!(v["device"]["line"]
        .as_str()
        .unwrap()
        .contains("behind a Modbus TCP gateway (MBAP, unit 1"));
    assert_hidden_checks_skipped(&v);
    // The device answers plain reads through the link; a generic server is no F510.
    assert!(
        v["summary"]["pass"].as_u64().unwrap() > 10,
        "{}",
        v["summary"]
    );
    assert!(
        v["summary"]["deviation"].as_u64().unwrap() > 5,
        "{}",
        v["summary"]
    );
    assert_eq!(exit, Some(1));
    // The other-address read goes to unit FEH (the F510's highest address; the unit map
    // keeps node numbers), and whatever comes back is from that unit: pymodbus 3.16's TCP
    // server answers a unit id it does not have with exception 04H (its simulator core
    // raises a KeyError where the serial server's context raises "no such id", which
    // would give 0BH), so this is a deviation of the device, reported as it came.
    let other = common::check_of(&v, "rtu.other-address");
    let ex = &other["exchanges"][0];
    assert!(
        ex["request"].as_str().unwrap().starts_with("FE 03"),
        "{other}"
    );
    let received = ex["received"].as_str().unwrap();
    assert!(
        received.is_empty() || received.starts_with("FE "),
        "{other}"
    );
    assert_ne!(other["status"], "error", "{other}");
    eprintln!("pymodbus TCP server as F510: {}", v["summary"]);
}

#[test]
fn check_through_mbap_against_the_simulated_gateway_has_no_deviation() {
    let sim = GatewaySim::start("f510", 1, &["--gateway-timeout", "50"]);
    let dir = Scratch::new("mbap-sim");
    let (exit, v) = check_device(
        &dir,
        &["--model", "f510", "--tcp", &sim.addr, "--framing", "mbap"],
        Duration::from_secs(180),
    );
    assert_eq!(v["complete"], true, "{}", v["stopped"]);
    assert_eq!(
        v["summary"]["deviation"],
        0,
        "{:#}",
        statuses(&v, "deviation")[0]
    );
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    assert_eq!(exit, Some(0));
    assert_hidden_checks_skipped(&v);
    assert_eq!(v["device"]["identification"], "0510");
}

#[test]
fn fuzz_through_mbap_sends_only_what_a_gateway_carries() {
    let sim = GatewaySim::start("f510", 1, &["--gateway-timeout", "20"]);
    let dir = Scratch::new("mbap-fuzz");
    let (exit, v) = report_of(
        "fuzz",
        &dir,
        &line(&[
            "--model f510 --tcp",
            &sim.addr,
            "--framing mbap --cases 300",
        ]),
        Duration::from_secs(240),
    );
    assert_eq!(v["complete"], true, "{}", v["stopped"]);
    let mode = &v["fuzz"]["modes"][0];
    assert_eq!(mode["cases"], 300, "{mode}");
    assert_eq!(mode["findings"].as_array().unwrap().len(), 0, "{mode}");
    // Damaged and back-to-back cases were made and not sent.
    assert!(
        mode["skipped"][HIDDEN].as_u64().unwrap_or(0) > 0,
        "{}",
        mode["skipped"]
    );
    assert_eq!(exit, Some(0), "{}", v["summary"]);
}

#[test]
fn what_mbap_cannot_do_is_refused_with_a_reason() {
    // Each command line split at white space ("010325200001 8ECC" is two frames).
    let cases = [
        (
            "check --model f510 --tcp 127.0.0.1:1 --framing mbap --mode ascii",
            "Modbus TCP has no ASCII mode",
        ),
        (
            "check --model f510 --tcp 127.0.0.1:1 --framing mbap --unit 0",
            "--unit 0 is the broadcast",
        ),
        (
            "check --model f510 --tcp 127.0.0.1:1 --framing mbap --echo on",
            "does not echo",
        ),
        (
            "send --model f510 --tcp 127.0.0.1:1 --framing mbap --burst 010325200001 8ECC",
            "--burst",
        ),
        (
            "simulate --tcp 127.0.0.1:0 --framing mbap --mode ascii",
            "Modbus TCP has no ASCII mode",
        ),
    ];
    for (args, want) in cases {
        let o = Run::words(args).run();
        let err = o.stderr.as_str();
        assert_eq!(o.code, Some(2), "{args}: {err}");
        assert!(err.contains(want), "{args}: {err}");
    }
    // --unit without --framing: clap says what is missing.
    let o = Run::words("check --model f510 --tcp 127.0.0.1:1 --unit 3").run();
    assert_eq!(o.code, Some(2));
    assert!(o.stderr.contains("--framing"));
}

/// `scan --tcp --framing mbap` sweeps unit ids through the simulated gateway and finds the
/// one drive behind it (unit 17), with the identification value; the gateway's 0BH for
/// the units nobody has counts as silence, never as a device. The result's header names
/// the gateway and the unit ids swept.
#[test]
fn scan_through_mbap_finds_the_unit_behind_the_gateway() {
    let sim = GatewaySim::start("l510", 17, &["--gateway-timeout", "30"]);
    let o = Run::words("scan --tcp")
        .arg(&sim.addr)
        .args(["--framing", "mbap"])
        .args(["--addresses", "10-20", "--format", "json", "-q"])
        .run();
    let stdout = o.stdout.as_str();
    assert_eq!(o.code, Some(0), "{stdout}\n{}", o.stderr);
    let v: serde_json::Value = serde_json::from_str(stdout).expect("scan JSON");
    let text = v.to_string();
    assert!(text.contains("\"address\":17"), "{text}");
    assert!(
        text.contains("0110"),
        "the L510's identification value: {text}"
    );
    for absent in [10, 16, 18, 20] {
        assert!(
            !text.contains(&format!("\"address\":{absent},")),
            "unit {absent} has no device: {text}"
        );
    }
    // The sweep is of unit ids: the result names the gateway and every unit id tried,
    // not the one unit a single request goes to.
    let swept = format!(
        "Modbus TCP gateway {} (MBAP, unit ids 10-20 swept, each the node address)",
        sim.addr
    );
    assert_eq!(v["link"], swept.as_str(), "{text}");
    let (code, out, err) = Run::words("scan --tcp")
        .arg(&sim.addr)
        .args(["--framing", "mbap", "--addresses", "10-12,17,20", "-q"])
        .timeout(Duration::from_secs(120))
        .run()
        .parts();
    assert_eq!(code, Some(0), "{out}{err}");
    let header = out.lines().next().unwrap_or_default();
    assert!(
        header.starts_with(&format!(
            "scan of Modbus TCP gateway {} (MBAP, unit ids 10-12,17,20 swept, each the node address): 1 device found",
            sim.addr
        )),
        "{out}"
    );
    assert!(!out.contains("unit 1)"), "{out}");
    // ASCII does not cross MBAP: refused with the reason.
    let o = Run::words("scan --tcp")
        .arg(&sim.addr)
        .args(["--framing", "mbap", "-m", "ascii"])
        .run();
    assert_eq!(o.code, Some(2));
    assert!(o.stderr.contains("no ASCII over Modbus TCP"));
}
