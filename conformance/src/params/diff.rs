//! Two sets of parameter values side by side: which parameters differ, by name and group,
//! and which one side has that the other has not.

use std::collections::BTreeMap;

use super::{find, Parameter};

/// One side of a comparison: a label for people and the values it has.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Side {
    /// What it is ("drive.toml (f510, node 1, 2026-11-28T02:00:00Z)", "live", "model").
    pub label: String,
    /// The values it has, by register.
    pub values: BTreeMap<u16, u16>,
    /// Whether a register this side has no value for is "not stated" (the model's
    /// initial values, which cover few parameters) rather than missing.
    pub partial: bool,
}

/// One parameter whose values differ.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ValueDiff {
    /// The register.
    pub register: u16,
    /// Its group, as the model names it.
    pub group: String,
    /// Its name.
    pub name: String,
    /// Side A's value.
    pub a: u16,
    /// Side B's value.
    pub b: u16,
}

/// The outcome of a comparison.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Difference {
    /// Parameters with a value on both sides that differ.
    pub differ: Vec<ValueDiff>,
    /// Registers only side A has (where B is not partial).
    pub only_a: Vec<u16>,
    /// Registers only side B has (where A is not partial).
    pub only_b: Vec<u16>,
    /// Parameters compared (a value on both sides).
    pub compared: usize,
    /// Registers one side has that a partial side does not state.
    pub not_stated: usize,
}

impl Difference {
    /// Whether anything differs (CI's exit 1).
    pub fn any(&self) -> bool {
        !self.differ.is_empty() || !self.only_a.is_empty() || !self.only_b.is_empty()
    }
}

/// Compares `a` and `b`; names and groups come from `params` (a register that is no
/// parameter of the model keeps its number as its name).
pub fn diff(params: &[Parameter], a: &Side, b: &Side) -> Difference {
    let mut d = Difference::default();
    for (&r, &va) in &a.values {
        match b.values.get(&r) {
            Some(&vb) => {
                d.compared += 1;
                if va != vb {
                    let (group, name) = match find(params, r) {
                        Some(p) => (p.group.clone(), p.name.clone()),
                        None => ("not a parameter".into(), format!("{r:04X}H")),
                    };
                    d.differ.push(ValueDiff {
                        register: r,
                        group,
                        name,
                        a: va,
                        b: vb,
                    });
                }
            }
            None if b.partial => d.not_stated += 1,
            None => d.only_a.push(r),
        }
    }
    for &r in b.values.keys() {
        if !a.values.contains_key(&r) {
            if a.partial {
                d.not_stated += 1;
            } else {
                d.only_b.push(r);
            }
        }
    }
    d
}
