//! Replays, under plain `cargo test` on stable, every input the fuzzers ever crashed on
//! (`fuzz/regressions/<target>/`) and the seed corpus made from the golden vectors,
//! through the same oracles the fuzz targets run.

use std::path::Path;

use conformance::oracle::TARGETS;
use conformance::vectors::{corpus, VectorSet};

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
            let result = std::panic::catch_unwind(|| oracle(&data));
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

#[test]
fn seed_corpus_passes_every_oracle() {
    let set = VectorSet::builtin().unwrap();
    let seeds = corpus::seeds(&set, &VectorSet::builtin_texts());
    assert!(seeds.len() > 300, "{} seeds", seeds.len());
    for seed in &seeds {
        let oracle = TARGETS.iter().find(|(n, _)| *n == seed.target).unwrap().1;
        oracle(&seed.bytes);
    }
    for (name, _) in TARGETS {
        if name != "roundtrip" {
            assert!(seeds.iter().any(|s| s.target == name), "no seed for {name}");
        }
    }
}
