//! Criterion benchmarks of the codec live in `benches/benches/`; this crate has no code of
//! its own. Run them with `cargo bench -p conformance-benches`.
