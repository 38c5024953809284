//! The expectations loader's laws on arbitrary text, for the cargo-fuzz target
//! `expectations_file` (issue 37) and the unit tests below.
//!
//! - No panic; the same text parsed twice gives the same result.
//! - A refusal is [`ExpectError::Invalid`] at a line inside the text, naming a field.
//! - Every entry loaded sits at a line of the text that holds its `[[expect]]` header.
//!
//! The suite writes expectations files only from a report (`starting_file`), not from an
//! [`Expectations`], so there is no save-and-load-back law here.

use super::{ExpectError, Expectations};

/// Parses `data` as an expectations file and checks the laws (see the module notes);
/// panics where one does not hold. For the fuzz target; any input is fine.
pub fn expectations_file(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let lines: Vec<&str> = text.split('\n').collect();
    let first = Expectations::parse(text, "fuzz.toml");
    let again = Expectations::parse(text, "fuzz.toml");
    match (&first, &again) {
        (Ok(a), Ok(b)) => assert_eq!(a, b, "the same text parsed twice differs"),
        (Err(a), Err(b)) => assert_eq!(a.to_string(), b.to_string(), "two errors differ"),
        _ => panic!("the same text parsed twice: once loaded, once refused"),
    }
    match first {
        Ok(exp) => {
            for e in &exp.entries {
                let at = e.line.checked_sub(1).and_then(|i| lines.get(i));
                assert!(
                    at.is_some_and(|l| l.contains("expect")),
                    "an entry placed at line {}, which holds no [[expect]] header: {at:?}",
                    e.line
                );
            }
        }
        Err(ExpectError::Invalid {
            line,
            field,
            problem,
            ..
        }) => {
            assert!(
                (1..=lines.len()).contains(&line),
                "an error at line {line} of a text of {} lines: {field}: {problem}",
                lines.len()
            );
            assert!(!field.is_empty(), "an error naming no field: {problem}");
        }
        Err(e @ ExpectError::Read { .. }) => panic!("parsing text cannot fail to read: {e}"),
    }
}

/// Files like those the tests and the guide use, cut anywhere and with bytes changed.
pub const FILES: [&str; 3] = [
    "[[expect]]\ncheck = \"F510.RTU.EXC.*\"\nstatus = \"DEVIATION\"\nreason = \"known: answers 02H\"\nticket = \"T-1\"\nexpires = 2030-01-01\n",
    "# comment\n[[expect]]\nsignature = \"fuzz-*\"\nnode = 3\nmode = \"ascii\"\nstatus = \"FINDING\"\nreason = \"r\"\nidentification = \"0A1B\"\n\n[[expect]]\ncheck = \"x\"\nstatus = \"OBSERVATION\"\nreason = \"y\"\n",
    "[[expect]]\ncheck = \"a\"\nstatus = \"PASS\"\n",
];

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn files_cut_and_changed_keep_the_laws() {
        for t in FILES {
            expectations_file(t.as_bytes());
            let b = t.as_bytes();
            for cut in 0..b.len() {
                expectations_file(&b[..cut]);
                let mut changed = b.to_vec();
                changed[cut] = b'"';
                expectations_file(&changed);
            }
        }
        expectations_file(b"");
        expectations_file(&[0xFF]);
        // A key of a quote alone: the error named no field (a campaign's finding).
        expectations_file(b"[[expect]]\n\" = x\n");
        match Expectations::parse("[[expect]]\n\" = x\n", "f.toml") {
            Err(ExpectError::Invalid { line, field, .. }) => {
                assert_eq!((line, field.as_str()), (2, "expect"))
            }
            other => panic!("{other:?}"),
        }
    }
}
