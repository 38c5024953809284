//! Replays, under plain `cargo test` on stable, every input the fuzzers ever crashed on
//! (`fuzz/regressions/<target>/`) and the seed corpus made from the golden vectors,
//! through the same oracles the fuzz targets run. The deframer targets read how to feed
//! the stream (direction, chunking, bursts, silences) from the first byte; here each input
//! is replayed under every feeding, so every law is checked on every stored input.

use std::path::Path;

use conformance::oracle::{Oracle, TARGETS};

/// Runs `oracle` on `data`, and for a deframer target on `data` under each of the 32
/// feedings its control byte can choose (the seed bits keep the input's own).
fn replay(name: &str, oracle: Oracle, data: &[u8]) {
    oracle(data);
    if matches!(name, "rtu_deframer" | "ascii_deframer") && !data.is_empty() {
        let mut v = data.to_vec();
        for feeding in 0..32u8 {
            v[0] = data[0] & 0xE0 | feeding;
            oracle(&v);
        }
    }
}
use conformance::vectors::VectorSet;

#[test]
fn fuzz_regressions_replay() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/regressions");
    let mut replayed = 0;
    for (name, oracle) in TARGETS {
        let dir = root.join(name);
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for entry in entries {
            let path = entry.unwrap().path();
            if path
                .file_name()
                .is_some_and(|n| n.to_string_lossy().starts_with('.'))
            {
                continue;
            }
            let data = std::fs::read(&path).unwrap();
            let result = std::panic::catch_unwind(|| replay(name, oracle, &data));
            assert!(
                result.is_ok(),
                "{name}: {} breaks a law again",
                path.display()
            );
            replayed += 1;
        }
    }
    // The directory holds at least the inputs committed with the fuzzing work.
    assert!(
        replayed > 0,
        "no regression inputs found under {}",
        root.display()
    );
}

/// The kept corpus (`fuzz/corpus-kept/<target>/`, what campaigns found, minimized) passes
/// every law on stable too, each input as its control byte feeds it.
#[test]
fn kept_corpus_passes_every_oracle() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("../fuzz/corpus-kept");
    let mut replayed = 0;
    for (name, oracle) in TARGETS {
        let Ok(entries) = std::fs::read_dir(root.join(name)) else {
            continue;
        };
        for entry in entries {
            let path = entry.unwrap().path();
            let data = std::fs::read(&path).unwrap();
            let result = std::panic::catch_unwind(|| oracle(&data));
            assert!(result.is_ok(), "{name}: {} breaks a law", path.display());
            replayed += 1;
        }
    }
    assert!(replayed > 0, "no kept corpus under {}", root.display());
}

#[test]
fn seed_corpus_passes_every_oracle() {
    let set = VectorSet::builtin().unwrap();
    let seeds = conformance::seeds::seeds(&set, &VectorSet::builtin_texts());
    assert!(seeds.len() > 300, "{} seeds", seeds.len());
    for seed in &seeds {
        let oracle = TARGETS.iter().find(|(n, _)| *n == seed.target).unwrap().1;
        replay(seed.target, oracle, &seed.bytes);
    }
    for (name, _) in TARGETS {
        if name != "roundtrip" {
            assert!(seeds.iter().any(|s| s.target == name), "no seed for {name}");
        }
    }
}
