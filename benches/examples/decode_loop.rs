//! A profiling aid, not a benchmark: checked decode of the F510 03H request and response
//! (RTU and ASCII) and modbus-core's RTU decode of the same frames, each in a loop, with
//! the best of several rounds printed. Run under `valgrind --tool=callgrind` to see where
//! the instructions go:
//!
//! ```sh
//! cargo build --release -p conformance-benches --example decode_loop
//! valgrind --tool=callgrind target/release/examples/decode_loop 200000
//! ```
use std::hint::black_box;
use std::time::Instant;

use conformance::codec::{decode_ascii, decode_rtu, Direction, MAX_RTU_FRAME};

fn best_ns(n: usize, mut f: impl FnMut() -> usize) -> f64 {
    (0..7)
        .map(|_| {
            let t = Instant::now();
            let mut acc = 0;
            for _ in 0..n {
                acc += f();
            }
            black_box(acc);
            t.elapsed().as_nanos() as f64 / n as f64
        })
        .fold(f64::INFINITY, f64::min)
}

fn main() {
    let n: usize = std::env::args()
        .nth(1)
        .and_then(|s| s.parse().ok())
        .unwrap_or(1_000_000);
    let request = [0x01u8, 0x03, 0x01, 0x23, 0x00, 0x01, 0x74, 0x3C];
    let response = [0x01u8, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50];
    let request_ascii = b":010301230001D7\r\n";
    let response_ascii = b":010302177073\r\n";
    let rtu =
        |f: &'static [u8], d| move || usize::from(decode_rtu(black_box(f), d).unwrap().address);
    let ascii = |f: &'static [u8], d| {
        move || {
            let mut s = [0u8; MAX_RTU_FRAME];
            usize::from(decode_ascii(black_box(f), d, &mut s).unwrap().address)
        }
    };
    let request: &'static [u8] = Box::leak(Box::new(request));
    let response: &'static [u8] = Box::leak(Box::new(response));
    let mut scratch = [0u8; MAX_RTU_FRAME];
    let reused = best_ns(n, || {
        usize::from(
            decode_ascii(black_box(request_ascii), Direction::Request, &mut scratch)
                .unwrap()
                .address,
        )
    });
    let rows: [(&str, f64); 7] = [
        ("request ascii reused", reused),
        ("request rtu", best_ns(n, rtu(request, Direction::Request))),
        (
            "request ascii",
            best_ns(n, ascii(request_ascii, Direction::Request)),
        ),
        (
            "request modbus-core",
            best_ns(n, || {
                usize::from(
                    modbus_core::rtu::server::decode_request(black_box(request))
                        .unwrap()
                        .unwrap()
                        .hdr
                        .slave,
                )
            }),
        ),
        (
            "response rtu",
            best_ns(n, rtu(response, Direction::Response)),
        ),
        (
            "response ascii",
            best_ns(n, ascii(response_ascii, Direction::Response)),
        ),
        (
            "response modbus-core",
            best_ns(n, || {
                usize::from(
                    modbus_core::rtu::client::decode_response(black_box(response))
                        .unwrap()
                        .unwrap()
                        .hdr
                        .slave,
                )
            }),
        ),
    ];
    for (name, ns) in rows {
        println!("{name:22} {ns:6.2} ns");
    }
}
