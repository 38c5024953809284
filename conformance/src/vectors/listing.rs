//! Checks of the vectors that are prose and program text rather than frames: the CRC
//! program the manuals print in C (`c-listing`) and the sentence that says how an error
//! reply's function code is formed (`exception-rule`).
//!
//! A listing is kept exactly as printed; `vectors verify` checks that its `corrected`
//! text is the printed text with the recorded repairs applied and nothing else changed.
//! Whether the printed text really fails to compile, and the corrected one really computes
//! CRC-16/MODBUS, needs a C compiler: `conformance/tests/c_listing.rs` checks that.

use std::collections::BTreeSet;
use std::fmt::Write as _;

use super::model::{
    parse_hex_number, Body, CListing, ExceptionRule, FrameKey, FrameKind, TextRepair, Vector,
    Verdict,
};
use super::outcome::{effective_body, VectorReport};
use super::set::VectorSet;

/// Flag of a listing that needs `repairs` before it compiles.
pub const CODE_DOES_NOT_COMPILE: &str = "code-does-not-compile";
/// Flag of a rule sentence that the document's own example frames contradict.
pub const PROSE_CONTRADICTS_EXAMPLES: &str = "prose-contradicts-examples";

/// The longest text repairs may produce: far more than any printed program, and a bound on
/// what a vector file (or a fuzzer) can make the repairs allocate.
pub const MAX_LISTING_BYTES: usize = 1 << 20;

/// Why recorded repairs cannot be applied to a listing.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum RepairError {
    /// A repair with nothing to find.
    #[error("repair {index}: `find` is empty")]
    EmptyFind {
        /// Position of the repair in its list.
        index: usize,
    },
    /// A repair that changes nothing.
    #[error("repair {index}: `find` and `replace` are both {find:?}")]
    NoChange {
        /// Position of the repair in its list.
        index: usize,
        /// The text.
        find: String,
    },
    /// The repaired text would be longer than any printed program.
    #[error("repair {index}: the text would grow past {limit} bytes")]
    TooLong {
        /// Position of the repair in its list.
        index: usize,
        /// The limit.
        limit: usize,
    },
    /// The text to repair occurs a different number of times than recorded.
    #[error("repair {index}: {find:?} occurs {found} times, the repair says {expected}")]
    Count {
        /// Position of the repair in its list.
        index: usize,
        /// The text to find.
        find: String,
        /// The recorded count.
        expected: u32,
        /// The count in the text.
        found: usize,
    },
}

/// `text` with every repair applied in order; each repair's `find` must occur exactly
/// `count` times in the text as it stands when the repair is applied.
pub fn apply_repairs(text: &str, repairs: &[TextRepair]) -> Result<String, RepairError> {
    let mut out = text.to_string();
    for (index, r) in repairs.iter().enumerate() {
        if r.find.is_empty() {
            return Err(RepairError::EmptyFind { index });
        }
        if r.find == r.replace {
            return Err(RepairError::NoChange {
                index,
                find: r.find.clone(),
            });
        }
        let found = out.matches(r.find.as_str()).count();
        if u32::try_from(found).ok() != Some(r.count) {
            return Err(RepairError::Count {
                index,
                find: r.find.clone(),
                expected: r.count,
                found,
            });
        }
        let grown = found
            .checked_mul(r.replace.len())
            .and_then(|added| out.len().checked_add(added));
        if grown.is_none_or(|n| n > MAX_LISTING_BYTES) {
            return Err(RepairError::TooLong {
                index,
                limit: MAX_LISTING_BYTES,
            });
        }
        out = out.replace(r.find.as_str(), &r.replace);
    }
    Ok(out)
}

impl CListing {
    /// The listing as the page prints it: the printed text with the OCR repairs applied
    /// (the printed text itself for a clean source).
    pub fn as_printed_on_page(&self) -> Result<String, RepairError> {
        apply_repairs(&self.printed, &self.ocr_repairs)
    }

    /// The corrected listing, rebuilt from the printed text and every recorded repair.
    pub fn rebuilt(&self) -> Result<String, RepairError> {
        apply_repairs(&self.as_printed_on_page()?, &self.repairs)
    }

    /// `typedef` lines for the types the listing uses without defining them.
    pub fn typedefs(&self) -> String {
        self.types
            .iter()
            .map(|(name, ty)| format!("typedef {ty} {name};\n"))
            .collect()
    }
}

/// Whether `word` occurs in `text` as a whole C identifier.
fn has_identifier(text: &str, word: &str) -> bool {
    let is_ident = |c: char| c.is_ascii_alphanumeric() || c == '_';
    text.match_indices(word).any(|(at, _)| {
        let before = text[..at].chars().next_back();
        let after = text[at + word.len()..].chars().next();
        !before.is_some_and(is_ident) && !after.is_some_and(is_ident)
    })
}

/// The C types a listing's `types` may name.
const C_TYPES: [&str; 8] = [
    "char",
    "signed char",
    "unsigned char",
    "short",
    "unsigned short",
    "int",
    "unsigned int",
    "unsigned long",
];

/// Declared against observed, for the flags this module observes; any other flag but
/// `ocr-repair` does not apply to these vectors.
fn compare_flags(
    v: &Vector,
    observed: &BTreeSet<&'static str>,
    ours: &[&str],
    rep: &mut VectorReport,
) {
    for flag in &v.flags {
        let flag = flag.as_str();
        if ours.contains(&flag) {
            if !observed.contains(flag) {
                rep.problems.push(format!(
                    "declares {flag}, but the check does not observe it"
                ));
            }
        } else if flag != "ocr-repair" {
            rep.problems.push(format!(
                "flag {flag} does not apply to a {} vector",
                v.body.type_name()
            ));
        }
    }
    for flag in observed {
        if !v.flags.iter().any(|f| f == flag) {
            rep.problems
                .push(format!("the check observes {flag}, but it is not declared"));
        }
    }
    let faults = observed.iter().any(|f| ours.contains(f));
    match v.verdict {
        Verdict::Erratum if !faults => rep
            .problems
            .push("verdict erratum, but the check observes no fault".into()),
        Verdict::Consistent if faults => rep
            .problems
            .push("verdict consistent, but the vector has faults".into()),
        Verdict::Incomplete => rep.problems.push(format!(
            "a {} vector is never incomplete",
            v.body.type_name()
        )),
        _ => {}
    }
}

/// Checks a `c-listing` vector: the repairs rebuild `corrected` exactly from `printed`,
/// the OCR repairs and the `ocr-repair` flag go together, and every assumed type occurs.
pub fn check_listing(v: &Vector, l: &CListing, rep: &mut VectorReport) {
    let mut observed: BTreeSet<&'static str> = BTreeSet::new();
    if l.printed.trim().is_empty() {
        rep.problems.push("printed is empty".into());
    }
    let ocr_declared = v.flags.iter().any(|f| f == "ocr-repair");
    let has_ocr_repairs = !l.ocr_repairs.is_empty();
    if ocr_declared != has_ocr_repairs {
        rep.problems
            .push("flag ocr-repair and field ocr_repairs go together".into());
    }
    if ocr_declared != v.notes.contains("OCR") {
        rep.problems
            .push("flag ocr-repair and an \"OCR: ...\" note go together".into());
    }
    if !l.repairs.is_empty() {
        observed.insert(CODE_DOES_NOT_COMPILE);
    }
    for r in l.ocr_repairs.iter().chain(&l.repairs) {
        if r.why.trim().is_empty() {
            rep.problems.push(format!(
                "repair {:?} -> {:?} gives no reason",
                r.find, r.replace
            ));
        }
    }
    match l.as_printed_on_page() {
        Err(e) => rep.problems.push(format!("ocr_repairs: {e}")),
        Ok(page) => match apply_repairs(&page, &l.repairs) {
            Err(e) => rep.problems.push(format!("repairs: {e}")),
            Ok(rebuilt) if rebuilt == l.corrected => {}
            Ok(rebuilt) => {
                let at = rebuilt
                    .lines()
                    .zip(l.corrected.lines())
                    .position(|(a, b)| a != b)
                    .unwrap_or_else(|| rebuilt.lines().count().min(l.corrected.lines().count()));
                rep.problems.push(format!(
                    "corrected is not the printed text with the recorded repairs applied (first difference at line {}: {:?})",
                    at + 1,
                    l.corrected.lines().nth(at).unwrap_or("")
                ));
            }
        },
    }
    let page = l.as_printed_on_page().unwrap_or_else(|_| l.printed.clone());
    for (name, ty) in &l.types {
        if !has_identifier(&page, name) {
            rep.problems
                .push(format!("type {name} does not occur in the listing"));
        }
        if !C_TYPES.contains(&ty.as_str()) {
            rep.problems
                .push(format!("type {name}: {ty:?} is not one of {C_TYPES:?}"));
        }
    }
    compare_flags(v, &observed, &[CODE_DOES_NOT_COMPILE], rep);
    rep.observed = observed.iter().map(|s| s.to_string()).collect();
}

/// What one evidence frame shows: the request's function (from the example's section),
/// the function byte the frame carries, and what each reading of the rule gives.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct RuleEvidence {
    /// The request's function code.
    pub request_function: u8,
    /// The error reply's function byte as printed.
    pub printed: u8,
    /// The stated operation applied to the request's function.
    pub stated: u8,
    /// The examples' operation applied to the request's function.
    pub examples: u8,
}

/// What the evidence frame `id` shows under `rule`, or why it is not evidence.
pub fn rule_evidence(
    set: &VectorSet,
    document: &str,
    rule: &ExceptionRule,
    id: &str,
) -> Result<RuleEvidence, String> {
    let operand = parse_hex_number(&rule.operand)
        .ok()
        .and_then(|n| u8::try_from(n).ok())
        .ok_or_else(|| format!("operand {:?} is not a hex byte", rule.operand))?;
    let key = FrameKey::parse(id)
        .filter(|k| k.document == document && k.kind == Some(FrameKind::Exception))
        .ok_or_else(|| {
            format!("{id} is not an example exception frame <{document}>.<fc>.<mode>.exception")
        })?;
    let request_function = key
        .function
        .ok_or_else(|| format!("{id}: the example names no function"))?;
    let fv = match set.get(id).map(|v| &v.body) {
        Some(Body::Frame(fv)) => fv,
        Some(_) => return Err(format!("{id} is not a frame vector")),
        None => return Err(format!("{id} does not exist")),
    };
    let printed = effective_body(fv)
        .and_then(|b| b.get(1).copied())
        .ok_or_else(|| format!("{id}: the function byte cannot be read"))?;
    Ok(RuleEvidence {
        request_function,
        printed,
        stated: rule.stated_operation.apply(request_function, operand),
        examples: rule.examples_operation.apply(request_function, operand),
    })
}

/// Checks an `exception-rule` vector: every evidence frame exists and carries the
/// function byte the examples' operation gives; every such frame of the document is
/// listed; the flag `prose-contradicts-examples` holds exactly when the stated operation
/// gives something else for every one of them.
pub fn check_exception_rule(
    set: &VectorSet,
    v: &Vector,
    r: &ExceptionRule,
    rep: &mut VectorReport,
) {
    let mut observed: BTreeSet<&'static str> = BTreeSet::new();
    let document = v.id.split_once('.').map_or("", |(d, _)| d);
    let quote = r.quote.to_ascii_uppercase();
    if !quote.contains(&r.stated_operation.to_string()) {
        rep.problems.push(format!(
            "the quote does not name the stated operation {}",
            r.stated_operation
        ));
    }
    if !quote.contains(r.operand.trim_end_matches(['H', 'h'])) {
        rep.problems.push(format!(
            "the quote does not contain the operand {}",
            r.operand
        ));
    }
    if r.evidence.is_empty() {
        rep.problems.push("no evidence frames".into());
    }
    let mut seen = BTreeSet::new();
    let (mut contradicted, mut agreed) = (0usize, 0usize);
    for id in &r.evidence {
        if !seen.insert(id.as_str()) {
            rep.problems.push(format!("evidence {id} is listed twice"));
            continue;
        }
        match rule_evidence(set, document, r, id) {
            Err(e) => rep.problems.push(format!("evidence: {e}")),
            Ok(ev) => {
                if ev.printed != ev.examples {
                    rep.problems.push(format!(
                        "evidence {id}: function {:02X}H, but {:02X}H {} {} is {:02X}H",
                        ev.printed,
                        ev.request_function,
                        r.examples_operation,
                        r.operand,
                        ev.examples
                    ));
                } else if ev.stated == ev.printed {
                    agreed += 1;
                } else {
                    contradicted += 1;
                }
            }
        }
    }
    // Every example exception frame of the document whose function byte is not flagged as
    // wrong is evidence; none is left out.
    if let Some(file) = set.file(document) {
        for other in &file.vectors {
            let is_exception =
                FrameKey::parse(&other.id).is_some_and(|k| k.kind == Some(FrameKind::Exception));
            if is_exception
                && !other.flags.iter().any(|f| f == "function-mismatch")
                && !seen.contains(other.id.as_str())
            {
                rep.problems.push(format!(
                    "{} is an example exception frame of the document but not in evidence",
                    other.id
                ));
            }
        }
    }
    if contradicted > 0 && agreed > 0 {
        rep.problems.push(format!(
            "the stated {} agrees with {agreed} evidence frames and not with {contradicted}",
            r.stated_operation
        ));
    } else if contradicted > 0 {
        observed.insert(PROSE_CONTRADICTS_EXAMPLES);
    }
    compare_flags(v, &observed, &[PROSE_CONTRADICTS_EXAMPLES], rep);
    rep.observed = observed.iter().map(|s| s.to_string()).collect();
}

/// The rendering of a `c-listing` vector.
pub fn render_listing(l: &CListing, s: &mut String) {
    let types: Vec<String> = l.types.iter().map(|(n, t)| format!("{n}={t}")).collect();
    let _ = writeln!(
        s,
        "  listing   {} lines printed; assumes {}",
        l.printed.lines().count(),
        types.join(", ")
    );
    for (label, r) in l
        .ocr_repairs
        .iter()
        .map(|r| ("ocr", r))
        .chain(l.repairs.iter().map(|r| ("repair", r)))
    {
        let _ = writeln!(
            s,
            "  {label:<9} {:?} -> {:?} ({}x): {}",
            r.find, r.replace, r.count, r.why
        );
    }
    match l.rebuilt() {
        Ok(c) if c == l.corrected => {
            let _ = writeln!(s, "  corrected the printed text with these repairs");
        }
        Ok(_) => {
            let _ = writeln!(
                s,
                "  corrected differs from the printed text with these repairs"
            );
        }
        Err(e) => {
            let _ = writeln!(s, "  corrected repairs do not apply: {e}");
        }
    }
}

/// The rendering of an `exception-rule` vector (needs the set for the evidence frames).
pub fn render_rule(set: Option<&VectorSet>, v: &Vector, r: &ExceptionRule, s: &mut String) {
    let _ = writeln!(s, "  quote     {}", r.quote);
    let operand = format!("{}H", r.operand.trim_end_matches(['H', 'h']));
    let _ = writeln!(
        s,
        "  stated    f {} {operand}; examples f {} {operand}",
        r.stated_operation, r.examples_operation
    );
    let document = v.id.split_once('.').map_or("", |(d, _)| d);
    for id in &r.evidence {
        let line = match set.map(|set| rule_evidence(set, document, r, id)) {
            Some(Ok(ev)) => format!(
                "printed {:02X}H; {:02X}H {} {operand} = {:02X}H, {:02X}H {} {operand} = {:02X}H",
                ev.printed,
                ev.request_function,
                r.examples_operation,
                ev.examples,
                ev.request_function,
                r.stated_operation,
                ev.stated
            ),
            Some(Err(e)) => e,
            None => String::new(),
        };
        let _ = writeln!(s, "  evidence  {id} {line}");
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vectors::model::BitOperation;

    fn repair(find: &str, replace: &str, count: u32) -> TextRepair {
        TextRepair {
            find: find.into(),
            replace: replace.into(),
            count,
            why: "test".into(),
        }
    }

    #[test]
    fn repairs_apply_in_order_with_their_counts() {
        let text = "while ( long-- ) { wkg ^= rxdbuff++; } long";
        let out = apply_repairs(
            text,
            &[
                repair("long", "len", 2),
                repair("rxdbuff++", "*rxdbuff++", 1),
            ],
        )
        .unwrap();
        assert_eq!(out, "while ( len-- ) { wkg ^= *rxdbuff++; } len");
        assert_eq!(
            apply_repairs(text, &[repair("long", "len", 1)]),
            Err(RepairError::Count {
                index: 0,
                find: "long".into(),
                expected: 1,
                found: 2
            })
        );
        assert!(matches!(
            apply_repairs(text, &[repair("", "x", 1)]),
            Err(RepairError::EmptyFind { index: 0 })
        ));
        assert!(matches!(
            apply_repairs(text, &[repair("long", "long", 2)]),
            Err(RepairError::NoChange { .. })
        ));
        // Repairs cannot blow a text up without bound.
        let tenfold = repair("a", "aaaaaaaaaa", 1);
        let mut grow = vec![tenfold];
        for i in 1..8u32 {
            grow.push(repair("a", "aaaaaaaaaa", 10u32.pow(i)));
        }
        assert!(matches!(
            apply_repairs("a", &grow),
            Err(RepairError::TooLong { .. })
        ));
    }

    #[test]
    fn identifiers_are_whole_words() {
        assert!(has_identifier("UBYTE *p", "UBYTE"));
        assert!(!has_identifier("UBYTEi=0;", "UBYTE"));
        assert!(!has_identifier("BYTEi=0;", "BYTE"));
        assert!(has_identifier("(BYTE)", "BYTE"));
    }

    #[test]
    fn bit_operations() {
        assert_eq!(BitOperation::Or.apply(0x03, 0x80), 0x83);
        assert_eq!(BitOperation::And.apply(0x03, 0x80), 0x00);
        assert_eq!(BitOperation::Xor.apply(0x83, 0x80), 0x03);
    }
}
