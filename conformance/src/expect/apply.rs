//! Marking a report's results against an expectations file.

use std::collections::BTreeMap;

use super::{glob_match, Day, Entry, Expectations, Expected, Target};
use crate::report::Report;
use crate::runner::{CheckResult, Status};

/// What became of an entry in a run.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntryState {
    /// It matched results of the run.
    Applied,
    /// Its `expires` day is past: it no longer applies.
    Expired,
    /// No result of the run that ran (not skipped) is the check or finding it names.
    Unmatched,
    /// Its check ran, but on a device whose identification is not the entry's (or was not
    /// read).
    OtherDevice,
    /// A fuzz finding's signature that a complete campaign of its mode did not find
    /// again: the fuzz run's UNEXPECTED PASS.
    NotFound,
}

impl EntryState {
    /// Its word in reports.
    pub fn key(self) -> &'static str {
        match self {
            EntryState::Applied => "applied",
            EntryState::Expired => "expired",
            EntryState::Unmatched => "unmatched",
            EntryState::OtherDevice => "other-device",
            EntryState::NotFound => "not-found",
        }
    }

    /// Reads [`EntryState::key`] back.
    pub fn from_key(s: &str) -> Option<EntryState> {
        Some(match s {
            "applied" => EntryState::Applied,
            "expired" => EntryState::Expired,
            "unmatched" => EntryState::Unmatched,
            "other-device" => EntryState::OtherDevice,
            "not-found" => EntryState::NotFound,
            _ => return None,
        })
    }
}

/// How a result stands against the entry that names it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum MarkKind {
    /// The entry's status: an expected result, reported apart from new ones.
    Expected,
    /// The entry expects a deviation or finding and the check now passes.
    UnexpectedPass,
    /// The entry expects one status and the check gave another (not PASS): judged as a
    /// result without an entry.
    Changed,
}

impl MarkKind {
    /// Its word in reports.
    pub fn key(self) -> &'static str {
        match self {
            MarkKind::Expected => "expected",
            MarkKind::UnexpectedPass => "unexpected-pass",
            MarkKind::Changed => "changed",
        }
    }

    /// Reads [`MarkKind::key`] back.
    pub fn from_key(s: &str) -> Option<MarkKind> {
        Some(match s {
            "expected" => MarkKind::Expected,
            "unexpected-pass" => MarkKind::UnexpectedPass,
            "changed" => MarkKind::Changed,
            _ => return None,
        })
    }
}

/// A result's mark: which entry names it, and how the result stands against it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Mark {
    /// How it stands.
    pub kind: MarkKind,
    /// The entry's line in the file.
    pub line: usize,
    /// The status the entry expects.
    pub expected: Expected,
    /// The entry's reason.
    pub reason: String,
    /// The entry's ticket.
    pub ticket: Option<String>,
}

/// An entry and what became of it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct EntryReport {
    /// The entry.
    pub entry: Entry,
    /// What became of it.
    pub state: EntryState,
    /// How many results it marked.
    pub matched: usize,
}

/// A run's results against an expectations file: recorded in the report.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Outcome {
    /// The file.
    pub path: String,
    /// Whether an unexpected pass fails the run (`--strict-expect`).
    pub strict: bool,
    /// The day expiry was judged on.
    pub today: Day,
    /// Every entry, in file order.
    pub entries: Vec<EntryReport>,
    /// Marks by result key ([`CheckResult::key`]).
    pub marks: BTreeMap<String, Mark>,
}

impl Outcome {
    /// The mark of `r`, if an entry names it.
    pub fn mark(&self, r: &CheckResult) -> Option<&Mark> {
        self.marks.get(&r.key())
    }

    /// Fuzz signatures a complete campaign did not find again (unexpected passes).
    pub fn not_found(&self) -> usize {
        self.entries
            .iter()
            .filter(|e| e.state == EntryState::NotFound)
            .count()
    }

    /// Entries that no longer apply, matched nothing, or (fuzz) were not found again.
    pub fn stale(&self) -> impl Iterator<Item = &EntryReport> {
        self.entries
            .iter()
            .filter(|e| e.state != EntryState::Applied)
    }
}

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
fn identification_of(report: &Report, r: &CheckResult) -> Option<u16> {
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
