//! `modbus-core-adapter`: lets the conformance gate (`conformance gate --codec CMD`) test
//! the RTU codec of the `modbus-core` crate. It speaks the line-delimited JSON protocol of
//! `adapters/PROTOCOL.md` on standard input and output; logs go to standard error.
//!
//! | operation | modbus-core API |
//! |---|---|
//! | decode, request | `rtu::server::decode_request` (what a modbus-core slave runs on received bytes) |
//! | decode, response | `rtu::client::decode_response` |
//! | encode, request | `rtu::client::encode_request` of a `Request` |
//! | encode, response | `rtu::server::encode_response` of a `Response` or `ExceptionResponse` |
//! | crc | `rtu::crc16` |
//!
//! ASCII is not in modbus-core (it has RTU and TCP only), so `decode` and `encode` are
//! announced for RTU only and `lrc` not at all. Every operation runs under `catch_unwind`:
//! a panic while decoding is answered `accepted: false, raised: true`, which the gate
//! reports as a deviation.

use modbus_core::rtu::{self, Header, RequestAdu, ResponseAdu};
use modbus_core::{
    Data, Exception, ExceptionResponse, FunctionCode, Request, RequestPdu, Response, ResponsePdu,
};
use serde_json::{json, Map, Value};

/// The modbus-core version in Cargo.toml (pinned with `=`).
const MODBUS_CORE_VERSION: &str = "0.2.0";

/// An answer's fields besides `id`, or the error text (`unsupported` is skipped by the gate).
type Outcome = Result<Value, String>;

fn main() {
    adapter_lines::install_panic_hook("modbus-core-adapter");
    adapter_lines::serve("modbus-core-adapter", handle_line);
}

/// Answers one request line; never panics.
fn handle_line(text: &str) -> Value {
    let request: Value = match serde_json::from_str(text) {
        Ok(v) => v,
        Err(e) => return json!({"id": null, "ok": false, "error": format!("not JSON: {e}")}),
    };
    let id = request.get("id").cloned().unwrap_or(Value::Null);
    let outcome = match adapter_lines::guarded(|| dispatch(&request)) {
        Ok(o) => o,
        Err(text) => {
            let text = text.unwrap_or_else(|| "a panic".into());
            if request.get("op").and_then(Value::as_str) == Some("decode") {
                Ok(json!({"accepted": false, "raised": true,
                          "reason": format!("modbus-core panicked: {text}")}))
            } else {
                Err(format!("modbus-core panicked: {text}"))
            }
        }
    };
    let mut answer = Map::new();
    answer.insert("id".into(), id);
    match outcome {
        Ok(Value::Object(fields)) => {
            answer.insert("ok".into(), true.into());
            answer.extend(fields);
        }
        Ok(other) => {
            answer.insert("ok".into(), false.into());
            answer.insert("error".into(), format!("internal: {other}").into());
        }
        Err(e) => {
            answer.insert("ok".into(), false.into());
            if let Some(detail) = e.strip_prefix("unsupported: ") {
                answer.insert("error".into(), "unsupported".into());
                answer.insert("detail".into(), detail.into());
            } else {
                answer.insert("error".into(), e.into());
            }
        }
    }
    Value::Object(answer)
}

fn dispatch(request: &Value) -> Outcome {
    let op = request.get("op").and_then(Value::as_str).unwrap_or("");
    if op != "hello" && op != "crc" {
        if let Some(mode) = request.get("mode").and_then(Value::as_str) {
            if mode != "rtu" {
                return Err(format!(
                    "unsupported: modbus-core has no {mode} framing (RTU and TCP only)"
                ));
            }
        }
    }
    let response = match request.get("direction").and_then(Value::as_str) {
        Some("request") => false,
        Some("response") => true,
        _ if op == "decode" || op == "encode" => return Err("no valid \"direction\"".into()),
        _ => false,
    };
    match op {
        "hello" => {
            if request.get("protocol") != Some(&json!(1)) {
                return Err("this adapter speaks protocol 1 only".into());
            }
            Ok(json!({"protocol": 1, "adapter": "modbus-core-adapter",
                      "implementation": "modbus-core", "version": MODBUS_CORE_VERSION,
                      "supports": ["decode:rtu", "encode:rtu", "crc"]}))
        }
        "crc" => {
            let data = hex_field(request, "data")?;
            // modbus-core returns the two CRC bytes in wire order read as big-endian.
            let wire = rtu::crc16(&data);
            Ok(json!({"crc": format!("{:04X}", wire.swap_bytes())}))
        }
        "decode" => {
            let frame = hex_field(request, "frame")?;
            if response {
                decode_response(&frame)
            } else {
                decode_request(&frame)
            }
        }
        "encode" => {
            let message = request
                .get("message")
                .ok_or("no \"message\" in the request")?;
            let frame = if response {
                encode_response(message)?
            } else {
                encode_request(message)?
            };
            Ok(json!({"frame": hex(&frame)}))
        }
        _ => Err("unsupported: unknown op".into()),
    }
}

fn hex(bytes: &[u8]) -> String {
    bytes
        .iter()
        .map(|b| format!("{b:02X}"))
        .collect::<Vec<_>>()
        .join(" ")
}

fn hex_field(v: &Value, key: &str) -> Result<Vec<u8>, String> {
    let s = v
        .get(key)
        .and_then(Value::as_str)
        .ok_or(format!("no \"{key}\""))?;
    s.split_whitespace()
        .map(|t| u8::from_str_radix(t, 16).map_err(|_| format!("bad hex byte {t:?}")))
        .collect()
}

fn hex_num(v: &Value, key: &str) -> Result<u16, String> {
    let s = v
        .get(key)
        .and_then(Value::as_str)
        .ok_or(format!("no hex field \"{key}\""))?;
    u16::from_str_radix(s.trim_end_matches(['H', 'h']), 16)
        .map_err(|_| format!("{key}: bad hex {s:?}"))
}

fn number(v: &Value, key: &str) -> Result<u64, String> {
    v.get(key)
        .and_then(Value::as_u64)
        .ok_or(format!("no number \"{key}\""))
}

fn words(v: &Value) -> Result<Vec<u16>, String> {
    v.get("values")
        .and_then(Value::as_array)
        .ok_or("no \"values\"")?
        .iter()
        .map(|w| {
            w.as_str()
                .and_then(|s| u16::from_str_radix(s, 16).ok())
                .ok_or(format!("bad value {w}"))
        })
        .collect()
}

fn hex4_list(data: &Data<'_>) -> Vec<String> {
    // `Data::get` is the application's way to read the values: a panic here is modbus-core's.
    (0..data.len())
        .map(|i| format!("{:04X}", data.get(i).unwrap_or_default()))
        .collect()
}

fn message(address: u8, function: u8, kind: &str, fields: Value) -> Value {
    json!({"address": format!("{address:02X}"), "function": format!("{function:02X}"),
           "kind": kind, "fields": fields})
}

fn accepted(message: Value) -> Outcome {
    Ok(json!({"accepted": true, "message": message}))
}

fn rejected(reason: String) -> Outcome {
    Ok(json!({"accepted": false, "reason": reason}))
}

/// What modbus-core's `call` decoded, or the answer that rejects the frame: no complete
/// frame found, or modbus-core's error.
fn found<T, E: std::fmt::Display>(decoded: Result<Option<T>, E>, call: &str) -> Result<T, Outcome> {
    match decoded {
        Ok(Some(adu)) => Ok(adu),
        Ok(None) => Err(rejected(format!(
            "modbus-core found no complete frame with a valid CRC ({call} gave None)"
        ))),
        Err(e) => Err(rejected(format!("modbus-core: {e}"))),
    }
}

/// 06H, the same in both directions.
fn write_single(a: u8, fc: u8, register: u16, value: u16) -> Value {
    let fields = json!({"register": format!("{register:04X}"), "value": format!("{value:04X}")});
    message(a, fc, "write-single", fields)
}

/// A PDU modbus-core hands over as bytes: 08H (with at least its test code) as a loop-back,
/// anything else as data.
fn custom(a: u8, fc: u8, bytes: &[u8]) -> Value {
    if fc == 0x08 && bytes.len() >= 2 {
        message(
            a,
            fc,
            "loop-back",
            json!({"test_code": format!("{:02X}{:02X}", bytes[0], bytes[1]),
                   "data": hex(&bytes[2..])}),
        )
    } else {
        message(a, fc, "other", json!({"data": hex(bytes)}))
    }
}

fn decode_request(frame: &[u8]) -> Outcome {
    let adu = match found(rtu::server::decode_request(frame), "decode_request") {
        Ok(adu) => adu,
        Err(rejection) => return rejection,
    };
    let a = adu.hdr.slave;
    let RequestPdu(pdu) = adu.pdu;
    let fc = FunctionCode::from(pdu).value();
    let m = match pdu {
        Request::ReadHoldingRegisters(start, count) => message(
            a,
            fc,
            "read-request",
            json!({"start": format!("{start:04X}"), "count": count}),
        ),
        Request::WriteSingleRegister(register, value) => write_single(a, fc, register, value),
        Request::WriteMultipleRegisters(start, data) => message(
            a,
            fc,
            "write-multiple-request",
            json!({"start": format!("{start:04X}"), "count": data.len(),
                   "byte_count": data.payload().len(), "values": hex4_list(&data)}),
        ),
        Request::Diagnostics(sub, data) => message(
            a,
            fc,
            "loop-back",
            json!({"test_code": format!("{:04X}", sub), "data": hex(data.payload())}),
        ),
        Request::Custom(_, bytes) => custom(a, fc, bytes),
        _ => message(a, fc, "other", json!({})),
    };
    accepted(m)
}

fn decode_response(frame: &[u8]) -> Outcome {
    let adu = match found(rtu::client::decode_response(frame), "decode_response") {
        Ok(adu) => adu,
        Err(rejection) => return rejection,
    };
    let a = adu.hdr.slave;
    let ResponsePdu(pdu) = adu.pdu;
    let m = match pdu {
        Err(ExceptionResponse {
            function,
            exception,
        }) => {
            let f = function.value();
            message(
                a,
                f | 0x80,
                "exception",
                json!({"exception_function": format!("{f:02X}"),
                       "code": format!("{:02X}", exception as u8)}),
            )
        }
        Ok(r) => {
            let fc = FunctionCode::from(r).value();
            match r {
                Response::ReadHoldingRegisters(data) => message(
                    a,
                    fc,
                    "read-response",
                    json!({"byte_count": data.payload().len(), "values": hex4_list(&data)}),
                ),
                Response::WriteSingleRegister(register, value) => {
                    write_single(a, fc, register, value)
                }
                Response::WriteMultipleRegisters(start, count) => message(
                    a,
                    fc,
                    "write-multiple-response",
                    json!({"start": format!("{start:04X}"), "count": count}),
                ),
                Response::Diagnostics(data) => {
                    let p = data.payload();
                    message(
                        a,
                        fc,
                        "loop-back",
                        json!({"test_code": format!("{:02X}{:02X}", p.first().copied().unwrap_or(0), p.get(1).copied().unwrap_or(0)),
                               "data": hex(p.get(2..).unwrap_or_default())}),
                    )
                }
                Response::Custom(_, bytes) => custom(a, fc, bytes),
                _ => message(a, fc, "other", json!({})),
            }
        }
    };
    accepted(m)
}

fn head(message: &Value) -> Result<(u8, u8, &str, &Value), String> {
    let address = hex_num(message, "address")?;
    let function = hex_num(message, "function")?;
    let kind = message
        .get("kind")
        .and_then(Value::as_str)
        .ok_or("no \"kind\"")?;
    let fields = message.get("fields").ok_or("no \"fields\"")?;
    if address > 0xFF || function > 0xFF {
        return Err("address or function over FFH".into());
    }
    Ok((address as u8, function as u8, kind, fields))
}

fn expect_function(function: u8, wanted: u8, kind: &str) -> Result<(), String> {
    if function == wanted {
        Ok(())
    } else {
        Err(format!(
            "unsupported: modbus-core's {kind} is function {wanted:02X}, not {function:02X}"
        ))
    }
}

/// Packs words, refusing what modbus-core's `Data::from_words` cannot hold (no words).
fn pack<'b>(values: &[u16], buf: &'b mut [u8]) -> Result<Data<'b>, String> {
    // The target must be exactly as long as the words: modbus-core encodes the whole slice.
    let n = (2 * values.len()).min(buf.len());
    Data::from_words(values, &mut buf[..n]).map_err(|e| {
        format!(
            "unsupported: modbus-core cannot pack {} words: {e}",
            values.len()
        )
    })
}

fn encode_request(message: &Value) -> Result<Vec<u8>, String> {
    let (address, function, kind, f) = head(message)?;
    let mut words_buf = [0u8; 256];
    let request = match kind {
        "read-request" => {
            expect_function(function, 0x03, kind)?;
            let count = u16::try_from(number(f, "count")?).map_err(|e| e.to_string())?;
            Request::ReadHoldingRegisters(hex_num(f, "start")?, count)
        }
        "write-single" => {
            expect_function(function, 0x06, kind)?;
            Request::WriteSingleRegister(hex_num(f, "register")?, hex_num(f, "value")?)
        }
        "write-multiple-request" => {
            expect_function(function, 0x10, kind)?;
            let values = words(f)?;
            if number(f, "count")? != values.len() as u64
                || number(f, "byte_count")? != 2 * values.len() as u64
            {
                return Err(
                    "unsupported: modbus-core derives count and byte count from the values".into(),
                );
            }
            Request::WriteMultipleRegisters(hex_num(f, "start")?, pack(&values, &mut words_buf)?)
        }
        "loop-back" => {
            expect_function(function, 0x08, kind)?;
            return Err("unsupported: modbus-core 0.2.0 cannot encode an 08H request (no length for it in its RTU codec)".into());
        }
        _ => return Err(format!("unsupported: kind {kind} as a request")),
    };
    let mut buf = [0u8; 256];
    let n = rtu::client::encode_request(
        RequestAdu {
            hdr: Header { slave: address },
            pdu: RequestPdu(request),
        },
        &mut buf,
    )
    .map_err(|e| format!("modbus-core: {e}"))?;
    Ok(buf[..n].to_vec())
}

fn exception_of(code: u16) -> Result<Exception, String> {
    Ok(match code {
        0x01 => Exception::IllegalFunction,
        0x02 => Exception::IllegalDataAddress,
        0x03 => Exception::IllegalDataValue,
        0x04 => Exception::ServerDeviceFailure,
        0x05 => Exception::Acknowledge,
        0x06 => Exception::ServerDeviceBusy,
        0x08 => Exception::MemoryParityError,
        0x0A => Exception::GatewayPathUnavailable,
        0x0B => Exception::GatewayTargetDevice,
        other => {
            return Err(format!(
                "unsupported: modbus-core's Exception has no code {other:02X}"
            ))
        }
    })
}

fn encode_response(message: &Value) -> Result<Vec<u8>, String> {
    let (address, function, kind, f) = head(message)?;
    let mut words_buf = [0u8; 256];
    let pdu = match kind {
        "exception" => {
            let ef = hex_num(f, "exception_function")? as u8;
            if function != ef | 0x80 {
                return Err("unsupported: modbus-core sends exception_function | 80H".into());
            }
            ResponsePdu(Err(ExceptionResponse {
                function: FunctionCode::new(ef),
                exception: exception_of(hex_num(f, "code")?)?,
            }))
        }
        "read-response" => {
            expect_function(function, 0x03, kind)?;
            let values = words(f)?;
            if number(f, "byte_count")? != 2 * values.len() as u64 {
                return Err(
                    "unsupported: modbus-core derives the byte count from the values".into(),
                );
            }
            ResponsePdu(Ok(Response::ReadHoldingRegisters(pack(
                &values,
                &mut words_buf,
            )?)))
        }
        "write-single" => {
            expect_function(function, 0x06, kind)?;
            ResponsePdu(Ok(Response::WriteSingleRegister(
                hex_num(f, "register")?,
                hex_num(f, "value")?,
            )))
        }
        "write-multiple-response" => {
            expect_function(function, 0x10, kind)?;
            let count = u16::try_from(number(f, "count")?).map_err(|e| e.to_string())?;
            ResponsePdu(Ok(Response::WriteMultipleRegisters(
                hex_num(f, "start")?,
                count,
            )))
        }
        "loop-back" => {
            expect_function(function, 0x08, kind)?;
            if std::env::var_os("MODBUS_CORE_ADAPTER_TRY_UNIMPLEMENTED").is_none() {
                // modbus-core 0.2.0 gives no length for a Diagnostics response (its
                // Response::pdu_len panics there, by the crate's design), so encoding one is
                // not attempted unless MODBUS_CORE_ADAPTER_TRY_UNIMPLEMENTED is set.
                return Err("unsupported: modbus-core 0.2.0 leaves the length of a Diagnostics response unimplemented (encoding one panics)".into());
            }
            let mut data = hex_num(f, "test_code")?.to_be_bytes().to_vec();
            data.extend(hex_field(f, "data")?);
            if data.len() % 2 != 0 {
                return Err("unsupported: modbus-core's Diagnostics data is whole words".into());
            }
            let values: Vec<u16> = data
                .chunks(2)
                .map(|c| u16::from_be_bytes([c[0], c[1]]))
                .collect();
            ResponsePdu(Ok(Response::Diagnostics(pack(&values, &mut words_buf)?)))
        }
        _ => return Err(format!("unsupported: kind {kind} as a response")),
    };
    let mut buf = [0u8; 256];
    let n = rtu::server::encode_response(
        ResponseAdu {
            hdr: Header { slave: address },
            pdu,
        },
        &mut buf,
    )
    .map_err(|e| format!("modbus-core: {e}"))?;
    Ok(buf[..n].to_vec())
}
