//! The judgement on operations built by the test, and a property test that it never
//! panics.

use super::requests::{longest_silence, open_ascii_frame};
use super::*;
use crate::gate::master::drive::{Dir, SentClass};
use crate::gate::master::protocol::MasterSettings;

fn ms_(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn settings() -> MasterSettings {
    MasterSettings {
        timeout: ms_(300),
        retries: 0,
    }
}

fn read() -> Operation {
    Operation::Read {
        unit: 1,
        start: 0,
        count: 2,
    }
}

fn request(seq: u32, at: u64) -> Request {
    Request {
        seq,
        start: ms_(at),
        end: ms_(at),
        bytes: vec![0x01, 0x03, 0x00, 0x00, 0x00, 0x02, 0xC4, 0x0B],
        valid: true,
        address: 1,
    }
}

fn sent(seq: u32, class: SentClass, values: Option<Vec<u16>>, at: u64) -> Sent {
    Sent {
        for_seq: seq,
        bytes: vec![0x01, 0x03, 0x04],
        class,
        values,
        exception: None,
        at: Some(ms_(at)),
    }
}

fn judged(
    reported: Reported,
    requests: &[Request],
    frames: &[Sent],
    behaviour: Behaviour,
) -> Vec<String> {
    let op = read();
    let rec = OpRecord {
        op: &op,
        behaviour: &behaviour,
        role: Role::Recovery,
        reported: &reported,
        took: ms_(10),
        requests,
        sent: frames,
        log: &[],
        called: ms_(100),
        ended: ms_(200),
        recent: ms_(50),
        timed: true,
    };
    judge_report(&rec, &settings())
        .into_iter()
        .map(|f| f.kind)
        .collect()
}

#[test]
fn values_are_traced_to_the_frame_that_carried_them() {
    let frames = [
        sent(1, SentClass::Stale, Some(vec![0x8010, 0x8011]), 60),
        sent(2, SentClass::Reply, Some(vec![0x8020, 0x8021]), 120),
        sent(3, SentClass::BadChecksum, Some(vec![0x8030, 0x8031]), 130),
    ];
    let reqs = [request(2, 110)];
    // Its own reply: nothing to say.
    assert!(judged(
        Reported::Values(vec![0x8020, 0x8021]),
        &reqs,
        &frames,
        Behaviour::Normal
    )
    .is_empty());
    // The reply to an earlier request.
    assert_eq!(
        judged(
            Reported::Values(vec![0x8010, 0x8011]),
            &reqs,
            &frames,
            Behaviour::Normal
        ),
        ["stale-reply-taken"]
    );
    // Values no frame carried.
    assert_eq!(
        judged(
            Reported::Values(vec![1, 2]),
            &reqs,
            &frames,
            Behaviour::Normal
        ),
        ["wrong-values"]
    );
    // A frame with a bad checksum, for this request.
    let bad = [sent(
        2,
        SentClass::BadChecksum,
        Some(vec![0x8040, 0x8041]),
        120,
    )];
    assert_eq!(
        judged(
            Reported::Values(vec![0x8040, 0x8041]),
            &reqs,
            &bad,
            Behaviour::BadChecksum
        ),
        ["accepted-bad-checksum"]
    );
}

#[test]
fn exceptions_are_held_to_the_code_sent() {
    let mut e = sent(2, SentClass::Reply, None, 120);
    e.exception = Some(0x52);
    let frames = [e];
    let reqs = [request(2, 110)];
    assert!(judged(
        Reported::Exception(0x52),
        &reqs,
        &frames,
        Behaviour::Exception(0x52)
    )
    .is_empty());
    assert_eq!(
        judged(
            Reported::Exception(0x02),
            &reqs,
            &frames,
            Behaviour::Exception(0x52)
        ),
        ["wrong-exception-code"]
    );
    let error = Reported::Error {
        kind: super::super::protocol::ErrorKind::Other,
        message: "unknown code".into(),
    };
    assert_eq!(
        judged(error, &reqs, &frames, Behaviour::Exception(0x52)),
        ["exception-not-recognised"]
    );
    assert_eq!(
        judged(
            Reported::Values(vec![]),
            &reqs,
            &frames,
            Behaviour::Exception(0x52)
        ),
        ["exception-ignored"]
    );
}

#[test]
fn a_failure_is_right_only_where_nothing_valid_came_in_time() {
    let timeout = || Reported::Error {
        kind: super::super::protocol::ErrorKind::Timeout,
        message: "no reply".into(),
    };
    let reqs = [request(2, 110)];
    // Nothing came: a timeout is right.
    assert!(judged(timeout(), &reqs, &[], Behaviour::NoReply).is_empty());
    // The reply came after the call ended: right too.
    let late = [sent(2, SentClass::Reply, Some(vec![1, 2]), 250)];
    assert!(judged(timeout(), &reqs, &late, Behaviour::Normal).is_empty());
    // The reply came at once: the read after a fault did not recover.
    let prompt = [sent(2, SentClass::Reply, Some(vec![1, 2]), 111)];
    assert_eq!(
        judged(timeout(), &reqs, &prompt, Behaviour::Normal),
        ["no-recovery"]
    );
}

fn chunk(at: u64, done: u64, dir: Dir, bytes: &[u8]) -> Chunk {
    Chunk {
        at: ms_(at),
        done: ms_(done),
        dir,
        bytes: bytes.to_vec(),
    }
}

#[test]
fn the_silence_before_a_request_is_an_upper_bound() {
    // The drive sent a byte every millisecond up to 50 ms; one write took 9 ms to
    // return (a stall between reading the clock and writing).
    let mut log: Vec<Chunk> = (0..50)
        .map(|t| chunk(t, t, Dir::ToMaster, &[0xFF]))
        .collect();
    log[20].done = ms_(29);
    // A request read at 51 ms, asked at 30 ms: after 30 ms the drive sent a byte a
    // millisecond, then the last one at 49 ms: at most 2 ms of silence. The stalled
    // write went out before 30 ms and does not count.
    assert_eq!(longest_silence(&log, ms_(30), ms_(51)), Some(ms_(2)));
    // Asked at 10 ms: the stalled write (recorded at 19, done at 29) may have left
    // 29 - 19 = 10 ms of silence.
    assert_eq!(longest_silence(&log, ms_(10), ms_(51)), Some(ms_(10)));
    // Nothing before the request: as long as it likes.
    assert_eq!(longest_silence(&[], ms_(0), ms_(5)), None);
}

#[test]
fn an_ascii_frame_is_under_way_from_its_colon_to_its_lf() {
    let mut log = vec![chunk(0, 0, Dir::ToMaster, b":")];
    log.extend((1..40).map(|t| chunk(t, t, Dir::ToMaster, b"0")));
    log.push(chunk(40, 40, Dir::ToMaster, b"\r\n"));
    // Read at 20 ms, asked at 10 ms: under way.
    assert_eq!(
        open_ascii_frame(&log, ms_(10), ms_(20)),
        Some(Duration::ZERO)
    );
    // Read after the LF: not.
    assert_eq!(open_ascii_frame(&log, ms_(10), ms_(45)), None);
    // A frame the drive abandoned (no LF ever): not under way.
    let cut: Vec<Chunk> = log[..30].to_vec();
    assert_eq!(open_ascii_frame(&cut, ms_(10), ms_(20)), None);
}

// The gate's arithmetic over anything an option, an adapter or a stalled host can give
// it: timeouts of any length (none, years), any retries and baud rate, any fault, and
// requests and line chunks at any times, in any order. It returns findings or none;
// it never panics (issue 33: a first request's unbounded silence plus one character
// overflowed).
mod arithmetic {
    use super::*;
    use crate::codec::timing::{LineSettings, Parity};
    use crate::codec::Mode;
    use crate::model::DriveModel;
    use crate::monitor::{Monitor, MonitorConfig};
    use proptest::prelude::*;

    fn any_duration() -> impl Strategy<Value = Duration> {
        prop_oneof![
            (0u64..2_000).prop_map(Duration::from_millis),
            any::<u64>().prop_map(Duration::from_micros),
            any::<u64>().prop_map(Duration::from_millis),
            Just(Duration::ZERO),
            Just(Duration::MAX),
        ]
    }

    fn any_behaviour() -> impl Strategy<Value = Behaviour> {
        prop_oneof![
            Just(Behaviour::Normal),
            Just(Behaviour::NoReply),
            Just(Behaviour::AfterTimeout),
            Just(Behaviour::InFlight),
            Just(Behaviour::Twice),
            Just(Behaviour::BadChecksum),
            Just(Behaviour::Truncated),
            Just(Behaviour::WrongFunction),
            any_duration().prop_map(Behaviour::Late),
            any_duration().prop_map(Behaviour::Split),
            any::<u8>().prop_map(Behaviour::Exception),
            proptest::collection::vec(any::<u8>(), 0..4).prop_map(Behaviour::GarbageBefore),
        ]
    }

    fn any_reported() -> impl Strategy<Value = Reported> {
        prop_oneof![
            proptest::collection::vec(any::<u16>(), 0..3).prop_map(Reported::Values),
            Just(Reported::Done),
            any::<u8>().prop_map(Reported::Exception),
            Just(Reported::Raised {
                kind: "timeout".into(),
                message: "no reply".into()
            }),
        ]
    }

    proptest! {
        #![proptest_config(ProptestConfig::with_cases(2_000))]
        #[test]
        fn judging_an_operation_never_panics(
            ascii in any::<bool>(),
            baud in any::<u32>(),
            timeout in any_duration(),
            retries in any::<u32>(),
            behaviour in any_behaviour(),
            reported in any_reported(),
            role_fault in any::<bool>(),
            times in proptest::collection::vec(any_duration(), 6),
            req_at in proptest::collection::vec((any_duration(), any_duration(), any::<bool>()), 0..4),
            chunks in proptest::collection::vec((any_duration(), any_duration(), any::<bool>(), any::<u8>()), 0..6),
            sent_at in proptest::collection::vec(proptest::option::of(any_duration()), 0..3),
            timed in any::<bool>(),
        ) {
            let mode = if ascii { Mode::Ascii } else { Mode::Rtu };
            let line = LineSettings::new(baud, if ascii { 7 } else { 8 }, Parity::Even, 1);
            let settings = MasterSettings { timeout, retries };
            let cfg = MonitorConfig {
                mode,
                line,
                nodes: vec![1],
                window: timeout.max(Duration::from_millis(1)),
                response_allowance: Duration::from_millis(5),
                gap_allowance: Duration::from_millis(5),
            };
            let monitor = Monitor::new(DriveModel::builtin("f510").unwrap(), cfg).unwrap();
            let requests: Vec<Request> = req_at
                .iter()
                .enumerate()
                .map(|(i, (start, end, valid))| Request {
                    seq: i as u32,
                    start: *start,
                    end: *end,
                    bytes: vec![0x01, 0x03, 0x00, 0x00, 0x00, 0x02, 0xC4, 0x0B],
                    valid: *valid,
                    address: 1,
                })
                .collect();
            let log: Vec<Chunk> = chunks
                .iter()
                .map(|(at, done, to_master, b)| Chunk {
                    at: *at,
                    done: *done,
                    dir: if *to_master { Dir::ToMaster } else { Dir::FromMaster },
                    bytes: vec![*b, b':', b'\n'],
                })
                .collect();
            let frames: Vec<Sent> = sent_at
                .iter()
                .enumerate()
                .map(|(i, at)| Sent {
                    for_seq: i as u32,
                    bytes: vec![0x01, 0x03, 0x04],
                    class: SentClass::Reply,
                    values: Some(vec![1, 2]),
                    exception: None,
                    at: *at,
                })
                .collect();
            let op = Operation::Read { unit: 1, start: 0, count: 2 };
            let rec = OpRecord {
                op: &op,
                behaviour: &behaviour,
                role: if role_fault { Role::Fault } else { Role::Recovery },
                reported: &reported,
                took: times[0],
                requests: &requests,
                sent: &frames,
                log: &log,
                called: times[1],
                ended: times[2],
                recent: times[3],
                timed,
            };
            let _ = judge_requests(&rec, &monitor, &settings);
            let _ = judge_report(&rec, &settings);
        }
    }
}
