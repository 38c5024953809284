//! Who is at fault, and why: the drive, the master or neither, on each node.

use super::*;

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
fn ascii_frames_are_judged_too() {
    let mut m = monitor(Mode::Ascii, &[1]);
    let req = ascii_read(1, 0x2530, 1);
    let wrong = ascii_exception(1, 3, 3);
    let right = ascii_exception(1, 3, 2);
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
