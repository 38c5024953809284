//! A profiling aid, not a benchmark: checked decode of the F510 03H request and response
//! (RTU and ASCII) and modbus-core's RTU decode of the same frames, each in a loop, with
//! the best of several rounds printed. Criterion (`benches/frames.rs`, group `peers`) gives
//! the figures; this gives the instructions. Run one case under
//! `valgrind --tool=callgrind` to count where its instructions go:
//!
//! ```sh
//! cargo build --release -p conformance-benches --example decode_loop
//! target/release/examples/decode_loop 1000000                 # every case, best of 7
//! valgrind --tool=callgrind target/release/examples/decode_loop 200000 "request rtu"
//! ```
use std::hint::black_box;
use std::time::Instant;

use conformance::codec::{decode_ascii, decode_rtu, Direction, Pdu, MAX_RTU_FRAME};

const REQUEST: [u8; 8] = [0x01, 0x03, 0x01, 0x23, 0x00, 0x01, 0x74, 0x3C];
const RESPONSE: [u8; 7] = [0x01, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50];
const REQUEST_ASCII: &[u8] = b":010301230001D7\r\n";
const RESPONSE_ASCII: &[u8] = b":010302177073\r\n";

/// What each case keeps of the decoded message: the fields the criterion bench keeps (the
/// start and count of the request, the first value of the response), so that no part of
/// the decode is dead code.
fn kept(p: &Pdu<'_>) -> usize {
    match p {
        Pdu::ReadRequest { start, count } => usize::from(start ^ count),
        Pdu::ReadResponse { values } => usize::from(values.get(0).unwrap_or(0)),
        _ => unreachable!(),
    }
}

/// A named decode, run in a loop.
type Case = (&'static str, Box<dyn FnMut() -> usize>);

fn cases() -> Vec<Case> {
    let mut scratch = [0u8; MAX_RTU_FRAME];
    let mut scratch2 = [0u8; MAX_RTU_FRAME];
    vec![
        (
            "request rtu",
            Box::new(|| {
                kept(
                    &decode_rtu(black_box(&REQUEST[..]), Direction::Request)
                        .unwrap()
                        .pdu,
                )
            }),
        ),
        (
            "request ascii",
            Box::new(move || {
                kept(
                    &decode_ascii(black_box(REQUEST_ASCII), Direction::Request, &mut scratch)
                        .unwrap()
                        .pdu,
                )
            }),
        ),
        (
            "request modbus-core",
            Box::new(|| {
                let r = modbus_core::rtu::server::decode_request(black_box(&REQUEST[..]))
                    .unwrap()
                    .unwrap();
                match r.pdu.0 {
                    modbus_core::Request::ReadHoldingRegisters(a, q) => usize::from(a ^ q),
                    _ => unreachable!(),
                }
            }),
        ),
        (
            "response rtu",
            Box::new(|| {
                kept(
                    &decode_rtu(black_box(&RESPONSE[..]), Direction::Response)
                        .unwrap()
                        .pdu,
                )
            }),
        ),
        (
            "response ascii",
            Box::new(move || {
                kept(
                    &decode_ascii(
                        black_box(RESPONSE_ASCII),
                        Direction::Response,
                        &mut scratch2,
                    )
                    .unwrap()
                    .pdu,
                )
            }),
        ),
        (
            "response modbus-core",
            Box::new(|| {
                modbus_core::rtu::client::decode_response(black_box(&RESPONSE[..]))
                    .unwrap()
                    .unwrap()
                    .hdr
                    .slave
                    .into()
            }),
        ),
    ]
}

fn main() {
    let mut args = std::env::args().skip(1);
    let n: usize = args
        .next()
        .and_then(|s| s.parse().ok())
        .unwrap_or(1_000_000);
    let only = args.next();
    for (name, mut f) in cases() {
        if only.as_deref().is_some_and(|o| o != name) {
            continue;
        }
        if only.is_some() {
            // One pass, for callgrind: instructions per decode = total / n.
            let mut acc = 0;
            for _ in 0..n {
                acc += f();
            }
            black_box(acc);
            continue;
        }
        let best = (0..7)
            .map(|_| {
                let t = Instant::now();
                let mut acc = 0;
                for _ in 0..n {
                    acc += f();
                }
                black_box(acc);
                t.elapsed().as_nanos() as f64 / n as f64
            })
            .fold(f64::INFINITY, f64::min);
        println!("{name:22} {best:6.2} ns");
    }
}
