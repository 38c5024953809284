//! What checking one vector gives, and the body a frame vector stands for: shared by the
//! checks of frames ([`super::verify`]) and of the manuals' C listings
//! ([`super::listing`]).

use super::model::*;
use crate::codec::{frame_parts, Mode};

/// The outcome of checking one vector.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct VectorReport {
    /// Vector id.
    pub id: String,
    /// Declared verdict.
    pub verdict: Verdict,
    /// Declared flags.
    pub flags: Vec<String>,
    /// Flags the codec observed.
    pub observed: Vec<String>,
    /// What does not hold; empty when the vector behaves as its verdict says.
    pub problems: Vec<String>,
}

impl VectorReport {
    /// Whether the vector behaves as its verdict and flags say.
    pub fn passed(&self) -> bool {
        self.problems.is_empty()
    }
}

/// The body (address, function, data) a frame vector stands for: from `printed` when its
/// body bytes are all known, else from `corrected`.
pub(crate) fn effective_body(fv: &FrameVector) -> Option<Vec<u8>> {
    let mode: Mode = fv.mode.into();
    let printed = parse_printed(&fv.printed).ok()?;
    if let Some(known) = printed.iter().copied().collect::<Option<Vec<u8>>>() {
        if let Ok(p) = frame_parts(mode, &known) {
            return Some(p.body);
        }
    }
    // Blanks only in the checksum: the body is still what was printed.
    let body_region = match mode {
        Mode::Rtu => printed.len().checked_sub(2).map(|e| 0..e),
        Mode::Ascii => printed.len().checked_sub(4).map(|e| 1..e),
    }?;
    if let Some(region) = printed[body_region]
        .iter()
        .copied()
        .collect::<Option<Vec<u8>>>()
    {
        match mode {
            Mode::Rtu => return Some(region),
            Mode::Ascii => {
                if region.len() % 2 == 0 {
                    let text = String::from_utf8(region).ok()?;
                    if let Ok(b) = crate::codec::hex::parse_hex(&text) {
                        if b.len() * 2 == text.len() {
                            return Some(b);
                        }
                    }
                }
            }
        }
    }
    let corrected = parse_known(fv.corrected.as_deref()?).ok()?;
    frame_parts(mode, &corrected).ok().map(|p| p.body)
}
