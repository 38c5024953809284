//! The drive models' laws: the simulated drive does what its model judges, and `model
//! lint` is deterministic and stricter than the loader.

use crate::codec::{Direction, MAX_RTU_FRAME};

/// The simulated drive of every model, in both modes, on arbitrary bytes taken as one
/// request frame (the first byte picks the model and the mode): never panics; does what
/// the model's judgement says (a reply exactly when the judgement expects one, none for
/// silence); every transmission is a valid frame of the mode, from the drive's node (or
/// from 00H only for a broadcast, which is never answered).
pub fn drive(data: &[u8]) {
    use std::sync::{Arc, OnceLock};
    static MODELS: OnceLock<Vec<Arc<crate::model::DriveModel>>> = OnceLock::new();
    let models = MODELS.get_or_init(|| {
        crate::model::MODELS
            .iter()
            .map(|m| Arc::new(crate::model::DriveModel::builtin(m).expect("built-in model")))
            .collect()
    });
    let Some((&sel, frame)) = data.split_first() else {
        return;
    };
    let model = &models[usize::from(sel & 0x7F) % models.len()];
    let mode = if sel & 0x80 == 0 {
        crate::codec::Mode::Rtu
    } else {
        crate::codec::Mode::Ascii
    };
    let mut d = crate::sim::Drive::new(model.clone(), 1, std::time::Duration::ZERO);
    let out = d.handle(mode, frame, std::time::Instant::now());
    assert_eq!(out.judgement, model.judge(1, mode, frame));
    assert_eq!(out.sends.len(), usize::from(out.judgement.expect.replies()));
    let mut scratch = [0u8; MAX_RTU_FRAME];
    for s in &out.sends {
        let reply = crate::codec::decode(mode, &s.bytes, Direction::Response, &mut scratch)
            .expect("the drive's reply is a valid frame");
        assert_eq!(reply.address, 1, "the reply comes from the drive's node");
    }
}

/// `model lint` on arbitrary text: it never panics; the same text gives the same
/// findings; every finding's line and column lie inside the text; and a text lint finds no
/// error in loads (lint is the stricter: it also refuses what the loader lets through, such
/// as a limit beyond the Modbus specification).
pub fn model_lint(data: &[u8]) {
    use crate::model::{lint, DriveModel};
    let Ok(text) = std::str::from_utf8(data) else {
        return;
    };
    let findings = lint::lint("fuzz.json", text);
    assert_eq!(
        findings,
        lint::lint("fuzz.json", text),
        "lint is not deterministic"
    );
    let lines = text.split('\n').count();
    for f in &findings {
        assert!(
            (1..=lines).contains(&f.line) && f.column >= 1,
            "{f} lies outside the text ({lines} lines)"
        );
    }
    if !lint::has_errors(&findings) {
        if let Err(e) = DriveModel::from_json_unlinted("fuzz.json", text) {
            panic!("lint found no error, the loader refuses it: {e}");
        }
    }
}
