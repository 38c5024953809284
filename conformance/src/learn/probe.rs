//! The probes after the map: functions and the unserved-function exception, the count
//! limit and its exception, the silences, a register that identifies the device, and
//! (with `allow_write`) whether its blocks take writes. Each probe that may upset a
//! device (an unknown function, a frame to another node) is followed by a read it has
//! answered: a device that stops answering ends the learn with what it had.

use crate::codec::{frame_of_body, Mode};
use crate::model::{DriveModel, MODELS};

use super::ask::{registers, Answer, Asker, Evidence};
use super::map::SPEC_READ_LIMIT;
use super::{FunctionSeen, LearnConfig, LearnError, Learned, SilenceSeen, WriteSeen};

/// The unserved function the runner sends (`check`'s `function.41`), with its data.
const UNSERVED: [u8; 5] = [0x41, 0x25, 0x20, 0x00, 0x01];
/// 04H as the runner sends it (`check`'s `function.04`).
const INPUT_READ: [u8; 5] = [0x04, 0x25, 0x20, 0x00, 0x01];
/// Loop-back, test code 0000H, two data bytes.
const LOOP_BACK: [u8; 5] = [0x08, 0x00, 0x00, 0xA5, 0x5A];

/// Runs every probe in order, filling `learned`.
pub fn all(
    ask: &mut Asker<'_>,
    cfg: &LearnConfig,
    learned: &mut Learned,
) -> Result<(), LearnError> {
    // A register the device serves, for the reads the probes need: the first of the
    // longest block (or the range's first register, refused, where none was found).
    let longest = learned
        .map
        .blocks
        .iter()
        .max_by_key(|b| {
            (
                u32::from(b.last) - u32::from(b.first),
                std::cmp::Reverse(b.first),
            )
        })
        .map(|b| (b.first, b.last));
    let at = longest.map_or(cfg.map.first, |(f, _)| f);
    ask.left = 16;
    ask.doing = "functions".into();
    functions(ask, learned, at, longest.is_some())?;
    if let Some((first, last)) = longest {
        ask.doing = "read limit".into();
        counts(ask, learned, first, last)?;
    }
    ask.doing = "silences".into();
    silences(ask, cfg, learned, at, longest.is_some())?;
    ask.doing = "identification".into();
    identification(ask, learned)?;
    if cfg.allow_write {
        ask.doing = "writes".into();
        writes(ask, learned)?;
    }
    Ok(())
}

fn read_body(node: u8, start: u16, count: u16) -> Vec<u8> {
    let [sh, sl] = start.to_be_bytes();
    let [ch, cl] = count.to_be_bytes();
    vec![node, 0x03, sh, sl, ch, cl]
}

/// Reads `at` again after a probe that may have upset the device: an error where it no
/// longer answers.
fn alive(ask: &mut Asker<'_>, at: u16, after: &str) -> Result<(), LearnError> {
    let (a, ev) = ask.ask(&read_body(ask.node(), at, 1), true)?;
    match a {
        Answer::Data(_) => Ok(()),
        other => Err(LearnError::Gone {
            after: after.to_string(),
            request: ev.request,
            answer: other.describe(),
        }),
    }
}

fn functions(
    ask: &mut Asker<'_>,
    learned: &mut Learned,
    at: u16,
    served_at: bool,
) -> Result<(), LearnError> {
    let node = ask.node();
    // 41H first: its exception is the unserved-function one, which tells what the
    // answers to 04H and 08H mean.
    for probe in [UNSERVED, INPUT_READ, LOOP_BACK] {
        let code = probe[0];
        let body = [&[node][..], &probe[..]].concat();
        let (answer, evidence) = ask.ask(&body, true)?;
        let unserved = learned.illegal_function.as_ref().map_or(0x01, |(c, _)| *c);
        let served = match &answer {
            Answer::Data(d) if code == 0x08 => Some(*d == probe[1..]),
            Answer::Data(_) => Some(true),
            Answer::Exception(c) if code == 0x41 => {
                learned.illegal_function = Some((*c, evidence.clone()));
                Some(false)
            }
            Answer::Exception(c) => Some(*c != unserved),
            Answer::Silent | Answer::Other => None,
        };
        learned.functions.push(FunctionSeen {
            code,
            served,
            answer: answer.clone(),
            evidence: evidence.clone(),
        });
        if served.is_none() {
            learned.notes.push(format!(
                "Function {code:02X}H drew {} ({}): whether the device serves it is not known.",
                answer.describe(),
                evidence.request
            ));
        }
        if served_at && !matches!(answer, Answer::Data(_)) {
            alive(ask, at, &format!("function {code:02X}H"))?;
        }
    }
    Ok(())
}

/// The read limit where the map did not show it, and the exception for a count over
/// it; at the first register of the longest block, `first..=last`.
fn counts(
    ask: &mut Asker<'_>,
    learned: &mut Learned,
    first: u16,
    last: u16,
) -> Result<(), LearnError> {
    let node = ask.node();
    let len = u32::from(last) - u32::from(first) + 1;
    let shown = learned.map.limit.as_ref().map(|(n, _)| *n).or_else(|| {
        learned
            .map
            .largest
            .as_ref()
            .map(|(n, _)| *n)
            .filter(|&n| n >= SPEC_READ_LIMIT)
    });
    let (over, over_ev) = ask.ask(&read_body(node, first, SPEC_READ_LIMIT + 1), true)?;
    let (zero, zero_ev) = ask.ask(&read_body(node, first, 0), true)?;
    let mut limit = shown;
    let mut count_ev = over_ev.clone();
    let mut count_answer = over.clone();
    if let Some(n) = shown.filter(|&n| n < SPEC_READ_LIMIT) {
        let (a, ev) = ask.ask(&read_body(node, first, n + 1), true)?;
        count_answer = a;
        count_ev = ev;
    } else if shown.is_none() && len < u32::from(SPEC_READ_LIMIT) {
        // Every block is shorter than the limit: a read past the block's end is refused
        // for its register; where the count exception differs, the first count that
        // draws it is one over the limit.
        let past = len as u16 + 1;
        let (a, _) = ask.ask(&read_body(node, first, past), true)?;
        if let (Answer::Exception(c), Answer::Exception(d)) = (&over, &a) {
            if c != d {
                let (mut good, mut bad) = (past, SPEC_READ_LIMIT + 1);
                let mut bad_ev = over_ev.clone();
                while bad - good > 1 {
                    let mid = good + (bad - good) / 2;
                    let (a, ev) = ask.ask(&read_body(node, first, mid), true)?;
                    if a == over {
                        bad = mid;
                        bad_ev = ev;
                    } else {
                        good = mid;
                    }
                }
                limit = Some(bad - 1);
                count_ev = bad_ev;
                learned.read_limit = Some((bad - 1, count_ev.clone()));
            }
        }
        if limit.is_none() {
            learned.notes.push(format!(
                "No block is as long as the read limit and the device answers a read past a block's end as it answers a count over the limit ({}): the read limit is not known; the largest read answered is {} registers.",
                a.describe(),
                learned.map.largest.as_ref().map_or(0, |(n, _)| *n)
            ));
        }
    }
    match (&count_answer, &zero) {
        (Answer::Exception(c), Answer::Exception(z)) if c == z => {
            learned.illegal_count = Some((*c, count_ev));
        }
        _ => learned.notes.push(format!(
            "A count over the limit drew {} ({}) and count 0 drew {} ({}): no one exception for an illegal count is stated.",
            count_answer.describe(),
            count_ev.request,
            zero.describe(),
            zero_ev.request
        )),
    }
    Ok(())
}

fn silences(
    ask: &mut Asker<'_>,
    cfg: &LearnConfig,
    learned: &mut Learned,
    at: u16,
    served_at: bool,
) -> Result<(), LearnError> {
    let node = ask.node();
    let mode = ask.mode();
    let read = read_body(node, at, 1);
    let mut broadcast = read.clone();
    broadcast[0] = 0;
    let mut other = read.clone();
    other[0] = cfg.other_address;
    let mut bad = frame_of_body(mode, &read).map_err(|e| LearnError::Frame(e.to_string()))?;
    match mode {
        Mode::Rtu => {
            if let Some(b) = bad.last_mut() {
                *b ^= 0xFF;
            }
        }
        Mode::Ascii => {
            // The LRC's last digit, changed to another hex digit.
            let i = bad.len().saturating_sub(3);
            if let Some(c) = bad.get_mut(i) {
                *c = if *c == b'0' { b'1' } else { b'0' };
            }
        }
    }
    let good = frame_of_body(mode, &broadcast).map_err(|e| LearnError::Frame(e.to_string()))?;
    let other = frame_of_body(mode, &other).map_err(|e| LearnError::Frame(e.to_string()))?;
    for (reason, frame) in [
        ("broadcast", good),
        ("other-address", other),
        ("bad-checksum", bad),
    ] {
        let (answer, evidence) = ask.ask_frame(&frame, false)?;
        let silent = answer == Answer::Silent;
        if !silent {
            learned.notes.push(format!(
                "{reason}: the device did not keep silent: {} drew {}{}.",
                evidence.request,
                answer.describe(),
                evidence
                    .reply
                    .as_ref()
                    .map_or(String::new(), |r| format!(" ({r})"))
            ));
        }
        learned.silence.push(SilenceSeen {
            reason,
            silent,
            evidence,
        });
        if served_at {
            alive(ask, at, reason)?;
        }
    }
    Ok(())
}

/// The identification values of the five models: (model, register, value), the
/// documented value or, where the manual gives none, this suite's simulator's.
fn model_identifications() -> Vec<(String, u16, u16)> {
    MODELS
        .iter()
        .filter_map(|id| DriveModel::builtin(id).ok())
        .filter_map(|m| {
            let i = m.identification.as_ref()?;
            Some((m.id.clone(), i.register?, i.value.unwrap_or(i.simulated)))
        })
        .collect()
}

/// A register whose value stayed the same over the learn and differs from every model
/// that identifies itself by the same register: TECO's 252FH first, then registers
/// holding something other than 0000H, then the rest; read again to see it stays.
fn identification(ask: &mut Asker<'_>, learned: &mut Learned) -> Result<(), LearnError> {
    let models = model_identifications();
    let tells = |r: u16, v: u16| !models.iter().any(|(_, mr, mv)| *mr == r && *mv == v);
    let steady = |r: &u16| !learned.map.changed.contains(r);
    let values = &learned.map.values;
    let mut candidates: Vec<u16> = Vec::new();
    if let Some(&v) = values.get(&0x252F) {
        if tells(0x252F, v) && steady(&0x252F) {
            candidates.push(0x252F);
        } else if let Some((id, ..)) = models.iter().find(|(_, r, mv)| *r == 0x252F && *mv == v) {
            learned.notes.push(format!(
                "252FH reads {v:04X}H, the {id} model's identification value: this may be that model; another register is named for identification."
            ));
        }
    }
    candidates.extend(
        values
            .iter()
            .filter(|&(r, v)| *v != 0 && *r != 0x252F && steady(r) && tells(*r, *v))
            .map(|(r, _)| *r)
            .take(3),
    );
    candidates.extend(
        values
            .iter()
            .filter(|&(r, v)| *v == 0 && *r != 0x252F && steady(r) && tells(*r, *v))
            .map(|(r, _)| *r)
            .take(1),
    );
    let node = ask.node();
    for r in candidates {
        let (a, ev) = ask.ask(&read_body(node, r, 1), true)?;
        let now = match &a {
            Answer::Data(d) => registers(d, 1).map(|v| v[0]),
            _ => None,
        };
        match (now, values.get(&r)) {
            (Some(v), Some(&was)) if v == was => {
                learned.identification = Some((r, v, ev));
                return Ok(());
            }
            (Some(_), Some(_)) => {
                learned.map.changed.insert(r);
            }
            _ => {}
        }
    }
    Ok(())
}

/// With `allow_write`: the first register of each block written with the value just
/// read (06H, then 10H with one register) and read back.
fn writes(ask: &mut Asker<'_>, learned: &mut Learned) -> Result<(), LearnError> {
    let node = ask.node();
    let firsts: Vec<u16> = learned.map.blocks.iter().map(|b| b.first).collect();
    for r in firsts {
        let [rh, rl] = r.to_be_bytes();
        for function in [0x06u8, 0x10] {
            let (a, _) = ask.ask(&read_body(node, r, 1), true)?;
            let Some(value) = (match &a {
                Answer::Data(d) => registers(d, 1).map(|v| v[0]),
                _ => None,
            }) else {
                continue;
            };
            let [vh, vl] = value.to_be_bytes();
            let body = if function == 0x06 {
                vec![node, 0x06, rh, rl, vh, vl]
            } else {
                vec![node, 0x10, rh, rl, 0x00, 0x01, 0x02, vh, vl]
            };
            let (answer, evidence) = ask.ask(&body, true)?;
            let verified = if matches!(answer, Answer::Data(_)) {
                let (a, _) = ask.ask(&read_body(node, r, 1), true)?;
                Some(matches!(&a, Answer::Data(d) if registers(d, 1) == Some(vec![value])))
            } else {
                None
            };
            if verified == Some(false) {
                learned.notes.push(format!(
                    "{r:04X}H: written with the value just read ({value:04X}H) by {function:02X}H, it read back otherwise."
                ));
            }
            learned.writes.push(WriteSeen {
                register: r,
                function,
                answer,
                verified,
                evidence,
            });
        }
    }
    Ok(())
}

/// What the draft says of a block's access, from the writes to its first register:
/// read-write (a write answered and read back), read-only (every write refused with an
/// exception other than the unserved-function one), or not known.
pub fn block_access(learned: &Learned, first: u16) -> Option<(&'static str, &Evidence)> {
    let unserved = learned.illegal_function.as_ref().map(|(c, _)| *c);
    let tried: Vec<&WriteSeen> = learned
        .writes
        .iter()
        .filter(|w| w.register == first)
        .collect();
    if let Some(w) = tried
        .iter()
        .find(|w| matches!(w.answer, Answer::Data(_)) && w.verified == Some(true))
    {
        return Some(("read-write", &w.evidence));
    }
    let refused = |w: &&&WriteSeen| matches!(w.answer, Answer::Exception(c) if Some(c) != unserved);
    if !tried.is_empty() && tried.iter().all(|w| refused(&w)) {
        return Some(("read-only", &tried[0].evidence));
    }
    None
}

/// Whether a write function was seen served (a reply, or an exception other than the
/// unserved-function one), with the write that showed it.
pub fn write_served(learned: &Learned, function: u8) -> Option<&Evidence> {
    let unserved = learned.illegal_function.as_ref().map(|(c, _)| *c);
    learned
        .writes
        .iter()
        .filter(|w| w.function == function)
        .find(|w| match w.answer {
            Answer::Data(_) => true,
            Answer::Exception(c) => Some(c) != unserved,
            _ => false,
        })
        .map(|w| &w.evidence)
}
