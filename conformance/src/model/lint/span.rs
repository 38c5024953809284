//! Where a field is in a description's text: a JSON path to a line and column.
//!
//! serde_json keeps no spans, so this walks the text itself. It is total over any input
//! (no panic, no recursion: objects and arrays it does not enter are skipped by counting
//! brackets), because it runs on files a user wrote, and a file that serde_json accepted
//! is the usual case but not a precondition.

use std::fmt;

/// One step of a JSON path: an object's member or an array's element.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Segment {
    /// A member, by key.
    Key(String),
    /// An element, by index.
    Index(usize),
}

/// A JSON path from the top of the file, printed as `limits.read_registers.rtu` or
/// `blocks[2].last` (the top level prints as `(top level)`).
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct JsonPath(pub Vec<Segment>);

impl JsonPath {
    /// This path and one more member.
    pub fn key(&self, k: &str) -> JsonPath {
        let mut p = self.0.clone();
        p.push(Segment::Key(k.to_string()));
        JsonPath(p)
    }

    /// This path and one more element.
    pub fn index(&self, i: usize) -> JsonPath {
        let mut p = self.0.clone();
        p.push(Segment::Index(i));
        JsonPath(p)
    }

    /// Reads a path as printed (`blocks[2].last`, `exceptions.illegal-count`); `None` if
    /// it is not one (a space, an unclosed bracket).
    pub fn parse(s: &str) -> Option<JsonPath> {
        let mut out = Vec::new();
        for part in s.split('.') {
            let (key, mut rest) = match part.find('[') {
                Some(i) => (&part[..i], &part[i..]),
                None => (part, ""),
            };
            if key.is_empty()
                || !key
                    .bytes()
                    .all(|b| b.is_ascii_alphanumeric() || b == b'_' || b == b'-')
            {
                return None;
            }
            out.push(Segment::Key(key.to_string()));
            while !rest.is_empty() {
                let close = rest.find(']')?;
                let n = rest.get(1..close)?.parse().ok()?;
                out.push(Segment::Index(n));
                rest = &rest[close + 1..];
                if !rest.is_empty() && !rest.starts_with('[') {
                    return None;
                }
            }
        }
        Some(JsonPath(out))
    }
}

impl fmt::Display for JsonPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.0.is_empty() {
            return f.write_str("(top level)");
        }
        for (i, s) in self.0.iter().enumerate() {
            match s {
                Segment::Key(k) if i == 0 => write!(f, "{k}")?,
                Segment::Key(k) => write!(f, ".{k}")?,
                Segment::Index(n) => write!(f, "[{n}]")?,
            }
        }
        Ok(())
    }
}

/// Line and column (both from 1; the column counts characters) of the byte `offset` of
/// `text`; an offset past the end, or inside a character, counts as far as it goes.
pub fn line_col(text: &str, offset: usize) -> (usize, usize) {
    let mut line = 1;
    let mut col = 1;
    for (i, c) in text.char_indices() {
        if i >= offset {
            break;
        }
        if c == '\n' {
            line += 1;
            col = 1;
        } else {
            col += 1;
        }
    }
    (line, col)
}

/// The byte offset in `text` of what `path` names: a member's key (so that an error
/// points at the field's name), an element's first character, or the top-level value.
/// Where the path leads nowhere (a member that is missing, a text that is not JSON), the
/// offset of the deepest part that was found.
pub fn locate(text: &str, path: &JsonPath) -> usize {
    let b = text.as_bytes();
    let mut at = skip_ws(b, 0);
    let mut found = at;
    for seg in &path.0 {
        match (seg, b.get(at)) {
            (Segment::Key(k), Some(b'{')) => match find_member(b, at, k) {
                Some((key_at, value_at)) => {
                    found = key_at;
                    at = value_at;
                }
                None => return found,
            },
            (Segment::Index(n), Some(b'[')) => match find_element(b, at, *n) {
                Some(e) => {
                    found = e;
                    at = e;
                }
                None => return found,
            },
            _ => return found,
        }
    }
    found
}

/// The byte offset of `line` and `column` (both from 1; the column in bytes, as
/// serde_json counts it), or the end of the text if it has no such place.
pub fn offset_of(text: &str, line: usize, column: usize) -> usize {
    let start = if line <= 1 {
        0
    } else {
        match text.match_indices('\n').nth(line - 2) {
            Some((i, _)) => i + 1,
            None => return text.len(),
        }
    };
    (start + column.saturating_sub(1)).min(text.len())
}

/// The path of the deepest member or element whose key or value holds the byte `offset`
/// (the field a serde error at that place is about); the top level if none does.
pub fn path_at(text: &str, offset: usize) -> JsonPath {
    let b = text.as_bytes();
    let mut path = JsonPath::default();
    let mut at = skip_ws(b, 0);
    'descend: loop {
        match b.get(at) {
            Some(b'{') => {
                let mut i = skip_ws(b, at + 1);
                while b.get(i) == Some(&b'"') {
                    let key_end = skip_string(b, i);
                    let key: Option<String> =
                        std::str::from_utf8(b.get(i..key_end).unwrap_or_default())
                            .ok()
                            .and_then(|raw| serde_json::from_str(raw).ok());
                    let colon = skip_ws(b, key_end);
                    if b.get(colon) != Some(&b':') {
                        break 'descend;
                    }
                    let value_at = skip_ws(b, colon + 1);
                    let value_end = skip_value(b, value_at);
                    if (i..value_end).contains(&offset) {
                        let Some(k) = key else { break 'descend };
                        path.0.push(Segment::Key(k));
                        at = value_at;
                        continue 'descend;
                    }
                    let Some(next) = next_item(b, value_end) else {
                        break 'descend;
                    };
                    i = next;
                }
                break 'descend;
            }
            Some(b'[') => {
                let mut i = skip_ws(b, at + 1);
                let mut n = 0;
                while i < b.len() && b.get(i) != Some(&b']') {
                    let end = skip_value(b, i);
                    if (i..end).contains(&offset) {
                        path.0.push(Segment::Index(n));
                        at = i;
                        continue 'descend;
                    }
                    let Some(next) = next_item(b, end) else {
                        break 'descend;
                    };
                    i = next;
                    n += 1;
                }
                break 'descend;
            }
            _ => break 'descend,
        }
    }
    path
}

/// Where the next member or element starts, past the comma after the one that ends at
/// `end`; None where no comma follows (the object or array ends there, or is broken).
fn next_item(b: &[u8], end: usize) -> Option<usize> {
    let i = skip_ws(b, end);
    (b.get(i) == Some(&b',')).then(|| skip_ws(b, i + 1))
}

fn skip_ws(b: &[u8], mut i: usize) -> usize {
    while matches!(b.get(i), Some(b' ' | b'\t' | b'\n' | b'\r')) {
        i += 1;
    }
    i
}

/// The end (one past the closing quote) of the string starting at `i`.
fn skip_string(b: &[u8], mut i: usize) -> usize {
    i += 1;
    while let Some(&c) = b.get(i) {
        match c {
            b'\\' => i += 2,
            b'"' => return i + 1,
            _ => i += 1,
        }
    }
    b.len()
}

/// The end of the value starting at `i`: strings and scalars directly, objects and
/// arrays by counting brackets outside strings.
fn skip_value(b: &[u8], i: usize) -> usize {
    match b.get(i) {
        Some(b'"') => skip_string(b, i),
        Some(b'{' | b'[') => {
            let mut depth = 0usize;
            let mut j = i;
            while let Some(&c) = b.get(j) {
                match c {
                    b'"' => {
                        j = skip_string(b, j);
                        continue;
                    }
                    b'{' | b'[' => depth += 1,
                    b'}' | b']' => {
                        depth = depth.saturating_sub(1);
                        if depth == 0 {
                            return j + 1;
                        }
                    }
                    _ => {}
                }
                j += 1;
            }
            b.len()
        }
        Some(_) => {
            let mut j = i;
            while let Some(&c) = b.get(j) {
                if matches!(c, b',' | b'}' | b']' | b' ' | b'\t' | b'\n' | b'\r') {
                    break;
                }
                j += 1;
            }
            j.max(i + 1)
        }
        None => b.len(),
    }
}

/// In the object at `open`, the offsets of member `key`'s key and of its value.
fn find_member(b: &[u8], open: usize, key: &str) -> Option<(usize, usize)> {
    let mut i = skip_ws(b, open + 1);
    while b.get(i) == Some(&b'"') {
        let key_at = i;
        let key_end = skip_string(b, i);
        let raw = std::str::from_utf8(b.get(i..key_end)?).ok()?;
        // Keys are compared decoded, so an escaped spelling still matches.
        let this: Option<String> = serde_json::from_str(raw).ok();
        i = skip_ws(b, key_end);
        if b.get(i) != Some(&b':') {
            return None;
        }
        let value_at = skip_ws(b, i + 1);
        if this.as_deref() == Some(key) {
            return Some((key_at, value_at));
        }
        i = skip_ws(b, skip_value(b, value_at));
        if b.get(i) != Some(&b',') {
            return None;
        }
        i = skip_ws(b, i + 1);
    }
    None
}

/// In the array at `open`, the offset of element `n`.
fn find_element(b: &[u8], open: usize, n: usize) -> Option<usize> {
    let mut i = skip_ws(b, open + 1);
    if b.get(i) == Some(&b']') {
        return None;
    }
    for _ in 0..n {
        i = skip_ws(b, skip_value(b, i));
        if b.get(i) != Some(&b',') {
            return None;
        }
        i = skip_ws(b, i + 1);
    }
    (i < b.len()).then_some(i)
}

#[cfg(test)]
mod tests {
    use super::*;

    const TEXT: &str = "{\n  \"a\": {\"b\": [1, {\"c\": \"x]}\"}, [2]]},\n  \"d\\u0065\": 3\n}";

    fn at(path: &str) -> (usize, usize) {
        line_col(TEXT, locate(TEXT, &JsonPath::parse(path).unwrap()))
    }

    #[test]
    fn a_member_points_at_its_key_and_an_element_at_its_value() {
        assert_eq!(at("a"), (2, 3));
        assert_eq!(at("a.b"), (2, 9));
        assert_eq!(at("a.b[0]"), (2, 15));
        assert_eq!(at("a.b[1].c"), (2, 19));
        // The bracket inside the string "x]}" does not end the object.
        assert_eq!(at("a.b[2]"), (2, 32));
        // An escaped key ("de" spelled d\u0065) still matches.
        assert_eq!(at("de"), (3, 3));
    }

    #[test]
    fn a_path_that_leads_nowhere_gives_the_deepest_part_found() {
        assert_eq!(at("a.b[7]"), (2, 9));
        assert_eq!(at("a.zz"), (2, 3));
        assert_eq!(at("zz"), (1, 1));
        assert_eq!(line_col(TEXT, locate(TEXT, &JsonPath::default())), (1, 1));
    }

    #[test]
    fn the_path_at_a_place_is_the_deepest_field_holding_it() {
        let path_at_lc = |l, c| path_at(TEXT, offset_of(TEXT, l, c)).to_string();
        assert_eq!(path_at_lc(2, 3), "a");
        assert_eq!(path_at_lc(2, 16), "a.b");
        assert_eq!(path_at_lc(2, 25), "a.b[1].c");
        assert_eq!(path_at_lc(2, 33), "a.b[2][0]");
        assert_eq!(path_at_lc(3, 14), "de");
        assert_eq!(path_at_lc(1, 1), "(top level)");
        assert_eq!(path_at_lc(99, 1), "(top level)");
        // What locate finds, path_at gives back.
        for p in ["a", "a.b[1].c", "a.b[2]", "de"] {
            let p = JsonPath::parse(p).unwrap();
            assert_eq!(path_at(TEXT, locate(TEXT, &p)), p);
        }
    }

    #[test]
    fn paths_print_as_they_parse() {
        for p in [
            "blocks[2].last",
            "limits.read_registers.rtu",
            "exceptions.illegal-count",
            "a[0][1]",
        ] {
            assert_eq!(JsonPath::parse(p).unwrap().to_string(), p);
        }
        for bad in ["register 2500", "a[", "a[x]", "", "a..b", "a[1]b"] {
            assert_eq!(JsonPath::parse(bad), None, "{bad}");
        }
    }

    #[test]
    fn any_text_and_path_is_total() {
        let texts = [
            "",
            "{",
            "[",
            "{\"a\"",
            "{\"a\":",
            "{\"a\":[",
            "\"",
            "{\"a\\",
            "]]]}}}",
            "{\"a\":1,",
            "{\"é\":{\"b\":[\"\\\"\",]}}",
        ];
        let paths = ["a", "a[0]", "a.b[3]", "b[1]", "a[0][0][0]"];
        for t in texts {
            for p in paths {
                let o = locate(t, &JsonPath::parse(p).unwrap());
                assert!(o <= t.len());
                let _ = line_col(t, o);
                let _ = path_at(t, o);
            }
            // Every prefix of every text, so a cut in the middle of anything is covered.
            for cut in 0..=t.len() {
                if let Some(s) = t.get(..cut) {
                    let _ = locate(s, &JsonPath::parse("a.b[1]").unwrap());
                    let _ = path_at(s, cut / 2);
                }
            }
        }
    }
}
