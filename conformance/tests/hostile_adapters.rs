//! Hostile adapters (issue 37): a codec or master adapter that writes huge lines, invalid
//! UTF-8, wrong types, duplicate or missing ids, answers to questions never asked, a hello
//! that lies about its role, that never answers, crashes, closes its output and lives on,
//! or floods the gate with lines. For each, the gate gets a typed error, never hangs (a
//! watchdog far past the gate's own deadline fails the test instead of stalling CI), and
//! holds no more than the protocol's line limit (adapters/PROTOCOL.md) of any line: its
//! peak memory is measured around the call.
//!
//! The adapters are `sh` one-liners; every `sh` has `printf`, `head` and `tr`.

use std::path::PathBuf;
use std::sync::mpsc;
use std::sync::Mutex;
use std::thread;
use std::time::Duration;

use conformance::codec::timing::{LineSettings, Parity};
use conformance::codec::Mode;
use conformance::gate::adapter::{Adapter, AdapterError, CallError, MAX_LINE};
use conformance::gate::master::drive::Endpoint;
use conformance::gate::master::protocol::{MasterAdapter, MasterSettings, Operation};
use serde_json::json;

/// The memory tests measure the process's peak: one test at a time.
static ONE_AT_A_TIME: Mutex<()> = Mutex::new(());

/// Far past any deadline of the gate's in these tests (10 s for a hello, under a second
/// for a call, 2 s for an adapter to exit): reaching it means the gate hung.
const WATCHDOG: Duration = Duration::from_secs(120);

/// Runs `f` on a thread; panics if it has not returned within [`WATCHDOG`].
fn within_deadline<T: Send + 'static>(what: &str, f: impl FnOnce() -> T + Send + 'static) -> T {
    let (tx, rx) = mpsc::channel();
    thread::spawn(move || {
        let _ = tx.send(f());
    });
    match rx.recv_timeout(WATCHDOG) {
        Ok(v) => v,
        Err(_) => panic!("{what}: the gate hung (no result after {WATCHDOG:?})"),
    }
}

/// The process's peak resident memory (VmHWM), in KiB, after `f`, less what it was
/// before (the peak is reset first where the kernel allows it).
fn peak_growth_kib<T>(f: impl FnOnce() -> T) -> (T, u64) {
    let hwm = || -> u64 {
        std::fs::read_to_string("/proc/self/status")
            .ok()
            .and_then(|s| {
                s.lines()
                    .find(|l| l.starts_with("VmHWM:"))
                    .and_then(|l| l.split_whitespace().nth(1))
                    .and_then(|n| n.parse().ok())
            })
            .unwrap_or(0)
    };
    // "5" resets the peak to the current size (Linux 4.0 and later).
    let _ = std::fs::write("/proc/self/clear_refs", "5");
    let before = hwm();
    let out = f();
    (out, hwm().saturating_sub(before))
}

const HELLO: &str = r#"{"id":0,"ok":true,"protocol":1,"adapter":"hostile","supports":["decode"]}"#;
const MASTER_HELLO: &str = r#"{"id":0,"ok":true,"protocol":1,"role":"master","supports":["read"],"lines":["pty"],"modes":["rtu"]}"#;

/// An adapter that answers the hello with `hello`, then runs `then` (sh).
fn adapter(hello: &str, then: &str) -> String {
    format!("read l; printf '%s\\n' '{hello}'; {then}")
}

fn start(command: &str, timeout: Duration) -> Result<Adapter, AdapterError> {
    let command = command.to_string();
    within_deadline("start", move || Adapter::start(&command, timeout))
}

/// A codec adapter whose hello is `HELLO` and that then runs `then`, started (it must
/// start).
fn started(then: &str, timeout: Duration) -> Adapter {
    start(&adapter(HELLO, then), timeout).unwrap()
}

fn call(a: Adapter, request: serde_json::Value) -> (Adapter, Result<serde_json::Value, CallError>) {
    within_deadline("call", move || {
        let mut a = a;
        let r = a.call(request);
        (a, r)
    })
}

fn malformed(r: &Result<serde_json::Value, CallError>, says: &str) {
    match r {
        Err(CallError::Malformed(m)) => assert!(m.contains(says), "{m:?} does not say {says:?}"),
        other => panic!("expected a malformed answer saying {says:?}, got {other:?}"),
    }
}

/// Asserts that each next `decode` call of `a` ends in the malformed answer each of `says`
/// names.
#[track_caller]
fn malformed_answers(mut a: Adapter, says: &[&str]) {
    for said in says {
        let (next, r) = call(a, json!({"op": "decode"}));
        malformed(&r, said);
        a = next;
    }
}

fn handshake_failed(r: Result<Adapter, AdapterError>, says: &str) {
    match r {
        Err(AdapterError::Handshake { problem, .. }) => {
            assert!(problem.contains(says), "{problem:?} does not say {says:?}")
        }
        Err(e) => panic!("expected a failed handshake saying {says:?}, got {e}"),
        Ok(_) => panic!("expected a failed handshake saying {says:?}, the adapter was taken"),
    }
}

#[test]
fn a_huge_line_is_refused_and_never_held() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    // 64 MiB of 'x' without a line end, then a line end and a valid answer.
    let huge = "head -c 67108864 /dev/zero | tr '\\0' x; printf '\\n'";
    let then = format!(
        "read l; {huge}; printf '%s\\n' '{{\"id\":1,\"ok\":true}}'; read l; printf '%s\\n' '{{\"id\":2,\"ok\":true}}'; cat >/dev/null"
    );
    let a = start(&adapter(HELLO, &then), Duration::from_secs(30)).expect("the hello is fine");
    let ((a, r), grew) = peak_growth_kib(|| call(a, json!({"op": "decode"})));
    malformed(&r, &format!("over {MAX_LINE} bytes"));
    // The line limit and the reader's buffers, not the line.
    assert!(
        grew < 16 * 1024,
        "the gate's peak memory grew by {grew} KiB reading a 64 MiB line (limit {MAX_LINE} bytes)"
    );
    // The lines after it are read: the stream stays in step (the late answer 1 is
    // dropped, answer 2 taken).
    let (_a, r) = call(a, json!({"op": "decode"}));
    assert_eq!(r.map(|v| v["id"].clone()), Ok(json!(2)));
}

#[test]
fn a_flood_of_lines_never_asked_for_is_not_held() {
    let _one = ONE_AT_A_TIME.lock().unwrap_or_else(|e| e.into_inner());
    // After the hello, two million answers to a question never asked (about 200 MB).
    let line = format!(r#"{{"id":999,"ok":true,"pad":"{}"}}"#, "p".repeat(80));
    let then = format!("yes '{line}' | head -n 2000000; cat >/dev/null");
    let (r, grew) = peak_growth_kib(|| {
        let a = start(&adapter(HELLO, &then), Duration::from_secs(5)).expect("the hello is fine");
        // Let it write while the gate is not reading.
        thread::sleep(Duration::from_secs(2));
        let (_a, r) = call(a, json!({"op": "decode"}));
        r
    });
    malformed(&r, "answer id Some(999), expected 1");
    assert!(
        grew < 16 * 1024,
        "the gate's peak memory grew by {grew} KiB while an adapter flooded it with lines"
    );
}

#[test]
fn invalid_utf8_is_a_typed_error_with_its_bytes() {
    // printf's format turns \377 into the byte FFH.
    let hello = r#"{"id":0,"ok":true,"protocol":1,"adapter":"bad\377\376"}"#;
    let r = start(
        &format!("read l; printf '{hello}\\n'; cat >/dev/null"),
        Duration::from_secs(5),
    );
    let at = hello.find('\\').unwrap();
    handshake_failed(r, &format!("not UTF-8: at byte {at}, FF FE"));
}

#[test]
fn wrong_types_are_typed_errors() {
    // A protocol given as a string.
    let hello = r#"{"id":0,"ok":true,"protocol":"1"}"#;
    handshake_failed(
        start(&adapter(hello, "cat >/dev/null"), Duration::from_secs(5)),
        "speaks protocol",
    );
    // "ok" as a string, a JSON array, an id as a string.
    let then = r#"read l; printf '%s\n' '{"id":1,"ok":"yes"}'; read l; printf '%s\n' '[1,2]'; read l; printf '%s\n' '{"id":"3","ok":true}'; cat >/dev/null"#;
    let a = started(then, Duration::from_secs(5));
    malformed_answers(
        a,
        &[
            "no \"ok\" field",
            "answer id None, expected 2",
            "answer id None, expected 3",
        ],
    );
}

#[test]
fn duplicate_and_missing_ids_and_answers_never_asked_for() {
    // Answer 1 twice (the second is late for call 2 and dropped), then no id, then an id
    // from the future.
    let then = r#"read l; printf '%s\n%s\n' '{"id":1,"ok":true,"n":1}' '{"id":1,"ok":true,"n":2}'; read l; printf '%s\n' '{"id":2,"ok":true,"n":3}'; read l; printf '%s\n' '{"ok":true}'; read l; printf '%s\n' '{"id":7,"ok":true}'; cat >/dev/null"#;
    let a = started(then, Duration::from_secs(5));
    let (a, r) = call(a, json!({"op": "decode"}));
    assert_eq!(r.unwrap()["n"], 1);
    let (a, r) = call(a, json!({"op": "decode"}));
    assert_eq!(
        r.unwrap()["n"],
        3,
        "the duplicate of answer 1 was taken for answer 2"
    );
    malformed_answers(
        a,
        &[
            "answer id None, expected 3",
            "answer id Some(7), expected 4",
        ],
    );
}

#[test]
fn a_hello_that_lies_about_its_role_is_refused() {
    // A codec adapter's hello where a master is wanted.
    let command = adapter(HELLO, "cat >/dev/null");
    let r = within_deadline("master start", move || {
        MasterAdapter::start(&command, Duration::from_secs(5)).map(|_| ())
    });
    match r {
        Err(AdapterError::Handshake { problem, .. }) => {
            assert!(
                problem.contains("does not speak the master protocol"),
                "{problem}"
            )
        }
        other => panic!("a codec's hello taken as a master's: {other:?}"),
    }
    // A hello that says master, then an open whose settings would make the gate wait for
    // ever (u64::MAX ms, u32::MAX retries).
    let then = r#"read l; printf '%s\n' '{"id":1,"ok":true,"timeout_ms":18446744073709551615,"retries":4294967295}'; cat >/dev/null"#;
    let command = adapter(MASTER_HELLO, then);
    let r = within_deadline("master open", move || {
        let mut m = MasterAdapter::start(&command, Duration::from_secs(5)).expect("a master");
        m.open(
            &Endpoint::Pty(PathBuf::from("/dev/null")),
            Mode::Rtu,
            LineSettings::new(19200, 8, Parity::Even, 1),
            MasterSettings {
                timeout: Duration::from_millis(200),
                retries: 0,
            },
        )
        .map(|s| (s, m.adapter.timeout()))
    });
    match r {
        Err(CallError::Malformed(m)) => assert!(m.contains("timeout_ms"), "{m}"),
        other => panic!("settings no master has were taken: {other:?}"),
    }
}

#[test]
fn an_adapter_that_never_answers_its_hello_fails_at_the_handshake_deadline() {
    handshake_failed(
        start("cat >/dev/null", Duration::from_millis(300)),
        "no answer within",
    );
}

#[test]
fn an_adapter_that_never_answers_times_out_and_is_restarted() {
    let mut a = started("cat >/dev/null", Duration::from_millis(300));
    for _ in 0..3 {
        let (b, r) = call(a, json!({"op": "decode"}));
        assert_eq!(r, Err(CallError::Timeout(300)));
        a = b;
    }
    assert!(
        a.incidents.iter().any(|i| i.contains("got no answer")),
        "{:?}",
        a.incidents
    );
    // A master whose operation never comes back: the same deadline.
    let command = adapter(MASTER_HELLO, "cat >/dev/null");
    let r = within_deadline("master operate", move || {
        let mut m = MasterAdapter::start(&command, Duration::from_millis(300)).expect("a master");
        m.operate(&Operation::Read {
            unit: 1,
            start: 0x2520,
            count: 1,
        })
    });
    assert_eq!(r, Err(CallError::Timeout(300)));
}

#[test]
fn an_adapter_that_crashes_is_restarted_once_then_gone() {
    let a = started("read l; exit 3", Duration::from_secs(5));
    let (a, r) = call(a, json!({"op": "decode"}));
    assert!(matches!(r, Err(CallError::Crashed(_))), "{r:?}");
    let (a, r) = call(a, json!({"op": "decode"}));
    assert!(matches!(r, Err(CallError::Crashed(_))), "{r:?}");
    let (a, r) = call(a, json!({"op": "decode"}));
    assert_eq!(r, Err(CallError::Gone));
    assert!(
        a.incidents.iter().any(|i| i.contains("restarted")),
        "{:?}",
        a.incidents
    );
}

#[test]
fn an_adapter_that_closes_its_output_and_lives_on_is_killed() {
    // It closes its standard output and sleeps (its input still open): the gate must not
    // wait for it to exit.
    let a = started("read l; exec 1>&-; sleep 600", Duration::from_secs(5));
    let (_a, r) = call(a, json!({"op": "decode"}));
    match r {
        Err(CallError::Crashed(why)) => assert!(why.contains("did not exit"), "{why}"),
        other => panic!("{other:?}"),
    }
}
