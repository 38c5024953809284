//! `model import --from csv`: a register map as integrators keep it, one row per register
//! or per range, into a description's `blocks`.
//!
//! The columns, matched by their header, case-insensitively and in any order (the guide's
//! "Import and export" section is the reference):
//! - `register` (required): the first register, `0x2500`, `2500H` or decimal `9472`; or a
//!   range `2500H-25FFH` (also `2500H..25FFH`). With [`ImportOptions::hex_registers`], a
//!   bare number is hex (`2500-25FF`), as some sheets write them.
//! - `last`: the last register of the row's range (instead of a range in `register`).
//! - `name`, `unit`: text. `access`: read-write (rw, r/w), read-only (r, ro), write-only
//!   (w, wo) or reserved; empty is read-write, the format's default.
//! - `min`, `max`: bounds of written values, `0x1770`, `1770H` or decimal.
//! - `scale`: a number, value = raw x scale.
//!
//! Other columns (a description, a comment) are not imported and are named in
//! [`Imported::ignored_columns`]. Blank rows and rows whose first cell starts with `#`
//! are skipped. Each row is one block, cited as `MAP.csv row N` (N as a spreadsheet
//! numbers rows, the header being row 1): rows are not merged, so that every block keeps
//! its own name and citation.

use serde::Serialize;
use serde_json::{json, Value};

/// One block of the description, its fields in the format's order (a person reads and
/// edits the file: `first` and `last` come first, the basis last).
#[derive(Debug, Clone, Default, Serialize)]
struct Block {
    first: String,
    last: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    name: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    access: Option<&'static str>,
    #[serde(skip_serializing_if = "Option::is_none")]
    min: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    max: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    unit: Option<String>,
    #[serde(skip_serializing_if = "Option::is_none")]
    scale: Option<f64>,
    basis: &'static str,
    source: String,
}

/// The functions fact.
#[derive(Debug, Clone, Serialize)]
struct Functions {
    codes: Vec<String>,
    basis: &'static str,
    why: String,
}

/// The description, its fields in the format's order.
#[derive(Debug, Clone, Serialize)]
struct Description<'a> {
    schema_version: u32,
    model: &'a str,
    title: &'a str,
    notes: String,
    modes: &'a [String],
    functions: Functions,
    blocks: Vec<Block>,
}

/// What the command line says of the description besides the map.
#[derive(Debug, Clone)]
pub struct ImportOptions {
    /// The file's name as cited in every block's `source` (`MAP.csv`).
    pub source_name: String,
    /// Model id: `^[a-z0-9][a-z0-9._-]{0,63}$`.
    pub model: String,
    /// Title of the description.
    pub title: String,
    /// Modes: a non-empty subset of rtu, ascii.
    pub modes: Vec<String>,
    /// Function codes served.
    pub functions: Vec<u8>,
    /// A bare number in the register and last columns is hex (else decimal).
    pub hex_registers: bool,
}

/// The description drawn up from a register map.
#[derive(Debug, Clone)]
pub struct Imported {
    /// The description (schema_version 2).
    pub description: Value,
    /// The description as JSON text, its fields in the format's order.
    pub text: String,
    /// Blocks written (one per row of the map).
    pub blocks: usize,
    /// Columns of the header that are not imported.
    pub ignored_columns: Vec<String>,
}

/// Why a register map could not be imported: the row and column, and what was expected.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CsvError {
    /// No header row.
    #[error(
        "{file}: empty: expected a header row (register, name, access, min, max, unit, scale)"
    )]
    Empty {
        /// The file.
        file: String,
    },
    /// The header has no register column.
    #[error("{file} row 1: no `register` column: expected a header naming register (and any of last, name, access, min, max, unit, scale), found {found:?}")]
    NoRegisterColumn {
        /// The file.
        file: String,
        /// The header's cells.
        found: Vec<String>,
    },
    /// A column is named twice.
    #[error("{file} row 1: column {column:?} is named twice")]
    DuplicateColumn {
        /// The file.
        file: String,
        /// The column.
        column: String,
    },
    /// A quoted cell is not closed, or text follows its closing quote.
    #[error("{file} row {row}: {problem}")]
    Quoting {
        /// The file.
        file: String,
        /// The row the record starts on.
        row: usize,
        /// What is wrong.
        problem: String,
    },
    /// A cell does not hold what its column takes.
    #[error("{file} row {row}, column {column}: {text:?} {problem}")]
    Cell {
        /// The file.
        file: String,
        /// The row.
        row: usize,
        /// The column.
        column: String,
        /// The cell's text.
        text: String,
        /// What was expected.
        problem: String,
    },
    /// Two rows name the same register.
    #[error("{file} row {row}: {first:04X}H..{last:04X}H overlaps row {other} ({other_first:04X}H..{other_last:04X}H): a register is described once")]
    Overlap {
        /// The file.
        file: String,
        /// The later row.
        row: usize,
        /// Its range.
        first: u16,
        /// Its range's end.
        last: u16,
        /// The earlier row.
        other: usize,
        /// Its range.
        other_first: u16,
        /// Its range's end.
        other_last: u16,
    },
    /// No row describes a register.
    #[error("{file}: no register rows under the header")]
    NoRows {
        /// The file.
        file: String,
    },
    /// An option of the description is not valid.
    #[error("{0}")]
    Option(String),
}

/// The columns imported, as the header names them (lower case).
const COLUMNS: [&str; 8] = [
    "register", "last", "name", "access", "min", "max", "unit", "scale",
];

/// Splits `text` into records of cells, RFC 4180 style (quotes, doubled quotes, line
/// breaks inside quotes), with the line each record starts on. The separator is `,`, or
/// `;` where the first line has a `;` and no `,` (spreadsheets of some locales).
fn records(file: &str, text: &str) -> Result<Vec<(usize, Vec<String>)>, CsvError> {
    let text = text.strip_prefix('\u{feff}').unwrap_or(text);
    let first_line = text.lines().next().unwrap_or("");
    let sep = if !first_line.contains(',') && first_line.contains(';') {
        ';'
    } else {
        ','
    };
    let mut out = Vec::new();
    let mut cells = Vec::new();
    let mut cell = String::new();
    let mut line = 1;
    let mut start = 1;
    let mut quoted = false;
    let mut after_quote = false;
    let mut chars = text.chars().peekable();
    while let Some(c) = chars.next() {
        if quoted {
            match c {
                '"' if chars.peek() == Some(&'"') => {
                    chars.next();
                    cell.push('"');
                }
                '"' => {
                    quoted = false;
                    after_quote = true;
                }
                '\n' => {
                    line += 1;
                    cell.push(c);
                }
                _ => cell.push(c),
            }
            continue;
        }
        match c {
            '"' if cell.trim().is_empty() && !after_quote => {
                cell.clear();
                quoted = true;
            }
            c if c == sep => {
                cells.push(std::mem::take(&mut cell));
                after_quote = false;
            }
            '\r' if chars.peek() == Some(&'\n') => {}
            '\n' => {
                cells.push(std::mem::take(&mut cell));
                out.push((start, std::mem::take(&mut cells)));
                after_quote = false;
                line += 1;
                start = line;
            }
            c if after_quote && !c.is_whitespace() => {
                return Err(CsvError::Quoting {
                    file: file.into(),
                    row: start,
                    problem: format!(
                        "{c:?} after a quoted cell's closing quote: expected {sep:?} or the end of the row (a quote inside a quoted cell is written twice: \"\")"
                    ),
                });
            }
            c if after_quote => {
                let _ = c;
            }
            _ => cell.push(c),
        }
    }
    if quoted {
        return Err(CsvError::Quoting {
            file: file.into(),
            row: start,
            problem:
                "a quoted cell is not closed: expected a closing \" before the end of the file"
                    .into(),
        });
    }
    if !cell.is_empty() || !cells.is_empty() {
        cells.push(cell);
        out.push((start, cells));
    }
    Ok(out)
}

/// A number as the map writes it: `0x2500`, `2500H`, or bare (decimal, or hex with
/// `bare_hex`); at most FFFFH.
fn number(text: &str, bare_hex: bool) -> Result<u16, String> {
    let t = text.trim();
    let (digits, radix) = if let Some(h) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        (h, 16)
    } else if let Some(h) = t.strip_suffix(['H', 'h']) {
        (h, 16)
    } else if bare_hex {
        (t, 16)
    } else {
        (t, 10)
    };
    if digits.is_empty() || !digits.chars().all(|c| c.is_digit(radix)) {
        let hint = if radix == 10
            && !digits.is_empty()
            && digits.chars().all(|c| c.is_ascii_hexdigit())
        {
            " (a bare number is decimal: write it 25FFH or 0x25FF, or import with --hex-registers where the sheet writes registers in bare hex)"
        } else {
            ""
        };
        return Err(format!(
            "is not a number: expected hex with H suffix or 0x prefix (2500H, 0x2500) or a decimal number{hint}"
        ));
    }
    u32::from_str_radix(digits, radix)
        .ok()
        .and_then(|v| u16::try_from(v).ok())
        .ok_or_else(|| "is over FFFFH (65535), the largest register or value".to_string())
}

/// A register or a range of registers.
fn registers(text: &str, bare_hex: bool) -> Result<(u16, Option<u16>), String> {
    let t = text.trim();
    let split = t.split_once("..").or_else(|| t.split_once('-'));
    match split {
        Some((a, b)) => Ok((number(a, bare_hex)?, Some(number(b, bare_hex)?))),
        None => Ok((number(t, bare_hex)?, None)),
    }
}

fn access(text: &str) -> Option<&'static str> {
    match text.trim().to_ascii_lowercase().as_str() {
        "read-write" | "read/write" | "rw" | "r/w" => Some("read-write"),
        "read-only" | "read only" | "r" | "ro" => Some("read-only"),
        "write-only" | "write only" | "w" | "wo" => Some("write-only"),
        "reserved" => Some("reserved"),
        _ => None,
    }
}

/// Draws a description (schema_version 2) up from the register map `text`.
pub fn import_csv(text: &str, options: &ImportOptions) -> Result<Imported, CsvError> {
    let file = options.source_name.as_str();
    if !crate::model::valid_model_id(&options.model) {
        return Err(CsvError::Option(format!(
            "model id {:?}: expected 1..64 of a-z 0-9 . _ - starting with a letter or digit",
            options.model
        )));
    }
    if options.modes.is_empty()
        || options.modes.iter().any(|m| m != "rtu" && m != "ascii")
        || (options.modes.len() == 2 && options.modes[0] == options.modes[1])
        || options.modes.len() > 2
    {
        return Err(CsvError::Option(format!(
            "modes {:?}: expected rtu, ascii or rtu,ascii",
            options.modes
        )));
    }
    let rows = records(file, text)?;
    let mut rows = rows
        .into_iter()
        .filter(|(_, cells)| cells.iter().any(|c| !c.trim().is_empty()));
    let (_, header) = rows
        .next()
        .ok_or_else(|| CsvError::Empty { file: file.into() })?;
    let header: Vec<String> = header
        .iter()
        .map(|h| h.trim().to_ascii_lowercase())
        .collect();
    let mut at = [None; COLUMNS.len()];
    let mut ignored = Vec::new();
    for (i, h) in header.iter().enumerate() {
        match COLUMNS.iter().position(|c| c == h) {
            Some(k) if at[k].is_some() => {
                return Err(CsvError::DuplicateColumn {
                    file: file.into(),
                    column: h.clone(),
                })
            }
            Some(k) => at[k] = Some(i),
            None if h.is_empty() => {}
            None => ignored.push(h.clone()),
        }
    }
    if at[0].is_none() {
        return Err(CsvError::NoRegisterColumn {
            file: file.into(),
            found: header,
        });
    }
    let mut blocks: Vec<(usize, u16, u16, Block)> = Vec::new();
    for (row, cells) in rows {
        let cell = |k: usize| -> &str {
            at[k]
                .and_then(|i| cells.get(i))
                .map(|s| s.trim())
                .unwrap_or("")
        };
        if cell(0).starts_with('#') || cells.first().is_some_and(|c| c.trim().starts_with('#')) {
            continue;
        }
        let bad = |k: usize, problem: String| CsvError::Cell {
            file: file.into(),
            row,
            column: COLUMNS[k].into(),
            text: cell(k).into(),
            problem,
        };
        if cell(0).is_empty() {
            return Err(bad(
                0,
                "is empty: expected the row's register (2500H) or range (2500H-25FFH)".into(),
            ));
        }
        let (first, range_end) =
            registers(cell(0), options.hex_registers).map_err(|p| bad(0, p))?;
        let last = match (range_end, cell(1)) {
            (Some(_), l) if !l.is_empty() => {
                return Err(bad(1, "names a last register where the register column already holds a range: give one of them".into()))
            }
            (Some(e), _) => e,
            (None, "") => first,
            (None, l) => number(l, options.hex_registers).map_err(|p| bad(1, p))?,
        };
        if last < first {
            return Err(bad(
                if range_end.is_some() { 0 } else { 1 },
                format!("runs backwards: the last register {last:04X}H is before the first {first:04X}H"),
            ));
        }
        let text = |k: usize| (!cell(k).is_empty()).then(|| cell(k).to_string());
        let mut b = Block {
            first: format!("{first:04X}"),
            last: format!("{last:04X}"),
            name: text(2),
            unit: text(6),
            basis: "documented",
            source: format!("{file} row {row}"),
            ..Block::default()
        };
        if !cell(3).is_empty() {
            b.access = Some(access(cell(3)).ok_or_else(|| {
                bad(3, "is not an access: expected read-write (rw), read-only (r), write-only (w) or reserved".into())
            })?);
        }
        let mut bounds = [None, None];
        for (n, k) in [4, 5].into_iter().enumerate() {
            if !cell(k).is_empty() {
                bounds[n] = Some(number(cell(k), false).map_err(|p| bad(k, p))?);
            }
        }
        if let [Some(min), Some(max)] = bounds {
            if min > max {
                return Err(bad(
                    5,
                    format!("is below min {min:04X}H: expected max >= min"),
                ));
            }
        }
        // Bounds are of values written: a block that is not written has none (the
        // format's rule, which the loader and lint hold every description to).
        if let (Some(a @ ("read-only" | "reserved")), Some(k)) =
            (b.access, [4, 5].into_iter().find(|&k| !cell(k).is_empty()))
        {
            return Err(bad(
                k,
                format!("bounds written values, and a {a} block is not written: leave min and max empty, or make it read-write or write-only"),
            ));
        }
        b.min = bounds[0].map(|v| format!("{v:04X}"));
        b.max = bounds[1].map(|v| format!("{v:04X}"));
        if !cell(7).is_empty() {
            b.scale = Some(
                cell(7)
                    .parse()
                    .ok()
                    // The format takes a finite scale other than 0, as the loader checks.
                    .filter(|s: &f64| s.is_finite() && *s != 0.0)
                    .ok_or_else(|| {
                        bad(
                            7,
                            "is not a scale: expected a finite number other than 0, such as 0.01 (value = raw x scale)"
                                .into(),
                        )
                    })?,
            );
        }
        blocks.push((row, first, last, b));
    }
    if blocks.is_empty() {
        return Err(CsvError::NoRows { file: file.into() });
    }
    blocks.sort_by_key(|(row, first, ..)| (*first, *row));
    for w in blocks.windows(2) {
        let (ra, fa, la, _) = &w[0];
        let (rb, fb, lb, _) = &w[1];
        if fb <= la {
            let ((row, first, last), (other, other_first, other_last)) = if rb > ra {
                ((*rb, *fb, *lb), (*ra, *fa, *la))
            } else {
                ((*ra, *fa, *la), (*rb, *fb, *lb))
            };
            return Err(CsvError::Overlap {
                file: file.into(),
                row,
                first,
                last,
                other,
                other_first,
                other_last,
            });
        }
    }
    let n = blocks.len();
    let d = Description {
        schema_version: 2,
        model: &options.model,
        title: &options.title,
        notes: format!("Imported from {file} by `conformance model import --from csv`: the register map only. Every other fact takes the format's default (the Modbus specification's limits) or is absent, and the checks that need it SKIP, naming the field."),
        modes: &options.modes,
        functions: Functions {
            codes: options.functions.iter().map(|f| format!("{f:02X}")).collect(),
            basis: "decision",
            why: format!("{file} is a register map and does not say which functions the device serves: the codes given to model import (--functions)"),
        },
        blocks: blocks.into_iter().map(|(.., b)| b).collect(),
    };
    // Serializing plain strings, numbers and vectors cannot fail.
    let text = serde_json::to_string_pretty(&d).unwrap_or_default() + "\n";
    Ok(Imported {
        description: json!(d),
        text,
        blocks: n,
        ignored_columns: ignored,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn opts() -> ImportOptions {
        ImportOptions {
            source_name: "MAP.csv".into(),
            model: "acme-x100".into(),
            title: "Acme X100 register map".into(),
            modes: vec!["rtu".into()],
            functions: vec![0x03, 0x06, 0x10],
            hex_registers: false,
        }
    }

    /// A register map is a file anybody writes: every cut of a map, every byte of it
    /// changed, and pseudo-random text are imported or refused with an error, never a
    /// panic; and whatever import writes, `model lint` takes without an error (the one
    /// loader every command runs).
    #[test]
    fn any_text_is_imported_or_refused_and_what_is_written_lints_clean() {
        let map = "Register,Name,Access,Min,Max,Unit,Scale,Last\r\n\
                   0x0000-0x0FFF,holding,rw,,,,,\r\n\
                   2500H,\"Frequency, command\",RW,0,6000,0.01 Hz,0.01,\r\n\
                   9473,status,r,,,,,9480\r\n\
                   0x2600,spare,reserved,,,,,\r\n";
        let mut texts: Vec<Vec<u8>> = (0..=map.len())
            .map(|n| map.as_bytes()[..n].to_vec())
            .collect();
        for i in 0..map.len() {
            for b in [b',', b'"', b'\n', b'-', b'H', b'0', b'F', 0xC3] {
                let mut t = map.as_bytes().to_vec();
                t[i] = b;
                texts.push(t);
            }
        }
        let mut x = 0x9E37_79B9u32;
        for _ in 0..500 {
            let t: Vec<u8> = (0..x % 120)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    let alphabet = b"0123456789ABCDEFHx-,.;\"\r\n rwegistrmax";
                    alphabet[x as usize % alphabet.len()]
                })
                .collect();
            texts.push(t);
        }
        let mut written = 0;
        for t in &texts {
            let text = String::from_utf8_lossy(t);
            if let Ok(out) = import_csv(&text, &opts()) {
                let findings = crate::model::lint::lint("imported", &out.text);
                assert!(
                    !crate::model::lint::has_errors(&findings),
                    "{text:?}\n{}\n{findings:#?}",
                    out.text
                );
                written += 1;
            }
        }
        assert!(written > 100, "only {written} of {} imported", texts.len());
    }

    #[test]
    fn rows_become_blocks_with_their_citation() {
        let csv = "Register,Name,Access,Min,Max,Unit,Scale,Comment\r\n\
                   0x0000-0x0FFF,holding,rw,,,,,the settings\r\n\
                   2500H,\"Frequency, command\",RW,0,6000,0.01 Hz,0.01,\r\n\
                   \r\n\
                   # a note\r\n\
                   9473,status,r,,,,,\r\n";
        let out = import_csv(csv, &opts()).unwrap();
        assert_eq!(out.blocks, 3);
        assert_eq!(out.ignored_columns, ["comment"]);
        let b = &out.description["blocks"];
        assert_eq!(
            b[0],
            json!({"first": "0000", "last": "0FFF", "name": "holding", "access": "read-write",
                   "basis": "documented", "source": "MAP.csv row 2"})
        );
        assert_eq!(
            b[1],
            json!({"first": "2500", "last": "2500", "name": "Frequency, command",
                   "access": "read-write", "min": "0000", "max": "1770", "unit": "0.01 Hz",
                   "scale": 0.01, "basis": "documented", "source": "MAP.csv row 3"})
        );
        // 9473 is decimal: 2501H.
        assert_eq!(b[2]["first"], "2501");
        assert_eq!(b[2]["access"], "read-only");
        assert_eq!(b[2]["source"], "MAP.csv row 6");
        let d = &out.description;
        assert_eq!(d["schema_version"], 2);
        assert_eq!(d["modes"], json!(["rtu"]));
        assert_eq!(d["functions"]["codes"], json!(["03", "06", "10"]));
    }

    #[test]
    fn ranges_in_a_last_column_and_bare_hex() {
        let csv = "register;last;name\n2500;252F;monitor\n";
        let mut o = opts();
        o.hex_registers = true;
        let out = import_csv(csv, &o).unwrap();
        assert_eq!(out.description["blocks"][0]["first"], "2500");
        assert_eq!(out.description["blocks"][0]["last"], "252F");
        // Without --hex-registers, 252F is no decimal number: the error says so.
        let e = import_csv(csv, &opts()).unwrap_err();
        assert_eq!(
            e.to_string(),
            "MAP.csv row 2, column last: \"252F\" is not a number: expected hex with H suffix or 0x prefix (2500H, 0x2500) or a decimal number (a bare number is decimal: write it 25FFH or 0x25FF, or import with --hex-registers where the sheet writes registers in bare hex)"
        );
    }

    #[test]
    fn errors_name_the_row_and_column() {
        let e = |csv: &str| import_csv(csv, &opts()).unwrap_err().to_string();
        assert_eq!(
            e("name,unit\nx,Hz\n"),
            "MAP.csv row 1: no `register` column: expected a header naming register (and any of last, name, access, min, max, unit, scale), found [\"name\", \"unit\"]"
        );
        assert_eq!(
            e("register,access\n1000H,maybe\n"),
            "MAP.csv row 2, column access: \"maybe\" is not an access: expected read-write (rw), read-only (r), write-only (w) or reserved"
        );
        assert_eq!(
            e("register\n0x0000-0x00FF\n0x0080H\n"),
            "MAP.csv row 3, column register: \"0x0080H\" is not a number: expected hex with H suffix or 0x prefix (2500H, 0x2500) or a decimal number"
        );
        assert_eq!(
            e("register\n0x0000-0x00FF\n80H\n"),
            "MAP.csv row 3: 0080H..0080H overlaps row 2 (0000H..00FFH): a register is described once"
        );
        assert_eq!(
            e("register\n20H-10H\n"),
            "MAP.csv row 2, column register: \"20H-10H\" runs backwards: the last register 0010H is before the first 0020H"
        );
        assert_eq!(
            e("register,min,max\n10H,100,50\n"),
            "MAP.csv row 2, column max: \"50\" is below min 0064H: expected max >= min"
        );
        assert_eq!(
            e("register,scale\n10H,x\n"),
            "MAP.csv row 2, column scale: \"x\" is not a scale: expected a finite number other than 0, such as 0.01 (value = raw x scale)"
        );
        assert_eq!(
            e("register,name\n10H,\"open\n"),
            "MAP.csv row 2: a quoted cell is not closed: expected a closing \" before the end of the file"
        );
        assert_eq!(
            e(""),
            "MAP.csv: empty: expected a header row (register, name, access, min, max, unit, scale)"
        );
        assert_eq!(
            e("register\n"),
            "MAP.csv: no register rows under the header"
        );
        assert_eq!(
            e("register\n70000\n"),
            "MAP.csv row 2, column register: \"70000\" is over FFFFH (65535), the largest register or value"
        );
        let mut o = opts();
        o.model = "Acme X".into();
        assert!(import_csv("register\n1\n", &o)
            .unwrap_err()
            .to_string()
            .starts_with("model id \"Acme X\""));
    }

    #[test]
    fn never_panics_on_any_bytes() {
        // A few hostile shapes: lone quotes, separators only, a very long cell.
        for csv in [
            "\"",
            ",,,\n,,,",
            "register\n\"\"\"",
            "register\n-",
            "register\n..",
            &"9".repeat(10_000),
        ] {
            let _ = import_csv(csv, &opts());
        }
    }
}
