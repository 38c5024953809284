//! Signatures: what a finding is about, so that one bug is one entry.
//!
//! A signature is mode × kind × function × the field of the difference: which field of
//! the reply differs from the model's (its exception code, a register value, its byte
//! count, bytes before it...), why the model predicted silence (a reply to a broadcast,
//! to another node...), the register whose value is wrong, or, for a hang, what was odd
//! about the request that silenced the device (a byte count over its data...). The case
//! classes that found a bug are not part of it: one bug found by mutated, truncated and
//! length-field cases is one entry, with the count per class.

use super::cases::Step;
use super::Kind;
use crate::codec::pdu::function;
use crate::codec::{frame_parts, Mode};
use crate::model::Expectation;
use crate::runner::Exchange;

/// The field of a difference between a reply and the model's prediction.
pub fn of_difference(
    kind: Kind,
    mode: Mode,
    expect: &Expectation,
    ex: &Exchange,
    expected: Option<&[u8]>,
    register: Option<u16>,
) -> String {
    match kind {
        Kind::UnexpectedReply => match expect {
            Expectation::Silence(r) => format!("reply-to-{}", r.key()),
            _ => "reply-where-silence".into(),
        },
        Kind::NoReply => match expect {
            Expectation::Exception { code, .. } => format!("no-reply-for-exception-{code:02X}"),
            _ => "no-reply-for-normal-reply".into(),
        },
        Kind::WrongValue => match register {
            Some(r) => format!("value-of-{r:04X}H"),
            None => "value".into(),
        },
        Kind::Hang => "silenced".into(),
        Kind::Mismatch => mismatch_field(mode, ex, expected).into(),
    }
}

fn mismatch_field(mode: Mode, ex: &Exchange, expected: Option<&[u8]>) -> &'static str {
    let Some(reply) = &ex.reply else {
        return "invalid-frame";
    };
    if !ex.leading.is_empty() {
        return "bytes-before-reply";
    }
    let (Some(exp), Ok(got)) = (
        expected.and_then(|e| frame_parts(mode, e).ok()),
        frame_parts(mode, reply),
    ) else {
        return if ex.trailing.is_empty() {
            "reply"
        } else {
            "bytes-after-reply"
        };
    };
    let (e, g) = (exp.body, got.body);
    if e.first() != g.first() {
        return "address";
    }
    let (ef, gf) = (
        e.get(1).copied().unwrap_or(0),
        g.get(1).copied().unwrap_or(0),
    );
    if ef & function::EXCEPTION_BIT != gf & function::EXCEPTION_BIT {
        return if gf & function::EXCEPTION_BIT != 0 {
            "exception-instead-of-reply"
        } else {
            "reply-instead-of-exception"
        };
    }
    if ef != gf {
        return "function";
    }
    if ef & function::EXCEPTION_BIT != 0 {
        return if e.get(2) != g.get(2) {
            "exception-code"
        } else if ex.trailing.is_empty() {
            "reply"
        } else {
            "bytes-after-reply"
        };
    }
    let Some(i) = e.iter().zip(&g).position(|(a, b)| a != b) else {
        return if e.len() != g.len() {
            "length"
        } else if !ex.trailing.is_empty() {
            "bytes-after-reply"
        } else {
            "checksum"
        };
    };
    match (ef, i) {
        (function::READ_HOLDING_REGISTERS, 2) => "byte-count",
        (function::READ_HOLDING_REGISTERS, _) => "register-value",
        (function::LOOP_BACK, 2 | 3) => "sub-function",
        (function::LOOP_BACK, _) => "loop-back-data",
        (_, 2 | 3) => "register-address",
        (function::WRITE_MULTIPLE_REGISTERS, _) => "register-count",
        (_, _) => "written-value",
    }
}

/// What was odd about the request(s) of a hang: the field class of its trigger.
pub fn of_request(mode: Mode, step: &Step) -> String {
    let frame = match step {
        Step::Burst(_) => return "back-to-back".into(),
        Step::Timed(t) => return t.damage.class().into(),
        Step::Frame(f) => f,
    };
    let Ok(parts) = frame_parts(mode, frame) else {
        return "unframed".into();
    };
    if !parts.checksum.is_valid() {
        return "bad-checksum".into();
    }
    let b = &parts.body;
    match b.get(1).copied() {
        Some(function::WRITE_MULTIPLE_REGISTERS) if b.len() >= 7 => {
            let data = b.len() - 7;
            let bc = usize::from(b[6]);
            let count = usize::from(u16::from_be_bytes([b[4], b[5]]));
            if bc > data {
                "byte-count-over-data".into()
            } else if bc < data {
                "byte-count-under-data".into()
            } else if count * 2 != bc {
                "count-vs-byte-count".into()
            } else {
                "well-formed".into()
            }
        }
        Some(
            function::READ_HOLDING_REGISTERS
            | function::WRITE_SINGLE_REGISTER
            | function::LOOP_BACK,
        ) => match b.len() {
            n if n < 6 => "short".into(),
            n if n > 6 => "long".into(),
            _ => "well-formed".into(),
        },
        Some(function::WRITE_MULTIPLE_REGISTERS) => "short".into(),
        _ => "function".into(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::frame_of_body;

    #[test]
    fn a_byte_count_over_the_data_is_one_class_however_it_was_made() {
        let f = frame_of_body(Mode::Rtu, &[1, 0x10, 0x25, 0x0C, 0, 1, 2]).unwrap();
        assert_eq!(
            of_request(Mode::Rtu, &Step::Frame(f)),
            "byte-count-over-data"
        );
        let f = frame_of_body(Mode::Rtu, &[1, 0x10, 0x25, 0x0C, 0, 1, 9, 0, 0]).unwrap();
        assert_eq!(
            of_request(Mode::Rtu, &Step::Frame(f)),
            "byte-count-over-data"
        );
        let f = frame_of_body(Mode::Rtu, &[1, 0x10, 0x25, 0x0C, 0, 2, 2, 0, 0]).unwrap();
        assert_eq!(
            of_request(Mode::Rtu, &Step::Frame(f)),
            "count-vs-byte-count"
        );
        assert_eq!(of_request(Mode::Rtu, &Step::Burst(vec![])), "back-to-back");
    }

    #[test]
    fn the_differing_field_of_a_reply_is_named() {
        let req = frame_of_body(Mode::Rtu, &[1, 3, 0, 0, 0, 1]).unwrap();
        let expected = frame_of_body(Mode::Rtu, &[1, 3, 2, 0, 4]).unwrap();
        let ex = |reply: Vec<u8>, leading: Vec<u8>| Exchange {
            request: req.clone(),
            raw: reply.clone(),
            chunks: vec![],
            echo: false,
            leading,
            reply: Some(reply),
            trailing: vec![],
            first_byte: None,
            listened: std::time::Duration::ZERO,
            retries: 0,
            link_notes: vec![],
        };
        let field = |e: &Exchange| mismatch_field(Mode::Rtu, e, Some(&expected));
        let value = frame_of_body(Mode::Rtu, &[1, 3, 2, 0, 5]).unwrap();
        assert_eq!(field(&ex(value.clone(), vec![])), "register-value");
        assert_eq!(field(&ex(value, vec![0xFF])), "bytes-before-reply");
        let exc = frame_of_body(Mode::Rtu, &[1, 0x83, 2]).unwrap();
        assert_eq!(field(&ex(exc, vec![])), "exception-instead-of-reply");
        let count = frame_of_body(Mode::Rtu, &[1, 3, 4, 0, 4, 0, 0]).unwrap();
        assert_eq!(field(&ex(count, vec![])), "byte-count");
    }
}
