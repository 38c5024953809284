//! The gate's side of the master adapter protocol (`adapters/PROTOCOL.md`, role
//! "master"): hello, open, the operations, and what the library returned.

use std::time::Duration;

use serde_json::{json, Value};

use crate::codec::hex::{parse_hex, Hex};
use crate::codec::timing::{LineSettings, Parity};
use crate::codec::Mode;
use crate::gate::adapter::{string_list, Adapter, AdapterError, CallError};

/// One operation asked of the master.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Operation {
    /// 03H: read `count` holding registers from `start`.
    Read {
        /// Node.
        unit: u8,
        /// First register.
        start: u16,
        /// Registers.
        count: u16,
    },
    /// 06H.
    WriteSingle {
        /// Node (0: broadcast).
        unit: u8,
        /// Register.
        register: u16,
        /// Value.
        value: u16,
    },
    /// 10H.
    WriteMultiple {
        /// Node (0: broadcast).
        unit: u8,
        /// First register.
        start: u16,
        /// Values.
        values: Vec<u16>,
    },
    /// 08H.
    LoopBack {
        /// Node.
        unit: u8,
        /// Sub-function.
        test_code: u16,
        /// Data.
        data: Vec<u8>,
    },
}

impl Operation {
    /// The `supports` name of the operation (`broadcast` for writes to unit 0).
    pub fn name(&self) -> &'static str {
        match self {
            Operation::Read { .. } => "read",
            Operation::WriteSingle { unit: 0, .. } | Operation::WriteMultiple { unit: 0, .. } => {
                "broadcast"
            }
            Operation::WriteSingle { .. } => "write-single",
            Operation::WriteMultiple { .. } => "write-multiple",
            Operation::LoopBack { .. } => "loop-back",
        }
    }

    /// The protocol's request.
    pub fn to_json(&self) -> Value {
        let h4 = |v: u16| format!("{v:04X}");
        match self {
            Operation::Read { unit, start, count } => {
                json!({"op": "read", "unit": unit, "start": h4(*start), "count": count})
            }
            Operation::WriteSingle {
                unit,
                register,
                value,
            } => {
                json!({"op": "write-single", "unit": unit, "register": h4(*register), "value": h4(*value)})
            }
            Operation::WriteMultiple {
                unit,
                start,
                values,
            } => json!({"op": "write-multiple", "unit": unit, "start": h4(*start),
                        "values": values.iter().map(|v| h4(*v)).collect::<Vec<_>>()}),
            Operation::LoopBack {
                unit,
                test_code,
                data,
            } => json!({"op": "loop-back", "unit": unit, "test_code": h4(*test_code),
                        "data": Hex(data).to_string()}),
        }
    }

    /// The function code on the wire.
    pub fn function(&self) -> u8 {
        match self {
            Operation::Read { .. } => 0x03,
            Operation::WriteSingle { .. } => 0x06,
            Operation::WriteMultiple { .. } => 0x10,
            Operation::LoopBack { .. } => 0x08,
        }
    }

    /// Whether the master must wait for no reply (a broadcast).
    pub fn broadcast(&self) -> bool {
        matches!(
            self,
            Operation::WriteSingle { unit: 0, .. } | Operation::WriteMultiple { unit: 0, .. }
        )
    }
}

impl std::fmt::Display for Operation {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Operation::Read { unit, start, count } => {
                write!(f, "read {count} from {start:04X}H at node {unit}")
            }
            Operation::WriteSingle {
                unit,
                register,
                value,
            } => write!(f, "write {value:04X}H to {register:04X}H at node {unit}"),
            Operation::WriteMultiple {
                unit,
                start,
                values,
            } => write!(
                f,
                "write {} registers from {start:04X}H at node {unit}",
                values.len()
            ),
            Operation::LoopBack {
                unit,
                test_code,
                data,
            } => write!(f, "loop-back {test_code:04X}H {} at node {unit}", Hex(data)),
        }
    }
}

/// The kind of a failure the library reported.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ErrorKind {
    /// No (valid) reply in time.
    Timeout,
    /// A checksum error.
    Checksum,
    /// A frame the library found invalid.
    InvalidFrame,
    /// Anything else.
    Other,
}

impl ErrorKind {
    fn parse(s: &str) -> Self {
        match s {
            "timeout" => ErrorKind::Timeout,
            "checksum" => ErrorKind::Checksum,
            "invalid-frame" => ErrorKind::InvalidFrame,
            _ => ErrorKind::Other,
        }
    }

    /// As the protocol spells it.
    pub fn key(self) -> &'static str {
        match self {
            ErrorKind::Timeout => "timeout",
            ErrorKind::Checksum => "checksum",
            ErrorKind::InvalidFrame => "invalid-frame",
            ErrorKind::Other => "other",
        }
    }
}

/// What the library returned for an operation.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Reported {
    /// Register values.
    Values(Vec<u16>),
    /// A write returned normally.
    Done,
    /// A loop-back returned.
    Echo {
        /// Sub-function.
        test_code: u16,
        /// Data.
        data: Vec<u8>,
    },
    /// A Modbus exception with its code.
    Exception(u8),
    /// A failure that is not an exception.
    Error {
        /// Its kind.
        kind: ErrorKind,
        /// The library's message.
        message: String,
    },
    /// The call raised or crashed.
    Raised {
        /// The type, if the language has one.
        kind: String,
        /// The message.
        message: String,
    },
}

impl Reported {
    /// Whether it is a failure (error or raised).
    pub fn failed(&self) -> bool {
        matches!(self, Reported::Error { .. } | Reported::Raised { .. })
    }
}

impl std::fmt::Display for Reported {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            Reported::Values(v) => {
                f.write_str("values")?;
                for x in v {
                    write!(f, " {x:04X}")?;
                }
                Ok(())
            }
            Reported::Done => f.write_str("done"),
            Reported::Echo { test_code, data } => {
                write!(f, "echo {test_code:04X} {}", Hex(data))
            }
            Reported::Exception(c) => write!(f, "exception {c:02X}H"),
            Reported::Error { kind, message } => write!(f, "error {}: {message}", kind.key()),
            Reported::Raised { kind, message } => write!(f, "raised {kind}: {message}"),
        }
    }
}

fn hex4(v: &Value) -> Option<u16> {
    v.as_str()
        .and_then(|s| u16::from_str_radix(s.trim(), 16).ok())
}

/// Reads an answer's `result`.
pub fn parse_answer(v: &Value) -> Result<Reported, String> {
    let s = |k: &str| v.get(k).and_then(Value::as_str).unwrap_or("").to_string();
    match v.get("result").and_then(Value::as_str) {
        Some("values") => {
            let list = v
                .get("values")
                .and_then(Value::as_array)
                .ok_or_else(|| format!("\"values\" without a list: {v}"))?;
            list.iter()
                .map(|x| hex4(x).ok_or_else(|| format!("a value that is not hex4: {x}")))
                .collect::<Result<Vec<_>, _>>()
                .map(Reported::Values)
        }
        Some("done") => Ok(Reported::Done),
        Some("echo") => Ok(Reported::Echo {
            test_code: v.get("test_code").and_then(hex4).unwrap_or(0),
            data: parse_hex(&s("data")).map_err(|e| format!("echo data: {e}"))?,
        }),
        Some("exception") => v
            .get("code")
            .and_then(Value::as_str)
            .and_then(|c| u8::from_str_radix(c.trim(), 16).ok())
            .map(Reported::Exception)
            .ok_or_else(|| format!("an exception without a hex2 code: {v}")),
        Some("error") => Ok(Reported::Error {
            kind: ErrorKind::parse(&s("kind")),
            message: s("message"),
        }),
        Some("raised") => Ok(Reported::Raised {
            kind: s("type"),
            message: s("message"),
        }),
        other => Err(format!("unknown result {other:?}: {v}")),
    }
}

/// What the adapter says in its hello as a master.
#[derive(Debug, Clone, Default)]
pub struct MasterHello {
    /// Operations (`read`, `write-single`, `write-multiple`, `loop-back`, `broadcast`).
    pub supports: Vec<String>,
    /// Lines (`pty`, `tcp-rtu`, `mbap`).
    pub lines: Vec<String>,
    /// Modes (`rtu`, `ascii`).
    pub modes: Vec<String>,
}

impl MasterHello {
    /// What a hello says of a master: refused unless it says `"role": "master"` (a codec
    /// adapter's hello, or one that lies about its role).
    pub fn from_hello(hello: &super::super::adapter::Hello) -> Result<MasterHello, String> {
        let raw = &hello.raw;
        if raw.get("role").and_then(Value::as_str) != Some("master") {
            return Err(format!(
                "the adapter does not speak the master protocol (no \"role\": \"master\" in its hello): {raw}"
            ));
        }
        Ok(MasterHello {
            supports: hello.supports.clone(),
            lines: string_list(raw, "lines"),
            modes: string_list(raw, "modes"),
        })
    }
}

/// The longest response timeout a master may say it runs with: no serial master waits a
/// minute for a reply, and the gate waits the master's worst case for each answer
/// (adapters/PROTOCOL.md).
pub const MAX_MASTER_TIMEOUT: Duration = Duration::from_secs(60);

/// The most retries a master may say it makes.
pub const MAX_MASTER_RETRIES: u32 = 10;

/// The settings an `open` answer says the master runs with (`want` where it says
/// nothing); refused where they are not whole numbers, or say more than
/// [`MAX_MASTER_TIMEOUT`] and [`MAX_MASTER_RETRIES`] (or than was asked, where more was
/// asked): the gate waits the master's worst case for each answer, and a hostile
/// adapter would make that wait endless.
pub fn settings_of_open(answer: &Value, want: MasterSettings) -> Result<MasterSettings, String> {
    let most_timeout = MAX_MASTER_TIMEOUT.max(want.timeout);
    let most_retries = MAX_MASTER_RETRIES.max(want.retries);
    let timeout = match answer.get("timeout_ms") {
        None | Some(Value::Null) => want.timeout,
        Some(v) => match v.as_u64() {
            Some(ms) if Duration::from_millis(ms) <= most_timeout => Duration::from_millis(ms),
            _ => {
                return Err(format!(
                    "\"timeout_ms\": {v}: expected a whole number of ms up to {}",
                    most_timeout.as_millis()
                ))
            }
        },
    };
    let retries = match answer.get("retries") {
        None | Some(Value::Null) => want.retries,
        Some(v) => match v.as_u64() {
            Some(r) if r <= u64::from(most_retries) => r as u32,
            _ => {
                return Err(format!(
                    "\"retries\": {v}: expected a whole number up to {most_retries}"
                ))
            }
        },
    };
    Ok(MasterSettings { timeout, retries })
}

/// The master's own settings, as it runs with them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MasterSettings {
    /// Its response timeout.
    pub timeout: Duration,
    /// Its retries after a timeout.
    pub retries: u32,
}

/// A master adapter.
pub struct MasterAdapter {
    /// The process.
    pub adapter: Adapter,
    /// What it said.
    pub hello: MasterHello,
    /// `--timeout`: the gate's own allowance over the master's worst case.
    pub slack: Duration,
}

fn parity_key(p: Parity) -> &'static str {
    match p {
        Parity::None => "N",
        Parity::Even => "E",
        Parity::Odd => "O",
    }
}

impl MasterAdapter {
    /// Starts `command` and shakes hands as a master.
    pub fn start(command: &str, slack: Duration) -> Result<Self, AdapterError> {
        let adapter = Adapter::start_with(command, slack, json!({"role": "master"}))?;
        let hello = MasterHello::from_hello(&adapter.hello).map_err(|problem| {
            AdapterError::Handshake {
                command: command.to_string(),
                problem,
                stderr: Vec::new(),
                hint: "a codec adapter is run with `conformance gate --codec`; a master adapter answers the hello with \"role\": \"master\" (adapters/PROTOCOL.md)".into(),
            }
        })?;
        Ok(MasterAdapter {
            adapter,
            hello,
            slack,
        })
    }

    /// Whether the master offers `op` (by its `supports` name).
    pub fn supports(&self, op: &str) -> bool {
        self.hello.supports.iter().any(|s| s == op)
    }

    /// Whether the master speaks `mode` (an adapter that lists no modes: RTU only).
    pub fn speaks(&self, mode: Mode) -> bool {
        let m = match mode {
            Mode::Rtu => "rtu",
            Mode::Ascii => "ascii",
        };
        if self.hello.modes.is_empty() {
            return mode == Mode::Rtu;
        }
        self.hello.modes.iter().any(|x| x == m)
    }

    /// Whether the master can open a line of `kind` (`pty`, `tcp-rtu`); an adapter that
    /// lists no `lines` opens a pty only.
    pub fn opens(&self, kind: &str) -> bool {
        if self.hello.lines.is_empty() {
            return kind == "pty";
        }
        self.hello.lines.iter().any(|l| l == kind)
    }

    /// Opens the line at `endpoint`; returns the settings the master runs with.
    pub fn open(
        &mut self,
        endpoint: &super::drive::Endpoint,
        mode: Mode,
        line: LineSettings,
        want: MasterSettings,
    ) -> Result<MasterSettings, CallError> {
        let line_json = match endpoint {
            super::drive::Endpoint::Pty(path) => {
                json!({"kind": "pty", "path": path.to_string_lossy()})
            }
            super::drive::Endpoint::TcpRtu(addr) => {
                json!({"kind": "tcp-rtu", "host": addr.ip().to_string(), "port": addr.port()})
            }
            super::drive::Endpoint::Mbap(addr) => {
                json!({"kind": "mbap", "host": addr.ip().to_string(), "port": addr.port()})
            }
        };
        let request = json!({
            "op": "open",
            "line": line_json,
            "mode": match mode { Mode::Rtu => "rtu", Mode::Ascii => "ascii" },
            "baud": line.baud,
            "parity": parity_key(line.parity),
            "data_bits": line.data_bits,
            "stop_bits": line.stop_bits,
            "timeout_ms": want.timeout.as_millis() as u64,
            "retries": want.retries,
        });
        self.adapter
            .set_timeout(self.slack.max(Duration::from_secs(5)));
        let answer = self.adapter.call(request.clone());
        let answer = match answer {
            Ok(a) => a,
            Err(CallError::Failed(e)) if e.starts_with("unsupported") => {
                return Err(CallError::Failed(format!(
                    "the adapter cannot honour the settings ({e}) and reported none it runs with"
                )))
            }
            Err(e) => return Err(e),
        };
        self.adapter.set_reopen(Some(request));
        let got = settings_of_open(&answer, want)
            .map_err(|e| CallError::Malformed(format!("the open answer's settings: {e}")))?;
        // Its worst case, and the gate's allowance over it.
        self.adapter.set_timeout(
            got.timeout
                .saturating_mul(got.retries.saturating_add(1))
                .saturating_add(self.slack),
        );
        Ok(got)
    }

    /// Asks for one operation; `Ok(None)`: unsupported.
    pub fn operate(&mut self, op: &Operation) -> Result<Option<Reported>, CallError> {
        match self.adapter.call(op.to_json()) {
            Ok(v) => parse_answer(&v).map(Some).map_err(CallError::Malformed),
            Err(CallError::Unsupported) => Ok(None),
            Err(e) => Err(e),
        }
    }

    /// Closes the line (the answer is not judged).
    pub fn close(&mut self) {
        let _ = self.adapter.call(json!({"op": "close"}));
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn answers_parse() {
        assert_eq!(
            parse_answer(&json!({"result": "values", "values": ["0001", "0bb8"]})),
            Ok(Reported::Values(vec![1, 0x0BB8]))
        );
        assert_eq!(
            parse_answer(&json!({"result": "exception", "code": "52"})),
            Ok(Reported::Exception(0x52))
        );
        assert!(matches!(
            parse_answer(&json!({"result": "error", "kind": "timeout", "message": "x"})),
            Ok(Reported::Error {
                kind: ErrorKind::Timeout,
                ..
            })
        ));
        assert!(parse_answer(&json!({"result": "values", "values": ["xyz"]})).is_err());
        assert!(parse_answer(&json!({"result": "maybe"})).is_err());
    }

    #[test]
    fn operations_speak_the_protocol() {
        let op = Operation::WriteMultiple {
            unit: 0,
            start: 0x2501,
            values: vec![1, 0x1770],
        };
        assert_eq!(op.name(), "broadcast");
        assert_eq!(
            op.to_json(),
            json!({"op": "write-multiple", "unit": 0, "start": "2501", "values": ["0001", "1770"]})
        );
    }
}
