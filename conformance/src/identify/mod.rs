//! Which of the five models a device follows, from its answers to reads only.
//!
//! Nothing is written and nothing restarted: every probe is an 03H read. The probes are
//! derived from the models ([`plan`]): reads on which the models' predictions exclude
//! each other (the identification register, the exception numbering 01H..05H against
//! 51H..55H, the register-map borders that differ, the read limits). Each probe is sent
//! once, the device's answer is compared with every model's prediction, and each model is
//! scored by how many answers it predicted exactly. The verdict is the one model that
//! predicted every answer (or all but `tolerance`), "ambiguous" where several did, and
//! "none of the five" where none did.
//!
//! The exchanges go through the runner's master and its preflight and liveness probes
//! ([`crate::runner::Ctx`]), so an echo is stripped and a silence is proven, as in
//! `check`; the target is opened as a session opens it ([`crate::session::open`]).
//! This module sits beside [`crate::session`]: it uses the runner and the session's
//! target, and nothing below it uses it.

pub mod plan;
pub mod predict;
pub mod render;

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::SystemTime;

pub use plan::{plan, Candidate, ModelPrediction, PlanLimits, Probe, ProbeKind};
pub use predict::{Answer, Prediction};

use crate::codec::timing::LineSettings;
use crate::codec::Mode;
use crate::model::DriveModel;
use crate::runner::{ExchangeRecord, Options, RunError};
use crate::session::{self, SessionConfig, SessionError, Target};

/// Everything an identification needs.
pub struct IdentifyConfig {
    /// The candidate models, in the order reports list them.
    pub models: Vec<Arc<DriveModel>>,
    /// The target.
    pub target: Target,
    /// With [`Target::Sim`]: the model the simulator runs.
    pub sim_model: Option<Arc<DriveModel>>,
    /// Modes to probe, in order (a drive is in one; the simulator can be in both).
    pub modes: Vec<Mode>,
    /// The serial line.
    pub line: LineSettings,
    /// The master's options (address, timing, echo); nothing is written.
    pub options: Options,
    /// How many probes.
    pub limits: PlanLimits,
    /// Answers a model may miss and still be named.
    pub tolerance: usize,
    /// Where every frame on the link is recorded (`--capture`), if anywhere.
    pub capture: Option<crate::transport::capture::SharedRecorder>,
}

/// One probe sent, and what came back.
#[derive(Debug, Clone)]
pub struct ProbeResult {
    /// "rtu#3".
    pub id: String,
    /// The mode.
    pub mode: Mode,
    /// The probe and the predictions.
    pub probe: Probe,
    /// The exchange.
    pub exchange: ExchangeRecord,
    /// The device's answer.
    pub answer: Answer,
    /// Per model (in the order of the models): whether it predicted the answer.
    pub fits: Vec<bool>,
}

/// Evidence that is not an answer: a fact of the run that rules a model out.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct StaticEvidence {
    /// The model it rules out.
    pub model: String,
    /// Why, in words.
    pub text: String,
}

/// One model's score.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Score {
    /// The model.
    pub model: String,
    /// Its manual.
    pub manual: String,
    /// Answers it predicted.
    pub predicted: usize,
    /// Probes answered.
    pub probes: usize,
    /// Ids of the probes it did not predict, and static evidence against it.
    pub misses: Vec<String>,
}

/// The verdict.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// One model predicted the answers.
    One(String),
    /// Several models predicted the answers equally well.
    Ambiguous(Vec<String>),
    /// No model predicted the answers; the nearest ones.
    NoneOfThem {
        /// The models with the fewest misses.
        nearest: Vec<String>,
    },
    /// The identification could not run or complete: why.
    NotRun(String),
}

impl Verdict {
    /// 0 one model, 1 ambiguous or none, 2 could not run.
    pub fn exit_code(&self) -> u8 {
        match self {
            Verdict::One(_) => 0,
            Verdict::Ambiguous(_) | Verdict::NoneOfThem { .. } => 1,
            Verdict::NotRun(_) => 2,
        }
    }

    /// The key in the JSON report: one, ambiguous, none, not-run.
    pub fn key(&self) -> &'static str {
        match self {
            Verdict::One(_) => "one",
            Verdict::Ambiguous(_) => "ambiguous",
            Verdict::NoneOfThem { .. } => "none",
            Verdict::NotRun(_) => "not-run",
        }
    }

    /// The models the verdict names.
    pub fn models(&self) -> Vec<String> {
        match self {
            Verdict::One(m) => vec![m.clone()],
            Verdict::Ambiguous(v) => v.clone(),
            Verdict::NoneOfThem { nearest } => nearest.clone(),
            Verdict::NotRun(_) => vec![],
        }
    }
}

/// Per mode: the link and the preflight.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ModeLink {
    /// The mode.
    pub mode: Mode,
    /// The link's description.
    pub link: String,
    /// The preflight's outcome, in words.
    pub preflight: String,
    /// Candidates on which the models disagree.
    pub candidates: usize,
    /// Whether the line echoes requests.
    pub echo: Option<bool>,
}

/// Everything an identification found.
#[derive(Debug, Clone)]
pub struct Identification {
    /// The candidate models (ids).
    pub models: Vec<String>,
    /// The descriptions the candidates were read from, in the order of `models`.
    pub sources: Vec<crate::model::Source>,
    /// Node address probed.
    pub address: u8,
    /// Line settings.
    pub line: String,
    /// With the simulator: its model and quirks.
    pub simulated: Option<(String, Vec<String>)>,
    /// When it started and ended (RFC 3339).
    pub started: String,
    /// When it ended.
    pub finished: String,
    /// Per mode.
    pub links: Vec<ModeLink>,
    /// The probes, in the order sent.
    pub probes: Vec<ProbeResult>,
    /// Facts that rule a model out without a probe.
    pub statics: Vec<StaticEvidence>,
    /// Per model.
    pub scores: Vec<Score>,
    /// Answers a model may miss and still be named.
    pub tolerance: usize,
    /// The verdict.
    pub verdict: Verdict,
}

fn now_rfc3339() -> String {
    humantime::format_rfc3339_seconds(SystemTime::now()).to_string()
}

/// Probes the device of `config` in each of its modes and gives the verdict. `progress`
/// is told each probe as it is sent (mode, probe number, probes in the mode).
pub fn run(
    config: &IdentifyConfig,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(Mode, usize, usize),
) -> Result<Identification, SessionError> {
    let models: Vec<&DriveModel> = config.models.iter().map(|m| m.as_ref()).collect();
    let address = config.options.address;
    let l = config.line;
    let mut out = Identification {
        models: models.iter().map(|m| m.id.clone()).collect(),
        sources: models.iter().map(|m| m.source.clone()).collect(),
        address,
        line: format!("{} baud {}{}{}", l.baud, l.data_bits, l.parity, l.stop_bits),
        simulated: match (&config.target, &config.sim_model) {
            (Target::Sim { quirks, .. }, Some(m)) => {
                Some((m.id.clone(), quirks.iter().map(|q| q.to_string()).collect()))
            }
            _ => None,
        },
        started: now_rfc3339(),
        finished: String::new(),
        links: Vec::new(),
        probes: Vec::new(),
        statics: statics(&models, address),
        scores: Vec::new(),
        tolerance: config.tolerance,
        verdict: Verdict::NotRun("nothing ran".into()),
    };
    let Some(host) = config
        .sim_model
        .clone()
        .or_else(|| config.models.first().cloned())
    else {
        out.verdict = Verdict::NotRun("no candidate model".into());
        return Ok(out);
    };
    let mut not_run = None;
    for &mode in &config.modes {
        if stop.load(Ordering::Relaxed) {
            not_run = Some("interrupted".to_string());
            break;
        }
        // The session's target as `check` opens it; the model only matters to a
        // simulator (which one to start).
        let session = SessionConfig {
            model: host.clone(),
            target: config.target.clone(),
            modes: vec![mode],
            line: config.line,
            options: config.options.clone(),
            capture: config.capture.clone(),
        };
        let (sim, transport) = session::open(&session, mode)?;
        let (probes, candidates) = plan(&models, mode, address, config.limits);
        let outcome = probe_mode(
            &models,
            mode,
            transport,
            &config.options,
            probes,
            stop,
            &mut |i, n| progress(mode, i, n),
        );
        drop(sim);
        out.links.push(ModeLink {
            mode,
            link: outcome.link,
            preflight: outcome.preflight,
            candidates,
            echo: outcome.echo,
        });
        out.probes.extend(outcome.results);
        if let Some(why) = outcome.stopped {
            not_run = Some(why);
            break;
        }
    }
    out.scores = scores(&models, &out.probes, &out.statics);
    out.verdict = match not_run {
        Some(why) => Verdict::NotRun(why),
        None => verdict(&out.scores, config.tolerance),
    };
    out.finished = now_rfc3339();
    Ok(out)
}

/// Facts of the run that rule models out: a node address outside a model's range.
fn statics(models: &[&DriveModel], address: u8) -> Vec<StaticEvidence> {
    models
        .iter()
        .filter(|m| !m.addresses.contains(&address))
        .map(|m| StaticEvidence {
            model: m.id.clone(),
            text: format!(
                "the device is probed at node {address:02X}H; the {} allows nodes {:02X}H..{:02X}H only ({})",
                m.manual,
                m.addresses.start(),
                m.addresses.end(),
                m.addresses_fact.citation()
            ),
        })
        .collect()
}

struct ModeOutcome {
    link: String,
    preflight: String,
    echo: Option<bool>,
    results: Vec<ProbeResult>,
    stopped: Option<String>,
}

/// Sends the preflight and then `probes` over `transport` in `mode`.
fn probe_mode(
    models: &[&DriveModel],
    mode: Mode,
    transport: Box<dyn crate::transport::Transport>,
    options: &Options,
    probes: Vec<Probe>,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(usize, usize),
) -> ModeOutcome {
    // The preflight and the liveness probes read a register every model answers (the
    // status register; a unit test holds the models to it), so any model can host them.
    let host = models[0];
    let mut ctx = crate::runner::Ctx::new(host, None, mode, options, transport);
    let link = ctx.link();
    ctx.current = format!("identify.{mode}.preflight");
    let mut outcome = ModeOutcome {
        link,
        preflight: String::new(),
        echo: None,
        results: Vec::new(),
        stopped: None,
    };
    match ctx.preflight() {
        Ok(v) => {
            outcome.preflight = v.error.clone().unwrap_or(v.pass_summary);
            if ctx.lost.is_some() {
                outcome.stopped = Some(format!(
                    "no answer to the preflight in {mode}: {}",
                    outcome.preflight
                ));
                return outcome;
            }
        }
        Err(e) => {
            outcome.stopped = Some(e.to_string());
            return outcome;
        }
    }
    let n = probes.len();
    for (i, probe) in probes.into_iter().enumerate() {
        if stop.load(Ordering::Relaxed) {
            outcome.stopped = Some("interrupted".into());
            break;
        }
        progress(i + 1, n);
        let id = format!("{mode}#{}", i + 1);
        ctx.current = format!("identify.{id}");
        let replies = probe
            .predictions
            .iter()
            .any(|p| p.prediction != Prediction::Silence);
        let (ex, _) = match ctx.exchange(&probe.frame, replies) {
            Ok(x) => x,
            Err(RunError::DeviceLost(why)) => {
                outcome.stopped = Some(why);
                break;
            }
            // An exchange is not judged by the model: never undescribed.
            Err(RunError::Undescribed(_)) => continue,
            // A probe this host could not send whole (or whose answer it delayed past
            // the timeout) tells nothing: it is left out, rather than scored as a silence
            // the device never had; the other probes decide.
            Err(RunError::HostStalled(_)) => continue,
            Err(RunError::Transport(e)) => {
                outcome.stopped = Some(e.to_string());
                break;
            }
        };
        let answer = Answer::of(mode, &ex);
        let fits = probe
            .predictions
            .iter()
            .map(|p| p.prediction.admits(&answer))
            .collect();
        let exchange = ExchangeRecord {
            request: ex.request.clone(),
            expected: None,
            received: ex.raw.clone(),
            reply: ex.reply.clone(),
            predicted: probe.candidate.why.clone(),
            actual: answer.describe(),
            latency: ex.first_byte,
        };
        outcome.results.push(ProbeResult {
            id,
            mode,
            probe,
            exchange,
            answer,
            fits,
        });
    }
    outcome.echo = ctx.echoes();
    outcome
}

/// Each model's score over the probes and the static evidence.
pub fn scores(
    models: &[&DriveModel],
    probes: &[ProbeResult],
    statics: &[StaticEvidence],
) -> Vec<Score> {
    models
        .iter()
        .enumerate()
        .map(|(i, m)| {
            let mut misses: Vec<String> = probes
                .iter()
                .filter(|p| !p.fits.get(i).copied().unwrap_or(false))
                .map(|p| p.id.clone())
                .collect();
            misses.extend(
                statics
                    .iter()
                    .filter(|s| s.model == m.id)
                    .map(|_| "node address".to_string()),
            );
            Score {
                model: m.id.clone(),
                manual: m.manual.clone(),
                predicted: probes
                    .iter()
                    .filter(|p| p.fits.get(i).copied().unwrap_or(false))
                    .count(),
                probes: probes.len(),
                misses,
            }
        })
        .collect()
}

/// The verdict from the scores: the models that missed at most `tolerance` answers, and
/// of those the ones that missed fewest.
pub fn verdict(scores: &[Score], tolerance: usize) -> Verdict {
    if scores.iter().all(|s| s.probes == 0) {
        return Verdict::NotRun("no probe was answered".into());
    }
    let fewest = |of: Vec<&Score>| -> Vec<String> {
        let min = of.iter().map(|s| s.misses.len()).min().unwrap_or(0);
        of.iter()
            .filter(|s| s.misses.len() == min)
            .map(|s| s.model.clone())
            .collect()
    };
    let fitting: Vec<&Score> = scores
        .iter()
        .filter(|s| s.misses.len() <= tolerance)
        .collect();
    if fitting.is_empty() {
        return Verdict::NoneOfThem {
            nearest: fewest(scores.iter().collect()),
        };
    }
    let best = fewest(fitting);
    match best.as_slice() {
        [one] => Verdict::One(one.clone()),
        _ => Verdict::Ambiguous(best),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::MODELS;
    use crate::runner::liveness::liveness_register;

    #[test]
    fn every_model_answers_the_same_preflight() {
        let models: Vec<DriveModel> = MODELS
            .iter()
            .map(|m| DriveModel::builtin(m).unwrap())
            .collect();
        for mode in [Mode::Rtu, Mode::Ascii] {
            let first = liveness_register(&models[0], 1, mode);
            assert!(first.is_some());
            for m in &models {
                assert_eq!(liveness_register(m, 1, mode), first, "{}", m.id);
            }
        }
    }

    fn score(model: &str, misses: usize) -> Score {
        Score {
            model: model.into(),
            manual: String::new(),
            predicted: 10 - misses,
            probes: 10,
            misses: (0..misses).map(|i| format!("rtu#{i}")).collect(),
        }
    }

    #[test]
    fn the_verdict_names_one_model_only_when_one_fits() {
        let s = [score("f510", 0), score("a510", 2), score("l510", 3)];
        assert_eq!(verdict(&s, 0), Verdict::One("f510".into()));
        let s = [score("f510", 0), score("a510", 0), score("l510", 3)];
        assert_eq!(
            verdict(&s, 0),
            Verdict::Ambiguous(vec!["f510".into(), "a510".into()])
        );
        let s = [score("f510", 1), score("a510", 2)];
        assert_eq!(
            verdict(&s, 0),
            Verdict::NoneOfThem {
                nearest: vec!["f510".into()]
            }
        );
        // With a tolerance, the one that fits best.
        assert_eq!(verdict(&s, 1), Verdict::One("f510".into()));
        assert_eq!(verdict(&s, 2), Verdict::One("f510".into()));
    }
}
