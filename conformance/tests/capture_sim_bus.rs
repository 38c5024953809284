//! Captures that the other programs record: `simulate --capture` killed mid-run and
//! served over TCP, `bus --capture` (one interface per endpoint), a tap's `monitor --port
//! --capture`, a gateway run's MBAP frames as TCP, and one run recorded three ways and
//! judged alike by `monitor --capture-in`. (A `check` run's own capture: tests/capture.rs.)
#![cfg(unix)]

mod captured;
mod common;

use captured::*;
use common::{need, Peer, Run};
use conformance::capture::Direction;
use std::time::Duration;

#[test]
fn a_simulator_killed_mid_run_leaves_a_whole_capture_seen_from_the_drive() {
    use std::io::{BufRead, BufReader};
    let d = dir();
    let cap = d.join("simulate.pcapng");
    let mut sim = Run::words("simulate --pty --pace --quiet --capture")
        .command()
        .arg(&cap)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut path = String::new();
    let mut sim_out = BufReader::new(sim.stdout.take().unwrap());
    sim_out.read_line(&mut path).unwrap();
    let out = Run::words("check --model f510 --mode rtu --quiet --port")
        .arg(path.trim())
        .args(["--only", "rtu.map.group-0.*", "--format", "json", "-o"])
        .arg(d.join("simulate.json"))
        .run();
    // Killed, not stopped: no chance to finish anything.
    sim.kill().unwrap();
    sim.wait().unwrap();
    drop(sim_out);
    assert_eq!(out.code, Some(0), "{}", out.stderr);
    let frames = frames(&cap);
    assert!(frames.len() >= 8, "{} frames", frames.len());
    // From the drive's side: the requests came in, the replies went out.
    for f in &frames {
        let request = f.bytes.len() == 8 && f.bytes[1] == 0x03;
        let expected = if request {
            Direction::Inbound
        } else {
            Direction::Outbound
        };
        assert_eq!(f.direction, Some(expected), "{:02X?}", f.bytes);
        assert!(crc_ok(&f.bytes), "{:02X?}", f.bytes);
    }
}

#[test]
fn a_bus_capture_holds_each_endpoints_frames_on_its_own_interface() {
    use std::io::{BufRead, BufReader};
    let d = dir();
    let cap = d.join("bus.pcapng");
    let link = d.join("bus-master");
    let mut bus = Run::words("bus --model f510 -a 1 --quiet --link")
        .command()
        .arg(format!("m={}", link.display()))
        .arg("--capture")
        .arg(&cap)
        .stdout(std::process::Stdio::piped())
        .stderr(std::fs::File::create(d.join("bus.err")).unwrap())
        .spawn()
        .unwrap();
    // One line per endpoint with a path: the master's. The pipe stays open while the bus
    // runs (a bus whose stdout is gone ends).
    let mut first = String::new();
    let mut paths = BufReader::new(bus.stdout.take().unwrap());
    paths.read_line(&mut first).unwrap();
    assert!(first.starts_with("m "), "{first}");
    let out = Run::words("check --model f510 --mode rtu -a 1 --quiet --port")
        .arg(&link)
        .args(["--only", "rtu.map.group-0.*", "--format", "json", "-o"])
        .arg(d.join("bus.json"))
        .run();
    let running = bus.try_wait().unwrap().is_none();
    bus.kill().unwrap();
    bus.wait().unwrap();
    drop(paths);
    assert_eq!(
        out.code,
        Some(0),
        "{} (the bus {}: {})",
        out.stderr.as_str(),
        if running { "was running" } else { "had ended" },
        std::fs::read_to_string(d.join("bus.err")).unwrap_or_default()
    );
    let report = common::json_file(&d.join("bus.json"));
    let frames = frames(&cap);
    // One interface per endpoint (and the line's own, for collisions): the master's is
    // the one that spoke first.
    let m = frames[0].interface;
    let master: Vec<&Frame> = frames.iter().filter(|f| f.interface == m).collect();
    let drive: Vec<&Frame> = frames.iter().filter(|f| f.interface != m).collect();
    assert!(drive.iter().all(|f| f.interface == drive[0].interface));
    let mut at = 0;
    for (id, r) in requests(&report) {
        let i = master[at..]
            .iter()
            .position(|f| f.bytes == r)
            .unwrap_or_else(|| panic!("{id}: {r:02X?} not sent by the master"));
        at += i + 1;
    }
    assert!(drive.len() >= 4, "{} replies", drive.len());
    for f in frames.iter() {
        assert_eq!(
            f.direction,
            Some(Direction::Outbound),
            "sent by its endpoint"
        );
        assert!(crc_ok(&f.bytes), "{:02X?}", f.bytes);
    }
    assert!(drive.iter().all(|f| f.bytes[0] == 1));
}

#[test]
fn a_monitor_on_a_bus_records_what_the_line_carried_and_tshark_decodes_it() {
    if !need(Peer::Tshark) {
        return;
    }
    let d = dir().join("tap");
    std::fs::create_dir_all(&d).unwrap();
    let (line_cap, tap_cap) = (d.join("bus.pcapng"), d.join("tap.pcapng"));
    let (out, status, stderr) = tapped_run(&d, "1", "8", &[]);
    assert_eq!(out.code, Some(0), "{}", out.stderr);
    assert!(matches!(status.code(), Some(0 | 1)), "{stderr}");
    assert!(stderr.contains("capture: "), "{stderr}");
    // The tap heard what the line carried, byte for byte, with no direction.
    let on_line: Vec<u8> = frames(&line_cap)
        .into_iter()
        .flat_map(|f| f.bytes)
        .collect();
    let tapped = frames(&tap_cap);
    let heard_bytes: Vec<u8> = tapped.iter().flat_map(|f| f.bytes.clone()).collect();
    assert_eq!(heard_bytes, on_line);
    for f in &tapped {
        assert_eq!(
            (f.direction, f.flags),
            (None, 0),
            "{:02X?} in {:02X?}",
            f.bytes,
            tapped.iter().map(|f| f.bytes.len()).collect::<Vec<_>>()
        );
    }
    assert!(tapped.len() >= 8, "{} frames", tapped.len());
    // tshark decodes every frame the tap recorded.
    let rows = tshark(
        &tap_cap,
        &["frame.number", "mbrtu.unit_id", "mbrtu.crc16.status"],
    );
    assert_eq!(rows.len(), tapped.len());
    for (row, f) in rows.iter().zip(&tapped) {
        assert_eq!(
            row[1],
            f.bytes[0].to_string(),
            "frame {}: {:02X?}",
            row[0],
            f.bytes
        );
        assert_eq!(row[2], "1", "frame {}", row[0]);
    }
}

/// A run through a Modbus TCP gateway records the TCP stream, each MBAP frame in a
/// segment under made-up Ethernet, IPv4 and TCP headers (server port 502): the capture
/// holds every request of the report as an MBAP frame in order, and tshark decodes each
/// as Modbus/TCP with its transaction, unit, function and register, with good checksums.
#[test]
fn a_gateway_run_records_its_mbap_frames_as_tcp_that_tshark_decodes_as_modbus_tcp() {
    let gw = common::GatewaySim::start("f510", 1, &[]);
    let (cap, out, report) = captured(
        "mbap",
        Run::words("check --model f510 --tcp")
            .arg(&gw.addr)
            .args(["--framing", "mbap"])
            .args(["--mode", "rtu", "--only", "rtu.map.monitor.*", "--quiet"]),
    );
    let stderr = out.stderr.as_str();
    assert_eq!(out.code, Some(0), "{stderr}");
    let frames = frames(&cap);
    assert!(frames
        .iter()
        .all(|f| f.link_type == conformance::capture::tcp::LINKTYPE_ETHERNET));
    // The handshake, then one segment a write and a read.
    let flags = |f: &Frame| f.bytes[14 + 20 + 13];
    assert_eq!(
        frames[..3].iter().map(flags).collect::<Vec<_>>(),
        [0x02, 0x12, 0x10]
    );
    let ours: Vec<&Frame> = frames[3..].iter().filter(|f| f.sent()).collect();
    // Each request of the report (RTU: address, PDU, CRC) is one MBAP frame sent, in
    // order: the same PDU, the unit id the node address.
    let sent: Vec<Vec<u8>> = requests(&report).into_iter().map(|(_, b)| b).collect();
    assert!(!sent.is_empty());
    let mbap: Vec<&[u8]> = ours.iter().map(|f| &f.bytes[54..]).collect();
    assert!(mbap.len() >= sent.len(), "{} < {}", mbap.len(), sent.len());
    let tail = &mbap[mbap.len() - sent.len()..];
    for (m, r) in tail.iter().zip(&sent) {
        assert_eq!(&m[2..4], &[0, 0], "protocol id");
        assert_eq!(usize::from(u16::from_be_bytes([m[4], m[5]])), m.len() - 6);
        assert_eq!(m[6], r[0], "unit id = node address");
        assert_eq!(&m[7..], &r[1..r.len() - 2], "the PDU");
    }
    if !need(Peer::Tshark) {
        return;
    }
    let out = Run::program("tshark", ["-r"])
        .arg(&cap)
        .args([
            "-o",
            "tcp.check_checksum:TRUE",
            "-o",
            "ip.check_checksum:TRUE",
        ])
        .args(["-Y", "mbtcp", "-T", "fields", "-E", "separator=/t"])
        .args([
            "-e",
            "tcp.dstport",
            "-e",
            "mbtcp.unit_id",
            "-e",
            "modbus.func_code",
        ])
        .args([
            "-e",
            "modbus.reference_num",
            "-e",
            "tcp.checksum.status",
            "-e",
            "ip.checksum.status",
        ])
        .run()
        .ok();
    let rows: Vec<Vec<String>> = out
        .stdout
        .lines()
        .map(|l| l.split('\t').map(str::to_string).collect())
        .collect();
    // Every segment carrying data is decoded as Modbus/TCP, with good checksums.
    assert_eq!(rows.len(), frames.len() - 3, "{rows:?}");
    assert!(rows.iter().all(|r| r[4] == "1" && r[5] == "1"), "{rows:?}");
    let queries: Vec<&Vec<String>> = rows.iter().filter(|r| r[0] == "502").collect();
    let last = &queries[queries.len() - sent.len()..];
    for (q, r) in last.iter().zip(&sent) {
        assert_eq!(q[1], r[0].to_string());
        assert_eq!(q[2], r[1].to_string());
        assert_eq!(q[3], u16::from_be_bytes([r[2], r[3]]).to_string());
    }
}

/// `simulate --tcp --capture`, seen from the drive's side: as a Modbus TCP gateway
/// (`--framing mbap`) each connection's stream under made-up headers, the requests from
/// the client, the replies from port 502; as a serial server (RTU frames over TCP) the
/// frames under link type 147, requests inbound and replies outbound.
#[test]
fn a_simulator_served_over_tcp_records_what_it_received_and_sent() {
    let d = dir();
    for framing in ["mbap", "rtu"] {
        let cap = d.join(format!("sim-tcp-{framing}.pcapng"));
        let port = common::free_port();
        let addr = format!("127.0.0.1:{port}");
        let _sim = common::Kill::spawn(
            Run::words("simulate --model f510 -q --tcp")
                .arg(&addr)
                .command()
                .args(["--framing", framing, "--capture"])
                .arg(&cap)
                .stdin(std::process::Stdio::null())
                .stdout(std::process::Stdio::null())
                .stderr(std::process::Stdio::null()),
        );
        common::wait_listening(&addr, std::time::Duration::from_secs(30));
        let out = Run::words("check --model f510 --tcp")
            .arg(&addr)
            .arg("--framing")
            .arg(framing)
            .args(["--mode", "rtu", "--only", "rtu.map.monitor.*", "--quiet"])
            .run();
        assert_eq!(out.code, Some(0), "{framing}: {}", out.stderr);
        let frames = frames(&cap);
        let inbound: Vec<&Frame> = frames.iter().filter(|f| f.received()).collect();
        let outbound: Vec<&Frame> = frames.iter().filter(|f| f.sent()).collect();
        // The map reads (and the preflight, where it is its own read), each answered.
        assert!(
            inbound.len() >= 5 && outbound.len() == inbound.len(),
            "{framing}: {} in, {} out",
            inbound.len(),
            outbound.len()
        );
        if framing == "mbap" {
            // Ethernet, handshake first; the drive's replies come from port 502.
            assert!(frames
                .iter()
                .all(|f| f.link_type == conformance::capture::tcp::LINKTYPE_ETHERNET));
            for f in &outbound {
                assert_eq!(&f.bytes[34..36], &502u16.to_be_bytes());
                assert_eq!(f.bytes[54 + 7] & 0x7F, 0x03, "a read's reply or exception");
            }
            for f in &inbound {
                assert_eq!(&f.bytes[36..38], &502u16.to_be_bytes());
            }
        } else {
            assert!(frames.iter().all(|f| f.link_type == 147));
            assert!(inbound
                .iter()
                .all(|f| f.bytes[1] == 0x03 && f.bytes.len() == 8 && crc_ok(&f.bytes)));
            assert!(outbound.iter().all(|f| crc_ok(&f.bytes)));
        }
    }
}

/// Issue 33: one run of `check` on a `bus` of two F510s, recorded three ways (the bus's
/// own capture, one interface per endpoint, every frame outbound on its sender's; a tap's
/// `monitor --port --capture`, no directions; the master's `check --capture`), is judged
/// by `monitor --capture-in` the same way from each file, and as the live monitor and
/// `check` judged it: every exchange of the report found, with the verdict check gave.
/// The bus's file was read as "every frame from the master's side", so each reply was a
/// new request (`drive.unexpected-reply`, `master.request-before-reply`).
#[test]
fn a_bus_a_tap_and_a_check_capture_of_one_run_are_judged_alike() {
    let d = dir().join("alike");
    std::fs::create_dir_all(&d).unwrap();
    let check_cap = d.join("check.pcapng");
    let (out, status, stderr) =
        tapped_run(&d, "1,2", "10", &["--capture", check_cap.to_str().unwrap()]);
    assert_eq!(out.code, Some(0), "{}", out.stderr);
    assert!(matches!(status.code(), Some(0 | 1)), "{stderr}");
    let check = common::json_file(&d.join("check.json"));
    let live = common::json_file(&d.join("live.json"));
    let mut judged = Vec::new();
    for name in ["bus", "tap", "check"] {
        let log = d.join(format!("{name}.heard.jsonl"));
        let (code, report, stderr) = monitor_capture(
            &d.join(format!("{name}.pcapng")),
            &format!("alike-{name}"),
            &["-a", "1,2", "-b", "9600", "--log", log.to_str().unwrap()],
        );
        assert!(matches!(code, Some(0 | 1)), "{name}: {stderr}");
        let heard = common::json_lines_file(&log);
        let (agree, _) = common::agree::exchanges(&format!("{name} capture"), &check, &heard, &[]);
        assert!(agree >= 8, "{name}: only {agree} exchanges compared");
        judged.push((name, kinds_by_node(&report)));
    }
    // Each node answered every request it was sent, and the three files, the live
    // monitor and one another agree on what was found on whose side.
    let live = kinds_by_node(&live);
    for (name, nodes) in &judged {
        assert_eq!(nodes.len(), 2, "{name}: {nodes:?}");
        for (address, replies, kinds) in nodes {
            assert!(*replies >= 4, "{name}: node {address}: {replies} replies");
            assert!(
                kinds.iter().all(|k| k.starts_with("master.")),
                "{name}: node {address}: {kinds:?}"
            );
        }
        assert_eq!(nodes, &judged[0].1, "{name} against {}", judged[0].0);
        let without_counts = |n: &[(String, u64, Vec<String>)]| {
            n.iter()
                .map(|(a, _, k)| (a.clone(), k.clone()))
                .collect::<Vec<_>>()
        };
        assert_eq!(
            without_counts(nodes),
            without_counts(&live),
            "{name} against the live monitor"
        );
    }
}

/// One run heard three ways, in `d`: a bus of F510 drives at `nodes` (its line captured
/// to bus.pcapng) with the master's end at `m` and a tap at `tap`; a monitor on the tap
/// for `duration` seconds (its capture tap.pcapng, its report live.json), started and
/// heard to be listening; `check` of group 0 on `m` with `check_extra` (its report
/// check.json). What check left, how the monitor ended and what it said after
/// listening.
fn tapped_run(
    d: &std::path::Path,
    nodes: &str,
    duration: &str,
    check_extra: &[&str],
) -> (common::Ran, std::process::ExitStatus, String) {
    let (m, tap) = (d.join("m"), d.join("tap"));
    let bus = common::Bus::start(
        &common::line(&[
            "--model f510 -a",
            nodes,
            "--link",
            &format!("m={}", m.display()),
            "--link",
            &format!("tap={}", tap.display()),
            "--capture",
            d.join("bus.pcapng").to_str().unwrap(),
        ]),
        2,
    );
    let mut monitor = common::Monitor::spawn(
        Run::words("monitor --model f510 -b 9600 -a")
            .args([nodes, "--duration", duration, "--port"])
            .arg(&tap)
            .arg("--capture")
            .arg(d.join("tap.pcapng"))
            .args(["--format", "json", "-o"])
            .arg(d.join("live.json"))
            .command(),
    );
    // The monitor's first word is that it listens.
    assert_eq!(monitor.until_listening(), Vec::<String>::new());
    let out = Run::words("check --model f510 --mode rtu --quiet -a")
        .args([nodes, "--port"])
        .arg(&m)
        .args(["--only", "rtu.map.group-0.*"])
        .args(check_extra)
        .args(["--format", "json", "-o"])
        .arg(d.join("check.json"))
        .run();
    let (status, said) = monitor.finish(Duration::from_secs(600), "the monitor");
    drop(bus);
    (out, status, said[1..].join("\n"))
}
