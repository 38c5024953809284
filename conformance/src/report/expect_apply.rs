//! Marking a report's results against an expectations file ([`crate::expect`]): the
//! report reads the file, the file knows nothing of reports.

use std::collections::BTreeMap;

use super::Report;
use crate::expect::{
    glob_match, Day, EntryReport, EntryState, Expectations, Expected, Mark, MarkKind, Outcome,
    Target,
};
use crate::runner::{CheckResult, Status};

fn holds(expected: Expected, status: Status) -> bool {
    match expected {
        Expected::Deviation => status == Status::Deviation,
        Expected::Observation => status == Status::Observation,
        Expected::Finding => matches!(status, Status::Deviation | Status::Observation),
    }
}

/// Whether a fuzz run's campaign that would have found `target` (its mode's, from the
/// signature's first part; any mode's for a signature that starts with a wildcard) ran to
/// its end.
fn campaign_passed(report: &Report, target: &Target) -> bool {
    let Target::Signature(sig) = target else {
        return false;
    };
    if report.kind != crate::report::ReportKind::Fuzz {
        return false;
    }
    let mode = sig.split('.').next().unwrap_or("");
    report.results.iter().any(|r| {
        r.status == Status::Pass
            && r.id
                .strip_prefix("fuzz.")
                .and_then(|x| x.strip_suffix(".campaign"))
                .is_some_and(|m| glob_match(mode, m))
    })
}

/// The identification of the device `r` is about.
pub(super) fn identification_of(report: &Report, r: &CheckResult) -> Option<u16> {
    match r.node {
        Some(n) => report
            .device
            .nodes
            .iter()
            .find(|x| x.address == n)
            .and_then(|x| x.identification),
        None => report.device.identification,
    }
}

/// The node `r` is about: its own, or the device's in a run of one node.
fn node_of(report: &Report, r: &CheckResult) -> Option<u8> {
    r.node.or_else(|| {
        (report.device.nodes.is_empty() && report.kind != crate::report::ReportKind::Gate)
            .then_some(report.device.address)
    })
}

/// Marks `report`'s results against `exp` on `today` and records the outcome in the
/// report (which then decides its exit code with it). The first entry that names a
/// result with its status wins; an entry whose check id is exact marks a pass as an
/// UNEXPECTED PASS; a glob marks passes so only when none of its checks still gives its
/// status (a glob says "these may deviate", not "each of these deviates").
pub fn apply(report: &mut Report, exp: &Expectations, strict: bool, today: Day) {
    let mut marks: BTreeMap<String, Mark> = BTreeMap::new();
    let mut entries = Vec::with_capacity(exp.entries.len());
    for e in &exp.entries {
        if e.expires.is_some_and(|d| today > d) {
            entries.push(EntryReport {
                entry: e.clone(),
                state: EntryState::Expired,
                matched: 0,
            });
            continue;
        }
        let pattern = e.target.id_pattern();
        let named: Vec<&CheckResult> = report
            .results
            .iter()
            .filter(|r| r.status != Status::Skip)
            .filter(|r| glob_match(&pattern, &r.id))
            .filter(|r| e.node.is_none() || e.node == node_of(report, r))
            .filter(|r| e.mode.is_none() || e.mode == r.mode)
            .filter(|r| {
                marks
                    .get(&r.key())
                    .is_none_or(|m| m.kind != MarkKind::Expected)
            })
            .collect();
        let on_device: Vec<&CheckResult> = named
            .iter()
            .copied()
            .filter(|r| {
                e.identification.is_none() || e.identification == identification_of(report, r)
            })
            .collect();
        let state = match (named.is_empty(), on_device.is_empty()) {
            (true, _) if campaign_passed(report, &e.target) => EntryState::NotFound,
            (true, _) => EntryState::Unmatched,
            (false, true) => EntryState::OtherDevice,
            (false, false) => EntryState::Applied,
        };
        let any_holds = on_device.iter().any(|r| holds(e.status, r.status));
        let mut matched = 0;
        for r in on_device {
            let kind = if holds(e.status, r.status) {
                MarkKind::Expected
            } else if e.target.is_glob() && any_holds {
                continue;
            } else if r.status == Status::Pass {
                MarkKind::UnexpectedPass
            } else {
                MarkKind::Changed
            };
            matched += 1;
            marks.insert(
                r.key(),
                Mark {
                    kind,
                    line: e.line,
                    expected: e.status,
                    reason: e.reason.clone(),
                    ticket: e.ticket.clone(),
                },
            );
        }
        entries.push(EntryReport {
            entry: e.clone(),
            state,
            matched,
        });
    }
    report.expect = Some(Outcome {
        path: exp.path.clone(),
        strict,
        today,
        entries,
        marks,
    });
}
