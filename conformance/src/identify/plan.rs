//! Which reads to send: derived from the models, not from a hand list.
//!
//! [`candidates`] collects read requests at the places where the models' register maps,
//! limits and exception tables can differ: the identification register, registers outside
//! every map, the first and last register of every group and range and the ones just
//! outside them, the "-" registers, alias spellings, reads up to and one past a range's
//! end, and each model's read limit and one over it. Every candidate is judged by every
//! model ([`Prediction::of`]); [`plan`] keeps those on which some models' predictions
//! exclude each other, and picks greedily the one that tells apart the most pairs of
//! models still short of `cover` distinguishing probes, until every pair has its `cover`
//! or no candidate helps.

use std::collections::BTreeMap;

use super::predict::Prediction;
use crate::codec::pdu::{Message, Pdu};
use crate::codec::Mode;
use crate::model::{Basis, DriveModel};

/// What a probe is about.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum ProbeKind {
    /// The identification register.
    Identification,
    /// A register outside every model's map: the exception numbering.
    OutsideEveryMap,
    /// Registers marked "-" (no Modbus access).
    NoAccess,
    /// The border of a register group or range (group sizes, gaps, the two-word
    /// register, reserved blocks, example registers).
    MapBorder,
    /// Another spelling of a block of registers.
    Alias,
    /// The register count: zero, a model's read limit, one over it.
    ReadLimit,
}

impl ProbeKind {
    /// A short name, as reports show it.
    pub fn key(self) -> &'static str {
        match self {
            ProbeKind::Identification => "identification register",
            ProbeKind::OutsideEveryMap => "outside every map",
            ProbeKind::NoAccess => "'-' register",
            ProbeKind::MapBorder => "map border",
            ProbeKind::Alias => "alias",
            ProbeKind::ReadLimit => "read limit",
        }
    }
}

/// A read request the models may disagree about.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Candidate {
    /// First register.
    pub start: u16,
    /// Register count.
    pub count: u16,
    /// What it is about.
    pub kind: ProbeKind,
    /// Why it is a candidate, with the model and the registers it comes from.
    pub why: String,
}

/// One model's prediction for a probe.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModelPrediction {
    /// The model.
    pub model: String,
    /// What it predicts.
    pub prediction: Prediction,
    /// The judgement's reason, with registers in hex.
    pub detail: String,
    /// The weakest basis of the facts it rests on.
    pub basis: Basis,
}

/// A read to send, with every model's prediction.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Probe {
    /// The candidate.
    pub candidate: Candidate,
    /// The request frame.
    pub frame: Vec<u8>,
    /// One per model, in the order of the models given.
    pub predictions: Vec<ModelPrediction>,
}

impl Probe {
    /// The pairs of models (indices) this probe tells apart.
    pub fn splits(&self) -> Vec<(usize, usize)> {
        let mut out = Vec::new();
        for i in 0..self.predictions.len() {
            for j in i + 1..self.predictions.len() {
                if self.predictions[i]
                    .prediction
                    .excludes(&self.predictions[j].prediction)
                {
                    out.push((i, j));
                }
            }
        }
        out
    }
}

/// How many probes to choose.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct PlanLimits {
    /// Distinguishing probes wanted for every pair of models.
    pub cover: usize,
    /// Most probes in one mode.
    pub max_probes: usize,
}

impl Default for PlanLimits {
    fn default() -> Self {
        PlanLimits {
            cover: 3,
            max_probes: 32,
        }
    }
}

/// The probes for `models` in `mode` at node `address`, and how many candidates the
/// models disagree on.
pub fn plan(
    models: &[&DriveModel],
    mode: Mode,
    address: u8,
    limits: PlanLimits,
) -> (Vec<Probe>, usize) {
    let mut pool: Vec<Probe> = candidates(models, mode)
        .into_iter()
        .filter_map(|c| judge(models, mode, address, c))
        .collect();
    // The identification register is read whatever it splits: its value is the
    // evidence a person looks for first, and a device that reads something other than
    // a documented value rules that model out.
    let mut chosen: Vec<Probe> = Vec::new();
    pool.retain(|p| {
        if p.candidate.kind == ProbeKind::Identification && p.candidate.count == 1 {
            chosen.push(p.clone());
            false
        } else {
            true
        }
    });
    pool.retain(|p| !p.splits().is_empty());
    let disagreeing = pool.len();
    let n = models.len();
    let mut need: BTreeMap<(usize, usize), usize> = BTreeMap::new();
    for i in 0..n {
        for j in i + 1..n {
            need.insert((i, j), limits.cover);
        }
    }
    for p in &chosen {
        for s in p.splits() {
            if let Some(k) = need.get_mut(&s) {
                *k = k.saturating_sub(1);
            }
        }
    }
    // One probe of each kind of evidence that tells some pair apart (the exception
    // numbering, the read limits, the '-' registers, the alias block, the map borders),
    // so that the verdict never rests on one kind alone; then the best, whatever kind.
    let kinds = [
        ProbeKind::OutsideEveryMap,
        ProbeKind::ReadLimit,
        ProbeKind::NoAccess,
        ProbeKind::Alias,
        ProbeKind::MapBorder,
    ];
    let every_pair: BTreeMap<(usize, usize), usize> = need.keys().map(|&k| (k, 1)).collect();
    for kind in kinds.into_iter().map(Some).chain(std::iter::repeat(None)) {
        if chosen.len() >= limits.max_probes {
            break;
        }
        // A kind's probe is the one that tells most pairs apart; the rest go by the
        // pairs still short of their cover.
        let wanted = if kind.is_some() { &every_pair } else { &need };
        let Some(i) = best(&pool, wanted, kind) else {
            if kind.is_none() {
                break;
            }
            continue;
        };
        let p = pool.remove(i);
        for s in p.splits() {
            if let Some(k) = need.get_mut(&s) {
                *k = k.saturating_sub(1);
            }
        }
        chosen.push(p);
    }
    (chosen, disagreeing)
}

/// The index in `pool` of the probe (of `kind`, if given) that tells apart the most pairs
/// still short of their cover; `None` where none tells apart any.
fn best(
    pool: &[Probe],
    need: &BTreeMap<(usize, usize), usize>,
    kind: Option<ProbeKind>,
) -> Option<usize> {
    use std::cmp::Reverse;
    let (gain, .., Reverse(i)) = pool
        .iter()
        .enumerate()
        .filter(|(_, p)| kind.is_none_or(|k| p.candidate.kind == k))
        .map(|(i, p)| {
            let gain = p
                .splits()
                .iter()
                .filter(|s| need.get(s).is_some_and(|&k| k > 0))
                .count();
            let binding = p.predictions.iter().filter(|m| m.basis.binding()).count();
            // Most pairs still wanted; then predictions that rest on the manuals rather
            // than on the models' decisions; then the kinds a person names first; then
            // the shortest read; then the first found.
            (
                gain,
                binding,
                Reverse(p.candidate.kind),
                Reverse(p.candidate.count),
                Reverse(i),
            )
        })
        .max()?;
    (gain > 0).then_some(i)
}

/// `candidate` judged by every model; `None` where it cannot be framed.
fn judge(models: &[&DriveModel], mode: Mode, address: u8, candidate: Candidate) -> Option<Probe> {
    let frame = Message {
        address,
        pdu: Pdu::ReadRequest {
            start: candidate.start,
            count: candidate.count,
        },
    }
    .to_frame_vec(mode)
    .ok()?;
    let predictions = models
        .iter()
        .map(|m| {
            let (prediction, j) = Prediction::of(m, address, mode, &frame);
            ModelPrediction {
                model: m.id.clone(),
                prediction,
                basis: j.basis(),
                detail: j.detail,
            }
        })
        .collect();
    Some(Probe {
        candidate,
        frame,
        predictions,
    })
}

/// Every read worth asking the models about, each (start, count) once.
pub fn candidates(models: &[&DriveModel], mode: Mode) -> Vec<Candidate> {
    let mut out: Vec<Candidate> = Vec::new();
    let mut add = |start: Option<u16>, count: u16, kind: ProbeKind, why: String| {
        let Some(start) = start else { return };
        if u32::from(start) + u32::from(count.max(1)) > 0x1_0000 {
            return;
        }
        if !out.iter().any(|c| c.start == start && c.count == count) {
            out.push(Candidate {
                start,
                count,
                kind,
                why,
            });
        }
    };
    for m in models {
        if let Some(r) = m.identification.as_ref().and_then(|i| i.register) {
            add(
                Some(r),
                1,
                ProbeKind::Identification,
                format!("{}'s identification register", m.id),
            );
        }
    }
    // The first registers past the command and monitor blocks that no model knows: an
    // exception there shows the numbering (02H against 52H).
    let known = |r: u16| models.iter().any(|m| m.lookup(r).is_some());
    let top = models
        .iter()
        .flat_map(|m| m.groups.iter().filter(|g| g.parameter_group.is_none()))
        .map(|g| *g.span.end())
        .max()
        .unwrap_or(0);
    if let Some(r) = (top.saturating_add(1)..=0xFFFF).find(|&r| !known(r)) {
        add(
            Some(r),
            1,
            ProbeKind::OutsideEveryMap,
            format!("{r:04X}H: the first register past the blocks that no model knows"),
        );
    }
    if !known(0xFFFF) {
        add(
            Some(0xFFFF),
            1,
            ProbeKind::OutsideEveryMap,
            "FFFFH: in no model's map".to_string(),
        );
    }
    for m in models {
        let limit = m.limits.read.get(mode);
        let longest = m
            .groups
            .iter()
            .flat_map(|g| g.registers.iter())
            .max_by_key(|r| u32::from(*r.end()) - u32::from(*r.start()));
        if let Some(r) = longest {
            for count in [0, limit, limit.saturating_add(1)] {
                add(
                    Some(*r.start()),
                    count,
                    ProbeKind::ReadLimit,
                    format!(
                        "{count} registers from {:04X}H: {}'s read limit in {mode} is {limit}",
                        r.start(),
                        m.id
                    ),
                );
            }
        }
        for g in &m.groups {
            for r in &g.no_access {
                add(
                    Some(*r.start()),
                    1,
                    ProbeKind::NoAccess,
                    format!(
                        "{:04X}H: marked '-' in {}'s {} ({:04X}H..{:04X}H)",
                        r.start(),
                        m.id,
                        g.name,
                        r.start(),
                        r.end()
                    ),
                );
            }
            let ranges = g.registers.iter().map(|r| (r, "range"));
            let spans = std::iter::once((&g.span, "span"));
            for (r, what) in spans.chain(ranges) {
                let (a, b) = (*r.start(), *r.end());
                let len = u16::try_from(r.clone().count()).unwrap_or(u16::MAX);
                let name = format!("{}'s {} {what} {a:04X}H..{b:04X}H", m.id, g.name);
                add(Some(a), 1, ProbeKind::MapBorder, format!("first of {name}"));
                add(Some(b), 1, ProbeKind::MapBorder, format!("last of {name}"));
                add(
                    a.checked_sub(1),
                    1,
                    ProbeKind::MapBorder,
                    format!("just before {name}"),
                );
                add(
                    b.checked_add(1),
                    1,
                    ProbeKind::MapBorder,
                    format!("just after {name}"),
                );
                add(
                    Some(b),
                    2,
                    ProbeKind::MapBorder,
                    format!("across the end of {name}"),
                );
                if len <= limit {
                    add(
                        Some(a),
                        len,
                        ProbeKind::MapBorder,
                        format!("the whole of {name}"),
                    );
                }
                if len < limit {
                    add(
                        Some(a),
                        len + 1,
                        ProbeKind::MapBorder,
                        format!("the whole of {name} and one more"),
                    );
                }
            }
        }
        for al in &m.aliases {
            let (a, b) = (*al.span.start(), *al.span.end());
            let name = format!("{}'s alias {a:04X}H..{b:04X}H = {:04X}H..", m.id, al.target);
            add(Some(a), 1, ProbeKind::Alias, format!("first of {name}"));
            add(
                b.checked_add(1),
                1,
                ProbeKind::Alias,
                format!("just after {name}"),
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::MODELS;

    fn builtin() -> Vec<DriveModel> {
        MODELS
            .iter()
            .map(|m| DriveModel::builtin(m).unwrap())
            .collect()
    }

    #[test]
    fn the_plan_tells_every_pair_of_models_apart() {
        let models = builtin();
        let refs: Vec<&DriveModel> = models.iter().collect();
        for mode in [Mode::Rtu, Mode::Ascii] {
            let (probes, disagreeing) = plan(&refs, mode, 1, PlanLimits::default());
            assert!(disagreeing > probes.len(), "{mode}: {disagreeing}");
            assert!(probes.len() <= PlanLimits::default().max_probes);
            for i in 0..refs.len() {
                for j in i + 1..refs.len() {
                    let n = probes
                        .iter()
                        .filter(|p| p.splits().contains(&(i, j)))
                        .count();
                    assert!(
                        n >= 3,
                        "{mode}: {} and {} are told apart by {n} probes",
                        refs[i].id,
                        refs[j].id
                    );
                }
            }
            // The identification register is read, and the exception numbering probed.
            assert!(probes
                .iter()
                .any(|p| p.candidate.kind == ProbeKind::Identification));
            assert!(probes.iter().any(|p| p
                .predictions
                .iter()
                .any(|m| m.prediction == Prediction::Exception(0x52))));
        }
    }

    #[test]
    fn the_plan_is_the_same_every_time() {
        let models = builtin();
        let refs: Vec<&DriveModel> = models.iter().collect();
        let a = plan(&refs, Mode::Rtu, 1, PlanLimits::default());
        let b = plan(&refs, Mode::Rtu, 1, PlanLimits::default());
        assert_eq!(a, b);
    }
}
