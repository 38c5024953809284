//! What marking a report's results against an expectations file gives: each entry's
//! state and each result's mark (the marking itself is the report's:
//! `crate::report::apply_expectations`).

use std::collections::BTreeMap;

use super::{Day, Entry, Expected};
use crate::runner::CheckResult;

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
