//! Tests of the master: replies in pieces, echoes, garbage, and requests the host broke
//! while pacing them.
use super::*;
use crate::transport::memory;

fn timing() -> MasterTiming {
    MasterTiming {
        timeout: Duration::from_millis(800),
        silence: Duration::from_millis(100),
        derive_silence: false,
        quiet: Duration::from_millis(30),
        gap: Duration::from_millis(1),
        retries: 0,
    }
}

/// A peer that reads one request and answers with `pieces`, each after its delay.
/// It hands its end back, so that the line stays open until the test is done.
fn peer(
    mut t: memory::MemoryEnd,
    pieces: Vec<(u64, Vec<u8>)>,
) -> std::thread::JoinHandle<memory::MemoryEnd> {
    std::thread::spawn(move || {
        let mut buf = [0u8; 64];
        let t0 = Instant::now();
        while t.recv(&mut buf, Duration::from_millis(20)).unwrap_or(0) == 0 {
            if t0.elapsed() > Duration::from_secs(2) {
                return t;
            }
        }
        for (ms, bytes) in pieces {
            std::thread::sleep(Duration::from_millis(ms));
            let _ = t.send(&bytes);
        }
        t
    })
}

#[test]
fn a_reply_that_stalls_mid_frame_is_collected_whole() {
    let req = [0x01, 0x03, 0x25, 0x20, 0x00, 0x01, 0x8E, 0xCC];
    let reply = [0x01, 0x03, 0x02, 0x00, 0x04, 0xB9, 0x87];
    for (mode_split, at) in [(Mode::Rtu, 1), (Mode::Rtu, 3), (Mode::Rtu, 6)] {
        let (a, b) = memory::pair();
        let h = peer(
            b,
            vec![(5, reply[..at].to_vec()), (120, reply[at..].to_vec())],
        );
        let mut m = Master::new(Box::new(a), mode_split, timing());
        let ex = m.exchange(&req, true).unwrap();
        h.join().unwrap();
        assert_eq!(
            ex.reply.as_deref(),
            Some(&reply[..]),
            "split at {at}: {:02X?}",
            ex.raw
        );
    }
    // ASCII: the CR LF comes 120 ms after the rest.
    let (a, b) = memory::pair();
    let h = peer(
        b,
        vec![(5, b":010302000AF0".to_vec()), (120, b"\r\n".to_vec())],
    );
    let mut m = Master::new(Box::new(a), Mode::Ascii, timing());
    let ex = m.exchange(b":010325200001B6\r\n", true).unwrap();
    h.join().unwrap();
    assert_eq!(ex.reply.as_deref(), Some(&b":010302000AF0\r\n"[..]));
    // A reply cut short for good is kept as it is, after the timeout.
    let (a, b) = memory::pair();
    let h = peer(b, vec![(5, reply[..5].to_vec())]);
    let mut m = Master::new(Box::new(a), Mode::Rtu, timing());
    let ex = m.exchange(&req, true).unwrap();
    h.join().unwrap();
    assert!(ex.reply.is_none());
    assert_eq!(ex.raw, reply[..5]);
    assert!(
        ex.listened >= Duration::from_millis(700),
        "{:?}",
        ex.listened
    );
}

#[test]
fn an_echo_is_stripped_and_the_reply_awaited() {
    // A 06H request: its echo and its reply are the same bytes.
    let req = {
        let mut r = vec![0x01, 0x06, 0x25, 0x02, 0x04, 0xD2];
        let c = crate::codec::crc::crc16(&r);
        r.extend_from_slice(&c.to_le_bytes());
        r
    };
    let exception = {
        let mut r = vec![0x01, 0x86, 0x04];
        let c = crate::codec::crc::crc16(&r);
        r.extend_from_slice(&c.to_le_bytes());
        r
    };
    // Echo learnt (on), the reply an exception 100 ms after the echo: the exception
    // is the reply, not the echo.
    let (a, b) = memory::pair();
    let h = peer(b, vec![(1, req.clone()), (100, exception.clone())]);
    let mut m = Master::new(Box::new(a), Mode::Rtu, timing()).with_echo(EchoMode::On);
    let ex = m.exchange(&req, true).unwrap();
    h.join().unwrap();
    assert!(ex.echo);
    assert_eq!(ex.reply.as_deref(), Some(&exception[..]));
    // Echo unknown (auto, nothing learnt): a lone copy is not taken while the window
    // is open; the exception that follows is the reply, and the echo is learnt.
    let (a, b) = memory::pair();
    let h = peer(b, vec![(1, req.clone()), (100, exception.clone())]);
    let mut m = Master::new(Box::new(a), Mode::Rtu, timing());
    let ex = m.exchange(&req, true).unwrap();
    h.join().unwrap();
    assert_eq!(ex.reply.as_deref(), Some(&exception[..]));
    assert_eq!(m.echoes(), Some(true));
    // No echo (off): the copy is the reply.
    let (a, b) = memory::pair();
    let h = peer(b, vec![(1, req.clone())]);
    let mut m = Master::new(Box::new(a), Mode::Rtu, timing()).with_echo(EchoMode::Off);
    let ex = m.exchange(&req, true).unwrap();
    h.join().unwrap();
    assert!(!ex.echo);
    assert_eq!(ex.reply.as_deref(), Some(&req[..]));
}

#[test]
fn the_reply_is_found_after_echo_and_garbage() {
    use crate::codec::pdu::{Message, Pdu, Registers};
    let req = Message {
        address: 1,
        pdu: Pdu::ReadRequest {
            start: 0x2520,
            count: 1,
        },
    }
    .to_rtu_vec()
    .unwrap();
    let reply = Message {
        address: 1,
        pdu: Pdu::ReadResponse {
            values: Registers::new(&[0x00, 0x04]).unwrap(),
        },
    }
    .to_rtu_vec()
    .unwrap();
    let mut rx = vec![0xFF, 0x00, 0xA5];
    rx.extend_from_slice(&reply);
    let (lead, r, trail) = find_reply(Mode::Rtu, &req, &rx);
    assert_eq!(lead, [0xFF, 0x00, 0xA5]);
    assert_eq!(r.unwrap(), reply);
    assert!(trail.is_empty());
    // A truncated reply is no reply; its bytes are kept.
    let (lead, r, _) = find_reply(Mode::Rtu, &req, &reply[..5]);
    assert!(r.is_none());
    assert_eq!(lead, reply[..5]);
    // ASCII: the first valid frame.
    let rx = b"#@!:010302000AF0\r\n";
    let (lead, r, _) = find_reply(Mode::Ascii, b":010325200001B6\r\n", rx);
    assert_eq!(lead, b"#@!");
    assert_eq!(r.unwrap(), b":010302000AF0\r\n");
}

/// A link on which this host stalls while pacing the first `broken` sends: those never
/// reach the other end whole (here: not at all, as a receiver that frames by silence drops
/// them), and the link says so ([`Transport::send_was_broken`]).
struct Stalling {
    inner: memory::MemoryEnd,
    broken: u32,
    sends: u32,
    last_broken: bool,
}

impl Stalling {
    /// `inner` with its first `broken` sends stalled.
    fn new(inner: memory::MemoryEnd, broken: u32) -> Self {
        Stalling {
            inner,
            broken,
            sends: 0,
            last_broken: false,
        }
    }
}

impl Transport for Stalling {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.sends += 1;
        self.last_broken = self.sends <= self.broken;
        if self.last_broken {
            return Ok(());
        }
        self.inner.send(bytes)
    }
    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        self.inner.recv(buf, timeout)
    }
    fn discard_input(&mut self) -> Result<(), TransportError> {
        self.inner.discard_input()
    }
    fn describe(&self) -> String {
        "a stalling link".into()
    }
    fn kind(&self) -> crate::transport::LinkKind {
        crate::transport::LinkKind::Memory
    }
    fn send_was_broken(&self) -> bool {
        self.last_broken
    }
    fn line_timing(&self) -> Option<crate::codec::timing::LineSettings> {
        None
    }
}

const READ_2520: [u8; 8] = [0x01, 0x03, 0x25, 0x20, 0x00, 0x01, 0x8E, 0xCC];
const REPLY_2520: [u8; 7] = [0x01, 0x03, 0x02, 0x00, 0x04, 0xB9, 0x87];

#[test]
fn a_request_the_host_broke_every_time_is_an_error_never_a_silence() {
    // Issue 24: the last of the broken sends was listened to for a silence window only
    // and handed back as an exchange without a reply, which the runner judged as the
    // device's ("no reply within 50 ms", a DEVIATION).
    let (a, b) = memory::pair();
    let h = peer(b, vec![(1, REPLY_2520.to_vec())]);
    let link = Stalling::new(a, u32::MAX);
    let mut timing = timing();
    timing.retries = 2;
    let mut m = Master::new(Box::new(link), Mode::Rtu, timing);
    let e = m.exchange(&READ_2520, true).unwrap_err();
    h.join().unwrap();
    match &e {
        TransportError::Stalled { sends, request, .. } => {
            assert_eq!(*sends, MAX_BROKEN_SENDS);
            assert_eq!(request, "01 03 25 20 00 01 8E CC");
        }
        other => panic!("not a stall: {other}"),
    }
    assert!(
        e.to_string().contains(
            "could not send the request 01 03 25 20 00 01 8E CC whole: the host stalled 8 times"
        ),
        "{e}"
    );
    // Every send was one of the broken ones: no resend "after a timeout" in between.
    assert_eq!(m.transport().sends, MAX_BROKEN_SENDS);
    // And the runner's error for it is not the one that ends a run.
    assert!(matches!(
        super::super::RunError::from(e),
        super::super::RunError::HostStalled(_)
    ));
}

#[test]
fn a_request_the_host_broke_is_sent_again_until_it_goes_out_whole() {
    let (a, b) = memory::pair();
    let h = peer(b, vec![(1, REPLY_2520.to_vec())]);
    let link = Stalling::new(a, MAX_BROKEN_SENDS - 1);
    let mut m = Master::new(Box::new(link), Mode::Rtu, timing());
    let ex = m.exchange(&READ_2520, true).unwrap();
    h.join().unwrap();
    assert_eq!(ex.reply.as_deref(), Some(&REPLY_2520[..]));
    assert_eq!(ex.retries, 0, "a broken send is not a resend after silence");
    assert_eq!(m.broken_requests(), u64::from(MAX_BROKEN_SENDS - 1));
    assert_eq!(m.transport().sends, MAX_BROKEN_SENDS);
}
