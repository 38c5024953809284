//! The description loader's laws on arbitrary text, for the cargo-fuzz target
//! `model_file` (issue 37) and the unit tests below: the path `--model-file` takes
//! ([`DriveModel::from_json`]: lint, then the loader), and the description saved again.
//!
//! - No panic, and only the loader's own errors: lint's findings, each at a line and
//!   column inside the text; a refusal the loader makes after lint found no error is a
//!   law broken (lint and the loader disagree).
//! - What loads, saved again (the file's fields written by serde, as `model export` and
//!   `model learn` write them), loads back to the same model, and saving that gives the
//!   same text (a fixed point).

use super::{DriveModel, ModelError, ModelFile};

/// The model as loaded, without where it came from (the hash of its text differs once it
/// is saved again).
fn shape(m: &DriveModel) -> String {
    let mut m = m.clone();
    m.source = super::Source::default();
    format!("{m:?}")
}

/// Loads `data` as a description and checks the laws (see the module notes); panics
/// where one does not hold. For the fuzz target; any input is fine.
pub fn model_file(data: &[u8]) {
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let lines = text.split('\n').count();
    let model = match DriveModel::from_json("fuzz.json", text) {
        Ok(m) => m,
        Err(ModelError::Lint { findings, .. }) => {
            assert!(
                super::lint::has_errors(&findings),
                "refused by lint without an error: {findings:?}"
            );
            for f in &findings {
                assert!(
                    (1..=lines).contains(&f.line) && f.column >= 1,
                    "{f} lies outside the text ({lines} lines)"
                );
            }
            return;
        }
        Err(e) => panic!("lint found no error, the loader refuses it otherwise: {e}"),
    };
    let file: ModelFile =
        serde_json::from_str(text).expect("a description that loads is a model file");
    let saved = serde_json::to_string_pretty(&file).expect("a model file serializes");
    let back = match DriveModel::from_json("saved.json", &saved) {
        Ok(m) => m,
        Err(e) => panic!("a description that loads, saved again, is refused: {e}\n{saved}"),
    };
    assert_eq!(
        shape(&model),
        shape(&back),
        "a description saved again loads to another model"
    );
    let again: ModelFile = serde_json::from_str(&saved).expect("saved text is a model file");
    assert_eq!(
        serde_json::to_string_pretty(&again).expect("a model file serializes"),
        saved,
        "saving a saved description changes it"
    );
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every built-in description and every example under vectors/models/examples, cut
    /// anywhere and with bytes changed, keeps the laws.
    #[test]
    fn descriptions_cut_and_changed_keep_the_laws() {
        let mut texts: Vec<String> = DriveModel::builtin_files()
            .iter()
            .map(|(_, t)| t.to_string())
            .collect();
        let examples = concat!(env!("CARGO_MANIFEST_DIR"), "/../vectors/models/examples");
        for e in std::fs::read_dir(examples).unwrap() {
            let p = e.unwrap().path();
            if p.extension().is_some_and(|x| x == "json") {
                texts.push(std::fs::read_to_string(p).unwrap());
            }
        }
        assert!(texts.len() >= 6, "{} descriptions", texts.len());
        for t in &texts {
            model_file(t.as_bytes());
            let b = t.as_bytes();
            for cut in (0..b.len()).step_by(b.len() / 7 + 1) {
                model_file(&b[..cut]);
                let mut changed = b.to_vec();
                changed[cut] = b'9';
                model_file(&changed);
            }
        }
        model_file(b"");
        model_file(b"{}");
        model_file(&[0xFF, 0xFE]);
    }
}
