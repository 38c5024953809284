//! Streaming deframers over a long recorded stream of back-to-back frames with some
//! garbage, fed in chunks of 1 byte, 32 bytes and 4 KiB.

use conformance::codec::{
    AsciiDeframer, Direction, Event, Message, Pdu, Registers, RtuDeframer, RtuFraming,
};
use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

/// About 1 MiB of responses of every modelled kind, with a few garbage bytes every 16 frames.
fn stream(ascii: bool) -> (Vec<u8>, u64) {
    let regs = [0x17u8, 0x70, 0, 1, 0, 2, 0, 3, 0, 4, 0, 5, 0, 6, 0, 7];
    let msgs = [
        Pdu::ReadResponse {
            values: Registers::new(&regs).unwrap(),
        },
        Pdu::WriteSingle {
            register: 0x2502,
            value: 0x1770,
        },
        Pdu::LoopBack {
            test_code: 0,
            data: &[0xA5, 0x37],
        },
        Pdu::WriteMultipleResponse {
            start: 0x2502,
            count: 2,
        },
        Pdu::Exception {
            function: 3,
            code: 2,
        },
    ];
    let mut out = Vec::new();
    let mut frames = 0;
    let mut i = 0usize;
    while out.len() < 1 << 20 {
        let m = Message {
            address: (i % 247 + 1) as u8,
            pdu: msgs[i % msgs.len()],
        };
        out.extend(
            if ascii {
                m.to_ascii_vec()
            } else {
                m.to_rtu_vec()
            }
            .unwrap(),
        );
        frames += 1;
        if i % 16 == 15 {
            out.extend_from_slice(&[0xFF, 0x00, 0x5A]);
        }
        i += 1;
    }
    (out, frames)
}

fn deframe(c: &mut Criterion) {
    for ascii in [false, true] {
        let (data, frames) = stream(ascii);
        // Every frame is found before anything is timed.
        let mut found = 0u64;
        if ascii {
            let mut d = AsciiDeframer::default();
            d.push(&data, |e| found += u64::from(matches!(e, Event::Frame(_))));
        } else {
            let mut d = RtuDeframer::new(Direction::Response, RtuFraming::ByLength);
            d.push(&data, |e| found += u64::from(matches!(e, Event::Frame(_))));
        }
        assert_eq!(found, frames);
        let name = if ascii {
            "deframe/ascii"
        } else {
            "deframe/rtu-by-length"
        };
        for (unit, throughput) in [
            ("bytes", Throughput::Bytes(data.len() as u64)),
            ("frames", Throughput::Elements(frames)),
        ] {
            let mut group = c.benchmark_group(format!("{name}/{unit}"));
            group.throughput(throughput);
            group.sample_size(20);
            for chunk in [1usize, 32, 4096] {
                group.bench_with_input(BenchmarkId::from_parameter(chunk), &data, |b, data| {
                    b.iter(|| {
                        let mut n = 0u64;
                        if ascii {
                            let mut d = AsciiDeframer::default();
                            for c in data.chunks(chunk) {
                                d.push(black_box(c), |e| {
                                    n += u64::from(matches!(e, Event::Frame(_)))
                                });
                            }
                        } else {
                            let mut d = RtuDeframer::new(Direction::Response, RtuFraming::ByLength);
                            for c in data.chunks(chunk) {
                                d.push(black_box(c), |e| {
                                    n += u64::from(matches!(e, Event::Frame(_)))
                                });
                            }
                        }
                        n
                    })
                });
            }
            group.finish();
        }
    }
}

criterion_group!(benches, deframe);
criterion_main!(benches);
