//! The tap's framer on pieces with times chosen by the test.

use super::*;
use crate::codec::crc::crc16;
use crate::codec::deframe::bus_rtu_frame_len;
use crate::codec::timing::Parity;

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

fn framer() -> TapFramer {
    TapFramer::new(Mode::Rtu, LineSettings::new(9600, 8, Parity::Even, 1))
}

fn read_frame() -> Vec<u8> {
    crate::codec::pdu::Message {
        address: 1,
        pdu: crate::codec::pdu::Pdu::ReadRequest {
            start: 0x2520,
            count: 1,
        },
    }
    .to_frame_vec(Mode::Rtu)
    .unwrap()
}

fn reply_frame() -> Vec<u8> {
    crate::codec::pdu::Message {
        address: 1,
        pdu: crate::codec::pdu::Pdu::ReadResponse {
            values: crate::codec::pdu::Registers::new(&[0x12, 0x34]).unwrap(),
        },
    }
    .to_frame_vec(Mode::Rtu)
    .unwrap()
}

#[test]
fn silence_ends_frames_and_is_measured_between_pieces() {
    let mut f = framer();
    let mut out = Vec::new();
    f.push(ms(0), &read_frame(), &mut out);
    f.push(ms(100), &reply_frame(), &mut out);
    f.idle(ms(200), &mut out);
    assert_eq!(out.len(), 2, "{out:?}");
    assert!(out
        .iter()
        .all(|t| t.status == FrameStatus::Valid && t.ended_by == EndedBy::Silence));
    assert_eq!(out[1].start, Some(ms(100)));
    let s = out[1].silence_before.unwrap();
    assert!(s > ms(90) && s < ms(100), "{s:?}");
}

#[test]
fn length_splits_frames_delivered_together_and_their_silence_is_unknown() {
    let mut f = framer();
    let mut out = Vec::new();
    f.push(ms(0), &[read_frame(), reply_frame()].concat(), &mut out);
    f.idle(ms(100), &mut out);
    assert_eq!(out.len(), 2, "{out:?}");
    assert_eq!(out[0].ended_by, EndedBy::Length);
    assert_eq!(out[1].ended_by, EndedBy::Silence);
    assert_eq!(out[1].bytes, reply_frame());
    assert_eq!(out[1].silence_before, None);
    assert_eq!(out[1].start, None);
}

/// A 04H request (not served by the drives: answered with exception 01H or 02H) read
/// together with the start of its reply, the rest in the next read, no silence seen
/// between (a stalled host, a tap's latency timer): still two frames, both valid.
#[test]
fn a_request_of_a_function_the_drives_do_not_serve_is_split_from_its_reply() {
    let req = [0x01, 0x04, 0x25, 0x20, 0x00, 0x01, 0x3B, 0x0C];
    let rep = [0x01, 0x84, 0x02, 0xC2, 0xC1];
    assert_eq!(crc16(&req), 0);
    assert_eq!(crc16(&rep), 0);
    for cut in [8, 9, 10, 12] {
        let all = [&req[..], &rep[..]].concat();
        let mut f = framer();
        let mut out = Vec::new();
        f.push(ms(0), &all[..cut], &mut out);
        f.push(Duration::from_micros(1500), &all[cut..], &mut out);
        f.idle(ms(100), &mut out);
        let got: Vec<(&[u8], FrameStatus)> = out.iter().map(|t| (&t.bytes[..], t.status)).collect();
        assert_eq!(
            got,
            [
                (&req[..], FrameStatus::Valid),
                (&rep[..], FrameStatus::Valid)
            ],
            "cut at {cut}: {out:?}"
        );
    }
    // Replies of those functions by their byte count, requests of 0FH by theirs.
    assert_eq!(bus_rtu_frame_len(Direction::Response, &[1, 4, 6]), Some(11));
    assert_eq!(
        bus_rtu_frame_len(Direction::Request, &[1, 0x0F, 0, 0, 0, 9, 2]),
        Some(11)
    );
    assert_eq!(bus_rtu_frame_len(Direction::Request, &[1, 0x2B]), None);
}

#[test]
fn a_gap_over_t15_inside_makes_a_corrupt_block_incomplete() {
    let mut f = framer();
    let mut out = Vec::new();
    let r = read_frame();
    f.push(ms(0), &r[..3], &mut out);
    // Nothing at 3.4 ms (the listener polls), the next byte read at 3.5 ms: a
    // silence of at least 3.4 ms less one character (2.3 ms), over t1.5 (1.7 ms) and
    // under t3.5 (4.0 ms).
    f.idle(Duration::from_micros(3400), &mut out);
    f.push(Duration::from_micros(3500), &r[3..4], &mut out);
    f.idle(ms(50), &mut out);
    // Its length says 4 more bytes are due: held a while for them, then given up.
    assert!(out.is_empty(), "{out:?}");
    f.idle(ms(100), &mut out);
    assert_eq!(out.len(), 1);
    assert_eq!(out[0].status, FrameStatus::Incomplete);
    assert_eq!(out[0].bytes, r[..4]);
}

#[test]
fn a_frame_whose_rest_a_late_reader_got_later_is_joined_by_its_length() {
    let mut f = framer();
    let mut out = Vec::new();
    let r = reply_frame();
    f.push(ms(0), &read_frame(), &mut out);
    // The listener polls: nothing a millisecond before each piece.
    f.idle(ms(99), &mut out);
    f.push(ms(100), &r[..3], &mut out);
    // 20 ms later (over t3.5): the deframer ends a block, the length joins it.
    f.idle(ms(119), &mut out);
    f.push(ms(120), &r[3..], &mut out);
    f.idle(ms(300), &mut out);
    assert_eq!(out.len(), 2, "{out:?}");
    assert_eq!(out[1].bytes, r);
    assert_eq!(out[1].status, FrameStatus::Valid);
    assert_eq!(out[1].start, Some(ms(100)));
    let gap = out[1].max_gap.unwrap();
    assert!(gap > ms(15) && gap <= ms(20), "{gap:?}");
}

/// libmodbus's server answers 0.5 ms after a request: a 04H request (a function
/// whose length the length rule does not know) and its exception reply come as one
/// block. The reply is found by its length; the request before it keeps its valid CRC.
#[test]
fn a_frame_of_a_function_of_unknown_length_glued_to_its_reply_is_a_frame() {
    let mut f = framer();
    let mut out = Vec::new();
    let request = [0x01, 0x04, 0x25, 0x20, 0x00, 0x01, 0x3B, 0x0C];
    let reply = [0x01, 0x84, 0x02, 0xC2, 0xC1];
    f.push(ms(0), &[&request[..], &reply[..]].concat(), &mut out);
    f.idle(ms(50), &mut out);
    assert_eq!(out.len(), 2, "{out:?}");
    assert_eq!(out[0].bytes, request);
    assert_eq!(out[0].status, FrameStatus::Valid);
    assert_eq!(out[1].bytes, reply);
    assert_eq!(out[1].status, FrameStatus::Valid);
}

/// A listener that read the rest of a frame late, with no read between: the reads
/// prove no silence inside it, and it is not cut (nor its reply called gappy).
#[test]
fn a_late_read_inside_a_frame_proves_no_gap() {
    let mut f = framer();
    let mut out = Vec::new();
    let r = reply_frame();
    f.idle(ms(99), &mut out);
    f.push(ms(100), &r[..2], &mut out);
    // Read 30 ms later, no read in between (the host was busy).
    f.push(ms(130), &r[2..], &mut out);
    f.idle(ms(300), &mut out);
    assert_eq!(out.len(), 1, "{out:?}");
    assert_eq!(out[0].status, FrameStatus::Valid);
    assert_eq!(out[0].max_gap, Some(Duration::ZERO));
}

/// Seen with pymodbus's server under load: the listener read the first 3 bytes of a
/// request of a function of unknown length, then nothing for 30 ms (the host
/// was busy), then the rest with the reply. No read proved a silence after the 3
/// bytes: they are joined with the rest, not called a malformed request.
#[test]
fn a_frame_of_unknown_length_read_in_two_late_pieces_is_one_frame() {
    let mut f = framer();
    let mut out = Vec::new();
    // Function 41H (user-defined: no length rule knows it; 04H, first seen here,
    // now has one) and its exception reply.
    let with_crc = |body: &[u8]| {
        let mut v = body.to_vec();
        v.extend_from_slice(&crc16(body).to_le_bytes());
        v
    };
    let request = with_crc(&[0x01, 0x41, 0x25, 0x20, 0x00, 0x01]);
    let reply = with_crc(&[0x01, 0xC1, 0x01]);
    assert!(bus_rtu_frame_len(Direction::Request, &request).is_none());
    f.idle(ms(9), &mut out);
    f.push(ms(10), &request[..3], &mut out);
    f.push(ms(40), &[&request[3..], &reply[..]].concat(), &mut out);
    f.idle(ms(300), &mut out);
    assert_eq!(out.len(), 2, "{out:?}");
    assert_eq!(out[0].bytes, request);
    assert_eq!(out[0].status, FrameStatus::Valid);
    assert_eq!(out[1].bytes, reply);
    // The same bytes with reads that prove the silence (the listener polled at 20
    // and 30 ms): the 3 bytes are a block of their own.
    let mut f = framer();
    let mut out = Vec::new();
    f.idle(ms(9), &mut out);
    f.push(ms(10), &request[..3], &mut out);
    f.idle(ms(20), &mut out);
    f.idle(ms(30), &mut out);
    f.idle(ms(39), &mut out);
    f.push(ms(40), &request[3..], &mut out);
    f.idle(ms(300), &mut out);
    assert_eq!(out[0].bytes, request[..3], "{out:?}");
    assert_ne!(out[0].status, FrameStatus::Valid);
}

#[test]
fn garbage_before_a_frame_comes_out_on_its_own() {
    let mut f = framer();
    let mut out = Vec::new();
    f.push(
        ms(0),
        &[&[0xFF, 0x00][..], &reply_frame()].concat(),
        &mut out,
    );
    f.idle(ms(50), &mut out);
    assert_eq!(out.len(), 2, "{out:?}");
    assert_eq!(out[0].status, FrameStatus::Corrupt);
    assert_eq!(out[0].bytes, [0xFF, 0x00]);
    assert_eq!(out[1].bytes, reply_frame());
}

#[test]
fn ascii_frames_run_from_colon_to_crlf() {
    let mut f = TapFramer::new(Mode::Ascii, LineSettings::new(9600, 7, Parity::Even, 1));
    let mut out = Vec::new();
    f.push(ms(0), b":010325200001B6\r\n", &mut out);
    f.push(ms(100), b":0103021234B4\r", &mut out);
    f.push(ms(101), b"\n", &mut out);
    assert_eq!(
        out.len(),
        1,
        "the last read is framed once time has passed: {out:?}"
    );
    f.idle(ms(101), &mut out);
    assert_eq!(out.len(), 2, "{out:?}");
    assert_eq!(out[1].ended_by, EndedBy::CrLf);
    assert_eq!(out[1].start, Some(ms(100)));
    assert_eq!(out[1].end, ms(101));
}

/// Every frame of `reads` (time in ms, bytes), framed then ended by 2 s of silence.
fn frames_of(mode: Mode, reads: &[(u64, &[u8])]) -> Vec<TapFrame> {
    let line = if mode == Mode::Rtu {
        LineSettings::new(9600, 8, Parity::Even, 1)
    } else {
        LineSettings::new(9600, 7, Parity::Even, 1)
    };
    let mut f = TapFramer::new(mode, line);
    let mut out = Vec::new();
    for (t, bytes) in reads {
        f.push(ms(*t), bytes, &mut out);
    }
    f.idle(ms(2000), &mut out);
    f.finish(&mut out);
    out
}

#[test]
fn reads_at_one_moment_are_framed_as_one_read() {
    // A request, a silence, then its reply and 2 bytes of noise delivered in one read at
    // 30 ms, or in three reads at 30 ms cut anywhere: the same frames, to their times.
    let request = read_frame();
    let tail = [&reply_frame()[..], &[0xFF, 0x00]].concat();
    let whole = frames_of(Mode::Rtu, &[(0, &request), (30, &tail)]);
    assert!(whole.len() >= 2, "{whole:?}");
    for cut in 1..tail.len() {
        for cut2 in cut..tail.len() {
            let (a, rest) = tail.split_at(cut);
            let (b, c) = rest.split_at(cut2 - cut);
            let parts = frames_of(Mode::Rtu, &[(0, &request), (30, a), (30, b), (30, c)]);
            assert_eq!(parts, whole, "cut at {cut} and {cut2}");
        }
    }
    // The same in ASCII.
    let ascii = b":0103021234B4\r\n:01";
    let whole = frames_of(Mode::Ascii, &[(0, b":010325200001B6\r\n"), (40, ascii)]);
    for cut in 1..ascii.len() {
        let (a, b) = ascii.split_at(cut);
        let parts = frames_of(
            Mode::Ascii,
            &[(0, b":010325200001B6\r\n"), (40, a), (40, b)],
        );
        assert_eq!(parts, whole, "ASCII cut at {cut}");
    }
}

#[test]
fn a_read_at_a_later_moment_or_from_another_side_is_another_read() {
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let mut f = TapFramer::new(Mode::Rtu, line);
    let mut out = Vec::new();
    f.push(ms(0), &read_frame(), &mut out);
    assert!(out.is_empty(), "held until time has passed: {out:?}");
    assert_eq!(f.held_bytes(), read_frame().len());
    // Bytes from another sender at the same moment are not the same read.
    f.set_side(Some(1));
    f.push(ms(0), &[0x01], &mut out);
    assert_eq!(
        f.held_bytes(),
        read_frame().len() + 1,
        "the request went to the deframer, the byte is held"
    );
    f.set_side(None);
    f.push(ms(5), &[0x03], &mut out);
    f.finish(&mut out);
    let all: Vec<u8> = out.iter().flat_map(|fr| fr.bytes.clone()).collect();
    assert_eq!(all, [&read_frame()[..], &[0x01, 0x03]].concat());
    assert_eq!(out[0].bytes, read_frame());
    assert_eq!(out[0].end, ms(0));
}

#[test]
fn reads_at_one_moment_are_held_a_read_buffer_at_a_time() {
    let line = LineSettings::new(115_200, 8, Parity::Even, 1);
    let mut f = TapFramer::new(Mode::Rtu, line);
    let mut out = Vec::new();
    let noise = vec![0xFFu8; 3 * STAGE_BYTES + 7];
    for chunk in noise.chunks(100) {
        f.push(ms(1), chunk, &mut out);
        assert!(
            f.held_bytes() <= STAGE_BYTES + 2 * crate::codec::MAX_ASCII_FRAME,
            "{} bytes held",
            f.held_bytes()
        );
    }
    f.finish(&mut out);
    assert_eq!(
        out.iter().map(|fr| fr.bytes.len()).sum::<usize>(),
        noise.len()
    );
}
