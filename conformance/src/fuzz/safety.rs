//! Safety on a real drive: every case is vetted after it is built, whatever made it.
//!
//! A frame is read as leniently as a buggy device might read it (any checksum, ASCII in
//! any case); if it could write a register, it is sent only when:
//!
//! - `--writes none`: never;
//! - `--writes preserving` (the default): it goes to this device (not to another node,
//!   not as a broadcast, which every drive on the line would execute), and every value it
//!   carries is the value the device returned for that register, so nothing changes;
//! - `--writes any`: always, to registers journalled first.
//!
//! And in every level, never to a register that sets the communication, nor to a register
//! with the run and external-fault bits without `--allow-motion`; never 08H sub-functions
//! 0001H (restart communications) or 0004H (listen-only) without `--allow-restart`.
//!
//! The communication registers: the F510 and A510 manuals name parameter group 09 as the
//! communication group ("09-01 Communication Selection", "09-02 Baud Rate Setting" in the
//! F510 manual's parameter table; "parameter group 9 for related communication" in the
//! A510 manual's Profibus chapter); the other models follow the same numbering. The rule
//! is conservative: the whole group, 0900H..09FFH, in every model, is never written.

use std::collections::BTreeMap;

use crate::codec::hex::decode_nibble;
use crate::codec::Mode;
use crate::model::{DriveModel, Role};

use super::Writes;

/// The registers that set the communication, never written (see the module text).
pub const COMMUNICATION_GROUP: std::ops::RangeInclusive<u16> = 0x0900..=0x09FF;

/// What a frame could do to a device that reads it leniently.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Effect {
    /// The node address it carries.
    pub address: u8,
    /// (register, value) pairs it could write.
    pub writes: Vec<(u16, u16)>,
    /// The 08H sub-function it carries.
    pub loop_back: Option<u16>,
}

/// The bytes of a frame's body, read leniently: RTU without its last two bytes, ASCII
/// from ':' in either case up to the last pair of digits.
fn lenient_body(mode: Mode, frame: &[u8]) -> Vec<u8> {
    match mode {
        Mode::Rtu => frame[..frame.len().saturating_sub(2)].to_vec(),
        Mode::Ascii => {
            let text = frame.strip_prefix(b":").unwrap_or(frame);
            let digits: Vec<u8> = text.iter().filter_map(|&c| decode_nibble(c)).collect();
            let mut bytes: Vec<u8> = digits.chunks_exact(2).map(|p| p[0] << 4 | p[1]).collect();
            bytes.pop(); // the LRC
            bytes
        }
    }
}

/// What `frame` could do.
pub fn effect(mode: Mode, frame: &[u8]) -> Effect {
    let b = lenient_body(mode, frame);
    let word = |i: usize| -> Option<u16> { Some(u16::from_be_bytes([*b.get(i)?, *b.get(i + 1)?])) };
    let mut e = Effect {
        address: b.first().copied().unwrap_or(0),
        writes: Vec::new(),
        loop_back: None,
    };
    match b.get(1) {
        Some(0x06) => {
            if let (Some(r), Some(v)) = (word(2), word(4)) {
                e.writes.push((r, v));
            } else if let Some(r) = word(2) {
                e.writes.push((r, 0));
            }
        }
        Some(0x10) => {
            let start = word(2).unwrap_or(0);
            let mut i = 7;
            let mut r = start;
            // Whatever data it carries, and at least the start register.
            e.writes.push((start, word(7).unwrap_or(0)));
            while let Some(v) = word(i) {
                if i > 7 {
                    e.writes.push((r, v));
                }
                i += 2;
                r = r.wrapping_add(1);
            }
        }
        Some(0x08) => e.loop_back = word(2),
        _ => {}
    }
    e
}

/// Whether `register` may ever be written (in any safety level): not a communication
/// register; not one with the run or external-fault bits unless motion is allowed (the
/// caller checks that: see [`vet`]).
pub fn writable_register(model: &DriveModel, register: u16) -> bool {
    !COMMUNICATION_GROUP.contains(&register)
        && model
            .lookup(register)
            .is_none_or(|i| !COMMUNICATION_GROUP.contains(&i.register))
        && model.named(register).and_then(|n| n.role) != Some(Role::Operation)
}

/// Why a case is not sent, or `Ok` with the registers to journal first.
#[allow(clippy::too_many_arguments)]
pub fn vet(
    model: &DriveModel,
    mode: Mode,
    frame: &[u8],
    own: u8,
    writes: Writes,
    allow_motion: bool,
    allow_restart: bool,
    known: &BTreeMap<u16, u16>,
) -> Result<Vec<u16>, &'static str> {
    let e = effect(mode, frame);
    if matches!(e.loop_back, Some(1 | 4)) && !allow_restart {
        return Err("08H 0001H/0004H needs --allow-restart");
    }
    if e.writes.is_empty() {
        return Ok(Vec::new());
    }
    if writes == Writes::None {
        return Err("a write, with --writes none");
    }
    for &(r, _) in &e.writes {
        let operation = model
            .lookup(r)
            .and_then(|i| model.named(i.register))
            .and_then(|n| n.role)
            == Some(Role::Operation);
        if operation && !allow_motion {
            return Err("a write to the run/external-fault register needs --allow-motion");
        }
        if COMMUNICATION_GROUP.contains(&r)
            || model
                .lookup(r)
                .is_some_and(|i| COMMUNICATION_GROUP.contains(&i.register))
        {
            return Err("a write to a communication register (group 09)");
        }
    }
    if writes == Writes::Preserving {
        if e.address != own {
            return Err("a write to another node or a broadcast, with --writes preserving");
        }
        if e.writes.iter().any(|(r, v)| known.get(r) != Some(v)) {
            return Err("a write of a value the device did not return, with --writes preserving");
        }
    }
    Ok(e.writes.iter().map(|(r, _)| *r).collect())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::frame_of_body;

    #[test]
    fn preserving_writes_only_what_was_read() {
        let model = DriveModel::builtin("f510").unwrap();
        let known: BTreeMap<u16, u16> = [(0x0500, 7)].into_iter().collect();
        let f = |body: &[u8]| frame_of_body(Mode::Rtu, body).unwrap();
        let vet = |frame: &[u8], w| vet(&model, Mode::Rtu, frame, 1, w, false, false, &known);
        assert_eq!(
            vet(&f(&[1, 6, 5, 0, 0, 7]), Writes::Preserving),
            Ok(vec![0x0500])
        );
        assert!(vet(&f(&[1, 6, 5, 0, 0, 8]), Writes::Preserving).is_err());
        assert!(vet(&f(&[0, 6, 5, 0, 0, 7]), Writes::Preserving).is_err());
        assert!(vet(&f(&[1, 6, 5, 0, 0, 7]), Writes::None).is_err());
        // A bad checksum does not make a write safe.
        let mut bad = f(&[1, 6, 5, 0, 0, 8]);
        bad[7] ^= 1;
        assert!(vet(&bad, Writes::Preserving).is_err());
        // Communication registers, never; 10H with a byte count over its data, by its data.
        assert!(vet(&f(&[1, 6, 9, 2, 0, 1]), Writes::Any).is_err());
        assert!(vet(&f(&[1, 0x10, 5, 0, 0, 1, 9, 0, 7]), Writes::Preserving).is_ok());
        assert!(vet(&f(&[1, 0x10, 5, 0, 0, 1, 9, 0, 8]), Writes::Preserving).is_err());
        // 08H restart and listen-only.
        assert!(vet(&f(&[1, 8, 0, 4, 0, 0]), Writes::Any).is_err());
        assert!(vet(&f(&[1, 8, 0, 0, 0x12, 0x34]), Writes::None).is_ok());
        // ASCII in lower case is read as a device might.
        let a = frame_of_body(Mode::Ascii, &[1, 6, 5, 0, 0, 8])
            .unwrap()
            .to_ascii_lowercase();
        assert!(super::vet(
            &model,
            Mode::Ascii,
            &a,
            1,
            Writes::Preserving,
            false,
            false,
            &known
        )
        .is_err());
    }

    #[test]
    fn the_operation_register_needs_motion() {
        let model = DriveModel::builtin("f510").unwrap();
        let op = model.register_with_role(Role::Operation).unwrap();
        let [h, l] = op.to_be_bytes();
        let f = frame_of_body(Mode::Rtu, &[1, 6, h, l, 0, 0]).unwrap();
        let known = BTreeMap::new();
        assert!(vet(&model, Mode::Rtu, &f, 1, Writes::Any, false, false, &known).is_err());
        assert!(vet(&model, Mode::Rtu, &f, 1, Writes::Any, true, false, &known).is_ok());
    }
}
