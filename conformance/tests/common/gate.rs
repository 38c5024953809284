//! What the gate's tests share (tests/gate.rs, tests/master_gate.rs,
//! tests/master_adapters.rs): `conformance gate` run for its JSON report, and that report
//! read.

use serde_json::Value;

use super::{Ran, Run};

/// Runs `conformance gate ROLE ADAPTER --format json --quiet EXTRA` (`ROLE` is `--codec` or
/// `--master`) and returns its output and its report, which it must print.
pub fn gate_json(role: &str, adapter: &str, extra: &[&str]) -> (Ran, Value) {
    let mut args = vec!["gate", role, adapter, "--format", "json", "--quiet"];
    args.extend_from_slice(extra);
    let o = Run::new(&args).run();
    let v: Value = serde_json::from_slice(&o.bytes).unwrap_or_else(|e| {
        panic!(
            "gate {role} printed no JSON ({e}): {}\n{}",
            o.stdout.as_str(),
            o.stderr
        )
    });
    (o, v)
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
