//! `--capture FILE.pcapng` and `monitor --capture-in`: a `check` run against the simulator
//! is recorded; the capture holds every request of the JSON report in order, tshark
//! decodes every frame with the unit ids, function codes and register addresses the
//! bytes carry and marks exactly the frames sent with a wrong CRC on purpose, and the
//! monitor judges the capture offline with the counts the capture holds.
#![cfg(unix)]

mod captured;
mod common;

use captured::*;
use common::{need, words, Peer, Run};
use conformance::capture::FLAG_CRC_ERROR;
use serde_json::Value;

#[test]
fn the_capture_holds_every_request_of_the_report_in_order_with_directions_and_damage_marked() {
    let (cap, report) = whole_run();
    let frames = frames(cap);
    let sent: Vec<&Frame> = frames.iter().filter(|f| f.sent()).collect();
    let received = frames.iter().filter(|f| f.received()).count();
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
    let ids: Vec<&str> = common::strings(&report["checks"], "id");
    let mut damaged = 0;
    for f in &frames {
        assert_eq!(
            f.flags & FLAG_CRC_ERROR != 0,
            !crc_ok(&f.bytes),
            "{:02X?}",
            f.bytes
        );
        if f.sent() && !crc_ok(&f.bytes) {
            damaged += 1;
            let c = f.comment.as_deref().unwrap_or_default();
            let id = c
                .strip_prefix("check ")
                .and_then(|c| c.split(':').next())
                .unwrap_or_default();
            assert!(ids.contains(&id), "comment {c:?} of {:02X?}", f.bytes);
            assert!(c.contains("on purpose"), "{c}");
        } else if f.received() && conformance::capture::late_on_host(f.comment.as_deref()).is_some()
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
        .filter(|f| f.received())
        .all(|f| crc_ok(&f.bytes)));
}

#[test]
fn tshark_decodes_every_frame_as_its_bytes_say_and_marks_exactly_the_bad_crc_frames() {
    if !need(Peer::Tshark) {
        return;
    }
    let (cap, report) = whole_run();
    let frames = frames(cap);
    let fields = "frame.number mbrtu.unit_id modbus.func_code mbrtu.crc16.status \
        modbus.reference_num frame.packet_flags_crc_error";
    let rows = tshark(cap, &words(fields));
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
        if f.sent() && crc_ok(b) && b.len() >= 8 && matches!(b[1], 0x03 | 0x10) {
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
        .filter(|(_, f)| f.sent())
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

/// Asserts that the monitor report `m` ended at the end of the capture of `all` its
/// packets.
#[track_caller]
fn ended_at_the_end_of(m: &Value, all: &[Frame]) {
    let end = format!("end of the capture ({} packets)", all.len());
    assert_eq!(m["monitor"]["ended"], end);
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
        .filter(|f| f.sent() && f.bytes[0] == 1)
        .count();
    let received = frames.iter().filter(|f| f.received()).count();
    assert!(sent > 50, "{sent}");
    // A request sent again with nothing received between: the simulator, on a loaded
    // host, answered too late for the master, which tried again. On the line that is a
    // request without a reply, and the monitor must say so, once for each.
    let retries = frames
        .windows(2)
        .filter(|w| w.iter().all(|f| f.sent()) && w[0].bytes == w[1].bytes)
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
    ended_at_the_end_of(&m, &all);
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
        .filter(|f| f.sent() && f.bytes[0] == 1 && !crc_ok(&f.bytes))
        .count() as u64;
    assert!(bad_to_1 >= 1);
    assert_eq!(n["crc_errors"], bad_to_1, "{n}");
    assert_eq!(n["errors"]["master.bad-checksum"], bad_to_1, "{n}");
    assert!(
        n["errors"]["master.register-not-in-map"].as_u64().unwrap() > 0,
        "{n}"
    );
    ended_at_the_end_of(&m, &all);
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
    let sent = frames.iter().filter(|f| f.sent()).count();
    assert!(sent >= 150, "{sent} frames sent for 150 cases");
    let rows = tshark_occurrences(
        &cap,
        &words("frame.number frame.packet_flags_crc_error mbrtu.unit_id mbrtu.crc16.status"),
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
        if f.received() {
            let joined = piece.take().map(|p| [p, b.clone()].concat());
            let next_inbound = frames.get(k + 1).is_some_and(|n| n.received());
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
    let sent: Vec<&Frame> = frames.iter().filter(|f| f.sent()).collect();
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

/// The bar: `monitor --capture-in` of a `check` run's capture gives the same
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
    let check = common::json_file(&json);
    assert!(matches!(out.code, Some(1 | 2)), "{}", out.stderr);
    assert_eq!(check["complete"], true, "{}", check["stopped"]);
    errors_are_host_stalls(&check);
    let (code, report, stderr) = monitor_capture(
        &cap,
        "agree",
        &["-a", "1", "--log", heard.to_str().unwrap()],
    );
    assert_eq!(code, Some(1), "{stderr}");
    let heard = common::json_lines_file(&heard);
    let (agree, _) = common::agree::exchanges("capture of check", &check, &heard, &[]);
    assert!(agree > 150, "only {agree} exchanges compared");
    let errors = &node(&report, "01")["errors"];
    assert!(
        errors["drive.wrong-exception"].as_u64().unwrap() > 0,
        "{errors}"
    );
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
    let report = common::json_file(&json);
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
    let heard = common::json_lines_file(&log);
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
