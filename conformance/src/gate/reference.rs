//! This suite's own codec behind the adapter protocol: the reference adapter
//! (`conformance adapter`). It shows the protocol working end to end, and with a
//! deliberate fault ([`Fault::AcceptBadChecksum`]) it is the broken implementation that the
//! gate's own tests must catch.

use std::io::{BufRead, Write};

use serde_json::{json, Value};

use crate::codec::hex::{parse_hex, Hex};
use crate::codec::pdu::Direction;
use crate::codec::{self, crc16, lrc, Mode};
use crate::vectors::export::message_json;

/// A deliberate fault of the reference adapter.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Fault {
    /// Decode frames whatever their CRC or LRC.
    AcceptBadChecksum,
}

fn hex_field(v: &Value, k: &str, digits: usize) -> Result<u32, String> {
    let s = v
        .get(k)
        .and_then(Value::as_str)
        .ok_or_else(|| format!("missing hex field {k:?}"))?;
    if s.len() != digits {
        return Err(format!("field {k:?}: {s:?} is not {digits} hex digits"));
    }
    u32::from_str_radix(s, 16).map_err(|e| format!("field {k:?}: {e}"))
}

fn num_field(v: &Value, k: &str) -> Result<u64, String> {
    v.get(k)
        .and_then(Value::as_u64)
        .ok_or_else(|| format!("missing number field {k:?}"))
}

fn words(v: &Value) -> Result<Vec<u8>, String> {
    let list = v
        .get("values")
        .and_then(Value::as_array)
        .ok_or("missing list \"values\"")?;
    let mut out = Vec::with_capacity(list.len() * 2);
    for w in list {
        let s = w.as_str().ok_or("a value is not a string")?;
        let x = u16::from_str_radix(s, 16).map_err(|e| format!("value {s:?}: {e}"))?;
        out.extend_from_slice(&x.to_be_bytes());
    }
    Ok(out)
}

/// The body (address, function, data) of a message described as in the protocol.
pub fn body_from_message(m: &Value) -> Result<Vec<u8>, String> {
    let address = hex_field(m, "address", 2)? as u8;
    let function = hex_field(m, "function", 2)? as u8;
    let kind = m
        .get("kind")
        .and_then(Value::as_str)
        .ok_or("missing \"kind\"")?;
    let f = m.get("fields").ok_or("missing \"fields\"")?;
    let mut b = vec![address, function];
    let u16b = |x: u32| (x as u16).to_be_bytes();
    match kind {
        "read-request" | "write-multiple-response" => {
            b.extend_from_slice(&u16b(hex_field(f, "start", 4)?));
            b.extend_from_slice(&u16b(num_field(f, "count")? as u32));
        }
        "read-response" => {
            let data = words(f)?;
            let count = u8::try_from(data.len()).map_err(|_| "too many values")?;
            b.push(count);
            b.extend_from_slice(&data);
        }
        "write-single" => {
            b.extend_from_slice(&u16b(hex_field(f, "register", 4)?));
            b.extend_from_slice(&u16b(hex_field(f, "value", 4)?));
        }
        "loop-back" => {
            b.extend_from_slice(&u16b(hex_field(f, "test_code", 4)?));
            let data = f.get("data").and_then(Value::as_str).unwrap_or("");
            b.extend_from_slice(&parse_hex(data).map_err(|e| e.to_string())?);
        }
        "write-multiple-request" => {
            let data = words(f)?;
            let count = u8::try_from(data.len()).map_err(|_| "too many values")?;
            b.extend_from_slice(&u16b(hex_field(f, "start", 4)?));
            b.extend_from_slice(&u16b(u32::from(count) / 2));
            b.push(count);
            b.extend_from_slice(&data);
        }
        "exception" => b.push(hex_field(f, "code", 2)? as u8),
        "other" => {
            let data = f.get("data").and_then(Value::as_str).unwrap_or("");
            b.extend_from_slice(&parse_hex(data).map_err(|e| e.to_string())?);
        }
        k => return Err(format!("unknown kind {k:?}")),
    }
    Ok(b)
}

fn mode_of(v: &Value) -> Result<Mode, String> {
    let m = v.get("mode").and_then(Value::as_str);
    m.and_then(Mode::from_key)
        .ok_or_else(|| format!("mode {m:?} is not rtu or ascii"))
}

fn direction_of(v: &Value) -> Result<Direction, String> {
    match v.get("direction").and_then(Value::as_str) {
        Some("request") => Ok(Direction::Request),
        Some("response") => Ok(Direction::Response),
        other => Err(format!("direction {other:?} is not request or response")),
    }
}

fn bytes_of(v: &Value, k: &str) -> Result<Vec<u8>, String> {
    let s = v
        .get(k)
        .and_then(Value::as_str)
        .ok_or_else(|| format!("missing {k:?}"))?;
    parse_hex(s).map_err(|e| e.to_string())
}

/// Answers one request.
pub fn answer(req: &Value, fault: Option<Fault>) -> Value {
    let id = req.get("id").cloned().unwrap_or(Value::Null);
    let result: Result<Value, String> = (|| match req.get("op").and_then(Value::as_str) {
        Some("hello") => Ok(json!({
            "protocol": 1,
            "adapter": "conformance-reference-adapter",
            "implementation": "teco-modbus-conformance",
            "version": env!("CARGO_PKG_VERSION"),
            "supports": ["decode", "encode", "crc", "lrc"],
        })),
        Some("decode") => {
            let mode = mode_of(req)?;
            let direction = direction_of(req)?;
            let frame = bytes_of(req, "frame")?;
            let mut scratch = [0u8; codec::MAX_RTU_FRAME];
            let decoded = match fault {
                Some(Fault::AcceptBadChecksum) => {
                    codec::decode_unchecked(mode, &frame, direction, &mut scratch)
                        .map(|u| u.message)
                }
                None => codec::decode(mode, &frame, direction, &mut scratch),
            };
            Ok(match decoded {
                Ok(m) => json!({"accepted": true, "message": message_json(&m)}),
                Err(e) => json!({"accepted": false, "reason": e.to_string()}),
            })
        }
        Some("encode") => {
            let mode = mode_of(req)?;
            let body = body_from_message(req.get("message").ok_or("missing \"message\"")?)?;
            Ok(
                json!({"frame": Hex(&codec::frame_of_body(mode, &body).map_err(|e| e.to_string())?).to_string()}),
            )
        }
        Some("crc") => Ok(json!({"crc": format!("{:04X}", crc16(&bytes_of(req, "data")?))})),
        Some("lrc") => Ok(json!({"lrc": format!("{:02X}", lrc(&bytes_of(req, "data")?))})),
        _ => Err("unsupported".to_string()),
    })();
    match result {
        Ok(mut v) => {
            v["id"] = id;
            v["ok"] = json!(true);
            v
        }
        Err(e) => json!({"id": id, "ok": false, "error": e}),
    }
}

/// Serves the protocol on `input` and `output` until the input ends.
pub fn serve(
    input: impl BufRead,
    mut output: impl Write,
    fault: Option<Fault>,
) -> std::io::Result<()> {
    for line in input.lines() {
        let line = line?;
        if line.trim().is_empty() {
            continue;
        }
        let answer = match serde_json::from_str::<Value>(&line) {
            Ok(req) => answer(&req, fault),
            Err(e) => json!({"id": null, "ok": false, "error": format!("not JSON: {e}")}),
        };
        writeln!(output, "{answer}")?;
        output.flush()?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_protocol_examples_hold() {
        let a = answer(
            &json!({"id": 7, "op": "decode", "mode": "rtu", "direction": "request", "frame": "01 03 01 23 00 01 74 3C"}),
            None,
        );
        assert_eq!(a["message"]["fields"]["start"], "0123");
        assert_eq!(a["accepted"], true);
        let a = answer(
            &json!({"id": 8, "op": "decode", "mode": "rtu", "direction": "response", "frame": "01 03 02 17 70 AF 82"}),
            None,
        );
        assert_eq!(a["accepted"], false);
        let a = answer(
            &json!({"id": 8, "op": "decode", "mode": "rtu", "direction": "response", "frame": "01 03 02 17 70 AF 82"}),
            Some(Fault::AcceptBadChecksum),
        );
        assert_eq!(a["accepted"], true);
        let a = answer(
            &json!({"id": 9, "op": "encode", "mode": "ascii", "direction": "request", "message": {"address": "01", "function": "06", "kind": "write-single", "fields": {"register": "0102", "value": "1770"}}}),
            None,
        );
        assert_eq!(
            a["frame"],
            "3A 30 31 30 36 30 31 30 32 31 37 37 30 36 46 0D 0A"
        );
        assert_eq!(
            answer(
                &json!({"id": 10, "op": "crc", "data": "01 03 01 23 00 01"}),
                None
            )["crc"],
            "3C74"
        );
        assert_eq!(
            answer(
                &json!({"id": 11, "op": "lrc", "data": "01 03 01 00 0A"}),
                None
            )["lrc"],
            "F1"
        );
        assert_eq!(
            answer(&json!({"id": 12, "op": "frobnicate"}), None)["error"],
            "unsupported"
        );
    }
}
