//! Set-up steps of a check (the read of a value it must restore, a write it needs
//! first): an exception is the device's answer, so evidence about it; only no valid
//! answer is "could not tell" (issue 28: exit codes a gate can trust).

use super::{ExchangeRecord, Finding, Verdict};
use crate::codec::Mode;
use crate::judge;

/// Why a set-up step (a read of the value a check must restore, or a write a check needs
/// first) failed: an answer of the device, or no answer.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum SetupError {
    /// The device answered with an exception: evidence about the device.
    Refused {
        /// What was asked and what came back.
        text: String,
        /// The exception code.
        code: u8,
        /// Whether the manual (the model) says the request is served with a normal
        /// reply, which makes the refusal a deviation.
        documented: bool,
        /// The exchange, for the report.
        exchange: Option<Box<ExchangeRecord>>,
    },
    /// No valid answer (silence, a broken frame): the run cannot tell.
    NoAnswer(String),
}

impl std::fmt::Display for SetupError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            SetupError::Refused { text, .. } | SetupError::NoAnswer(text) => f.write_str(text),
        }
    }
}

/// The exception code of a reply body (address, function | 80H, code), if it is one.
pub(super) fn exception_code(mode: Mode, reply: Option<&Vec<u8>>) -> Option<u8> {
    let body = judge::body_of(mode, reply?)?;
    (body.len() == 3 && body[1] & 0x80 != 0).then(|| body[2])
}

impl Verdict {
    /// The verdict of a check whose set-up step (`what`: "read 1000H first", the read of
    /// the value it must restore, or a write it needs) failed. An exception is the
    /// device's answer, so evidence about it, never "could not tell": where the manual
    /// says the request is served, a DEVIATION (with the frames); where it predicts the
    /// exception, a SKIP. Only no valid answer is an ERROR (exit 2).
    pub fn setup_failed(what: &str, e: SetupError) -> Self {
        match e {
            SetupError::Refused {
                text,
                code,
                documented: true,
                exchange,
            } => Verdict {
                findings: vec![Finding::deviation(format!(
                    "cannot {what}: the manual serves it, the device refused it with exception {code:02X}H ({text}), so the check did not run"
                ))],
                exchanges: exchange.map(|x| vec![*x]).unwrap_or_default(),
                ..Verdict::default()
            },
            SetupError::Refused {
                text,
                documented: false,
                ..
            } => Verdict::skip(format!(
                "cannot {what}: the device refused it as the manual predicts ({text})"
            )),
            SetupError::NoAnswer(text) => Verdict::error(format!("cannot {what}: {text}")),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::runner::{ExchangeRecord, Severity};

    fn refused(documented: bool) -> SetupError {
        SetupError::Refused {
            text: "reading 1 from 1000H: node 01 83 exception function=03 code=02".into(),
            code: 2,
            documented,
            exchange: Some(Box::new(ExchangeRecord {
                request: vec![1, 3, 0x10, 0, 0, 1, 0x80, 0xCA],
                expected: None,
                received: vec![1, 0x83, 2, 0xC0, 0xF1],
                reply: Some(vec![1, 0x83, 2, 0xC0, 0xF1]),
                predicted: String::new(),
                actual: String::new(),
                latency: None,
            })),
        }
    }

    /// The rule of issue 28: an exception is the device's answer (a deviation where the
    /// manual serves the register, a skip where it predicts the exception); only no valid
    /// answer is "could not tell".
    #[test]
    fn a_refused_setup_step_is_evidence_and_silence_is_not() {
        let v = Verdict::setup_failed("read 1000H first", refused(true));
        assert!(v.error.is_none() && v.skip.is_none());
        assert_eq!(v.findings.len(), 1);
        assert_eq!(v.findings[0].severity, Severity::Deviation);
        assert!(v.findings[0].text.contains("cannot read 1000H first"));
        assert!(v.findings[0].text.contains("exception 02H"));
        assert_eq!(v.exchanges.len(), 1, "the frames are kept");

        let v = Verdict::setup_failed("read 1000H first", refused(false));
        assert!(v.error.is_none() && v.findings.is_empty());
        assert!(v.skip.as_deref().is_some_and(|s| s.contains("predicts")));

        let v = Verdict::setup_failed(
            "read 1000H first",
            SetupError::NoAnswer("reading 1 from 1000H: no reply".into()),
        );
        assert!(v.findings.is_empty() && v.skip.is_none());
        assert_eq!(
            v.error.as_deref(),
            Some("cannot read 1000H first: reading 1 from 1000H: no reply")
        );
    }
}
