//! A whole packet fed at once ([`Monitor::feed_packet`], [`TapFramer::push_packet`])
//! against the two pieces it stands for (its first byte, then the rest): the same frames,
//! field for field, and the same verdicts, over varied traffic and timings.

use std::time::Duration;

use super::frames::{TapFrame, TapFramer};
use super::replay::{replay, replay_in_two_pieces};
use super::tests::{everything, kinds, varied_traffic};
use super::*;
use crate::capture::{Direction as CapDirection, Interface, PacketMeta, PcapngWriter};
use crate::codec::pdu::Pdu;
use crate::codec::timing::Parity;

/// A small deterministic generator (xorshift64*): no seed from the clock.
struct Rng(u64);

impl Rng {
    fn next(&mut self) -> u64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        self.0.wrapping_mul(0x2545_F491_4F6C_DD1D)
    }

    fn below(&mut self, n: u64) -> u64 {
        self.next() % n.max(1)
    }
}

/// One packet: its time (us), its bytes, its side.
type Packet = (u64, Vec<u8>, Option<bool>);

/// Packets as a capture would hold them, cut, glued and timed at random from frames of
/// the varied traffic, with garbage, long bursts and bytes no address begins.
fn random_packets(seed: u64, line: LineSettings, count: usize) -> Vec<Packet> {
    let mut rng = Rng(seed | 1);
    let frames: Vec<Vec<u8>> = varied_traffic(1).into_iter().map(|(_, f)| f).collect();
    let char_us = line.char_time_us();
    let mut out = Vec::new();
    let mut t = 1_000u64;
    let mut stream: Vec<u8> = Vec::new();
    while out.len() < count {
        if stream.is_empty() {
            match rng.below(12) {
                0 => stream.extend((0..rng.below(8) + 1).map(|_| rng.next() as u8)),
                1 => stream.extend((0..rng.below(400) + 200).map(|_| rng.next() as u8)),
                2 => {
                    stream.push(0xF8 + rng.below(8) as u8);
                    stream.extend(&frames[rng.below(frames.len() as u64) as usize]);
                }
                _ => stream.extend(&frames[rng.below(frames.len() as u64) as usize]),
            }
            if rng.below(4) == 0 {
                // Glued to the next frame in one packet.
                stream.extend(&frames[rng.below(frames.len() as u64) as usize]);
            }
        }
        let take = match rng.below(6) {
            0 => 1,
            1 => rng.below(4) as usize + 1,
            _ => stream.len(),
        }
        .min(stream.len());
        let bytes: Vec<u8> = stream.drain(..take).collect();
        let side = match rng.below(3) {
            0 => None,
            1 => Some(true),
            _ => Some(false),
        };
        out.push((t, bytes.clone(), side));
        // The next packet: after this one's characters and a gap from none (or less:
        // times that overlap) to well past t3.5, now and then much later.
        let chars = char_us * bytes.len() as u64;
        t += match rng.below(8) {
            0 => rng.below(chars + 1),
            1..=3 => chars + rng.below(char_us * 6),
            4 => chars + rng.below(60_000),
            5 => chars + 200_000 + rng.below(2_000_000),
            _ => chars + rng.below(char_us * 40),
        };
    }
    out
}

/// The frames a framer gives for `packets`, fed as `replay` feeds a monitor: whole, or in
/// two pieces. Every call's frames are kept apart, so that the two are compared call by
/// call. Also: how many packets the framer took whole.
fn framed(line: LineSettings, packets: &[Packet], whole: bool) -> (Vec<Vec<TapFrame>>, usize) {
    let mut f = TapFramer::new(Mode::Rtu, line);
    let char = Duration::from_micros(line.char_time_us());
    let mut calls = Vec::new();
    let mut taken = 0;
    for (t, bytes, side) in packets {
        let first = Duration::from_micros(*t);
        let mut out = Vec::new();
        f.idle(first, &mut out);
        calls.push(std::mem::take(&mut out));
        f.set_side(side.map(u64::from));
        let end = first + char * bytes.len() as u32;
        taken += usize::from(f.takes_whole(bytes));
        if whole {
            f.push_packet(first + char, end, bytes, &mut out);
        } else {
            let (head, rest) = bytes.split_at(1.min(bytes.len()));
            f.push(first + char, head, &mut out);
            f.push(end, rest, &mut out);
        }
        calls.push(out);
    }
    let mut out = Vec::new();
    f.finish(&mut out);
    calls.push(out);
    (calls, taken)
}

fn lines() -> [LineSettings; 4] {
    [
        LineSettings::new(9600, 8, Parity::Even, 1),
        LineSettings::new(19200, 8, Parity::None, 2),
        LineSettings::new(115200, 8, Parity::Even, 1),
        LineSettings::new(1200, 8, Parity::Odd, 1),
    ]
}

/// The framer gives the same frames, every field, call by call, whole or in two pieces.
#[test]
fn a_whole_packet_gives_the_frames_of_its_two_pieces() {
    let mut whole_taken = 0;
    for line in lines() {
        for seed in 1..=12u64 {
            let packets = random_packets(seed * 7919, line, 3000);
            let (whole, taken) = framed(line, &packets, true);
            let (pieces, _) = framed(line, &packets, false);
            whole_taken += taken;
            assert_eq!(whole.len(), pieces.len());
            for (i, (w, p)) in whole.iter().zip(&pieces).enumerate() {
                assert_eq!(w, p, "line {line}, seed {seed}, call {i}");
            }
            let n: usize = whole.iter().map(Vec::len).sum();
            assert!(n > 1000, "{n}");
        }
    }
    assert!(whole_taken > 10_000, "{whole_taken}");
}

fn monitor_on(mode: Mode, line: LineSettings, nodes: &[u8]) -> Monitor {
    Monitor::new(
        crate::model::DriveModel::builtin("f510").unwrap(),
        MonitorConfig {
            gap_allowance: Duration::from_millis(5),
            ..MonitorConfig::new(mode, line, nodes.to_vec())
        },
    )
    .unwrap()
}

/// A pcapng capture of `packets` (with their directions where `sides`).
fn capture(link_type: u16, packets: &[Packet], sides: bool) -> Vec<u8> {
    let mut w = PcapngWriter::new(Vec::new(), "tests_packet").unwrap();
    w.add_interface(&Interface {
        link_type,
        name: "test".into(),
        description: "test".into(),
    })
    .unwrap();
    for (t, bytes, side) in packets {
        let flags = match side {
            Some(true) if sides => CapDirection::Outbound.flag(),
            Some(false) if sides => CapDirection::Inbound.flag(),
            _ => 0,
        };
        let meta = PacketMeta {
            interface: 0,
            timestamp_us: 1_700_000_000_000_000 + t,
            flags,
            comment: None,
        };
        w.write_packet(&meta, bytes).unwrap();
    }
    w.into_inner()
}

/// Everything two monitors report after judging `data`, whole and in two pieces.
fn judged_both(
    data: &[u8],
    mode: Mode,
    line: LineSettings,
    live: bool,
) -> [(String, Vec<String>); 2] {
    [true, false].map(|whole| {
        let mut m = monitor_on(mode, line, &[1]);
        m.set_live(live);
        let mut lines = Vec::new();
        let r = if whole {
            replay(data, &mut m, |l| lines.push(l.clone()))
        } else {
            replay_in_two_pieces(data, &mut m, |l| lines.push(l.clone()))
        }
        .unwrap();
        let all = format!(
            "{}\n{} {} {:?}",
            everything(&m, &lines),
            r.packets,
            r.bytes,
            r.span
        );
        (all, kinds(&m, 1))
    })
}

/// The varied traffic of `the_memo_changes_no_verdict` as captures (each frame a packet,
/// with and without directions; the frames squeezed together; the frames cut and glued
/// at random), judged whole and in two pieces: the same lines, statistics, findings,
/// examples, notices and results.
#[test]
fn a_capture_judged_by_whole_packets_gets_the_verdicts_of_two_pieces() {
    let traffic = varied_traffic(6);
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let char_us = line.char_time_us();
    let as_sent: Vec<Packet> = traffic
        .iter()
        .enumerate()
        .map(|(i, (t, f))| (t * 1000, f.clone(), Some(i % 2 == 0)))
        .collect();
    // Each frame 1 to 3 characters after the one before: blocks the length rule splits.
    let mut t = 0;
    let squeezed: Vec<Packet> = traffic
        .iter()
        .enumerate()
        .map(|(i, (_, f))| {
            let at = t;
            t += char_us * (f.len() as u64 + 1 + i as u64 % 3);
            (at, f.clone(), None)
        })
        .collect();
    let mut checked = 0;
    for (packets, sides) in [(&as_sent, true), (&as_sent, false), (&squeezed, false)] {
        let data = capture(crate::capture::LINKTYPE_USER0, packets, sides);
        for live in [true, false] {
            let [(w, k), (p, _)] = judged_both(&data, Mode::Rtu, line, live);
            assert!(w == p, "live {live}:\n{w}\n---\n{p}");
            if packets == &as_sent {
                for want in ["drive.wrong-value", "drive.late-reply", "master.retry"] {
                    assert!(k.contains(&want.to_string()), "{want} not in {k:?}");
                }
            }
            checked += 1;
        }
    }
    for l in lines() {
        for seed in 1..=4u64 {
            let packets = random_packets(seed * 104_729, l, 2000);
            let data = capture(crate::capture::LINKTYPE_USER0, &packets, seed % 2 == 0);
            let [(w, _), (p, _)] = judged_both(&data, Mode::Rtu, l, seed % 2 == 0);
            assert!(w == p, "line {l}, seed {seed}:\n{w}\n---\n{p}");
            checked += 1;
        }
    }
    // ASCII (never framed whole: the two pieces either way).
    let ascii = LineSettings::new(9600, 7, Parity::Even, 1);
    let req = crate::codec::pdu::Message {
        address: 1,
        pdu: Pdu::ReadRequest {
            start: 0x2520,
            count: 1,
        },
    }
    .to_frame_vec(Mode::Ascii)
    .unwrap();
    let packets: Vec<Packet> = (0..20u64)
        .map(|i| (i * 40_000, req.clone(), Some(true)))
        .collect();
    let data = capture(crate::capture::LINKTYPE_USER0 + 1, &packets, true);
    let [(w, _), (p, _)] = judged_both(&data, Mode::Ascii, ascii, true);
    assert!(w == p, "ascii:\n{w}\n---\n{p}");
    assert_eq!(checked, 6 + 16);
}

/// A read of 2520H of node 1, and its reply.
const REQUEST: [u8; 8] = [0x01, 0x03, 0x25, 0x20, 0x00, 0x01, 0x8E, 0xCC];
const REPLY: [u8; 7] = [0x01, 0x03, 0x02, 0x00, 0x04, 0xB9, 0x87];

/// A pcapng capture on one RTU interface of `packets`: each its time (us since the
/// epoch), bytes, `epb_flags` and comment.
fn commented_capture(packets: &[(u64, &[u8], u32, Option<String>)]) -> Vec<u8> {
    let mut w = PcapngWriter::new(Vec::new(), "tests_packet").unwrap();
    w.add_interface(&Interface {
        link_type: crate::capture::LINKTYPE_USER0,
        name: "test".into(),
        description: "test".into(),
    })
    .unwrap();
    for (t, bytes, flags, comment) in packets {
        let meta = PacketMeta {
            interface: 0,
            timestamp_us: *t,
            flags: *flags,
            comment: comment.clone(),
        };
        w.write_packet(&meta, bytes).unwrap();
    }
    w.into_inner()
}

/// A reply its capture's writer marked as begun late by the host of the simulator it ran
/// (`check --sim` on a busy host) is judged when it was due: no `drive.late-reply`, and the
/// replay counts it. The same reply unmarked, 60 ms after its request, is a late reply.
#[test]
fn a_reply_marked_late_by_the_writers_host_is_judged_when_it_was_due() {
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let char_us = line.char_time_us();
    let late = 50_000u64;
    let mut judged = Vec::new();
    for marked in [false, true] {
        let t0 = 1_700_000_000_000_000u64;
        let comment = format!(
            "check rtu.map.monitor.first: {}: {late} us (the simulator on this host was due to begin it 10.0 ms after the request)",
            crate::capture::LATE_ON_HOST
        );
        let data = commented_capture(&[
            (t0, &REQUEST[..], CapDirection::Outbound.flag(), None),
            (
                t0 + 8 * char_us + 10_000 + late,
                &REPLY[..],
                CapDirection::Inbound.flag(),
                marked.then(|| comment.clone()),
            ),
        ]);
        let mut m = monitor_on(Mode::Rtu, line, &[1]);
        let r = replay(&data, &mut m, |_| {}).unwrap();
        assert_eq!(r.late_on_host, u64::from(marked));
        judged.push(kinds(&m, 1));
    }
    assert!(
        judged[0].contains(&"drive.late-reply".to_string()),
        "{:?}",
        judged[0]
    );
    assert!(judged[1].is_empty(), "{:?}", judged[1]);
}

/// A capture whose first packet its writer marked as read before the line was heard
/// quiet (`monitor --capture` that began listening while the line was busy: a backlog of
/// two exchanges read at once) is judged as the live monitor judged it: that packet's
/// bytes are not judged, with the same notice, and the exchange after the silence is.
/// Unmarked (a sniffer's file, which begins quiet), the backlog's exchanges are judged
/// too.
#[test]
fn a_first_packet_read_mid_traffic_is_judged_as_the_live_monitor_did() {
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let backlog = [&REQUEST[..], &REPLY[..], &REQUEST[..], &REPLY[..]].concat();
    let char_us = line.char_time_us();
    for marked in [false, true] {
        let t0 = 1_700_000_000_000_000u64;
        let comment = format!(
            "{}: listening began while the line was busy, so this may begin inside a frame",
            crate::capture::HEARD_MID_TRAFFIC
        );
        let t1 = t0 + 30 * char_us + 20_000;
        let data = commented_capture(&[
            (t0, &backlog[..], 0, marked.then_some(comment)),
            (t1, &REQUEST[..], 0, None),
            (t1 + 8 * char_us + 10_000, &REPLY[..], 0, None),
        ]);
        let mut m = monitor_on(Mode::Rtu, line, &[1]);
        let r = replay(&data, &mut m, |_| {}).unwrap();
        assert_eq!((r.packets, r.bytes), (3, 45));
        assert_eq!(kinds(&m, 1), Vec::<String>::new());
        let said = m.notices().iter().any(|n| {
            n.starts_with("listening began in the middle of the traffic: the first 30 bytes")
        });
        assert_eq!(said, marked, "{:?}", m.notices());
        assert_eq!(
            m.nodes()[&1].exchanges,
            if marked { 1 } else { 3 },
            "{:?}",
            m.notices()
        );
    }
}
