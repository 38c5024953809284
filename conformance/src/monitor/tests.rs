//! The monitor on byte streams with times chosen by the test: no port, no clock, so the
//! gaps are exact and nothing depends on how busy the machine is.

use std::time::Duration;

use super::*;
use crate::codec::pdu::{Pdu, Registers};
use crate::codec::timing::Parity;
use crate::model::{Access, Expectation};

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

pub(super) fn monitor(mode: Mode, nodes: &[u8]) -> Monitor {
    let data_bits = if mode == Mode::Rtu { 8 } else { 7 };
    Monitor::new(
        DriveModel::builtin("f510").unwrap(),
        MonitorConfig {
            mode,
            line: LineSettings::new(9600, data_bits, Parity::Even, 1),
            nodes: nodes.to_vec(),
            window: ms(1000),
            response_allowance: ms(20),
            gap_allowance: ms(5),
        },
    )
    .unwrap()
}

fn frame(mode: Mode, address: u8, pdu: Pdu<'_>) -> Vec<u8> {
    Message { address, pdu }.to_frame_vec(mode).unwrap()
}

fn read(address: u8, start: u16, count: u16) -> Vec<u8> {
    frame(Mode::Rtu, address, Pdu::ReadRequest { start, count })
}

fn values(address: u8, v: &[u16]) -> Vec<u8> {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_be_bytes()).collect();
    frame(
        Mode::Rtu,
        address,
        Pdu::ReadResponse {
            values: Registers::new(&bytes).unwrap(),
        },
    )
}

fn exception(address: u8, function: u8, code: u8) -> Vec<u8> {
    frame(Mode::Rtu, address, Pdu::Exception { function, code })
}

fn write(address: u8, register: u16, value: u16) -> Vec<u8> {
    frame(Mode::Rtu, address, Pdu::WriteSingle { register, value })
}

/// Feeds `frames` at their times (ms), then a long silence, then the end.
fn run(m: &mut Monitor, frames: &[(u64, &[u8])]) -> Vec<Line> {
    for (t, f) in frames {
        m.idle(ms(*t));
        m.feed(ms(*t), f);
    }
    let end = frames.last().map_or(0, |f| f.0) + 5000;
    m.idle(ms(end));
    m.finish();
    m.take_lines()
}

/// The (side.kind) of every finding on `node`.
pub(super) fn kinds(m: &Monitor, node: u8) -> Vec<String> {
    m.nodes()
        .get(&node)
        .map(|s| s.errors.keys().cloned().collect())
        .unwrap_or_default()
}

#[test]
fn a_clean_conversation_has_no_finding_and_its_statistics() {
    let mut m = monitor(Mode::Rtu, &[1]);
    let w = write(1, 0x2502, 4500);
    let lines = run(
        &mut m,
        &[
            (0, &read(1, 0x2520, 2)),
            (15, &values(1, &[0x0000, 0x0001])),
            (100, &w),
            (112, &w),
            (200, &read(1, 0x2520, 1)),
            (208, &values(1, &[0x0003])),
        ],
    );
    assert_eq!(lines.len(), 3, "{lines:#?}");
    assert!(
        lines.iter().all(|l| l.status == VerdictStatus::Pass),
        "{lines:#?}"
    );
    assert_eq!(m.deviations(), 0);
    let s = &m.nodes()[&1];
    assert_eq!(
        (s.requests, s.exchanges, s.replies, s.timeouts),
        (3, 3, 3, 0)
    );
    assert!(s.errors.is_empty(), "{:?}", s.errors);
    assert_eq!(s.response.count(), 3);
    // The 06H reply is a copy of the request: the line says how it was told apart.
    assert!(
        lines[1]
            .notes
            .iter()
            .any(|n| n.contains("copy of the request")),
        "{:?}",
        lines[1]
    );
    assert!(
        lines[1].meaning.contains("45.00 Hz"),
        "{}",
        lines[1].meaning
    );
    let shown = lines[0].to_string();
    assert!(
        shown.contains("node 01")
            && shown.contains("03H")
            && shown.contains("CRC ok")
            && shown.contains("PASS"),
        "{shown}"
    );
    assert!(m
        .results()
        .iter()
        .all(|r| r.status == crate::runner::Status::Pass));
}

#[test]
fn a_wrong_exception_is_found_on_its_node_with_the_manual() {
    let mut m = monitor(Mode::Rtu, &[1, 2]);
    run(
        &mut m,
        &[
            (0, &read(2, 0x2530, 1)),
            (15, &exception(2, 3, 3)),
            (100, &read(1, 0x2530, 1)),
            (115, &exception(1, 3, 2)),
        ],
    );
    assert!(
        kinds(&m, 2).contains(&"drive.wrong-exception".to_string()),
        "{:?}",
        kinds(&m, 2)
    );
    assert!(
        !kinds(&m, 1).iter().any(|k| k.starts_with("drive.")),
        "{:?}",
        kinds(&m, 1)
    );
    let e = &m.examples()[&(2, Side::Drive, "wrong-exception")];
    assert_eq!(e.severity, Severity::Deviation);
    assert!(!e.citations.is_empty());
    assert_eq!(
        e.exchange.expected.as_deref(),
        Some(&exception(2, 3, 2)[..])
    );
    // Both requests read past the map: the master's finding, on each node.
    assert!(kinds(&m, 1).contains(&"master.register-not-in-map".to_string()));
}

#[test]
fn a_bad_crc_a_late_reply_and_garbage_are_the_drives() {
    let mut m = monitor(Mode::Rtu, &[1]);
    let mut bad = values(1, &[7]);
    let n = bad.len();
    bad.swap(n - 1, n - 2);
    let mut garbage = vec![0xFF, 0x00];
    garbage.extend(values(1, &[7]));
    run(
        &mut m,
        &[
            (0, &read(1, 0x2520, 1)),
            (15, &bad),
            (100, &read(1, 0x2520, 1)),
            (400, &values(1, &[7])),
            (1000, &read(1, 0x2520, 1)),
            (1015, &garbage),
        ],
    );
    let k = kinds(&m, 1);
    for want in [
        "drive.bad-checksum",
        "drive.late-reply",
        "drive.extra-bytes",
    ] {
        assert!(k.contains(&want.to_string()), "{want} not in {k:?}");
    }
    assert_eq!(m.nodes()[&1].crc_errors, 1);
    assert_eq!(m.nodes()[&1].timeouts, 0);
}

#[test]
fn replies_to_broadcasts_and_for_other_nodes_are_found() {
    let mut m = monitor(Mode::Rtu, &[1]);
    let b = write(0, 0x2502, 1000);
    run(
        &mut m,
        &[
            (0, &b),
            (12, &b),
            (200, &read(1, 0x2520, 1)),
            (215, &values(2, &[1])),
            (400, &read(3, 0x2520, 1)),
            (415, &values(3, &[1])),
        ],
    );
    assert!(
        kinds(&m, 0).contains(&"drive.unexpected-reply".to_string()),
        "{:?}",
        kinds(&m, 0)
    );
    assert!(
        kinds(&m, 1).contains(&"drive.wrong-address".to_string()),
        "{:?}",
        kinds(&m, 1)
    );
    // Node 03 is not on the bus (-a 1): whatever answers for it is a finding.
    assert!(
        kinds(&m, 3).contains(&"drive.unexpected-reply".to_string()),
        "{:?}",
        kinds(&m, 3)
    );
}

#[test]
fn the_master_is_judged_on_its_requests_and_its_timing() {
    let mut m = monitor(Mode::Rtu, &[1]);
    let mut bad = read(1, 0x2520, 1);
    bad[7] ^= 0xFF;
    run(
        &mut m,
        &[
            (0, &read(1, 0x2520, 1)),
            (15, &values(1, &[1])),
            // 1 ms after the reply (with its 8 bytes, well under t3.5 = 4 ms).
            (16, &read(1, 0x2520, 1)),
            (31, &values(1, &[1])),
            (200, &read(0, 0x2520, 1)),
            (
                1500,
                &frame(
                    Mode::Rtu,
                    1,
                    Pdu::Other {
                        function: 0x04,
                        data: &[0, 0, 0, 1],
                    },
                ),
            ),
            (1515, &exception(1, 4, 1)),
            (2000, &bad),
            (3500, &read(1, 0x2520, 1)),
            // The next request 2 ms later, where the reply was due.
            (3502, &write(1, 0x2502, 100)),
            (3514, &write(1, 0x2502, 100)),
        ],
    );
    let k1 = kinds(&m, 1);
    for want in [
        "master.no-t3.5",
        "master.function-not-served",
        "master.bad-checksum",
        "master.request-before-reply",
    ] {
        assert!(k1.contains(&want.to_string()), "{want} not in {k1:?}");
    }
    assert!(
        kinds(&m, 0).contains(&"master.broadcast-read".to_string()),
        "{:?}",
        kinds(&m, 0)
    );
    // The request with a bad CRC is the master's: the drive's silence after it is right.
    assert!(!k1.contains(&"drive.no-reply".to_string()), "{k1:?}");
}

#[test]
fn no_reply_and_a_retry_are_counted() {
    let mut m = monitor(Mode::Rtu, &[1]);
    let r = read(1, 0x2520, 1);
    run(&mut m, &[(0, &r), (1500, &r), (1515, &values(1, &[1]))]);
    let s = &m.nodes()[&1];
    assert_eq!((s.timeouts, s.retries, s.exchanges), (1, 1, 2));
    let k = kinds(&m, 1);
    assert!(
        k.contains(&"drive.no-reply".to_string()) && k.contains(&"master.retry".to_string()),
        "{k:?}"
    );
    assert_eq!(
        m.examples()[&(1, Side::Master, "retry")].severity,
        Severity::Observation
    );
}

#[test]
fn values_are_judged_only_after_a_write_seen_on_the_bus_set_them() {
    let model = DriveModel::builtin("f510").unwrap();
    // A writable parameter (not a command register, which the drive may change itself).
    let value = 1u16;
    let reg = writable_parameter(&model, value);
    let mut m = monitor(Mode::Rtu, &[1]);
    let w = write(1, reg, value);
    run(
        &mut m,
        &[
            // Before any write, any value passes.
            (0, &read(1, reg, 1)),
            (15, &values(1, &[value + 5])),
            (100, &w),
            (112, &w),
            (200, &read(1, reg, 1)),
            (215, &values(1, &[value + 5])),
        ],
    );
    let k = kinds(&m, 1);
    assert_eq!(k, ["drive.wrong-value"], "{reg:04X}H");
    assert_eq!(m.nodes()[&1].deviations, 1);
}

/// A writable parameter the model takes `value` for with a normal reply.
fn writable_parameter(model: &DriveModel, value: u16) -> u16 {
    model
        .registers()
        .filter(|(r, a)| *a == Access::ReadWrite && model.named(*r).is_none())
        .find(|(r, _)| {
            matches!(
                model.judge(1, Mode::Rtu, &write(1, *r, value)).expect,
                Expectation::WriteSingle
            )
        })
        .expect("a writable parameter")
        .0
}

#[test]
fn a_write_the_drive_confirmed_early_sets_the_value_all_the_same() {
    // pymodbus's server echoes a write 1.5 ms after it at 9600 baud: an early reply, a
    // finding on timing, yet the drive took the value, and a read of it later returns it.
    let model = DriveModel::builtin("f510").unwrap();
    let reg = writable_parameter(&model, 1);
    let w = write(1, reg, 1);
    // 2 set and confirmed, then 1 written and answered with `answer` (ms, bytes), then
    // a read that returns 1.
    let after = |answer: (u64, &[u8])| {
        let mut m = monitor(Mode::Rtu, &[1]);
        run(
            &mut m,
            &[
                (0, &write(1, reg, 2)),
                (12, &write(1, reg, 2)),
                (100, &w),
                answer,
                (200, &read(1, reg, 1)),
                (215, &values(1, &[1])),
            ],
        )
    };
    let lines = after((101, &w));
    assert!(
        lines[1].issues.contains(&"drive.early-reply".to_string()),
        "{:?}",
        lines[1]
    );
    assert_eq!(lines[1].status, VerdictStatus::Deviation);
    assert_eq!(lines[2].issues, Vec::<String>::new(), "{:?}", lines[2]);
    // The same write refused (an exception), or echoed with a bad CRC, teaches nothing:
    // the value set before holds.
    let mut damaged = w.clone();
    *damaged.last_mut().unwrap() ^= 1;
    for answer in [exception(1, 0x06, 3), damaged] {
        let lines = after((112, &answer));
        assert!(
            lines[2].issues.contains(&"drive.wrong-value".to_string()),
            "{answer:02X?}: {:?}",
            lines[2]
        );
    }
}

#[test]
fn a_write_is_confirmed_by_its_normal_reply_only() {
    use super::exchange::confirms_write;
    let w = write(1, 0x2502, 0x04D2);
    assert!(confirms_write(Mode::Rtu, &w, &w));
    assert!(!confirms_write(Mode::Rtu, &w, &write(1, 0x2502, 0x04D3)));
    assert!(!confirms_write(Mode::Rtu, &w, &exception(1, 0x06, 3)));
    let mut bad = w.clone();
    *bad.last_mut().unwrap() ^= 1;
    assert!(!confirms_write(Mode::Rtu, &w, &bad));
    // 10H: the reply carries the start and the count.
    let values = Registers::new(&[0, 1, 0, 2]).unwrap();
    let q = frame(
        Mode::Rtu,
        1,
        Pdu::WriteMultipleRequest {
            start: 0x2501,
            values,
        },
    );
    let ack = |count| {
        frame(
            Mode::Rtu,
            1,
            Pdu::WriteMultipleResponse {
                start: 0x2501,
                count,
            },
        )
    };
    assert!(confirms_write(Mode::Rtu, &q, &ack(2)));
    assert!(!confirms_write(Mode::Rtu, &q, &ack(1)));
    // ASCII: a request in lower case is confirmed by the echo in upper case, as the
    // judge expects it (the characters differ, the message is the same).
    let upper = frame(
        Mode::Ascii,
        1,
        Pdu::WriteSingle {
            register: 0x250A,
            value: 0x00AB,
        },
    );
    let lower = upper.to_ascii_lowercase();
    assert_ne!(lower, upper);
    assert!(confirms_write(Mode::Ascii, &lower, &upper));
}

#[test]
fn ascii_frames_are_judged_too() {
    let mut m = monitor(Mode::Ascii, &[1]);
    let req = frame(
        Mode::Ascii,
        1,
        Pdu::ReadRequest {
            start: 0x2530,
            count: 1,
        },
    );
    let wrong = frame(
        Mode::Ascii,
        1,
        Pdu::Exception {
            function: 3,
            code: 3,
        },
    );
    let right = frame(
        Mode::Ascii,
        1,
        Pdu::Exception {
            function: 3,
            code: 2,
        },
    );
    let lines = run(
        &mut m,
        &[(0, &req), (40, &right), (200, &req), (240, &wrong)],
    );
    assert_eq!(lines.len(), 2);
    assert_eq!(lines[0].status, VerdictStatus::Deviation, "{lines:#?}"); // the master's read past the map
    assert!(lines[0].checksum.contains("LRC ok"));
    assert!(
        kinds(&m, 1).contains(&"drive.wrong-exception".to_string()),
        "{:?}",
        kinds(&m, 1)
    );
    assert_eq!(m.examples()[&(1, Side::Drive, "wrong-exception")].count, 1);
}

#[test]
fn state_stays_bounded_over_a_long_stream() {
    let mut m = monitor(Mode::Rtu, &[1]);
    let r = read(1, 0x2520, 1);
    let v = values(1, &[1]);
    for i in 0..20_000u64 {
        m.feed(ms(i * 50), &r);
        m.feed(ms(i * 50 + 15), &v);
        if i % 1000 == 0 {
            let _ = m.take_lines();
        }
    }
    m.finish();
    assert_eq!(m.nodes()[&1].exchanges, 20_000);
    assert!(m.examples().is_empty());
    assert!(m.written.is_empty() && m.last_request.len() == 1);
}

#[test]
fn where_the_manual_is_silent_the_drive_gets_an_observation_as_in_check() {
    let mut m = monitor(Mode::Rtu, &[1]);
    // 251FH..2520H crosses the command and monitor blocks: the F510 manual is silent,
    // the model decides exception 02H.
    let req = read(1, 0x251F, 2);
    let j = m.model().judge(1, Mode::Rtu, &req);
    assert_eq!(j.basis(), crate::model::Basis::Decision, "{}", j.detail);
    let Expectation::Exception { code, .. } = j.expect else {
        panic!("{:?}", j.expect)
    };
    run(&mut m, &[(0, &req), (15, &exception(1, 3, code))]);
    let e = &m.examples()[&(1, Side::Drive, "decision")];
    assert_eq!(e.severity, Severity::Observation);
    assert_eq!(m.deviations(), 0, "{:?}", kinds(&m, 1));
    assert_eq!(m.nodes()[&1].observations, 1);
}

/// A listener that the host let sleep reads the rest of a reply late, after the next
/// request already began on the line. Measured between the reads, the request seems to
/// follow the reply at once; measured from the earliest the reply can have ended (the
/// read before it plus its characters), it left 20 ms of silence. Only a silence the
/// reads prove too short is the master's missing t3.5.
#[test]
fn a_reply_read_late_does_not_make_the_next_request_miss_t35() {
    let req = read(1, 0x2520, 1);
    let rep = values(1, &[7]);
    let us = Duration::from_micros;
    let heard = |rest_read_at: Duration, next_at: Duration| {
        let mut m = monitor(Mode::Rtu, &[1]);
        m.idle(ms(0));
        m.feed(ms(10), &req);
        m.idle(ms(30));
        // The reply's first byte read at once, then nothing read until `rest_read_at`.
        m.feed(us(31_200), &rep[..1]);
        m.feed(rest_read_at, &rep[1..]);
        // The next request, read whole at `next_at`, a poll just before it.
        m.idle(next_at - us(9_500));
        m.feed(next_at, &req);
        m.idle(next_at + ms(2000));
        m.finish();
        kinds(&m, 1)
    };
    // The rest (6 characters, 6.9 ms) read 22 ms late; the request read 10 ms later.
    let k = heard(ms(60), ms(70));
    assert!(!k.contains(&"master.no-t3.5".to_string()), "{k:?}");
    // The same request right behind a reply read on time: t3.5 missed, proved.
    let k = heard(us(38_200), us(48_400));
    assert!(k.contains(&"master.no-t3.5".to_string()), "{k:?}");
}

/// pymodbus's server answers a read of 0 registers with `01 80 01`: an exception for
/// function 00H. No master sends a function of 80H or more, so the frame is the reply
/// (a wrong one), not a new request.
#[test]
fn an_exception_for_another_function_is_a_wrong_reply_not_a_request() {
    let mut m = monitor(Mode::Rtu, &[1]);
    let lines = run(
        &mut m,
        &[(0, &read(1, 0x0000, 0)), (20, &exception(1, 0x00, 0x01))],
    );
    assert_eq!(lines.len(), 1, "{lines:#?}");
    let k = kinds(&m, 1);
    assert!(
        !k.iter().any(|k| k == "master.function-not-served"),
        "{k:?}"
    );
    assert!(!k.iter().any(|k| k == "drive.no-reply"), "{k:?}");
    assert!(
        k.iter()
            .any(|k| k == "drive.wrong-exception" || k == "drive.wrong-reply"),
        "{k:?}"
    );
}

/// A master that sends its next request 20 ms after a broadcast write does not give the
/// drives the turnaround delay (an observation: the TECO manuals give none); 150 ms
/// later is enough.
#[test]
fn a_request_too_soon_after_a_broadcast_is_an_observation_on_the_master() {
    let b = write(0, 0x2502, 1000);
    let soon = |after: u64| {
        let mut m = monitor(Mode::Rtu, &[1]);
        run(
            &mut m,
            &[
                (0, &b),
                (after, &read(1, 0x2520, 1)),
                (after + 15, &values(1, &[1])),
            ],
        );
        m
    };
    let m = soon(20);
    assert!(
        kinds(&m, 1).contains(&"master.broadcast-turnaround".to_string()),
        "{:?}",
        kinds(&m, 1)
    );
    assert_eq!(
        m.examples()[&(1, Side::Master, "broadcast-turnaround")].severity,
        Severity::Observation
    );
    let m = soon(150);
    assert!(
        !kinds(&m, 1).contains(&"master.broadcast-turnaround".to_string()),
        "{:?}",
        kinds(&m, 1)
    );
}

/// A tap that hands over request and reply in one read (a USB adapter's 16 ms latency
/// timer) is named once, with what to do; a tap that reads them apart is not.
#[test]
fn a_tap_that_reads_request_and_reply_together_is_named_once() {
    let mut m = monitor(Mode::Rtu, &[1]);
    let both = [read(1, 0x2520, 1), values(1, &[1])].concat();
    let slices: Vec<(u64, &[u8])> = (0..6).map(|i| (i * 100, &both[..])).collect();
    run(&mut m, &slices);
    let said = m.take_notices();
    assert_eq!(said.len(), 1, "{said:?}");
    assert!(said[0].contains("latency_timer"), "{}", said[0]);
    assert!(
        said[0].starts_with("latency timer: 4 of 4 replies"),
        "{}",
        said[0]
    );
    assert!(m.take_notices().is_empty());
    assert_eq!(m.notices().len(), 1);
    assert_eq!(m.nodes()[&1].exchanges, 6);
    let mut m = monitor(Mode::Rtu, &[1]);
    let (r, v) = (read(1, 0x2520, 1), values(1, &[1]));
    let apart: Vec<(u64, &[u8])> = (0..6)
        .flat_map(|i| [(i * 100, &r[..]), (i * 100 + 15, &v[..])])
        .collect();
    run(&mut m, &apart);
    assert!(m.notices().is_empty(), "{:?}", m.notices());
}

/// Two loop-backs in a row (test codes 0002H then 000AH), the first sent twice: 000AH,
/// another test code, is never the reply to 0002H, so every request keeps its own echo.
#[test]
fn a_loop_back_with_another_test_code_is_a_request_not_a_reply() {
    let lb = |code: u16| {
        frame(
            Mode::Rtu,
            1,
            Pdu::LoopBack {
                test_code: code,
                data: &[0, 0],
            },
        )
    };
    let (a, b) = (lb(0x0002), lb(0x000A));
    let mut m = monitor(Mode::Rtu, &[1]);
    let lines = run(
        &mut m,
        &[
            (0, &a),
            (60, &a),
            (77, &a),
            (95, &b),
            (112, &b),
            (200, &b),
            (217, &b),
        ],
    );
    // The last two exchanges of 000AH are each a request and its echo.
    let last: Vec<(&str, bool)> = lines
        .iter()
        .rev()
        .take(2)
        .map(|l| {
            (
                l.meaning.as_str(),
                l.issues.iter().any(|i| i == "drive.wrong-reply"),
            )
        })
        .collect();
    assert_eq!(
        last,
        [
            ("loop-back test 000AH", false),
            ("loop-back test 000AH", false)
        ],
        "{lines:#?}"
    );
    assert!(
        !lines
            .iter()
            .any(|l| l.issues.iter().any(|i| i == "drive.wrong-reply")),
        "{lines:#?}"
    );
}

/// The runner sent a write to a reserved register twice, 51 ms apart (its host stalled),
/// then the drive's exception came. A copy later than any reply is due (10 ms + t3.5
/// allowance) is the master's resend, not the echo; the exception is the resend's reply;
/// and an exception frame is never taken for a request.
#[test]
fn a_copy_later_than_a_reply_is_due_is_a_resend_and_the_exception_its_reply() {
    let w = write(1, 0x2500, 0);
    let mut m = monitor(Mode::Rtu, &[1]);
    let lines = run(
        &mut m,
        &[(0, &w), (51, &w), (60, &exception(1, 0x06, 0x03))],
    );
    let k = kinds(&m, 1);
    assert!(k.contains(&"master.retry".to_string()), "{k:?}\n{lines:#?}");
    assert!(
        !k.contains(&"master.function-not-served".to_string()),
        "{k:?}"
    );
    assert!(!k.contains(&"drive.unexpected-reply".to_string()), "{k:?}");
    let last = lines.last().unwrap();
    assert!(
        last.reply.as_deref().unwrap_or("").contains("exception"),
        "{lines:#?}"
    );
    // An exception frame with no request under way is a reply nobody asked for; as the
    // first frame heard, its request may have come before listening began: not judged.
    let mut m = monitor(Mode::Rtu, &[1]);
    let ok = write(1, 0x2502, 100);
    run(
        &mut m,
        &[(0, &ok), (12, &ok), (100, &exception(1, 0x06, 0x03))],
    );
    assert_eq!(kinds(&m, 1), ["drive.unexpected-reply"]);
    let mut m = monitor(Mode::Rtu, &[1]);
    run(&mut m, &[(0, &exception(1, 0x06, 0x03))]);
    assert!(kinds(&m, 1).is_empty(), "{:?}", kinds(&m, 1));
    assert!(
        m.notices()
            .iter()
            .any(|n| n.starts_with("the first frame heard was a reply")),
        "{:?}",
        m.notices()
    );
}

/// Listening that ends before the last request's reply is due does not call it
/// unanswered; one that ends after the window does.
#[test]
fn a_request_cut_off_by_the_end_of_listening_is_not_judged() {
    let r = read(1, 0x2520, 1);
    let mut m = monitor(Mode::Rtu, &[1]);
    m.idle(ms(0));
    m.feed(ms(0), &r);
    m.idle(ms(3));
    m.finish();
    assert!(kinds(&m, 1).is_empty(), "{:?}", kinds(&m, 1));
    assert!(
        m.notices()
            .iter()
            .any(|n| n.starts_with("listening ended") && n.contains("not judged")),
        "{:?}",
        m.notices()
    );
    let mut m = monitor(Mode::Rtu, &[1]);
    run(&mut m, &[(0, &r)]);
    assert_eq!(kinds(&m, 1), ["drive.no-reply"]);
}

/// A capture with directions settles what order and time cannot: a copy from the
/// request's side is the master's resend however soon it comes, and one from the other
/// side is the echo however late (then a late reply).
#[test]
fn directions_from_a_capture_tell_a_resend_from_a_late_echo() {
    let w = write(1, 0x2502, 100);
    let sided = |steps: &[(u64, bool)]| {
        let mut m = monitor(Mode::Rtu, &[1]);
        for (t, side) in steps {
            m.idle(ms(*t));
            m.set_side(Some(u64::from(*side)));
            m.feed(ms(*t), &w);
        }
        m.idle(ms(5000));
        m.finish();
        let lines = m.take_lines();
        (kinds(&m, 1), lines)
    };
    // A resend 20 ms after (soon enough to pass for an echo by time), then the echo.
    let (k, lines) = sided(&[(0, true), (20, true), (35, false)]);
    assert!(k.contains(&"master.retry".to_string()), "{k:?}\n{lines:#?}");
    assert_eq!(lines.len(), 2, "{lines:#?}");
    // The echo 80 ms after (later than a reply is due): still the echo, a late one.
    let (k, lines) = sided(&[(0, true), (80, false)]);
    assert_eq!(lines.len(), 1, "{lines:#?}");
    assert!(k.contains(&"drive.late-reply".to_string()), "{k:?}");
    assert!(!k.contains(&"master.retry".to_string()), "{k:?}");
}

/// A request with a bad CRC sent twice (the runner sends its bad-CRC request again when a
/// stalled host broke the first): the second is the master's again, never taken for the
/// first one's damaged reply: from the request's side (a capture), or without sides,
/// later than a reply is due.
#[test]
fn a_damaged_request_sent_again_is_no_reply_to_the_first() {
    let mut bad = read(1, 0x2520, 1);
    let n = bad.len();
    bad[n - 1] ^= 0xFF;
    for sides in [true, false] {
        let mut m = monitor(Mode::Rtu, &[1]);
        for t in [0u64, 100] {
            m.idle(ms(t));
            m.set_side(sides.then_some(1));
            m.feed(ms(t), &bad);
        }
        m.idle(ms(5000));
        m.finish();
        let lines = m.take_lines();
        let k = kinds(&m, 1);
        assert!(
            !k.contains(&"drive.unexpected-reply".to_string()),
            "{k:?}\n{lines:#?}"
        );
        assert_eq!(lines.len(), 2, "sides {sides}: {lines:#?}");
        assert!(
            lines.iter().all(|l| l.received.is_empty()),
            "sides {sides}: {lines:#?}"
        );
        assert_eq!(m.nodes()[&1].crc_errors, 2, "sides {sides}");
    }
}

/// Without live lines (`--quiet` and no `--log`) the verdicts and statistics are the
/// same; only the lines are not made.
#[test]
fn without_live_lines_the_verdicts_are_the_same() {
    let steps: Vec<(u64, Vec<u8>)> = vec![
        (0, read(1, 0x2520, 1)),
        (15, values(1, &[1])),
        (100, read(1, 0x2530, 1)),
        (115, exception(1, 3, 3)),
        (300, write(1, 0x2502, 100)),
    ];
    let heard = |live: bool| {
        let mut m = monitor(Mode::Rtu, &[1]);
        m.set_live(live);
        let frames: Vec<(u64, &[u8])> = steps.iter().map(|(t, f)| (*t, &f[..])).collect();
        let lines = run(&mut m, &frames);
        (
            kinds(&m, 1),
            m.nodes()[&1].exchanges,
            m.deviations(),
            lines.len(),
        )
    };
    let (k, n, d, lines) = heard(true);
    assert_eq!(lines, 3);
    assert!(
        d > 0 && k.contains(&"drive.wrong-exception".to_string()),
        "{k:?}"
    );
    assert_eq!(heard(false), (k, n, d, 0));
}

/// Every kind of traffic the monitor judges, `cycles` times over (the same exchanges
/// again, as a bus polls them; the values written change from cycle to cycle, so that the
/// reads after them are judged against other known values): normal polling, writes that
/// change later reads, right and wrong exceptions, wrong values, late replies, bad CRCs on
/// either side, garbage before a reply, gaps inside a reply, replies to broadcasts, from
/// the wrong node and for a node not on the bus, no reply (within the window and cut
/// short by the next request) and a retry, a request before the reply was due, no t3.5,
/// an unserved function, a reply with no request.
pub(super) fn varied_traffic(cycles: u64) -> Vec<(u64, Vec<u8>)> {
    let mut out = Vec::new();
    for c in 0..cycles {
        let t = c * 6000;
        let v = 100 + (c % 3) as u16;
        let mut bad_reply = values(1, &[7]);
        let n = bad_reply.len();
        bad_reply.swap(n - 1, n - 2);
        let mut bad_request = read(1, 0x2520, 1);
        bad_request[7] ^= 0xFF;
        let mut garbage = vec![0xFF, 0x00];
        garbage.extend(values(1, &[7]));
        let gappy = values(1, &[0x0102, 0x0304]);
        let steps: Vec<(u64, Vec<u8>)> = vec![
            (0, read(1, 0x2520, 1)),
            (15, values(1, &[0])),
            (100, write(1, 0x2502, v)),
            (112, write(1, 0x2502, v)),
            (200, read(1, 0x2502, 1)),
            // Right in one cycle of two, wrong in the other.
            (215, values(1, &[if c % 2 == 0 { v } else { v + 1 }])),
            (300, read(1, 0x2530, 1)),
            (315, exception(1, 3, if c % 2 == 0 { 2 } else { 3 })),
            (400, read(1, 0x2520, 1)),
            (700, values(1, &[0])),
            (1000, read(1, 0x2520, 1)),
            (1015, bad_reply),
            (1100, read(1, 0x2520, 1)),
            (1115, garbage),
            (1200, write(0, 0x2502, v)),
            (1212, write(0, 0x2502, v)),
            (1500, read(1, 0x2520, 1)),
            (1515, values(2, &[1])),
            (1700, read(3, 0x2520, 1)),
            (1715, values(3, &[1])),
            (1900, read(1, 0x2521, 1)),
            (2950, read(1, 0x2521, 1)),
            (2965, values(1, &[1])),
            (3500, read(1, 0x2520, 1)),
            (3502, write(1, 0x2502, v)),
            (3514, write(1, 0x2502, v)),
            (3600, read(1, 0x2520, 1)),
            (3615, values(1, &[0])),
            (3616, read(1, 0x2520, 1)),
            (3631, values(1, &[0])),
            (3800, bad_request),
            (4000, values(1, &[5])),
            (
                4200,
                frame(
                    Mode::Rtu,
                    1,
                    Pdu::Other {
                        function: 0x04,
                        data: &[0, 0, 0, 1],
                    },
                ),
            ),
            (4215, exception(1, 4, 1)),
            (4400, read(1, 0x2520, 2)),
            (4415, gappy[..3].to_vec()),
            (4423, gappy[3..].to_vec()),
            (4600, read(1, 0x251F, 2)),
            (4615, exception(1, 3, 2)),
            // No reply, and the next request after the reply was due but within the
            // window: how long the monitor listened differs from cycle to cycle.
            (5000, read(1, 0x2521, 1)),
            (5300 + 10 * (c % 2), read(1, 0x2520, 1)),
            (5315 + 10 * (c % 2), values(1, &[0])),
        ];
        out.extend(steps.into_iter().map(|(dt, f)| (t + dt, f)));
    }
    out
}

/// Everything a monitor reports, for comparing two: the live lines, every exchange as
/// counted (its findings with their texts, its citations, the exchange as an example
/// would keep it), the per-node statistics, the examples, the notices and the results.
pub(super) fn everything(m: &Monitor, lines: &[Line]) -> String {
    format!(
        "{lines:#?}\n{:#?}\n{:#?}\n{:#?}\n{:#?}\n{:#?}\n{}",
        m.trail,
        m.nodes(),
        m.examples(),
        m.notices(),
        m.results(),
        m.deviations()
    )
}

/// The memo changes no verdict: the same traffic judged with it and without gives the
/// same lines, statistics, findings, citations, examples and results.
#[test]
fn the_memo_changes_no_verdict() {
    let steps = varied_traffic(6);
    let frames: Vec<(u64, &[u8])> = steps.iter().map(|(t, f)| (*t, &f[..])).collect();
    for live in [true, false] {
        let judged = |memo: bool| {
            let mut m = monitor(Mode::Rtu, &[1]);
            m.set_live(live);
            m.set_memo(memo);
            let lines = run(&mut m, &frames);
            let held = (m.requests_memo.len(), m.verdicts_memo.len());
            (
                everything(&m, &lines),
                kinds(&m, 1),
                held,
                m.nodes()[&1].exchanges,
            )
        };
        let (with, k, held, exchanges) = judged(true);
        let (without, _, none, _) = judged(false);
        assert_eq!(none, (0, 0));
        // The memo was used: far fewer kinds of exchange than exchanges.
        assert!(held.0 > 0 && held.1 > 0, "{held:?}");
        assert!((held.1 as u64) < exchanges / 2, "{held:?} {exchanges}");
        // The traffic is as varied as it says.
        for want in [
            "drive.wrong-value",
            "drive.wrong-exception",
            "drive.wrong-address",
            "drive.late-reply",
            "drive.bad-checksum",
            "drive.extra-bytes",
            "drive.no-reply",
            "drive.unexpected-reply",
            "drive.decision",
            "master.no-t3.5",
            "master.retry",
            "master.request-before-reply",
            "master.bad-checksum",
            "master.function-not-served",
        ] {
            assert!(k.contains(&want.to_string()), "{want} not in {k:?}");
        }
        assert!(with == without, "live {live}:\n{with}\n---\n{without}");
    }
    // ASCII too.
    let req = frame(
        Mode::Ascii,
        1,
        Pdu::ReadRequest {
            start: 0x2530,
            count: 1,
        },
    );
    let ok = frame(
        Mode::Ascii,
        1,
        Pdu::Exception {
            function: 3,
            code: 2,
        },
    );
    let wrong = frame(
        Mode::Ascii,
        1,
        Pdu::Exception {
            function: 3,
            code: 3,
        },
    );
    let mut bad = ok.clone();
    let n = bad.len();
    bad.swap(n - 3, n - 4);
    let ascii: Vec<(u64, &[u8])> = (0..5u64)
        .flat_map(|c| {
            [
                (c * 1000, &req[..]),
                (c * 1000 + 40, &ok[..]),
                (c * 1000 + 200, &req[..]),
                (c * 1000 + 240, &wrong[..]),
                (c * 1000 + 400, &req[..]),
                (c * 1000 + 440, &bad[..]),
            ]
        })
        .collect();
    let judged = |memo: bool| {
        let mut m = monitor(Mode::Ascii, &[1]);
        m.set_memo(memo);
        let lines = run(&mut m, &ascii);
        everything(&m, &lines)
    };
    assert!(judged(true) == judged(false));
}

/// The memos stay bounded however many kinds of exchange the bus carries.
#[test]
fn the_memo_stays_bounded() {
    let mut m = monitor(Mode::Rtu, &[1]);
    let r = read(1, 0x2520, 1);
    let n = memo::MEMO_ENTRIES as u64 + 500;
    for i in 0..n {
        m.feed(ms(i * 50), &r);
        // A different value each time: a different exchange.
        m.feed(ms(i * 50 + 15), &values(1, &[i as u16]));
        assert!(m.verdicts_memo.len() <= memo::MEMO_ENTRIES);
    }
    m.finish();
    assert_eq!(m.nodes()[&1].exchanges, n);
    assert!(m.verdicts_memo.len() <= memo::MEMO_ENTRIES);
    assert_eq!(m.requests_memo.len(), 1);
}
