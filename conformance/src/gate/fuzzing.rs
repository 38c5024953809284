//! The adapter protocols as a hostile adapter speaks them, for the cargo-fuzz target
//! `adapter_protocol` (issue 37) and the unit tests below. The process side (an adapter
//! that never answers, crashes, or closes its output and lives on) is held to the gate's
//! deadline by `tests/hostile_adapters.rs`; here is everything the gate makes of the
//! bytes an adapter writes.
//!
//! [`adapter_protocol`] reads a control byte (codec or master adapter; the line limit, 16
//! to 1039 bytes, standing for [`MAX_LINE`](super::adapter::MAX_LINE) so that short inputs
//! reach it), then takes the rest as the adapter's standard output. It reads it line by
//! line as the gate does ([`next_line_within`]) and plays a session with it: the hello (id
//! 0), then for a master the `open` (id 1), then operations, each line judged by [`hear`]
//! for the call under way. The laws:
//!
//! - No panic; reading ends with every byte consumed, in at most one line per `\n` and one
//!   more.
//! - Memory: no line buffer holds more than the limit (and its growth).
//! - A line is text exactly when its bytes are UTF-8 and within the limit, and then it is
//!   those bytes (the independent split at `\n`).
//! - Every line is an answer to the call under way (its id), a late answer to an earlier
//!   one, or a typed error; judged twice, the same.
//! - A hello is a hello only if it says `ok` and the protocol; a master's only if it says
//!   `"role": "master"`; an `open` answer's settings are within the gate's bounds or
//!   refused; an operation's answer is a result or a refusal that says why.

use std::io::BufReader;

use serde_json::Value;

use super::adapter::{hear, next_line_within, Heard, Hello, Line, PROTOCOL};
use super::master::protocol::{
    parse_answer, settings_of_open, MasterHello, MasterSettings, MAX_MASTER_RETRIES,
    MAX_MASTER_TIMEOUT,
};

/// Plays a session with the adapter output `data` describes and checks the laws (see
/// the module notes); panics where one does not hold. Any input is fine.
pub fn adapter_protocol(data: &[u8]) {
    let (control, out) = data.split_first().map_or((0, data), |(c, r)| (*c, r));
    let master = control & 1 == 1;
    let limit = 16 + usize::from(control >> 1) * 8;
    // A small read buffer, so that long lines are read in many pieces.
    let mut reader = BufReader::with_capacity(64, out);
    let mut buf = Vec::new();
    let mut lines = Vec::new();
    while let Some(line) = next_line_within(&mut reader, &mut buf, limit) {
        assert!(
            buf.len() <= limit && buf.capacity() <= 2 * (limit + 1) + 128,
            "a line buffer of {} bytes ({} reserved) over the limit of {limit}",
            buf.len(),
            buf.capacity()
        );
        lines.push(line);
        assert!(lines.len() <= out.len() + 1, "more lines than bytes");
    }
    let newlines = out.iter().filter(|&&b| b == b'\n').count();
    assert!(
        lines.len() <= newlines + 1,
        "{} lines from {newlines} line ends",
        lines.len()
    );
    // The independent split: each line's bytes, as the protocol defines a line.
    let raw: Vec<&[u8]> = out.split_inclusive(|&b| b == b'\n').collect();
    assert_eq!(
        raw.len(),
        lines.len(),
        "lines read are not the lines written"
    );
    for (bytes, line) in raw.iter().zip(&lines) {
        match line {
            Line::Text(t) => {
                assert!(bytes.len() <= limit, "a line over the limit read as text");
                assert_eq!(
                    t.as_str(),
                    std::str::from_utf8(bytes)
                        .expect("text is UTF-8")
                        .trim_end(),
                    "a line read otherwise than written"
                );
            }
            Line::NotUtf8 { at, bytes: shown } => {
                assert!(
                    bytes.len() <= limit,
                    "a line over the limit judged by its text"
                );
                assert!(std::str::from_utf8(bytes).is_err(), "UTF-8 refused");
                assert!(*at < bytes.len() && bytes[*at..].starts_with(shown));
            }
            Line::TooLong => assert!(bytes.len() > limit, "a line within the limit refused"),
        }
    }
    // The session: which call each line is heard by.
    let mut id = 0u64;
    for line in &lines {
        let heard = hear(line, id);
        assert_eq!(heard, hear(line, id), "a line judged twice differs");
        let answer = match heard {
            Heard::Late => {
                // Late: an earlier id than the call's; while the hello (id 0) is waited
                // for, any other id (the gate's rule: it waits on, and its deadline ends
                // the wait).
                let got = match line {
                    Line::Text(t) => serde_json::from_str::<Value>(t)
                        .ok()
                        .and_then(|v| v.get("id").and_then(Value::as_u64)),
                    _ => None,
                };
                assert!(
                    got.is_some_and(|g| g < id || (id == 0 && g > 0)),
                    "a line taken as late whose id is {got:?}, waiting for {id}"
                );
                continue;
            }
            Heard::Error(e) => {
                assert!(!e.to_string().is_empty());
                id += 1;
                continue;
            }
            Heard::Answer(v) => v,
        };
        assert_eq!(answer.get("id").and_then(Value::as_u64), Some(id));
        match (id, master) {
            (0, _) => match Hello::from_answer(answer.clone()) {
                Ok(h) => {
                    assert_eq!(answer.get("ok"), Some(&Value::Bool(true)));
                    assert_eq!(
                        answer.get("protocol").and_then(Value::as_u64),
                        Some(PROTOCOL)
                    );
                    if master {
                        if let Ok(mh) = MasterHello::from_hello(&h) {
                            assert_eq!(answer.get("role").and_then(Value::as_str), Some("master"));
                            assert!(mh.supports.len() <= h.supports.len());
                        }
                    }
                }
                Err(e) => assert!(!e.is_empty()),
            },
            (1, true) => {
                let want = MasterSettings {
                    timeout: std::time::Duration::from_millis(200),
                    retries: 0,
                };
                if let Ok(got) = settings_of_open(&answer, want) {
                    assert!(got.timeout <= MAX_MASTER_TIMEOUT && got.retries <= MAX_MASTER_RETRIES);
                }
            }
            _ => {
                if master {
                    if let Err(e) = parse_answer(&answer) {
                        assert!(!e.is_empty());
                    }
                }
            }
        }
        id += 1;
    }
}

/// What adapters say, honest and hostile: a session of each role, a hello that lies
/// about its role, answers never asked for, wrong types, a missing id, invalid UTF-8,
/// a line over the limit, settings no master has.
pub fn sessions() -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    let codec = concat!(
        "{\"id\":0,\"ok\":true,\"protocol\":1,\"adapter\":\"x\",\"supports\":[\"decode\"]}\n",
        "{\"id\":1,\"ok\":true,\"message\":{}}\n",
        "{\"id\":1,\"ok\":true}\n",
        "{\"id\":9,\"ok\":true}\n",
        "{\"ok\":true}\n",
        "{\"id\":\"3\",\"ok\":1}\n",
        "[1,2,3]\n",
    );
    let master = concat!(
        "{\"id\":0,\"ok\":true,\"protocol\":1,\"role\":\"master\",\"supports\":[\"read\"],\"lines\":[\"pty\"],\"modes\":[\"rtu\"]}\n",
        "{\"id\":1,\"ok\":true,\"timeout_ms\":200,\"retries\":1}\n",
        "{\"id\":2,\"ok\":true,\"result\":\"values\",\"values\":[\"0001\",\"zz\"]}\n",
        "{\"id\":3,\"ok\":true,\"result\":\"exception\",\"code\":\"02\"}\n",
        "{\"id\":4,\"ok\":true,\"result\":\"echo\",\"test_code\":\"0000\",\"data\":\"12 34\"}\n",
        "{\"id\":5,\"ok\":true,\"result\":\"sideways\"}\n",
    );
    let liar = "{\"id\":0,\"ok\":true,\"protocol\":1,\"role\":\"codec\"}\n{\"id\":1,\"ok\":true,\"timeout_ms\":1e300,\"retries\":-1}\n";
    let greedy = "{\"id\":0,\"ok\":true,\"protocol\":1,\"role\":\"master\"}\n{\"id\":1,\"ok\":true,\"timeout_ms\":18446744073709551615,\"retries\":4294967295}\n";
    for (control, text) in [
        (0u8, codec),
        (1, master),
        (1, liar),
        (1, greedy),
        (0xFE, codec),
    ] {
        let mut s = vec![control];
        s.extend_from_slice(text.as_bytes());
        out.push(s);
    }
    let mut bad = vec![0u8];
    bad.extend_from_slice(b"{\"id\":0,\"ok\":true,\"protocol\":1,\"adapter\":\"\xFF\xFE\"}\n");
    bad.extend(std::iter::repeat_n(b'x', 5000));
    bad.extend_from_slice(b"\n{\"id\":1}\n");
    out.push(bad);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn honest_and_hostile_sessions_keep_the_laws() {
        for s in sessions() {
            adapter_protocol(&s);
            for cut in 0..s.len().min(400) {
                adapter_protocol(&s[..cut]);
            }
        }
        adapter_protocol(&[]);
        adapter_protocol(&[1, b'\n', b'\n', 0xC3]);
    }

    #[test]
    fn a_line_over_the_limit_is_skipped_and_the_next_read() {
        let mut out = vec![b'{'; 3000];
        out.extend_from_slice(b"\n{\"id\":0}\n");
        let mut reader = BufReader::with_capacity(64, &out[..]);
        let mut buf = Vec::new();
        assert_eq!(
            next_line_within(&mut reader, &mut buf, 100),
            Some(Line::TooLong)
        );
        assert!(buf.len() <= 100);
        assert_eq!(
            next_line_within(&mut reader, &mut buf, 100),
            Some(Line::Text("{\"id\":0}".into()))
        );
        assert_eq!(next_line_within(&mut reader, &mut buf, 100), None);
    }

    #[test]
    fn invalid_utf8_is_a_typed_error_with_its_bytes() {
        let line = Line::NotUtf8 {
            at: 3,
            bytes: vec![0xFF, 0x41],
        };
        match hear(&line, 1) {
            Heard::Error(e) => assert!(e.to_string().contains("FF 41"), "{e}"),
            other => panic!("{other:?}"),
        }
    }

    #[test]
    fn settings_no_master_has_are_refused() {
        let want = MasterSettings {
            timeout: std::time::Duration::from_millis(200),
            retries: 1,
        };
        for answer in [
            serde_json::json!({"timeout_ms": u64::MAX}),
            serde_json::json!({"timeout_ms": 60_001}),
            serde_json::json!({"retries": 11}),
            serde_json::json!({"retries": -1}),
            serde_json::json!({"timeout_ms": "200"}),
        ] {
            assert!(settings_of_open(&answer, want).is_err(), "{answer}");
        }
        assert_eq!(
            settings_of_open(&serde_json::json!({"timeout_ms": 500}), want),
            Ok(MasterSettings {
                timeout: std::time::Duration::from_millis(500),
                retries: 1
            })
        );
    }
}
