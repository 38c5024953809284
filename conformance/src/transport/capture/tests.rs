//! The recorder and the recorded transport on in-memory links: the packets, their
//! flags, comments and times as a reader of the file sees them.

use super::captured::line_silence;
use super::*;
use crate::capture::{Packet, Reader, FLAG_INBOUND, FLAG_OUTBOUND, FLAG_WRONG_GAP};
use crate::codec::timing::LineSettings;
use crate::codec::timing::Parity;
use crate::codec::Mode;
use crate::transport::memory;
use crate::transport::{LinkKind, Transport, TransportError};

/// A sink the test reads back after the recorder wrote to it.
#[derive(Clone, Default)]
struct Sink(Arc<Mutex<Vec<u8>>>);

impl Write for Sink {
    fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(b);
        Ok(b.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

impl Sink {
    /// What the recorder wrote so far.
    fn bytes(&self) -> Vec<u8> {
        self.0.lock().unwrap().clone()
    }
}

/// A recorder on a sink the test reads back.
fn recorder() -> (Sink, SharedRecorder) {
    let sink = Sink::default();
    let rec = Recorder::new(Box::new(sink.clone()), "test")
        .unwrap()
        .shared();
    (sink, rec)
}

/// The packets of a capture whose every block reads.
fn read_back(data: &[u8]) -> Vec<Packet<'_>> {
    Reader::new(data)
        .unwrap()
        .collect::<Result<_, _>>()
        .unwrap()
}

const REQUEST: [u8; 8] = [0x01, 0x03, 0x01, 0x23, 0x00, 0x01, 0x74, 0x3C];
const REPLY: [u8; 7] = [0x01, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50];
const EXCEPTION: [u8; 5] = [0x01, 0x83, 0x02, 0xC0, 0xF1];

fn drain(t: &mut impl Transport, wait: Duration) -> usize {
    let mut buf = [0u8; 64];
    t.recv(&mut buf, wait).unwrap()
}

#[test]
fn sends_and_receives_become_packets_with_directions_flags_and_comments() {
    let (sink, rec) = recorder();
    let (a, mut b) = memory::pair();
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let mut a = Captured::new(a, rec.clone(), Mode::Rtu, line);
    rec.lock()
        .unwrap()
        .set_label(Some("check rtu.bad-crc".into()));
    a.send(&REQUEST).unwrap();
    // A reply the host delivers in two parts 20 ms apart (over the 5 ms frame gap):
    // its length says it is not whole after the first part, so it is one packet.
    b.send(&REPLY[..3]).unwrap();
    assert_eq!(drain(&mut a, Duration::from_millis(200)), 3);
    std::thread::sleep(Duration::from_millis(20));
    b.send(&REPLY[3..]).unwrap();
    assert_eq!(drain(&mut a, Duration::from_millis(200)), 4);
    // A whole frame after a silence: a new packet.
    std::thread::sleep(Duration::from_millis(20));
    b.send(&EXCEPTION).unwrap();
    assert_eq!(drain(&mut a, Duration::from_millis(200)), 5);
    assert_eq!(drain(&mut a, Duration::from_millis(20)), 0);
    let mut bad = REQUEST;
    bad[7] ^= 0xFF;
    a.send(&bad).unwrap();
    a.send_pieces(&[&REQUEST[..4], &REQUEST[4..]], Duration::from_millis(2))
        .unwrap();
    drop(a);
    let data = sink.bytes();
    let packets = read_back(&data);
    let seen: Vec<(&[u8], u32)> = packets
        .iter()
        .map(|p| (p.data, p.flags.unwrap_or(0)))
        .collect();
    assert_eq!(
        seen,
        vec![
            (&REQUEST[..], FLAG_OUTBOUND),
            (&REPLY[..], FLAG_INBOUND),
            (&EXCEPTION[..], FLAG_INBOUND),
            (&bad[..], FLAG_OUTBOUND | capture::FLAG_CRC_ERROR),
            (&REQUEST[..4], FLAG_OUTBOUND | capture::FLAG_CRC_ERROR),
            (
                &REQUEST[4..],
                FLAG_OUTBOUND | capture::FLAG_CRC_ERROR | FLAG_WRONG_GAP
            ),
        ]
    );
    assert!(packets
        .iter()
        .all(|p| p.link_type == capture::LINKTYPE_USER0));
    assert_eq!(packets[0].comment, None);
    assert_eq!(packets[1].comment, None);
    assert_eq!(
        packets[3].comment,
        Some("check rtu.bad-crc: sent with a wrong CRC on purpose")
    );
    assert!(packets[5]
        .comment
        .is_some_and(|c| c.starts_with("check rtu.bad-crc: ") && c.contains("piece 2 of 2")));
    // Times: in order, the reply after the request, the exception 20 ms or more after
    // the reply's first part.
    let t: Vec<u64> = packets.iter().map(|p| p.timestamp_ns.unwrap()).collect();
    assert!(t.windows(2).all(|w| w[0] <= w[1]), "{t:?}");
    assert!(t[2] - t[1] >= 40_000_000, "{t:?}");
    assert_eq!(rec.lock().unwrap().packets(), 6);
    assert_eq!(rec.lock().unwrap().error(), None);
}

/// 9600 8E1 (1146 us a character, a 5 ms frame gap): four characters read 7 ms after
/// the read before came within the last 4.6 ms, so the line was silent 2.4 ms at most
/// (no frame gap); one character 7 ms later leaves 5.9 ms (a frame gap); with the
/// host's timing only, the time between reads is all there is.
#[test]
fn the_silence_between_reads_leaves_out_the_time_the_characters_took() {
    let c = Some(Duration::from_micros(1146));
    let ms = Duration::from_millis;
    assert_eq!(
        line_silence(ms(7), 4, c),
        Duration::from_micros(7000 - 4584)
    );
    assert_eq!(
        line_silence(ms(7), 1, c),
        Duration::from_micros(7000 - 1146)
    );
    assert_eq!(line_silence(ms(7), 0, c), ms(7));
    assert_eq!(line_silence(ms(3), 10, c), Duration::ZERO);
    assert_eq!(line_silence(ms(7), 4, None), ms(7));
    assert_eq!(line_silence(ms(7), usize::MAX, c), Duration::ZERO);
}

#[test]
fn a_tap_records_requests_and_replies_apart_and_without_direction() {
    let (sink, rec) = recorder();
    let (a, mut b) = memory::pair();
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let mut a = Captured::new(a, rec, Mode::Rtu, line).as_tap();
    // A request read as a reply would be 42 bytes long (byte count 25H): its right
    // CRC says it is whole.
    let request = [0x01, 0x03, 0x25, 0x20, 0x00, 0x01, 0x8E, 0xCC];
    b.send(&request).unwrap();
    assert_eq!(drain(&mut a, Duration::from_millis(200)), 8);
    std::thread::sleep(Duration::from_millis(20));
    b.send(&REPLY).unwrap();
    assert_eq!(drain(&mut a, Duration::from_millis(200)), 7);
    drop(a);
    let data = sink.bytes();
    let packets = read_back(&data);
    let seen: Vec<(&[u8], Option<u32>)> = packets.iter().map(|p| (p.data, p.flags)).collect();
    assert_eq!(seen, vec![(&request[..], None), (&REPLY[..], None)]);
}

/// A tap that began listening while the line was busy (a backlog read at once, before
/// any read came back empty) marks its first packet, so that a reader judges it as the
/// live monitor did; one that heard the line quiet first marks none. On a link with no
/// timing of its own, a packet is dated back from its read one character time of the
/// line a byte, as the monitor dates the read: 15 bytes at 9600 8E1 end at the read,
/// so they began 17.2 ms before it.
#[test]
fn a_tap_marks_a_packet_read_before_the_line_was_quiet_and_dates_it_back() {
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let chars = Duration::from_micros(line.char_time_us() * 15);
    for quiet_first in [false, true] {
        let (sink, rec) = recorder();
        let (a, mut b) = memory::pair();
        let mut a = Captured::new(a, rec, Mode::Rtu, line).as_tap();
        if quiet_first {
            assert_eq!(drain(&mut a, Duration::from_millis(5)), 0);
        }
        b.send(&[&REQUEST[..], &REPLY[..]].concat()).unwrap();
        assert_eq!(drain(&mut a, Duration::from_millis(200)), 15);
        let read = std::time::SystemTime::now()
            .duration_since(std::time::UNIX_EPOCH)
            .unwrap();
        std::thread::sleep(Duration::from_millis(20));
        assert_eq!(drain(&mut a, Duration::from_millis(5)), 0);
        b.send(&REQUEST).unwrap();
        assert_eq!(drain(&mut a, Duration::from_millis(200)), 8);
        drop(a);
        let data = sink.bytes();
        let packets = read_back(&data);
        assert_eq!(packets.len(), 2, "{quiet_first}");
        let first = packets[0].comment;
        if quiet_first {
            assert_eq!(first, None);
        } else {
            assert!(capture::heard_mid_traffic(first), "{first:?}");
        }
        assert_eq!(packets[1].comment, None);
        let ts = Duration::from_nanos(packets[0].timestamp_ns.unwrap());
        assert!(
            ts + chars <= read,
            "dated {:?} before the read returned",
            read.saturating_sub(ts)
        );
    }
}

/// The rest of a reply read long after its first part (the reading host stalled) is
/// the same packet, as the master that waits its timeout for it takes it whole.
#[test]
fn a_reply_read_in_two_parts_by_a_stalled_host_is_one_packet_while_the_master_waits() {
    let (sink, rec) = recorder();
    let (a, mut b) = memory::pair();
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let mut a = Captured::new(a, rec, Mode::Rtu, line).holding_frames_for(Duration::from_secs(30));
    a.send(&REQUEST).unwrap();
    b.send(&REPLY[..4]).unwrap();
    let mut got = 0;
    while got < 4 {
        got += drain(&mut a, Duration::from_millis(100));
    }
    // Longer than HOST_STALL, far shorter than the hold.
    std::thread::sleep(HOST_STALL + Duration::from_millis(100));
    b.send(&REPLY[4..]).unwrap();
    while got < REPLY.len() {
        got += drain(&mut a, Duration::from_millis(100));
    }
    a.send(&REQUEST).unwrap();
    drop(a);
    let data = sink.bytes();
    let packets = read_back(&data);
    let datas: Vec<&[u8]> = packets.iter().map(|p| p.data).collect();
    assert_eq!(datas, [&REQUEST[..], &REPLY[..], &REQUEST[..]]);
    assert_eq!(packets[1].flags.unwrap_or(0) & capture::FLAG_CRC_ERROR, 0);
}

#[test]
fn bytes_discarded_by_the_caller_are_in_the_capture_first() {
    let (sink, rec) = recorder();
    let (a, mut b) = memory::pair();
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let mut a = Captured::new(a, rec, Mode::Rtu, line);
    a.send(&REQUEST).unwrap();
    b.send(&REPLY).unwrap();
    std::thread::sleep(Duration::from_millis(10));
    a.discard_input().unwrap();
    assert_eq!(drain(&mut a, Duration::from_millis(10)), 0);
    drop(a);
    let data = sink.bytes();
    let packets = read_back(&data);
    assert_eq!(packets.len(), 2);
    assert_eq!(packets[1].data, &REPLY);
    assert_eq!(packets[1].direction, Some(capture::Direction::Inbound));
}

#[test]
fn a_failing_file_stops_the_recording_and_says_why_once() {
    struct Full;
    impl Write for Full {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            Err(std::io::Error::other("disk full"))
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    // The section header goes to a sink that fails from the first packet on.
    struct Once(bool);
    impl Write for Once {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            if self.0 {
                Full.write(b)
            } else {
                Ok(b.len())
            }
        }
        fn flush(&mut self) -> std::io::Result<()> {
            self.0 = true;
            Ok(())
        }
    }
    let rec = Recorder::new(Box::new(Once(false)), "test")
        .unwrap()
        .shared();
    let (a, _b) = memory::pair();
    let mut a = Captured::new(
        a,
        rec.clone(),
        Mode::Rtu,
        LineSettings::new(9600, 8, Parity::Even, 1),
    );
    // The link goes on working; the recording stopped at the interface block.
    a.send(&REQUEST).unwrap();
    a.send(&REQUEST).unwrap();
    let r = rec.lock().unwrap();
    assert_eq!(r.packets(), 0);
    assert!(
        r.error().is_some_and(|e| e.contains("disk full")),
        "{:?}",
        r.error()
    );
}

/// An in-memory link that says what a paced link says: its first `broken` sends were
/// broken by its host ([`Transport::send_was_broken`]), and the simulator at its other
/// end told when it began its replies (`starts`, [`Transport::peer_reply_starts`]).
struct Shaped {
    inner: memory::MemoryEnd,
    broken: u32,
    sends: u32,
    starts: Option<crate::transport::ReplyStarts>,
}

impl Shaped {
    fn new(inner: memory::MemoryEnd) -> Self {
        Shaped {
            inner,
            broken: 0,
            sends: 0,
            starts: None,
        }
    }
}

impl Transport for Shaped {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.sends += 1;
        self.inner.send(bytes)
    }
    fn recv(&mut self, buf: &mut [u8], t: Duration) -> Result<usize, TransportError> {
        self.inner.recv(buf, t)
    }
    fn discard_input(&mut self) -> Result<(), TransportError> {
        self.inner.discard_input()
    }
    fn describe(&self) -> String {
        "a paced link".into()
    }
    fn line_timing(&self) -> Option<LineSettings> {
        None
    }
    fn kind(&self) -> LinkKind {
        LinkKind::Pty
    }
    fn send_was_broken(&self) -> bool {
        self.sends <= self.broken
    }
    fn peer_reply_starts(&self) -> Option<crate::transport::ReplyStarts> {
        self.starts.clone()
    }
}

/// A link whose host stalled inside a send (on a line whose receiver is not told the
/// silences, see [`Transport::send_was_broken`]): each broken send is its own outbound
/// packet flagged "wrong inter-frame gap" (bit 27) with a comment saying the host broke
/// it, which [`capture::broken_by_host`] reads back; the next, whole send is plain.
#[test]
fn a_send_the_host_broke_is_flagged_and_commented_and_the_next_one_is_not() {
    let (sink, rec) = recorder();
    let (a, _b) = memory::pair();
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let link = Shaped {
        broken: 2,
        ..Shaped::new(a)
    };
    let mut a = Captured::new(link, rec.clone(), Mode::Rtu, line);
    for _ in 0..3 {
        a.send(&REQUEST).unwrap();
    }
    drop(a);
    let data = sink.bytes();
    let packets = read_back(&data);
    let broken: Vec<bool> = packets
        .iter()
        .map(|p| capture::broken_by_host(p.flags, p.comment))
        .collect();
    assert_eq!(broken, [true, true, false]);
    assert!(packets.iter().all(|p| p.data == REQUEST));
    assert_eq!(packets[0].flags, Some(FLAG_OUTBOUND | FLAG_WRONG_GAP));
    assert_eq!(packets[2].flags, Some(FLAG_OUTBOUND));
    // ASCII is not broken by a silence under its 1 s timeout: nothing is flagged.
    let (sink, rec) = recorder();
    let (a, _b) = memory::pair();
    let link = Shaped {
        broken: 1,
        ..Shaped::new(a)
    };
    let mut a = Captured::new(link, rec, Mode::Ascii, line);
    a.send(b":010300000001FB\r\n").unwrap();
    drop(a);
    let data = sink.bytes();
    let p = read_back(&data);
    assert_eq!(p.len(), 1);
    assert!(!capture::broken_by_host(p[0].flags, p[0].comment));
}

/// Where the simulator at the other end says when it began its replies, a reply is
/// recorded at that time (whenever this host read it); one it began 30 ms after it was
/// due carries a comment that says so, which [`capture::late_on_host`] reads back; one
/// on time carries none, and a start from before the request (an earlier reply's) is
/// not taken for this one's.
#[test]
fn a_reply_the_simulators_host_began_late_is_recorded_when_it_began_and_marked() {
    let (sink, rec) = recorder();
    let (a, mut b) = memory::pair();
    let starts = crate::transport::ReplyStarts::default();
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let link = Shaped {
        starts: Some(starts.clone()),
        ..Shaped::new(a)
    };
    let mut a = Captured::new(link, rec, Mode::Rtu, line);
    let after = Duration::from_millis(10);
    let mut began = Vec::new();
    let mut slack = Duration::ZERO;
    for late in [Duration::from_millis(30), Duration::ZERO] {
        // An earlier reply's start, before this request: not this reply's.
        crate::transport::push_reply_start(
            &starts,
            crate::transport::ReplyStart {
                at: Instant::now(),
                after,
            },
        );
        std::thread::sleep(Duration::from_millis(2));
        let before = Instant::now();
        a.send(&REQUEST).unwrap();
        let sent = Instant::now();
        slack = slack.max(sent - before);
        let at = sent + after + late;
        began.push((before, at));
        crate::transport::push_reply_start(&starts, crate::transport::ReplyStart { at, after });
        while Instant::now() < at {
            std::thread::sleep(Duration::from_millis(1));
        }
        b.send(&REPLY).unwrap();
        // Read well after it came (this host busy too).
        std::thread::sleep(Duration::from_millis(40));
        assert_eq!(drain(&mut a, Duration::from_millis(200)), 7);
    }
    drop(a);
    let data = sink.bytes();
    let packets = read_back(&data);
    assert_eq!(packets.len(), 4);
    let late = capture::late_on_host(packets[1].comment).expect("the late reply is marked");
    // Late by 30 ms from the end of the request as the recorder's clock read it (a
    // little before this test's own reading of it).
    assert!(
        late >= Duration::from_millis(30)
            && late <= Duration::from_millis(30) + slack + Duration::from_millis(1),
        "{late:?}"
    );
    assert_eq!(packets[3].comment, None);
    // Recorded when the simulator began, not when this host read them (40 ms later).
    let t = |i: usize| Duration::from_nanos(packets[i].timestamp_ns.unwrap());
    for (k, i) in [1usize, 3].into_iter().enumerate() {
        let took = t(i) - t(i - 1);
        let meant = began[k].1 - began[k].0;
        assert!(
            took.abs_diff(meant) < Duration::from_millis(1),
            "packet {i}: {took:?} against {meant:?}"
        );
    }
}
