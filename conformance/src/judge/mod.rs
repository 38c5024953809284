//! The judge of one conversation: a request, what came back and when, against what the
//! drive's model says. `check` (the runner), the fuzzer's oracle and `monitor` (which
//! listens to a bus it does not drive) all judge through here, so that one exchange gets
//! one verdict whoever saw it.
//!
//! The input, a [`Conversation`], does not depend on who sent the request: the mode, the
//! node, the request's bytes, the bytes that came back (split into what came before the
//! reply, the reply, and what came after), and the timing as far as the listener could
//! see it. The output, a [`Verdict`], is a status, the findings (each with its
//! [`Kind`] and severity), the manual's citations, the frame the model predicts, the
//! frame received and the positions where they differ.
//!
//! Findings are DEVIATIONs where the prediction rests only on documented or derived facts
//! (or on the frame format, which every manual documents), and OBSERVATIONs where it rests
//! on a decision of the model.

mod compare;
mod show;

use std::time::Duration;

pub use compare::{diff_positions, Known};
pub use show::{body_cow, body_of, describe_reply, explain_invalid, show};

use crate::codec::timing::LineSettings;
use crate::codec::Mode;
use crate::model::{Basis, DriveModel, Judgement};

/// How serious a finding is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
pub enum Severity {
    /// The manual is silent or contradicts itself; this is what the device did.
    Observation,
    /// The device does not do what the manual says.
    Deviation,
}

impl Severity {
    /// Deviation for binding facts, observation for decisions.
    pub fn of(basis: Basis) -> Self {
        if basis.binding() {
            Severity::Deviation
        } else {
            Severity::Observation
        }
    }
}

/// One thing a check found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Finding {
    /// Deviation or observation.
    pub severity: Severity,
    /// What, in words, with bytes in hex.
    pub text: String,
}

impl Finding {
    /// A deviation.
    pub fn deviation(text: impl Into<String>) -> Self {
        Finding {
            severity: Severity::Deviation,
            text: text.into(),
        }
    }

    /// An observation.
    pub fn observation(text: impl Into<String>) -> Self {
        Finding {
            severity: Severity::Observation,
            text: text.into(),
        }
    }
}

/// What kind of thing a finding is about: the key a listener counts errors by.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Kind {
    /// The reply is a valid frame but not the one the model predicts (function, length,
    /// count).
    WrongReply,
    /// An exception where the model predicts another code, or a normal reply.
    WrongException,
    /// The register values of a read differ from values known to be right.
    WrongValue,
    /// The reply carries another node's address.
    WrongAddress,
    /// No reply where one is due.
    NoReply,
    /// Bytes that hold no valid reply: a wrong CRC or LRC.
    BadChecksum,
    /// A reply cut short.
    Truncated,
    /// Bytes that are no frame.
    Malformed,
    /// Bytes before or after the reply.
    ExtraBytes,
    /// A reply where the model predicts silence (a broadcast, another node's request,
    /// a bad checksum).
    UnexpectedReply,
    /// The reply began later than the manual's response time (and the allowance).
    LateReply,
    /// The reply began sooner than t3.5 after the request.
    EarlyReply,
    /// A silence over t1.5 inside the reply.
    GapInReply,
    /// Answered only after a resend.
    Retried,
    /// The device did what a decision of the model says (the manual is silent).
    Decision,
}

impl Kind {
    /// Every kind, in the order of the enum.
    pub const ALL: [Kind; 15] = [
        Kind::WrongReply,
        Kind::WrongException,
        Kind::WrongValue,
        Kind::WrongAddress,
        Kind::NoReply,
        Kind::BadChecksum,
        Kind::Truncated,
        Kind::Malformed,
        Kind::ExtraBytes,
        Kind::UnexpectedReply,
        Kind::LateReply,
        Kind::EarlyReply,
        Kind::GapInReply,
        Kind::Retried,
        Kind::Decision,
    ];

    /// The kind as reports spell it.
    pub fn key(self) -> &'static str {
        match self {
            Kind::WrongReply => "wrong-reply",
            Kind::WrongException => "wrong-exception",
            Kind::WrongValue => "wrong-value",
            Kind::WrongAddress => "wrong-address",
            Kind::NoReply => "no-reply",
            Kind::BadChecksum => "bad-checksum",
            Kind::Truncated => "truncated",
            Kind::Malformed => "malformed",
            Kind::ExtraBytes => "extra-bytes",
            Kind::UnexpectedReply => "unexpected-reply",
            Kind::LateReply => "late-reply",
            Kind::EarlyReply => "early-reply",
            Kind::GapInReply => "gap-in-reply",
            Kind::Retried => "retried",
            Kind::Decision => "decision",
        }
    }
}

impl std::fmt::Display for Kind {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(self.key())
    }
}

/// When things happened, as far as the listener could see. Every instant is a time since
/// one origin of the listener's choosing (the runner's is the end of its request);
/// `None` where the listener could not see it (a tap adapter that delivered request and
/// reply in one piece blurs the silence between them).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Timing {
    /// When the request's last byte was on the line.
    pub request_end: Option<Duration>,
    /// The earliest the request's last byte can have been on the line, where the
    /// listener reads late and knows it (a tap: the read before it returned without
    /// it); `None`: `request_end` is exact. An early reply is judged from it, so that a
    /// request read late does not make its reply look early.
    pub request_end_earliest: Option<Duration>,
    /// When the first byte after the request came.
    pub first_byte: Option<Duration>,
    /// The earliest the first byte after the request can have come, where the listener
    /// reads late and knows it (a tap: the read before it returned without it); `None`:
    /// `first_byte` is exact. A late reply is judged from it, so that a reply read late
    /// (a listener's busy host) does not look late.
    pub first_byte_earliest: Option<Duration>,
    /// When the last byte of the reply came.
    pub last_byte: Option<Duration>,
    /// The largest silence between two bytes of the reply.
    pub max_gap: Option<Duration>,
    /// The silence on the line before the request began.
    pub silence_before: Option<Duration>,
    /// How long the listener waited for a reply.
    pub listened: Duration,
}

impl Timing {
    /// Time from the end of the request to the first byte after it.
    pub fn response_time(&self) -> Option<Duration> {
        Some(self.first_byte?.saturating_sub(self.request_end?))
    }
}

/// One request and what came back, whoever sent the request.
#[derive(Debug, Clone, Copy)]
pub struct Conversation<'a> {
    /// RTU or ASCII.
    pub mode: Mode,
    /// The node whose model judges the request (the drive the listener is about).
    pub node: u8,
    /// The request frame as it was on the line.
    pub request: &'a [u8],
    /// Every byte that came back after the request (a local echo of it removed).
    pub received: &'a [u8],
    /// Bytes of `received` before the reply frame.
    pub leading: &'a [u8],
    /// The reply frame (valid checksum), if one was found in `received`.
    pub reply: Option<&'a [u8]>,
    /// Bytes of `received` after the reply frame.
    pub trailing: &'a [u8],
    /// When.
    pub timing: Timing,
    /// Resends of the request before anything came back.
    pub retries: u32,
    /// What the link itself said meanwhile (a Modbus TCP gateway's exception in place of
    /// the device's reply).
    pub link_notes: &'a [String],
}

impl<'a> Conversation<'a> {
    /// A conversation with no reply and nothing known of its timing.
    pub fn new(mode: Mode, node: u8, request: &'a [u8]) -> Self {
        Conversation {
            mode,
            node,
            request,
            received: &[],
            leading: &[],
            reply: None,
            trailing: &[],
            timing: Timing::default(),
            retries: 0,
            link_notes: &[],
        }
    }

    /// The same conversation with `reply` as everything that came back.
    pub fn with_reply(mut self, reply: &'a [u8]) -> Self {
        self.received = reply;
        self.reply = Some(reply);
        self
    }

    /// The same conversation with `bytes` as everything that came back, but no valid
    /// reply among them (a wrong checksum, a frame cut short, noise).
    pub fn with_invalid(mut self, bytes: &'a [u8]) -> Self {
        self.received = bytes;
        self.reply = None;
        self
    }

    /// The same conversation with `timing`.
    pub fn with_timing(mut self, timing: Timing) -> Self {
        self.timing = timing;
        self
    }
}

/// The status of a verdict.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum VerdictStatus {
    /// The device did what the manual says.
    Pass,
    /// The manual is silent; this is what the device did.
    Observation,
    /// The manual says X, the device did Y.
    Deviation,
}

/// What the judge found in one conversation.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Verdict {
    /// What was found; empty when the device did what the model says.
    pub findings: Vec<Finding>,
    /// The kind of each finding the judge made, in the order of `findings` (a caller may
    /// add findings of its own after them, without a kind).
    pub kinds: Vec<Kind>,
    /// The frame the model predicts, where it can be built (values the judge does not
    /// know are taken from the reply).
    pub expected: Option<Vec<u8>>,
    /// The reply frame received, if a valid one came.
    pub received: Option<Vec<u8>>,
    /// Positions where `received` differs from `expected` (bytes one has beyond the
    /// other included).
    pub differing: Vec<usize>,
    /// The reply decoded, one line.
    pub actual: String,
    /// What the model predicts, with the basis: one line.
    pub predicted: String,
    /// The manual's citations for the prediction.
    pub citations: Vec<String>,
}

impl Verdict {
    /// Pass, observation or deviation: the most serious finding.
    pub fn status(&self) -> VerdictStatus {
        match self.worst() {
            None => VerdictStatus::Pass,
            Some(Severity::Observation) => VerdictStatus::Observation,
            Some(Severity::Deviation) => VerdictStatus::Deviation,
        }
    }

    /// The severity of the most serious finding; `None` where there is none.
    pub fn worst(&self) -> Option<Severity> {
        self.findings.iter().map(|f| f.severity).max()
    }

    /// The findings' texts in one line, joined by "; " (a fuzz finding's text).
    pub fn text(&self) -> String {
        self.findings
            .iter()
            .map(|f| f.text.as_str())
            .collect::<Vec<_>>()
            .join("; ")
    }

    /// The judge's findings with their kinds.
    pub fn found(&self) -> impl Iterator<Item = (Kind, &Finding)> {
        self.kinds.iter().copied().zip(&self.findings)
    }

    fn push(&mut self, kind: Kind, finding: Finding) {
        debug_assert_eq!(self.kinds.len(), self.findings.len());
        self.kinds.push(kind);
        self.findings.push(finding);
    }
}

/// The longest silence between two characters of one ASCII frame: Modbus over Serial Line
/// V1.02, 2.5.2.1 ("intervals of up to one second can elapse between characters"). ASCII
/// frames are delimited by ':' and CR LF, so neither t1.5 nor t3.5 applies to them.
pub const ASCII_CHARACTER_TIMEOUT: Duration = Duration::from_secs(1);

/// The longest silence inside a frame of `mode` on `line` before it counts: t1.5 plus
/// `allowance` in RTU, [`ASCII_CHARACTER_TIMEOUT`] in ASCII; with the rule it breaks.
pub fn gap_limit(mode: Mode, line: &LineSettings, allowance: Duration) -> (Duration, String) {
    (
        gap_limit_only(mode, line, allowance),
        gap_rule(mode, line, allowance),
    )
}

/// The limit of [`gap_limit`] alone (no words made).
fn gap_limit_only(mode: Mode, line: &LineSettings, allowance: Duration) -> Duration {
    match mode {
        Mode::Rtu => Duration::from_micros(line.t1_5_us()) + allowance,
        Mode::Ascii => ASCII_CHARACTER_TIMEOUT,
    }
}

/// The rule of [`gap_limit`], in words.
fn gap_rule(mode: Mode, line: &LineSettings, allowance: Duration) -> String {
    match mode {
        Mode::Rtu => format!(
            "over t1.5 ({} us + allowance {} us); Modbus over Serial Line V1.02, 2.5.1.1",
            line.t1_5_us(),
            allowance.as_micros()
        ),
        Mode::Ascii => "over the 1 s that may elapse between the characters of an ASCII frame; Modbus over Serial Line V1.02, 2.5.2.1".to_string(),
    }
}

/// How a listener that sees the line's timing judges it: the runner judges response
/// times over a whole mode (its `response-time` check), a monitor exchange by exchange.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct TimingRule {
    /// The line, where its timing is known (t1.5, t3.5, the character time).
    pub line: Option<LineSettings>,
    /// Allowance over the manual's response time before a reply counts as late (the
    /// host's and the adapter's delays).
    pub response_allowance: Duration,
    /// Allowance over t1.5 before a gap inside a reply counts.
    pub gap_allowance: Duration,
}

impl TimingRule {
    /// The latest a reply may begin after its request: the manual's response time (or
    /// t3.5 where that is longer), one character time (a UART hands over a byte after its
    /// stop bit) and the allowance; the rule of `check`'s response-time check.
    pub fn response_limit(&self, model: &DriveModel) -> Duration {
        let manual = model.response_time_on(self.line.as_ref());
        let first_char = self
            .line
            .map_or(Duration::ZERO, |l| Duration::from_micros(l.char_time_us()));
        manual + first_char + self.response_allowance
    }
}

/// The judge: a drive model, and how to judge timing.
#[derive(Debug, Clone, Copy)]
pub struct Judge<'m> {
    model: &'m DriveModel,
    timing: Option<TimingRule>,
}

impl<'m> Judge<'m> {
    /// A judge of conversations with drives of `model`; timing is not judged.
    pub fn new(model: &'m DriveModel) -> Self {
        Judge {
            model,
            timing: None,
        }
    }

    /// The same judge, also judging each conversation's timing by `rule`.
    pub fn with_timing(mut self, rule: TimingRule) -> Self {
        self.timing = Some(rule);
        self
    }

    /// The model.
    pub fn model(&self) -> &'m DriveModel {
        self.model
    }

    /// What the model says node `conv.node` does with the request.
    pub fn predict(&self, conv: &Conversation<'_>) -> Judgement {
        self.model.judge(conv.node, conv.mode, conv.request)
    }

    /// The verdict on `conv`. `known` gives, for a read, the values known to be right
    /// (None where any value is right) and the fact that says so. Where the device did
    /// what a decision of the model says, that is an observation (the manual does not
    /// settle it).
    pub fn verdict(&self, conv: &Conversation<'_>, known: Option<Known<'_>>) -> Verdict {
        let judgement = self.predict(conv);
        self.verdict_on(&judgement, conv, known)
    }

    /// [`Judge::verdict`] with the model's judgement already made (the runner makes it
    /// before sending, to know whether to wait for a reply).
    pub fn verdict_on(
        &self,
        judgement: &Judgement,
        conv: &Conversation<'_>,
        known: Option<Known<'_>>,
    ) -> Verdict {
        let mut v = self.untimed_verdict_on(judgement, conv, known);
        self.timing_findings(judgement, conv, |k, f| v.push(k, f));
        v
    }

    /// [`Judge::verdict_on`] without the findings on timing (response time, t3.5, gaps):
    /// what depends only on the bytes, the values known and, where nothing came back, how
    /// long the listener waited (`conv.timing.listened`). With
    /// [`Judge::timing_findings`] after it, the same findings in the same order as
    /// `verdict_on`: a listener that sees the same exchanges again may keep this part and
    /// judge the timing of each.
    pub fn untimed_verdict_on(
        &self,
        judgement: &Judgement,
        conv: &Conversation<'_>,
        known: Option<Known<'_>>,
    ) -> Verdict {
        compare::compare(self.model, judgement, conv, known, true)
    }

    /// Only the differences between `conv` and the judgement: [`Judge::verdict_on`]
    /// without the observation that the device did what a decision of the model says
    /// (the fuzzer's oracle, for which agreeing is no finding).
    pub fn differences(
        &self,
        judgement: &Judgement,
        conv: &Conversation<'_>,
        known: Option<Known<'_>>,
    ) -> Verdict {
        let mut v = compare::compare(self.model, judgement, conv, known, false);
        self.timing_findings(judgement, conv, |k, f| v.push(k, f));
        v
    }

    /// The findings on `conv`'s timing by the judge's rule (none without one), each
    /// handed to `out` in the order [`Judge::verdict_on`] lists them: a late or early
    /// reply, a gap inside it. Words are made only for findings.
    pub fn timing_findings(
        &self,
        judgement: &Judgement,
        conv: &Conversation<'_>,
        mut out: impl FnMut(Kind, Finding),
    ) {
        let Some(rule) = self.timing else {
            return;
        };
        if !judgement.expect.replies() || conv.received.is_empty() {
            return;
        }
        let ms = |d: Duration| d.as_secs_f64() * 1000.0;
        let stated = self
            .model
            .limits
            .response_time_ms
            .zip(self.model.limits.response_time_fact.as_ref());
        if let Some(rt) = conv.timing.response_time() {
            let limit = rule.response_limit(self.model);
            // The shortest the response time can have been, from what the listener read.
            let shortest = conv
                .timing
                .first_byte_earliest
                .zip(conv.timing.request_end)
                .map_or(rt, |(first, end)| first.saturating_sub(end).min(rt));
            // A description that states no response time holds no reply late.
            if let Some((stated_ms, source)) = stated.filter(|_| shortest > limit) {
                // Said where the reads leave a millisecond or more of doubt.
                let as_read = if rt.saturating_sub(shortest) >= Duration::from_millis(1) {
                    format!(
                        " as read (no sooner than {:.1} ms: the listener read it late)",
                        ms(shortest)
                    )
                } else {
                    String::new()
                };
                out(
                    Kind::LateReply,
                    Finding {
                        severity: Severity::of(source.basis),
                        text: format!(
                            "late reply: it began {:.1} ms after the request{as_read}; manual: {} ms{} (limit with one character and the allowance {:.1} ms). Source: {}",
                            ms(rt),
                            stated_ms,
                            rule.line.map_or(String::new(), |l| format!(
                                ", t3.5 on this line {:.1} ms",
                                l.t3_5_us() as f64 / 1000.0
                            )),
                            ms(limit),
                            source.citation()
                        ),
                    },
                );
            }
            // t3.5 delimits RTU frames only; an ASCII frame begins with its ':'.
            if let Some(line) = rule.line.filter(|_| conv.mode == Mode::Rtu) {
                // The listener reads the end of the request a little late: one character
                // of tolerance, as `check`'s line-timing check.
                let t35 = Duration::from_micros(line.t3_5_us());
                let tolerance = Duration::from_micros(line.char_time_us());
                // The longest the silence can have been, from what the listener read.
                let longest = conv
                    .timing
                    .first_byte
                    .zip(conv.timing.request_end_earliest)
                    .map_or(rt, |(first, end)| first.saturating_sub(end).max(rt));
                if longest + tolerance < t35 {
                    out(
                        Kind::EarlyReply,
                        Finding::deviation(format!(
                            "the reply began {} us after the request, sooner than t3.5 ({} us, less one character of tolerance); Modbus over Serial Line V1.02, 2.5.1.1",
                            longest.as_micros(),
                            t35.as_micros()
                        )),
                    );
                }
            }
        }
        if let (Some(gap), Some(line)) = (conv.timing.max_gap, rule.line) {
            if gap > gap_limit_only(conv.mode, &line, rule.gap_allowance) {
                out(
                    Kind::GapInReply,
                    Finding::deviation(format!(
                        "a silence of {} us inside the reply, {}",
                        gap.as_micros(),
                        gap_rule(conv.mode, &line, rule.gap_allowance)
                    )),
                );
            }
        }
    }
}

#[cfg(test)]
mod tests;
