//! Checks every vector against the codec: a `consistent` vector decodes and re-encodes
//! byte for byte; an `erratum` fails in exactly the ways its flags say; an `incomplete`
//! vector's known bytes agree with its `corrected` frame. Also the completeness rule (every
//! document has all of its items) and a human-readable rendering of every vector.

use std::collections::BTreeSet;
use std::fmt::Write as _;

use super::model::*;
use super::outcome::effective_body;
pub use super::outcome::VectorReport;
use super::set::VectorSet;
use crate::codec::hex::Hex;
use crate::codec::lrc::{lrc, lrc_chars};
use crate::codec::{crc::CrcBytes, Direction, FrameError, Message, Mode, Pdu};

/// Flags the checks can observe in a frame. Other flags (`ocr-repair`,
/// `checksum-placeholder`) describe the transcription and are checked separately.
const OBSERVABLE: [&str; 9] = [
    "framing-error",
    "crc-mismatch",
    "lrc-mismatch",
    "wrong-node-address",
    "ascii-rtu-mismatch",
    "register-mismatch",
    "function-mismatch",
    "exception-code-not-in-table",
    "length-mismatch",
];

pub use crate::codec::{frame_parts, FrameParts};

/// The body of the frame an example means: its `corrected` frame when the manual got it
/// wrong, else what was printed. A response is judged against the request it answers as
/// intended, so one misprinted request does not make its correct response look wrong.
fn intended_body(fv: &FrameVector) -> Option<Vec<u8>> {
    if let Some(c) = fv.corrected.as_deref().and_then(|c| parse_known(c).ok()) {
        if let Ok(p) = frame_parts(fv.mode.into(), &c) {
            return Some(p.body);
        }
    }
    effective_body(fv)
}

fn frame_of<'a>(set: &'a VectorSet, key: &FrameKey) -> Option<&'a FrameVector> {
    match &set.get(&key.id())?.body {
        Body::Frame(f) => Some(f),
        _ => None,
    }
}

fn exception_table(set: &VectorSet, document: &str) -> Option<Vec<u32>> {
    match &set.get(&format!("{document}.exception-codes"))?.body {
        Body::ExceptionCodes(t) => t
            .codes
            .iter()
            .map(|c| parse_hex_number(&c.code).ok())
            .collect(),
        _ => None,
    }
}

fn expect_num(e: &Option<Expect>, pick: fn(&Expect) -> &Option<String>) -> Option<u32> {
    e.as_ref()
        .and_then(|e| pick(e).as_deref())
        .and_then(|s| parse_hex_number(s).ok())
}

/// Flags the codec observes in the body of a frame vector, relative to its narrative
/// (`expect`), the request it answers and its twin in the other mode.
fn observe_body(
    set: &VectorSet,
    key: &FrameKey,
    fv: &FrameVector,
    body: &[u8],
    observed: &mut BTreeSet<&'static str>,
    problems: &mut Vec<String>,
) {
    let direction: Direction = fv.direction.into();
    let msg = match Message::parse_body(body, direction) {
        Ok(m) => Some(m),
        Err(
            FrameError::DataLength { .. }
            | FrameError::ByteCount { .. }
            | FrameError::CountMismatch { .. }
            | FrameError::ExceptionLength { .. }
            | FrameError::OddRegisterBytes { .. },
        ) => {
            observed.insert("length-mismatch");
            None
        }
        Err(e) => {
            problems.push(format!("body {} does not parse: {e}", Hex(body)));
            None
        }
    };

    // Node address: the narrative's, else the request's.
    let request_body = key
        .request()
        .and_then(|k| frame_of(set, &k))
        .and_then(intended_body);
    let want_address = expect_num(&fv.expect, |e| &e.address).or_else(|| {
        request_body
            .as_ref()
            .and_then(|b| b.first())
            .map(|&a| u32::from(a))
    });
    if let (Some(want), Some(&got)) = (want_address, body.first()) {
        if want != u32::from(got) {
            observed.insert("wrong-node-address");
        }
    }

    // Twin in the other mode.
    if let Some(twin_body) = frame_of(set, &key.twin()).and_then(effective_body) {
        if twin_body != body {
            observed.insert("ascii-rtu-mismatch");
        }
    }

    let Some(msg) = msg else { return };
    let is_exception_item = key.kind == Some(FrameKind::Exception) || key.kind.is_none();
    let want_function = key
        .function
        .map(u32::from)
        .or_else(|| expect_num(&fv.expect, |e| &e.function).map(|f| f & 0x7F));
    if is_exception_item {
        match msg.pdu {
            Pdu::Exception { function, code } => {
                if want_function.is_some_and(|w| w != u32::from(function)) {
                    observed.insert("function-mismatch");
                }
                if let Some(table) = exception_table(set, &key.document) {
                    if !table.contains(&u32::from(code)) {
                        observed.insert("exception-code-not-in-table");
                    }
                }
            }
            _ => {
                observed.insert("function-mismatch");
            }
        }
        return;
    }
    if want_function.is_some_and(|w| w != u32::from(msg.pdu.function_code())) {
        observed.insert("function-mismatch");
        return;
    }

    // Register, count and value: against the narrative, then against the request.
    let (reg, count, value) = match msg.pdu {
        Pdu::ReadRequest { start, count } => (Some(start), Some(count), None),
        Pdu::ReadResponse { values } => (None, u16::try_from(values.len()).ok(), values.get(0)),
        Pdu::WriteSingle { register, value } => (Some(register), None, Some(value)),
        Pdu::WriteMultipleRequest { start, values } => {
            (Some(start), u16::try_from(values.len()).ok(), values.get(0))
        }
        Pdu::WriteMultipleResponse { start, count } => (Some(start), Some(count), None),
        _ => (None, None, None),
    };
    let differs = |want: Option<u32>, got: Option<u16>| match (want, got) {
        (Some(w), Some(g)) => w != u32::from(g),
        _ => false,
    };
    if differs(expect_num(&fv.expect, |e| &e.register), reg)
        || differs(expect_num(&fv.expect, |e| &e.count), count)
        || differs(expect_num(&fv.expect, |e| &e.value), value)
    {
        observed.insert("register-mismatch");
    }
    if key.kind == Some(FrameKind::Response) {
        if let Some(rb) = &request_body {
            if let Ok(req) = Message::parse_body(rb, Direction::Request) {
                let answers = match (req.pdu, msg.pdu) {
                    (Pdu::ReadRequest { count, .. }, Pdu::ReadResponse { values }) => {
                        values.len() == usize::from(count)
                    }
                    (
                        Pdu::WriteMultipleRequest { start, values },
                        Pdu::WriteMultipleResponse { start: s, count },
                    ) => start == s && values.len() == usize::from(count),
                    (a @ (Pdu::WriteSingle { .. } | Pdu::LoopBack { .. }), b) => a == b,
                    _ => true,
                };
                if !answers {
                    observed.insert("register-mismatch");
                }
            }
        }
    }
}

fn check_frame(set: &VectorSet, v: &Vector, fv: &FrameVector, rep: &mut VectorReport) {
    let mode: Mode = fv.mode.into();
    let direction: Direction = fv.direction.into();
    let Some(key) = FrameKey::parse(&v.id) else {
        rep.problems.push("id is not a frame id".into());
        return;
    };
    let printed = match parse_printed(&fv.printed) {
        Ok(p) => p,
        Err(e) => {
            rep.problems.push(format!("printed: {e}"));
            return;
        }
    };
    let declared: BTreeSet<&str> = v.flags.iter().map(String::as_str).collect();
    let mut observed: BTreeSet<&'static str> = BTreeSet::new();

    if let (Mode::Ascii, Some(text)) = (mode, &fv.text) {
        let from_text: Vec<Option<u8>> = text
            .bytes()
            .map(|c| if c == b'?' { None } else { Some(c) })
            .collect();
        if from_text != printed {
            rep.problems.push(format!(
                "text {text:?} is not the characters of printed ({})",
                fv.printed
            ));
        }
    } else if mode == Mode::Ascii {
        rep.problems.push("ASCII frame vector without text".into());
    }
    if declared.contains("ocr-repair") != fv.ocr_raw.is_some() {
        rep.problems
            .push("flag ocr-repair and field ocr_raw go together".into());
    }

    let known: Option<Vec<u8>> = printed.iter().copied().collect();
    match &known {
        Some(bytes) => match frame_parts(mode, bytes) {
            Ok(parts) => {
                if !parts.checksum.is_valid() {
                    observed.insert(match mode {
                        Mode::Rtu => "crc-mismatch",
                        Mode::Ascii => "lrc-mismatch",
                    });
                }
                observe_body(set, &key, fv, &parts.body, &mut observed, &mut rep.problems);
            }
            Err(
                e @ (FrameError::AsciiNoStart { .. }
                | FrameError::AsciiNoEnd { .. }
                | FrameError::AsciiBadChar { .. }
                | FrameError::AsciiOddLength { .. }),
            ) => {
                observed.insert("framing-error");
                match effective_body(fv) {
                    Some(body) => {
                        observe_body(set, &key, fv, &body, &mut observed, &mut rep.problems)
                    }
                    None => rep.problems.push(format!(
                        "printed is not a frame ({e}) and has no readable body"
                    )),
                }
            }
            Err(e) => rep.problems.push(format!("printed is not a frame: {e}")),
        },
        None => {
            if v.verdict != Verdict::Incomplete {
                rep.problems
                    .push("printed has blank (??) bytes but the verdict is not incomplete".into());
            }
            let blank_in_checksum = match mode {
                Mode::Rtu => printed.iter().rev().take(2).any(Option::is_none),
                Mode::Ascii => printed.iter().rev().skip(2).take(2).any(Option::is_none),
            };
            if blank_in_checksum {
                observed.insert("checksum-placeholder");
            }
            if let Some(body) = effective_body(fv) {
                observe_body(set, &key, fv, &body, &mut observed, &mut rep.problems);
            }
        }
    }
    // A blank checksum is either printed as '?' or made illegible by the OCR.
    let blank_declared =
        declared.contains("checksum-placeholder") || declared.contains("ocr-illegible");
    if declared.contains("checksum-placeholder") && !observed.contains("checksum-placeholder") {
        rep.problems
            .push("flag checksum-placeholder, but the checksum bytes are all printed".into());
    } else if observed.contains("checksum-placeholder") && !blank_declared {
        rep.problems.push(
            "the checksum is blank but neither checksum-placeholder nor ocr-illegible is declared"
                .into(),
        );
    }
    if declared.contains("ocr-illegible") && known.is_some() {
        rep.problems
            .push("flag ocr-illegible, but no byte is blank".into());
    }

    // Compare observed with declared. A twin disagreement is one fact about two vectors:
    // it must be declared on at least one of them.
    for flag in OBSERVABLE {
        let d = declared.contains(flag);
        let o = observed.contains(flag);
        if d && !o {
            rep.problems.push(format!(
                "declares {flag}, but the codec does not observe it"
            ));
        } else if o && !d {
            let twin_declares = flag == "ascii-rtu-mismatch"
                && set
                    .get(&key.twin().id())
                    .is_some_and(|t| t.flags.iter().any(|f| f == flag));
            if !twin_declares {
                rep.problems
                    .push(format!("the codec observes {flag}, but it is not declared"));
            }
        }
    }
    rep.observed = observed.iter().map(|s| s.to_string()).collect();

    let has_fault = observed.iter().any(|f| *f != "ascii-rtu-mismatch")
        || declared.iter().any(|f| OBSERVABLE.contains(f));
    match v.verdict {
        Verdict::Consistent => {
            if has_fault {
                rep.problems
                    .push("verdict consistent, but the vector has faults".into());
            }
            if fv.corrected.is_some() {
                rep.problems
                    .push("a consistent vector has no corrected frame".into());
            }
            if let Some(bytes) = &known {
                let mut scratch = [0u8; crate::codec::MAX_RTU_FRAME];
                match crate::codec::decode(mode, bytes, direction, &mut scratch) {
                    Ok(m) => match m.to_frame_vec(mode) {
                        Ok(re) if &re == bytes => {}
                        Ok(re) => rep
                            .problems
                            .push(format!("re-encodes as {}, not as printed", Hex(&re))),
                        Err(e) => rep.problems.push(format!("does not re-encode: {e}")),
                    },
                    Err(e) => rep.problems.push(format!("checked decode fails: {e}")),
                }
            }
        }
        Verdict::Erratum => {
            if !has_fault && !observed.contains("ascii-rtu-mismatch") {
                rep.problems
                    .push("verdict erratum, but no fault is declared or observed".into());
            }
            if known.is_none() {
                rep.problems
                    .push("verdict erratum, but bytes are blank: use incomplete".into());
            }
        }
        Verdict::Incomplete => {
            if known.is_some() {
                rep.problems
                    .push("verdict incomplete, but every byte is printed".into());
            }
        }
    }

    // The corrected frame: decodes cleanly and is exactly what the codec emits.
    if v.verdict != Verdict::Consistent {
        let Some(corrected) = &fv.corrected else {
            rep.problems
                .push(format!("verdict {} needs a corrected frame", v.verdict));
            return;
        };
        let corrected = match parse_known(corrected) {
            Ok(c) => c,
            Err(e) => {
                rep.problems.push(format!("corrected: {e}"));
                return;
            }
        };
        let mut scratch = [0u8; crate::codec::MAX_RTU_FRAME];
        match crate::codec::decode(mode, &corrected, direction, &mut scratch) {
            Ok(m) => match m.to_frame_vec(mode) {
                Ok(re) if re == corrected => {}
                Ok(re) => rep.problems.push(format!(
                    "corrected re-encodes as {}, not as recorded",
                    Hex(&re)
                )),
                Err(e) => rep
                    .problems
                    .push(format!("corrected does not re-encode: {e}")),
            },
            Err(e) => rep
                .problems
                .push(format!("corrected does not decode cleanly: {e}")),
        }
        if corrected.len() == printed.len() {
            let only_checksum = declared.iter().all(|f| {
                [
                    "crc-mismatch",
                    "lrc-mismatch",
                    "checksum-placeholder",
                    "ocr-repair",
                ]
                .contains(f)
            });
            let checksum_at = match mode {
                Mode::Rtu => printed.len().saturating_sub(2)..printed.len(),
                Mode::Ascii => printed.len().saturating_sub(4)..printed.len().saturating_sub(2),
            };
            for (i, (p, c)) in printed.iter().zip(&corrected).enumerate() {
                let may_differ = !only_checksum || checksum_at.contains(&i);
                if let Some(p) = p {
                    if p != c && (!may_differ || v.verdict == Verdict::Incomplete && only_checksum)
                    {
                        rep.problems.push(format!(
                            "corrected byte {i} is {c:02X}, printed {p:02X}: only the flagged fields may change"
                        ));
                        break;
                    }
                }
            }
        } else if declared
            .iter()
            .all(|f| ["crc-mismatch", "lrc-mismatch", "checksum-placeholder"].contains(f))
        {
            rep.problems.push(format!(
                "corrected has {} bytes, printed {}: a checksum fix keeps the length",
                corrected.len(),
                printed.len()
            ));
        }
    }
}

/// Largest `n` registers (at most 125) whose frame (as `frame_len(n)`) fits in `max`.
fn max_registers(max: u32, frame_len: impl Fn(u16) -> usize) -> u32 {
    (0u16..=125)
        .take_while(|&n| frame_len(n) <= max as usize)
        .last()
        .map_or(0, u32::from)
}

/// The registers per read and per write, in each mode, that fit a frame of `max_frame`
/// bytes (characters in ASCII): the read response and the write request are the longest
/// frames of 03H and 10H.
pub fn derived_register_limits(max_frame: u32) -> (PerMode, PerMode) {
    let per_mode = |len: fn(Mode, u16) -> usize| PerMode {
        ascii: max_registers(max_frame, |n| len(Mode::Ascii, n)),
        rtu: max_registers(max_frame, |n| len(Mode::Rtu, n)),
    };
    (
        per_mode(crate::codec::read_response_len),
        per_mode(crate::codec::write_request_len),
    )
}

fn check_other(v: &Vector, rep: &mut VectorReport) {
    let declared: BTreeSet<&str> = v.flags.iter().map(String::as_str).collect();
    let mut observed: BTreeSet<&'static str> = BTreeSet::new();
    match &v.body {
        Body::Frame(_) | Body::CListing(_) | Body::ExceptionRule(_) => {}
        Body::LrcExample(e) => {
            let input = match parse_known(&e.input) {
                Ok(i) => i,
                Err(err) => return rep.problems.push(format!("input: {err}")),
            };
            let computed = lrc(&input);
            match parse_hex_number(&e.printed_lrc) {
                Ok(p) if p == u32::from(computed) => {}
                Ok(_) => {
                    observed.insert("lrc-mismatch");
                }
                Err(err) => rep.problems.push(format!("printed_lrc: {err}")),
            }
            if let Some(sum) = &e.printed_sum {
                let s = input.iter().fold(0u8, |a, &b| a.wrapping_add(b));
                if parse_hex_number(sum).ok() != Some(u32::from(s)) {
                    rep.problems
                        .push(format!("printed_sum {sum} is not the sum {s:02X}"));
                }
            }
            match parse_known(&e.printed_chars) {
                Ok(c) if c == lrc_chars(computed) => {}
                Ok(c) => rep.problems.push(format!(
                    "printed_chars {} are not the characters of LRC {computed:02X} ({})",
                    Hex(&c),
                    Hex(&lrc_chars(computed))
                )),
                Err(err) => rep.problems.push(format!("printed_chars: {err}")),
            }
        }
        Body::CrcByteOrder(c) => {
            if let (Some(value), Some(sent)) = (&c.crc_value, &c.sent) {
                match (parse_hex_number(value), parse_known(sent)) {
                    (Ok(val), Ok(sent)) => {
                        let wire = CrcBytes { value: val as u16 }.wire();
                        if sent != wire {
                            rep.problems.push(format!(
                                "sentence sends {}, but CRC {val:04X} goes on the wire as {} (low byte first)",
                                Hex(&sent),
                                Hex(&wire)
                            ));
                        }
                    }
                    (a, b) => rep
                        .problems
                        .push(format!("crc_value/sent unreadable: {a:?} {b:?}")),
                }
            } else if v.verdict != Verdict::Incomplete {
                rep.problems
                    .push("no crc_value/sent but verdict is not incomplete".into());
            }
        }
        Body::ExceptionCodes(t) => {
            let mut seen = BTreeSet::new();
            for c in &t.codes {
                match parse_hex_number(&c.code) {
                    Ok(n) if n <= 0xFF => {
                        if !seen.insert(n) {
                            rep.problems.push(format!("code {} appears twice", c.code));
                        }
                    }
                    _ => rep
                        .problems
                        .push(format!("code {:?} is not a hex byte", c.code)),
                }
            }
            if t.codes.is_empty() && v.verdict != Verdict::Incomplete {
                rep.problems
                    .push("empty table but verdict is not incomplete".into());
            }
        }
        Body::NodeAddress(n) => {
            match (
                parse_hex_number(&n.broadcast),
                parse_hex_number(&n.first),
                parse_hex_number(&n.last),
            ) {
                (Ok(b), Ok(f), Ok(l)) => {
                    if b != 0 {
                        rep.problems
                            .push(format!("broadcast address {b:02X} is not 00"));
                    }
                    if !(1..=l).contains(&f) || l > 0xFF {
                        rep.problems.push(format!(
                            "address range {f:02X}..{l:02X} is not within 01..FF"
                        ));
                    }
                }
                _ => rep.problems.push("addresses are not hex".into()),
            }
        }
        Body::Limits(l) => {
            if let Some(max) = l.max_frame_bytes {
                let (read, write) = derived_register_limits(max);
                let stated = [
                    ("read", l.max_read_registers, read),
                    ("write", l.max_write_registers, write),
                ];
                for (what, stated, derived) in stated {
                    let Some(s) = stated.filter(|s| *s != derived) else {
                        continue;
                    };
                    observed.insert("limit-not-derived");
                    if !declared.contains("limit-not-derived") {
                        rep.problems.push(format!(
                            "stated {what} limit ascii {} / rtu {} differs from what a {max}-byte frame allows (ascii {} / rtu {})",
                            s.ascii, s.rtu, derived.ascii, derived.rtu
                        ));
                    }
                }
            }
        }
    }
    for flag in &declared {
        if (OBSERVABLE.contains(flag) || *flag == "limit-not-derived") && !observed.contains(flag) {
            rep.problems.push(format!(
                "declares {flag}, but the codec does not observe it"
            ));
        }
    }
    for flag in &observed {
        if !declared.contains(flag) && *flag != "limit-not-derived" {
            rep.problems
                .push(format!("the codec observes {flag}, but it is not declared"));
        }
    }
    if declared.contains("ocr-repair") != v.notes.contains("OCR") {
        rep.problems
            .push("flag ocr-repair and an \"OCR: ...\" note go together".into());
    }
    if v.verdict == Verdict::Consistent && declared.iter().any(|f| *f != "ocr-repair") {
        rep.problems
            .push("verdict consistent, but flags are declared".into());
    }
    if v.verdict == Verdict::Erratum
        && observed.is_empty()
        && declared.iter().all(|f| OBSERVABLE.contains(f))
    {
        rep.problems
            .push("verdict erratum, but the codec observes no fault".into());
    }
    rep.observed = observed.iter().map(|s| s.to_string()).collect();
}

/// Checks one vector.
pub fn verify_vector(set: &VectorSet, v: &Vector) -> VectorReport {
    let mut rep = VectorReport {
        id: v.id.clone(),
        verdict: v.verdict,
        flags: v.flags.clone(),
        observed: vec![],
        problems: vec![],
    };
    if v.verdict != Verdict::Consistent && v.notes.trim().is_empty() {
        rep.problems
            .push(format!("verdict {} needs notes", v.verdict));
    }
    match &v.body {
        Body::Frame(fv) => check_frame(set, v, fv, &mut rep),
        Body::CListing(l) => super::listing::check_listing(v, l, &mut rep),
        Body::ExceptionRule(r) => super::listing::check_exception_rule(set, v, r, &mut rep),
        _ => check_other(v, &mut rep),
    }
    rep
}

/// Checks every vector.
pub fn verify_all(set: &VectorSet) -> Vec<VectorReport> {
    set.iter().map(|(_, v)| verify_vector(set, v)).collect()
}

/// The ids every document must have.
pub fn required_ids(document: &str) -> Vec<String> {
    let mut ids = Vec::new();
    for fc in ["03", "06", "08", "10"] {
        for mode in ["ascii", "rtu"] {
            for kind in ["request", "response", "exception"] {
                ids.push(format!("{document}.{fc}.{mode}.{kind}"));
            }
        }
    }
    for tail in [
        "exception-example.ascii",
        "exception-example.rtu",
        "lrc-example",
        "crc-byte-order",
        "exception-codes",
        "node-address",
        "limits",
        "crc-listing",
        "exception-rule",
    ] {
        ids.push(format!("{document}.{tail}"));
    }
    ids
}

/// Ids missing from the set, and documents with no file.
pub fn missing(set: &VectorSet) -> Vec<String> {
    let mut out = Vec::new();
    for d in DOCUMENTS {
        if set.file(d).is_none() {
            out.push(format!("{d}: no vector file"));
            continue;
        }
        for id in required_ids(d) {
            if set.get(&id).is_none() {
                out.push(id);
            }
        }
    }
    out
}

/// A human-readable rendering of one vector: what it is and what the codec makes of it.
pub fn render(v: &Vector) -> String {
    render_inner(None, v)
}

/// [`render`], with what the vector's evidence frames in `set` show (exception rules).
pub fn render_in(set: &VectorSet, v: &Vector) -> String {
    render_inner(Some(set), v)
}

fn render_inner(set: Option<&VectorSet>, v: &Vector) -> String {
    let mut s = String::new();
    let flags = if v.flags.is_empty() {
        String::new()
    } else {
        format!(" [{}]", v.flags.join(", "))
    };
    let _ = writeln!(s, "{} ({}{flags})", v.id, v.verdict);
    match &v.body {
        Body::Frame(fv) => {
            let mode: Mode = fv.mode.into();
            let _ = writeln!(s, "  printed   {}", fv.printed);
            if let Some(t) = &fv.text {
                let _ = writeln!(s, "  text      {t:?}");
            }
            let show = |label: &str, bytes: &[u8], s: &mut String| match frame_parts(mode, bytes) {
                Ok(parts) => {
                    match Message::parse_body(&parts.body, fv.direction.into()) {
                        Ok(m) => {
                            let _ = writeln!(s, "  {label:<9} {m}");
                        }
                        Err(e) => {
                            let _ = writeln!(
                                s,
                                "  {label:<9} body {} does not parse: {e}",
                                Hex(&parts.body)
                            );
                        }
                    }
                    let _ = writeln!(s, "  checksum  {}", parts.checksum);
                }
                Err(e) => {
                    let _ = writeln!(s, "  {label:<9} not a frame: {e}");
                }
            };
            match parse_known(&fv.printed) {
                Ok(bytes) => show("decoded", &bytes, &mut s),
                Err(_) => {
                    let _ = writeln!(s, "  decoded   (blank bytes)");
                }
            }
            if let Some(c) = &fv.corrected {
                let _ = writeln!(s, "  corrected {c}");
                if let Ok(bytes) = parse_known(c) {
                    show("as", &bytes, &mut s);
                }
            }
        }
        Body::LrcExample(e) => {
            let _ = writeln!(
                s,
                "  LRC of {} printed {} as {}",
                e.input, e.printed_lrc, e.printed_chars
            );
            if let Ok(i) = parse_known(&e.input) {
                let _ = writeln!(s, "  computed {:02X}", lrc(&i));
            }
        }
        Body::CrcByteOrder(c) => {
            let _ = writeln!(
                s,
                "  CRC {} sent as {} (first byte called {:?})",
                c.crc_value.as_deref().unwrap_or("?"),
                c.sent.as_deref().unwrap_or("?"),
                c.first_byte_label.as_deref().unwrap_or("?")
            );
        }
        Body::ExceptionCodes(t) => {
            for c in &t.codes {
                let _ = writeln!(s, "  {} {}", c.code, c.meaning);
            }
        }
        Body::NodeAddress(n) => {
            let _ = writeln!(
                s,
                "  broadcast {}, nodes {}..{}",
                n.broadcast, n.first, n.last
            );
        }
        Body::Limits(l) => {
            let _ = writeln!(
                s,
                "  max frame {:?} bytes, response time {:?} ms, read {:?}, write {:?}",
                l.max_frame_bytes, l.response_time_ms, l.max_read_registers, l.max_write_registers
            );
            if let Some(max) = l.max_frame_bytes {
                let (r, w) = derived_register_limits(max);
                let _ = writeln!(
                    s,
                    "  derived from {max} bytes: read ascii {} / rtu {}, write ascii {} / rtu {}",
                    r.ascii, r.rtu, w.ascii, w.rtu
                );
            }
            if let Some(rule) = &l.same_group_rule {
                let _ = writeln!(s, "  same group: {rule}");
            }
        }
        Body::CListing(l) => super::listing::render_listing(l, &mut s),
        Body::ExceptionRule(r) => super::listing::render_rule(set, v, r, &mut s),
    }
    if !v.notes.is_empty() {
        let _ = writeln!(s, "  notes     {}", v.notes);
    }
    s
}
