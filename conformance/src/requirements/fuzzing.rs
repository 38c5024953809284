//! The requirements catalogue loader's laws on arbitrary text, for the cargo-fuzz target
//! `requirements_file` (issue 37) and the unit tests below.
//!
//! - No panic.
//! - A refusal is typed: a parse error at a line and column inside the text, or a rule
//!   broken by a requirement whose id the text holds (or by the document).
//! - What loads, saved again (serde writes the same fields), loads back equal.

use super::{Catalogue, RequirementsError};

/// Parses `data` as a catalogue and checks the laws (see the module notes); panics where
/// one does not hold. For the fuzz target; any input is fine.
pub fn requirements_file(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let lines = text.split('\n').count();
    match Catalogue::parse("fuzz.json", text) {
        Ok(cat) => {
            let saved = serde_json::to_string_pretty(&cat).expect("a catalogue serializes");
            match Catalogue::parse("saved.json", &saved) {
                Ok(back) => assert_eq!(back, cat, "a catalogue saved again loads otherwise"),
                Err(e) => panic!("a catalogue that loads, saved again, is refused: {e}"),
            }
        }
        Err(RequirementsError::Parse {
            line,
            column,
            message,
            ..
        }) => assert!(
            (1..=lines).contains(&line) || (line == 0 && column == 0),
            "a parse error at line {line}, column {column} of a text of {lines} lines: {message}"
        ),
        Err(RequirementsError::Invalid {
            id, field, message, ..
        }) => assert!(
            id == "document" || text.contains(id.as_str()),
            "a rule broken by {id:?}, which the text does not hold: {field}: {message}"
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn built_in_catalogues_cut_and_changed_keep_the_laws() {
        for (_, text) in Catalogue::builtin_texts() {
            requirements_file(text.as_bytes());
            let b = text.as_bytes();
            for cut in (0..b.len()).step_by(b.len() / 40 + 1) {
                requirements_file(&b[..cut]);
                let mut changed = b.to_vec();
                changed[cut] = b'0';
                requirements_file(&changed);
            }
        }
        requirements_file(b"");
        requirements_file(b"{\"schema_version\": 1}");
    }
}
