//! This suite's own master behind the master adapter protocol (`conformance adapter
//! --master`): **a test double, for the gate's own tests only**. It shows the protocol
//! working end to end, and with a deliberate quirk ([`Quirk`]) it is the broken master
//! that the gate must catch, each quirk as its own kind of finding and no other.
//!
//! The clean master, before each request, drops what is waiting in its input and waits
//! for t3.5 of silence on the line; it takes as the reply only a frame with a valid
//! checksum, from the node it asked, that answers its request (function, byte count,
//! echo), and drops a frame with a silence over t1.5 inside it; after a timeout it tries
//! again as often as its `retries` say; after a broadcast it waits the turnaround delay
//! and reads nothing.

use std::io::{BufRead, Write};
use std::time::{Duration, Instant};

use serde_json::{json, Value};

use crate::codec::ascii::Scratch;
use crate::codec::deframe::{rtu_frame_len, AsciiDeframer, Event, RtuDeframer, RtuFraming};
use crate::codec::hex::{parse_hex, Hex};
use crate::codec::pdu::{Direction, Message, Pdu, Registers};
use crate::codec::timing::later;
use crate::codec::timing::{LineSettings, Parity};
use crate::codec::{self, Mode};
use crate::transport::serial::SerialTransport;
use crate::transport::tcp::TcpTransport;
use crate::transport::{LinkKind, Transport};

/// A deliberate bug of the test-double master.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Quirk {
    /// Does not drop old input before a request: a late reply of the right shape that
    /// waits in its input is taken as the next request's (it still checks the node,
    /// the function and the byte count).
    TakesStaleReply,
    /// Sends at once, without waiting for t3.5 of silence (also while the drive sends).
    NoT35,
    /// Takes a reply whatever its CRC or LRC.
    AcceptsBadCrc,
    /// Sends a request five times, a tenth of its timeout apart, whatever its retries.
    RetryStorm,
    /// Takes an exception reply as a normal one.
    IgnoresException,
    /// Reads 100 registers whatever it is asked, and returns the first ones.
    ReadsOverLimit,
}

impl Quirk {
    /// Every quirk with its name.
    pub const ALL: [(&'static str, Quirk); 6] = [
        ("takes-stale-reply", Quirk::TakesStaleReply),
        ("no-t35", Quirk::NoT35),
        ("accepts-bad-crc", Quirk::AcceptsBadCrc),
        ("retry-storm", Quirk::RetryStorm),
        ("ignores-exception", Quirk::IgnoresException),
        ("reads-over-limit", Quirk::ReadsOverLimit),
    ];

    /// The quirk named `name`.
    pub fn parse(name: &str) -> Option<Quirk> {
        Quirk::ALL.iter().find(|(n, _)| *n == name).map(|(_, q)| *q)
    }
}

/// The registers the reads-over-limit quirk asks for.
pub const OVER_LIMIT_COUNT: u16 = 100;

/// The pause after a broadcast (Modbus over Serial Line V1.02, 2.4.1: typically 100 to
/// 200 ms).
const TURNAROUND: Duration = Duration::from_millis(100);

struct Open {
    port: Box<dyn Transport>,
    mode: Mode,
    line: LineSettings,
    timeout: Duration,
    retries: u32,
    /// What the takes-stale-reply quirk read while it waited for silence: still its input.
    kept: Vec<u8>,
}

enum Outcome {
    Reply(Vec<u8>),
    Failed(&'static str, String),
}

struct MasterState {
    quirk: Option<Quirk>,
    open: Option<Open>,
}

fn hex4(v: &Value, k: &str) -> Result<u16, String> {
    v.get(k)
        .and_then(Value::as_str)
        .and_then(|s| u16::from_str_radix(s, 16).ok())
        .ok_or_else(|| format!("missing or bad hex4 field {k:?}"))
}

fn unit(v: &Value) -> Result<u8, String> {
    v.get("unit")
        .and_then(Value::as_u64)
        .and_then(|u| u8::try_from(u).ok())
        .ok_or_else(|| "missing or bad \"unit\"".to_string())
}

/// Serves the master adapter protocol on `input`/`output` until the input ends.
pub fn serve(
    input: impl BufRead,
    mut output: impl Write,
    quirk: Option<Quirk>,
) -> std::io::Result<()> {
    let mut state = MasterState { quirk, open: None };
    for line in input.lines() {
        let line = line?;
        if line.trim().is_empty() {
            continue;
        }
        let answer = match serde_json::from_str::<Value>(&line) {
            Ok(req) => {
                let id = req.get("id").cloned().unwrap_or(Value::Null);
                let mut a = match state.handle(&req) {
                    Ok(a) => a,
                    Err(e) => json!({"ok": false, "error": e}),
                };
                a["id"] = id;
                a
            }
            Err(e) => json!({"id": null, "ok": false, "error": format!("not JSON: {e}")}),
        };
        writeln!(output, "{answer}")?;
        output.flush()?;
    }
    Ok(())
}

impl MasterState {
    fn handle(&mut self, req: &Value) -> Result<Value, String> {
        match req.get("op").and_then(Value::as_str) {
            Some("hello") => Ok(json!({
                "ok": true, "protocol": 1, "role": "master",
                "adapter": "conformance-master",
                "implementation": "teco-modbus-conformance (test double)",
                "version": env!("CARGO_PKG_VERSION"),
                "supports": ["read", "write-single", "write-multiple", "loop-back", "broadcast"],
                "lines": ["pty", "tcp-rtu"], "modes": ["rtu", "ascii"],
                "quirk": self.quirk.and_then(|q| Quirk::ALL.iter().find(|(_, x)| *x == q).map(|(n, _)| *n)),
            })),
            Some("open") => self.open(req),
            Some("close") => {
                self.open = None;
                Ok(json!({"ok": true}))
            }
            Some("read") => {
                let (u, start) = (unit(req)?, hex4(req, "start")?);
                let count = req
                    .get("count")
                    .and_then(Value::as_u64)
                    .and_then(|c| u16::try_from(c).ok())
                    .ok_or("missing or bad \"count\"")?;
                let asked = if self.quirk == Some(Quirk::ReadsOverLimit) {
                    count.max(OVER_LIMIT_COUNT)
                } else {
                    count
                };
                let request = Message {
                    address: u,
                    pdu: Pdu::ReadRequest {
                        start,
                        count: asked,
                    },
                };
                self.operate(&request, |m| match m.pdu {
                    Pdu::ReadResponse { values } => {
                        let v: Vec<String> = values
                            .iter()
                            .take(usize::from(count))
                            .map(|x| format!("{x:04X}"))
                            .collect();
                        json!({"ok": true, "result": "values", "values": v})
                    }
                    _ => json!({"ok": true, "result": "values", "values": []}),
                })
            }
            Some("write-single") => {
                let request = Message {
                    address: unit(req)?,
                    pdu: Pdu::WriteSingle {
                        register: hex4(req, "register")?,
                        value: hex4(req, "value")?,
                    },
                };
                self.operate(&request, |_| json!({"ok": true, "result": "done"}))
            }
            Some("write-multiple") => {
                let list = req
                    .get("values")
                    .and_then(Value::as_array)
                    .ok_or("missing \"values\"")?;
                let mut bytes = Vec::new();
                for x in list {
                    let v = x
                        .as_str()
                        .and_then(|s| u16::from_str_radix(s, 16).ok())
                        .ok_or("a value that is not hex4")?;
                    bytes.extend_from_slice(&v.to_be_bytes());
                }
                let values = Registers::new(&bytes).map_err(|e| e.to_string())?;
                let request = Message {
                    address: unit(req)?,
                    pdu: Pdu::WriteMultipleRequest {
                        start: hex4(req, "start")?,
                        values,
                    },
                };
                self.operate(&request, |_| json!({"ok": true, "result": "done"}))
            }
            Some("loop-back") => {
                let data = parse_hex(req.get("data").and_then(Value::as_str).unwrap_or(""))
                    .map_err(|e| e.to_string())?;
                let request = Message {
                    address: unit(req)?,
                    pdu: Pdu::LoopBack {
                        test_code: hex4(req, "test_code")?,
                        data: &data,
                    },
                };
                self.operate(&request, |m| match m.pdu {
                    Pdu::LoopBack { test_code, data } => json!({"ok": true, "result": "echo",
                        "test_code": format!("{test_code:04X}"), "data": Hex(data).to_string()}),
                    _ => json!({"ok": true, "result": "echo", "test_code": "0000", "data": ""}),
                })
            }
            Some(_) => Ok(json!({"ok": false, "error": "unsupported"})),
            None => Err("no \"op\"".into()),
        }
    }

    fn open(&mut self, req: &Value) -> Result<Value, String> {
        self.open = None;
        let line_req = req.get("line").ok_or("missing \"line\"")?;
        let kind = line_req.get("kind").and_then(Value::as_str).unwrap_or("");
        let mode = match req.get("mode").and_then(Value::as_str) {
            Some("ascii") => Mode::Ascii,
            _ => Mode::Rtu,
        };
        let num = |k: &str, d: u64| req.get(k).and_then(Value::as_u64).unwrap_or(d);
        let parity = match req.get("parity").and_then(Value::as_str) {
            Some("E") => Parity::Even,
            Some("O") => Parity::Odd,
            _ => Parity::None,
        };
        let line = LineSettings::new(
            num("baud", 9600) as u32,
            num("data_bits", 8) as u8,
            parity,
            num("stop_bits", 1) as u8,
        );
        let port: Box<dyn Transport> = match kind {
            "pty" => {
                let path = line_req
                    .get("path")
                    .and_then(Value::as_str)
                    .ok_or("missing line.path")?;
                Box::new(
                    SerialTransport::open(path, line, LinkKind::Pty).map_err(|e| e.to_string())?,
                )
            }
            "tcp-rtu" => {
                let host = line_req
                    .get("host")
                    .and_then(Value::as_str)
                    .ok_or("missing line.host")?;
                let port = line_req
                    .get("port")
                    .and_then(Value::as_u64)
                    .ok_or("missing line.port")?;
                Box::new(
                    TcpTransport::connect(&format!("{host}:{port}"), Duration::from_secs(5))
                        .map_err(|e| e.to_string())?,
                )
            }
            _ => return Ok(json!({"ok": false, "error": "unsupported: line kind"})),
        };
        self.open = Some(Open {
            port,
            mode,
            line,
            timeout: Duration::from_millis(num("timeout_ms", 1000)),
            retries: num("retries", 0) as u32,
            kept: Vec::new(),
        });
        Ok(json!({"ok": true}))
    }

    /// Sends `request`, waits for its reply, and answers with `normal` of it, or the
    /// exception, or the failure.
    fn operate(
        &mut self,
        request: &Message<'_>,
        normal: impl Fn(&Message<'_>) -> Value,
    ) -> Result<Value, String> {
        let quirk = self.quirk;
        let open = self.open.as_mut().ok_or("the line is not open")?;
        let frame = request.to_frame_vec(open.mode).map_err(|e| e.to_string())?;
        let broadcast = request.address == 0;
        let (tries, wait) = if quirk == Some(Quirk::RetryStorm) {
            (5, open.timeout / 10)
        } else {
            (open.retries.saturating_add(1), open.timeout)
        };
        let mut outcome = Outcome::Failed("timeout", "no reply".into());
        for _ in 0..tries {
            // First the line's silence (reading what comes, so that an ASCII frame
            // under way is seen from its ':'), then whatever is left is dropped.
            if quirk != Some(Quirk::NoT35) {
                open.wait_silence(quirk == Some(Quirk::TakesStaleReply));
            }
            if quirk != Some(Quirk::TakesStaleReply) {
                let _ = open.port.discard_input();
            }
            open.port.send(&frame).map_err(|e| e.to_string())?;
            if broadcast {
                std::thread::sleep(TURNAROUND);
                return Ok(json!({"ok": true, "result": "done"}));
            }
            outcome = open.receive(request, &frame, wait, quirk);
            if let Outcome::Reply(_) = outcome {
                break;
            }
        }
        match outcome {
            Outcome::Reply(reply) => {
                let mut scratch: Scratch = [0; codec::MAX_RTU_FRAME];
                let m = match codec::decode(open.mode, &reply, Direction::Response, &mut scratch) {
                    Ok(m) => m,
                    Err(_) => {
                        match codec::decode_unchecked(
                            open.mode,
                            &reply,
                            Direction::Response,
                            &mut scratch,
                        ) {
                            Ok(u) => u.message,
                            Err(e) => {
                                return Ok(json!({"ok": true, "result": "error",
                                    "kind": "invalid-frame", "message": e.to_string()}))
                            }
                        }
                    }
                };
                match m.pdu {
                    Pdu::Exception { code, .. } if quirk != Some(Quirk::IgnoresException) => Ok(
                        json!({"ok": true, "result": "exception", "code": format!("{code:02X}")}),
                    ),
                    _ => Ok(normal(&m)),
                }
            }
            Outcome::Failed(kind, message) => {
                Ok(json!({"ok": true, "result": "error", "kind": kind, "message": message}))
            }
        }
    }
}

impl Open {
    fn t(&self, us: u64) -> Duration {
        Duration::from_micros(us)
    }

    /// Reads and drops what comes until the line has been silent for t3.5 (at most 2 s).
    fn wait_silence(&mut self, keep: bool) {
        let t35 = self.t(self.line.t3_5_us());
        let deadline = Instant::now() + Duration::from_secs(2);
        let mut buf = [0u8; 512];
        // ASCII: a frame under way (':' seen, no LF yet) may pause; wait for its end.
        let mut open = false;
        while Instant::now() < deadline {
            let wait = if open { Duration::from_millis(20) } else { t35 };
            match self.port.recv(&mut buf, wait) {
                Ok(0) if open => {}
                Ok(0) | Err(_) => return,
                Ok(n) => {
                    if self.mode == Mode::Ascii {
                        for b in &buf[..n] {
                            match b {
                                b':' => open = true,
                                b'\n' => open = false,
                                _ => {}
                            }
                        }
                    }
                    if keep {
                        self.kept.extend_from_slice(&buf[..n]);
                    }
                }
            }
        }
    }

    /// Waits `wait` for a reply to `request`.
    fn receive(
        &mut self,
        request: &Message<'_>,
        frame: &[u8],
        wait: Duration,
        quirk: Option<Quirk>,
    ) -> Outcome {
        let deadline = later(Instant::now(), wait);
        let mut rtu = RtuDeframer::new(Direction::Response, RtuFraming::ByLength);
        let mut ascii = AsciiDeframer::default();
        let mut raw: Vec<u8> = Vec::new();
        let mut last: Option<Instant> = None;
        let t15 = self.t(self.line.t1_5_us()) + Duration::from_millis(2);
        let mut buf = [0u8; 512];
        let mut kept = std::mem::take(&mut self.kept);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() {
                return Outcome::Failed("timeout", format!("no reply to {} in time", Hex(frame)));
            }
            let n = if kept.is_empty() {
                match self
                    .port
                    .recv(&mut buf, left.min(Duration::from_millis(20)))
                {
                    Ok(n) => n,
                    Err(e) => return Outcome::Failed("other", e.to_string()),
                }
            } else {
                let n = kept.len().min(buf.len());
                buf[..n].copy_from_slice(&kept[..n]);
                kept.drain(..n);
                n
            };
            if n == 0 {
                continue;
            }
            let now = Instant::now();
            // A silence over t1.5 inside a frame: what came before it is dropped.
            if last.is_some_and(|l| now.duration_since(l) > t15) {
                rtu.flush(|_| {});
                ascii.flush(|_| {});
                raw.clear();
            }
            last = Some(now);
            raw.extend_from_slice(&buf[..n]);
            let mut frames: Vec<Vec<u8>> = Vec::new();
            match self.mode {
                Mode::Rtu => rtu.push(&buf[..n], |e| {
                    if let Event::Frame(f) = e {
                        frames.push(f.to_vec())
                    }
                }),
                Mode::Ascii => ascii.push(&buf[..n], |e| {
                    if let Event::Frame(f) = e {
                        frames.push(f.to_vec())
                    }
                }),
            }
            for f in frames {
                if answers(self.mode, request, &f) {
                    return Outcome::Reply(f);
                }
            }
            if quirk == Some(Quirk::AcceptsBadCrc) {
                if let Some(f) = unchecked_frame(self.mode, request, &raw) {
                    return Outcome::Reply(f);
                }
            }
        }
    }
}

/// Whether `frame` (valid) answers `request`: its function or its exception, and for a
/// normal reply the byte count, the echo, or the start and count.
fn answers(mode: Mode, request: &Message<'_>, frame: &[u8]) -> bool {
    let mut scratch: Scratch = [0; codec::MAX_RTU_FRAME];
    let Ok(m) = codec::decode(mode, frame, Direction::Response, &mut scratch) else {
        return false;
    };
    answers_message(request, &m)
}

/// Whether `m` answers `request` (see [`answers`]).
fn answers_message(request: &Message<'_>, m: &Message<'_>) -> bool {
    if m.address != request.address {
        return false;
    }
    match (&request.pdu, &m.pdu) {
        (_, Pdu::Exception { function, .. }) => *function == request.pdu.function_code(),
        (Pdu::ReadRequest { count, .. }, Pdu::ReadResponse { values }) => {
            values.len() == usize::from(*count)
        }
        (Pdu::WriteSingle { .. }, Pdu::WriteSingle { .. })
        | (Pdu::LoopBack { .. }, Pdu::LoopBack { .. }) => m.pdu == request.pdu,
        (
            Pdu::WriteMultipleRequest { start, values },
            Pdu::WriteMultipleResponse { start: s, count },
        ) => s == start && usize::from(*count) == values.len(),
        _ => false,
    }
}

/// The accepts-bad-crc quirk: the first frame in `raw` that answers `request` as its
/// length says, whatever its checksum.
fn unchecked_frame(mode: Mode, request: &Message<'_>, raw: &[u8]) -> Option<Vec<u8>> {
    let mut scratch: Scratch = [0; codec::MAX_RTU_FRAME];
    let mut fits = |f: &[u8]| {
        codec::decode_unchecked(mode, f, Direction::Response, &mut scratch)
            .ok()
            .is_some_and(|u| answers_message(request, &u.message))
    };
    match mode {
        Mode::Rtu => (0..raw.len()).find_map(|i| {
            let rest = &raw[i..];
            let n = rtu_frame_len(Direction::Response, rest)?;
            let f = rest.get(..n)?;
            fits(f).then(|| f.to_vec())
        }),
        Mode::Ascii => {
            let mut at = 0;
            while let Some(start) = raw[at..].iter().position(|b| *b == b':').map(|p| p + at) {
                let end = raw[start..].windows(2).position(|w| w == b"\r\n")? + start + 2;
                let f = &raw[start..end];
                if fits(f) {
                    return Some(f.to_vec());
                }
                at = end;
            }
            None
        }
    }
}
