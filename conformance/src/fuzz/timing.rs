//! Timing damage: frames whose characters are on time but whose silences are not.
//!
//! An RTU receiver finds frames by silence (Modbus over Serial Line V1.02, 2.5.1.1): more
//! than t1.5 between two characters makes the frame incomplete (discarded), t3.5 ends it.
//! Only a link with line timing carries a silence the device can measure: a real port,
//! or the simulator's paced pseudo-terminal (which frames by silence, see
//! [`crate::sim::line_clock`]). On links without timing (an unpaced pseudo-terminal, TCP)
//! and in ASCII (whose frames are delimited by characters, with a 1 s inter-character
//! timeout) these cases are not generated, and the report says why.
//!
//! The classes, each a field class of its own in the finding signatures:
//!
//! - `timing.gap-in-frame`: a request the device answers, with a silence between t1.5 and
//!   t3.5 at one position: the frame must be discarded; the model predicts silence
//!   (documented: 2.5.1.1).
//! - `timing.split-under-t15`: the same request with a silence well under t1.5 at one
//!   position: one frame; the model predicts what it predicts for the request.
//! - `timing.split-over-t35`: the same request with a silence over t3.5 at one position:
//!   two fragments, each a frame with a wrong CRC: silence (documented).
//! - `timing.no-t35`: two requests without t3.5 between them (back to back, or with a
//!   silence between t1.5 and t3.5): by the standard one frame with a wrong CRC (or an
//!   incomplete one), so silence. Receivers that find frames by the length the function
//!   implies answer the first; the manuals do not say how the drives frame, so this is
//!   a decision of the model (an observation where a device differs, not a deviation).
//!
//! The positions sweep every byte boundary of the frame in turn. The gaps keep clear of
//! t1.5 and t3.5 by a margin; a send whose gap the host moved past its tolerance (or that
//! the host broke inside a piece) is sent again before it is judged, and a difference is
//! a finding only if it is seen again on two replays (host scheduling can move a silence
//! on an emulated line, a device bug does not go away).

use std::time::Duration;

use super::state::{Observed, State};
use super::Kind;
use crate::codec::timing::LineSettings;
use crate::codec::Mode;
use crate::judge::{self, Judge, Severity};
use crate::model::{Basis, Expectation, Fact, Judgement, SilenceReason};
use crate::runner::{Ctx, RunError};
use crate::transport::LinkKind;

/// What a timing case does to its frames.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Damage {
    /// A silence between t1.5 and t3.5 inside one frame.
    GapInFrame,
    /// A silence under t1.5 inside one frame.
    SplitUnderT15,
    /// A silence over t3.5 inside one frame.
    SplitOverT35,
    /// Two frames with less than t3.5 between them.
    NoT35,
}

impl Damage {
    /// The field class.
    pub fn class(self) -> &'static str {
        match self {
            Damage::GapInFrame => "timing.gap-in-frame",
            Damage::SplitUnderT15 => "timing.split-under-t15",
            Damage::SplitOverT35 => "timing.split-over-t35",
            Damage::NoT35 => "timing.no-t35",
        }
    }

    /// All of them.
    pub const ALL: [Damage; 4] = [
        Damage::GapInFrame,
        Damage::SplitUnderT15,
        Damage::SplitOverT35,
        Damage::NoT35,
    ];
}

/// One timing case: frames sent as one transmission cut at `cuts`, with `gap_us` of
/// silence at each cut.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Timed {
    /// What it does.
    pub damage: Damage,
    /// The frames (one, or two for `no-t35`), whole.
    pub frames: Vec<Vec<u8>>,
    /// Byte positions in the frames' concatenation where a silence goes.
    pub cuts: Vec<usize>,
    /// The silence at each cut, in microseconds.
    pub gap_us: u64,
    /// How far the host may move the silence before the case is sent again.
    pub tolerance_us: u64,
}

impl Timed {
    /// The bytes on the line, without their timing.
    pub fn bytes(&self) -> Vec<u8> {
        self.frames.concat()
    }

    /// The command-line options of `conformance send` that replay the timing.
    pub fn send_options(&self) -> String {
        let cuts: Vec<String> = self.cuts.iter().map(ToString::to_string).collect();
        format!("--split {} --gap {}us", cuts.join(","), self.gap_us)
    }
}

/// The silences used on `line`, in microseconds: (under t1.5, between t1.5 and t3.5,
/// over t3.5), each with the tolerance within which the host must keep it.
pub fn gaps(line: &LineSettings) -> [(u64, u64); 3] {
    let t15 = line.t1_5_us();
    let t35 = line.t3_5_us();
    let mid = (t15 + t35) / 2;
    [
        // Half of t1.5: the host may move it by up to 40% of t1.5 and stay under.
        (t15 / 2, t15 * 2 / 5),
        // Half-way between t1.5 and t3.5.
        (mid, (t35 - t15) * 2 / 5),
        // t3.5 + t1.5.
        (t35 + t15, t15 * 4 / 5),
    ]
}

/// Why timing cases cannot be sent on this link in this mode, if they cannot.
pub fn unavailable(ctx: &Ctx<'_>) -> Option<&'static str> {
    if ctx.mode != Mode::Rtu {
        return Some("ASCII frames are delimited by ':' and CR LF, not by silences (2.5.2.1)");
    }
    if ctx.line_timing().is_none() {
        return Some(match ctx.link_kind() {
            LinkKind::Tcp => "TCP carries no line timing",
            _ => "the link has no line timing (a pseudo-terminal without pacing)",
        });
    }
    None
}

/// The sweep of positions, one counter per damage, so that every byte boundary of a
/// frame is cut in turn.
#[derive(Debug, Clone, Default)]
pub struct Sweep {
    next: [usize; 4],
}

impl Sweep {
    /// The next timing case of `damage` on `line`: `frame` (and `second` for `no-t35`)
    /// requests the device answers. None for a frame too short to cut.
    pub fn make(
        &mut self,
        line: &LineSettings,
        damage: Damage,
        frame: Vec<u8>,
        second: Vec<u8>,
        back_to_back: bool,
    ) -> Option<Timed> {
        if frame.len() < 2 {
            return None;
        }
        let [under, between, over] = gaps(line);
        let i = Damage::ALL.iter().position(|d| *d == damage).unwrap_or(0);
        let pos = 1 + self.next[i] % (frame.len() - 1);
        self.next[i] += 1;
        let (frames, cut, (gap_us, tolerance_us)) = match damage {
            Damage::GapInFrame => (vec![frame], pos, between),
            Damage::SplitUnderT15 => (vec![frame], pos, under),
            Damage::SplitOverT35 => (vec![frame], pos, over),
            Damage::NoT35 => {
                let n = frame.len();
                let g = if back_to_back {
                    (0, line.t1_5_us() * 3 / 5)
                } else {
                    between
                };
                (vec![frame, second], n, g)
            }
        };
        Some(Timed {
            damage,
            frames,
            cuts: vec![cut],
            gap_us,
            tolerance_us,
        })
    }
}

/// The model's prediction for a timing case: what the device does with the bytes as the
/// standard frames them.
pub fn predict(ctx: &Ctx<'_>, t: &Timed) -> Judgement {
    predict_for(ctx.model, ctx.opts.address, ctx.mode, t)
}

/// What a silence of `gap_us` at `cuts` in `frames` is, on `line` (for `conformance
/// send --split`): two or more frames cut only where one ends, with less than t3.5,
/// are frames without t3.5; otherwise the silence decides.
pub fn classify(line: &LineSettings, frames: &[Vec<u8>], cuts: &[usize], gap_us: u64) -> Damage {
    let mut ends = Vec::new();
    let mut at = 0;
    for f in frames.iter().take(frames.len().saturating_sub(1)) {
        at += f.len();
        ends.push(at);
    }
    if frames.len() > 1 && gap_us < line.t3_5_us() && cuts.iter().all(|c| ends.contains(c)) {
        return Damage::NoT35;
    }
    if gap_us >= line.t3_5_us() {
        Damage::SplitOverT35
    } else if gap_us > line.t1_5_us() {
        Damage::GapInFrame
    } else {
        Damage::SplitUnderT15
    }
}

/// [`predict`] for a drive of `model` at `address`.
pub fn predict_for(
    model: &crate::model::DriveModel,
    address: u8,
    mode: Mode,
    t: &Timed,
) -> Judgement {
    let whole = t.bytes();
    let silence = |detail: String, fact: Fact| Judgement {
        expect: Expectation::Silence(SilenceReason::BadChecksum),
        write: None,
        facts: vec![fact],
        detail,
        missing: vec![],
    };
    let t15_fact = || {
        Fact {
        basis: Basis::Documented,
        source: Some("Modbus over Serial Line V1.02, 2.5.1.1: \"if a silent interval of more than 1.5 character times occurs between two characters, the message frame is declared incomplete and should be discarded by the receiver\"".into()),
        rule: None,
        why: None,
    }
    };
    match t.damage {
        Damage::SplitUnderT15 => model.judge(address, mode, &whole),
        Damage::GapInFrame => silence(
            format!(
                "a silence of {} us (over t1.5, under t3.5) after byte {}: the frame is incomplete and discarded",
                t.gap_us,
                t.cuts.first().copied().unwrap_or(0)
            ),
            t15_fact(),
        ),
        Damage::SplitOverT35 => {
            // Two frames by the standard; each judged as it is (a fragment has a wrong
            // CRC, unless by chance it has not).
            let cut = t.cuts.first().copied().unwrap_or(0).min(whole.len());
            let (a, b) = whole.split_at(cut);
            let ja = model.judge(address, mode, a);
            let jb = model.judge(address, mode, b);
            if ja.expect.replies() {
                return ja;
            }
            if jb.expect.replies() {
                return jb;
            }
            silence(
                format!(
                    "a silence of {} us (over t3.5) after byte {cut}: two fragments, neither a frame ({}; {})",
                    t.gap_us, ja.detail, jb.detail
                ),
                Fact {
                    basis: Basis::Documented,
                    source: Some("Modbus over Serial Line V1.02, 2.5.1.1: a silent interval of at least 3.5 character times ends a frame; the CRC of each part is wrong".into()),
                    rule: None,
                    why: None,
                },
            )
        }
        Damage::NoT35 => silence(
            format!(
                "{} frames with {} us between them (less than t3.5): one frame by the standard, {} bytes with a wrong CRC{}",
                t.frames.len(),
                t.gap_us,
                whole.len(),
                if t.gap_us > 0 { ", and incomplete (a silence over t1.5 inside it)" } else { "" }
            ),
            Fact {
                basis: Basis::Decision,
                source: Some("Modbus over Serial Line V1.02, 2.5.1.1: frames are separated by a silent interval of at least 3.5 character times".into()),
                rule: None,
                why: Some("the manuals do not say how the drives find the end of a frame; a receiver that frames by silence (as the standard describes) takes frames less than t3.5 apart as one frame with a wrong CRC and stays silent, one that frames by the length the function implies answers the first: the model follows the standard, and a device that answers is an observation".into()),
            },
        ),
    }
}

/// Sends a timing case once and compares with the prediction.
fn once(ctx: &mut Ctx<'_>, t: &Timed) -> Result<Option<Observed>, RunError> {
    let judgement = predict(ctx, t);
    let whole = t.bytes();
    let (ex, _, _) = ctx.exchange_split(
        &whole,
        &t.cuts,
        Duration::from_micros(t.gap_us),
        Duration::from_micros(t.tolerance_us),
        judgement.expect.replies(),
    )?;
    let diff = Judge::new(ctx.model).differences(
        &judgement,
        &ex.conversation(ctx.mode, ctx.opts.address),
        None,
    );
    if diff.findings.is_empty() {
        return Ok(None);
    }
    let rx_empty = ex.after_echo().is_empty();
    let kind = match (&judgement.expect, rx_empty) {
        (Expectation::Silence(_), _) => Kind::UnexpectedReply,
        (_, true) => Kind::NoReply,
        _ => Kind::Mismatch,
    };
    let severity = diff.worst().unwrap_or(Severity::Deviation);
    let mut text = format!(
        "{} sent with {} us of silence after byte(s) {:?}: ",
        judge::show(ctx.mode, &whole),
        t.gap_us,
        t.cuts
    );
    text.push_str(&diff.text());
    let record = crate::runner::ExchangeRecord {
        request: whole,
        expected: diff.expected.clone(),
        received: ex.raw.clone(),
        reply: ex.reply.clone(),
        predicted: judgement.expect.describe(),
        actual: diff.actual.clone(),
        latency: ex.first_byte,
    };
    Ok(Some(Observed {
        kind,
        severity,
        text,
        exchange: Some(record),
        register: None,
        recovery: None,
        field: t.damage.class().into(),
    }))
}

/// Sends a timing case and judges it; a difference is confirmed by two replays (see the
/// module's notes). An unconfirmed difference is counted in `state`, not reported.
pub fn observe(
    ctx: &mut Ctx<'_>,
    t: &Timed,
    state: &mut State,
) -> Result<Option<Observed>, RunError> {
    let Some(first) = once(ctx, t)? else {
        return Ok(None);
    };
    for _ in 0..2 {
        match once(ctx, t)? {
            Some(o) if o.kind == first.kind => {}
            _ => {
                state.timing_unconfirmed += 1;
                return Ok(None);
            }
        }
    }
    Ok(Some(first))
}

/// The least time a timing case needs on the line (for the campaign's bound).
pub fn line_time(ctx: &Ctx<'_>, t: &Timed, replied: bool) -> Duration {
    let Some(line) = ctx.line_timing() else {
        return Duration::ZERO;
    };
    let ch = Duration::from_micros(line.char_time_us());
    let t35 = Duration::from_micros(line.t3_5_us());
    let n = |k: usize| ch * u32::try_from(k).unwrap_or(u32::MAX);
    let gaps = Duration::from_micros(t.gap_us) * u32::try_from(t.cuts.len()).unwrap_or(1);
    let sent = n(t.bytes().len()) + gaps + t35;
    if replied {
        sent + ctx.model.response_delay(&line) + n(8) + t35
    } else {
        // The silence window and the liveness probe after it.
        sent + ctx.silence_window() + n(15) + t35 * 2 + ctx.model.response_delay(&line)
    }
}

/// Shrinks a timing finding: the same damage on the shortest request the device
/// answers (the liveness read), at the first cut position that still reproduces it.
/// Returns the reproducer and the replays spent.
pub fn minimize(
    ctx: &mut Ctx<'_>,
    t: &Timed,
    kind: Kind,
    state: &mut State,
    max_replays: u32,
) -> (Timed, bool, u32) {
    let mut replays = 0;
    let mut best = t.clone();
    let mut reproduced = false;
    let probe = crate::runner::liveness::liveness_register(ctx.model, ctx.opts.address, ctx.mode)
        .map(|r| ctx.frame(crate::codec::pdu::Pdu::ReadRequest { start: r, count: 1 }));
    let mut candidates = Vec::new();
    if let Some(p) = probe {
        let base = match t.damage {
            Damage::NoT35 => vec![p.clone(), p.clone()],
            _ => vec![p.clone()],
        };
        let len = p.len();
        let mut positions: Vec<usize> = match t.damage {
            Damage::NoT35 => vec![len],
            _ => (1..len).collect(),
        };
        // The case's own position first (if it fits the shorter frame).
        if let Some(&c) = t.cuts.first() {
            if c < len && t.damage != Damage::NoT35 {
                positions.retain(|&x| x != c);
                positions.insert(0, c);
            }
        }
        for c in positions {
            candidates.push(Timed {
                frames: base.clone(),
                cuts: vec![c],
                ..t.clone()
            });
        }
    }
    for c in candidates {
        if replays >= max_replays {
            break;
        }
        replays += 1;
        let _ = super::state::recover(ctx, Duration::from_secs(10));
        if matches!(observe(ctx, &c, state), Ok(Some(o)) if o.kind == kind) {
            best = c;
            reproduced = true;
            break;
        }
    }
    if !reproduced && replays < max_replays {
        replays += 1;
        reproduced = matches!(observe(ctx, t, state), Ok(Some(o)) if o.kind == kind);
    }
    (best, reproduced, replays)
}

/// What the timing damage of a mode did.
#[derive(Debug, Clone, Default)]
pub struct TimingStats {
    /// Cases sent, by class.
    pub sent: std::collections::BTreeMap<&'static str, u64>,
    /// Differences not seen again on replay (host scheduling), not reported as findings.
    pub unconfirmed: u64,
    /// Requests sent again because the host stalled inside a piece or moved a gap past
    /// its tolerance (all requests of the mode, timing cases or not).
    pub resent: u64,
    /// Why no timing case was sent, where none could be.
    pub not_sent: Option<&'static str>,
}

impl TimingStats {
    /// One sentence for the text report.
    pub fn describe(&self) -> String {
        if let Some(why) = self.not_sent {
            return format!("timing damage not sent: {why}");
        }
        let total: u64 = self.sent.values().sum();
        let by: Vec<String> = self.sent.iter().map(|(c, n)| format!("{c} {n}")).collect();
        format!(
            "timing damage: {total} case(s) ({}), {} difference(s) not seen again on replay, {} request(s) sent again after a host stall",
            if by.is_empty() { "none".to_string() } else { by.join(", ") },
            self.unconfirmed,
            self.resent
        )
    }

    /// The `timing` object of a mode in the JSON report.
    pub fn to_json(&self) -> serde_json::Value {
        serde_json::json!({
            "sent": self.sent,
            "unconfirmed": self.unconfirmed,
            "resent": self.resent,
            "not_sent": self.not_sent,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::timing::Parity;

    #[test]
    fn the_gaps_keep_clear_of_t15_and_t35_within_their_tolerance() {
        for baud in [1200, 2400, 4800, 9600, 19200, 38400, 115200] {
            let line = LineSettings::new(baud, 8, Parity::Even, 1);
            let (t15, t35) = (line.t1_5_us(), line.t3_5_us());
            let [(u, ut), (m, mt), (o, ot)] = gaps(&line);
            assert!(u + ut < t15, "{baud}: under");
            assert!(m - mt > t15 && m + mt < t35, "{baud}: between");
            assert!(o - ot > t35, "{baud}: over");
        }
    }

    #[test]
    fn the_sweep_cuts_every_byte_boundary_in_turn() {
        let line = LineSettings::new(9600, 8, Parity::Even, 1);
        let mut s = Sweep::default();
        let f = vec![1u8, 3, 0x25, 0x20, 0, 1, 0x8E, 0xCC];
        let cuts: Vec<usize> = (0..8)
            .map(|_| {
                s.make(&line, Damage::GapInFrame, f.clone(), Vec::new(), false)
                    .unwrap()
                    .cuts[0]
            })
            .collect();
        assert_eq!(cuts, vec![1, 2, 3, 4, 5, 6, 7, 1]);
        let t = s
            .make(&line, Damage::NoT35, f.clone(), f.clone(), true)
            .unwrap();
        assert_eq!((t.cuts[0], t.gap_us, t.bytes().len()), (8, 0, 16));
    }
}
