//! A register's value as the description means it: its unit and scale, the range a
//! value must be in, and its bits by name. The monitor prints writes with it
//! ("2502H (Frequency command (0.01 Hz)) <- 1194H = 45.00 Hz") and `watch` prints and
//! judges every value it reads with it, so that both say the same.

use super::{DriveModel, Fact, NamedBit};

/// How a raw value becomes a quantity: value = raw x `scale`, in `unit`.
#[derive(Debug, Clone, PartialEq)]
pub struct Unit {
    /// The factor (0.01 for a 0.01 Hz register).
    pub scale: f64,
    /// The unit ("Hz", "A"); empty for a plain number that has a scale.
    pub unit: String,
    /// Decimals that show one step of the scale (2 for 0.01).
    pub decimals: usize,
}

impl Unit {
    /// The unit of a register a description gives a scale and a unit for (either may be
    /// left out); `None` where it gives neither, or only a scale of 1.
    pub fn of(scale: Option<f64>, unit: Option<&str>) -> Option<Unit> {
        let unit = unit.unwrap_or("");
        let scale = scale.unwrap_or(1.0);
        if unit.is_empty() && scale == 1.0 {
            return None;
        }
        Some(Unit {
            scale,
            unit: unit.to_string(),
            decimals: decimals_of(scale),
        })
    }

    /// The quantity `raw` stands for, as text ("45.00 Hz"). A scale that is a power of
    /// ten is applied in integers, so that no rounding shows (1194H is 45.00, never
    /// 44.99999).
    pub fn show(&self, raw: u16) -> String {
        let number = match pow10(self.scale) {
            Some(k) if k > 0 => {
                let d = 10u32.pow(k as u32);
                let v = u32::from(raw);
                format!("{}.{:0w$}", v / d, v % d, w = k as usize)
            }
            _ => format!("{:.*}", self.decimals, f64::from(raw) * self.scale),
        };
        if self.unit.is_empty() {
            number
        } else {
            format!("{number} {}", self.unit)
        }
    }

    /// The quantity as a number (for a chart or a CSV column).
    pub fn value(&self, raw: u16) -> f64 {
        f64::from(raw) * self.scale
    }
}

/// `k` where `scale` is 10^-k (0 <= k <= 6).
fn pow10(scale: f64) -> Option<i32> {
    (0..=6).find(|&k| (scale - 10f64.powi(-k)).abs() < 1e-12)
}

/// Decimals that show one step of `scale` (at most 6).
fn decimals_of(scale: f64) -> usize {
    (0..=6)
        .find(|&k| {
            let s = scale * 10f64.powi(k as i32);
            (s - s.round()).abs() < 1e-9
        })
        .unwrap_or(6)
}

/// The range a register's value must be in, with where it comes from.
#[derive(Debug, Clone, PartialEq)]
pub struct ValueRange {
    /// Smallest legal value, if the description gives one.
    pub min: Option<u16>,
    /// Largest legal value, if the description gives one.
    pub max: Option<u16>,
    /// Basis and citation of the bound.
    pub fact: Fact,
}

impl ValueRange {
    /// Whether `v` is inside.
    pub fn admits(&self, v: u16) -> bool {
        self.min.is_none_or(|m| v >= m) && self.max.is_none_or(|m| v <= m)
    }

    /// "0000H..9C40H", "0001H or more", "03E8H or less".
    pub fn bounds(&self) -> String {
        match (self.min, self.max) {
            (Some(lo), Some(hi)) => format!("{lo:04X}H..{hi:04X}H"),
            (Some(lo), None) => format!("{lo:04X}H or more"),
            (None, Some(hi)) => format!("{hi:04X}H or less"),
            (None, None) => "any".to_string(),
        }
    }
}

impl DriveModel {
    /// The unit and scale of `register`: a block's `unit` and `scale`, or the unit a
    /// named register's name prints in parentheses ("Frequency command (0.01 Hz)");
    /// `None` where the description gives none (the value is a plain number).
    pub fn unit_of(&self, register: u16) -> Option<Unit> {
        if let Some(n) = self.named(register) {
            return unit_in_name(&n.name);
        }
        let b = self.block_of(register)?;
        let scale = b.scale.unwrap_or(1.0);
        if b.unit.is_none() && b.scale.is_none() {
            return None;
        }
        Some(Unit {
            scale,
            unit: b.unit.clone().unwrap_or_default(),
            decimals: decimals_of(scale),
        })
    }

    /// The value `raw` of `register` in its unit ("45.00 Hz"), where it has one.
    pub fn value_text(&self, register: u16, raw: u16) -> Option<String> {
        self.unit_of(register).map(|u| u.show(raw))
    }

    /// A register with its name and a value written to it, in its unit where it has one
    /// ("2502H (Frequency command (0.01 Hz)) <- 1194H = 45.00 Hz").
    pub fn assignment(&self, register: u16, raw: u16) -> String {
        let name = self.describe(register);
        match self.value_text(register, raw) {
            Some(v) => format!("{name} <- {raw:04X}H = {v}"),
            None => format!("{name} <- {raw:04X}H"),
        }
    }

    /// The range a value of `register` must be in: a named register's maximum (from 0),
    /// or a block's bounds; `None` where the description gives none.
    pub fn range_of(&self, register: u16) -> Option<ValueRange> {
        if let Some((max, fact)) = self.named(register).and_then(|n| n.max.as_ref()) {
            return Some(ValueRange {
                min: None,
                max: Some(*max),
                fact: fact.clone(),
            });
        }
        let b = self.block_of(register)?;
        (b.min.is_some() || b.max.is_some()).then(|| ValueRange {
            min: b.min,
            max: b.max,
            fact: b.fact.clone(),
        })
    }

    /// The bits of `register` by name (empty where it is no command or status word).
    pub fn bits_of(&self, register: u16) -> &[NamedBit] {
        self.named(register).map_or(&[], |n| n.bits.as_slice())
    }
}

/// The unit a name prints in its last parentheses: "(0.01 Hz)" is 0.01 Hz, "(Unit:
/// 0.1A)" is 0.1 A; "(0..1000)" and "(fault code)" are none.
fn unit_in_name(name: &str) -> Option<Unit> {
    let open = name.rfind('(')?;
    let inner = name[open + 1..].strip_suffix(')')?.trim();
    let inner = inner
        .strip_prefix("Unit:")
        .or_else(|| inner.strip_prefix("unit:"))
        .unwrap_or(inner)
        .trim();
    let split = inner
        .find(|c: char| !(c.is_ascii_digit() || c == '.'))
        .unwrap_or(inner.len());
    let (number, unit) = inner.split_at(split);
    let unit = unit.trim();
    // A bare range or a word is no unit; a unit is letters (and %) only.
    if number.is_empty() || unit.is_empty() || !unit.chars().all(|c| c.is_alphabetic() || c == '%')
    {
        return None;
    }
    let scale: f64 = number.parse().ok()?;
    (scale > 0.0).then(|| Unit {
        scale,
        unit: unit.to_string(),
        decimals: decimals_of(scale),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_unit_of_a_scale_and_a_unit_shows_every_digit_of_a_step() {
        assert_eq!(
            Unit::of(Some(0.01), Some("Hz")).unwrap().show(0x1194),
            "45.00 Hz"
        );
        // A step of 0.25 needs two decimals (params once printed one: 0.2 for 0.25).
        assert_eq!(Unit::of(Some(0.25), None).unwrap().show(1), "0.25");
        assert_eq!(Unit::of(None, Some("A")).unwrap().show(7), "7 A");
        assert_eq!(Unit::of(Some(10.0), Some("rpm")).unwrap().show(3), "30 rpm");
        assert!(Unit::of(None, None).is_none());
        assert!(Unit::of(Some(1.0), Some("")).is_none());
    }

    #[test]
    fn a_unit_is_read_from_the_name() {
        let u = unit_in_name("Frequency command (0.01 Hz)").unwrap();
        assert_eq!(u.show(0x1194), "45.00 Hz");
        assert_eq!(u.show(5), "0.05 Hz");
        assert_eq!(
            unit_in_name("Output current (Unit: 0.1A)")
                .unwrap()
                .show(123),
            "12.3 A"
        );
        assert!(unit_in_name("AO1 (0..1000)").is_none());
        assert!(unit_in_name("Error description (fault code)").is_none());
        assert!(unit_in_name("State signal").is_none());
    }

    #[test]
    fn the_f510_frequency_command_has_a_unit_a_range_and_the_status_word_bits() {
        let m = DriveModel::builtin("f510").unwrap();
        assert_eq!(
            m.assignment(0x2502, 0x1194),
            "2502H (Frequency command (0.01 Hz)) <- 1194H = 45.00 Hz"
        );
        let r = m.range_of(0x2502).unwrap();
        assert!(r.admits(0x9C40) && !r.admits(0x9C41));
        assert_eq!(r.bounds(), "9C40H or less");
        let bits = m.bits_of(0x2501);
        assert_eq!(bits.len(), 16);
        assert!(bits[4].reserved() && !bits[0].reserved());
        assert_eq!(m.bits_of(0x2520)[2].name, "Inverter ready (1: ready)");
        assert!(m.value_text(0x2521, 3).is_none());
    }

    #[test]
    fn a_block_scale_that_is_no_power_of_ten_is_shown_with_its_decimals() {
        let u = Unit {
            scale: 0.5,
            unit: "V".into(),
            decimals: decimals_of(0.5),
        };
        assert_eq!(u.show(3), "1.5 V");
    }
}
