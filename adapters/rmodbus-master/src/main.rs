//! Master adapter for rmodbus's client (`rmodbus::client::ModbusRequest`) over the
//! `serialport` crate, for `conformance gate --master` (adapters/PROTOCOL.md, role master).
//!
//! rmodbus is a sans-I/O library: its client builds a request (`generate_*`), tells how
//! long the reply is (`guess_response_frame_len`) and checks and parses it (`parse_*`); the
//! application moves the bytes. The adapter moves them the way rmodbus's own example
//! (`examples/rtuclient.rs`, and the README's "RTU clients" paragraph) does: write the
//! request, read the unit id and function (2 bytes), an exception is 5 bytes in all,
//! otherwise one more byte and `guess_response_frame_len` for the rest. Every read is
//! bounded by the master's `timeout_ms` for the whole reply. ASCII: `generate_ascii_frame`
//! on the way out, bytes up to LF and `parse_ascii_frame` on the way in. Like the example,
//! the adapter does not clear the input before a request and does not retry (an `open`
//! answers `retries: 0` whatever was asked). Set
//! `RMODBUS_MASTER_CLEAR_INPUT=1` to clear the port's input before each request.

use std::io::{BufRead, Read, Write};
use std::time::{Duration, Instant};

use rmodbus::client::ModbusRequest;
use rmodbus::{
    generate_ascii_frame, guess_response_frame_len, parse_ascii_frame, ErrorKind, ModbusProto,
};
use serde_json::{json, Map, Value};

enum Line {
    Serial(Box<dyn serialport::SerialPort>),
    Tcp(std::net::TcpStream),
}

impl Line {
    fn set_timeout(&mut self, d: Duration) -> std::io::Result<()> {
        let d = d.max(Duration::from_millis(1));
        match self {
            Line::Serial(p) => p.set_timeout(d).map_err(std::io::Error::from),
            Line::Tcp(s) => s.set_read_timeout(Some(d)),
        }
    }
    fn clear_input(&mut self) {
        match self {
            Line::Serial(p) => {
                let _ = p.clear(serialport::ClearBuffer::Input);
            }
            Line::Tcp(s) => {
                let _ = s.set_nonblocking(true);
                let mut b = [0u8; 512];
                while matches!(s.read(&mut b), Ok(n) if n > 0) {}
                let _ = s.set_nonblocking(false);
            }
        }
    }
}

impl Read for Line {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        match self {
            Line::Serial(p) => p.read(buf),
            Line::Tcp(s) => s.read(buf),
        }
    }
}

impl Write for Line {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        match self {
            Line::Serial(p) => p.write(buf),
            Line::Tcp(s) => s.write(buf),
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        match self {
            Line::Serial(p) => p.flush(),
            Line::Tcp(s) => s.flush(),
        }
    }
}

struct Master {
    line: Line,
    proto: ModbusProto,
    timeout: Duration,
    clear_input: bool,
}

/// What went wrong in one exchange, as the protocol's answer.
enum Failure {
    Timeout(String),
    Io(String),
    Rmodbus(ErrorKind),
}

impl Master {
    /// Reads exactly `buf.len()` bytes before `deadline`.
    fn read_exact_by(&mut self, buf: &mut [u8], deadline: Instant) -> Result<(), Failure> {
        let mut got = 0;
        while got < buf.len() {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Err(Failure::Timeout(format!(
                    "{got} of {} bytes before the timeout",
                    buf.len()
                )));
            }
            self.line
                .set_timeout(left)
                .map_err(|e| Failure::Io(e.to_string()))?;
            match self.line.read(&mut buf[got..]) {
                Ok(0) => return Err(Failure::Io("end of stream".into())),
                Ok(n) => got += n,
                Err(e)
                    if e.kind() == std::io::ErrorKind::TimedOut
                        || e.kind() == std::io::ErrorKind::WouldBlock =>
                {
                    return Err(Failure::Timeout(format!(
                        "{got} of {} bytes before the timeout",
                        buf.len()
                    )))
                }
                Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
                Err(e) => return Err(Failure::Io(e.to_string())),
            }
        }
        Ok(())
    }

    /// Sends the request; reads the reply (none for a broadcast) as rmodbus's example does.
    fn exchange(
        &mut self,
        req: &ModbusRequest,
        frame: &[u8],
        broadcast: bool,
    ) -> Result<Vec<u8>, Failure> {
        if self.clear_input {
            self.line.clear_input();
        }
        let wire = if self.proto == ModbusProto::Ascii {
            let mut a = Vec::new();
            generate_ascii_frame(frame, &mut a).map_err(Failure::Rmodbus)?;
            a
        } else {
            frame.to_vec()
        };
        self.line
            .write_all(&wire)
            .map_err(|e| Failure::Io(e.to_string()))?;
        let _ = self.line.flush();
        let _ = req;
        if broadcast {
            return Ok(Vec::new());
        }
        let deadline = Instant::now() + self.timeout;
        if self.proto == ModbusProto::Ascii {
            // Up to and including LF.
            let mut text = Vec::new();
            let mut b = [0u8; 1];
            loop {
                self.read_exact_by(&mut b, deadline)?;
                text.push(b[0]);
                if b[0] == b'\n' || text.len() > 600 {
                    break;
                }
            }
            let mut bin = [0u8; 256];
            let n = parse_ascii_frame(&text, text.len(), &mut bin, 0).map_err(Failure::Rmodbus)?;
            return Ok(bin[..n as usize].to_vec());
        }
        let mut response = vec![0u8; 2];
        self.read_exact_by(&mut response, deadline)?;
        let total = if response[1] & 0x80 != 0 {
            5
        } else {
            response.resize(3, 0);
            self.read_exact_by(&mut response[2..], deadline)?;
            usize::from(
                guess_response_frame_len(&response, ModbusProto::Rtu).map_err(Failure::Rmodbus)?,
            )
        };
        if response.len() < total {
            let had = response.len();
            response.resize(total, 0);
            self.read_exact_by(&mut response[had..], deadline)?;
        }
        Ok(response)
    }
}

fn exception_code(e: ErrorKind) -> Option<u8> {
    // rmodbus keeps no code, only its ErrorKind (ErrorKind::from_modbus_error): back to the
    // code that kind stands for in rmodbus 0.13 (09H and 10H as rmodbus maps them).
    Some(match e {
        ErrorKind::IllegalFunction => 0x01,
        ErrorKind::IllegalDataAddress => 0x02,
        ErrorKind::IllegalDataValue => 0x03,
        ErrorKind::SlaveDeviceFailure => 0x04,
        ErrorKind::Acknowledge => 0x05,
        ErrorKind::SlaveDeviceBusy => 0x06,
        ErrorKind::NegativeAcknowledge => 0x07,
        ErrorKind::MemoryParityError => 0x08,
        ErrorKind::GatewayPathUnavailable => 0x09,
        ErrorKind::GatewayTargetFailed => 0x10,
        _ => return None,
    })
}

fn failure(f: Failure) -> Value {
    match f {
        Failure::Timeout(m) => {
            json!({"ok": true, "result": "error", "kind": "timeout", "message": m})
        }
        Failure::Io(m) => json!({"ok": true, "result": "error", "kind": "other", "message": m}),
        Failure::Rmodbus(e) => match exception_code(e) {
            Some(code) => json!({"ok": true, "result": "exception", "code": format!("{code:02X}"),
                                 "message": format!("{e:?}: {e}")}),
            None => {
                let kind = match e {
                    ErrorKind::FrameCRCError => "checksum",
                    ErrorKind::FrameBroken | ErrorKind::OOB | ErrorKind::UnknownError => {
                        "invalid-frame"
                    }
                    _ => "other",
                };
                json!({"ok": true, "result": "error", "kind": kind, "message": format!("{e:?}: {e}")})
            }
        },
    }
}

fn h4(v: u16) -> String {
    format!("{v:04X}")
}

fn hex4(v: &Value, key: &str) -> Result<u16, String> {
    let s = v
        .get(key)
        .and_then(Value::as_str)
        .ok_or(format!("field {key} missing"))?;
    u16::from_str_radix(s.trim_end_matches(['H', 'h']), 16).map_err(|e| format!("field {key}: {e}"))
}

fn int(v: &Value, key: &str) -> Result<u64, String> {
    v.get(key)
        .and_then(Value::as_u64)
        .ok_or(format!("field {key} missing"))
}

fn open(req: &Value) -> Result<(Master, Value), Value> {
    let proto = match req.get("mode").and_then(Value::as_str).unwrap_or("rtu") {
        "rtu" => ModbusProto::Rtu,
        "ascii" => ModbusProto::Ascii,
        m => {
            return Err(json!({"ok": false, "error": "unsupported", "detail": format!("mode {m}")}))
        }
    };
    let timeout = Duration::from_millis(int(req, "timeout_ms").unwrap_or(1000));
    let line = req.get("line").cloned().unwrap_or(Value::Null);
    let kind = line.get("kind").and_then(Value::as_str).unwrap_or("");
    let bad = |e: String| json!({"ok": false, "error": e});
    let line = match kind {
        "pty" => {
            let path = line.get("path").and_then(Value::as_str).unwrap_or("");
            let parity = match req.get("parity").and_then(Value::as_str).unwrap_or("N") {
                p if p.starts_with(['E', 'e']) => serialport::Parity::Even,
                p if p.starts_with(['O', 'o']) => serialport::Parity::Odd,
                _ => serialport::Parity::None,
            };
            let data_bits = if int(req, "data_bits").unwrap_or(8) == 7 {
                serialport::DataBits::Seven
            } else {
                serialport::DataBits::Eight
            };
            let stop_bits = if int(req, "stop_bits").unwrap_or(1) == 2 {
                serialport::StopBits::Two
            } else {
                serialport::StopBits::One
            };
            let port = serialport::new(path, int(req, "baud").unwrap_or(19200) as u32)
                .parity(parity)
                .data_bits(data_bits)
                .stop_bits(stop_bits)
                .flow_control(serialport::FlowControl::None)
                .timeout(timeout)
                .open()
                .map_err(|e| bad(format!("serialport: {e}")))?;
            Line::Serial(port)
        }
        "tcp-rtu" => {
            let host = line
                .get("host")
                .and_then(Value::as_str)
                .unwrap_or("127.0.0.1");
            let port = int(&line, "port").unwrap_or(502);
            let s = std::net::TcpStream::connect((host, port as u16))
                .map_err(|e| bad(format!("connect: {e}")))?;
            let _ = s.set_nodelay(true);
            Line::Tcp(s)
        }
        k => {
            return Err(json!({"ok": false, "error": "unsupported", "detail": format!("line {k}")}))
        }
    };
    let clear_input = std::env::var_os("RMODBUS_MASTER_CLEAR_INPUT").is_some();
    Ok((
        Master {
            line,
            proto,
            timeout,
            clear_input,
        },
        // No retries (the example sends once): 0, whatever was asked.
        json!({"ok": true, "timeout_ms": timeout.as_millis() as u64, "retries": 0}),
    ))
}

fn operate(m: &mut Master, op: &str, req: &Value) -> Result<Value, String> {
    let unit = int(req, "unit")? as u8;
    let mut mreq = ModbusRequest::new(unit, m.proto);
    let mut frame: Vec<u8> = Vec::new();
    let gen =
        |r: Result<(), ErrorKind>| r.map_err(|e| format!("rmodbus refused the request: {e:?}"));
    match op {
        "read" => gen(mreq.generate_get_holdings(
            hex4(req, "start")?,
            int(req, "count")? as u16,
            &mut frame,
        ))?,
        "write-single" => {
            gen(mreq.generate_set_holding(hex4(req, "register")?, hex4(req, "value")?, &mut frame))?
        }
        "write-multiple" => {
            let values: Vec<u16> = req
                .get("values")
                .and_then(Value::as_array)
                .ok_or("field values missing")?
                .iter()
                .map(|v| {
                    v.as_str()
                        .and_then(|s| u16::from_str_radix(s, 16).ok())
                        .ok_or("bad value")
                })
                .collect::<Result<_, _>>()?;
            gen(mreq.generate_set_holdings_bulk(hex4(req, "start")?, &values, &mut frame))?
        }
        _ => unreachable!(),
    }
    let broadcast = unit == 0;
    let response = match m.exchange(&mreq, &frame, broadcast) {
        Ok(r) => r,
        Err(f) => return Ok(failure(f)),
    };
    if broadcast {
        return Ok(json!({"ok": true, "result": "done"}));
    }
    Ok(match op {
        "read" => {
            let mut values: Vec<u16> = Vec::new();
            match mreq.parse_u16(&response, &mut values) {
                Ok(()) => json!({"ok": true, "result": "values",
                                 "values": values.into_iter().map(h4).collect::<Vec<_>>()}),
                Err(e) => failure(Failure::Rmodbus(e)),
            }
        }
        _ => match mreq.parse_ok(&response) {
            Ok(()) => json!({"ok": true, "result": "done"}),
            Err(e) => failure(Failure::Rmodbus(e)),
        },
    })
}

fn main() {
    let stdin = std::io::stdin();
    let mut out = std::io::stdout().lock();
    let mut master: Option<Master> = None;
    for line in stdin.lock().lines() {
        let Ok(line) = line else { break };
        let line = line.trim();
        if line.is_empty() {
            continue;
        }
        let req: Value = match serde_json::from_str(line) {
            Ok(v @ Value::Object(_)) => v,
            _ => {
                let _ = writeln!(
                    out,
                    "{}",
                    json!({"id": null, "ok": false, "error": "bad request: not a JSON object"})
                );
                let _ = out.flush();
                continue;
            }
        };
        let op = req
            .get("op")
            .and_then(Value::as_str)
            .unwrap_or("")
            .to_string();
        let mut answer = match op.as_str() {
            "hello" => {
                if req.get("protocol").and_then(Value::as_u64) == Some(1)
                    && req.get("role").and_then(Value::as_str) == Some("master")
                {
                    json!({"ok": true, "protocol": 1, "role": "master", "adapter": "rmodbus-master",
                           "implementation": "rmodbus", "version": "0.13.0",
                           "supports": ["read", "write-single", "write-multiple", "broadcast"],
                           "lines": ["pty", "tcp-rtu"], "modes": ["rtu", "ascii"]})
                } else {
                    json!({"ok": false, "error": "this adapter speaks protocol 1, role master"})
                }
            }
            "open" => {
                master = None;
                match open(&req) {
                    Ok((m, a)) => {
                        master = Some(m);
                        a
                    }
                    Err(a) => a,
                }
            }
            "close" => {
                master = None;
                json!({"ok": true})
            }
            "read" | "write-single" | "write-multiple" => match master.as_mut() {
                None => json!({"ok": false, "error": "not open"}),
                Some(m) => match std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                    operate(m, &op, &req)
                })) {
                    Ok(Ok(a)) => a,
                    Ok(Err(e)) => json!({"ok": false, "error": format!("bad request: {e}")}),
                    Err(p) => {
                        let msg = p
                            .downcast_ref::<String>()
                            .cloned()
                            .or_else(|| p.downcast_ref::<&str>().map(|s| s.to_string()))
                            .unwrap_or_default();
                        json!({"ok": true, "result": "raised", "type": "panic", "message": msg})
                    }
                },
            },
            "loop-back" => {
                json!({"ok": false, "error": "unsupported", "detail": "rmodbus's client has no 08H request"})
            }
            other => {
                json!({"ok": false, "error": "unsupported", "detail": format!("op {other:?}")})
            }
        };
        if let Value::Object(map) = &mut answer {
            let mut with_id = Map::new();
            with_id.insert("id".into(), req.get("id").cloned().unwrap_or(Value::Null));
            with_id.extend(std::mem::take(map));
            answer = Value::Object(with_id);
        }
        if writeln!(out, "{answer}").and_then(|_| out.flush()).is_err() {
            break;
        }
    }
}
