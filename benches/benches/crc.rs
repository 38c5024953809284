//! CRC-16/MODBUS: the manuals' bitwise reference against the codec's table-driven CRC.

use conformance::codec::crc::{crc16, crc16_reference};
use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

fn crc(c: &mut Criterion) {
    let mut group = c.benchmark_group("crc16");
    for size in [8usize, 80, 256, 64 * 1024] {
        let data: Vec<u8> = (0..size).map(|i| (i * 31 + 7) as u8).collect();
        group.throughput(Throughput::Bytes(size as u64));
        group.bench_with_input(BenchmarkId::new("reference", size), &data, |b, d| {
            b.iter(|| crc16_reference(black_box(d)))
        });
        group.bench_with_input(BenchmarkId::new("table8", size), &data, |b, d| {
            b.iter(|| crc16(black_box(d)))
        });
    }
    group.finish();
}

criterion_group!(benches, crc);
criterion_main!(benches);
