//! CRC-16/MODBUS and LRC: the manuals' bitwise reference, our implementations, and the
//! peer crates `crc-fast` (SIMD), `crc` (Table<1>, Table<16>) and `crc16`, in the same run.
//!
//! `crc16/ours/SIZE:PATH` is the dispatcher (`crc16`), named with the path it took at that
//! size on this CPU, as the dispatcher itself reports it (`crc16_path`); `crc16/ours-PATH`
//! forces one path, at the sizes where that path's own kernel runs. `crc16-crossover/*`
//! times every path this CPU has, forced, at the sizes around the dispatcher's
//! thresholds: where they cross is where each tier's thresholds come from
//! (`benches/compare.py --crossover`). `CONFORMANCE_CRC_PATH=table|pclmul|avx2|avx512`
//! caps the dispatcher's tier, so one machine can measure the dispatcher of each tier up
//! to its own.

use conformance::codec::crc::{
    crc16, crc16_path, crc16_reference, crc16_tier, crc16_update_table, crc16_update_with, CrcPath,
};
use conformance::codec::crc_clmul::PATH_ENV;
use conformance::codec::lrc::lrc;
use criterion::{black_box, criterion_group, criterion_main, BenchmarkId, Criterion, Throughput};

const SIZES: [usize; 6] = [8, 80, 256, 1024, 4096, 64 * 1024];

/// Sizes around the dispatcher's thresholds, some of them not multiples of any register
/// (the end of a fold costs more for them).
const CROSSOVER_SIZES: [usize; 19] = [
    16, 24, 32, 40, 48, 56, 64, 72, 80, 96, 112, 128, 160, 192, 224, 256, 320, 384, 512,
];

fn data(size: usize) -> Vec<u8> {
    (0..size).map(|i| (i.wrapping_mul(31) + 7) as u8).collect()
}

/// CRC-16/MODBUS by `crc-fast`, whose one-shot API returns every width as `u64`.
fn crc_fast_modbus(d: &[u8]) -> u16 {
    crc_fast::checksum(crc_fast::CrcAlgorithm::Crc16Modbus, d) as u16
}

/// Says which tier the dispatcher runs (so a run's output names it) and refuses a
/// `CONFORMANCE_CRC_PATH` that names no path, which the library would ignore.
fn announce_tier() {
    let tier = crc16_tier();
    let paths: Vec<&str> = CrcPath::supported().map(CrcPath::name).collect();
    match std::env::var(PATH_ENV) {
        Ok(v) => {
            assert!(
                CrcPath::from_name(&v).is_some(),
                "{PATH_ENV}={v:?} names no CRC path (table, pclmul, avx2, avx512)"
            );
            println!(
                "crc16 dispatcher: tier {} ({PATH_ENV}={v}; this CPU runs {})",
                tier.name(),
                paths.join(" ")
            );
        }
        Err(_) => println!(
            "crc16 dispatcher: tier {} (this CPU runs {})",
            tier.name(),
            paths.join(" ")
        ),
    }
}

fn crc(c: &mut Criterion) {
    announce_tier();
    let table1 = crc::Crc::<u16, crc::Table<1>>::new(&crc::CRC_16_MODBUS);
    let table16 = crc::Crc::<u16, crc::Table<16>>::new(&crc::CRC_16_MODBUS);
    let mut group = c.benchmark_group("crc16");
    for size in SIZES {
        let d = data(size);
        // Every implementation must agree before it is timed.
        let want = crc16_reference(&d);
        assert_eq!(crc16(&d), want);
        assert_eq!(crc16_update_table(0xFFFF, &d), want);
        assert_eq!(table1.checksum(&d), want);
        assert_eq!(table16.checksum(&d), want);
        assert_eq!(crc16::State::<crc16::MODBUS>::calculate(&d), want);
        assert_eq!(crc_fast_modbus(&d), want);
        for path in CrcPath::supported() {
            assert_eq!(crc16_update_with(path, 0xFFFF, &d), Some(want));
        }

        group.throughput(Throughput::Bytes(size as u64));
        group.bench_with_input(BenchmarkId::new("manual-bitwise", size), &d, |b, d| {
            b.iter(|| crc16_reference(black_box(d)))
        });
        // Named with the path the dispatcher takes at this size, asked of it.
        let ran = crc16_path(size).name();
        group.bench_with_input(
            BenchmarkId::new("ours", format!("{size}:{ran}")),
            &d,
            |b, d| b.iter(|| crc16(black_box(d))),
        );
        group.bench_with_input(BenchmarkId::new("ours-table", size), &d, |b, d| {
            b.iter(|| crc16_update_table(0xFFFF, black_box(d)))
        });
        // Each SIMD path forced, where this CPU has it ("ours" picks one by length), and
        // only where its own kernel runs (below, it hands the input to a narrower one).
        for path in CrcPath::supported().filter(|p| *p != CrcPath::Table && size >= p.min_len()) {
            let id = BenchmarkId::new(format!("ours-{}", path.name()), size);
            group.bench_with_input(id, &d, |b, d| {
                b.iter(|| crc16_update_with(path, 0xFFFF, black_box(d)))
            });
        }
        group.bench_with_input(BenchmarkId::new("crc-fast", size), &d, |b, d| {
            b.iter(|| crc_fast_modbus(black_box(d)))
        });
        group.bench_with_input(BenchmarkId::new("crc-table1", size), &d, |b, d| {
            b.iter(|| table1.checksum(black_box(d)))
        });
        group.bench_with_input(BenchmarkId::new("crc-table16", size), &d, |b, d| {
            b.iter(|| table16.checksum(black_box(d)))
        });
        group.bench_with_input(BenchmarkId::new("crc16-crate", size), &d, |b, d| {
            b.iter(|| crc16::State::<crc16::MODBUS>::calculate(black_box(d)))
        });
    }
    group.finish();

    let mut group = c.benchmark_group("crc16-crossover");
    for size in CROSSOVER_SIZES {
        let d = data(size);
        let want = crc16_reference(&d);
        group.throughput(Throughput::Bytes(size as u64));
        for path in CrcPath::supported().filter(|p| size >= p.min_len()) {
            assert_eq!(crc16_update_with(path, 0xFFFF, &d), Some(want));
            group.bench_with_input(BenchmarkId::new(path.name(), size), &d, |b, d| {
                b.iter(|| crc16_update_with(path, 0xFFFF, black_box(d)))
            });
        }
    }
    group.finish();

    let mut group = c.benchmark_group("lrc");
    for size in SIZES {
        let d = data(size);
        group.throughput(Throughput::Bytes(size as u64));
        group.bench_with_input(BenchmarkId::new("ours", size), &d, |b, d| {
            b.iter(|| lrc(black_box(d)))
        });
    }
    group.finish();
}

criterion_group!(benches, crc);
criterion_main!(benches);
