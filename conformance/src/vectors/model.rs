//! The vector files as Rust types (serde), and their loading.

use std::collections::BTreeMap;
use std::fmt;

use serde::{Deserialize, Serialize};

use crate::codec::hex::decode_nibble;
use crate::codec::{Direction, Mode};

/// Documents the vectors come from, in the order reports list them.
pub const DOCUMENTS: [&str; 5] = ["f510", "a510", "l510", "e510", "l510-legacy"];

/// Why a vector file could not be loaded.
#[derive(Debug, thiserror::Error)]
pub enum LoadError {
    /// Not JSON, or not of the file format.
    #[error("{file}: not a valid vector file")]
    Json {
        /// The file (or document name).
        file: String,
        /// What serde said, with line and column.
        source: serde_json::Error,
    },
    /// A hex field that is not upper-case pairs separated by single spaces.
    #[error("{file}: vector {id}: field {field}: {problem}: {value:?}")]
    Hex {
        /// The file.
        file: String,
        /// The vector.
        id: String,
        /// The field.
        field: &'static str,
        /// What is wrong.
        problem: String,
        /// The field's text.
        value: String,
    },
    /// A rule of the format is broken (an id that does not start with the document, two
    /// vectors with one id, an unknown flag, a frame id that does not match its fields).
    #[error("{file}: {problem}")]
    Format {
        /// The file.
        file: String,
        /// What is wrong.
        problem: String,
    },
    /// A file could not be read.
    #[error("cannot read {file}")]
    Io {
        /// The file.
        file: String,
        /// The I/O error.
        source: std::io::Error,
    },
}

/// Verdict of a vector.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "kebab-case")]
pub enum Verdict {
    /// Decodes cleanly and agrees with its narrative and its twin.
    Consistent,
    /// The manual is wrong in the ways its flags name.
    Erratum,
    /// The manual leaves bytes blank.
    Incomplete,
}

impl fmt::Display for Verdict {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Verdict::Consistent => "consistent",
            Verdict::Erratum => "erratum",
            Verdict::Incomplete => "incomplete",
        })
    }
}

/// One vector file: the vectors of one document.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct VectorFile {
    /// Format version (1).
    pub schema_version: u32,
    /// Document id: f510, a510, l510, e510 or l510-legacy.
    pub document: String,
    /// Title of the source document.
    pub title: String,
    /// The vectors.
    pub vectors: Vec<Vector>,
}

/// One vector: common fields and the type-specific body.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Vector {
    /// Unique id, `<document>.<...>`.
    pub id: String,
    /// Document and section.
    pub source: String,
    /// Verdict.
    pub verdict: Verdict,
    /// Flag names from `flags.json`.
    #[serde(default)]
    pub flags: Vec<String>,
    /// What is wrong and how we know.
    #[serde(default)]
    pub notes: String,
    /// The type-specific fields.
    #[serde(flatten)]
    pub body: Body,
}

/// The type-specific part of a vector.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(tag = "type", rename_all = "kebab-case")]
pub enum Body {
    /// An example frame.
    Frame(FrameVector),
    /// The LRC worked example.
    LrcExample(LrcExample),
    /// The CRC byte-order sentence.
    CrcByteOrder(CrcByteOrder),
    /// The exception-code table.
    ExceptionCodes(ExceptionCodes),
    /// The node-address statement.
    NodeAddress(NodeAddress),
    /// Stated limits.
    Limits(Limits),
    /// A program printed in the document (the CRC routine in C).
    CListing(CListing),
    /// A sentence that states how the exception function code is formed.
    ExceptionRule(ExceptionRule),
}

impl Body {
    /// The `type` name.
    pub fn type_name(&self) -> &'static str {
        match self {
            Body::Frame(_) => "frame",
            Body::LrcExample(_) => "lrc-example",
            Body::CrcByteOrder(_) => "crc-byte-order",
            Body::ExceptionCodes(_) => "exception-codes",
            Body::NodeAddress(_) => "node-address",
            Body::Limits(_) => "limits",
            Body::CListing(_) => "c-listing",
            Body::ExceptionRule(_) => "exception-rule",
        }
    }
}

impl FrameVector {
    /// The bytes of a correct frame for this example: the `corrected` frame where the
    /// manual's is wrong or incomplete, else the printed one; `None` if neither is usable.
    pub fn correct_bytes(&self) -> Option<Vec<u8>> {
        let text = self.corrected.as_deref().unwrap_or(&self.printed);
        crate::codec::hex::parse_hex(text).ok()
    }
}

/// Mode as spelled in the files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FileMode {
    /// RTU.
    Rtu,
    /// ASCII.
    Ascii,
}

impl From<FileMode> for Mode {
    fn from(m: FileMode) -> Mode {
        match m {
            FileMode::Rtu => Mode::Rtu,
            FileMode::Ascii => Mode::Ascii,
        }
    }
}

/// Direction as spelled in the files.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum FileDirection {
    /// Master to slave.
    Request,
    /// Slave to master.
    Response,
}

impl From<FileDirection> for Direction {
    fn from(d: FileDirection) -> Direction {
        match d {
            FileDirection::Request => Direction::Request,
            FileDirection::Response => Direction::Response,
        }
    }
}

/// An example frame.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FrameVector {
    /// RTU or ASCII.
    pub mode: FileMode,
    /// Request or response.
    pub direction: FileDirection,
    /// Bytes as printed, `??` for a blank.
    pub printed: String,
    /// ASCII frames: the characters.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub text: Option<String>,
    /// E510: the damaged OCR tokens a repair was made from.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub ocr_raw: Option<serde_json::Value>,
    /// A correct frame for the same example (errata and incomplete vectors).
    #[serde(default)]
    pub corrected: Option<String>,
    /// What the example's narrative says the frame carries.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub expect: Option<Expect>,
}

/// What the narrative of an example says a frame carries (hex strings).
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct Expect {
    /// Node address.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub address: Option<String>,
    /// Function code.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub function: Option<String>,
    /// Register or start address.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub register: Option<String>,
    /// Register count.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub count: Option<String>,
    /// Value written or read.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub value: Option<String>,
    /// Exception code.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub exception_code: Option<String>,
    /// Anything else the narrative states, kept as data.
    #[serde(flatten)]
    pub other: BTreeMap<String, serde_json::Value>,
}

/// The LRC worked example.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct LrcExample {
    /// Bytes summed.
    pub input: String,
    /// The sum as printed.
    #[serde(default)]
    pub printed_sum: Option<String>,
    /// The LRC as printed.
    pub printed_lrc: String,
    /// The two characters as printed (hex codes).
    pub printed_chars: String,
}

/// The CRC byte-order sentence.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CrcByteOrder {
    /// The sentence, verbatim.
    #[serde(default)]
    pub quote: Option<String>,
    /// The CRC value (4 hex digits).
    #[serde(default)]
    pub crc_value: Option<String>,
    /// The two bytes in the order the sentence says they are sent.
    #[serde(default)]
    pub sent: Option<String>,
    /// What the sentence calls the first byte sent: "high" or "low".
    #[serde(default)]
    pub first_byte_label: Option<String>,
}

/// One row of an exception-code table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExceptionCode {
    /// Code, hex.
    pub code: String,
    /// Meaning as printed.
    pub meaning: String,
}

/// The exception-code table.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExceptionCodes {
    /// Rows in the order printed.
    pub codes: Vec<ExceptionCode>,
}

/// The node-address statement.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct NodeAddress {
    /// The statement, verbatim.
    #[serde(default)]
    pub quote: Option<String>,
    /// Broadcast address (hex).
    pub broadcast: String,
    /// First node address (hex).
    pub first: String,
    /// Last node address (hex).
    pub last: String,
}

/// Registers per mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
pub struct PerMode {
    /// ASCII mode.
    pub ascii: u32,
    /// RTU mode.
    pub rtu: u32,
}

/// Limits a document states.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Limits {
    /// Maximum frame length in bytes.
    #[serde(default)]
    pub max_frame_bytes: Option<u32>,
    /// Response time or interval in ms.
    #[serde(default)]
    pub response_time_ms: Option<u32>,
    /// Registers per read.
    #[serde(default)]
    pub max_read_registers: Option<PerMode>,
    /// Registers per write.
    #[serde(default)]
    pub max_write_registers: Option<PerMode>,
    /// The same-group rule.
    #[serde(default)]
    pub same_group_rule: Option<String>,
    /// Verbatim sentences.
    #[serde(default)]
    pub quotes: Vec<String>,
}

/// One textual repair of a printed program: every occurrence of `find` becomes `replace`.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct TextRepair {
    /// The text as it stands before the repair.
    pub find: String,
    /// What it becomes.
    pub replace: String,
    /// How many times `find` occurs (all occurrences are replaced).
    pub count: u32,
    /// Why the repair is needed.
    pub why: String,
}

/// A program listing printed in a document, kept character for character, with what it
/// takes to make it compile and compute what the document says it computes.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct CListing {
    /// The listing exactly as the source text has it (line breaks, spacing and all).
    pub printed: String,
    /// OCR sources only: the repairs that turn the extracted characters into what the
    /// page prints (flag `ocr-repair`), applied before `repairs`.
    #[serde(default, skip_serializing_if = "Vec::is_empty")]
    pub ocr_repairs: Vec<TextRepair>,
    /// Type names the listing uses without defining them, and the C type each must be.
    pub types: BTreeMap<String, String>,
    /// The smallest edits that make the listing a correct program, applied in order.
    pub repairs: Vec<TextRepair>,
    /// The listing after `ocr_repairs` and `repairs`.
    pub corrected: String,
}

/// A bitwise operation a sentence or an example applies to a function code.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BitOperation {
    /// `f & operand`.
    And,
    /// `f | operand`.
    Or,
    /// `f ^ operand`.
    Xor,
}

impl BitOperation {
    /// The operation applied to `f`.
    pub fn apply(self, f: u8, operand: u8) -> u8 {
        match self {
            BitOperation::And => f & operand,
            BitOperation::Or => f | operand,
            BitOperation::Xor => f ^ operand,
        }
    }
}

impl fmt::Display for BitOperation {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            BitOperation::And => "AND",
            BitOperation::Or => "OR",
            BitOperation::Xor => "XOR",
        })
    }
}

/// The sentence that says how an error reply's function code is made from the request's.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct ExceptionRule {
    /// The sentence, verbatim.
    pub quote: String,
    /// The operation the sentence names.
    pub stated_operation: BitOperation,
    /// Its operand (hex).
    pub operand: String,
    /// The operation the document's example exception frames apply.
    pub examples_operation: BitOperation,
    /// Ids of the document's example exception frames the rule is checked against.
    pub evidence: Vec<String>,
}

/// A byte of a printed frame: known, or left blank by the manual.
pub type Printed = Vec<Option<u8>>;

/// Parses the vectors' hex notation: upper-case pairs separated by single spaces, `??`
/// for a blank.
pub fn parse_printed(s: &str) -> Result<Printed, String> {
    if s.is_empty() {
        return Ok(Vec::new());
    }
    s.split(' ')
        .map(|tok| match tok.as_bytes() {
            b"??" => Ok(None),
            [h, l] if !h.is_ascii_lowercase() && !l.is_ascii_lowercase() => {
                match (decode_nibble(*h), decode_nibble(*l)) {
                    (Some(h), Some(l)) => Ok(Some(h << 4 | l)),
                    _ => Err(format!("{tok:?} is not a hex pair")),
                }
            }
            _ => Err(format!(
                "{tok:?} is not an upper-case hex pair or ?? (pairs are separated by one space)"
            )),
        })
        .collect()
}

/// Parses hex that must have no blanks.
pub fn parse_known(s: &str) -> Result<Vec<u8>, String> {
    parse_printed(s)?
        .into_iter()
        .collect::<Option<Vec<u8>>>()
        .ok_or_else(|| "blank (??) bytes are not allowed here".to_string())
}

/// Parses a hex number field ("2502", "01").
pub fn parse_hex_number(s: &str) -> Result<u32, String> {
    let t = s.trim().trim_end_matches(['H', 'h']);
    u32::from_str_radix(t, 16).map_err(|e| format!("{s:?} is not a hex number: {e}"))
}

/// The flags table (`flags.json`).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct FlagsFile {
    /// Format version (1).
    pub schema_version: u32,
    /// Flag name to explanation.
    pub flags: BTreeMap<String, String>,
}

impl VectorFile {
    /// Parses and validates one vector file's text. `name` is used in errors.
    pub fn from_json(name: &str, text: &str, flags: &FlagsFile) -> Result<Self, LoadError> {
        let file: VectorFile = serde_json::from_str(text).map_err(|source| LoadError::Json {
            file: name.to_string(),
            source,
        })?;
        file.validate(name, flags)?;
        Ok(file)
    }

    fn validate(&self, name: &str, flags: &FlagsFile) -> Result<(), LoadError> {
        let fmt_err = |problem: String| LoadError::Format {
            file: name.to_string(),
            problem,
        };
        if self.schema_version != 1 {
            return Err(fmt_err(format!(
                "schema_version {} is not supported (expected 1)",
                self.schema_version
            )));
        }
        if !DOCUMENTS.contains(&self.document.as_str()) {
            return Err(fmt_err(format!(
                "document {:?} is not one of {DOCUMENTS:?}",
                self.document
            )));
        }
        let mut seen = std::collections::BTreeSet::new();
        for v in &self.vectors {
            let prefix = format!("{}.", self.document);
            if !v.id.starts_with(&prefix) {
                return Err(fmt_err(format!(
                    "vector id {:?} does not start with {prefix:?}",
                    v.id
                )));
            }
            if !seen.insert(v.id.as_str()) {
                return Err(fmt_err(format!("vector id {:?} appears twice", v.id)));
            }
            for f in &v.flags {
                if !flags.flags.contains_key(f) {
                    return Err(fmt_err(format!(
                        "vector {}: flag {f:?} is not explained in flags.json",
                        v.id
                    )));
                }
            }
            let hex_err = |field: &'static str, problem: String, value: &str| LoadError::Hex {
                file: name.to_string(),
                id: v.id.clone(),
                field,
                problem,
                value: value.to_string(),
            };
            let fixed_id = match &v.body {
                Body::CListing(_) => Some("crc-listing"),
                Body::ExceptionRule(_) => Some("exception-rule"),
                _ => None,
            };
            if let Some(tail) = fixed_id {
                if v.id != format!("{prefix}{tail}") {
                    return Err(fmt_err(format!(
                        "a {} vector's id is {prefix}{tail}, not {:?}",
                        v.body.type_name(),
                        v.id
                    )));
                }
            }
            if let Body::Frame(fv) = &v.body {
                parse_printed(&fv.printed).map_err(|p| hex_err("printed", p, &fv.printed))?;
                if let Some(c) = &fv.corrected {
                    parse_known(c).map_err(|p| hex_err("corrected", p, c))?;
                }
                if let Some(key) = FrameKey::parse(&v.id) {
                    let mode_ok = key.mode == fv.mode;
                    let dir_ok = match key.kind {
                        Some(FrameKind::Request) => fv.direction == FileDirection::Request,
                        _ => fv.direction == FileDirection::Response,
                    };
                    if !mode_ok || !dir_ok {
                        return Err(fmt_err(format!(
                            "vector {}: mode/direction fields ({:?}, {:?}) disagree with the id",
                            v.id, fv.mode, fv.direction
                        )));
                    }
                } else {
                    return Err(fmt_err(format!(
                        "frame vector id {:?} is neither <doc>.<fc>.<mode>.<kind> nor <doc>.exception-example.<mode>",
                        v.id
                    )));
                }
            }
        }
        Ok(())
    }
}

/// Kind of an example frame.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub enum FrameKind {
    /// Command message.
    Request,
    /// Normal response.
    Response,
    /// Error response.
    Exception,
}

/// The parts of a frame vector's id.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct FrameKey {
    /// Document.
    pub document: String,
    /// Function section (03, 06, 08, 10), `None` for the chapter's exception example.
    pub function: Option<u8>,
    /// Mode.
    pub mode: FileMode,
    /// Kind, `None` for the chapter's exception example.
    pub kind: Option<FrameKind>,
}

impl FrameKey {
    /// Parses `<doc>.<fc>.<mode>.<kind>` or `<doc>.exception-example.<mode>`.
    pub fn parse(id: &str) -> Option<FrameKey> {
        let doc = DOCUMENTS.iter().find(|d| {
            id.strip_prefix(**d)
                .is_some_and(|rest| rest.starts_with('.'))
        })?;
        let rest = &id[doc.len() + 1..];
        let parts: Vec<&str> = rest.split('.').collect();
        let mode = |s: &str| match s {
            "rtu" => Some(FileMode::Rtu),
            "ascii" => Some(FileMode::Ascii),
            _ => None,
        };
        match parts.as_slice() {
            ["exception-example", m] => Some(FrameKey {
                document: doc.to_string(),
                function: None,
                mode: mode(m)?,
                kind: None,
            }),
            [fc, m, kind] => {
                let function = match *fc {
                    "03" => 0x03,
                    "06" => 0x06,
                    "08" => 0x08,
                    "10" => 0x10,
                    _ => return None,
                };
                let kind = match *kind {
                    "request" => FrameKind::Request,
                    "response" => FrameKind::Response,
                    "exception" => FrameKind::Exception,
                    _ => return None,
                };
                Some(FrameKey {
                    document: doc.to_string(),
                    function: Some(function),
                    mode: mode(m)?,
                    kind: Some(kind),
                })
            }
            _ => None,
        }
    }

    /// Id of this key.
    pub fn id(&self) -> String {
        let mode = match self.mode {
            FileMode::Rtu => "rtu",
            FileMode::Ascii => "ascii",
        };
        match (self.function, self.kind) {
            (Some(fc), Some(kind)) => {
                let kind = match kind {
                    FrameKind::Request => "request",
                    FrameKind::Response => "response",
                    FrameKind::Exception => "exception",
                };
                format!("{}.{fc:02X}.{mode}.{kind}", self.document)
            }
            _ => format!("{}.exception-example.{mode}", self.document),
        }
    }

    /// The same example in the other mode.
    pub fn twin(&self) -> FrameKey {
        FrameKey {
            mode: match self.mode {
                FileMode::Rtu => FileMode::Ascii,
                FileMode::Ascii => FileMode::Rtu,
            },
            ..self.clone()
        }
    }

    /// The request this response or exception answers (same mode).
    pub fn request(&self) -> Option<FrameKey> {
        match self.kind {
            Some(FrameKind::Response | FrameKind::Exception) => Some(FrameKey {
                kind: Some(FrameKind::Request),
                ..self.clone()
            }),
            _ => None,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn printed_notation() {
        assert_eq!(
            parse_printed("01 03 ?? AF").unwrap(),
            vec![Some(1), Some(3), None, Some(0xAF)]
        );
        assert!(parse_printed("01  03").is_err());
        assert!(parse_printed("01 af").is_err());
        assert!(parse_printed("1 03").is_err());
        assert!(parse_printed("0G").is_err());
        assert_eq!(parse_printed("").unwrap(), vec![]);
        assert!(parse_known("01 ??").is_err());
    }

    #[test]
    fn frame_keys() {
        let k = FrameKey::parse("l510-legacy.10.ascii.exception").unwrap();
        assert_eq!(k.document, "l510-legacy");
        assert_eq!(k.function, Some(0x10));
        assert_eq!(k.twin().id(), "l510-legacy.10.rtu.exception");
        assert_eq!(k.request().unwrap().id(), "l510-legacy.10.ascii.request");
        let k = FrameKey::parse("f510.exception-example.rtu").unwrap();
        assert_eq!(k.twin().id(), "f510.exception-example.ascii");
        assert_eq!(k.request(), None);
        assert_eq!(FrameKey::parse("f510.04.rtu.request"), None);
        assert_eq!(FrameKey::parse("f510.lrc-example"), None);
        assert_eq!(FrameKey::parse("x510.03.rtu.request"), None);
    }
}
