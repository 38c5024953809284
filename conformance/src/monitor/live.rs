//! One line per exchange, as a person watches the bus: time, the silence before, node,
//! function, the meaning decoded with the model's register names, the checksum, the
//! response time, the verdict.

use std::fmt;
use std::time::Duration;

use crate::codec::hex::Hex;
use crate::codec::pdu::{Direction, Message, Pdu};
use crate::codec::Mode;
use crate::judge::{self, VerdictStatus};
use crate::model::DriveModel;

/// One exchange (a request and its reply or silence), or a frame nobody asked for.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Line {
    /// When the request began (or ended, where its start was not seen).
    pub at: Duration,
    /// The silence before it, where seen.
    pub since_previous: Option<Duration>,
    /// The node addressed.
    pub node: u8,
    /// The function code.
    pub function: u8,
    /// The request decoded.
    pub meaning: String,
    /// The reply decoded, or what came instead.
    pub reply: Option<String>,
    /// "CRC ok", "CRC bad (reply)", "LRC ok", ...
    pub checksum: String,
    /// The response time, where seen.
    pub response: Option<Duration>,
    /// The verdict.
    pub status: VerdictStatus,
    /// The findings' side and kind ("drive.wrong-exception").
    pub issues: Vec<String>,
    /// Remarks (a copy of a 06H request taken as its reply, a resend).
    pub notes: Vec<String>,
    /// The request's bytes as heard (empty for a frame nobody asked for).
    pub request: Vec<u8>,
    /// What came back (the reply, damaged or not; a frame nobody asked for), as heard.
    pub received: Vec<u8>,
}

impl Line {
    /// The line as one JSON object (`monitor --log`): every field, the frames in hex.
    pub fn to_json(&self) -> serde_json::Value {
        let ms = |d: Duration| (d.as_secs_f64() * 1_000_000.0).round() / 1000.0;
        serde_json::json!({
            "at_s": (self.at.as_secs_f64() * 1_000_000.0).round() / 1_000_000.0,
            "since_previous_ms": self.since_previous.map(ms),
            "node": format!("{:02X}", self.node),
            "function": format!("{:02X}", self.function),
            "request": Hex(&self.request).to_string(),
            "received": Hex(&self.received).to_string(),
            "meaning": self.meaning,
            "reply": self.reply,
            "checksum": self.checksum,
            "response_ms": self.response.map(ms),
            "status": match self.status {
                VerdictStatus::Pass => "pass",
                VerdictStatus::Observation => "observation",
                VerdictStatus::Deviation => "deviation",
            },
            "issues": self.issues,
            "notes": self.notes,
        })
    }
}

impl fmt::Display for Line {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        let ms = |d: Duration| d.as_secs_f64() * 1000.0;
        write!(f, "{:>10.3} s ", self.at.as_secs_f64())?;
        match self.since_previous {
            Some(d) => write!(f, "{:>+9.1} ms", ms(d))?,
            None => write!(f, "{:>12}", "-")?,
        }
        write!(
            f,
            "  node {:02X}  {:02X}H  {}",
            self.node, self.function, self.meaning
        )?;
        if let Some(r) = &self.reply {
            write!(f, " -> {r}")?;
        }
        write!(f, "  {}", self.checksum)?;
        match self.response {
            Some(d) => write!(f, "  rt {:.1} ms", ms(d))?,
            None => write!(f, "  rt -")?,
        }
        write!(
            f,
            "  {}",
            match self.status {
                VerdictStatus::Pass => "PASS",
                VerdictStatus::Observation => "OBSERVATION",
                VerdictStatus::Deviation => "DEVIATION",
            }
        )?;
        if !self.issues.is_empty() {
            write!(f, " [{}]", self.issues.join(", "))?;
        }
        for n in &self.notes {
            write!(f, " ({n})")?;
        }
        Ok(())
    }
}

/// A register with its name and a value in its unit where the model gives one
/// ("2502H (Frequency command (0.01 Hz)) <- 1194H = 45.00 Hz").
fn value(model: &DriveModel, register: u16, v: u16) -> String {
    model.assignment(register, v)
}

/// A frame decoded with the model's register names.
pub(super) fn meaning(
    model: &DriveModel,
    mode: Mode,
    frame: &[u8],
    direction: Direction,
) -> String {
    let Some(body) = judge::body_of(mode, frame) else {
        return format!("{} bytes, no frame", frame.len());
    };
    let Ok(m) = Message::parse_body(&body, direction) else {
        return judge::describe_reply(mode, frame);
    };
    match m.pdu {
        Pdu::ReadRequest { start, count } => {
            format!("read {} x{count}", model.describe(start))
        }
        Pdu::ReadResponse { values } => {
            let v: Vec<String> = values.iter().take(8).map(|x| format!("{x:04X}H")).collect();
            format!(
                "{} {}{}",
                values.len(),
                v.join(" "),
                if values.len() > 8 { " ..." } else { "" }
            )
        }
        Pdu::WriteSingle { register, value: v } => match direction {
            Direction::Request => format!("write {}", value(model, register, v)),
            Direction::Response => "echo".to_string(),
        },
        Pdu::WriteMultipleRequest { start, values } => {
            let first = values.get(0).unwrap_or(0);
            format!(
                "write x{} from {}{}",
                values.len(),
                value(model, start, first),
                if values.len() > 1 { " ..." } else { "" }
            )
        }
        Pdu::WriteMultipleResponse { start, count } => format!("wrote {start:04X}H x{count}"),
        Pdu::LoopBack { test_code, .. } => format!("loop-back test {test_code:04X}H"),
        Pdu::Exception { code, .. } => format!(
            "exception {code:02X}H ({})",
            model.exception_meaning(code).unwrap_or("not in the table")
        ),
        Pdu::Other { function, data } => {
            format!("function {function:02X}H, {} data bytes", data.len())
        }
    }
}
