//! What the gate's tests share (tests/gate.rs, tests/master_gate.rs,
//! tests/master_adapters.rs): `conformance gate` run for its JSON report, and that report
//! read.

use serde_json::Value;

use super::{Ran, Run};

/// Runs `conformance gate ROLE ADAPTER --format json --quiet EXTRA` (`ROLE` is `--codec` or
/// `--master`) and returns its output and its report, which it must print.
///
/// A master gate that could not judge a case because the host did not schedule its drive
/// ([`unscheduled`]) is run again, as it says to ([`again_while_unscheduled`]).
pub fn gate_json(role: &str, adapter: &str, extra: &[&str]) -> (Ran, Value) {
    let mut args = vec!["gate", role, adapter, "--format", "json", "--quiet"];
    args.extend_from_slice(extra);
    again_while_unscheduled(|| {
        let o = Run::new(&args).run();
        let v: Value = serde_json::from_slice(&o.bytes).unwrap_or_else(|e| {
            panic!(
                "gate {role} printed no JSON ({e}): {}\n{}",
                o.stdout.as_str(),
                o.stderr
            )
        });
        (o, v)
    })
}

/// Runs of a gate made, at most, while cases come back unjudged for an overloaded host.
pub const GATE_TRIES: u32 = 3;

/// The cases of a master gate's report (`v`) left unjudged because the gate's own drive
/// was not scheduled during them, three times (an overloaded host; the gate says to run
/// it again): "id: why".
pub fn unscheduled(v: &Value) -> Vec<String> {
    v["checks"]
        .as_array()
        .into_iter()
        .flatten()
        .filter(|c| {
            c["status"] == "error"
                && c["summary"]
                    .as_str()
                    .is_some_and(|s| s.starts_with(conformance::gate::master::UNSCHEDULED))
        })
        .map(|c| format!("{}: {}", c["id"], c["summary"]))
        .collect()
}

/// `run` (a gate run, its report last) again while its report has [`unscheduled`] cases,
/// at most [`GATE_TRIES`] runs; each run made again is noted with why. The last run is
/// returned whatever it says: a gate that cannot judge three times fails the test.
pub fn again_while_unscheduled<T>(mut run: impl FnMut() -> (T, Value)) -> (T, Value) {
    let mut attempt = 1;
    loop {
        let (o, v) = run();
        let unjudged = unscheduled(&v);
        if unjudged.is_empty() || attempt == GATE_TRIES {
            return (o, v);
        }
        super::note(&format!(
            "gate run {attempt}: {} case(s) not judged, the host did not schedule the gate's drive ({}); running it again",
            unjudged.len(),
            unjudged[0]
        ));
        attempt += 1;
    }
}

#[allow(unused_imports)] // tests/gate.rs reads it from here
pub use super::schema_valid;

/// The status of case `id` in a report (it must have the case).
pub fn status_of<'a>(v: &'a Value, id: &str) -> &'a str {
    v["checks"]
        .as_array()
        .unwrap()
        .iter()
        .find(|c| c["id"] == id)
        .unwrap_or_else(|| panic!("no case {id}"))["status"]
        .as_str()
        .unwrap()
}

/// Asserts that each of the cases `ids` has `status` in the report, naming the first that
/// does not.
#[track_caller]
pub fn assert_statuses(v: &Value, status: &str, ids: &[&str]) {
    for id in ids {
        assert_eq!(status_of(v, id), status, "{id}");
    }
}
