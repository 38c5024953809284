//! What the runner's tests share (tests/runner.rs, tests/runner_busy_host.rs,
//! tests/verdicts.rs): the runner's options and a session against the simulator, run in
//! this process, and the report's deviations.
#![allow(dead_code)]

use std::sync::atomic::AtomicBool;
use std::sync::Arc;
use std::time::Duration;

use conformance::codec::timing::{LineSettings, Parity};
use conformance::codec::Mode;
use conformance::model::DriveModel;
use conformance::report::Report;
use conformance::runner::{MasterTiming, Options, Status};
use conformance::session::{self, SessionConfig, Target};
use conformance::sim::Quirk;

/// The runner's options for a check of node 1 limited to `only` (none: every check).
pub fn options(only: &[&str]) -> Options {
    Options {
        address: 1,
        other_address: 0x7F,
        bus: vec![1],
        read_only: false,
        allow_motion: false,
        only: only.iter().map(|s| s.to_string()).collect(),
        timing: MasterTiming {
            timeout: Duration::from_millis(500),
            silence: Duration::from_millis(250),
            derive_silence: false,
            quiet: Duration::from_millis(30),
            gap: Duration::from_millis(5),
            retries: 0,
        },
        // Generous: the tests run many sessions at once on a small machine. The
        // late-reply quirk (200 ms) is still far over it.
        response_allowance: Duration::from_millis(100),
        // The host's scheduler puts gaps of several ms into a paced pseudo-terminal when
        // the machine is busy (the tests run in parallel).
        gap_allowance: Duration::from_millis(20),
        seed: 1,
        echo: conformance::runner::EchoMode::Auto,
        allow_restart: false,
        injected_stalls: None,
        line: None,
    }
}

/// A session against the simulated `model` with `quirks` in `modes`.
pub fn config(
    model: &str,
    modes: &[Mode],
    quirks: &[Quirk],
    pace: bool,
    opts: Options,
) -> SessionConfig {
    SessionConfig {
        model: Arc::new(DriveModel::builtin(model).unwrap()),
        target: Target::Sim {
            quirks: quirks.iter().map(|&q| q.into()).collect(),
            pace,
            delay: None,
            log: None,
        },
        modes: modes.to_vec(),
        line: LineSettings::new(9600, 8, Parity::Even, 1),
        options: opts,
        capture: None,
    }
}

/// Runs the session to its end: its report.
pub fn run(c: &SessionConfig) -> Report {
    let stop = AtomicBool::new(false);
    session::run(c, &stop, &mut |_, _| {}, &mut |_| {}).unwrap()
}

/// The report's deviations, as "id: summary".
pub fn deviations(r: &Report) -> Vec<String> {
    r.results
        .iter()
        .filter(|c| c.status == Status::Deviation)
        .map(|c| format!("{}: {}", c.id, c.summary))
        .collect()
}

/// The report schema, compiled.
pub fn schema() -> jsonschema::Validator {
    let text = include_str!("../../../vectors/schema/report.schema.json");
    jsonschema::validator_for(&serde_json::from_str(text).unwrap()).unwrap()
}

/// Asserts that a report matches the report schema, listing where it does not.
pub fn assert_valid(r: &Report) {
    super::common::schema_valid(&r.to_json());
}
