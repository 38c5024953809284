//! Steering the campaign away from a hang it already knows.
//!
//! A device that hangs on one shape of request (a 10H whose byte count is over its data,
//! the planted `hang-on-byte-count`) costs seconds each time: the silence, the liveness
//! probes, the wait for it to answer again. The generator makes such cases again and
//! again (issue 33: 56 re-triggers in 3,581 cases, 20.9 cases/s against 1,094 on the
//! clean simulator). Once a hang is confirmed (minimized and replayed, or seen twice), a
//! case of its minimized frame's shape is still sent until [`HANG_RETRIGGERS`] more hangs
//! have shown how often that shape hangs the device; after that such cases are not sent,
//! and are counted. The time every hang cost is counted too.

use std::collections::BTreeMap;
use std::time::Duration;

use serde_json::{json, Value};

use super::cases::Step;
use super::{FuzzFinding, Kind};
use crate::codec::{frame_parts, Mode};

/// Hangs of a known shape still let happen after the hang is confirmed, to measure how
/// often that shape hangs the device; cases of the shape are not sent after that.
pub const HANG_RETRIGGERS: u64 = 2;

/// Why a case is not sent where it has the shape of a known hang (counted with the cases
/// not sent).
pub const STEERED_AWAY: &str =
    "the shape of a known hang, whose re-trigger budget is spent (steered away)";

/// A known hang's shape and what became of the cases of that shape.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct KnownHang {
    /// The finding's signature.
    pub signature: String,
    /// The shape: function code and what is odd about the request (see [`shape_of`]).
    pub shape: String,
    /// Cases of the shape sent after the hang was confirmed.
    pub sent: u64,
    /// Of them, the ones that hung the device again.
    pub retriggers: u64,
    /// Cases of the shape not sent (the budget spent).
    pub steered: u64,
}

/// What the campaign knows about hangs, and what they cost.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct Steering {
    /// Confirmed hangs by shape.
    pub known: BTreeMap<String, KnownHang>,
    /// Every hang of the campaign (the first of each signature included).
    pub hangs: u64,
    /// What they cost: from sending the case to the device answering again (the silence,
    /// the liveness probes, the recovery wait; not the replays that minimize).
    pub cost: Duration,
}

/// The shape of a step: the function code of its first frame and what was odd about it
/// (the field class a hang's signature names: `byte-count-over-data`, `bad-checksum`,
/// `back-to-back`, a timing damage class...).
pub fn shape_of(mode: Mode, step: &Step) -> String {
    let function = step
        .frames()
        .first()
        .and_then(|f| frame_parts(mode, f).ok())
        .and_then(|p| p.body.get(1).copied());
    let odd = super::signature::of_request(mode, step);
    match function {
        Some(fc) => format!("{fc:02X}H {odd}"),
        None => odd,
    }
}

impl Steering {
    /// Whether a case of `step` is to be sent: not where its shape is a known hang's
    /// whose re-trigger budget is spent (then it is counted as steered away).
    pub fn admits(&mut self, mode: Mode, step: &Step) -> bool {
        if self.known.is_empty() {
            return true;
        }
        match self.known.get_mut(&shape_of(mode, step)) {
            Some(k) if k.retriggers >= HANG_RETRIGGERS => {
                k.steered += 1;
                false
            }
            Some(k) => {
                k.sent += 1;
                true
            }
            None => true,
        }
    }

    /// A case of `step` hung the device, which answered again after `cost` (or not).
    pub fn hung(&mut self, mode: Mode, step: &Step, cost: Duration) {
        self.hangs += 1;
        self.cost = self.cost.saturating_add(cost);
        if let Some(k) = self.known.get_mut(&shape_of(mode, step)) {
            if k.sent > 0 {
                k.retriggers += 1;
            }
        }
    }

    /// `f` (a hang) is confirmed: replayed from its minimized frames, or seen again.
    pub fn confirm(&mut self, mode: Mode, f: &FuzzFinding) {
        if f.kind != Kind::Hang {
            return;
        }
        let frames = if f.minimized.is_empty() {
            &f.frames
        } else {
            &f.minimized
        };
        let step = match (&f.timed, frames.as_slice()) {
            (Some(t), _) => Step::Timed(t.clone()),
            (None, [one]) => Step::Frame(one.clone()),
            (None, many) => Step::Burst(many.to_vec()),
        };
        let shape = shape_of(mode, &step);
        self.known
            .entry(shape.clone())
            .or_insert_with(|| KnownHang {
                signature: f.signature(),
                shape,
                ..KnownHang::default()
            });
    }

    /// Cases not sent because of a known hang.
    pub fn steered(&self) -> u64 {
        self.known.values().map(|k| k.steered).sum()
    }

    /// One clause for the campaign's summary; `None` where there was no hang.
    pub fn describe(&self) -> Option<String> {
        if self.hangs == 0 {
            return None;
        }
        let mut s = format!(
            "{} hang(s) cost {:.1} s (silence, liveness probes, recovery)",
            self.hangs,
            self.cost.as_secs_f64()
        );
        for k in self.known.values() {
            s.push_str(&format!(
                "; known hang {} ({}): {} of the {} case(s) of its shape sent once it was known hung the device again, {} were not sent (budget: {HANG_RETRIGGERS} re-triggers)",
                k.signature, k.shape, k.retriggers, k.sent, k.steered
            ));
        }
        Some(s)
    }

    /// The `hangs` object of a mode in the JSON report.
    pub fn to_json(&self) -> Value {
        json!({
            "count": self.hangs,
            "cost_ms": (self.cost.as_secs_f64() * 10_000.0).round() / 10.0,
            "retrigger_budget": HANG_RETRIGGERS,
            "known": self.known.values().map(|k| json!({
                "signature": k.signature,
                "shape": k.shape,
                "sent": k.sent,
                "retriggers": k.retriggers,
                "steered": k.steered,
            })).collect::<Vec<_>>(),
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::frame_of_body;

    fn frame(body: &[u8]) -> Step {
        Step::Frame(frame_of_body(Mode::Rtu, body).unwrap())
    }

    fn hang(minimized: Step) -> FuzzFinding {
        let Step::Frame(f) = minimized else {
            unreachable!()
        };
        FuzzFinding {
            kind: Kind::Hang,
            mode: Mode::Rtu,
            function: 0x10,
            field: "byte-count-over-data".into(),
            classes: Default::default(),
            count: 1,
            first_case: 3,
            frames: vec![f.clone()],
            burst: false,
            timed: None,
            minimized: vec![f],
            reproduced: true,
            replays: 2,
            text: String::new(),
            severity: crate::runner::Severity::Deviation,
            exchange: None,
            recovery: None,
            register: None,
            replay: String::new(),
        }
    }

    #[test]
    fn a_known_hang_is_retriggered_within_its_budget_then_steered_away_from() {
        let over = |bc: u8, data: &[u8]| {
            let mut b = vec![1, 0x10, 0x25, 0x02, 0, 1, bc];
            b.extend_from_slice(data);
            frame(&b)
        };
        let mut s = Steering::default();
        let first = over(2, &[]);
        assert!(s.admits(Mode::Rtu, &first));
        s.hung(Mode::Rtu, &first, Duration::from_secs(6));
        s.confirm(Mode::Rtu, &hang(first));
        // Another frame of the same shape (a byte count over its data, other values).
        let same = over(9, &[0, 0]);
        let well_formed = over(2, &[0, 7]);
        let read = frame(&[1, 3, 0x25, 0x20, 0, 1]);
        for _ in 0..HANG_RETRIGGERS {
            assert!(s.admits(Mode::Rtu, &same));
            s.hung(Mode::Rtu, &same, Duration::from_secs(6));
        }
        // The budget is spent: that shape is not sent again; other shapes are.
        for _ in 0..5 {
            assert!(!s.admits(Mode::Rtu, &same));
            assert!(s.admits(Mode::Rtu, &well_formed));
            assert!(s.admits(Mode::Rtu, &read));
        }
        let k = s.known.values().next().unwrap();
        assert_eq!(
            (k.sent, k.retriggers, k.steered),
            (HANG_RETRIGGERS, HANG_RETRIGGERS, 5)
        );
        assert_eq!(k.shape, "10H byte-count-over-data");
        assert_eq!(s.hangs, 1 + HANG_RETRIGGERS);
        assert_eq!(s.cost, Duration::from_secs(6 * (1 + HANG_RETRIGGERS)));
        assert!(s.describe().unwrap().starts_with("3 hang(s) cost 18.0 s"));
    }
}
