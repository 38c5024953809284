//! Liveness: a silent line proves nothing by itself.
//!
//! A device that is unplugged, frozen, at another address or at another baud rate is
//! silent, and silence is exactly what the broadcast, other-address and bad-checksum
//! checks expect. So silence is never taken on its own:
//!
//! - before the first check of a mode, a **preflight** read that the model says must be
//!   answered; no answer ends the run at once (exit 2) with what was tried and what to try;
//! - after **every** exchange that brought nothing back (whether silence was expected or a
//!   reply was), a **liveness probe** (the same read, with at least one resend); silence
//!   counts as the device's answer only when that probe is answered;
//! - when the probe is not answered either, the device has stopped answering: the check
//!   ends as ERROR ([`RunError::DeviceLost`]), every remaining check is ERROR, and the
//!   restore first asks whether the device is back.

use std::time::Duration;

use super::master::{EchoMode, Exchange};
use super::{Ctx, ExchangeRecord, RunError, Verdict};
use crate::codec::hex::Hex;
use crate::codec::pdu::Pdu;
use crate::codec::Mode;
use crate::judge;
use crate::model::{DriveModel, Expectation, Role};

/// The register a liveness probe reads: the status register, or the identification
/// register, or the first register of the map; one the model says a read of is answered
/// with data.
pub fn liveness_register(model: &DriveModel, address: u8, mode: Mode) -> Option<u16> {
    let candidates = [
        model.register_with_role(Role::Status),
        model.register_with_role(Role::Identification),
    ]
    .into_iter()
    .flatten()
    .chain(model.registers().map(|(r, _)| r));
    for r in candidates {
        let frame = crate::codec::pdu::Message {
            address,
            pdu: Pdu::ReadRequest { start: r, count: 1 },
        }
        .to_frame_vec(mode)
        .ok()?;
        if matches!(
            model.judge(address, mode, &frame).expect,
            Expectation::Read(_)
        ) {
            return Some(r);
        }
    }
    None
}

impl Ctx<'_> {
    /// Sends `frame` and collects the answer. Where nothing comes back, a liveness probe
    /// follows: the second value says it was answered; if it was not, the device has
    /// stopped answering and the run cannot judge anything more.
    pub fn exchange(
        &mut self,
        frame: &[u8],
        expect_reply: bool,
    ) -> Result<(Exchange, bool), RunError> {
        if let Some(why) = &self.lost {
            return Err(RunError::DeviceLost(why.clone()));
        }
        let mut late = 0;
        loop {
            let ex = self.master.exchange(frame, expect_reply)?;
            if !ex.after_echo().is_empty() {
                self.answered_in = Some(self.current.clone());
                return Ok((ex, false));
            }
            let stray = self.master.stray();
            let (alive, extra, answer_before) = match self.liveness_probe()? {
                None => (true, false, false),
                Some(p) => (
                    !p.after_echo().is_empty(),
                    !p.leading.is_empty() || !p.trailing.is_empty(),
                    // The answer to a frame for another node cannot be the probe's,
                    // wherever it is; one like the probe's only before it.
                    starts_an_answer(self.mode, frame, &p.leading)
                        || (address_of(self.mode, frame) != Some(self.opts.address)
                            && starts_an_answer(self.mode, frame, p.after_echo())),
                ),
            };
            // On a pseudo-terminal the other end is a program on this host, and a reply
            // the host delayed past the timeout is not the device's silence (issue 24: "no
            // reply within 500 ms" with every core busy, once the liveness probe was
            // answered). The late reply turns up before the probe goes, or is taken for
            // the probe's answer, whose own then follows: bytes found waiting either way.
            // Sent again; where it is late every time, the check is an ERROR.
            let on_pty = self.link_kind() == crate::transport::LinkKind::Pty;
            let came_late = alive && expect_reply && on_pty && {
                let settled = self.settle_late_answers()?;
                extra || settled > 0 || self.master.stray() > stray
            };
            if came_late {
                late += 1;
                if late < LATE_ON_A_PTY {
                    continue;
                }
                return Err(RunError::HostStalled(
                    crate::transport::TransportError::LateOnHost {
                        link: self.link(),
                        request: Hex(&frame[..frame.len().min(64)]).to_string(),
                        times: late,
                        timeout_ms: u64::try_from(self.opts.timing.timeout.as_millis())
                            .unwrap_or(u64::MAX),
                    },
                ));
            }
            // Where silence was due, an answer that turns up only after the silence
            // window (found waiting before the probe, or the start of an answer to this
            // request before the probe's own) is the other end's answer all the same,
            // which a busy host delayed (issue 24: answer-every-address missed with every
            // core busy). On a pseudo-terminal the request is sent once more and listened
            // to for the whole timeout; what comes then is judged.
            if alive && !expect_reply && on_pty && (answer_before || self.master.stray() > stray) {
                self.settle_late_answers()?;
                let ex = self
                    .master
                    .exchange_listening(frame, self.opts.timing.timeout)?;
                if !ex.after_echo().is_empty() {
                    self.answered_in = Some(self.current.clone());
                    return Ok((ex, false));
                }
                if self.liveness()? {
                    return Ok((ex, true));
                }
                break;
            }
            if alive {
                return Ok((ex, true));
            }
            break;
        }
        let why = format!(
            "the device stopped answering in {}: no byte came back to {} ({}) nor to {} liveness probe(s) (a read of {}); {}",
            self.current,
            judge::show(self.mode, frame),
            if expect_reply { "a reply was due" } else { "silence was due, so it had to be proven" },
            self.liveness_attempts() + 1,
            self.liveness_what(),
            match &self.answered_in {
                Some(c) => format!("the last check it answered was {c}"),
                None => "it answered nothing in this mode".to_string(),
            }
        );
        self.lost = Some(why.clone());
        Err(RunError::DeviceLost(why))
    }

    /// On a pseudo-terminal, after an answer came late: waits until the line has been
    /// quiet for a silence window, dropping what comes (the answers to earlier sends of
    /// the request or of a probe, which a busy host delayed), so that none is taken for
    /// the next exchange's reply or found after it ([`super::master::Master::settle`]).
    /// How many bytes were dropped.
    fn settle_late_answers(&mut self) -> Result<usize, RunError> {
        let quiet = self.master.silence_window();
        Ok(self.master.settle(quiet, self.opts.timing.timeout)?)
    }

    fn liveness_attempts(&self) -> u32 {
        self.opts.timing.retries.max(1)
    }

    fn liveness_frame(&self) -> Option<Vec<u8>> {
        let r = liveness_register(self.model, self.opts.address, self.mode)?;
        Some(self.frame(Pdu::ReadRequest { start: r, count: 1 }))
    }

    fn liveness_what(&self) -> String {
        match liveness_register(self.model, self.opts.address, self.mode) {
            Some(r) => format!("{r:04X}H"),
            None => "no register".to_string(),
        }
    }

    /// One liveness probe (with at least one resend): whether the device sent anything
    /// back. A model without any readable register has no probe: the device counts as
    /// alive (the preflight says so).
    pub fn liveness(&mut self) -> Result<bool, RunError> {
        Ok(self
            .liveness_probe()?
            .is_none_or(|ex| !ex.after_echo().is_empty()))
    }

    /// [`Ctx::liveness`], with the probe's exchange (None: the model has no probe).
    fn liveness_probe(&mut self) -> Result<Option<Exchange>, RunError> {
        let Some(frame) = self.liveness_frame() else {
            return Ok(None);
        };
        self.liveness_probes += 1;
        let ex = self
            .master
            .exchange_retrying(&frame, true, self.liveness_attempts())?;
        Ok(Some(ex))
    }

    /// The preflight: a read the model says must be answered. Its verdict is PASS, or
    /// ERROR with what was tried and what to try, in which case [`Ctx::lost`] is set and
    /// the run ends.
    pub fn preflight(&mut self) -> Result<Verdict, RunError> {
        let Some(frame) = self.liveness_frame() else {
            return Ok(Verdict {
                pass_summary: "the model has no register a read of is answered; no preflight"
                    .into(),
                ..Verdict::default()
            });
        };
        let mut ex = self.master.exchange(&frame, true)?;
        let mut sends = self.opts.timing.retries.saturating_add(1);
        // On a pseudo-terminal the other end is a program on this host (the simulator,
        // in this process or another), which a busy host can delay past the timeout: it
        // is not dead for that (issue 24: "no answer to the preflight" from the
        // in-process simulator with every core busy). Sent again, as a check's request
        // is, before the run is stopped; an answer late for an earlier send is an answer
        // all the same, and the one that may still be on its way is waited for and
        // dropped, so that it is not taken for the next check's reply.
        if self.link_kind() == crate::transport::LinkKind::Pty {
            let mut late = 1;
            while ex.after_echo().is_empty() && late < LATE_ON_A_PTY {
                late += 1;
                ex = self.master.exchange(&frame, true)?;
                sends = sends.saturating_add(self.opts.timing.retries.saturating_add(1));
            }
            if late > 1 && !ex.after_echo().is_empty() {
                self.settle_late_answers()?;
            }
        }
        let record = ExchangeRecord {
            request: ex.request.clone(),
            expected: None,
            received: ex.raw.clone(),
            reply: ex.reply.clone(),
            predicted: "a normal 03H reply".into(),
            actual: match &ex.reply {
                Some(r) => judge::describe_reply(self.mode, r),
                None if ex.after_echo().is_empty() && !ex.link_notes.is_empty() => {
                    format!("{}: no reply", ex.link_notes.join("; "))
                }
                None if ex.after_echo().is_empty() => "no reply".into(),
                None => judge::explain_invalid(self.mode, ex.after_echo()),
            },
            latency: ex.first_byte,
        };
        let echo = match (self.opts.echo, ex.echo) {
            (EchoMode::On, false) if ex.reply.is_some() => {
                let why = format!(
                    "--echo on, but the preflight request {} did not come back before the reply: this adapter does not echo; use --echo auto or --echo off",
                    judge::show(self.mode, &frame)
                );
                self.lost = Some(why.clone());
                return Ok(Verdict {
                    exchanges: vec![record],
                    ..Verdict::error(why)
                });
            }
            (_, true) => "the line echoes every request (a 2-wire adapter that hears itself); the echo is stripped and the reply awaited for the whole response window",
            (_, false) => "no local echo",
        };
        let latency = ex
            .first_byte
            .map(|t| format!(" in {:.1} ms", t.as_secs_f64() * 1000.0))
            .unwrap_or_default();
        let answer = match &ex.reply {
            Some(reply) => Some(judge::describe_reply(self.mode, reply)),
            // Not a valid reply, but the device's own start of one (its address and the
            // function or its exception): a device that answers badly is alive, and the
            // checks will say what is wrong with its answers.
            None if starts_an_answer(self.mode, &frame, ex.after_echo()) => Some(format!(
                "an invalid answer: {}",
                judge::explain_invalid(self.mode, ex.after_echo())
            )),
            None => None,
        };
        if let Some(answer) = answer {
            self.answered_in = Some(self.current.clone());
            return Ok(Verdict {
                exchanges: vec![record],
                pass_summary: format!(
                    "node {:02X} answered{latency}: {answer}; {echo}",
                    self.opts.address
                ),
                ..Verdict::default()
            });
        }
        let why = self.no_answer_advice(&frame, &ex, sends);
        self.lost = Some(why.clone());
        Ok(Verdict {
            exchanges: vec![record],
            ..Verdict::error(why)
        })
    }

    /// What the preflight tried, what came back, and what to try.
    fn no_answer_advice(&self, frame: &[u8], ex: &Exchange, sends: u32) -> String {
        let line = match self.line_timing() {
            Some(l) => l.to_string(),
            None => String::new(),
        };
        let tried = format!(
            "no answer from node {:02X}: sent {} (read {}) {} time(s) in {} over {}{}, waiting {} ms each",
            self.opts.address,
            judge::show(self.mode, frame),
            self.liveness_what(),
            sends,
            self.mode.to_string().to_uppercase(),
            self.link(),
            if line.is_empty() { String::new() } else { format!(" ({line})") },
            self.opts.timing.timeout.as_millis()
        );
        let rx = ex.after_echo();
        let got = if ex.raw.is_empty() && !ex.link_notes.is_empty() {
            format!(
                "nothing came back from the device: {}",
                ex.link_notes.join("; ")
            )
        } else if ex.raw.is_empty() {
            "nothing came back".to_string()
        } else if rx.is_empty() {
            "only the echo of the request came back (the adapter echoes; the drive did not answer)"
                .to_string()
        } else {
            format!(
                "{} bytes came back that are not a reply: {} (bytes that are no frame usually mean another baud rate or parity, or the other mode)",
                rx.len(),
                Hex(&rx[..rx.len().min(64)])
            )
        };
        let other = match self.mode {
            Mode::Rtu => "--mode ascii",
            Mode::Ascii => "--mode rtu",
        };
        if self.link_kind() == crate::transport::LinkKind::Mbap {
            return format!(
                "{tried}; {got}. Check: the unit id (--unit; which unit id the gateway routes to which serial node, and whether it rewrites it), the node address (-a), the gateway's serial settings (baud rate, parity, stop bits, RTU: set in the gateway, not here), a longer --timeout (the gateway's own serial timeout may be longer than this one), the wiring behind the gateway, and that the drive is powered"
            );
        }
        format!(
            "{tried}; {got}. Check: the node address (-a; the drive's communication address parameter), the baud rate (-b), parity (-P none|even|odd), data and stop bits (-d, -s), the mode ({other}), a longer --timeout, the wiring (A/B swapped, no common ground, termination), that the drive is powered, and that the adapter drives the RS-485 direction itself"
        )
    }
}

/// The address `frame` is for.
fn address_of(mode: Mode, frame: &[u8]) -> Option<u8> {
    crate::codec::frame_parts(mode, frame)
        .ok()
        .and_then(|p| p.body.first().copied())
}

/// Whether `rx` holds the start of an answer to `request`: its address and function (or
/// the function's exception) in RTU, a ':' and those in ASCII.
fn starts_an_answer(mode: Mode, request: &[u8], rx: &[u8]) -> bool {
    let Ok(parts) = crate::codec::frame_parts(mode, request) else {
        return false;
    };
    let (Some(&address), Some(&function)) = (parts.body.first(), parts.body.get(1)) else {
        return false;
    };
    let heads: Vec<Vec<u8>> = [function, function | 0x80]
        .iter()
        .map(|&f| match mode {
            Mode::Rtu => vec![address, f],
            Mode::Ascii => format!(":{address:02X}{f:02X}").into_bytes(),
        })
        .collect();
    heads
        .iter()
        .any(|h| rx.windows(h.len()).any(|w| w.eq_ignore_ascii_case(h)))
}

/// How many times a request whose answer came only after the timeout on a
/// pseudo-terminal is sent before the check is an ERROR ([`Ctx::exchange`]).
pub const LATE_ON_A_PTY: u32 = 3;

/// Statuses that a lost device leaves to the checks that did not run.
pub fn not_run(lost_in: &str) -> String {
    format!("not run: the device stopped answering in {lost_in}")
}

/// How long after a restart of communications (08H 0001H) to wait before probing.
pub const RESTART_SETTLE: Duration = Duration::from_secs(2);
