//! The judge on conversations built by hand: no master, no link.

use std::time::Duration;

use super::*;
use crate::codec::timing::{LineSettings, Parity};

fn f510() -> DriveModel {
    DriveModel::builtin("f510").unwrap()
}

/// 01 03 25 30 00 01: one register past the end of the monitor block (exception 02H).
const PAST_END: [u8; 8] = [0x01, 0x03, 0x25, 0x30, 0x00, 0x01, 0x8F, 0x09];

/// The F510's verdict on an RTU conversation with node 1, untimed.
fn verdict_of(conv: &Conversation<'_>) -> Verdict {
    Judge::new(&f510()).verdict(conv, None)
}

#[test]
fn the_right_exception_passes_and_cites_the_manual() {
    let reply = [0x01, 0x83, 0x02, 0xC0, 0xF1];
    let v = verdict_of(&Conversation::new(Mode::Rtu, 1, &PAST_END).with_reply(&reply));
    assert_eq!(v.status(), VerdictStatus::Pass, "{:?}", v.findings);
    assert_eq!(v.expected.as_deref(), Some(&reply[..]));
    assert!(v.differing.is_empty());
    assert!(!v.citations.is_empty());
    assert!(
        v.citations.iter().any(|c| c.contains("exception code")),
        "{:?}",
        v.citations
    );
}

#[test]
fn a_wrong_exception_is_a_deviation_of_its_kind_with_the_differing_bytes() {
    let reply = [0x01, 0x83, 0x03, 0x01, 0x31];
    let v = verdict_of(&Conversation::new(Mode::Rtu, 1, &PAST_END).with_reply(&reply));
    assert_eq!(v.status(), VerdictStatus::Deviation);
    assert_eq!(v.kinds, [Kind::WrongException]);
    assert_eq!(v.differing, [2, 3, 4]);
    assert_eq!(v.received.as_deref(), Some(&reply[..]));
    assert!(
        v.findings[0].text.contains("code 02H"),
        "{}",
        v.findings[0].text
    );
}

#[test]
fn a_bad_crc_and_a_reply_to_a_broadcast_are_told_apart() {
    let bad = [0x01, 0x83, 0x02, 0xF1, 0xC0];
    let v = verdict_of(&Conversation::new(Mode::Rtu, 1, &PAST_END).with_invalid(&bad));
    assert_eq!(v.kinds, [Kind::BadChecksum]);

    // 06H to node 0 (broadcast): frequency command 2502H <- 1234H.
    let req = crate::codec::pdu::Message {
        address: 0,
        pdu: crate::codec::pdu::Pdu::WriteSingle {
            register: 0x2502,
            value: 0x1234,
        },
    }
    .to_frame_vec(Mode::Rtu)
    .unwrap();
    let v = verdict_of(&Conversation::new(Mode::Rtu, 1, &req).with_reply(&req));
    assert_eq!(v.status(), VerdictStatus::Deviation);
    assert_eq!(v.kinds, [Kind::UnexpectedReply]);
}

/// The timing rule of `line`: 20 ms over the response time, 5 ms over the longest gap.
fn rule_of(line: LineSettings) -> TimingRule {
    TimingRule {
        line: Some(line),
        response_allowance: Duration::from_millis(20),
        gap_allowance: Duration::from_millis(5),
    }
}

/// A request that ended at 100 ms, its reply's first byte `first` ms later with a longest
/// gap of `gap` ms inside it, heard over `listened` ms.
fn reply_at(first: u64, gap: u64, listened: u64) -> Timing {
    Timing {
        request_end: Some(Duration::from_millis(100)),
        request_end_earliest: None,
        first_byte: Some(Duration::from_millis(100 + first)),
        first_byte_earliest: None,
        last_byte: None,
        max_gap: Some(Duration::from_millis(gap)),
        silence_before: None,
        listened: Duration::from_millis(listened),
    }
}

#[test]
fn timing_is_judged_only_when_asked_and_only_where_seen() {
    let model = f510();
    let reply = [0x01, 0x83, 0x02, 0xC0, 0xF1];
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let rule = rule_of(line);
    let at = |first: u64, gap: u64| reply_at(first, gap, 1000);
    let late = Conversation::new(Mode::Rtu, 1, &PAST_END)
        .with_reply(&reply)
        .with_timing(at(300, 0));
    // The runner judges response times over a mode, not here.
    assert!(Judge::new(&model).verdict(&late, None).findings.is_empty());
    let judge = Judge::new(&model).with_timing(rule);
    assert_eq!(judge.verdict(&late, None).kinds, [Kind::LateReply]);
    let on_time = late.with_timing(at(15, 0));
    assert_eq!(judge.verdict(&on_time, None).status(), VerdictStatus::Pass);
    let gappy = late.with_timing(at(15, 50));
    assert_eq!(judge.verdict(&gappy, None).kinds, [Kind::GapInReply]);
    let early = late.with_timing(at(0, 0));
    assert_eq!(judge.verdict(&early, None).kinds, [Kind::EarlyReply]);
    // What a listener that reads late knows: the earliest the request can have ended,
    // or the reply begun (the read before returned without it). Each case: the earliest
    // request end (ms; it was read at 100), the reply's first byte as read (ms after 100)
    // and at the earliest (ms), the findings.
    type Case = (&'static str, Option<u64>, u64, Option<u64>, &'static [Kind]);
    let cases: [Case; 4] = [
        // The request read late: it may have ended 10 ms before it was read, so a reply
        // 0 ms after the read is not proved early.
        ("request read late", Some(90), 0, None, &[]),
        // Read on time (it ended no sooner than 1 ms before the read): early, proved.
        (
            "request read on time",
            Some(99),
            0,
            None,
            &[Kind::EarlyReply],
        ),
        // The reply read late (its host busy: the read before returned 295 ms before the
        // reply was read): it may have begun 5 ms after the request, so it is not proved
        // late; its time as read is kept for the statistics.
        ("reply read late", None, 300, Some(105), &[]),
        // Late even at the earliest it can have come: late, said with both times.
        (
            "reply late either way",
            None,
            300,
            Some(250),
            &[Kind::LateReply],
        ),
    ];
    let ms = |t: Option<u64>| t.map(Duration::from_millis);
    for (case, request_end_earliest, first, first_byte_earliest, want) in cases {
        let v = judge.verdict(
            &late.with_timing(Timing {
                request_end_earliest: ms(request_end_earliest),
                first_byte_earliest: ms(first_byte_earliest),
                ..at(first, 0)
            }),
            None,
        );
        assert_eq!(v.kinds, want, "{case}: {v:?}");
    }
    let v = judge.verdict(
        &late.with_timing(Timing {
            first_byte_earliest: Some(Duration::from_millis(250)),
            ..at(300, 0)
        }),
        None,
    );
    assert!(
        v.findings[0]
            .text
            .contains("it began 300.0 ms after the request as read (no sooner than 150.0 ms"),
        "{}",
        v.findings[0].text
    );
    let unseen = late.with_timing(Timing::default());
    assert_eq!(judge.verdict(&unseen, None).status(), VerdictStatus::Pass);
}

#[test]
fn ascii_frames_are_timed_by_the_one_second_between_characters_not_by_t15_or_t35() {
    // Modbus over Serial Line V1.02, 2.5.2.1: up to 1 s may pass between the characters
    // of an ASCII frame, which ':' and CR LF delimit (no t1.5, no t3.5).
    let model = f510();
    let request = b":010300390001C2\r\n";
    let reply = b":0183027A\r\n";
    let judge =
        Judge::new(&model).with_timing(rule_of(LineSettings::new(9600, 7, Parity::Even, 1)));
    let conv = |first, gap| {
        Conversation::new(Mode::Ascii, 1, request)
            .with_reply(reply)
            .with_timing(reply_at(first, gap, 3000))
    };
    // A reply at once and a 50 ms pause between characters: both fine in ASCII (an RTU
    // reply would be early and have a gap over t1.5).
    let v = judge.verdict(&conv(0, 50), None);
    assert!(v.kinds.is_empty(), "{:?}", v.findings);
    let v = judge.verdict(&conv(5, 999), None);
    assert!(v.kinds.is_empty(), "{:?}", v.findings);
    let v = judge.verdict(&conv(5, 1_001), None);
    assert_eq!(v.kinds, [Kind::GapInReply]);
    assert!(v.findings[0].text.contains("2.5.2.1"), "{:?}", v.findings);
}
