//! The protocol's operations, each carried out with rmodbus 0.13:
//!
//! | operation | rmodbus API |
//! |---|---|
//! | decode, request | `server::ModbusFrame::parse`, then its `func`/`reg`/`count` fields and `get_external_write` (values of 06H/10H) |
//! | decode, response | `client::ModbusRequest::parse_u16` (03H/04H), `parse_slice` (other functions), `parse_ok` (exceptions) |
//! | decode, ASCII | `parse_ascii_frame` first, then as above with `ModbusProto::Ascii` (LRC) |
//! | encode, request | `client::ModbusRequest::generate_get_holdings` / `generate_set_holding` / `generate_set_holdings_bulk` (and the other `generate_*`) |
//! | encode, response | `server::ModbusFrame::parse` of a request built with `ModbusRequest`, then `get_external_read` + `process_external_read`, `process_external_write`, or the `error` field, then `finalize_response` |
//! | encode, ASCII | the binary frame with its LRC as above, then `generate_ascii_frame` |
//! | crc, lrc | `server::ModbusFrame::finalize_response` (rmodbus keeps `calc_crc16` / `calc_lrc` private) |
//!
//! Every request runs under `catch_unwind`: a panic inside rmodbus while decoding becomes
//! `{"accepted": false, "raised": true, ...}` (a rejection by panic, which the gate reports
//! as a deviation); elsewhere `{"ok": false, "error": "rmodbus panicked: ..."}`. The
//! adapter carries on either way.

use rmodbus::client::ModbusRequest;
use rmodbus::consts::{ModbusErrorCode, ModbusFunction};
use rmodbus::server::{ModbusFrame, Read, Write};
use rmodbus::{ErrorKind, ModbusFrameBuf, ModbusProto};
use serde::Deserialize;
use serde_json::{json, Map, Value};

/// The protocol version this adapter speaks.
const PROTOCOL: u64 = 1;

/// The rmodbus version Cargo resolved (from Cargo.lock, by build.rs).
const RMODBUS_VERSION: &str = env!("RMODBUS_VERSION");

/// One request line. Fields this adapter does not know are ignored, as the protocol asks.
#[derive(Deserialize)]
struct Request {
    op: Option<String>,
    protocol: Option<Value>,
    mode: Option<String>,
    direction: Option<String>,
    frame: Option<String>,
    message: Option<Value>,
    data: Option<String>,
}

/// A message as the protocol describes it (`encode`'s input).
#[derive(Deserialize)]
struct Message {
    address: String,
    function: String,
    kind: String,
    #[serde(default)]
    fields: Map<String, Value>,
}

/// Why an operation gave no result.
#[derive(Debug)]
enum Failure {
    /// Answered `"error": "unsupported"` (the gate skips the case), with a `detail`.
    Unsupported(String),
    /// Any other error.
    Error(String),
}

/// The answer's fields (besides `id` and `ok`), or why there is none.
type Outcome = Result<Map<String, Value>, Failure>;

#[derive(Clone, Copy, PartialEq, Eq)]
enum Mode {
    Rtu,
    Ascii,
}

impl Mode {
    fn proto(self) -> ModbusProto {
        match self {
            Mode::Rtu => ModbusProto::Rtu,
            Mode::Ascii => ModbusProto::Ascii,
        }
    }
}

#[derive(Clone, Copy, PartialEq, Eq)]
enum Direction {
    Request,
    Response,
}

/// Answers one (non-blank) input line. Never panics.
pub fn handle_line(text: &str) -> Value {
    let mut answer = Map::new();
    let outcome = match serde_json::from_str::<Value>(text) {
        Err(e) => {
            answer.insert("id".into(), Value::Null);
            Err(Failure::Error(format!("not JSON: {e}")))
        }
        Ok(value) => {
            answer.insert("id".into(), value.get("id").cloned().unwrap_or(Value::Null));
            match serde_json::from_value::<Request>(value) {
                Ok(request) => run_guarded(&request),
                Err(e) => Err(Failure::Error(format!("not a protocol request: {e}"))),
            }
        }
    };
    match outcome {
        Ok(fields) => {
            answer.insert("ok".into(), true.into());
            answer.extend(fields);
        }
        Err(Failure::Unsupported(detail)) => {
            answer.insert("ok".into(), false.into());
            answer.insert("error".into(), "unsupported".into());
            answer.insert("detail".into(), detail.into());
        }
        Err(Failure::Error(e)) => {
            answer.insert("ok".into(), false.into());
            answer.insert("error".into(), e.into());
        }
    }
    Value::Object(answer)
}

fn run_guarded(request: &Request) -> Outcome {
    match adapter_lines::guarded(|| dispatch(request)) {
        Ok(outcome) => outcome,
        Err(text) => {
            let text = text.unwrap_or_else(|| "(no message)".into());
            if request.op.as_deref() == Some("decode") {
                // rmodbus rejected the frame by panicking: a rejection, but not a graceful
                // one (PROTOCOL.md: "raised").
                let mut m = Map::new();
                m.insert("accepted".into(), false.into());
                m.insert("raised".into(), true.into());
                m.insert("reason".into(), format!("rmodbus panicked: {text}").into());
                return Ok(m);
            }
            Err(Failure::Error(format!("rmodbus panicked: {text}")))
        }
    }
}

fn dispatch(request: &Request) -> Outcome {
    match request.op.as_deref() {
        Some("hello") => hello(request),
        Some("decode") => decode(request),
        Some("encode") => encode(request),
        Some("crc") => crc(request),
        Some("lrc") => lrc(request),
        Some(other) => Err(Failure::Unsupported(format!("unknown operation {other:?}"))),
        None => Err(Failure::Error("the request has no \"op\"".into())),
    }
}

// ---------------------------------------------------------------- small helpers

fn object(value: Value) -> Map<String, Value> {
    match value {
        Value::Object(map) => map,
        _ => Map::new(),
    }
}

fn bad(text: impl Into<String>) -> Failure {
    Failure::Error(text.into())
}

fn unsupported(text: impl Into<String>) -> Failure {
    Failure::Unsupported(text.into())
}

fn hex2(b: u8) -> String {
    format!("{b:02X}")
}

fn hex4(v: u16) -> String {
    format!("{v:04X}")
}

fn hex_bytes(bytes: &[u8]) -> String {
    bytes.iter().map(|b| hex2(*b)).collect::<Vec<_>>().join(" ")
}

/// Parses "01 03 0A" (pairs separated by white space; a token may hold several pairs).
fn parse_hex(text: &str) -> Result<Vec<u8>, Failure> {
    let mut out = Vec::new();
    for token in text.split_whitespace() {
        if token.len() % 2 != 0 || !token.bytes().all(|c| c.is_ascii_hexdigit()) {
            return Err(bad(format!("bad hex {token:?}")));
        }
        for pair in token.as_bytes().chunks(2) {
            let pair = std::str::from_utf8(pair).map_err(|_| bad("bad hex"))?;
            out.push(u8::from_str_radix(pair, 16).map_err(|_| bad("bad hex"))?);
        }
    }
    Ok(out)
}

fn parse_hex_number(text: &str, digits: usize, what: &str) -> Result<u16, Failure> {
    let t = text.trim();
    if t.is_empty() || t.len() > digits || !t.bytes().all(|c| c.is_ascii_hexdigit()) {
        return Err(bad(format!("{what}: bad hex {text:?}")));
    }
    u16::from_str_radix(t, 16).map_err(|_| bad(format!("{what}: bad hex {text:?}")))
}

fn parse_hex2(text: &str, what: &str) -> Result<u8, Failure> {
    parse_hex_number(text, 2, what).map(|v| v.to_be_bytes()[1])
}

fn field<'a>(fields: &'a Map<String, Value>, name: &str) -> Result<&'a Value, Failure> {
    fields
        .get(name)
        .ok_or_else(|| bad(format!("the message has no field {name:?}")))
}

fn field_hex4(fields: &Map<String, Value>, name: &str) -> Result<u16, Failure> {
    let v = field(fields, name)?;
    let s = v
        .as_str()
        .ok_or_else(|| bad(format!("{name}: expected a hex string, got {v}")))?;
    parse_hex_number(s, 4, name)
}

fn field_hex2(fields: &Map<String, Value>, name: &str) -> Result<u8, Failure> {
    let v = field(fields, name)?;
    let s = v
        .as_str()
        .ok_or_else(|| bad(format!("{name}: expected a hex string, got {v}")))?;
    parse_hex2(s, name)
}

fn field_number(fields: &Map<String, Value>, name: &str) -> Result<u64, Failure> {
    let v = field(fields, name)?;
    v.as_u64()
        .ok_or_else(|| bad(format!("{name}: expected a number, got {v}")))
}

fn field_values(fields: &Map<String, Value>) -> Result<Vec<u16>, Failure> {
    let v = field(fields, "values")?;
    let list = v
        .as_array()
        .ok_or_else(|| bad(format!("values: expected a list, got {v}")))?;
    list.iter()
        .map(|x| {
            x.as_str()
                .ok_or_else(|| bad(format!("values: expected hex strings, got {x}")))
                .and_then(|s| parse_hex_number(s, 4, "values"))
        })
        .collect()
}

fn u16_of(n: u64, what: &str) -> Result<u16, Failure> {
    u16::try_from(n).map_err(|_| bad(format!("{what} {n} does not fit in 16 bits")))
}

fn mode_of(request: &Request) -> Result<Mode, Failure> {
    let modes = [("rtu", Mode::Rtu), ("ascii", Mode::Ascii)];
    one_of(request.mode.as_deref(), "mode", modes, unsupported)
}

fn direction_of(request: &Request) -> Result<Direction, Failure> {
    let directions = [
        ("request", Direction::Request),
        ("response", Direction::Response),
    ];
    one_of(request.direction.as_deref(), "direction", directions, bad)
}

/// The request's `field`, one of `choices` in any case; a value that is none of them is
/// refused by `other` with its text ("mode \"x\"").
fn one_of<T: Copy>(
    value: Option<&str>,
    field: &str,
    choices: [(&str, T); 2],
    other: impl FnOnce(String) -> Failure,
) -> Result<T, Failure> {
    let v = value.ok_or_else(|| bad(format!("the request has no \"{field}\"")))?;
    choices
        .iter()
        .find(|(name, _)| v.eq_ignore_ascii_case(name))
        .map(|&(_, t)| t)
        .ok_or_else(|| other(format!("{field} {v:?}")))
}

fn message(address: u8, function: u8, kind: &str, fields: Value) -> Value {
    json!({"address": hex2(address), "function": hex2(function), "kind": kind, "fields": fields})
}

fn rejected(reason: String) -> Map<String, Value> {
    object(json!({"accepted": false, "reason": reason}))
}

fn accepted(message: Value, note: Option<String>) -> Map<String, Value> {
    let mut answer = object(json!({"accepted": true, "message": message}));
    if let Some(note) = note {
        // An extra field: the gate ignores it, a person reading the log does not.
        answer.insert("note".into(), note.into());
    }
    answer
}

/// The `reason` for a frame rmodbus refused.
fn refusal(e: ErrorKind, proto: ModbusProto) -> String {
    let what = match (e, proto) {
        (ErrorKind::FrameCRCError, ModbusProto::Ascii) => "LRC error".to_string(),
        (ErrorKind::FrameCRCError, _) => "CRC error".to_string(),
        (ErrorKind::FrameBroken, _) => "frame broken (too short for its function)".to_string(),
        _ => e.to_string(),
    };
    format!("{what} (rmodbus ErrorKind::{e:?})")
}

fn rmodbus_error(context: &str, e: ErrorKind) -> Failure {
    bad(format!("{context}: rmodbus ErrorKind::{e:?} ({e})"))
}

/// Big-endian register values of `data`; an odd last byte is left out.
fn words(data: &[u8]) -> Vec<u16> {
    data.chunks_exact(2)
        .map(|p| u16::from_be_bytes([p[0], p[1]]))
        .collect()
}

fn hex4_list(values: &[u16]) -> Vec<String> {
    values.iter().map(|v| hex4(*v)).collect()
}

// ---------------------------------------------------------------- hello

fn hello(request: &Request) -> Outcome {
    let protocol = request.protocol.as_ref().and_then(Value::as_u64);
    if protocol != Some(PROTOCOL) {
        return Err(bad(format!(
            "protocol {} is not spoken here; rmodbus-adapter speaks protocol {PROTOCOL}",
            request
                .protocol
                .as_ref()
                .map_or_else(|| "(none)".to_string(), Value::to_string)
        )));
    }
    Ok(object(json!({
        "protocol": PROTOCOL,
        "adapter": "rmodbus-adapter",
        "implementation": "rmodbus",
        "version": RMODBUS_VERSION,
        "supports": ["decode", "encode", "crc", "lrc"],
    })))
}

// ---------------------------------------------------------------- crc and lrc

/// The checksum rmodbus appends to `data`: two CRC bytes (low first) for RTU, one LRC byte
/// for ASCII.
///
/// rmodbus 0.13 has no public CRC or LRC function (`calc_crc16` and `calc_lrc` are private).
/// Its public `ModbusFrame::finalize_response` applies them to the frame's response buffer
/// (a public field): with no Modbus error set it appends the CRC (RTU) or LRC (ASCII) of
/// whatever the buffer holds. That is rmodbus's own checksum code, reached through its API.
fn rmodbus_checksum(data: &[u8], proto: ModbusProto) -> Result<Vec<u8>, Failure> {
    let mut response: Vec<u8> = Vec::new();
    {
        let mut frame = ModbusFrame::new(0, &[], proto, &mut response);
        frame.response.extend_from_slice(data);
        frame.finalize_response().map_err(|e| {
            unsupported(format!(
                "rmodbus's finalize_response refused {} bytes: ErrorKind::{e:?} ({e}); \
                 it checksums at most 255 bytes",
                data.len()
            ))
        })?;
    }
    Ok(response.get(data.len()..).unwrap_or_default().to_vec())
}

fn data_of(request: &Request) -> Result<Vec<u8>, Failure> {
    parse_hex(
        request
            .data
            .as_deref()
            .ok_or_else(|| bad("the request has no \"data\""))?,
    )
}

fn crc(request: &Request) -> Outcome {
    let data = data_of(request)?;
    let sum = rmodbus_checksum(&data, ModbusProto::Rtu)?;
    match sum.as_slice() {
        [lo, hi] => Ok(object(json!({"crc": hex4(u16::from_le_bytes([*lo, *hi]))}))),
        other => Err(bad(format!(
            "rmodbus appended {} bytes, not a 2-byte CRC",
            other.len()
        ))),
    }
}

fn lrc(request: &Request) -> Outcome {
    let data = data_of(request)?;
    let sum = rmodbus_checksum(&data, ModbusProto::Ascii)?;
    match sum.as_slice() {
        [l] => Ok(object(json!({"lrc": hex2(*l)}))),
        other => Err(bad(format!(
            "rmodbus appended {} bytes, not a 1-byte LRC",
            other.len()
        ))),
    }
}

// ---------------------------------------------------------------- decode

fn decode(request: &Request) -> Outcome {
    let mode = mode_of(request)?;
    let direction = direction_of(request)?;
    let bytes = parse_hex(
        request
            .frame
            .as_deref()
            .ok_or_else(|| bad("the request has no \"frame\""))?,
    )?;
    let proto = mode.proto();
    let binary = match mode {
        Mode::Rtu => bytes,
        Mode::Ascii => {
            // rmodbus's ASCII support is this one function: characters to binary (address,
            // PDU and LRC byte). The LRC is checked later, by the server or client parser.
            let mut buf: ModbusFrameBuf = [0; 256];
            match rmodbus::parse_ascii_frame(&bytes, bytes.len(), &mut buf, 0) {
                Ok(n) => buf[..usize::from(n)].to_vec(),
                Err(e) => {
                    return Ok(rejected(format!(
                        "rmodbus parse_ascii_frame: ErrorKind::{e:?} ({e})"
                    )))
                }
            }
        }
    };
    match direction {
        Direction::Request => decode_request(&binary, proto),
        Direction::Response => decode_response(&binary, proto),
    }
}

/// A request, decoded as an rmodbus slave does: `ModbusFrame::parse`.
fn decode_request(binary: &[u8], proto: ModbusProto) -> Outcome {
    // The adapter plays the slave the frame is addressed to, with rmodbus's default
    // broadcast handling (address 0: writes are processed without a reply, reads ignored).
    let unit = binary.first().copied().unwrap_or(0);
    let mut response: Vec<u8> = Vec::new();
    let mut frame = ModbusFrame::new(unit, binary, proto, &mut response);
    if let Err(e) = frame.parse() {
        return Ok(rejected(refusal(e, proto)));
    }
    let function = frame.responding_to_fn;
    if ModbusFunction::try_from(function).is_err() {
        // rmodbus implements 01H-06H, 0FH and 10H only. For any other function parse()
        // returns Ok before looking at the CRC/LRC and sets exception 01 as the answer.
        let reaction =
            if frame.response_required && frame.error == Some(ModbusErrorCode::IllegalFunction) {
                "would answer exception 01 (illegal function)"
            } else {
                "would not answer"
            };
        return Err(unsupported(format!(
            "rmodbus {RMODBUS_VERSION} does not implement function {function:02X}H: \
             ModbusFrame::parse returned Ok and rmodbus {reaction}; it checks no CRC/LRC \
             for functions it does not implement"
        )));
    }
    if let Some(code) = frame.error {
        return Ok(rejected(format!(
            "rmodbus answers exception {:02X} itself and does not hand the request to the \
             application (function {function:02X}H, count {})",
            code.byte(),
            frame.count
        )));
    }
    if !frame.processing_required {
        // rmodbus 0.13 returns Ok without looking further (no CRC/LRC check either) for a
        // read addressed to a broadcast unit.
        return Ok(rejected(format!(
            "rmodbus ignores the frame (function {function:02X}H addressed to {unit:02X}): \
             a read sent to the broadcast address"
        )));
    }
    let (start, count) = (frame.reg, frame.count);
    let mut note = None;
    let msg = match frame.func {
        ModbusFunction::GetHoldings => message(
            unit,
            function,
            "read-request",
            json!({"start": hex4(start), "count": count}),
        ),
        ModbusFunction::SetHolding | ModbusFunction::SetHoldingsBulk => {
            let data = match frame.get_external_write() {
                Ok(Write::Words(w)) => w.data.to_vec(),
                Ok(Write::Bits(_)) => {
                    return Err(bad("rmodbus described a register write as a coil write"))
                }
                Err(e) => return Err(rmodbus_error("get_external_write", e)),
            };
            let values = words(&data);
            if frame.func == ModbusFunction::SetHolding {
                let value = values.first().copied().unwrap_or_default();
                message(
                    unit,
                    function,
                    "write-single",
                    json!({"register": hex4(start), "value": hex4(value)}),
                )
            } else {
                if data.len() != 2 * usize::from(count) {
                    note = Some(format!(
                        "rmodbus accepted a byte count of {} for {count} registers",
                        data.len()
                    ));
                }
                message(
                    unit,
                    function,
                    "write-multiple-request",
                    json!({"start": hex4(start), "count": count, "byte_count": data.len(),
                           "values": hex4_list(&values)}),
                )
            }
        }
        // 01H, 02H, 04H, 05H, 0FH: not among the suite's kinds; the gate compares address
        // and function only. Start and count are rmodbus's reading.
        _ => message(
            unit,
            function,
            "other",
            json!({"start": hex4(start), "count": count}),
        ),
    };
    Ok(accepted(msg, note))
}

/// A response, decoded as an rmodbus master does: `ModbusRequest::parse_*`.
///
/// rmodbus's client parses a response only against the `ModbusRequest` it answers (unit,
/// function and, for reads, the register count). The adapter sets one up from the frame
/// itself: unit and function from its first two bytes, count from its byte count, i.e. the
/// request this frame would be a right answer to. CRC/LRC, unit, function, exception and
/// byte-count checks are rmodbus's; for write responses rmodbus returns the data bytes
/// (`parse_slice`) and the adapter names the fields.
fn decode_response(binary: &[u8], proto: ModbusProto) -> Outcome {
    let unit = binary.first().copied().unwrap_or(0);
    let Some(&wire_function) = binary.get(1) else {
        // Too short to name a function: any request will do for rmodbus to refuse it.
        let req = ModbusRequest::new(unit, proto);
        return match req.parse_ok(binary) {
            Err(e) => Ok(rejected(refusal(e, proto))),
            Ok(()) => Err(bad("rmodbus parse_ok accepted a frame of under two bytes")),
        };
    };
    let function = wire_function & 0x7F;
    let Ok(func) = ModbusFunction::try_from(function) else {
        return Err(unsupported(format!(
            "rmodbus {RMODBUS_VERSION}'s client has no function {function:02X}H: a \
             ModbusRequest for it cannot be made, so its responses cannot be parsed"
        )));
    };
    let mut req = ModbusRequest::new(unit, proto);
    req.func = func;

    if wire_function & 0x80 != 0 {
        // parse_response takes any function byte other than the request's as an exception
        // and returns ErrorKind::from_modbus_error(code) after checking the CRC/LRC.
        return match req.parse_ok(binary) {
            Ok(()) => Err(bad(
                "rmodbus parse_ok returned Ok for an exception response",
            )),
            Err(e @ (ErrorKind::FrameCRCError | ErrorKind::FrameBroken)) => {
                Ok(rejected(refusal(e, proto)))
            }
            Err(e) => {
                let code = binary.get(2).copied().unwrap_or_default();
                let reported = e.to_modbus_error().ok().map(|c| c.byte());
                let note = (reported != Some(code)).then(|| {
                    format!(
                        "rmodbus reports exception code {code:02X} as ErrorKind::{e:?}{}; the \
                         adapter reads the code from the checked frame",
                        reported.map_or_else(String::new, |r| format!(" (code {r:02X})"))
                    )
                });
                Ok(accepted(
                    message(
                        unit,
                        wire_function,
                        "exception",
                        json!({"exception_function": hex2(function), "code": hex2(code)}),
                    ),
                    note,
                ))
            }
        };
    }

    match func {
        ModbusFunction::GetHoldings | ModbusFunction::GetInputs => {
            let byte_count = binary.get(2).copied().unwrap_or_default();
            // The request this answers asked for as many registers as the byte count says.
            req.count = u16::from(byte_count) / 2;
            let mut values: Vec<u16> = Vec::new();
            if let Err(e) = req.parse_u16(binary, &mut values) {
                return Ok(rejected(refusal(e, proto)));
            }
            let data_len = req.parse_slice(binary).map(<[u8]>::len).unwrap_or_default();
            let note = (data_len != usize::from(byte_count)).then(|| {
                format!("rmodbus accepted a byte count of {byte_count} with {data_len} data bytes")
            });
            let kind = if func == ModbusFunction::GetHoldings {
                "read-response"
            } else {
                "other"
            };
            Ok(accepted(
                message(
                    unit,
                    wire_function,
                    kind,
                    json!({"byte_count": byte_count, "values": hex4_list(&values)}),
                ),
                note,
            ))
        }
        ModbusFunction::SetHolding
        | ModbusFunction::SetHoldingsBulk
        | ModbusFunction::SetCoil
        | ModbusFunction::SetCoilsBulk => {
            let data = match req.parse_slice(binary) {
                Ok(d) => d.to_vec(),
                Err(e) => return Ok(rejected(refusal(e, proto))),
            };
            let note = (data.len() != 4).then(|| {
                format!(
                    "rmodbus accepted a {function:02X}H response with {} data bytes (4 expected); \
                     its client does not check the length of write responses",
                    data.len()
                )
            });
            let first = data
                .get(0..2)
                .map(|p| hex4(u16::from_be_bytes([p[0], p[1]])));
            let second = data.get(2..4).map(|p| u16::from_be_bytes([p[0], p[1]]));
            let (kind, fields) = match func {
                ModbusFunction::SetHolding => (
                    "write-single",
                    json!({"register": first, "value": second.map(hex4)}),
                ),
                ModbusFunction::SetHoldingsBulk => (
                    "write-multiple-response",
                    json!({"start": first, "count": second}),
                ),
                _ => ("other", json!({"data": hex_bytes(&data)})),
            };
            Ok(accepted(message(unit, wire_function, kind, fields), note))
        }
        ModbusFunction::GetCoils | ModbusFunction::GetDiscretes => {
            let data = match req.parse_slice(binary) {
                Ok(d) => d.to_vec(),
                Err(e) => return Ok(rejected(refusal(e, proto))),
            };
            Ok(accepted(
                message(
                    unit,
                    wire_function,
                    "other",
                    json!({"byte_count": binary.get(2), "data": hex_bytes(&data)}),
                ),
                None,
            ))
        }
    }
}

// ---------------------------------------------------------------- encode

fn encode(request: &Request) -> Outcome {
    let mode = mode_of(request)?;
    let direction = direction_of(request)?;
    let message: Message = serde_json::from_value(
        request
            .message
            .clone()
            .ok_or_else(|| bad("the request has no \"message\""))?,
    )
    .map_err(|e| bad(format!("bad message: {e}")))?;
    let address = parse_hex2(&message.address, "address")?;
    let function = parse_hex2(&message.function, "function")?;
    let proto = mode.proto();
    let binary = match direction {
        Direction::Request => encode_request(address, function, &message, proto)?,
        Direction::Response => encode_response(address, function, &message, proto)?,
    };
    let frame = match mode {
        Mode::Rtu => binary,
        Mode::Ascii => {
            let mut chars: Vec<u8> = Vec::new();
            rmodbus::generate_ascii_frame(&binary, &mut chars)
                .map_err(|e| rmodbus_error("generate_ascii_frame", e))?;
            chars
        }
    };
    Ok(object(json!({"frame": hex_bytes(&frame)})))
}

/// A request, built as an rmodbus master does: `ModbusRequest::generate_*` (binary frame
/// with CRC for RTU, with LRC for ASCII).
fn encode_request(
    address: u8,
    function: u8,
    message: &Message,
    proto: ModbusProto,
) -> Result<Vec<u8>, Failure> {
    let f = &message.fields;
    let mut req = ModbusRequest::new(address, proto);
    let mut out: Vec<u8> = Vec::new();
    let result = match (message.kind.as_str(), function) {
        ("read-request", 0x01..=0x04) => {
            let start = field_hex4(f, "start")?;
            let count = u16_of(field_number(f, "count")?, "count")?;
            match function {
                0x01 => req.generate_get_coils(start, count, &mut out),
                0x02 => req.generate_get_discretes(start, count, &mut out),
                0x03 => req.generate_get_holdings(start, count, &mut out),
                _ => req.generate_get_inputs(start, count, &mut out),
            }
        }
        ("write-single", 0x06) => {
            let register = field_hex4(f, "register")?;
            let value = field_hex4(f, "value")?;
            req.generate_set_holding(register, value, &mut out)
        }
        ("write-multiple-request", 0x10) => {
            let start = field_hex4(f, "start")?;
            let values = field_values(f)?;
            // generate_set_holdings_bulk derives count and byte count from the values.
            let count = field_number(f, "count")?;
            let byte_count = field_number(f, "byte_count")?;
            if count != values.len() as u64 || byte_count != 2 * values.len() as u64 {
                return Err(unsupported(format!(
                    "rmodbus derives count and byte count from the values ({} values): it \
                     cannot encode count {count} with byte count {byte_count}",
                    values.len()
                )));
            }
            req.generate_set_holdings_bulk(start, &values, &mut out)
        }
        ("loop-back", _) => {
            return Err(unsupported(format!(
                "rmodbus {RMODBUS_VERSION} has no 08H (diagnostics / loop-back)"
            )))
        }
        ("read-response" | "write-multiple-response" | "exception", _) => {
            return Err(bad(format!(
                "kind {} is a response layout, not a request",
                message.kind
            )))
        }
        (kind, _) => {
            return Err(unsupported(format!(
                "rmodbus-adapter encodes no {kind} request with function {function:02X}H"
            )))
        }
    };
    result.map_err(|e| rmodbus_error("ModbusRequest::generate_*", e))?;
    Ok(out)
}

/// A minimal request for `function`, built by rmodbus's client, for rmodbus's server to
/// answer. For a function rmodbus does not implement its server reads nothing but the
/// address and function bytes (and answers exception 01), so those two bytes are the
/// request.
fn synthesize_request(address: u8, function: u8, proto: ModbusProto) -> Result<Vec<u8>, Failure> {
    let mut req = ModbusRequest::new(address, proto);
    let mut out: Vec<u8> = Vec::new();
    let result = match ModbusFunction::try_from(function) {
        Ok(ModbusFunction::GetCoils) => req.generate_get_coils(0, 1, &mut out),
        Ok(ModbusFunction::GetDiscretes) => req.generate_get_discretes(0, 1, &mut out),
        Ok(ModbusFunction::GetHoldings) => req.generate_get_holdings(0, 1, &mut out),
        Ok(ModbusFunction::GetInputs) => req.generate_get_inputs(0, 1, &mut out),
        Ok(ModbusFunction::SetCoil) => req.generate_set_coil(0, 0u8, &mut out),
        Ok(ModbusFunction::SetHolding) => req.generate_set_holding(0, 0, &mut out),
        Ok(ModbusFunction::SetCoilsBulk) => req.generate_set_coils_bulk(0, &[0u8], &mut out),
        Ok(ModbusFunction::SetHoldingsBulk) => req.generate_set_holdings_bulk(0, &[0], &mut out),
        Err(_) => {
            out = vec![address, function];
            Ok(())
        }
    };
    result.map_err(|e| rmodbus_error("ModbusRequest::generate_*", e))?;
    Ok(out)
}

/// Runs rmodbus's server on `request` (a binary frame with its checksum), lets `respond`
/// fill in the answer, and has `finalize_response` add the CRC/LRC.
fn serve(
    address: u8,
    request: &[u8],
    proto: ModbusProto,
    respond: impl FnOnce(&mut ModbusFrame<'_, Vec<u8>>) -> Result<(), Failure>,
) -> Result<Vec<u8>, Failure> {
    let mut response: Vec<u8> = Vec::new();
    {
        let mut frame =
            ModbusFrame::new(address, request, proto, &mut response).with_broadcast_units(&[]);
        frame.parse().map_err(|e| {
            rmodbus_error(
                "rmodbus's server refused the request the adapter built with its client",
                e,
            )
        })?;
        respond(&mut frame)?;
        frame
            .finalize_response()
            .map_err(|e| rmodbus_error("finalize_response", e))?;
    }
    Ok(response)
}

fn refuse_if_error(frame: &ModbusFrame<'_, Vec<u8>>, what: &str) -> Result<(), Failure> {
    match frame.error {
        Some(code) => Err(unsupported(format!(
            "rmodbus's server answers {what} with exception {:02X}",
            code.byte()
        ))),
        None => Ok(()),
    }
}

/// The server's side of a write (`what`) that a device takes: refused where rmodbus's
/// server answers it with an exception, else its values taken and the response built.
fn accept_write(frame: &mut ModbusFrame<'_, Vec<u8>>, what: &str) -> Result<(), Failure> {
    refuse_if_error(frame, what)?;
    frame
        .get_external_write()
        .map_err(|e| rmodbus_error("get_external_write", e))?;
    frame
        .process_external_write(Ok(()))
        .map_err(|e| rmodbus_error("process_external_write", e))
}

/// A response, built as an rmodbus slave does: its server parses a request (made by its
/// client) and answers it through the "external" read/write API, then `finalize_response`.
fn encode_response(
    address: u8,
    function: u8,
    message: &Message,
    proto: ModbusProto,
) -> Result<Vec<u8>, Failure> {
    let f = &message.fields;
    match (message.kind.as_str(), function) {
        ("read-response", 0x03 | 0x04) => {
            let values = field_values(f)?;
            let byte_count = field_number(f, "byte_count")?;
            if byte_count != 2 * values.len() as u64 {
                return Err(unsupported(format!(
                    "rmodbus's server derives the byte count from the values ({} values): it \
                     cannot encode byte count {byte_count}",
                    values.len()
                )));
            }
            let n = u16_of(values.len() as u64, "number of values")?;
            let mut req = ModbusRequest::new(address, proto);
            let mut request = Vec::new();
            if function == 0x03 {
                req.generate_get_holdings(0, n, &mut request)
            } else {
                req.generate_get_inputs(0, n, &mut request)
            }
            .map_err(|e| rmodbus_error("ModbusRequest::generate_get_*", e))?;
            serve(address, &request, proto, |frame| {
                refuse_if_error(frame, &format!("a read of {n} registers"))?;
                match frame.get_external_read() {
                    Ok(Read::Words(w)) => {
                        for (slot, v) in w.buf.chunks_exact_mut(2).zip(&values) {
                            slot.copy_from_slice(&v.to_be_bytes());
                        }
                    }
                    Ok(Read::Bits(_)) => {
                        return Err(bad("rmodbus described a register read as a coil read"))
                    }
                    Err(e) => return Err(rmodbus_error("get_external_read", e)),
                }
                frame
                    .process_external_read(Ok(()))
                    .map_err(|e| rmodbus_error("process_external_read", e))
            })
        }
        ("write-single", 0x06) => {
            let register = field_hex4(f, "register")?;
            let value = field_hex4(f, "value")?;
            let mut request = Vec::new();
            ModbusRequest::new(address, proto)
                .generate_set_holding(register, value, &mut request)
                .map_err(|e| rmodbus_error("generate_set_holding", e))?;
            serve(address, &request, proto, |frame| {
                accept_write(frame, "this write")
            })
        }
        ("write-multiple-response", 0x10) => {
            let start = field_hex4(f, "start")?;
            let count = field_number(f, "count")?;
            let n = usize::try_from(count)
                .ok()
                .filter(|n| *n <= 125)
                .ok_or_else(|| {
                    unsupported(format!(
                        "rmodbus's client builds no 10H request for {count} registers (at most 125)"
                    ))
                })?;
            let mut request = Vec::new();
            ModbusRequest::new(address, proto)
                .generate_set_holdings_bulk(start, &vec![0u16; n], &mut request)
                .map_err(|e| rmodbus_error("generate_set_holdings_bulk", e))?;
            serve(address, &request, proto, |frame| {
                accept_write(frame, &format!("a write of {count} registers"))
            })
        }
        ("exception", _) => {
            let exception_function = field_hex2(f, "exception_function")?;
            let code = field_hex2(f, "code")?;
            if exception_function >= 0x80 || function != exception_function | 0x80 {
                return Err(bad(format!(
                    "function {function:02X} is not exception_function {exception_function:02X} + 80H"
                )));
            }
            let code = match ModbusErrorCode::try_from(code) {
                Ok(ModbusErrorCode::NoError) | Err(_) => {
                    return Err(unsupported(format!(
                        "rmodbus's server has no exception code {code:02X} \
                         (ModbusErrorCode covers 01..0A)"
                    )))
                }
                Ok(c) => c,
            };
            let request = synthesize_request(address, exception_function, proto)?;
            serve(address, &request, proto, |frame| {
                // The public `error` field is what finalize_response turns into an
                // exception frame (set_modbus_error_if_unset would not override the 01
                // rmodbus sets itself for a function it does not implement).
                frame.response.clear();
                frame.error = Some(code);
                Ok(())
            })
        }
        ("loop-back", _) => Err(unsupported(format!(
            "rmodbus {RMODBUS_VERSION} has no 08H (diagnostics / loop-back)"
        ))),
        ("read-request" | "write-multiple-request", _) => Err(bad(format!(
            "kind {} is a request layout, not a response",
            message.kind
        ))),
        (kind, _) => Err(unsupported(format!(
            "rmodbus-adapter encodes no {kind} response with function {function:02X}H"
        ))),
    }
}
