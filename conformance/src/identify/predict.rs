//! What a model predicts for one read request, and what a device answered: the two sides
//! of one piece of evidence.
//!
//! A prediction is the model's judgement ([`DriveModel::judge`]) reduced to what can be
//! seen on the line: a normal reply with so many registers (and the values the manual
//! gives, which for reads is the identification register's documented value only), an
//! exception code, or silence. Values that the model fills in by a decision (a reserved
//! register reads 0000H, the simulator's identification value) are not predicted: a real
//! drive need not follow them, and a device must not be told apart by them.

use std::fmt;

use crate::codec::pdu::{Direction, Message, Pdu};
use crate::codec::Mode;
use crate::judge::{body_of, explain_invalid};
use crate::model::{Basis, DriveModel, Expectation, Judgement};
use crate::runner::Exchange;

/// What a model predicts a device of it answers.
#[derive(Debug, Clone, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum Prediction {
    /// A normal 03H reply with one value per entry: `Some(v)` where the manual gives the
    /// value, `None` where any value is right.
    Read(Vec<Option<u16>>),
    /// An exception reply with this code.
    Exception(u8),
    /// An exception reply whose code the description does not state (it names the
    /// missing rule): any code fits, and only a normal reply or silence tells it apart.
    AnyException(String),
    /// No reply.
    Silence,
    /// Any other normal reply (a write's echo, a loop-back); identify sends reads only,
    /// so a plan never holds one.
    Other(String),
}

impl Prediction {
    /// `model`'s prediction for `frame` sent to node `address` in `mode`, and the
    /// judgement it comes from.
    pub fn of(model: &DriveModel, address: u8, mode: Mode, frame: &[u8]) -> (Self, Judgement) {
        let j = model.judge(address, mode, frame);
        let p = match &j.expect {
            Expectation::Read(plan) => Prediction::Read(
                plan.registers
                    .iter()
                    .map(|&r| documented_value(model, r))
                    .collect(),
            ),
            Expectation::Exception { .. } if !j.missing.is_empty() => {
                Prediction::AnyException(j.missing.join(", "))
            }
            Expectation::Exception { code, .. } => Prediction::Exception(*code),
            Expectation::Silence(_) => Prediction::Silence,
            other => Prediction::Other(other.describe()),
        };
        (p, j)
    }

    /// Whether `answer` is what this predicts.
    pub fn admits(&self, answer: &Answer) -> bool {
        match (self, answer) {
            (Prediction::Read(want), Answer::Read(got)) => {
                want.len() == got.len()
                    && want.iter().zip(got).all(|(w, g)| w.is_none_or(|w| w == *g))
            }
            (Prediction::Exception(a), Answer::Exception(b)) => a == b,
            (Prediction::AnyException(_), Answer::Exception(_)) => true,
            (Prediction::Silence, Answer::Silence) => true,
            _ => false,
        }
    }

    /// Whether no answer can fit both predictions: an answer that fits one tells the
    /// two models apart.
    pub fn excludes(&self, other: &Prediction) -> bool {
        match (self, other) {
            (Prediction::Read(a), Prediction::Read(b)) => {
                a.len() != b.len()
                    || a.iter()
                        .zip(b)
                        .any(|(x, y)| matches!((x, y), (Some(x), Some(y)) if x != y))
            }
            (
                Prediction::AnyException(_),
                Prediction::Exception(_) | Prediction::AnyException(_),
            )
            | (Prediction::Exception(_), Prediction::AnyException(_)) => false,
            (a, b) => a != b,
        }
    }

    /// One line: "a normal reply with 2 registers (252FH = 0110H)", "exception 02H".
    pub fn describe(&self) -> String {
        match self {
            Prediction::Read(v) => {
                let known: Vec<String> = v
                    .iter()
                    .enumerate()
                    .filter_map(|(i, x)| x.map(|x| format!("value {} = {x:04X}H", i + 1)))
                    .collect();
                format!(
                    "a normal reply with {} register{}{}",
                    v.len(),
                    if v.len() == 1 { "" } else { "s" },
                    if known.is_empty() {
                        String::new()
                    } else {
                        format!(" ({})", known.join(", "))
                    }
                )
            }
            Prediction::Exception(c) => format!("exception {c:02X}H"),
            Prediction::AnyException(missing) => {
                format!("an exception (code not stated: the description has no {missing})")
            }
            Prediction::Silence => "no reply".to_string(),
            Prediction::Other(s) => s.clone(),
        }
    }
}

impl fmt::Display for Prediction {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.describe())
    }
}

/// The value the manual documents for `register`, where it gives one: the identification
/// register's (L510: 252FH reads 0110H).
fn documented_value(model: &DriveModel, register: u16) -> Option<u16> {
    let id = model.identification.as_ref()?;
    match (id.register, id.value) {
        (Some(r), Some(v)) if r == register && id.fact.basis != Basis::Decision => Some(v),
        _ => None,
    }
}

/// What a device answered to one request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Answer {
    /// A normal 03H reply with these values.
    Read(Vec<u16>),
    /// An exception reply with this code.
    Exception(u8),
    /// No byte came back (and a liveness probe showed the device alive).
    Silence,
    /// Bytes that are not a reply to the request: what they are, in words with hex.
    Other(String),
}

impl Answer {
    /// The answer in `ex`, an exchange of a read request in `mode`.
    pub fn of(mode: Mode, ex: &Exchange) -> Self {
        let rx = ex.after_echo();
        let Some(reply) = &ex.reply else {
            return if rx.is_empty() {
                Answer::Silence
            } else {
                Answer::Other(explain_invalid(mode, rx))
            };
        };
        let (Some(req), Some(body)) = (body_of(mode, &ex.request), body_of(mode, reply)) else {
            return Answer::Other(explain_invalid(mode, reply));
        };
        let msg = match Message::parse_body(&body, Direction::Response) {
            Ok(m) => m,
            Err(e) => return Answer::Other(format!("a reply that does not parse: {e}")),
        };
        if msg.address != req[0] {
            return Answer::Other(format!(
                "a reply from node {:02X}H to a request to node {:02X}H: {msg}",
                msg.address, req[0]
            ));
        }
        match msg.pdu {
            Pdu::ReadResponse { values } => Answer::Read(values.iter().collect()),
            Pdu::Exception { code, .. } => Answer::Exception(code),
            _ => Answer::Other(format!("not a read reply: {msg}")),
        }
    }

    /// One line: "2 registers: 0000H 0A51H", "exception 02H", "no reply".
    pub fn describe(&self) -> String {
        match self {
            Answer::Read(v) => {
                let mut s = format!(
                    "{} register{}:",
                    v.len(),
                    if v.len() == 1 { "" } else { "s" }
                );
                for (i, x) in v.iter().enumerate() {
                    if i == 8 && v.len() > 10 {
                        s.push_str(&format!(" ... ({} more)", v.len() - 8));
                        break;
                    }
                    s.push_str(&format!(" {x:04X}H"));
                }
                s
            }
            Answer::Exception(c) => format!("exception {c:02X}H"),
            Answer::Silence => "no reply".to_string(),
            Answer::Other(s) => s.clone(),
        }
    }
}

impl fmt::Display for Answer {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.describe())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::pdu::Message;

    fn read(start: u16, count: u16) -> Vec<u8> {
        Message {
            address: 1,
            pdu: Pdu::ReadRequest { start, count },
        }
        .to_frame_vec(Mode::Rtu)
        .unwrap()
    }

    #[test]
    fn the_identification_value_is_predicted_only_where_the_manual_gives_it() {
        let l510 = DriveModel::builtin("l510").unwrap();
        let f510 = DriveModel::builtin("f510").unwrap();
        let (p, _) = Prediction::of(&l510, 1, Mode::Rtu, &read(0x252F, 1));
        assert_eq!(p, Prediction::Read(vec![Some(0x0110)]));
        // The F510 manual gives no value; the simulator's 0510H is this suite's choice.
        let (q, _) = Prediction::of(&f510, 1, Mode::Rtu, &read(0x252F, 1));
        assert_eq!(q, Prediction::Read(vec![None]));
        assert!(p.admits(&Answer::Read(vec![0x0110])));
        assert!(!p.admits(&Answer::Read(vec![0x0510])));
        assert!(q.admits(&Answer::Read(vec![0x0510])));
        assert!(!q.admits(&Answer::Read(vec![1, 2])));
        // Overlapping predictions do not tell the two apart.
        assert!(!p.excludes(&q));
    }

    #[test]
    fn an_exception_whose_code_a_description_leaves_out_admits_any_code() {
        let m = DriveModel::from_json(
            "x",
            r#"{"schema_version": 2, "model": "x", "title": "x", "modes": ["rtu"],
                "functions": {"codes": ["03"], "basis": "documented", "source": "s"},
                "blocks": [{"first": "0000", "last": "000F", "basis": "documented", "source": "s"}]}"#,
        )
        .unwrap();
        let (p, _) = Prediction::of(&m, 1, Mode::Rtu, &read(0x1000, 1));
        assert_eq!(
            p,
            Prediction::AnyException("exceptions.illegal-register".into())
        );
        assert!(p.admits(&Answer::Exception(0x02)));
        assert!(p.admits(&Answer::Exception(0x52)));
        assert!(!p.admits(&Answer::Silence));
        assert!(!p.excludes(&Prediction::Exception(0x52)));
        assert!(p.excludes(&Prediction::Silence));
    }

    #[test]
    fn exception_numbering_tells_the_legacy_note_apart() {
        let f510 = DriveModel::builtin("f510").unwrap();
        let legacy = DriveModel::builtin("l510-legacy").unwrap();
        let (a, _) = Prediction::of(&f510, 1, Mode::Rtu, &read(0x2530, 1));
        let (b, _) = Prediction::of(&legacy, 1, Mode::Rtu, &read(0x2530, 1));
        assert_eq!(a, Prediction::Exception(0x02));
        assert_eq!(b, Prediction::Exception(0x52));
        assert!(a.excludes(&b));
        assert!(a.admits(&Answer::Exception(2)));
        assert!(!a.admits(&Answer::Silence));
    }
}
