//! The run of a mode's checks: the section of the suite it takes, the loop that runs each
//! check (safety skips, the preflight first, liveness, ERRORs for what a lost device left),
//! and the restore at the end.

use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use super::checks::{self, plan, Check};
use super::liveness;
use super::master::Master;
use super::{CheckResult, Ctx, ModeBudget, ModeRun, Options, RunError, Status, Verdict};
use crate::codec::Mode;
use crate::judge::Severity;
use crate::model::DriveModel;
use crate::transport::{Transport, TransportError};
use crate::vectors::VectorFile;

/// Which checks of a mode a run takes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Section {
    /// Every check: a run of one node.
    All,
    /// The checks of one node ([`Options::address`]) of several on one bus; the checks
    /// of the whole bus ([`Check::bus`]) are left to [`Section::Bus`]. Results name the
    /// node.
    Node,
    /// The checks of the whole bus, once, after the nodes' sections (preflight and
    /// liveness probes go to [`Options::address`]).
    Bus,
}

impl Section {
    /// Whether this section runs `check`.
    pub fn takes(self, check: &Check) -> bool {
        match self {
            Section::All => true,
            Section::Node => !check.bus,
            Section::Bus => check.bus,
        }
    }
}

/// Told about each check as it starts and ends (progress bars, incremental reports).
pub trait Progress {
    /// A check starts.
    fn started(&mut self, check: &Check);
    /// A check ended.
    fn finished(&mut self, result: &CheckResult);
}

/// Runs the checks of `mode` that `opts.only` selects, telling `progress` about each
/// (for incremental reports and progress bars). Stops early when `stop` is set or the link
/// fails; registers the run changed are restored either way.
pub fn run_mode(
    model: &DriveModel,
    vectors: Option<&VectorFile>,
    mode: Mode,
    transport: Box<dyn Transport>,
    opts: &Options,
    stop: &AtomicBool,
    progress: &mut dyn Progress,
) -> ModeRun {
    let master = Master::new(transport, mode, opts.timing).with_echo(opts.echo);
    run_section(
        model,
        vectors,
        mode,
        master,
        opts,
        stop,
        progress,
        Section::All,
    )
    .0
}

/// [`run_mode`] for one section of a run of several nodes on one bus, over a master
/// that the sections share (it is handed back for the next). The budget's line figures
/// are the master's so far; its wall time is this section's.
#[allow(clippy::too_many_arguments)]
pub fn run_section(
    model: &DriveModel,
    vectors: Option<&VectorFile>,
    mode: Mode,
    master: Master<dyn Transport>,
    opts: &Options,
    stop: &AtomicBool,
    progress: &mut dyn Progress,
    section: Section,
) -> (ModeRun, Master<dyn Transport>) {
    let selected_checks: Vec<Check> = plan(model, vectors, mode, opts)
        .into_iter()
        .filter(|c| selected(&c.id, &opts.only) && section.takes(c))
        .collect();
    let node = (section == Section::Node).then_some(opts.address);
    let mode_started = Instant::now();
    let mut ctx = Ctx::on_master(model, vectors, mode, opts, master);
    let mut run = ModeRun::default();
    let mut host_reruns = 0;
    // The preflight runs first, whatever --only selects: nothing can be judged on a line
    // where the device does not answer.
    let preflight = checks::preflight(model, mode);
    let mut queue = std::iter::once(&preflight).chain(selected_checks.iter());
    for check in queue.by_ref() {
        if stop.load(Ordering::Relaxed) {
            run.stopped = Some("interrupted".to_string());
            break;
        }
        progress.started(check);
        ctx.current = check.id.clone();
        let started = Instant::now();
        let verdict = if check.motion && !opts.allow_motion {
            Ok(Verdict::skip(
                "sets the run or external-fault bit; needs --allow-motion",
            ))
        } else if check.writes && opts.read_only {
            Ok(Verdict::skip("writes registers; --read-only"))
        } else if check.restarts && !opts.allow_restart {
            Ok(Verdict::skip(
                "restarts or silences the device's communications (08H 0001H/0004H); needs --allow-restart",
            ))
        } else if let (true, Some(why)) = (check.needs_line, ctx.frames_only()) {
            Ok(Verdict::skip(why))
        } else {
            run_again_after_stalls(check, &mut ctx, opts, &mut host_reruns)
        };
        let (verdict, fatal) = match verdict {
            Ok(v) => (v, None),
            Err(RunError::DeviceLost(why)) => (Verdict::error(why), None),
            Err(RunError::Undescribed(why)) => (Verdict::skip(why), None),
            Err(e @ RunError::HostStalled(_)) => (
                Verdict::error(format!(
                    "{e} (the check ran {} times, and this host stalled under it each time: an overloaded host; run it again)",
                    super::HOST_STALL_RUNS
                )),
                None,
            ),
            Err(RunError::Transport(e)) => {
                let msg = e.to_string();
                (Verdict::error(msg.clone()), Some(msg))
            }
        };
        let mut result = result_of(check, mode, verdict, started.elapsed());
        result.node = node;
        progress.finished(&result);
        run.results.push(result);
        if let Some(msg) = fatal {
            run.stopped = Some(msg);
            break;
        }
        if ctx.lost.is_some() {
            break;
        }
    }
    if let Some(why) = ctx.lost.clone() {
        run.lost = true;
        let lost_in = ctx.current.clone();
        if lost_in == preflight.id {
            run.stopped = Some(format!(
                "no answer to the preflight: nothing was checked (see [{lost_in}])"
            ));
            let _ = why;
        } else {
            // Every check that did not run is an ERROR: none of them can pass.
            for check in queue {
                progress.started(check);
                let mut result = result_of(
                    check,
                    mode,
                    Verdict::error(liveness::not_run(&lost_in)),
                    Duration::ZERO,
                );
                result.node = node;
                progress.finished(&result);
                run.results.push(result);
            }
            run.stopped = Some(match &ctx.answered_in {
                Some(last) => format!(
                    "the device stopped answering in {lost_in} (the last check it answered was {last})"
                ),
                None => format!("the device stopped answering in {lost_in}"),
            });
        }
    }
    run.identification = ctx.identification;
    run.echo = ctx.echoes();
    run.restore = ctx.restore();
    let line = ctx.master.budget();
    // Behind a gateway the serial side's timing is the gateway's, and a pseudo-terminal
    // without pacing has none: no bound of ours.
    let no_bound = if ctx.frames_only().is_some() {
        Some(super::NoBound::Gateway)
    } else if ctx.line_timing().is_none() && ctx.link_kind() == crate::transport::LinkKind::Pty {
        Some(super::NoBound::Pty)
    } else {
        None
    };
    run.budget = ModeBudget {
        wall: mode_started.elapsed(),
        line,
        bound: match no_bound {
            Some(_) => Duration::ZERO,
            None => ctx
                .line_timing()
                .or(opts.line)
                .map_or(Duration::ZERO, |l| line.bound(&l)),
        },
        no_bound,
        host_reruns,
    };
    (run, ctx.master)
}

/// Runs `check`, and again where this host stalled under it (nothing about the device
/// can be judged from such a run), [`super::HOST_STALL_RUNS`] times in all before its
/// ERROR stands; each run again is counted in `reruns`.
fn run_again_after_stalls(
    check: &Check,
    ctx: &mut Ctx<'_>,
    opts: &Options,
    reruns: &mut u32,
) -> Result<Verdict, RunError> {
    let mut runs = 0;
    loop {
        runs += 1;
        let injected = opts.injected_stalls.as_ref().filter(|(pattern, n)| {
            runs <= *n && selected(&check.id, std::slice::from_ref(pattern))
        });
        let verdict = match injected {
            Some(_) => Err(RunError::HostStalled(TransportError::Stalled {
                link: "injected (--inject-host-stall)".into(),
                request: "(planted)".into(),
                sends: 1,
            })),
            None => (check.run)(ctx),
        };
        match verdict {
            Err(RunError::HostStalled(_)) if runs < super::HOST_STALL_RUNS => *reruns += 1,
            v => return v,
        }
    }
}

pub(crate) fn result_of(
    check: &Check,
    mode: Mode,
    mut v: Verdict,
    duration: Duration,
) -> CheckResult {
    v.findings.sort_by_key(|f| std::cmp::Reverse(f.severity));
    // A finding that repeats the model's reason, which the check's source already quotes,
    // keeps its first part only.
    for f in &mut v.findings {
        if let Some(at) = f.text.find(". Model: ") {
            if check.source.contains(&f.text[at + 9..]) {
                f.text.truncate(at);
            }
        }
    }
    let (status, summary) = if let Some(e) = &v.error {
        (Status::Error, e.clone())
    } else if let Some(s) = &v.skip {
        (Status::Skip, s.clone())
    } else if let Some(f) = v.findings.first() {
        let status = match f.severity {
            Severity::Deviation => Status::Deviation,
            Severity::Observation => Status::Observation,
        };
        (status, f.text.clone())
    } else {
        (Status::Pass, v.pass_summary.clone())
    };
    CheckResult {
        id: check.id.clone(),
        title: check.title.clone(),
        mode: Some(mode),
        source: check.source.clone(),
        status,
        summary,
        findings: v.findings,
        exchanges: v.exchanges,
        duration,
        node: None,
    }
}

/// Whether check `id` is selected by `only` (every check when empty): a pattern without
/// '*' selects the ids that contain it (see [`id_matches`]).
pub fn selected(id: &str, only: &[String]) -> bool {
    only.is_empty() || only.iter().any(|p| id_matches(p, id, Plain::WithinId))
}

/// What a pattern without '*' names (see [`id_matches`]).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Plain {
    /// The id equal to it (a requirement's link to a check).
    WholeId,
    /// Every id that contains it (`--only`).
    WithinId,
}

/// Whether `pattern` names `id`, the one matcher of ids against patterns (`--only`, a
/// requirement's links). '*' matches any run of characters, and a pattern with one spans
/// the whole id (`rtu.*` names the ids that start with `rtu.`, `*first` those that end
/// with `first`); a pattern without one names ids as `plain` says.
pub fn id_matches(pattern: &str, id: &str, plain: Plain) -> bool {
    let mut parts = pattern.split('*');
    let first = parts.next().unwrap_or("");
    let parts: Vec<&str> = parts.collect();
    let Some((last, middle)) = parts.split_last() else {
        return match plain {
            Plain::WholeId => id == pattern,
            Plain::WithinId => id.contains(pattern),
        };
    };
    let Some(mut rest) = id.strip_prefix(first) else {
        return false;
    };
    for part in middle {
        match rest.find(part) {
            Some(at) => rest = &rest[at + part.len()..],
            None => return false,
        }
    }
    rest.ends_with(last)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_patterns() {
        assert!(selected("rtu.map.group-0.first", &[]));
        assert!(selected("rtu.map.group-0.first", &["group-0".into()]));
        assert!(selected("rtu.map.group-0.first", &["rtu.*.first".into()]));
        assert!(!selected("ascii.map.group-0.first", &["rtu.*".into()]));
        assert!(selected("ascii.map.group-0.first", &["*first".into()]));
        assert!(!selected("ascii.map.group-0.last", &["*first".into()]));
    }

    #[test]
    fn a_pattern_without_a_star_names_the_whole_id_or_what_contains_it() {
        use Plain::{WholeId, WithinId};
        assert!(id_matches("map.group-0", "rtu.map.group-0.first", WithinId));
        assert!(!id_matches("map.group-0", "rtu.map.group-0.first", WholeId));
        assert!(id_matches("rtu.map.first", "rtu.map.first", WholeId));
        assert!(id_matches("rtu.map.first", "rtu.map.first", WithinId));
        assert!(!id_matches("rtu.map.first.x", "rtu.map.first", WithinId));
        assert!(id_matches("", "anything", WithinId));
        assert!(!id_matches("", "anything", WholeId));
        // With a '*' the two are one: the pattern spans the whole id.
        for plain in [WholeId, WithinId] {
            assert!(id_matches("rtu.*.first", "rtu.map.group-0.first", plain));
            assert!(!id_matches("map.*", "rtu.map.group-0.first", plain));
            assert!(!id_matches("*.group-0", "rtu.map.group-0.first", plain));
            assert!(id_matches("*", "", plain));
            assert!(id_matches("a*a", "aa", plain));
            assert!(!id_matches("a*a", "a", plain));
            assert!(!id_matches("ab*ba", "aba", plain));
            assert!(id_matches("a**b", "ab", plain));
        }
    }
}
