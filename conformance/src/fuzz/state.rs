//! What a campaign knows of the device between cases, and what one case found, shared by
//! every way of sending a case (careful, brisk, timed, minimizing): below them all, so
//! that each can use it without reaching up into the campaign.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use super::Kind;
use crate::codec::{frame_parts, Mode};
use crate::judge::Severity;
use crate::runner::{Ctx, ExchangeRecord, RunError};

/// What the device's state is known to be.
#[derive(Debug, Default)]
pub struct State {
    /// Values the device returned for registers (what a preserving write may carry).
    pub known: BTreeMap<u16, u16>,
    /// Values the device confirmed writing, for plain parameters: a read must return them.
    pub written: BTreeMap<u16, u16>,
    /// Timing cases whose difference did not show again on replay (host scheduling).
    pub timing_unconfirmed: u64,
}

/// One difference, before grouping.
#[derive(Debug, Clone)]
pub struct Observed {
    /// Kind.
    pub kind: Kind,
    /// Severity.
    pub severity: Severity,
    /// Words.
    pub text: String,
    /// The exchange.
    pub exchange: Option<ExchangeRecord>,
    /// For a wrong value: the register.
    pub register: Option<u16>,
    /// For a hang found without losing the device: how long it was gone.
    pub recovery: Option<Option<Duration>>,
    /// The field of the difference (see [`super::signature`]).
    pub field: String,
}

/// Waits for a device that stopped answering: re-probes with growing pauses until it
/// answers or `wait` has passed. How long it took, or None.
pub fn recover(ctx: &mut Ctx<'_>, wait: Duration) -> Result<Option<Duration>, RunError> {
    let t0 = Instant::now();
    let mut pause = Duration::from_millis(250);
    loop {
        ctx.lost = None;
        match ctx.liveness() {
            Ok(true) => return Ok(Some(t0.elapsed())),
            // A probe this host could not send whole says nothing: probe again.
            Ok(false) | Err(RunError::HostStalled(_)) => {}
            Err(e) => return Err(e),
        }
        if t0.elapsed() >= wait {
            return Ok(None);
        }
        std::thread::sleep(pause.min(wait.saturating_sub(t0.elapsed())));
        pause = (pause * 2).min(Duration::from_secs(2));
    }
}

/// The function code of a frame (its second byte, leniently in ASCII).
pub fn function_of(mode: Mode, frame: &[u8]) -> u8 {
    match frame_parts(mode, frame) {
        Ok(p) => p.body.get(1).copied().unwrap_or(0),
        Err(_) => match mode {
            Mode::Rtu => frame.get(1).copied().unwrap_or(0),
            Mode::Ascii => frame
                .get(3..5)
                .and_then(|h| std::str::from_utf8(h).ok())
                .and_then(|h| u8::from_str_radix(h, 16).ok())
                .unwrap_or(0),
        },
    }
}
