//! The export: one JSON document with every vector and the flags table, for other
//! implementations to consume (schema: `vectors/schema/export.schema.json`).

use serde_json::{json, Map, Value};

use super::model::{parse_known, Body};
use super::set::VectorSet;
use super::verify::frame_parts;
use crate::codec::hex::Hex;
use crate::codec::{Message, Mode, Pdu};

/// Format version of the export.
pub const EXPORT_SCHEMA_VERSION: u32 = 1;

/// A message as machine-readable fields: hex strings for addresses, registers, values and
/// data; numbers for counts.
pub fn message_json(m: &Message<'_>) -> Value {
    let hex4 = |v: u16| Value::String(format!("{v:04X}"));
    let mut o = Map::new();
    o.insert("address".into(), format!("{:02X}", m.address).into());
    o.insert(
        "function".into(),
        format!("{:02X}", m.pdu.function_code()).into(),
    );
    let (kind, fields) = match m.pdu {
        Pdu::ReadRequest { start, count } => (
            "read-request",
            json!({"start": hex4(start), "count": count}),
        ),
        Pdu::ReadResponse { values } => (
            "read-response",
            json!({"byte_count": values.as_bytes().len(), "values": values.iter().map(hex4).collect::<Vec<_>>()}),
        ),
        Pdu::WriteSingle { register, value } => (
            "write-single",
            json!({"register": hex4(register), "value": hex4(value)}),
        ),
        Pdu::LoopBack { test_code, data } => (
            "loop-back",
            json!({"test_code": hex4(test_code), "data": Hex(data).to_string()}),
        ),
        Pdu::WriteMultipleRequest { start, values } => (
            "write-multiple-request",
            json!({"start": hex4(start), "count": values.len(), "byte_count": values.as_bytes().len(),
                   "values": values.iter().map(hex4).collect::<Vec<_>>()}),
        ),
        Pdu::WriteMultipleResponse { start, count } => (
            "write-multiple-response",
            json!({"start": hex4(start), "count": count}),
        ),
        Pdu::Exception { function, code } => (
            "exception",
            json!({"exception_function": format!("{function:02X}"), "code": format!("{code:02X}")}),
        ),
        Pdu::Other { data, .. } => ("other", json!({"data": Hex(data).to_string()})),
    };
    o.insert("kind".into(), kind.into());
    o.insert("fields".into(), fields);
    Value::Object(o)
}

/// The decoded message of a frame's bytes (checksum not required to be valid), or null.
fn decoded(mode: Mode, direction: crate::codec::Direction, hex: &str) -> Value {
    let Ok(bytes) = parse_known(hex) else {
        return Value::Null;
    };
    let Ok(parts) = frame_parts(mode, &bytes) else {
        return Value::Null;
    };
    match Message::parse_body(&parts.body, direction) {
        Ok(m) => {
            let mut v = message_json(&m);
            if let Value::Object(o) = &mut v {
                o.insert("checksum_valid".into(), parts.checksum.is_valid().into());
            }
            v
        }
        Err(_) => Value::Null,
    }
}

/// The whole export document.
pub fn export_json(set: &VectorSet) -> Value {
    let mut count = 0usize;
    let documents: Vec<Value> = set
        .files
        .iter()
        .map(|f| {
            let vectors: Vec<Value> = f
                .vectors
                .iter()
                .map(|v| {
                    count += 1;
                    let mut value = serde_json::to_value(v).unwrap_or(Value::Null);
                    if let (Body::Frame(fv), Value::Object(o)) = (&v.body, &mut value) {
                        let mode: Mode = fv.mode.into();
                        o.insert(
                            "decoded".into(),
                            decoded(mode, fv.direction.into(), &fv.printed),
                        );
                        if let Some(c) = &fv.corrected {
                            o.insert(
                                "corrected_decoded".into(),
                                decoded(mode, fv.direction.into(), c),
                            );
                        }
                    }
                    value
                })
                .collect();
            json!({"document": f.document, "title": f.title, "vectors": vectors})
        })
        .collect();
    json!({
        "schema": "teco-modbus-golden-vectors",
        "schema_version": EXPORT_SCHEMA_VERSION,
        "generator": format!("conformance {}", env!("CARGO_PKG_VERSION")),
        "number_of_vectors": count,
        "flags": set.flags.flags,
        "documents": documents,
    })
}
