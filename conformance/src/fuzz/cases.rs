//! The case generator: a seeded, reproducible stream of requests, well-formed and not.
//!
//! Every case comes from one seed and the case's number, so `--seed S` gives the same
//! cases on every machine. The mix: the manual's example requests (printed and
//! corrected), structure-aware requests over function × address × start × count × byte
//! count × values with edge values, byte mutations with the checksum recomputed and not,
//! truncation and extension, length fields that disagree with the data under a valid
//! checksum, unknown and exception-bit function codes, ASCII damage, and frames sent back
//! to back without t3.5 between them.
//!
//! Writes are generated only as the safety level allows (see [`super::safety`], which
//! vets every case again after it is built): with `preserving`, a write carries the value
//! the device returned for that register, so the generator asks for a read first.

use std::collections::BTreeMap;

use crate::codec::crc::crc16;
use crate::codec::deframe::rtu_frame_len;
use crate::codec::pdu::{function, Direction};
use crate::codec::{frame_of_body, frame_parts, Mode};
use crate::model::{Access, DriveModel};
use crate::rng::Rng;
use crate::vectors::model::{Body, FileDirection};
use crate::vectors::VectorFile;

use super::Writes;

/// What a case sends.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Step {
    /// One frame, answered as the model predicts.
    Frame(Vec<u8>),
    /// Frames written back to back in one write, without t3.5 between them (timing
    /// damage); judged by liveness only, as the standard leaves the outcome open.
    Burst(Vec<Vec<u8>>),
    /// Timing damage: frames sent with exact silences inside them (see
    /// [`super::timing`]); on links with line timing only.
    Timed(super::timing::Timed),
}

impl Step {
    /// The frames.
    pub fn frames(&self) -> Vec<&[u8]> {
        match self {
            Step::Frame(f) => vec![f.as_slice()],
            Step::Burst(fs) => fs.iter().map(Vec::as_slice).collect(),
            Step::Timed(t) => t.frames.iter().map(Vec::as_slice).collect(),
        }
    }
}

/// One case.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Case {
    /// Its number in the stream.
    pub index: u64,
    /// How it was made: the field class of its signature.
    pub class: &'static str,
    /// What it sends.
    pub step: Step,
}

/// The generator of one mode.
pub struct Generator<'a> {
    model: &'a DriveModel,
    mode: Mode,
    address: u8,
    other: u8,
    writes: Writes,
    rng: Rng,
    index: u64,
    golden: Vec<Vec<u8>>,
    edges: Vec<u16>,
    writable: Vec<u16>,
    /// Whether the link frames RTU by silence; without it, an RTU case is sent only if
    /// its whole burst is one frame by its checksum (see [`needs_line_timing`]).
    timed: bool,
    /// Timing damage, on a line with timing (see [`Generator::with_timing_damage`]).
    timing: Option<(crate::codec::timing::LineSettings, super::timing::Sweep)>,
}

/// Percent of the cases that are timing damage, where the link has line timing.
pub const TIMING_SHARE: u64 = 8;

/// Register counts worth trying.
const COUNTS: [u16; 12] = [0, 1, 2, 3, 8, 0x10, 0x7C, 0x7D, 0x7E, 0x7F, 0xFF, 0xFFFF];

/// Values worth writing (with `--writes any`).
const VALUES: [u16; 8] = [0, 1, 0x7F, 0x80, 0x7FFF, 0x8000, 0xFFFE, 0xFFFF];

/// Function codes no TECO drive serves, and exception-bit codes.
const ODD_FUNCTIONS: [u8; 16] = [
    0x00, 0x01, 0x02, 0x04, 0x05, 0x07, 0x0F, 0x11, 0x17, 0x2B, 0x41, 0x7F, 0x83, 0x86, 0x90, 0xFF,
];

impl<'a> Generator<'a> {
    /// A generator for `mode`, sending to `address` (`other` is an address no device on
    /// the line has), from `seed`.
    #[allow(clippy::too_many_arguments)]
    pub fn new(
        model: &'a DriveModel,
        vectors: Option<&VectorFile>,
        mode: Mode,
        address: u8,
        other: u8,
        writes: Writes,
        seed: u64,
        timed: bool,
    ) -> Self {
        let mut golden = Vec::new();
        for v in vectors.map(|f| f.vectors.as_slice()).unwrap_or_default() {
            let Body::Frame(fv) = &v.body else { continue };
            if fv.direction != FileDirection::Request {
                continue;
            }
            let vmode: Mode = fv.mode.into();
            let mut candidates = Vec::new();
            if let Ok(b) = crate::codec::hex::parse_hex(&fv.printed) {
                candidates.push(b);
            }
            if let Some(b) = fv.correct_bytes() {
                candidates.push(b);
            }
            for bytes in candidates {
                // The example's body, in this mode, to this device.
                if let Ok(p) = frame_parts(vmode, &bytes) {
                    let mut body = p.body.to_vec();
                    if let Some(a) = body.first_mut() {
                        *a = address;
                    }
                    if let Ok(f) = frame_of_body(mode, &body) {
                        golden.push(f);
                    }
                }
                if vmode == mode {
                    golden.push(bytes);
                }
            }
        }
        let in_map: std::collections::BTreeSet<u16> = model.registers().map(|(r, _)| r).collect();
        let mut edges: Vec<u16> = vec![0, 1, 0x7D, 0x7E, 0xFF, 0x100, 0xFFFE, 0xFFFF];
        for &r in &in_map {
            let below = r.checked_sub(1).is_none_or(|b| !in_map.contains(&b));
            let above = r.checked_add(1).is_none_or(|a| !in_map.contains(&a));
            if below || above {
                edges.extend(
                    [Some(r), r.checked_sub(1), r.checked_add(1)]
                        .into_iter()
                        .flatten(),
                );
            }
        }
        edges.extend(model.named.iter().map(|n| n.register));
        edges.sort_unstable();
        edges.dedup();
        let writable = model
            .registers()
            .filter(|(r, a)| *a == Access::ReadWrite && super::safety::writable_register(model, *r))
            .map(|(r, _)| r)
            .collect();
        Generator {
            model,
            mode,
            address,
            other,
            writes,
            rng: Rng::new(seed ^ (mode as u64).wrapping_mul(0x9E37_79B9)),
            index: 0,
            golden,
            edges,
            writable,
            timed,
            timing: None,
        }
    }

    /// Mixes timing damage into the stream (one case in [`TIMING_SHARE`] percent): the
    /// link carries `line`'s timing (a real port, or the simulator's paced
    /// pseudo-terminal), in RTU.
    pub fn with_timing_damage(mut self, line: crate::codec::timing::LineSettings) -> Self {
        self.timing = Some((line, super::timing::Sweep::default()));
        self
    }

    /// A timing case: the damage applied to requests for this device.
    fn timing_case(&mut self, known: &BTreeMap<u16, u16>) -> Option<(&'static str, Step)> {
        use super::timing::Damage;
        let damage = self.pick(&Damage::ALL);
        let (_, mut body) = self.structured(known);
        body[0] = self.address;
        let (_, mut second) = self.structured(known);
        second[0] = self.address;
        let back_to_back = self.rng.below(2) == 0;
        let (frame, second) = (self.frame(&body), self.frame(&second));
        let (line, sweep) = self.timing.as_mut()?;
        let t = sweep.make(line, damage, frame, second, back_to_back)?;
        Some((damage.class(), Step::Timed(t)))
    }

    /// The next case. `known` holds the values the device returned for registers it was
    /// read from (a `preserving` write carries one of these).
    pub fn next_case(&mut self, known: &BTreeMap<u16, u16>) -> Case {
        loop {
            let timing = if self.timing.is_some() && self.rng.below(100) < TIMING_SHARE {
                self.timing_case(known)
            } else {
                None
            };
            let (class, step) = match timing {
                Some(t) => t,
                None => self.make(known),
            };
            let ok = match &step {
                Step::Frame(f) => self.timed || self.mode == Mode::Ascii || !needs_line_timing(f),
                Step::Burst(_) | Step::Timed(_) => true,
            };
            if ok {
                let index = self.index;
                self.index += 1;
                return Case { index, class, step };
            }
        }
    }

    fn pick<T: Copy>(&mut self, items: &[T]) -> T {
        items[self.rng.below(items.len() as u64) as usize]
    }

    fn register(&mut self, known: &BTreeMap<u16, u16>) -> u16 {
        match self.rng.below(5) {
            0 => self.rng.word(),
            // A register read or written before: a read of it again must agree.
            2 if !known.is_empty() => {
                let k = self.rng.below(known.len() as u64) as usize;
                known.keys().nth(k).copied().unwrap_or(0)
            }
            1 if !self.writable.is_empty() => {
                let w = self.writable.clone();
                self.pick(&w)
            }
            _ => {
                let e = self.edges.clone();
                self.pick(&e)
            }
        }
    }

    fn address_for(&mut self) -> u8 {
        match self.rng.below(40) {
            0 => 0,
            1 => self.other,
            2 => self.rng.byte(),
            _ => self.address,
        }
    }

    fn frame(&self, body: &[u8]) -> Vec<u8> {
        frame_of_body(self.mode, body).unwrap_or_default()
    }

    /// A well-formed request body (the structure-aware generator).
    fn structured(&mut self, known: &BTreeMap<u16, u16>) -> (&'static str, Vec<u8>) {
        let a = self.address_for();
        let limit = self.model.limits.read.get(self.mode);
        let count = match self.rng.below(3) {
            0 => self.pick(&COUNTS),
            1 => limit.saturating_add(self.rng.below(2) as u16),
            _ => 1 + self.rng.below(4) as u16,
        };
        let start = self.register(known);
        let wants_write = self.writes != Writes::None && self.rng.below(3) == 0;
        if wants_write {
            // Half the time a writable register at a border (group ends, gaps), which
            // the reads favour too, so that a written value is read back soon.
            let edge_writable: Vec<u16> = self
                .edges
                .iter()
                .copied()
                .filter(|r| self.writable.binary_search(r).is_ok())
                .collect();
            let r = if !edge_writable.is_empty() && self.rng.below(2) == 0 {
                self.pick(&edge_writable)
            } else if self.writable.is_empty() {
                start
            } else {
                let w = self.writable.clone();
                self.pick(&w)
            };
            let value = match self.writes {
                Writes::Any => {
                    let v = self.pick(&VALUES);
                    if self.rng.below(2) == 0 {
                        v
                    } else {
                        self.rng.word()
                    }
                }
                _ => match known.get(&r) {
                    Some(&v) => v,
                    // The value is not known yet: read it first.
                    None => {
                        let [h, l] = r.to_be_bytes();
                        return ("read", vec![self.address, 0x03, h, l, 0, 1]);
                    }
                },
            };
            if self.rng.below(2) == 0 {
                let [h, l] = r.to_be_bytes();
                let [vh, vl] = value.to_be_bytes();
                return ("write-single", vec![a, 0x06, h, l, vh, vl]);
            }
            // 10H over consecutive registers whose values are known (or any, with `any`).
            let mut values = vec![value];
            let n = 1 + self.rng.below(3) as u16;
            for i in 1..n {
                let Some(next) = r.checked_add(i) else { break };
                match (self.writes, known.get(&next)) {
                    (Writes::Any, _) => values.push(self.rng.word()),
                    (_, Some(&v)) => values.push(v),
                    _ => break,
                }
            }
            let [h, l] = r.to_be_bytes();
            let [ch, cl] = (values.len() as u16).to_be_bytes();
            let mut body = vec![a, 0x10, h, l, ch, cl, (values.len() * 2) as u8];
            for v in values {
                body.extend_from_slice(&v.to_be_bytes());
            }
            return ("write-multiple", body);
        }
        match self.rng.below(8) {
            0 => {
                let sub = self.pick(&[0u16, 0, 0, 2, 3, 0x0A, 0x0B, 0x12, 0xFFFF]);
                let [sh, sl] = sub.to_be_bytes();
                let [dh, dl] = self.rng.word().to_be_bytes();
                ("loop-back", vec![a, 0x08, sh, sl, dh, dl])
            }
            _ => {
                let [h, l] = start.to_be_bytes();
                let [ch, cl] = count.to_be_bytes();
                ("read", vec![a, 0x03, h, l, ch, cl])
            }
        }
    }

    fn make(&mut self, known: &BTreeMap<u16, u16>) -> (&'static str, Step) {
        let roll = self.rng.below(100);
        if roll < 4 && !self.golden.is_empty() {
            let g = self.golden[self.rng.below(self.golden.len() as u64) as usize].clone();
            return ("golden", Step::Frame(g));
        }
        let (class, mut body) = self.structured(known);
        match roll {
            0..=44 => (class, Step::Frame(self.frame(&body))),
            45..=69 => {
                // Byte mutations of the body; the checksum recomputed half the time.
                let n = 1 + self.rng.below(3);
                for _ in 0..n {
                    let i = self.rng.below(body.len() as u64) as usize;
                    match self.rng.below(3) {
                        0 => body[i] ^= 1 << self.rng.below(8),
                        1 => body[i] = self.pick(&[0, 1, 0x7D, 0x7E, 0x7F, 0x80, 0xFF]),
                        _ => body[i] = self.rng.byte(),
                    }
                }
                let mut f = self.frame(&body);
                if self.rng.below(2) == 0 {
                    damage_checksum(self.mode, &mut f);
                    ("mutated-bad-checksum", Step::Frame(f))
                } else {
                    ("mutated", Step::Frame(f))
                }
            }
            70..=77 => {
                // Truncation or extension of the body, under a valid checksum or not.
                if self.rng.below(2) == 0 && body.len() > 2 {
                    let keep = 2 + self.rng.below(body.len() as u64 - 2) as usize;
                    body.truncate(keep);
                    ("truncated", Step::Frame(self.frame(&body)))
                } else {
                    let extra = 1 + self.rng.below(6);
                    for _ in 0..extra {
                        let b = self.rng.byte();
                        body.push(b);
                    }
                    let mut f = self.frame(&body);
                    if self.rng.below(3) == 0 {
                        damage_checksum(self.mode, &mut f);
                    }
                    ("extended", Step::Frame(f))
                }
            }
            78..=85 => {
                // A 10H whose byte count or register count disagrees with its data, under
                // a valid checksum.
                let r = self.register(known);
                let [h, l] = r.to_be_bytes();
                let words = self.rng.below(4) as usize;
                let count = self.pick(&[words as u16, words as u16 + 1, 0, 0x7B, 0xFFFF]);
                let [ch, cl] = count.to_be_bytes();
                let bc = match self.rng.below(3) {
                    0 => (words * 2 + 1 + self.rng.below(8) as usize) as u8,
                    1 => (words * 2).saturating_sub(1) as u8,
                    _ => self.rng.byte(),
                };
                let mut b = vec![self.address, 0x10, h, l, ch, cl, bc];
                for _ in 0..words * 2 {
                    let v = self.rng.byte();
                    b.push(v);
                }
                ("length-field", Step::Frame(self.frame(&b)))
            }
            86..=91 => {
                let fc = self.pick(&ODD_FUNCTIONS);
                let mut b = vec![self.address, fc];
                for _ in 0..self.rng.below(7) {
                    let v = self.rng.byte();
                    b.push(v);
                }
                ("function", Step::Frame(self.frame(&b)))
            }
            92..=95 => match self.mode {
                Mode::Ascii => ("ascii-damage", Step::Frame(self.ascii_damage(&body))),
                Mode::Rtu => {
                    body[1] = self.pick(&[function::READ_HOLDING_REGISTERS, 0x10, 0x06]);
                    ("address", Step::Frame(self.frame(&body)))
                }
            },
            _ => {
                // Frames back to back without t3.5: 2..8 reads of the device.
                let n = 2 + self.rng.below(7) as usize;
                let probe = self.edges.iter().copied().find(|&r| {
                    self.model
                        .lookup(r)
                        .is_some_and(|i| i.access != Access::NoAccess)
                });
                let r = probe.unwrap_or(0);
                let [h, l] = r.to_be_bytes();
                let f = self.frame(&[self.address, 0x03, h, l, 0, 1]);
                ("back-to-back", Step::Burst(vec![f; n]))
            }
        }
    }

    fn ascii_damage(&mut self, body: &[u8]) -> Vec<u8> {
        let mut f = self.frame(body);
        let n = f.len();
        match self.rng.below(5) {
            0 => f.make_ascii_lowercase(),
            1 if n > 5 => {
                f.remove(1 + self.rng.below(n as u64 - 3) as usize);
            }
            2 => {
                f.remove(n - 1 - self.rng.below(2) as usize);
            }
            3 if n > 3 => {
                let i = 1 + self.rng.below(n as u64 - 3) as usize;
                f[i] = self.pick(&[b'G', b'g', b' ', b'Z', 0x00, 0xFF, b':']);
            }
            _ => damage_checksum(Mode::Ascii, &mut f),
        }
        f
    }
}

/// Whether a Modbus TCP gateway can carry `step`: one RTU frame with a valid CRC (the
/// gateway sends its PDU; there is no checksum, no line timing and no ASCII on the TCP
/// side). Damaged frames and frames back to back cannot cross.
pub fn crosses_a_gateway(mode: Mode, step: &Step) -> bool {
    match step {
        Step::Frame(f) => {
            mode == Mode::Rtu
                && crate::codec::RtuFrame::new_checked(f.as_slice())
                    .is_ok_and(|v| v.verify_crc().is_ok())
        }
        Step::Burst(_) | Step::Timed(_) => false,
    }
}

/// Makes a frame's checksum wrong (RTU: the last CRC byte; ASCII: the last LRC digit).
pub fn damage_checksum(mode: Mode, frame: &mut [u8]) {
    let n = frame.len();
    match mode {
        Mode::Rtu if n >= 1 => frame[n - 1] ^= 0x5A,
        Mode::Ascii if n >= 3 => {
            let c = &mut frame[n - 3];
            *c = if *c == b'0' { b'1' } else { b'0' };
        }
        _ => {}
    }
}

/// Whether an RTU frame can only be told from what follows it by a silence: on a link
/// without timing (a pseudo-terminal, TCP) a receiver finds frames by the length their
/// function code implies, or by a whole burst that carries a valid CRC. A frame whose
/// checksum is wrong and whose implied length differs from its own (or that holds a
/// shorter frame) would swallow or spill into the next request there.
pub fn needs_line_timing(frame: &[u8]) -> bool {
    if frame.len() >= 4 && crc16(frame) == 0 {
        // One burst, one frame by its checksum; unless a shorter frame by the implied
        // length sits at its start.
        return matches!(rtu_frame_len(Direction::Request, frame), Some(n) if n < frame.len() && n >= 4 && crc16(&frame[..n]) == 0);
    }
    match rtu_frame_len(Direction::Request, frame) {
        Some(n) => n != frame.len() || (1..frame.len()).any(|i| starts_frame(&frame[i..])),
        None => {
            frame.len() < 4
                || frame.get(1) == Some(&function::WRITE_MULTIPLE_REGISTERS)
                || (1..frame.len()).any(|i| starts_frame(&frame[i..]))
        }
    }
}

/// Whether `rest` begins what a by-length receiver would wait on.
fn starts_frame(rest: &[u8]) -> bool {
    match rest.get(1) {
        Some(&f) => matches!(
            f,
            function::READ_HOLDING_REGISTERS
                | function::WRITE_SINGLE_REGISTER
                | function::LOOP_BACK
                | function::WRITE_MULTIPLE_REGISTERS
        ),
        None => true,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn gen(mode: Mode, seed: u64, writes: Writes) -> Vec<Case> {
        let model = DriveModel::builtin("f510").unwrap();
        let set = crate::vectors::VectorSet::builtin().unwrap();
        let mut g = Generator::new(&model, set.file("f510"), mode, 1, 0xF7, writes, seed, false);
        let known: BTreeMap<u16, u16> = BTreeMap::new();
        (0..3000).map(|_| g.next_case(&known)).collect()
    }

    #[test]
    fn the_same_seed_gives_the_same_cases() {
        assert_eq!(
            gen(Mode::Rtu, 7, Writes::Any),
            gen(Mode::Rtu, 7, Writes::Any)
        );
        assert_ne!(
            gen(Mode::Rtu, 7, Writes::Any),
            gen(Mode::Rtu, 8, Writes::Any)
        );
    }

    #[test]
    fn every_class_is_generated_and_untimed_rtu_is_framed_by_its_burst() {
        for mode in [Mode::Rtu, Mode::Ascii] {
            let cases = gen(mode, 1, Writes::Any);
            let classes: std::collections::BTreeSet<&str> = cases.iter().map(|c| c.class).collect();
            for want in [
                "golden",
                "read",
                "write-single",
                "write-multiple",
                "loop-back",
                "mutated",
                "truncated",
                "extended",
                "length-field",
                "function",
                "back-to-back",
            ] {
                assert!(
                    classes.contains(want),
                    "{mode}: no {want} case in {classes:?}"
                );
            }
            // Untimed RTU sends no frame with a wrong CRC (only a silence delimits one).
            assert_eq!(
                classes.contains("mutated-bad-checksum"),
                mode == Mode::Ascii,
                "{mode}"
            );
            if mode == Mode::Ascii {
                assert!(classes.contains("ascii-damage"));
            } else {
                for c in &cases {
                    if let Step::Frame(f) = &c.step {
                        assert!(!needs_line_timing(f), "{:02X?}", f);
                    }
                }
            }
        }
    }

    #[test]
    fn without_writes_no_write_is_generated() {
        for c in gen(Mode::Rtu, 3, Writes::None) {
            assert!(!matches!(c.class, "write-single" | "write-multiple"));
        }
    }

    #[test]
    fn a_byte_count_over_the_data_under_a_valid_crc_is_framed_by_its_burst() {
        let f = frame_of_body(Mode::Rtu, &[1, 0x10, 0x09, 0, 0, 1, 4, 0xAA, 0xBB]).unwrap();
        assert!(!needs_line_timing(&f));
        let mut bad = f.clone();
        damage_checksum(Mode::Rtu, &mut bad);
        assert!(needs_line_timing(&bad));
        let read = frame_of_body(Mode::Rtu, &[1, 3, 0x25, 0x20, 0, 1]).unwrap();
        assert!(!needs_line_timing(&read));
        assert!(needs_line_timing(&read[..5]));
    }
}
