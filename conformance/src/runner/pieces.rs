//! Exchanges that are not one whole request: a request sent in pieces with an exact gap
//! between them (the fuzzer's timing damage), and the raw link for traffic the master
//! does not own (the storm test's frames for other nodes). Both go through the context,
//! so the liveness probes, the echo handling and the journal stay the runner's.

use std::time::{Duration, Instant};

use super::{Ctx, Exchange, RunError};
use crate::judge;
use crate::transport::Transport;

impl Ctx<'_> {
    /// Sends `frame` cut at `cuts` (byte positions) with `gap` of silence between the
    /// pieces and collects the answer, as [`Ctx::exchange`] does (a liveness probe after
    /// an exchange that brought nothing back). A send whose gaps the host moved by more
    /// than `tolerance`, or that the host broke inside a piece, is sent again before
    /// anything is judged. Returns the exchange, whether a liveness probe proved the
    /// device alive after it, and the gaps as the last send left this host.
    pub fn exchange_split(
        &mut self,
        frame: &[u8],
        cuts: &[usize],
        gap: Duration,
        tolerance: Duration,
        expect_reply: bool,
    ) -> Result<(Exchange, bool, Vec<Duration>), RunError> {
        if let Some(why) = &self.lost {
            return Err(RunError::DeviceLost(why.clone()));
        }
        let (ex, sent) = self
            .master
            .exchange_split(frame, cuts, gap, tolerance, expect_reply)?;
        if !ex.after_echo().is_empty() {
            self.answered_in = Some(self.current.clone());
            return Ok((ex, false, sent));
        }
        if self.liveness()? {
            return Ok((ex, true, sent));
        }
        let why = format!(
            "the device stopped answering in {}: no byte came back to {} sent in pieces with {} us between them, nor to the liveness probes",
            self.current,
            judge::show(self.mode, frame),
            gap.as_micros()
        );
        self.lost = Some(why.clone());
        Err(RunError::DeviceLost(why))
    }

    /// Requests sent again because the host broke them (or moved their gaps) while
    /// pacing them.
    pub fn broken_requests(&self) -> u64 {
        self.master.broken_requests()
    }

    /// The link itself, for frames the master does not exchange (the storm test). The
    /// next exchange keeps t3.5 after `quiet_since`.
    pub fn transport_mut(&mut self, quiet_since: Instant) -> &mut dyn Transport {
        self.master.transport_mut(quiet_since)
    }
}
