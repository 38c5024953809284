//! Traceability: each requirement's links resolved against what exists in this suite (the
//! model's checks, the golden vectors, the model's facts, the monitor's kinds, the fuzz
//! oracle's classes), and the coverage that follows.

use std::collections::{BTreeMap, BTreeSet};

use serde_json::Value;

use super::{matches, Catalogue, Requirement, Verification};
use crate::codec::Mode;
use crate::model::{DriveModel, Fault, SilenceReason};
use crate::vectors::VectorSet;

/// How a requirement is covered, from the strongest.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Coverage {
    /// A check of `conformance check` verifies it.
    Check,
    /// Only the golden vectors, the model's facts or the fuzz oracle cover it.
    Otherwise,
    /// It can be verified only by listening (`monitor`).
    Passive,
    /// It cannot be observed on the wire.
    NotOnWire,
    /// Nothing covers it; its reason says why.
    Uncovered,
}

impl Coverage {
    /// All, in report order.
    pub const ALL: [Coverage; 5] = [
        Coverage::Check,
        Coverage::Otherwise,
        Coverage::Passive,
        Coverage::NotOnWire,
        Coverage::Uncovered,
    ];

    /// As reports spell it.
    pub fn key(self) -> &'static str {
        match self {
            Coverage::Check => "check",
            Coverage::Otherwise => "vectors-or-model",
            Coverage::Passive => "passive-only",
            Coverage::NotOnWire => "not-on-wire",
            Coverage::Uncovered => "uncovered",
        }
    }

    /// In words, for a heading.
    pub fn words(self) -> &'static str {
        match self {
            Coverage::Check => "verified by a check",
            Coverage::Otherwise => "covered by the vectors, the model or the fuzz oracle only",
            Coverage::Passive => "verifiable only passively (monitor)",
            Coverage::NotOnWire => "not observable on the wire",
            Coverage::Uncovered => "not covered",
        }
    }
}

/// How `r` is covered.
pub fn coverage(r: &Requirement) -> Coverage {
    let v = &r.verified_by;
    if !v.checks.is_empty() {
        Coverage::Check
    } else if r.verification == Verification::NotOnWire {
        Coverage::NotOnWire
    } else if !v.vectors.is_empty() || !v.model.is_empty() || !v.fuzz.is_empty() {
        Coverage::Otherwise
    } else if !v.monitor.is_empty() || r.verification == Verification::Passive {
        Coverage::Passive
    } else {
        Coverage::Uncovered
    }
}

/// Counts per coverage of one catalogue.
pub fn counts(cat: &Catalogue) -> BTreeMap<Coverage, usize> {
    let mut out: BTreeMap<Coverage, usize> = Coverage::ALL.iter().map(|c| (*c, 0)).collect();
    for r in cat.current() {
        *out.entry(coverage(r)).or_default() += 1;
    }
    out
}

/// What exists for the links of one catalogue to name.
pub struct Universe {
    /// The model's check ids (both modes).
    pub checks: Vec<String>,
    /// Every golden vector id.
    pub vectors: BTreeSet<String>,
    /// The model file as JSON.
    pub model: Value,
    /// The monitor's kinds.
    pub monitor: Vec<&'static str>,
    /// The oracle's classes: the model's faults and silence reasons.
    pub fuzz: Vec<&'static str>,
    /// Every requirement id of every catalogue (for conflicts).
    pub requirement_ids: BTreeSet<String>,
    /// Every flag of the vectors.
    pub flags: BTreeSet<String>,
}

/// A link that names nothing, or a rule of traceability broken.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Problem {
    /// The requirement (or the check, for an unlinked check).
    pub id: String,
    /// What is wrong.
    pub text: String,
}

impl Universe {
    /// What exists for `cat`, built from the built-in vectors and models; `all` are every
    /// catalogue (for the ids conflicts name).
    pub fn of(cat: &Catalogue, all: &[Catalogue]) -> Result<Universe, String> {
        let model = DriveModel::builtin(&cat.model).map_err(|e| e.to_string())?;
        let set = VectorSet::builtin().map_err(|e| e.to_string())?;
        let file = set.file(&cat.model);
        let opts = crate::runner::Options::for_listing();
        let mut checks = Vec::new();
        for mode in [Mode::Rtu, Mode::Ascii] {
            for c in crate::runner::plan(&model, file, mode, &opts) {
                checks.push(c.id);
            }
        }
        let text = DriveModel::builtin_files()
            .iter()
            .find(|(id, _)| *id == cat.model)
            .map(|(_, t)| *t)
            .ok_or_else(|| format!("no built-in model file {}", cat.model))?;
        let model_json: Value = serde_json::from_str(text).map_err(|e| e.to_string())?;
        Ok(Universe {
            checks,
            vectors: set
                .files
                .iter()
                .flat_map(|f| f.vectors.iter().map(|v| v.id.clone()))
                .collect(),
            model: model_json,
            monitor: crate::monitor::kinds(),
            fuzz: Fault::ALL
                .iter()
                .map(|f| f.key())
                .chain(SilenceReason::ALL.iter().map(|s| s.key()))
                .collect(),
            requirement_ids: all
                .iter()
                .flat_map(|c| c.requirements.iter().map(|r| r.id.clone()))
                .collect(),
            flags: set.flags.flags.keys().cloned().collect(),
        })
    }

    /// The checks a pattern names.
    pub fn checks_of<'a>(&'a self, pattern: &'a str) -> impl Iterator<Item = &'a str> + 'a {
        self.checks
            .iter()
            .map(String::as_str)
            .filter(move |c| matches(pattern, c))
    }
}

/// Resolves a JSON pointer into a model file: in a list, a token selects the element whose
/// `register`, `name`, `group`, `code` or `id` equals it (case-insensitively), or an index.
pub fn resolve<'v>(doc: &'v Value, pointer: &str) -> Option<&'v Value> {
    let rest = pointer.strip_prefix('/')?;
    let mut cur = doc;
    for tok in rest.split('/') {
        cur = match cur {
            Value::Object(m) => m.get(tok)?,
            Value::Array(items) => items
                .iter()
                .find(|e| {
                    ["register", "name", "group", "code", "id"].iter().any(|k| {
                        e.get(k).is_some_and(|v| match v {
                            Value::String(s) => s.eq_ignore_ascii_case(tok),
                            Value::Number(n) => n.to_string() == tok,
                            _ => false,
                        })
                    })
                })
                .or_else(|| tok.parse::<usize>().ok().and_then(|i| items.get(i)))?,
            _ => return None,
        };
    }
    Some(cur)
}

/// Every link of `cat` that names nothing, and every check of its model that verifies no
/// requirement.
pub fn problems(cat: &Catalogue, u: &Universe) -> Vec<Problem> {
    let mut out = Vec::new();
    let mut linked: BTreeSet<&str> = BTreeSet::new();
    for r in cat.current() {
        let mut bad = |text: String| {
            out.push(Problem {
                id: r.id.clone(),
                text,
            })
        };
        let v = &r.verified_by;
        for p in &v.checks {
            let n = u.checks_of(p).inspect(|c| {
                linked.insert(c);
            });
            if n.count() == 0 {
                bad(format!(
                    "check pattern '{p}' names no check of model {}",
                    cat.model
                ));
            }
        }
        for id in &v.vectors {
            if !u.vectors.contains(id) {
                bad(format!("vector '{id}' does not exist"));
            }
        }
        for p in &v.model {
            if resolve(&u.model, p).is_none() {
                bad(format!(
                    "model fact '{p}' names nothing in vectors/models/{}.json",
                    cat.model
                ));
            }
        }
        for k in &v.monitor {
            if !u.monitor.contains(&k.as_str()) {
                bad(format!("'{k}' is not a kind the monitor judges"));
            }
        }
        for k in &v.fuzz {
            if !u.fuzz.contains(&k.as_str()) {
                bad(format!("'{k}' is not a class of the fuzz oracle"));
            }
        }
        for c in &r.conflicts {
            if !u.requirement_ids.contains(&c.with) {
                bad(format!("conflict with '{}', which does not exist", c.with));
            }
            let s = c.settled_by.as_str();
            let settled = s.starts_with("unsettled: ")
                || u.vectors.contains(s)
                || u.flags.contains(s)
                || s.split_once(':').is_some_and(|(model, ptr)| {
                    DriveModel::builtin_files()
                        .iter()
                        .find(|(id, _)| *id == model)
                        .and_then(|(_, t)| serde_json::from_str::<Value>(t).ok())
                        .is_some_and(|doc| resolve(&doc, ptr).is_some())
                });
            if !settled {
                bad(format!(
                    "conflict with '{}' is settled by '{s}', which is no vector, flag, model fact or 'unsettled: ...'",
                    c.with
                ));
            }
        }
    }
    let mut exempt: BTreeSet<&str> = BTreeSet::new();
    for x in &cat.checks_without_requirement {
        let mut n = 0;
        for c in u.checks_of(&x.checks) {
            n += 1;
            exempt.insert(c);
            if linked.contains(c) {
                out.push(Problem {
                    id: c.to_string(),
                    text: format!(
                        "listed under checks_without_requirement ('{}'), yet a requirement links it",
                        x.checks
                    ),
                });
            }
        }
        if n == 0 {
            out.push(Problem {
                id: x.checks.clone(),
                text: format!(
                    "checks_without_requirement pattern names no check of model {}",
                    cat.model
                ),
            });
        }
    }
    for c in &u.checks {
        if !linked.contains(c.as_str()) && !exempt.contains(c.as_str()) {
            out.push(Problem {
                id: c.clone(),
                text: format!(
                    "check of model {} verifies no requirement of {}",
                    cat.model, cat.document
                ),
            });
        }
    }
    out
}

/// What a run did for one requirement that a check verifies.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum RunCoverage {
    /// A check ran and passed (or observed).
    Verified,
    /// A check ran and found the device deviating.
    Deviated,
    /// Its checks were skipped; the first skip's reason.
    Skipped(String),
    /// Its checks could not tell (ERROR); the first one's reason.
    Error(String),
    /// None of its checks was selected (`--only`).
    NotRun,
    /// Its checks are all of a mode the run did not speak (`--mode`): that mode.
    OtherMode(crate::codec::Mode),
}

impl RunCoverage {
    /// As reports spell it.
    pub fn key(&self) -> &'static str {
        match self {
            RunCoverage::Verified => "verified",
            RunCoverage::Deviated => "deviated",
            RunCoverage::Skipped(_) => "skipped",
            RunCoverage::Error(_) => "error",
            RunCoverage::NotRun => "not-run",
            RunCoverage::OtherMode(_) => "other-mode",
        }
    }
}

/// For each requirement of `cat` that a check verifies: what the run's `results` did for
/// it. `results` are (check id, status key, summary) of a run of `cat`'s model, which
/// spoke the modes `spoken` (none known: no requirement is put down to a mode).
pub fn of_run<'c>(
    cat: &'c Catalogue,
    spoken: &[crate::codec::Mode],
    results: &[(&str, &str, &str)],
) -> Vec<(&'c Requirement, RunCoverage)> {
    use crate::codec::Mode;
    // A check's id begins with its mode ("rtu.map...", "ascii.write...", "*.write...").
    let mode_of = |id: &str| id.split('.').next().and_then(Mode::from_key);
    // The one mode all of `r`'s checks are of, when the run did not speak it.
    let other_mode = |r: &Requirement| {
        let first = mode_of(r.verified_by.checks.first()?)?;
        let all = r
            .verified_by
            .checks
            .iter()
            .all(|p| mode_of(p) == Some(first));
        (all && !spoken.is_empty() && !spoken.contains(&first)).then_some(first)
    };
    cat.current()
        .filter(|r| !r.verified_by.checks.is_empty())
        .map(|r| {
            let mine: Vec<&(&str, &str, &str)> = results
                .iter()
                .filter(|(id, _, _)| r.verified_by.checks.iter().any(|p| matches(p, id)))
                .collect();
            let got = if mine.iter().any(|(_, s, _)| *s == "deviation") {
                RunCoverage::Deviated
            } else if mine
                .iter()
                .any(|(_, s, _)| *s == "pass" || *s == "observation")
            {
                RunCoverage::Verified
            } else if let Some((_, _, why)) = mine.iter().find(|(_, s, _)| *s == "error") {
                RunCoverage::Error(why.to_string())
            } else if let Some((_, _, why)) = mine.first() {
                RunCoverage::Skipped(why.to_string())
            } else if let Some(m) = other_mode(r) {
                RunCoverage::OtherMode(m)
            } else {
                RunCoverage::NotRun
            };
            (r, got)
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// A requirement whose checks are all of the mode a run did not speak is said to be
    /// of that mode, not "not selected"; one whose checks are of either mode, or of the
    /// mode spoken, is not.
    #[test]
    fn a_requirement_of_the_mode_not_run_is_named_so() {
        let cat = crate::requirements::of_model("f510").unwrap();
        let only_rtu = [("rtu.map.group-0.first", "pass", "")];
        let rows = of_run(cat, &[crate::codec::Mode::Rtu], &only_rtu);
        let of = |m: &str| {
            rows.iter()
                .filter(|(r, _)| {
                    r.verified_by
                        .checks
                        .iter()
                        .all(|p| p.starts_with(&format!("{m}.")))
                })
                .map(|(_, c)| c.clone())
                .collect::<Vec<_>>()
        };
        let ascii = of("ascii");
        assert!(!ascii.is_empty());
        assert!(
            ascii
                .iter()
                .all(|c| *c == RunCoverage::OtherMode(crate::codec::Mode::Ascii)),
            "{ascii:?}"
        );
        let rtu = of("rtu");
        assert!(!rtu.is_empty());
        assert!(
            rtu.iter().all(|c| !matches!(c, RunCoverage::OtherMode(_))),
            "{rtu:?}"
        );
        // Checks of either mode ("*."), not selected: not the other mode's.
        assert!(rows
            .iter()
            .filter(|(r, _)| r.verified_by.checks.iter().all(|p| p.starts_with("*.")))
            .all(|(_, c)| !matches!(c, RunCoverage::OtherMode(_))));
        // A run of both modes whose --only kept RTU checks: the ASCII requirements were
        // not selected; and with the modes not known, nothing is put down to one.
        use crate::codec::Mode;
        for spoken in [&[Mode::Rtu, Mode::Ascii][..], &[]] {
            assert!(of_run(cat, spoken, &only_rtu)
                .iter()
                .all(|(_, c)| !matches!(c, RunCoverage::OtherMode(_))));
        }
    }

    #[test]
    fn pointers_select_list_elements_by_their_key() {
        let doc = json!({"registers": [{"register": "2500"}, {"register": "2501", "name": "Operation"}],
                         "groups": [{"name": "monitor"}], "limits": {"read_registers": {"rtu": 37}}});
        assert_eq!(
            resolve(&doc, "/registers/2501/name"),
            Some(&json!("Operation"))
        );
        assert!(resolve(&doc, "/registers/2502").is_none());
        assert!(resolve(&doc, "/groups/monitor").is_some());
        assert!(resolve(&doc, "/groups/0").is_some());
        assert!(resolve(&doc, "/limits/read_registers/rtu").is_some());
        assert!(resolve(&doc, "/limits/write").is_none());
        assert!(resolve(&doc, "limits").is_none());
    }
}
