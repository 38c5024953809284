//! Telling a request from a reply, an echo from a resend, on timing and directions.

use super::*;

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

/// Listening that stops while a reply is arriving (a `--duration` on a bus polled back to
/// back) cuts the reply: its first bytes say nothing of the drive, so neither it nor its
/// request is judged, and a notice names both. So does listening that stops while the
/// framer still holds them for their rest (a late read may yet bring it). The same bytes
/// with the line quiet after them for longer than that hold are a reply the drive cut
/// short, and judged so. An ASCII frame with no line end yet is cut alike.
#[test]
fn a_reply_cut_by_the_end_of_listening_is_not_judged() {
    let req = read(1, 0x252F, 1);
    let rep = values(1, &[0x0510]);
    let heard = |quiet_after: Option<u64>| {
        let mut m = monitor(Mode::Rtu, &[1]);
        m.idle(ms(0));
        m.feed(ms(10), &req);
        m.idle(ms(20));
        m.feed(ms(21), &rep[..4]);
        if let Some(q) = quiet_after {
            m.idle(ms(21 + q));
        }
        m.finish();
        m
    };
    // No silence after the bytes; then a silence over t3.5 (2 ms) but within CARRY_HOLD.
    for quiet in [None, Some(20)] {
        let m = heard(quiet);
        assert!(kinds(&m, 1).is_empty(), "{quiet:?}: {:?}", kinds(&m, 1));
        let t = m.tally();
        assert_eq!((t.requests, t.unjudged, t.cut), (1, 1, 1), "{t:?}");
        assert_eq!(m.frames_heard(), 2);
        assert!(
            m.notices().iter().any(|n| n.starts_with(
                "listening ended inside the frame after the last request (01 03 25 2F 00 01 BE CF): 4 bytes of it were heard (01 03 02 05)"
            ) && n.ends_with("neither was judged")),
            "{:?}",
            m.notices()
        );
    }
    let m = heard(Some(frames::CARRY_HOLD.as_millis() as u64 + 20));
    assert_eq!(kinds(&m, 1), ["drive.truncated"]);
    assert_eq!(m.tally().cut, 0);

    let mut m = monitor(Mode::Ascii, &[1]);
    m.idle(ms(0));
    m.feed(ms(10), &ascii_read(1, 0x252F, 1));
    m.idle(ms(20));
    m.feed(ms(21), b":010302");
    m.finish();
    assert!(kinds(&m, 1).is_empty(), "{:?}", kinds(&m, 1));
    assert_eq!(m.tally().cut, 1);
}

/// A request that listening stops inside is not the master's incomplete request: it is
/// named in a notice and not judged. A whole frame with no silence after it yet is
/// judged as any other.
#[test]
fn a_request_cut_by_the_end_of_listening_is_not_judged() {
    let req = read(1, 0x252F, 1);
    let mut m = monitor(Mode::Rtu, &[1]);
    m.idle(ms(0));
    m.feed(ms(10), &req[..5]);
    m.finish();
    assert!(kinds(&m, 1).is_empty(), "{:?}", kinds(&m, 1));
    assert_eq!(m.nodes().get(&1).map_or(0, |n| n.requests), 0);
    assert_eq!((m.tally().cut, m.tally().requests), (1, 0));
    assert!(
        m.notices().iter().any(|n| n
            == "listening ended inside a frame: 5 bytes of it were heard (01 03 25 2F 00), and it was not judged"),
        "{:?}",
        m.notices()
    );
    // The whole request, then the whole reply with no silence after it: both judged.
    let mut m = monitor(Mode::Rtu, &[1]);
    m.idle(ms(0));
    m.feed(ms(10), &req);
    m.idle(ms(20));
    m.feed(ms(21), &values(1, &[0x0510]));
    m.finish();
    assert_eq!(m.nodes()[&1].exchanges, 1);
    assert_eq!((m.tally().answered, m.tally().cut), (1, 0));
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

/// A monitor of node 1 (RTU) that read a request for 2520H at 0 ms (after an empty read),
/// then `reads`: each a time (ms) and its bytes, none for a read that came back empty;
/// then finished.
fn after_the_request(reads: &[(u64, &[u8])]) -> Monitor {
    let mut m = monitor(Mode::Rtu, &[1]);
    m.idle(ms(0));
    m.feed(ms(0), &read(1, 0x2520, 1));
    for (t, bytes) in reads {
        if bytes.is_empty() {
            m.idle(ms(*t));
        } else {
            m.feed(ms(*t), bytes);
        }
    }
    m.finish();
    m
}

/// A listener whose host was busy reads late: a reply in time on the line is read
/// 1.5 s after its request, with no read in between (as a monitor descheduled on a
/// loaded machine saw it). The reads prove only that the reply was not there at the read
/// before: it is the request's reply, neither unanswered nor late. Where a read in
/// between returned empty, it was not there, and the window decides as before.
#[test]
fn a_reply_read_late_by_a_busy_listener_is_its_requests_reply() {
    let v = values(1, &[7]);
    // The empty read that ended the request, then none for 1.5 s.
    let mut m = after_the_request(&[(3, &[]), (1500, &v), (1505, &[])]);
    assert!(kinds(&m, 1).is_empty(), "{:?}", kinds(&m, 1));
    let s = &m.nodes()[&1];
    assert_eq!((s.exchanges, s.replies, s.timeouts), (1, 1, 0));
    let lines = m.take_lines();
    assert_eq!(lines.len(), 1, "{lines:#?}");
    assert_eq!(lines[0].status, VerdictStatus::Pass, "{lines:#?}");
    // The same bytes with a read that came back empty at 1.2 s: the reply came after the
    // window, proved by the reads.
    let m = after_the_request(&[(3, &[]), (1200, &[]), (1500, &v), (1505, &[])]);
    let k = kinds(&m, 1);
    assert!(
        k.contains(&"drive.no-reply".to_string())
            && k.contains(&"drive.unexpected-reply".to_string()),
        "{k:?}"
    );
}

/// A reply read late that came late even at the earliest the reads allow is late: the
/// finding says both times.
#[test]
fn a_reply_late_at_the_earliest_the_reads_allow_is_late() {
    let v = values(1, &[7]);
    // Empty until 400 ms, then the reply read at 900 ms.
    let mut m = after_the_request(&[(3, &[]), (400, &[]), (900, &v), (905, &[])]);
    assert_eq!(kinds(&m, 1), ["drive.late-reply"]);
    let lines = m.take_lines();
    assert!(
        lines[0].issues.iter().any(|i| i == "drive.late-reply"),
        "{lines:#?}"
    );
    let e = m
        .examples()
        .iter()
        .find(|((_, _, k), _)| *k == "late-reply")
        .map(|(_, e)| format!("{e:?}"))
        .unwrap_or_default();
    assert!(
        e.contains("it began 900.0 ms after the request as read (no sooner than 401.1 ms: the listener read it late)"),
        "{e}"
    );
}

/// A listener stopped for 1.2 s (a busy host) reads the bus's backlog at once: the reply
/// to the request it read before, then request and reply after request and reply, 512
/// bytes in one read, past any frame's length. Every frame is dated by that read (the
/// frames past a frame's length were dated by the read before it, 1.2 s earlier, and
/// the reply looked early), and the reply is its request's.
#[test]
fn a_backlog_read_at_once_is_dated_by_its_read() {
    let (r, v) = (read(1, 0x2520, 1), values(1, &[7]));
    let mut backlog = v.clone();
    while backlog.len() + r.len() + v.len() <= 512 {
        backlog.extend_from_slice(&r);
        backlog.extend_from_slice(&v);
    }
    let mut m = after_the_request(&[(1210, &backlog), (1215, &[])]);
    assert!(kinds(&m, 1).is_empty(), "{:?}", kinds(&m, 1));
    let lines = m.take_lines();
    assert_eq!(lines[0].at, ms(0), "{lines:#?}");
    assert!(lines[1..].iter().all(|l| l.at == ms(1210)), "{lines:#?}");
    let mut f = super::frames::TapFramer::new(Mode::Rtu, m.config().line);
    let mut out = Vec::new();
    f.idle(ms(0), &mut out);
    f.push(ms(0), &r, &mut out);
    f.push(ms(1210), &backlog, &mut out);
    f.idle(ms(1215), &mut out);
    assert!(out.len() > 30, "{out:#?}");
    assert!(out[1..].iter().all(|f| f.end == ms(1210)), "{out:#?}");
    // The reply: no sooner than its 7 characters after the read before (1.146 ms each
    // at 9600 8E1), so it may have begun one character after the request.
    assert_eq!(
        out[1].end_low,
        Duration::from_micros(7 * 1146),
        "{:#?}",
        out[1]
    );
}

/// The echo of a 06H write read late by a busy listener (1.5 s, no read between) may
/// have come in time: it is the write's reply, not the master sending it again (which
/// would leave the write unanswered), and its line says both times. Where an empty read
/// in between proves it came after the window, it is the resend, as before.
#[test]
fn a_write_s_echo_read_late_is_its_reply() {
    let w = write(1, 0x2502, 100);
    let heard = |reads: &[(u64, &[u8])]| {
        let mut m = monitor(Mode::Rtu, &[1]);
        for (t, bytes) in reads {
            if bytes.is_empty() {
                m.idle(ms(*t));
            } else {
                m.feed(ms(*t), bytes);
            }
        }
        m.idle(ms(2000));
        m.finish();
        m
    };
    let mut m = heard(&[(0, &[]), (0, &w), (3, &[]), (1500, &w)]);
    assert!(kinds(&m, 1).is_empty(), "{:?}", kinds(&m, 1));
    assert_eq!(m.nodes()[&1].replies, 1);
    let lines = m.take_lines();
    assert_eq!(lines.len(), 1, "{lines:#?}");
    assert!(
        lines[0].notes[0].contains("(1500.0 ms after it as read, no sooner than 4.1 ms: the listener read it late, within the 1000 ms window)"),
        "{lines:#?}"
    );
    // The window closed on the empty read, and the copy is the next request: the master
    // sending it again (left unjudged, as listening ends inside its window).
    let m = heard(&[(0, &[]), (0, &w), (3, &[]), (1200, &[]), (1500, &w)]);
    assert_eq!(kinds(&m, 1), ["drive.no-reply"]);
    assert_eq!(m.nodes()[&1].retries, 1);
}
