//! Several drives on one bus in one run (`check -a 1,2,5`): one report with a section per
//! node, the checks of the whole bus (broadcasts, another address) once, a node that stops
//! answering ends its own section only. Against this suite's simulator serving several
//! nodes on one pseudo-terminal (per-node state, `QUIRK@NODE`), and against pymodbus's
//! serial server serving two nodes, a device nobody here wrote; and masters nobody here
//! wrote (mbpoll, minimalmodbus) against the simulated bus.

mod common;
use common::{line, words, Kill, Run, Scratch};

use std::collections::BTreeMap;
use std::process::Stdio;
use std::time::Duration;

use serde_json::Value;

fn check(name: &str, args: &[&str]) -> (Option<i32>, Value) {
    common::check_device(&Scratch::new(name), args, Duration::from_secs(240))
}

/// Each check of a report as a line on stderr, `WHO node NODE ID STATUS: SUMMARY`, to
/// read what a peer did.
fn print_checks(who: &str, v: &Value) {
    for c in checks(v) {
        eprintln!(
            "{who} node {} {} {}: {}",
            c["node"].as_str().unwrap_or("bus"),
            c["id"].as_str().unwrap(),
            c["status"],
            c["summary"].as_str().unwrap()
        );
    }
}

fn checks(v: &Value) -> &Vec<Value> {
    v["checks"].as_array().unwrap()
}

/// Results per check id: the nodes they name ("-" for a check of the whole bus).
fn nodes_per_id(v: &Value) -> BTreeMap<String, Vec<String>> {
    let mut out: BTreeMap<String, Vec<String>> = BTreeMap::new();
    for c in checks(v) {
        out.entry(c["id"].as_str().unwrap().to_string())
            .or_default()
            .push(c["node"].as_str().unwrap_or("-").to_string());
    }
    out
}

const BUS_CHECKS: [&str; 3] = [
    "rtu.broadcast.write",
    "rtu.broadcast.read",
    "rtu.other-address",
];

#[test]
fn the_whole_suite_runs_per_node_and_the_bus_checks_once() {
    let (exit, v) = check(
        "whole",
        &["--sim", "f510", "-a", "1,2", "--mode", "rtu", "--no-pace"],
    );
    assert_eq!(exit, Some(0), "{}", v["summary"]);
    assert_eq!(v["complete"], true, "{}", v["stopped"]);
    assert_eq!(v["summary"]["deviation"], 0);
    assert_eq!(v["summary"]["error"], 0);
    let nodes = v["device"]["nodes"].as_array().unwrap();
    let addresses: Vec<&str> = nodes
        .iter()
        .map(|n| n["address"].as_str().unwrap())
        .collect();
    assert_eq!(addresses, ["01", "02"]);
    for n in nodes {
        assert_eq!(n["identification"], "0510", "{n}");
        assert!(n["stopped"].is_null(), "{n}");
    }
    let per_id = nodes_per_id(&v);
    for (id, nodes) in &per_id {
        if BUS_CHECKS.contains(&id.as_str()) {
            assert_eq!(nodes, &["-"], "{id} runs once for the bus");
        } else if id == "rtu.preflight" {
            // Each node's preflight, and the bus section's.
            assert_eq!(nodes, &["01", "02", "-"], "{id}");
        } else {
            assert_eq!(nodes, &["01", "02"], "{id} runs once per node");
        }
    }
    for id in BUS_CHECKS {
        assert!(per_id.contains_key(id), "{id} missing");
    }
    // The broadcast write changes every node: each is journalled and restored.
    let restored: Vec<(&str, &str)> = v["restore"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|r| r["register"] == "2502")
        .map(|r| (r["node"].as_str().unwrap(), r["detail"].as_str().unwrap()))
        .collect();
    for node in ["01", "02"] {
        assert!(
            restored.iter().any(|(n, _)| *n == node),
            "2502H of node {node} is not in the restore journal: {restored:?}"
        );
    }
    assert!(v["restore"]
        .as_array()
        .unwrap()
        .iter()
        .all(|r| r["restored"] == true));
    let bw = checks(&v)
        .iter()
        .find(|c| c["id"] == "rtu.broadcast.write")
        .unwrap();
    // The broadcast and a read-back from each node.
    assert_eq!(bw["exchanges"].as_array().unwrap().len(), 3, "{bw}");
}

#[test]
fn a_fault_planted_on_one_node_is_reported_on_that_node_only() {
    let (exit, v) = check(
        "planted",
        &words(
            "--sim f510 -a 1,2,5 --mode rtu --no-pace --quirk \
        wrong-exception@2 --quirk reply-to-broadcast@5 --only rtu.map.group-0* --only \
        rtu.function.* --only rtu.broadcast.* --only rtu.other-address",
        ),
    );
    assert_eq!(exit, Some(1), "{}", v["summary"]);
    let quirks: Vec<(String, Value)> = v["device"]["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            (
                n["address"].as_str().unwrap().to_string(),
                n["quirks"].clone(),
            )
        })
        .collect();
    assert_eq!(
        quirks[1],
        ("02".into(), serde_json::json!(["wrong-exception"]))
    );
    assert_eq!(
        quirks[2],
        ("05".into(), serde_json::json!(["reply-to-broadcast"]))
    );
    let deviating: Vec<(String, String)> = checks(&v)
        .iter()
        .filter(|c| c["status"] == "deviation")
        .map(|c| {
            (
                c["node"].as_str().unwrap_or("-").to_string(),
                c["id"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    assert!(!deviating.is_empty());
    for (node, id) in &deviating {
        match id.as_str() {
            // Node 05 answers broadcasts: seen once, in the bus section.
            "rtu.broadcast.read" | "rtu.broadcast.write" => assert_eq!(node, "-", "{id}"),
            _ => assert_eq!(
                node, "02",
                "{id}: only node 02 has the wrong exception codes"
            ),
        }
    }
    assert!(
        deviating.iter().any(|(_, id)| id == "rtu.broadcast.read"),
        "{deviating:?}"
    );
    assert!(
        deviating
            .iter()
            .any(|(n, id)| n == "02" && id.starts_with("rtu.function.")),
        "{deviating:?}"
    );
}

#[test]
fn a_dead_node_ends_its_own_section_only() {
    let (exit, v) = check(
        "dead",
        &words(
            "--sim f510 -a 1,2,5 --mode rtu --no-pace --quirk dead@2 \
        --only rtu.map.group-0* --only rtu.broadcast.*",
        ),
    );
    assert_eq!(
        exit,
        Some(2),
        "a node that does not answer leaves the run incomplete"
    );
    assert_eq!(v["complete"], false);
    let stopped = v["stopped"].as_str().unwrap();
    assert!(stopped.contains("node 02H"), "{stopped}");
    let nodes = v["device"]["nodes"].as_array().unwrap();
    assert!(
        nodes[1]["stopped"].as_str().unwrap().contains("preflight"),
        "{}",
        nodes[1]
    );
    assert!(nodes[0]["stopped"].is_null() && nodes[2]["stopped"].is_null());
    let per_id = nodes_per_id(&v);
    // Nodes 01 and 05 were checked whole; 02 has its failed preflight only.
    assert_eq!(per_id["rtu.map.group-0.first"], ["01", "05"]);
    assert_eq!(per_id["rtu.preflight"], ["01", "02", "05", "-"]);
    for c in checks(&v) {
        let node = c["node"].as_str().unwrap_or("-");
        if node == "02" {
            assert_eq!(c["status"], "error", "{c}");
        } else {
            assert_ne!(c["status"], "error", "{c}");
            assert_ne!(c["status"], "deviation", "{c}");
        }
    }
    // The broadcast write is read back from the nodes that answer.
    let bw = checks(&v)
        .iter()
        .find(|c| c["id"] == "rtu.broadcast.write")
        .unwrap();
    assert_eq!(bw["status"], "pass", "{bw}");
    let reads: Vec<&str> = bw["exchanges"].as_array().unwrap()[1..]
        .iter()
        .map(|e| e["request"].as_str().unwrap())
        .collect();
    assert!(
        reads[0].starts_with("01 ") && reads[1].starts_with("05 "),
        "{reads:?}"
    );
}

#[test]
fn lists_and_refusals() {
    let run = |args: &[&str]| Run::new(args).run();
    let o = run(&["fuzz", "--sim", "f510", "-a", "1,2", "--cases", "1"]);
    assert_eq!(o.code, Some(2));
    assert!(
        o.stderr
            .as_str()
            .contains("several drives on one bus are for `check`"),
        "{}",
        o.stderr
    );
    let o = run(&words("check --sim f510 -a 1,2 --other-address 2"));
    assert_eq!(o.code, Some(2));
    assert!(o.stderr.contains("--other-address"));
    let o = run(&words(
        "check --sim f510 -a 1,2 --quirk dead@3 --only identification",
    ));
    assert_eq!(o.code, Some(2));
    assert!(
        o.stderr.contains("node 3 is not on the bus"),
        "{}",
        o.stderr
    );
    let o = run(&["check", "--sim", "f510", "-a", "1,1"]);
    assert_eq!(o.code, Some(2));
    assert!(o.stderr.contains("twice"));
}

/// pymodbus's serial server with nodes 1 and 2 (each its own registers), checked as a bus
/// of F510s with a node 3 it does not serve. Its deviations from the F510 manual are its
/// own; what is asserted is what it does and the report's shape. pymodbus 3.16.1 answers
/// every address it does not serve (3, FEH, the broadcast 00H) with exception 04H, so
/// node 3 is not silent: it is checked, and every read of it deviates.
#[test]
fn pymodbus_serving_two_nodes_is_checked_node_by_node() {
    let d = Scratch::new("pymodbus");
    let Some(peer) = common::pymodbus_serial_nodes(&d, "rtu", "1,2") else {
        return;
    };
    let b = peer.port.clone();
    let (exit, v) = common::check_device(
        &d,
        &line(&[
            "--model f510 --port",
            b.to_str().unwrap(),
            "-P none --timeout 300 -a 1,2,3 --only rtu.map.group-0* --only rtu.write.group-0 \
             --only rtu.broadcast.* --only rtu.other-address",
        ]),
        Duration::from_secs(180),
    );
    print_checks("pymodbus", &v);
    // Node 3 answers every read with an exception: that is the device's answer, so
    // deviations (exit 1), never "could not tell" (issue 28).
    assert_eq!(exit, Some(1), "{}", v["summary"]);
    assert_eq!(v["summary"]["error"], 0, "{}", v["summary"]);
    let per_id = nodes_per_id(&v);
    assert_eq!(per_id["rtu.map.group-0.first"], ["01", "02", "03"]);
    assert_eq!(per_id["rtu.preflight"], ["01", "02", "03", "-"]);
    for id in BUS_CHECKS {
        assert_eq!(per_id[id], ["-"], "{id}");
    }
    let find = |id: &str, node: &str| {
        checks(&v)
            .iter()
            .find(|c| c["id"] == id && c["node"].as_str().unwrap_or("-") == node)
            .unwrap_or_else(|| panic!("{id} of {node}"))
            .clone()
    };
    // Nodes 1 and 2 are one server's: they answer alike, and keep their own registers.
    for id in [
        "rtu.map.group-0.first",
        "rtu.map.group-0.past-end",
        "rtu.write.group-0",
    ] {
        assert_eq!(find(id, "01")["status"], find(id, "02")["status"], "{id}");
    }
    assert_eq!(find("rtu.map.group-0.first", "01")["status"], "pass");
    // Node 3: exception 04H to every read.
    let first3 = find("rtu.map.group-0.first", "03");
    assert_eq!(first3["status"], "deviation");
    let received = first3["exchanges"][0]["received"].as_str().unwrap();
    assert!(received.starts_with("03 83 04"), "{received}");
    // The writing check of node 3 cannot read the register it would write: the manual
    // serves it, node 3 refused it: a DEVIATION with the frames, not an ERROR.
    let w3 = find("rtu.write.group-0", "03");
    assert_eq!(w3["status"], "deviation", "{w3}");
    assert!(
        w3["summary"]
            .as_str()
            .unwrap()
            .starts_with("cannot read 0000H first: the manual serves it, the device refused it with exception 04H"),
        "{w3}"
    );
    assert!(w3["exchanges"][0]["received"]
        .as_str()
        .unwrap()
        .starts_with("03 83 04"));
    // The broadcast read is answered (00 83 04 ..): a deviation, once for the bus.
    let br = find("rtu.broadcast.read", "-");
    assert_eq!(br["status"], "deviation");
    assert!(br["exchanges"][0]["received"]
        .as_str()
        .unwrap()
        .starts_with("00 83 04"));
    // The broadcast write is judged on the nodes whose register could be read first; node
    // 3's refusal of that read is a deviation of its own.
    let bw = find("rtu.broadcast.write", "-");
    assert_eq!(bw["status"], "deviation", "{bw}");
    let texts: Vec<&str> = common::strings(&bw["findings"], "text");
    assert!(
        texts
            .iter()
            .any(|t| t.contains("cannot read 2502H of node 03H first")
                && t.contains("refused it with exception 04H")),
        "{texts:?}"
    );
}

/// mbpoll and minimalmodbus (masters nobody here wrote) against `simulate -a 1,2,5`: each
/// node answers with its own address and keeps its own registers; node 3 is silent.
#[test]
fn foreign_masters_see_three_drives_on_the_simulated_bus() {
    if !common::need_all(&[common::Peer::Mbpoll, common::Peer::Minimalmodbus]) {
        return;
    }
    let d = Scratch::new("masters");
    let link = d.join("bus");
    let _sim = Kill(
        Run::words("simulate --model f510 --pty --quiet -a 1,2,5 --link")
            .command()
            .arg(&link)
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    common::wait_for(&link);
    let port = link.to_str().unwrap();
    // mbpoll [options] PORT [values to write]
    let mbpoll = |args: &[&str], values: &[&str]| {
        let o = Run::program("mbpoll", words("-m rtu -b 9600 -P even -t 4:hex -1 -o 0.5"))
            .args(args)
            .arg(port)
            .args(values)
            .run();
        (o.code, o.stdout)
    };
    // Write 1234H to the frequency command (2502H, mbpoll counts from 1: 9475) of node 2.
    let (code, out) = mbpoll(&["-a", "2", "-r", "9475"], &["0x1234"]);
    assert_eq!(code, Some(0), "{out}");
    let (code, out) = mbpoll(&["-a", "2", "-r", "9475"], &[]);
    assert_eq!(code, Some(0), "{out}");
    assert!(
        out.contains("[9475]: \t0x1234"),
        "node 2 keeps the value: {out}"
    );
    for node in ["1", "5"] {
        let (code, out) = mbpoll(&["-a", node, "-r", "9475"], &[]);
        assert_eq!(code, Some(0), "{out}");
        assert!(
            out.contains("[9475]: \t0x0000"),
            "node {node} has its own registers: {out}"
        );
    }
    let (code, out) = mbpoll(&["-a", "3", "-r", "9475"], &[]);
    assert_ne!(code, Some(0), "no node 3 on the bus: {out}");
    // minimalmodbus reads the identification register (252FH) of each node.
    let script = format!(
        "import minimalmodbus, serial\n\
         for n in (1, 2, 5):\n\
         \x20   i = minimalmodbus.Instrument({port:?}, n)\n\
         \x20   i.serial.baudrate = 9600\n\
         \x20   i.serial.timeout = 0.5\n\
         \x20   print(n, hex(i.read_register(0x252F)), hex(i.read_register(0x2502)))\n\
         i = minimalmodbus.Instrument({port:?}, 3)\n\
         i.serial.timeout = 0.3\n\
         try:\n\
         \x20   i.read_register(0x252F)\n\
         \x20   print('3 answered')\n\
         except minimalmodbus.NoResponseError:\n\
         \x20   print('3 silent')\n"
    );
    let o = Run::program(common::python(), ["-c", &script]).run();
    let out = o.stdout.as_str();
    assert_eq!(o.code, Some(0), "{out}{}", o.stderr);
    assert_eq!(
        out.lines().collect::<Vec<_>>(),
        ["1 0x510 0x0", "2 0x510 0x1234", "5 0x510 0x0", "3 silent"],
        "{out}"
    );
}

/// Through a Modbus TCP gateway each node's unit id is its address: against the simulated
/// gateway serving two drives, and against pymodbus's TCP server with units 1 and 2.
#[test]
fn several_nodes_through_a_modbus_tcp_gateway() {
    let only = [
        "--only",
        "rtu.map.group-0*",
        "--only",
        "rtu.write.group-0",
        "--only",
        "rtu.broadcast.*",
        "--only",
        "rtu.other-address",
        "--only",
        "rtu.bad-crc",
    ];
    let port = common::free_port().to_string();
    let addr = format!("127.0.0.1:{port}");
    let _sim = Kill(
        Run::words("simulate --model f510 --quiet -a 1,2 --framing mbap --tcp")
            .arg(&addr)
            .command()
            .stdout(Stdio::null())
            .spawn()
            .unwrap(),
    );
    common::wait_listening(&addr, Duration::from_secs(30));
    let mut args = common::line(&["--model f510 --tcp", &addr, "--framing mbap -a 1,2"]);
    args.extend(only);
    let d = Scratch::new("mbap-sim");
    let (exit, v) = common::check_device(&d, &args, Duration::from_secs(120));
    assert_eq!(exit, Some(0), "{}", v["summary"]);
    // Behind a gateway the serial line's timing is not ours to bound.
    assert_eq!(v["budget"]["rtu"]["bound_ms"], 0.0);
    let text = Run::words("report")
        .arg(d.join("check.json"))
        .args(["--format", "text"])
        .run();
    let text = text.stdout.as_str();
    assert!(
        text.contains("no line bound: the serial line is behind a gateway"),
        "{text}"
    );
    let per_id = nodes_per_id(&v);
    assert_eq!(per_id["rtu.map.group-0.first"], ["01", "02"]);
    assert_eq!(per_id["rtu.broadcast.write"], ["-"]);
    // The checks a gateway hides SKIP once per node.
    assert_eq!(per_id["rtu.bad-crc"], ["01", "02"]);
    assert!(v["device"]["line"]
        .as_str()
        .unwrap()
        .contains("each node's unit id is its address"));
    // mbpoll through the simulated gateway: units 1 and 2 answer, unit 3 gets the
    // gateway's exception 0BH.
    if common::need(common::Peer::Mbpoll) {
        let poll = |unit: &str| {
            let o = Run::program("mbpoll", ["-m", "tcp", "-p", &port, "-a", unit])
                .args(words("-t 4:hex -r 9505 -1 -o 1 127.0.0.1"))
                .run();
            (o.code, o.text())
        };
        for unit in ["1", "2"] {
            let (code, out) = poll(unit);
            assert_eq!(code, Some(0), "unit {unit}: {out}");
            assert!(out.contains("[9505]: \t0x0004"), "unit {unit}: {out}");
        }
        let (code, out) = poll("3");
        assert_ne!(code, Some(0), "{out}");
        eprintln!(
            "mbpoll -m tcp -a 3 through the simulated gateway: {}",
            out.lines().last().unwrap_or("")
        );
    }
    let o = Run::words("check --model f510 --tcp")
        .arg(&addr)
        .args(["--framing", "mbap", "-a", "1,2", "--unit", "4"])
        .run();
    assert_eq!(o.code, Some(2));
    assert!(o.stderr.contains("leave --unit out"));

    let Some((_server, addr)) = common::pymodbus_tcp_units("1,2") else {
        return;
    };
    let mut args = common::line(&[
        "--model f510 --tcp",
        &addr,
        "--framing mbap -a 1,2,3 --timeout 500",
    ]);
    args.extend(only);
    let (_, v) = common::check_device(
        &Scratch::new("mbap-pymodbus"),
        &args,
        Duration::from_secs(120),
    );
    print_checks("pymodbus tcp", &v);
    let per_id = nodes_per_id(&v);
    // Units 1 and 2 are served. pymodbus 3.16.1 with several units answers a unit id it
    // does not have (3, FEH, 0) with exception 04H, as its serial server does (with one unit
    // it answers 0BH): node 3 is checked, and its reads deviate.
    assert_eq!(per_id["rtu.map.group-0.first"], ["01", "02", "03"]);
    let first3 = checks(&v)
        .iter()
        .find(|c| c["id"] == "rtu.map.group-0.first" && c["node"] == "03")
        .unwrap();
    assert_eq!(first3["status"], "deviation");
    assert!(first3["exchanges"][0]["received"]
        .as_str()
        .unwrap()
        .starts_with("03 83 04"));
    for c in checks(&v) {
        if c["node"] == "01" || c["node"] == "02" {
            assert_ne!(c["status"], "error", "{c}");
        }
    }
    assert!(v["device"]["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .all(|n| n["stopped"].is_null()));
}

/// No node answers: each node's preflight is its ERROR, and the checks of the whole bus
/// are ERRORs that say why, not silently left out.
#[test]
fn a_bus_where_no_node_answers_reports_the_bus_checks_as_not_run() {
    let (exit, v) = check(
        "all-dead",
        &words(
            "--sim f510 -a 1,2 --mode rtu --no-pace --timeout 200 \
        --quirk dead --only rtu.map.group-0.first --only rtu.broadcast.*",
        ),
    );
    assert_eq!(exit, Some(2));
    let per_id = nodes_per_id(&v);
    assert_eq!(per_id["rtu.preflight"], ["01", "02"]);
    for id in ["rtu.broadcast.write", "rtu.broadcast.read"] {
        let c = checks(&v).iter().find(|c| c["id"] == id).unwrap();
        assert_eq!(c["status"], "error", "{c}");
        assert!(
            c["summary"]
                .as_str()
                .unwrap()
                .contains("no node of the bus answers"),
            "{c}"
        );
        assert!(c["node"].is_null());
    }
    let nodes = v["device"]["nodes"].as_array().unwrap();
    assert!(nodes.iter().all(|n| n["stopped"]
        .as_str()
        .is_some_and(|s| s.contains("preflight"))));
}

/// `scan` finds every drive of a simulated bus (and nothing at the addresses between).
#[test]
fn scan_finds_every_node_of_a_simulated_bus() {
    let (_sim, pty) = common::sim_pty(&["--model", "f510", "--pace", "-a", "1,2,5"]);
    // A simulator that starts late on a busy machine is not a missing drive: scan once it
    // answers.
    common::wait_until_answers(
        std::path::Path::new(&pty),
        "rtu",
        &["-b", "9600", "-P", "even"],
    );
    let o = Run::words("scan --port")
        .arg(&pty)
        .args(words("-b 9600 -P even --mode rtu"))
        // A wide reply window: tests run side by side on 2 cores, and a simulator
        // thread scheduled late must not look like a missing drive (the default window's
        // slack on a pseudo-terminal is 5 ms).
        .args(words(
            "--addresses 1-6 --reply-window 150 --format json --quiet",
        ))
        .run();
    assert_eq!(o.code, Some(0), "{}", o.stderr);
    let v: Value = serde_json::from_slice(&o.bytes).unwrap();
    let found: Vec<u64> = v["found"]
        .as_array()
        .unwrap_or_else(|| panic!("{v}"))
        .iter()
        .map(|d| d["address"].as_u64().unwrap())
        .collect();
    assert_eq!(found, [1, 2, 5], "{v}");
}
