//! The backup file: TOML that a person reads and edits. A `[device]` header (model, node,
//! identification value, time, mode), then one table per group with one line per
//! parameter, `REGISTER = VALUE  # name, unit`: the register in hex as the manual prints
//! it, the value in decimal as read.
//!
//! The reader takes the subset of TOML that the writer writes (tables, `key = value`
//! with a string or an integer, comments), so that every error names its line and
//! column and says what was expected and what was found; any TOML reader reads the file.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use super::Parameter;
use crate::model::DriveModel;

/// What a backup says about the drive it was read from.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Header {
    /// The model id (f510, a description's id).
    pub model: String,
    /// The node address it was read from.
    pub node: u8,
    /// The identification register's value, where the model has one and it answered.
    pub identification: Option<u16>,
    /// When it was read (RFC 3339, UTC).
    pub time: String,
    /// The transmission mode it was read in.
    pub mode: Option<String>,
}

/// One parameter line of a backup.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Entry {
    /// The register.
    pub register: u16,
    /// The value.
    pub value: u16,
    /// The line it is on (1-based), for errors.
    pub line: usize,
}

/// A backup file: its header and its parameter lines by group, in file order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Backup {
    /// The header.
    pub header: Header,
    /// The groups (the table name) and their lines.
    pub groups: Vec<(String, Vec<Entry>)>,
}

/// Why a backup file could not be read.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum FileError {
    /// Text that is not the expected syntax.
    #[error("line {line}, column {column}: expected {expected}, found {found}")]
    Syntax {
        /// Line (1-based).
        line: usize,
        /// Column (1-based, in characters).
        column: usize,
        /// What was expected there.
        expected: String,
        /// What was found: the text and its bytes in hex.
        found: String,
    },
    /// A register given twice.
    #[error("line {line}: register {register:04X} is given a second time (first on line {first})")]
    Duplicate {
        /// The second line.
        line: usize,
        /// The register.
        register: u16,
        /// The first line.
        first: usize,
    },
    /// A header field that is missing.
    #[error("the [device] table has no {field} (expected {expected})")]
    Missing {
        /// The field.
        field: &'static str,
        /// What it should hold.
        expected: &'static str,
    },
    /// A line a restore refuses to write.
    #[error("line {line}: {register:04X} = {value}: {why}")]
    Refused {
        /// The line.
        line: usize,
        /// The register.
        register: u16,
        /// The value.
        value: u16,
        /// Why, naming the model's fact.
        why: String,
    },
}

/// The text at `rest` as an error shows it: up to 16 characters, and their bytes in hex
/// (a stray control character or a non-ASCII look-alike is seen for what it is).
fn found(rest: &str) -> String {
    if rest.is_empty() {
        return "the end of the line".into();
    }
    let shown: String = rest.chars().take(16).collect();
    format!("{shown:?} ({})", crate::codec::hex::Hex(shown.as_bytes()))
}

/// A value on the right of `=`.
enum Value {
    Str(String),
    Int(u64),
}

/// A cursor over one line, which knows its line number, for errors.
struct Cursor<'a> {
    text: &'a str,
    at: usize,
    line: usize,
}

impl<'a> Cursor<'a> {
    fn rest(&self) -> &'a str {
        &self.text[self.at..]
    }

    fn column(&self) -> usize {
        self.text[..self.at].chars().count() + 1
    }

    fn error(&self, expected: impl Into<String>) -> FileError {
        FileError::Syntax {
            line: self.line,
            column: self.column(),
            expected: expected.into(),
            found: found(self.rest()),
        }
    }

    fn skip_space(&mut self) {
        let r = self.rest();
        self.at += r.len() - r.trim_start_matches([' ', '\t']).len();
    }

    fn eat(&mut self, c: char) -> bool {
        if self.rest().starts_with(c) {
            self.at += c.len_utf8();
            true
        } else {
            false
        }
    }

    /// The end of a line: spaces, then nothing or a comment.
    fn end(&mut self) -> Result<(), FileError> {
        self.skip_space();
        let r = self.rest();
        if r.is_empty() || r.starts_with('#') {
            Ok(())
        } else {
            Err(self.error("the end of the line or a comment ('#')"))
        }
    }

    /// A key: bare (letters, digits, '_', '-') or a basic string.
    fn key(&mut self) -> Result<String, FileError> {
        if self.rest().starts_with('"') {
            return self.string();
        }
        let r = self.rest();
        let n = r
            .find(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == '-'))
            .unwrap_or(r.len());
        if n == 0 {
            return Err(self.error("a key (a register in hex, or a header field)"));
        }
        self.at += n;
        Ok(r[..n].to_string())
    }

    /// A basic string without escapes other than \" and \\ (what the writer writes).
    fn string(&mut self) -> Result<String, FileError> {
        if !self.eat('"') {
            return Err(self.error("'\"'"));
        }
        let mut s = String::new();
        loop {
            let Some(c) = self.rest().chars().next() else {
                return Err(self.error("the closing '\"' of the string"));
            };
            match c {
                '"' => {
                    self.at += 1;
                    return Ok(s);
                }
                '\\' => {
                    self.at += 1;
                    match self.rest().chars().next() {
                        Some(e @ ('"' | '\\')) => {
                            s.push(e);
                            self.at += 1;
                        }
                        _ => return Err(self.error("'\\\"' or '\\\\' (the only escapes read)")),
                    }
                }
                c if c.is_control() => {
                    return Err(self.error("a printable character or the closing '\"'"))
                }
                c => {
                    s.push(c);
                    self.at += c.len_utf8();
                }
            }
        }
    }

    /// A string, or a non-negative integer: decimal, or hex with 0x.
    fn value(&mut self) -> Result<Value, FileError> {
        if self.rest().starts_with('"') {
            return self.string().map(Value::Str);
        }
        let r = self.rest();
        let (digits, radix, skip) = match r.strip_prefix("0x") {
            Some(h) => (h, 16, 2),
            None => (r, 10, 0),
        };
        let n = digits
            .find(|c: char| !(c.is_digit(radix) || c == '_'))
            .unwrap_or(digits.len());
        let text: String = digits[..n].chars().filter(|c| *c != '_').collect();
        if text.is_empty() {
            return Err(self.error("a value: a decimal number, 0x and hex digits, or a string"));
        }
        match u64::from_str_radix(&text, radix) {
            Ok(v) => {
                self.at += skip + n;
                Ok(Value::Int(v))
            }
            Err(_) => Err(self.error("a number below 2^64")),
        }
    }
}

impl Backup {
    /// The values by register.
    pub fn values(&self) -> BTreeMap<u16, u16> {
        self.entries().map(|e| (e.register, e.value)).collect()
    }

    /// Every parameter line, in file order.
    pub fn entries(&self) -> impl Iterator<Item = &Entry> + '_ {
        self.groups.iter().flat_map(|(_, e)| e.iter())
    }

    /// The group each register is in.
    pub fn group_of(&self, register: u16) -> Option<&str> {
        self.groups
            .iter()
            .find(|(_, es)| es.iter().any(|e| e.register == register))
            .map(|(g, _)| g.as_str())
    }

    /// The file's text: the header, then per group `REGISTER = VALUE  # name, unit`.
    /// Read-only parameters are written as comments: a person sees them, and a restore of
    /// the file never meets a line it must refuse. A register the device refused to read
    /// (`refused`, with why) is a comment that says so.
    pub fn write(
        model: &DriveModel,
        header: &Header,
        params: &[Parameter],
        values: &BTreeMap<u16, u16>,
        refused: &BTreeMap<u16, String>,
    ) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "# The parameters of a {} device ({}), read by `conformance params backup`.",
            model.id, model.title
        );
        s.push_str("# One line per parameter: REGISTER (hex) = VALUE (decimal, raw as read)  # name, unit.\n");
        s.push_str("# Edit a value and `conformance params restore FILE` writes it (it shows the writes first);\n");
        s.push_str("# read-only parameters are comments: a restore never writes them.\n\n");
        s.push_str("[device]\n");
        let _ = writeln!(s, "model = {}", quote(&header.model));
        let _ = writeln!(s, "node = {}", header.node);
        if let Some(id) = header.identification {
            let _ = writeln!(s, "identification = \"{id:04X}\"");
        }
        let _ = writeln!(s, "time = {}", quote(&header.time));
        if let Some(m) = &header.mode {
            let _ = writeln!(s, "mode = {}", quote(m));
        }
        let mut group: Option<&str> = None;
        for p in params {
            let (v, why) = (values.get(&p.register), refused.get(&p.register));
            if v.is_none() && why.is_none() {
                continue;
            }
            if group != Some(p.group.as_str()) {
                let _ = writeln!(s, "\n[{}]", quote(&p.group));
                group = Some(p.group.as_str());
            }
            let Some(v) = v else {
                // A register the device would not read is kept in sight, not lost.
                let why = why.map(|w| w.replace('\n', " ")).unwrap_or_default();
                let _ = writeln!(s, "# {:04X} not read: {why}", p.register);
                continue;
            };
            let line = format!("{:04X} = {v}", p.register);
            if p.writable {
                let _ = writeln!(s, "{line:<14} # {}", p.comment(*v));
            } else {
                let _ = writeln!(s, "# {line:<12} # {}, read-only", p.comment(*v));
            }
        }
        s
    }

    /// Reads a backup file's text.
    pub fn parse(text: &str) -> Result<Backup, FileError> {
        let mut header = (None, None, None, None, None);
        let mut seen_header = false;
        let mut groups: Vec<(String, Vec<Entry>)> = Vec::new();
        let mut section: Option<String> = None;
        let mut first_line: BTreeMap<u16, usize> = BTreeMap::new();
        for (i, raw) in text.lines().enumerate() {
            let mut c = Cursor {
                text: raw,
                at: 0,
                line: i + 1,
            };
            c.skip_space();
            if c.rest().is_empty() || c.rest().starts_with('#') {
                continue;
            }
            if c.eat('[') {
                c.skip_space();
                let name = c.key()?;
                c.skip_space();
                if !c.eat(']') {
                    return Err(c.error("']' closing the table name"));
                }
                c.end()?;
                if name == "device" {
                    if seen_header {
                        return Err(FileError::Syntax {
                            line: i + 1,
                            column: 1,
                            expected: "one [device] table".into(),
                            found: "a second one".into(),
                        });
                    }
                    seen_header = true;
                } else if !groups.iter().any(|(g, _)| *g == name) {
                    groups.push((name.clone(), Vec::new()));
                }
                section = Some(name);
                continue;
            }
            let key_at = c.column();
            let key = c.key()?;
            c.skip_space();
            if !c.eat('=') {
                return Err(c.error("'=' after the key"));
            }
            c.skip_space();
            let value_at = c.column();
            let value = c.value()?;
            c.end()?;
            let at = |column, expected: &str, found: String| FileError::Syntax {
                line: i + 1,
                column,
                expected: expected.into(),
                found,
            };
            match section.as_deref() {
                None => {
                    return Err(at(
                        1,
                        "a table ([device] or a group) before the first key",
                        format!("{key:?}"),
                    ))
                }
                Some("device") => {
                    let (int, string) = match value {
                        Value::Int(v) => (Some(v), None),
                        Value::Str(s) => (None, Some(s)),
                    };
                    match (key.as_str(), int, string) {
                        ("model", _, Some(s)) => header.0 = Some(s),
                        ("node", Some(v), _) => {
                            header.1 = Some(u8::try_from(v).map_err(|_| {
                                at(value_at, "a node address 0..=255", v.to_string())
                            })?)
                        }
                        ("identification", _, Some(s)) => {
                            header.2 = Some(u16::from_str_radix(&s, 16).map_err(|_| {
                                at(value_at, "4 hex digits in quotes (\"0510\")", found(&s))
                            })?)
                        }
                        ("time", _, Some(s)) => header.3 = Some(s),
                        ("mode", _, Some(s)) => header.4 = Some(s),
                        ("model" | "identification" | "time" | "mode", _, None) => {
                            return Err(at(value_at, "a string in quotes", "a number".into()))
                        }
                        ("node", None, _) => {
                            return Err(at(value_at, "a number", "a string".into()))
                        }
                        _ => {
                            return Err(at(
                                key_at,
                                "model, node, identification, time or mode",
                                format!("{key:?}"),
                            ))
                        }
                    }
                }
                Some(_) => {
                    let register = (key.len() == 4)
                        .then(|| u16::from_str_radix(&key, 16).ok())
                        .flatten()
                        .ok_or_else(|| {
                            at(key_at, "a register: 4 hex digits (0305)", found(&key))
                        })?;
                    let value = match value {
                        Value::Int(v) => u16::try_from(v).map_err(|_| {
                            at(value_at, "a register value 0..=65535", v.to_string())
                        })?,
                        Value::Str(s) => {
                            return Err(at(
                                value_at,
                                "a number (decimal, or 0x and hex digits)",
                                format!("the string {s:?}"),
                            ))
                        }
                    };
                    if let Some(first) = first_line.insert(register, i + 1) {
                        return Err(FileError::Duplicate {
                            line: i + 1,
                            register,
                            first,
                        });
                    }
                    if let Some((_, es)) = groups
                        .iter_mut()
                        .find(|(g, _)| section.as_deref() == Some(g.as_str()))
                    {
                        es.push(Entry {
                            register,
                            value,
                            line: i + 1,
                        });
                    }
                }
            }
        }
        let (model, node, identification, time, mode) = header;
        Ok(Backup {
            header: Header {
                model: model.ok_or(FileError::Missing {
                    field: "model",
                    expected: "model = \"f510\"",
                })?,
                node: node.ok_or(FileError::Missing {
                    field: "node",
                    expected: "node = 1",
                })?,
                identification,
                time: time.unwrap_or_default(),
                mode,
            },
            groups,
        })
    }
}

/// `s` as a TOML basic string.
fn quote(s: &str) -> String {
    let mut q = String::from("\"");
    for c in s.chars() {
        match c {
            '"' => q.push_str("\\\""),
            '\\' => q.push_str("\\\\"),
            c if c.is_control() => q.push(' '),
            c => q.push(c),
        }
    }
    q.push('"');
    q
}
