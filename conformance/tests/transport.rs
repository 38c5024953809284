//! Transports on real operating-system links: a pseudo-terminal pair opened from the slave
//! side by the serial-port code (as the runner opens the simulator), and TCP on loopback.
//! Every byte value must cross unchanged (no CR/LF translation, no echo), a closed link
//! must be reported, and pacing must take the line's time.

use std::time::{Duration, Instant};

use conformance::codec::timing::{LineSettings, Parity};
use conformance::transport::serial::SerialTransport;
use conformance::transport::tcp::TcpTransport;
use conformance::transport::{LinkKind, Transport};

fn read_exact(t: &mut dyn Transport, n: usize) -> Vec<u8> {
    let mut out = Vec::new();
    let deadline = Instant::now() + Duration::from_secs(5);
    let mut buf = [0u8; 512];
    while out.len() < n && Instant::now() < deadline {
        let k = t.recv(&mut buf, Duration::from_millis(50)).unwrap();
        out.extend_from_slice(&buf[..k]);
    }
    out
}

const LINE: LineSettings = LineSettings::new(9600, 8, Parity::Even, 1);

#[cfg(unix)]
#[test]
fn every_byte_crosses_a_pty_unchanged_both_ways() {
    use conformance::transport::pty::PtyMaster;
    let mut master = PtyMaster::open(None).unwrap();
    let path = master.slave_path().to_str().unwrap().to_string();
    let mut slave = SerialTransport::open(&path, LINE, LinkKind::Pty).unwrap();
    let all: Vec<u8> = (0..=255u8).collect();
    slave.send(&all).unwrap();
    assert_eq!(read_exact(&mut master, 256), all);
    master.send(&all).unwrap();
    assert_eq!(read_exact(&mut slave, 256), all);
    // Nothing more: no echo of what was sent.
    let mut buf = [0u8; 16];
    assert_eq!(master.recv(&mut buf, Duration::from_millis(50)).unwrap(), 0);
    assert_eq!(slave.recv(&mut buf, Duration::from_millis(50)).unwrap(), 0);
    assert_eq!(slave.line_timing(), None, "a pty slave has no line timing");
}

#[cfg(unix)]
#[test]
fn pacing_takes_the_line_time() {
    use conformance::transport::pty::PtyMaster;
    let mut master = PtyMaster::open(Some(LINE)).unwrap();
    let path = master.slave_path().to_str().unwrap().to_string();
    let mut slave = SerialTransport::open(&path, LINE, LinkKind::Pty).unwrap();
    let frame = [0x55u8; 20];
    let t0 = Instant::now();
    master.send(&frame).unwrap();
    let took = t0.elapsed();
    // 20 characters of 11 bits at 9600 baud: 22.9 ms.
    assert!(
        took >= Duration::from_micros(20 * LINE.char_time_us()),
        "{took:?}"
    );
    assert_eq!(read_exact(&mut slave, 20), frame);
    assert_eq!(master.line_timing(), Some(LINE));
}

#[test]
fn tcp_carries_bytes_and_reports_a_closed_peer() {
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let addr = listener.local_addr().unwrap().to_string();
    let server = std::thread::spawn(move || {
        let mut t = TcpTransport::accept(&listener).unwrap();
        let got = read_exact(&mut t, 3);
        t.send(&got).unwrap();
    });
    let mut client = TcpTransport::connect(&addr, Duration::from_secs(2)).unwrap();
    client.send(&[0x3A, 0x0D, 0x0A]).unwrap();
    assert_eq!(read_exact(&mut client, 3), [0x3A, 0x0D, 0x0A]);
    server.join().unwrap();
    let mut buf = [0u8; 4];
    let mut closed = false;
    for _ in 0..20 {
        match client.recv(&mut buf, Duration::from_millis(50)) {
            Ok(_) => continue,
            Err(e) => {
                assert!(e.to_string().contains("closed"), "{e}");
                closed = true;
                break;
            }
        }
    }
    assert!(
        closed,
        "a closed peer must be reported, not read as silence"
    );
}

#[test]
fn opening_a_missing_port_says_which() {
    let err = SerialTransport::open("/dev/does-not-exist-0", LINE, LinkKind::Serial)
        .err()
        .unwrap();
    assert!(err.to_string().contains("/dev/does-not-exist-0"), "{err}");
}
