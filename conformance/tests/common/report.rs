//! A report read back: `conformance check` or `fuzz` run for its JSON report, the report
//! parsed and held to the report schema, and the parts of it that many tests read.

use std::path::Path;
use std::time::Duration;

use serde_json::Value;

use super::Run;

/// Runs `conformance check ARGS --format json -o dir/check.json` with a bound on its
/// time (a hang is a failure, not a stalled CI job), asserts it did not panic and that
/// the report matches its schema; returns the exit code and the report.
pub fn check_device(dir: &Path, args: &[&str], limit: Duration) -> (Option<i32>, Value) {
    report_of("check", dir, args, limit)
}

/// Runs `conformance COMMAND ARGS --format json -o DIR/COMMAND.json` (check or fuzz),
/// bounded by `limit`, and returns its exit code and the report, checked against the
/// report schema.
pub fn report_of(
    command: &str,
    dir: &Path,
    args: &[&str],
    limit: Duration,
) -> (Option<i32>, Value) {
    let report = dir.join(format!("{command}.json"));
    let ran = Run::new([command])
        .args(args)
        .args(["--format", "json", "--quiet", "-o"])
        .arg(&report)
        .timeout(limit)
        .run();
    let v = report_file(&report).unwrap_or_else(|e| panic!("{e}: {ran}"));
    (ran.code, v)
}

/// The JSON report at `path`, held to the report schema; Err says why it is not one.
pub fn report_file(path: &Path) -> Result<Value, String> {
    let text = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let v: Value = serde_json::from_slice(&text).map_err(|e| format!("{}: {e}", path.display()))?;
    schema_valid(&v);
    Ok(v)
}

/// The JSON file at `path` as it is, not held to any schema (an identify or scan result);
/// a file that is missing or not JSON fails the test, naming it.
#[track_caller]
pub fn json_file(path: &Path) -> Value {
    let text = std::fs::read(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    serde_json::from_slice(&text).unwrap_or_else(|e| panic!("{}: not JSON ({e})", path.display()))
}

/// The records of the JSON-lines file at `path` (a log); a file that is missing or a line
/// that is not JSON fails the test, naming it.
#[track_caller]
pub fn json_lines_file(path: &Path) -> Vec<Value> {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
    text.lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{}: {e}: {l}", path.display())))
        .collect()
}

/// Asserts that a report matches the report schema, listing where it does not.
pub fn schema_valid(v: &Value) {
    let text = include_str!("../../../vectors/schema/report.schema.json");
    let s = jsonschema::validator_for(&serde_json::from_str(text).unwrap()).unwrap();
    let errors: Vec<String> = s
        .iter_errors(v)
        .map(|e| format!("{e} at {}", e.instance_path))
        .collect();
    assert!(
        errors.is_empty(),
        "the report does not match its schema: {errors:#?}"
    );
}

/// The findings of every mode of a fuzz report that are not unconfirmed: a finding that
/// was replayed and not seen again is an observation (a host stall under load can make
/// one), not one of the device's bugs.
pub fn confirmed_findings(v: &Value) -> Vec<Value> {
    findings(v)
        .into_iter()
        .filter(|f| f["reproduced"] == true || f["replays"].as_u64().unwrap_or(0) == 0)
        .collect()
}

/// Whether a fuzz finding of `kind` whose signature ends in `field` is one that a generic
/// Modbus server (pymodbus's, libmodbus's) shows against a TECO model, as seen on the
/// wire: it serves registers past the model's map and refuses some the model serves
/// (the mismatches below), answers broadcasts and other nodes (`reply-to-*`), answers
/// nothing to what it does not take (`no-reply-for-*`) and reads a write back as written
/// (`value-of-*`); or one of the mismatches in `more` that the one server is known for.
pub fn generic_server_explains(kind: &str, field: &str, more: &[&str]) -> bool {
    const MISMATCHES: &[&str] = &[
        "register-value",
        "byte-count",
        "reply-instead-of-exception",
        "exception-instead-of-reply",
        "exception-code",
        "register-address",
        "register-count",
        "written-value",
    ];
    match kind {
        "mismatch" => MISMATCHES.contains(&field) || more.contains(&field),
        "unexpected-reply" => field.starts_with("reply-to-"),
        "no-reply" => field.starts_with("no-reply-for-"),
        "wrong-value" => field.starts_with("value-of-"),
        _ => false,
    }
}

/// The sum of the counts in a JSON object (a finding's `classes`, a document's
/// `coverage`); anything else fails the test.
#[track_caller]
pub fn total(counts: &Value) -> u64 {
    let all = counts
        .as_object()
        .unwrap_or_else(|| panic!("no object: {counts}"));
    all.values()
        .map(|n| {
            n.as_u64()
                .unwrap_or_else(|| panic!("no count: {n} in {counts}"))
        })
        .sum()
}

/// The findings of every mode of a fuzz report.
pub fn findings(v: &Value) -> Vec<Value> {
    v["fuzz"]["modes"]
        .as_array()
        .unwrap()
        .iter()
        .flat_map(|m| m["findings"].as_array().unwrap().clone())
        .collect()
}

/// `conformance report JSON -o OUT` (the format from OUT's extension), which must exit 0:
/// what it wrote.
pub fn rendered(json: &Path, out: &Path) -> String {
    Run::new(["report"]).arg(json).arg("-o").arg(out).run().ok();
    std::fs::read_to_string(out).unwrap()
}

/// [`report_of`] in a fresh [`Scratch`](super::Scratch) folder `name`, with the words
/// of `args` (split at white space) as the arguments: `report_in("fuzz", "hang",
/// "--sim f510 --mode rtu --cases 300", limit)`.
pub fn report_in(command: &str, name: &str, args: &str, limit: Duration) -> (Option<i32>, Value) {
    let args: Vec<&str> = args.split_whitespace().collect();
    report_of(command, &super::Scratch::new(name), &args, limit)
}

/// [`check_device`] in a fresh [`Scratch`](super::Scratch) folder `name`, with the words
/// of `args` as the arguments, for a test that reads what the run left there
/// (`check.json`) or writes beside it: the folder, the exit code and the report.
pub fn check_in(name: &str, args: &str, limit: Duration) -> (super::Scratch, Option<i32>, Value) {
    let dir = super::Scratch::new(name);
    let args: Vec<&str> = args.split_whitespace().collect();
    let (code, v) = check_device(&dir, &args, limit);
    (dir, code, v)
}

/// Node `address` of a monitor report (a report without it fails the test, showing the
/// monitor's part).
#[track_caller]
pub fn monitor_node<'a>(r: &'a Value, address: &str) -> &'a Value {
    r["monitor"]["nodes"]
        .as_array()
        .and_then(|all| all.iter().find(|n| n["address"] == address))
        .unwrap_or_else(|| panic!("no node {address} in {:#}", r["monitor"]))
}

/// The check `id` of a report (a report without it fails the test, naming the ids it
/// has).
#[track_caller]
pub fn check_of<'a>(v: &'a Value, id: &str) -> &'a Value {
    v["checks"]
        .as_array()
        .and_then(|all| all.iter().find(|c| c["id"] == id))
        .unwrap_or_else(|| {
            panic!(
                "no check {id} in the report: {:?}",
                strings(&v["checks"], "id")
            )
        })
}

/// The text field `key` of each item of the JSON array `items` (the ids of a report's
/// checks: `strings(&v["checks"], "id")`); an item without it fails the test.
#[track_caller]
pub fn strings<'a>(items: &'a Value, key: &str) -> Vec<&'a str> {
    items
        .as_array()
        .unwrap_or_else(|| panic!("not an array: {items}"))
        .iter()
        .map(|i| {
            i[key]
                .as_str()
                .unwrap_or_else(|| panic!("no text {key} in {i}"))
        })
        .collect()
}

/// The checks of a report whose status is one of `statuses`, each as `"STATUS" "ID":
/// "SUMMARY"` (the JSON values as they print): for a failure's message, or to be sorted.
pub fn with_status(v: &Value, statuses: &[&str]) -> Vec<String> {
    checks_where(v, |c| statuses.iter().any(|s| c["status"] == *s))
        .map(|c| format!("{} {}: {}", c["status"], c["id"], c["summary"]))
        .collect()
}

/// The ids of the checks of a report whose status is `status`, in the report's order.
pub fn ids_with_status(v: &Value, status: &str) -> Vec<String> {
    checks_where(v, |c| c["status"] == status)
        .map(|c| {
            let id = c["id"].as_str();
            id.unwrap_or_else(|| panic!("a check without an id: {c}"))
                .to_string()
        })
        .collect()
}

/// The deviations of a report that its expectations file does not accept, each as
/// `"ID": "SUMMARY"`.
pub fn unexpected_deviations(v: &Value) -> Vec<String> {
    checks_where(v, |c| {
        c["status"] == "deviation" && c["expectation"]["outcome"] != "expected"
    })
    .map(|c| format!("{}: {}", c["id"], c["summary"]))
    .collect()
}

/// The checks of a report for which `keep` holds (a report without checks fails the test).
fn checks_where<'a>(
    v: &'a Value,
    keep: impl Fn(&Value) -> bool + 'a,
) -> impl Iterator<Item = &'a Value> + 'a {
    v["checks"]
        .as_array()
        .unwrap_or_else(|| panic!("a report without checks: {v}"))
        .iter()
        .filter(move |c| keep(c))
}
