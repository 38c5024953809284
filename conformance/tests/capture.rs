//! `--capture FILE.pcapng` and `monitor --capture-in`: a `check` run against the simulator
//! is recorded; the capture holds every request of the JSON report in order, tshark
//! decodes every frame with the unit ids, function codes and register addresses the
//! bytes carry and marks exactly the frames sent with a wrong CRC on purpose, and the
//! monitor judges the capture offline with the counts the capture holds.
#![cfg(unix)]

mod common;

use std::path::{Path, PathBuf};

use std::sync::OnceLock;

use common::{need, words, Peer, Run, TSHARK_USER_DLT as USER_DLT};
use conformance::capture::{Direction, Reader, FLAG_CRC_ERROR};
use serde_json::Value;

fn dir() -> PathBuf {
    let d = std::env::temp_dir().join(format!("capture-test-{}", std::process::id()));
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// A run of `check --sim f510 --mode MODE` with `extra` arguments, captured: the
/// capture's path and the JSON report.
fn captured_check(name: &str, mode: &str, extra: &[&str]) -> (PathBuf, Value) {
    let d = dir();
    let cap = d.join(format!("{name}.pcapng"));
    let json = d.join(format!("{name}.json"));
    let out = Run::words("check --sim f510 --mode")
        .arg(mode)
        .arg("--quiet")
        .args(extra)
        .arg("--capture")
        .arg(&cap)
        .args(["--format", "json", "-o"])
        .arg(&json)
        .run();
    let stderr = out.stderr.as_str();
    assert!(stderr.contains("capture: "), "{stderr}");
    let report: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    // Exit 0, or 2 where only this host stalled sending a request (an ERROR, never
    // judged: a busy machine), with no deviation either way.
    assert_eq!(report["summary"]["deviation"], 0, "{stderr}");
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
    assert!(matches!(out.code, Some(0 | 2)), "{stderr}");
    (cap, report)
}

/// The whole RTU suite, once for every test of this file.
fn whole_run() -> &'static (PathBuf, Value) {
    static RUN: OnceLock<(PathBuf, Value)> = OnceLock::new();
    RUN.get_or_init(|| captured_check("whole", "rtu", &[]))
}

/// One packet of a capture, owned.
struct Frame {
    interface: u32,
    link_type: u16,
    direction: Option<Direction>,
    flags: u32,
    comment: Option<String>,
    bytes: Vec<u8>,
}

fn frames(path: &Path) -> Vec<Frame> {
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
fn broken_by_host(f: &Frame) -> bool {
    conformance::capture::broken_by_host(Some(f.flags), f.comment.as_deref())
}

/// The frames `monitor --capture-in` judges: all but the sends this host broke (it reads
/// those as not sent, as `check` did).
fn judged(frames: &[Frame]) -> Vec<&Frame> {
    frames.iter().filter(|f| !broken_by_host(f)).collect()
}

fn hex(s: &str) -> Vec<u8> {
    s.split_whitespace()
        .map(|b| u8::from_str_radix(b, 16).unwrap())
        .collect()
}

/// Every exchange's request in the report, with the check it belongs to, in order.
fn requests(report: &Value) -> Vec<(String, Vec<u8>)> {
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

fn crc_ok(b: &[u8]) -> bool {
    b.len() >= 4 && conformance::codec::crc::crc16_frame_ok(b)
}

#[test]
fn the_capture_holds_every_request_of_the_report_in_order_with_directions_and_damage_marked() {
    let (cap, report) = whole_run();
    let frames = frames(cap);
    let sent: Vec<&Frame> = frames
        .iter()
        .filter(|f| f.direction == Some(Direction::Outbound))
        .collect();
    let received = frames
        .iter()
        .filter(|f| f.direction == Some(Direction::Inbound))
        .count();
    assert_eq!(
        sent.len() + received,
        frames.len(),
        "every frame has a direction"
    );
    assert!(received > 100, "{received} frames received");
    // The report's requests are the frames sent, in order (the capture has more: the
    // preflight, liveness probes, the restore).
    let reqs = requests(report);
    assert!(reqs.len() > 100, "{} requests", reqs.len());
    let mut at = 0;
    for (id, r) in &reqs {
        let found = sent[at..].iter().position(|f| &f.bytes == r);
        let Some(i) = found else {
            panic!("{id}: request {r:02X?} is not among the frames sent after frame {at}");
        };
        at += i + 1;
    }
    // The CRC-error bit is set on exactly the frames whose CRC is wrong; every such frame
    // the suite sent names the check that damaged it, and that check is in the report.
    let ids: Vec<&str> = report["checks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["id"].as_str().unwrap())
        .collect();
    let mut damaged = 0;
    for f in &frames {
        assert_eq!(
            f.flags & FLAG_CRC_ERROR != 0,
            !crc_ok(&f.bytes),
            "{:02X?}",
            f.bytes
        );
        if f.direction == Some(Direction::Outbound) && !crc_ok(&f.bytes) {
            damaged += 1;
            let c = f.comment.as_deref().unwrap_or_default();
            let id = c
                .strip_prefix("check ")
                .and_then(|c| c.split(':').next())
                .unwrap_or_default();
            assert!(ids.contains(&id), "comment {c:?} of {:02X?}", f.bytes);
            assert!(c.contains("on purpose"), "{c}");
        } else if f.direction == Some(Direction::Inbound)
            && conformance::capture::late_on_host(f.comment.as_deref()).is_some()
        {
            // A reply this busy host made the simulator begin late: said so.
        } else if !broken_by_host(f) {
            assert_eq!(f.comment, None, "{:02X?}", f.bytes);
        }
    }
    let bad_crc = reqs.iter().find(|(id, _)| id == "rtu.bad-crc").unwrap();
    assert!(!crc_ok(&bad_crc.1));
    assert!(damaged >= 1);
    // The clean simulator never answers with a wrong CRC.
    assert!(frames
        .iter()
        .filter(|f| f.direction == Some(Direction::Inbound))
        .all(|f| crc_ok(&f.bytes)));
}

/// tshark's fields for every frame of `cap`, one row per frame (of a field that occurs
/// several times in a frame, the first).
fn tshark(cap: &Path, fields: &[&str]) -> Vec<Vec<String>> {
    tshark_occurrences(cap, fields, "f")
}

/// [`tshark`], with `occurrence` "f" (first), "l" (last) or "a" (all, comma-separated).
fn tshark_occurrences(cap: &Path, fields: &[&str], occurrence: &str) -> Vec<Vec<String>> {
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

#[test]
fn tshark_decodes_every_frame_as_its_bytes_say_and_marks_exactly_the_bad_crc_frames() {
    if !need(Peer::Tshark) {
        return;
    }
    let (cap, report) = whole_run();
    let frames = frames(cap);
    let rows = tshark(
        cap,
        &[
            "frame.number",
            "mbrtu.unit_id",
            "modbus.func_code",
            "mbrtu.crc16.status",
            "modbus.reference_num",
            "frame.packet_flags_crc_error",
        ],
    );
    assert_eq!(rows.len(), frames.len());
    let mut decoded = 0;
    let mut incorrect = Vec::new();
    for (row, f) in rows.iter().zip(&frames) {
        let b = &f.bytes;
        let (unit, function, status, reference, flag) =
            (&row[1], &row[2], &row[3], &row[4], &row[5]);
        // Wireshark reads our CRC-error bit from the Enhanced Packet Block flags.
        assert_eq!(flag == "1", !crc_ok(b), "frame {}: {b:02X?}", row[0]);
        if unit.is_empty() {
            // Only frames the dissector cannot take are left undecoded: the broadcast
            // address 0 (mbrtu refuses a first byte of 0) and fragments too short for a
            // function code and a CRC.
            assert!(
                b.first() == Some(&0) || b.len() < 5,
                "frame {} not decoded: {b:02X?}",
                row[0]
            );
            continue;
        }
        decoded += 1;
        assert_eq!(unit, &b[0].to_string(), "frame {}", row[0]);
        assert_eq!(function, &(b[1] & 0x7F).to_string(), "frame {}", row[0]);
        if status == "0" {
            incorrect.push(b.clone());
        } else {
            assert_eq!(status, "1", "frame {}", row[0]);
            assert!(crc_ok(b), "frame {}: tshark says its CRC is right", row[0]);
        }
        // A request's register address, where the function has one and the dissector
        // can tell a request from a reply by its length (a 06H reply is a copy of its
        // request: Wireshark leaves it unclassified, without fields).
        if f.direction == Some(Direction::Outbound)
            && crc_ok(b)
            && b.len() >= 8
            && matches!(b[1], 0x03 | 0x10)
        {
            let start = u16::from_be_bytes([b[2], b[3]]);
            assert_eq!(reference, &start.to_string(), "frame {}: {b:02X?}", row[0]);
        }
    }
    assert!(
        decoded * 10 > frames.len() * 9,
        "{decoded} of {} decoded",
        frames.len()
    );
    // The frames Wireshark shows as "CRC incorrect" are the frames sent with a wrong CRC
    // on purpose, and the request of the bad-CRC check is one of them.
    assert!(!incorrect.is_empty());
    for b in &incorrect {
        assert!(!crc_ok(b));
    }
    let bad = requests(report)
        .into_iter()
        .find(|(id, _)| id == "rtu.bad-crc")
        .unwrap()
        .1;
    assert!(incorrect.contains(&bad), "{bad:02X?} not marked");
    // Every report exchange's unit id and function code, as tshark decoded its frame.
    let sent: Vec<(usize, &Frame)> = frames
        .iter()
        .enumerate()
        .filter(|(_, f)| f.direction == Some(Direction::Outbound))
        .collect();
    let mut at = 0;
    for (id, r) in requests(report) {
        let i = sent[at..].iter().position(|(_, f)| f.bytes == r).unwrap() + at;
        at = i + 1;
        let row = &rows[sent[i].0];
        if r[0] != 0 && r.len() >= 5 {
            assert_eq!(row[1], r[0].to_string(), "{id}");
            assert_eq!(row[2], (r[1] & 0x7F).to_string(), "{id}");
        }
    }
}

fn monitor_capture(cap: &Path, name: &str, extra: &[&str]) -> (Option<i32>, Value, String) {
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

fn node<'a>(r: &'a Value, address: &str) -> &'a Value {
    r["monitor"]["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .find(|n| n["address"] == address)
        .unwrap_or_else(|| panic!("no node {address} in {}", r["monitor"]))
}

#[test]
fn monitor_judges_a_clean_capture_with_the_counts_it_holds() {
    // Reads and writes the manual allows, each answered: nothing to find on either side.
    let (cap, report) = captured_check(
        "clean",
        "rtu",
        &words("--only rtu.map.*.first --only rtu.map.*.last --only rtu.write.group-*"),
    );
    assert_eq!(report["summary"]["deviation"], 0);
    let all = frames(&cap);
    // The sends this host broke are not judged (tested apart).
    let frames = judged(&all);
    let sent = frames
        .iter()
        .filter(|f| f.direction == Some(Direction::Outbound) && f.bytes[0] == 1)
        .count();
    let received = frames
        .iter()
        .filter(|f| f.direction == Some(Direction::Inbound))
        .count();
    assert!(sent > 50, "{sent}");
    // A request sent again with nothing received between: the simulator, on a loaded
    // host, answered too late for the master, which tried again. On the line that is a
    // request without a reply, and the monitor must say so, once for each.
    let retries = frames
        .windows(2)
        .filter(|w| {
            w.iter().all(|f| f.direction == Some(Direction::Outbound)) && w[0].bytes == w[1].bytes
        })
        .count() as u64;
    let (code, m, stderr) = monitor_capture(&cap, "clean", &["-a", "1"]);
    let n = node(&m, "01");
    assert_eq!(n["requests"], sent as u64, "{n}");
    let replies = n["replies"].as_u64().unwrap();
    let deviations = n["deviations"].as_u64().unwrap();
    if retries == 0 {
        // Nothing went wrong on the line: nothing to find.
        assert_eq!(code, Some(0), "{stderr}");
        assert_eq!(replies, received as u64, "{n}");
        assert_eq!(deviations, 0, "{n}");
    } else {
        // What the line shows of a late answer and a retry, and nothing else: the
        // request without its reply in time, the reply late or after the next request.
        assert_eq!(code, Some(1), "{stderr}");
        assert!(replies <= received as u64, "{n}");
        assert!(deviations >= 1 && deviations <= 2 * retries, "{n}");
        let kinds: Vec<&String> = n["errors"].as_object().unwrap().keys().collect();
        let explained = [
            "drive.no-reply",
            "drive.late-reply",
            "master.request-before-reply",
            "master.retry",
        ];
        assert!(
            kinds.iter().all(|k| explained.contains(&k.as_str())),
            "{kinds:?}"
        );
    }
    assert_eq!(
        m["monitor"]["ended"],
        format!("end of the capture ({} packets)", all.len())
    );
}

#[test]
fn monitor_judges_the_whole_run_and_finds_the_damage_the_checks_did_on_purpose() {
    let (cap, _) = whole_run();
    let all = frames(cap);
    let frames = judged(&all);
    let (code, m, stderr) = monitor_capture(cap, "whole", &["-a", "1"]);
    // The suite sends what the manual forbids on purpose: the master's side deviates.
    assert_eq!(code, Some(1), "{stderr}");
    let n = node(&m, "01");
    let bad_to_1 = frames
        .iter()
        .filter(|f| {
            f.direction == Some(Direction::Outbound) && f.bytes[0] == 1 && !crc_ok(&f.bytes)
        })
        .count() as u64;
    assert!(bad_to_1 >= 1);
    assert_eq!(n["crc_errors"], bad_to_1, "{n}");
    assert_eq!(n["errors"]["master.bad-checksum"], bad_to_1, "{n}");
    assert!(
        n["errors"]["master.register-not-in-map"].as_u64().unwrap() > 0,
        "{n}"
    );
    assert_eq!(
        m["monitor"]["ended"],
        format!("end of the capture ({} packets)", all.len())
    );
}

#[test]
fn monitor_refuses_what_is_no_capture_and_names_the_offset_of_a_cut() {
    let d = dir();
    let junk = d.join("junk.pcapng");
    std::fs::write(&junk, b"not a capture at all").unwrap();
    let (code, _, stderr) = monitor_capture(&junk, "junk", &[]);
    assert_eq!(code, Some(2), "{stderr}");
    assert!(stderr.contains("at byte 0"), "{stderr}");
    // A capture cut inside its last block: the packets before it are judged.
    let (cap, _) = whole_run();
    let data = std::fs::read(cap).unwrap();
    let cut = d.join("cut.pcapng");
    std::fs::write(&cut, &data[..data.len() - 3]).unwrap();
    let (code, m, stderr) = monitor_capture(&cut, "cut", &["-a", "1"]);
    assert_eq!(code, Some(1), "{stderr}");
    assert!(
        stderr.contains("Enhanced Packet Block cut short"),
        "{stderr}"
    );
    let ended = m["monitor"]["ended"].as_str().unwrap();
    let whole = frames(cap).len();
    assert!(
        ended.starts_with(&format!(
            "end of the capture, cut short after {} packets",
            whole - 1
        )),
        "{ended}"
    );
}

#[test]
fn a_fuzz_capture_decodes_in_tshark_and_every_damaged_frame_is_marked_and_named() {
    if !need(Peer::Tshark) {
        return;
    }
    let d = dir();
    let cap = d.join("fuzz.pcapng");
    let out = Run::words("fuzz --sim f510 --mode rtu --cases 150 --quiet")
        .arg("--capture")
        .arg(&cap)
        .args(["--format", "json", "-o"])
        .arg(d.join("fuzz.json"))
        .run();
    assert_eq!(out.code, Some(0), "{}", out.stderr);
    let frames = frames(&cap);
    let sent = frames
        .iter()
        .filter(|f| f.direction == Some(Direction::Outbound))
        .count();
    assert!(sent >= 150, "{sent} frames sent for 150 cases");
    let rows = tshark_occurrences(
        &cap,
        &[
            "frame.number",
            "frame.packet_flags_crc_error",
            "mbrtu.unit_id",
            "mbrtu.crc16.status",
        ],
        "a",
    );
    assert_eq!(rows.len(), frames.len());
    let mut damaged = 0;
    // Pieces of a reply still to come: a reply the host handed over in two reads with a
    // silence of the frame gap between (a descheduled simulator or reader) is two
    // packets, as the master read it.
    let mut piece: Option<Vec<u8>> = None;
    for (k, (row, f)) in rows.iter().zip(&frames).enumerate() {
        let b = &f.bytes;
        assert_eq!(f.link_type, 147);
        assert_eq!(row[1] == "1", !crc_ok(b), "frame {}: {b:02X?}", row[0]);
        let statuses: Vec<&str> = row[3].split(',').filter(|s| !s.is_empty()).collect();
        if f.direction == Some(Direction::Inbound) {
            let joined = piece.take().map(|p| [p, b.clone()].concat());
            let next_inbound = frames
                .get(k + 1)
                .is_some_and(|n| n.direction == Some(Direction::Inbound));
            match joined {
                None if crc_ok(b) => {
                    // The simulator's replies: whole frames, decoded, CRC right.
                    assert_eq!(statuses, ["1"], "frame {}: {b:02X?}", row[0]);
                    assert_eq!(row[2].split(',').next().unwrap(), b[0].to_string());
                }
                // Its first piece (the next packet is inbound too), or a later one.
                j => {
                    let so_far = j.unwrap_or_else(|| b.clone());
                    if crc_ok(&so_far) || whole_replies(&so_far) {
                        // Or several replies a starved host read together (a stale one
                        // and the next): each whole, one after the other.
                        common::note(&format!(
                            "frame {}: the end of a reply handed over in pieces: {so_far:02X?}",
                            row[0]
                        ));
                    } else {
                        assert!(
                            next_inbound,
                            "frame {}: {b:02X?} is not a whole reply, nor its pieces ({so_far:02X?})",
                            row[0]
                        );
                        piece = Some(so_far);
                    }
                }
            }
        } else if !crc_ok(b) {
            damaged += 1;
            // Wireshark never shows a damaged frame as all right, and the comment says
            // the campaign damaged it.
            assert!(
                !statuses.iter().all(|s| *s == "1") || statuses.is_empty(),
                "frame {}",
                row[0]
            );
            let c = f.comment.as_deref().unwrap_or_default();
            assert!(
                c.starts_with("fuzz") && c.contains("on purpose"),
                "frame {}: {c:?}",
                row[0]
            );
        }
    }
    assert!(piece.is_none(), "a reply cut at the end: {piece:02X?}");
    assert!(damaged > 5, "{damaged} damaged frames in 150 cases");
}

#[test]
fn an_ascii_capture_keeps_the_characters_under_link_type_148_and_the_monitor_judges_it() {
    let (cap, report) = captured_check(
        "ascii",
        "ascii",
        &words("--only ascii.map.group-0.* --only ascii.map.group-1.*"),
    );
    let frames = frames(&cap);
    assert!(frames.iter().all(|f| f.link_type == 148));
    let sent: Vec<&Frame> = frames
        .iter()
        .filter(|f| f.direction == Some(Direction::Outbound))
        .collect();
    let reqs = requests(&report);
    assert!(reqs.len() >= 4, "{} requests", reqs.len());
    for (id, r) in reqs {
        assert!(sent.iter().any(|f| f.bytes == r), "{id}: {r:02X?}");
        assert!(r.starts_with(b":") && r.ends_with(b"\r\n"), "{id}");
    }
    for f in &frames {
        let lrc_ok = conformance::codec::ascii::is_valid_frame(&f.bytes);
        // A whole frame carries its RTU equivalent in its comment.
        if lrc_ok {
            let mut rtu = [0u8; 256];
            let n = conformance::codec::ascii_to_rtu(&f.bytes, &mut rtu).unwrap();
            let shown: Vec<String> = rtu[..n].iter().map(|b| format!("{b:02X}")).collect();
            let want = format!("as RTU: {}", shown.join(" "));
            // After the mark of a reply the simulator's host began late, where there is one.
            let c = f.comment.as_deref().unwrap_or_default();
            assert!(
                c == want
                    || (conformance::capture::late_on_host(Some(c)).is_some()
                        && c.ends_with(&format!("; {want}"))),
                "{c:?}: {want}"
            );
        }
        assert_eq!(
            f.flags & FLAG_CRC_ERROR != 0,
            !lrc_ok,
            "{:?}",
            String::from_utf8_lossy(&f.bytes)
        );
    }
    let (code, m, stderr) = monitor_capture(&cap, "ascii", &["-a", "1", "--mode", "ascii"]);
    assert!(matches!(code, Some(0 | 1)), "{stderr}");
    let n = node(&m, "01");
    let to_1 = sent.iter().filter(|f| f.bytes.starts_with(b":01")).count() as u64;
    assert!(to_1 >= 4);
    assert_eq!(n["requests"], to_1, "{n}");
    assert_eq!(n["crc_errors"], 0, "{n}");
}

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
    let report: Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("bus.json")).unwrap()).unwrap();
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
    use std::io::{BufRead, BufReader};
    if !need(Peer::Tshark) {
        return;
    }
    let d = dir();
    let line_cap = d.join("tap-line.pcapng");
    let tap_cap = d.join("tap.pcapng");
    let (m, tap) = (d.join("tap-master"), d.join("tap-tap"));
    let mut bus = Run::words("bus --model f510 -a 1 --quiet --link")
        .command()
        .arg(format!("m={}", m.display()))
        .arg("--link")
        .arg(format!("tap={}", tap.display()))
        .arg("--capture")
        .arg(&line_cap)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(bus.stdout.take().unwrap()).lines();
    for _ in 0..2 {
        lines.next().unwrap().unwrap();
    }
    let mut monitor = Run::words("monitor --model f510 -a 1 -b 9600 --duration 8 --port")
        .command()
        .arg(&tap)
        .arg("--capture")
        .arg(&tap_cap)
        .args(["--format", "json", "-o"])
        .arg(d.join("tap.json"))
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut heard = BufReader::new(monitor.stderr.take().unwrap()).lines();
    let first = heard.next().unwrap().unwrap();
    assert!(first.starts_with("listening on"), "{first}");
    let drain = std::thread::spawn(move || heard.map_while(Result::ok).collect::<Vec<_>>());
    let out = Run::words("check --model f510 --mode rtu -a 1 --quiet --port")
        .arg(&m)
        .args(["--only", "rtu.map.group-0.*", "--format", "json", "-o"])
        .arg(d.join("tap-check.json"))
        .run();
    let status = monitor.wait().unwrap();
    let stderr = drain.join().unwrap().join("\n");
    bus.kill().unwrap();
    bus.wait().unwrap();
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

/// A classic pcap file as a serial sniffer writes it: RTU frames under link type 147,
/// no direction, in either byte order, with microsecond or nanosecond times.
fn sniffer_pcap(big: bool, nanos: bool, frames: &[(u64, &[u8])]) -> Vec<u8> {
    let w32 = |v: &mut Vec<u8>, x: u32| {
        v.extend_from_slice(&if big {
            x.to_be_bytes()
        } else {
            x.to_le_bytes()
        })
    };
    let mut v = Vec::new();
    w32(&mut v, if nanos { 0xA1B2_3C4D } else { 0xA1B2_C3D4 });
    v.extend_from_slice(&if big { [0, 2, 0, 4] } else { [2, 0, 4, 0] });
    for x in [0, 0, 65535, 147] {
        w32(&mut v, x);
    }
    for (t_us, bytes) in frames {
        let sec = 1_700_000_000 + t_us / 1_000_000;
        let frac = if nanos {
            t_us % 1_000_000 * 1000
        } else {
            t_us % 1_000_000
        };
        for x in [sec, frac, bytes.len() as u64, bytes.len() as u64] {
            w32(&mut v, x as u32);
        }
        v.extend_from_slice(bytes);
    }
    v
}

#[test]
fn monitor_judges_a_sniffers_pcap_in_either_byte_order_and_resolution() {
    // Node 1 reads 2520H twice, each answered in 10 ms: first with one register, then
    // with two (one was asked for): one deviation, on the drive's side.
    let read = [0x01, 0x03, 0x25, 0x20, 0x00, 0x01, 0x8E, 0xCC];
    let reply = [0x01, 0x03, 0x02, 0x00, 0x04, 0xB9, 0x87];
    let read2 = read;
    let mut wrong = vec![0x01, 0x03, 0x04, 0x00, 0x04, 0x00, 0x00];
    let crc = conformance::codec::crc::crc16(&wrong).to_le_bytes();
    wrong.extend_from_slice(&crc);
    let frames: [(u64, &[u8]); 4] = [
        (0, &read),
        (19_200, &reply),
        (200_000, &read2),
        (219_200, &wrong),
    ];
    let d = dir();
    for (big, nanos) in [(false, false), (true, true), (true, false), (false, true)] {
        let name = format!("sniffer-{big}-{nanos}");
        let path = d.join(format!("{name}.pcap"));
        std::fs::write(&path, sniffer_pcap(big, nanos, &frames)).unwrap();
        let (code, m, stderr) = monitor_capture(&path, &name, &["-a", "1"]);
        assert_eq!(code, Some(1), "{name}: {stderr}");
        let n = node(&m, "01");
        assert_eq!(
            (n["requests"].as_u64(), n["replies"].as_u64()),
            (Some(2), Some(2)),
            "{name}: {n}"
        );
        assert_eq!(n["deviations"], 1, "{name}: {n}");
        let kinds: Vec<&String> = n["errors"].as_object().unwrap().keys().collect();
        assert!(
            kinds.len() == 1 && kinds[0].starts_with("drive."),
            "{name}: {kinds:?}"
        );
        // Response times from the file's times: the reply began 10 ms after the 8-byte
        // request ended, and its first character took 1.15 ms at 9600 8E1 (the monitor
        // measures to its arrival, as a tap hears it).
        let p50 = n["response_ms"]["p50"].as_f64().unwrap();
        assert!((10.8..=11.6).contains(&p50), "{name}: {p50}");
    }
}

/// The issue's bar: `monitor --capture-in` of a `check` run's capture gives the same
/// verdicts for the same exchanges as the run's report. A simulator with a planted fault
/// (every exception code one too high), so that some exchanges differ: each exchange of
/// the report is found in the monitor's log, in order, and the two agree on every one.
#[test]
fn monitor_capture_in_judges_every_exchange_of_the_check_run_as_check_did() {
    let d = dir();
    let (cap, json, heard) = (
        d.join("agree.pcapng"),
        d.join("agree.json"),
        d.join("agree.heard.jsonl"),
    );
    let out = Run::words("check --sim f510 --mode rtu --quiet")
        .args(["--quirk", "wrong-exception", "--capture"])
        .arg(&cap)
        .args(["--format", "json", "-o"])
        .arg(&json)
        .run();
    // Exit 1: deviations (the planted fault). 2 only where this host stalled sending a
    // request (an ERROR, never judged); the other exchanges are still compared.
    let check: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert!(matches!(out.code, Some(1 | 2)), "{}", out.stderr);
    assert_eq!(check["complete"], true, "{}", check["stopped"]);
    for c in check["checks"].as_array().unwrap() {
        if c["status"] == "error" {
            let why = c["summary"].as_str().unwrap();
            assert!(
                why.contains("could not send the request"),
                "{}: {why}",
                c["id"]
            );
        }
    }
    let (code, report, stderr) = monitor_capture(
        &cap,
        "agree",
        &["-a", "1", "--log", heard.to_str().unwrap()],
    );
    assert_eq!(code, Some(1), "{stderr}");
    let heard: Vec<Value> = std::fs::read_to_string(&heard)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let (agree, _) = common::agree::exchanges("capture of check", &check, &heard, &[]);
    assert!(agree > 150, "only {agree} exchanges compared");
    let errors = &node(&report, "01")["errors"];
    assert!(
        errors["drive.wrong-exception"].as_u64().unwrap() > 0,
        "{errors}"
    );
}

/// A run through a Modbus TCP gateway records the TCP stream, each MBAP frame in a
/// segment under made-up Ethernet, IPv4 and TCP headers (server port 502): the capture
/// holds every request of the report as an MBAP frame in order, and tshark decodes each
/// as Modbus/TCP with its transaction, unit, function and register, with good checksums.
#[test]
fn a_gateway_run_records_its_mbap_frames_as_tcp_that_tshark_decodes_as_modbus_tcp() {
    let gw = common::GatewaySim::start("f510", 1, &[]);
    let d = dir();
    let cap = d.join("mbap.pcapng");
    let json = d.join("mbap.json");
    let out = Run::words("check --model f510 --tcp")
        .arg(&gw.addr)
        .args(["--framing", "mbap"])
        .args(["--mode", "rtu", "--only", "rtu.map.monitor.*", "--quiet"])
        .arg("--capture")
        .arg(&cap)
        .args(["--format", "json", "-o"])
        .arg(&json)
        .run();
    let stderr = out.stderr.as_str();
    assert_eq!(out.code, Some(0), "{stderr}");
    let report: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
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
    let ours: Vec<&Frame> = frames[3..]
        .iter()
        .filter(|f| f.direction == Some(Direction::Outbound))
        .collect();
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
        let inbound: Vec<&Frame> = frames
            .iter()
            .filter(|f| f.direction == Some(Direction::Inbound))
            .collect();
        let outbound: Vec<&Frame> = frames
            .iter()
            .filter(|f| f.direction == Some(Direction::Outbound))
            .collect();
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

/// Kinds of finding per node of a monitor report, leaving out the drive's timing (a
/// capture made by a program on a busy host has its host's timing, not the line's).
fn kinds_by_node(r: &Value) -> Vec<(String, u64, Vec<String>)> {
    r["monitor"]["nodes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|n| {
            let mut kinds: Vec<String> = n["errors"]
                .as_object()
                .map(|o| o.keys().cloned().collect())
                .unwrap_or_default();
            kinds.retain(|k| !common::agree::TIMING_KINDS.contains(&k.as_str()));
            (
                n["address"].as_str().unwrap().to_string(),
                n["replies"].as_u64().unwrap_or(0),
                kinds,
            )
        })
        .collect()
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
    use std::io::{BufRead, BufReader};
    let d = dir().join("alike");
    std::fs::create_dir_all(&d).unwrap();
    let (m, tap) = (d.join("m"), d.join("tap"));
    let mut bus = Run::words("bus --model f510 -a 1,2 --quiet --link")
        .command()
        .arg(format!("m={}", m.display()))
        .arg("--link")
        .arg(format!("tap={}", tap.display()))
        .arg("--capture")
        .arg(d.join("bus.pcapng"))
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut lines = BufReader::new(bus.stdout.take().unwrap()).lines();
    for _ in 0..2 {
        lines.next().unwrap().unwrap();
    }
    let mut monitor = Run::words("monitor --model f510 -a 1,2 -b 9600")
        .command()
        .args(["--duration", "10", "--port"])
        .arg(&tap)
        .arg("--capture")
        .arg(d.join("tap.pcapng"))
        .args(["--format", "json", "-o"])
        .arg(d.join("live.json"))
        .stderr(std::process::Stdio::piped())
        .stdout(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let mut heard = BufReader::new(monitor.stderr.take().unwrap()).lines();
    let first = heard.next().unwrap().unwrap();
    assert!(first.starts_with("listening on"), "{first}");
    let drain = std::thread::spawn(move || heard.map_while(Result::ok).collect::<Vec<_>>());
    let out = Run::words("check --model f510 --mode rtu -a 1,2")
        .args(["--quiet", "--port"])
        .arg(&m)
        .args(["--only", "rtu.map.group-0.*", "--capture"])
        .arg(d.join("check.pcapng"))
        .args(["--format", "json", "-o"])
        .arg(d.join("check.json"))
        .run();
    let status = monitor.wait().unwrap();
    let stderr = drain.join().unwrap().join("\n");
    bus.kill().unwrap();
    bus.wait().unwrap();
    assert_eq!(out.code, Some(0), "{}", out.stderr);
    assert!(matches!(status.code(), Some(0 | 1)), "{stderr}");
    let check: Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("check.json")).unwrap()).unwrap();
    let live: Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("live.json")).unwrap()).unwrap();
    let mut judged = Vec::new();
    for name in ["bus", "tap", "check"] {
        let log = d.join(format!("{name}.heard.jsonl"));
        let (code, report, stderr) = monitor_capture(
            &d.join(format!("{name}.pcapng")),
            &format!("alike-{name}"),
            &["-a", "1,2", "-b", "9600", "--log", log.to_str().unwrap()],
        );
        assert!(matches!(code, Some(0 | 1)), "{name}: {stderr}");
        let heard: Vec<Value> = std::fs::read_to_string(&log)
            .unwrap()
            .lines()
            .map(|l| serde_json::from_str(l).unwrap())
            .collect();
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

/// Issue 33: a `check` run whose host stalls while it paces requests onto the simulator's
/// line (the test stops the process, SIGSTOP, for 20 ms every 100 ms: a silence over t1.5
/// inside many sends). The emulated line carries a request whole, as a real port's UART
/// does (the sender tells the simulator the silences of the whole request before its first
/// character leaves), so no send is broken, none is sent again or given up, and
/// `monitor --capture-in` of the capture judges every exchange as `check` did: no request
/// the drive left unanswered, no retry of the master. Before, each stall inside a request
/// broke it on the line: the runner sent it again (or gave up, exit 2), and the
/// capture's broken sends were judged `drive.no-reply` and their copies `master.retry`.
/// (How a capture marks a send its host did break, on a line that is not told the
/// silences: `transport::capture`'s unit tests.)
#[test]
fn a_check_whose_host_stalls_keeps_its_requests_whole_and_its_capture_agrees() {
    use nix::sys::signal::{kill, Signal};
    use nix::unistd::Pid;
    let d = dir().join("stalled");
    std::fs::create_dir_all(&d).unwrap();
    let (cap, json, log) = (
        d.join("run.pcapng"),
        d.join("run.json"),
        d.join("heard.jsonl"),
    );
    let mut check = Run::words("check --sim f510 --mode rtu --quiet")
        .command()
        .args(["--only", "rtu.map.group-2*", "--capture"])
        .arg(&cap)
        .args(["--format", "json", "-o"])
        .arg(&json)
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let pid = Pid::from_raw(i32::try_from(check.id()).unwrap());
    let mut stops = 0;
    while check.try_wait().unwrap().is_none() {
        if kill(pid, Signal::SIGSTOP).is_ok() {
            std::thread::sleep(std::time::Duration::from_millis(20));
            let _ = kill(pid, Signal::SIGCONT);
            stops += 1;
        }
        std::thread::sleep(std::time::Duration::from_millis(80));
    }
    let out = check.wait_with_output().unwrap();
    let stderr = String::from_utf8_lossy(&out.stderr);
    // A stall may still delay a reply (the simulator's thread is stopped too): the runner
    // runs such a check again, and gives an ERROR only where every run was disturbed.
    assert!(matches!(out.status.code(), Some(0 | 2)), "{stderr}");
    let report: Value = serde_json::from_str(&std::fs::read_to_string(&json).unwrap()).unwrap();
    assert_eq!(report["summary"]["deviation"], 0, "{stderr}");
    assert!(stops >= 5, "only {stops} stops");
    let broken = report["budget"]["rtu"]["broken_sends"]
        .as_u64()
        .unwrap_or(0);
    assert_eq!(broken, 0, "{stops} stops broke sends: {}", report["budget"]);
    for c in report["checks"].as_array().unwrap() {
        let why = c["summary"].as_str().unwrap_or_default();
        assert!(!why.contains("whole"), "{}: {why}", c["id"]);
    }
    let frames = frames(&cap);
    assert!(
        !frames
            .iter()
            .any(|f| conformance::capture::broken_by_host(Some(f.flags), f.comment.as_deref())),
        "a frame is marked broken"
    );
    let (code, monitor, stderr) = monitor_capture(
        &cap,
        "stalled",
        &["-a", "1", "--log", log.to_str().unwrap()],
    );
    assert!(matches!(code, Some(0 | 1)), "{stderr}");
    let errors = &node(&monitor, "01")["errors"];
    for kind in ["drive.no-reply", "master.retry"] {
        assert!(errors.get(kind).is_none(), "{kind}: {errors}");
    }
    let heard: Vec<Value> = std::fs::read_to_string(&log)
        .unwrap()
        .lines()
        .map(|l| serde_json::from_str(l).unwrap())
        .collect();
    let (agree, _) = common::agree::exchanges("capture of a stalled check", &report, &heard, &[]);
    assert!(agree >= 15, "only {agree} exchanges compared");
}

/// Whether `bytes` are two or more whole RTU replies one after the other, each as long
/// as its function says and with its CRC right.
fn whole_replies(bytes: &[u8]) -> bool {
    use conformance::codec::deframe::bus_rtu_frame_len;
    use conformance::codec::Direction;
    let (mut at, mut frames) = (0, 0);
    while at < bytes.len() {
        match bus_rtu_frame_len(Direction::Response, &bytes[at..]) {
            Some(n) if at + n <= bytes.len() && crc_ok(&bytes[at..at + n]) => {
                at += n;
                frames += 1;
            }
            _ => return false,
        }
    }
    frames >= 2
}
