//! The runner's Modbus master: sends one request, collects everything the line carries
//! back with arrival times, and finds the reply in it.
//!
//! The master keeps the raw bytes: an echo of the request, garbage before the reply, a
//! truncated or corrupt reply and trailing bytes are all evidence a check reports on, so
//! nothing is thrown away. Collection ends when the line has been quiet for the quiet
//! window after some bytes arrived (a reply comes in one burst), or at the timeout.

use std::time::{Duration, Instant};

use crate::codec::crc::crc16;
use crate::codec::deframe::rtu_frame_len;
use crate::codec::pdu::function;
use crate::codec::pdu::Direction;
use crate::codec::timing::later;
use crate::codec::{ascii, Mode, MAX_ASCII_FRAME};
use crate::judge::{Conversation, Timing};
use crate::transport::{sleep_until, LinkKind, Transport, TransportError};

/// Bytes that arrived together, with their arrival time after the end of the request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Chunk {
    /// Arrival time, after the request was sent.
    pub at: Duration,
    /// The bytes.
    pub bytes: Vec<u8>,
}

/// One request and everything that came back.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Exchange {
    /// The request as sent.
    pub request: Vec<u8>,
    /// Everything received, in order.
    pub raw: Vec<u8>,
    /// The same bytes with their arrival times.
    pub chunks: Vec<Chunk>,
    /// Whether the received bytes start with an exact copy of the request.
    pub echo: bool,
    /// Bytes between the echo (if any) and the reply frame.
    pub leading: Vec<u8>,
    /// The reply frame (valid checksum), if one was found.
    pub reply: Option<Vec<u8>>,
    /// Bytes after the reply frame.
    pub trailing: Vec<u8>,
    /// Time from the end of the request to the first byte after the echo.
    pub first_byte: Option<Duration>,
    /// How long the master listened.
    pub listened: Duration,
    /// Resends after a timeout without any byte.
    pub retries: u32,
    /// What the link itself said meanwhile (a Modbus TCP gateway's exception 0AH/0BH in
    /// place of the device's reply, which is silence on the serial line; a late reply
    /// dropped): see [`Transport::take_notes`].
    pub link_notes: Vec<String>,
}

impl Exchange {
    /// The exchange as the judge takes it: node `node`'s conversation in `mode`, with
    /// times since the end of the request (a local echo stripped).
    pub fn conversation(&self, mode: Mode, node: u8) -> Conversation<'_> {
        Conversation {
            mode,
            node,
            request: &self.request,
            received: self.after_echo(),
            leading: &self.leading,
            reply: self.reply.as_deref(),
            trailing: &self.trailing,
            timing: Timing {
                request_end: Some(Duration::ZERO),
                request_end_earliest: None,
                first_byte: self.first_byte,
                first_byte_earliest: None,
                last_byte: self.chunks.last().map(|c| c.at),
                // The runner measures gaps inside replies over the whole mode (its
                // line-timing check), where it knows whether the host made them.
                max_gap: None,
                silence_before: None,
                listened: self.listened,
            },
            retries: self.retries,
            link_notes: &self.link_notes,
        }
    }

    /// Received bytes other than an exact echo of the request.
    pub fn after_echo(&self) -> &[u8] {
        if self.echo {
            &self.raw[self.request.len()..]
        } else {
            &self.raw
        }
    }
}

/// What the master does about a local echo (a 2-wire RS-485 adapter whose receiver hears
/// its own transmission returns every request before the reply).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum EchoMode {
    /// Learn it from the first exchange whose request cannot be mistaken for its reply
    /// (an 03H or 10H request; the runner's preflight read is one), then strip it.
    #[default]
    Auto,
    /// Every request comes back first: strip it, then wait for the reply.
    On,
    /// Nothing comes back but the reply: a copy of the request is the device's.
    Off,
}

impl std::str::FromStr for EchoMode {
    type Err = String;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        match s {
            "auto" => Ok(EchoMode::Auto),
            "on" => Ok(EchoMode::On),
            "off" => Ok(EchoMode::Off),
            _ => Err(format!("unknown echo mode {s:?}: auto, on or off")),
        }
    }
}

impl std::fmt::Display for EchoMode {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            EchoMode::Auto => "auto",
            EchoMode::On => "on",
            EchoMode::Off => "off",
        })
    }
}

/// Where a mode's time went, against what the line needs: the lower bound of a run is
/// the bytes on the wire at the line's character time, t3.5 before every frame, the
/// device's measured response delays, and for every silence the device's longest
/// measured response delay (the least wait that proves no reply is coming).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct LineBudget {
    /// Requests sent (resends included) and raw sends.
    pub frames: u64,
    /// Bytes (RTU) or characters (ASCII) sent.
    pub bytes_sent: u64,
    /// Bytes or characters received.
    pub bytes_received: u64,
    /// Sum of the device's response delays (request end to reply start).
    pub response: Duration,
    /// Exchanges that ended in silence.
    pub silences: u64,
    /// Longest response delay measured.
    pub max_response: Duration,
    /// Wall time of the exchanges (waiting for the gap, sending, listening).
    pub busy: Duration,
    /// Sends this host broke as they left (it stalled while pacing them: a silence over
    /// t1.5 inside), each sent again or, the last of a request never sent whole, given up:
    /// a capture marks each ([`crate::capture::BROKEN_BY_HOST`]).
    pub broken_sends: u64,
}

impl LineBudget {
    /// The lower bound of the exchanges on `line`: what the line and the device need.
    pub fn bound(&self, line: &crate::codec::timing::LineSettings) -> Duration {
        let ct = Duration::from_micros(line.char_time_us());
        let t35 = Duration::from_micros(line.t3_5_us());
        let times = |d: Duration, n: u64| d.saturating_mul(u32::try_from(n).unwrap_or(u32::MAX));
        let wire = times(ct, self.bytes_sent.saturating_add(self.bytes_received));
        let gaps = times(t35, self.frames);
        let silences = times(self.max_response.saturating_add(ct), self.silences);
        wire.saturating_add(gaps)
            .saturating_add(self.response)
            .saturating_add(silences)
    }
}

/// How many times a request is sent when the host breaks every send of it (a stall over
/// t1.5 inside it as it left, or a gap of a split request moved past its tolerance)
/// before the exchange ends in [`TransportError::Stalled`]. A broken send is listened to
/// for a silence window only, so the attempts cost little; on a loaded host (two cores,
/// a build alongside) a long request (10H with 35 registers: 80 ms of pacing at 9600
/// baud) was broken four times in a row.
pub const MAX_BROKEN_SENDS: u32 = 8;

/// Least silence window the master derives (the device's measured response time decides
/// beyond it).
pub const SILENCE_FLOOR: Duration = Duration::from_millis(50);

/// Timing of the master.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MasterTiming {
    /// How long to wait for the first byte of a reply.
    pub timeout: Duration,
    /// How long to listen when no reply is expected; with `derive_silence`, the most.
    pub silence: Duration,
    /// Derive the silence window from the device's measured response time: twice the
    /// longest reply delay seen, plus t3.5 and 20 ms, at least [`SILENCE_FLOOR`], at most
    /// `silence` (which is used as it is until a reply has been measured).
    pub derive_silence: bool,
    /// Quiet time that ends a reply.
    pub quiet: Duration,
    /// Least time between the end of one exchange and the next request.
    pub gap: Duration,
    /// Resends after a timeout without any byte, when a reply is expected.
    pub retries: u32,
}

/// A Modbus master over a transport.
pub struct Master<T: Transport + ?Sized> {
    mode: Mode,
    timing: MasterTiming,
    last_end: Option<Instant>,
    echo_mode: EchoMode,
    /// With [`EchoMode::Auto`]: what the line has shown (None until an exchange told).
    echo_seen: Option<bool>,
    budget: LineBudget,
    broken_requests: u64,
    /// Timing damage: the request goes out in pieces (see [`Master::exchange_split`]).
    split: Option<Split>,
    /// Brisk listening (see [`Master::set_brisk`]).
    brisk: bool,
    /// Bytes found waiting before a request was sent, since the last
    /// [`Master::take_stray`]: the late end of an earlier exchange.
    stray: usize,
    /// On a pseudo-terminal: answers due to requests sent whose exchange ended without
    /// them (late ones, on a busy host), awaited before the next request
    /// ([`Master::settle`]).
    owed: usize,
    transport: Box<T>,
}

/// How [`Master::exchange_split`] sends its request: cut at `cuts` (byte positions),
/// with `gap` of silence between the pieces, which must leave this host within
/// `tolerance` of `gap` (else the request is sent again, as a broken one is).
#[derive(Debug, Clone, Default)]
struct Split {
    cuts: Vec<usize>,
    gap: Duration,
    tolerance: Duration,
    /// The gaps as the last send left this host.
    sent: Vec<Duration>,
    /// Whether one of them was off by more than the tolerance.
    drifted: bool,
}

impl<T: Transport + ?Sized> Master<T> {
    /// A master speaking `mode` over `transport`.
    pub fn new(transport: Box<T>, mode: Mode, timing: MasterTiming) -> Self {
        Master {
            mode,
            timing,
            last_end: None,
            echo_mode: EchoMode::Auto,
            echo_seen: None,
            budget: LineBudget::default(),
            broken_requests: 0,
            split: None,
            brisk: false,
            stray: 0,
            owed: 0,
            transport,
        }
    }

    /// Requests sent again because the host broke them while pacing them.
    pub fn broken_requests(&self) -> u64 {
        self.broken_requests
    }

    /// Where the time of the exchanges so far went.
    pub fn budget(&self) -> LineBudget {
        self.budget
    }

    /// The silence window: fixed, or derived from the device's measured response time.
    pub fn silence_window(&self) -> Duration {
        let cap = self.timing.silence;
        if !self.timing.derive_silence || self.budget.max_response.is_zero() {
            return cap;
        }
        let t35 = self
            .transport
            .line_timing()
            .map_or(Duration::ZERO, |l| Duration::from_micros(l.t3_5_us()));
        (self.budget.max_response.saturating_mul(2))
            .saturating_add(t35)
            .saturating_add(Duration::from_millis(20))
            .max(SILENCE_FLOOR)
            .min(cap)
    }

    /// Brisk listening, for a link without timing whose user catches late bytes: once a
    /// whole reply is in, stop at once instead of waiting a settle time for trailing
    /// bytes. Whatever comes later is not lost: it is found waiting before the next
    /// request and counted by [`Master::take_stray`], so that the exchange it belongs to
    /// can be repeated with full windows.
    pub fn set_brisk(&mut self, on: bool) {
        self.brisk = on;
    }

    /// Whether listening is brisk.
    pub fn brisk(&self) -> bool {
        self.brisk
    }

    /// Bytes that were found waiting before a request was sent (and dropped), since the
    /// last call: evidence that an earlier exchange ended before the device did.
    pub fn take_stray(&mut self) -> usize {
        std::mem::take(&mut self.stray)
    }

    /// Bytes found waiting before a request was sent since the last
    /// [`Master::take_stray`], without taking them.
    pub fn stray(&self) -> usize {
        self.stray
    }

    /// Reads what is waiting on the link (counted as stray too) and discards the rest:
    /// how many bytes were waiting.
    pub fn drain_input(&mut self) -> Result<usize, TransportError> {
        let before = self.stray;
        self.drain()?;
        Ok(self.stray - before)
    }

    /// Reads and counts what is waiting on the link, then discards the rest.
    fn drain(&mut self) -> Result<(), TransportError> {
        let mut buf = [0u8; 256];
        let mut got = Vec::new();
        // Bounded: a device that talks without end is not drained forever here.
        for _ in 0..64 {
            let n = self.transport.recv(&mut buf, Duration::ZERO)?;
            if n == 0 {
                break;
            }
            self.stray += n;
            got.extend_from_slice(&buf[..n]);
        }
        self.owed = self.owed.saturating_sub(count_frames(self.mode, &got));
        self.transport.discard_input()
    }

    /// Whether the last send was broken on the line: an RTU request the host stalled
    /// inside (a silence over t1.5 as it left: [`Transport::send_was_broken`]), which a
    /// receiver that frames by silence drops. An ASCII frame runs from ':' to CR LF and
    /// is not broken by a silence under its 1 s inter-character timeout (Modbus over
    /// Serial Line V1.02, 2.5.2.1): the receiver takes it and answers, so sending it
    /// again would leave an answer nobody waits for (issue 24: ASCII requests were
    /// reported as "could not send ... whole", and the answers to the extra sends were
    /// found before and after later replies, as deviations).
    fn send_broken(&self) -> bool {
        self.mode == Mode::Rtu && self.transport.send_was_broken()
    }

    /// Answers due that did not come in their exchange (see [`Master::settle`]).
    pub fn owed(&self) -> usize {
        self.owed
    }

    /// Waits for the answers still owed ([`Master::owed`]) as long as bytes keep coming
    /// within `wait` of each other, then until `quiet` passes without a byte, and drops
    /// what came (counted as stray): the late end of earlier exchanges. Nothing is owed
    /// afterwards. How many bytes were dropped.
    pub fn settle(&mut self, quiet: Duration, wait: Duration) -> Result<usize, TransportError> {
        let owed = self.owed;
        let mut got = Vec::new();
        let mut last = Instant::now();
        let mut buf = [0u8; 256];
        loop {
            let left = owed.saturating_sub(count_frames(self.mode, &got));
            let limit = if left > 0 { wait.max(quiet) } else { quiet };
            let waited = last.elapsed();
            // Bounded: a device that talks without end is not listened to forever here.
            if waited >= limit || got.len() > 64 * MAX_ASCII_FRAME {
                break;
            }
            let n = self
                .transport
                .recv(&mut buf, (limit - waited).min(Duration::from_millis(50)))?;
            if n > 0 {
                got.extend_from_slice(&buf[..n]);
                last = Instant::now();
            }
        }
        self.stray += got.len();
        self.owed = 0;
        self.last_end = Some(last.max(self.last_end.unwrap_or(last)));
        self.transport.discard_input()?;
        Ok(got.len())
    }

    /// Sends `request`, where no reply is expected, and listens for `window` only (zero:
    /// not at all). For a caller that proves the silence otherwise: on a link that keeps
    /// the order of frames, the reply to a request sent right after must be the next
    /// frame, and anything before it is the answer to this one.
    pub fn exchange_listening(
        &mut self,
        request: &[u8],
        window: Duration,
    ) -> Result<Exchange, TransportError> {
        self.exchange_once(request, false, 0, Some(window))
    }

    /// Sets what to do about a local echo.
    pub fn with_echo(mut self, echo: EchoMode) -> Self {
        self.echo_mode = echo;
        self
    }

    /// The echo mode configured.
    pub fn echo_mode(&self) -> EchoMode {
        self.echo_mode
    }

    /// Whether the line echoes requests: as configured, or as learnt (None while
    /// [`EchoMode::Auto`] has not seen an exchange that tells).
    pub fn echoes(&self) -> Option<bool> {
        match self.echo_mode {
            EchoMode::On => Some(true),
            EchoMode::Off => Some(false),
            EchoMode::Auto => self.echo_seen,
        }
    }

    /// The transport.
    pub fn transport(&self) -> &T {
        &self.transport
    }

    /// The transport itself, for traffic that is not an exchange of this master (the
    /// storm test's interleaved frames). The gap before the next exchange counts from
    /// `quiet_since`, when the caller last left the line.
    pub fn transport_mut(&mut self, quiet_since: Instant) -> &mut T {
        self.last_end = Some(quiet_since);
        self.transport.as_mut()
    }

    /// The mode.
    pub fn mode(&self) -> Mode {
        self.mode
    }

    /// The timing.
    pub fn timing(&self) -> MasterTiming {
        self.timing
    }

    /// Sends raw bytes that are not a request (garbage, a partial frame) and waits the gap.
    pub fn send_raw(&mut self, bytes: &[u8], pause: Duration) -> Result<(), TransportError> {
        let t0 = Instant::now();
        self.wait_gap();
        self.transport.send(bytes)?;
        std::thread::sleep(pause);
        self.last_end = Some(Instant::now());
        self.budget.frames += 1;
        self.budget.bytes_sent += bytes.len() as u64;
        self.budget.busy += t0.elapsed();
        Ok(())
    }

    /// Waits until the line has been quiet for the configured gap, and never less than
    /// t3.5 of the line where it has timing (a frame must follow 3.5 character times of
    /// silence: Modbus over Serial Line V1.02, 2.5.1.1).
    fn wait_gap(&self) {
        if let Some(t) = self.last_end {
            let t35 = self
                .transport
                .line_timing()
                .map_or(Duration::ZERO, |l| Duration::from_micros(l.t3_5_us()));
            sleep_until(later(t, self.timing.gap.max(t35)));
        }
    }

    /// Sends `request` and collects the answer. With `expect_reply`, waits up to the
    /// timeout for a first byte (resending up to `retries` times if none comes); without,
    /// listens for the silence window.
    pub fn exchange(
        &mut self,
        request: &[u8],
        expect_reply: bool,
    ) -> Result<Exchange, TransportError> {
        self.exchange_retrying(request, expect_reply, self.timing.retries)
    }

    /// [`Master::exchange`] with `max_retries` resends instead of the configured number.
    pub fn exchange_retrying(
        &mut self,
        request: &[u8],
        expect_reply: bool,
        max_retries: u32,
    ) -> Result<Exchange, TransportError> {
        let mut retries = 0;
        let mut broken = 0;
        let mut notes = Vec::new();
        loop {
            let mut ex = self.exchange_once(request, expect_reply, retries, None)?;
            // What the link said about earlier attempts stays with the exchange.
            notes.append(&mut ex.link_notes);
            ex.link_notes = notes.clone();
            // A request that left this host with a gap over t1.5 inside it (the host
            // stalled while pacing it) is not the request on the line: send it again.
            // Where every send was broken, the device never saw the request: that is an
            // error of this host, never the device's silence to judge (the exchange was
            // listened to for a silence window only, so its "no reply" means nothing).
            let drifted = self.split.as_ref().is_some_and(|s| s.drifted);
            if self.send_broken() {
                self.budget.broken_sends += 1;
            }
            if self.send_broken() || drifted {
                broken += 1;
                if broken >= MAX_BROKEN_SENDS {
                    return Err(TransportError::Stalled {
                        link: self.transport.describe(),
                        request: crate::codec::hex::Hex(&request[..request.len().min(64)])
                            .to_string(),
                        sends: broken,
                    });
                }
                self.broken_requests += 1;
                continue;
            }
            if expect_reply && ex.after_echo().is_empty() && retries < max_retries {
                retries += 1;
                continue;
            }
            return Ok(ex);
        }
    }

    fn exchange_once(
        &mut self,
        request: &[u8],
        expect_reply: bool,
        retries: u32,
        window: Option<Duration>,
    ) -> Result<Exchange, TransportError> {
        let t0 = Instant::now();
        // On a pseudo-terminal the other end is a program on this host, which a busy
        // host delays: an answer an earlier exchange waited for in vain may still come.
        // It is awaited (and dropped) before this request goes, so that it is not taken
        // for this request's reply or found after it (issue 24). The fuzzer's brisk
        // listening catches late bytes its own way.
        if self.owed > 0 && !self.brisk && self.transport.kind() == LinkKind::Pty {
            self.settle(self.silence_window(), self.timing.timeout)?;
        }
        self.wait_gap();
        self.drain()?;
        self.send_request(request)?;
        let sent = self.transport.sent_at().unwrap_or_else(Instant::now);
        // A request the host stalled inside (a gap over t1.5 as it left) is not the request
        // on the line: a receiver that frames by silence drops it, and it is sent again
        // ([`Master::exchange_retrying`]), so listen only as long as for a silence, not
        // the whole timeout.
        let wait = match window {
            Some(w) => w,
            None if expect_reply && !self.send_broken() => self.timing.timeout,
            None => self.silence_window(),
        };
        let deadline = later(sent, wait);
        let mut raw = Vec::new();
        let mut chunks = Vec::new();
        let mut last_rx: Option<Instant> = None;
        let mut complete = false;
        let settle = match self.transport.line_timing() {
            // Brisk: trailing bytes are caught before the next request instead.
            _ if self.brisk => Duration::ZERO,
            Some(l) => Duration::from_micros(2 * l.t3_5_us()).max(Duration::from_millis(5)),
            // A link without timing: 5 ms, or the quiet window where it is shorter (the
            // fuzzer's unpaced simulator).
            None => Duration::from_millis(5).min(self.timing.quiet),
        };
        let mut buf = [0u8; 512];
        // 06H and 08H replies are copies of the request, so a copy of one of these
        // requests may be the reply or an echo; a copy of any other request is an echo.
        let copy_may_be_reply = matches!(
            match self.mode {
                Mode::Rtu => request.get(1).copied(),
                Mode::Ascii => ascii::AsciiFrame::new_checked(request)
                    .ok()
                    .map(|f| f.function()),
            },
            Some(function::WRITE_SINGLE_REGISTER | function::LOOP_BACK)
        );
        let echoes = self.echoes();
        loop {
            let now = Instant::now();
            let seen = Seen::of(request, &raw, echoes, copy_may_be_reply);
            let skip = seen.skip(request);
            let unfinished = !complete && starts_a_reply(self.mode, request, &raw[skip..]);
            let limit = if seen.waiting() {
                // Nothing but (part of) an echo, or a copy that may be an echo: listen for
                // the whole response window.
                deadline.saturating_duration_since(now)
            } else if unfinished {
                // A reply (expected or not) whose rest has not come: the timeout is how long
                // to wait for a byte, so wait that long after the last one (a reply that
                // stalls mid-frame, on a busy host or behind a USB adapter's latency timer,
                // or a long reply at a low baud rate, is collected whole; the line-timing
                // check reports any gap).
                let after_last = later(last_rx.unwrap_or(now), self.timing.timeout);
                deadline.max(after_last).saturating_duration_since(now)
            } else {
                // Once a whole reply is in, a short settle catches trailing bytes; before
                // that, the quiet window waits for the rest of a reply in pieces.
                let quiet = if complete { settle } else { self.timing.quiet };
                let quiet_end = later(last_rx.unwrap_or(now), quiet);
                quiet_end.saturating_duration_since(now)
            };
            if limit.is_zero() {
                break;
            }
            let n = self
                .transport
                .recv(&mut buf, limit.min(Duration::from_millis(50)))?;
            if n > 0 {
                let t = Instant::now();
                chunks.push(Chunk {
                    at: t.duration_since(sent),
                    bytes: buf[..n].to_vec(),
                });
                raw.extend_from_slice(&buf[..n]);
                last_rx = Some(t);
                // Also where silence was expected: an answer that comes is collected whole.
                let skip = Seen::of(request, &raw, echoes, copy_may_be_reply).skip(request);
                complete = find_reply(self.mode, request, &raw[skip..]).1.is_some();
                // A reply longer than any frame is not a reply: stop collecting.
                if raw.len() > 4 * MAX_ASCII_FRAME {
                    break;
                }
            } else if Instant::now() >= deadline && seen.waiting() {
                break;
            }
        }
        let end = Instant::now();
        // The line has been quiet since the last byte (or since the request): the gap
        // before the next request counts from there, not from the end of listening.
        self.last_end = Some(last_rx.unwrap_or(sent));
        let seen = Seen::of(request, &raw, echoes, copy_may_be_reply);
        // What the exchange taught about the line (auto mode): a copy followed by more
        // bytes, or a copy of a request that cannot be its own reply, is an echo; a reply
        // without a copy before it shows there is none.
        if self.echo_mode == EchoMode::Auto && self.echo_seen.is_none() {
            match seen {
                Seen::Echo | Seen::EchoOnly => self.echo_seen = Some(true),
                Seen::Plain
                    if !raw.is_empty() && find_reply(self.mode, request, &raw).1.is_some() =>
                {
                    // A lone copy of a 06H/08H request is the reply of a line without echo.
                    self.echo_seen = Some(false)
                }
                _ => {}
            }
        }
        let skip = seen.skip(request);
        let echo = skip > 0;
        let first_byte = first_arrival_after(&chunks, skip);
        let (leading, reply, trailing) = find_reply(self.mode, request, &raw[skip..]);
        if expect_reply && !self.send_broken() {
            self.owed += 1;
        }
        self.owed = self
            .owed
            .saturating_sub(count_frames(self.mode, &raw[skip..]));
        self.account(request, &raw[skip..], first_byte, reply.is_some(), end - t0);
        Ok(Exchange {
            request: request.to_vec(),
            raw,
            chunks,
            echo,
            leading,
            reply,
            trailing,
            first_byte,
            listened: end.duration_since(sent),
            retries,
            link_notes: self.transport.take_notes(),
        })
    }
}

// Timing damage (the fuzzer's `timing.*` cases): a request sent in pieces.
impl<T: Transport + ?Sized> Master<T> {
    /// [`Master::exchange`] of `request` sent in pieces cut at `cuts` (byte positions,
    /// ascending) with `gap` of silence between them, on a link with line timing. The
    /// request is sent again where the host moved a gap by more than `tolerance` or
    /// stalled inside a piece (such a request is not the one meant), up to
    /// [`MAX_BROKEN_SENDS`] sends in all, then [`TransportError::Stalled`].
    /// Returns the exchange and the gaps as the last send left this host.
    pub fn exchange_split(
        &mut self,
        request: &[u8],
        cuts: &[usize],
        gap: Duration,
        tolerance: Duration,
        expect_reply: bool,
    ) -> Result<(Exchange, Vec<Duration>), TransportError> {
        self.split = Some(Split {
            cuts: cuts.to_vec(),
            gap,
            tolerance,
            ..Split::default()
        });
        let ex = self.exchange_retrying(request, expect_reply, self.timing.retries);
        let sent = self.split.take().map(|s| s.sent).unwrap_or_default();
        Ok((ex?, sent))
    }

    fn send_request(&mut self, request: &[u8]) -> Result<(), TransportError> {
        let Some(split) = self.split.as_mut() else {
            return self.transport.send(request);
        };
        let mut pieces: Vec<&[u8]> = Vec::new();
        let mut from = 0;
        for &c in &split.cuts {
            if c > from && c < request.len() {
                pieces.push(&request[from..c]);
                from = c;
            }
        }
        pieces.push(&request[from..]);
        let sent = self.transport.send_pieces(&pieces, split.gap)?;
        split.drifted = sent.iter().any(|g| g.abs_diff(split.gap) > split.tolerance);
        split.sent = sent;
        Ok(())
    }
}

impl<T: Transport + ?Sized> Master<T> {
    fn account(
        &mut self,
        request: &[u8],
        rx: &[u8],
        first_byte: Option<Duration>,
        replied: bool,
        busy: Duration,
    ) {
        let b = &mut self.budget;
        b.frames += 1;
        b.bytes_sent += request.len() as u64;
        b.bytes_received += rx.len() as u64;
        b.busy += busy;
        if rx.is_empty() {
            b.silences += 1;
        }
        if let (true, Some(t)) = (replied, first_byte) {
            // The first byte arrives one character after the reply starts on a line.
            let ct = self
                .transport
                .line_timing()
                .map_or(Duration::ZERO, |l| Duration::from_micros(l.char_time_us()));
            let delay = t.saturating_sub(ct);
            b.response += delay;
            b.max_response = b.max_response.max(delay);
        }
    }
}

/// What the received bytes are so far, as far as an echo goes.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Seen {
    /// Nothing, or the first bytes of a copy of the request that is an echo.
    PartialEcho,
    /// Exactly a copy of the request, which is an echo (nothing else yet).
    EchoOnly,
    /// Exactly a copy of a 06H/08H request on a line whose echo is not known: an echo or
    /// the reply; only the rest of the response window tells.
    Ambiguous,
    /// A copy of the request, then more bytes: the copy is the echo.
    Echo,
    /// Bytes that do not start with an echo.
    Plain,
}

impl Seen {
    fn of(request: &[u8], raw: &[u8], echoes: Option<bool>, copy_may_be_reply: bool) -> Seen {
        let n = request.len();
        if raw.is_empty() {
            return Seen::PartialEcho;
        }
        if echoes == Some(false) {
            return Seen::Plain;
        }
        if raw.len() < n {
            // A prefix of the request: an echo under way, where echo is expected; a reply
            // under way (or garbage) where it is not known.
            return if echoes == Some(true) && request.starts_with(raw) {
                Seen::PartialEcho
            } else {
                Seen::Plain
            };
        }
        if raw[..n] != *request {
            return Seen::Plain;
        }
        if raw.len() > n {
            return Seen::Echo;
        }
        match (echoes, copy_may_be_reply) {
            (Some(true), _) | (None, false) => Seen::EchoOnly,
            _ => Seen::Ambiguous,
        }
    }

    /// Whether only an echo (or what may be one) has come: keep listening for the reply.
    fn waiting(self) -> bool {
        matches!(self, Seen::PartialEcho | Seen::EchoOnly | Seen::Ambiguous)
    }

    /// How many leading bytes of the received ones are the echo of `request`.
    fn skip(self, request: &[u8]) -> usize {
        match self {
            Seen::Echo | Seen::EchoOnly => request.len(),
            _ => 0,
        }
    }
}

/// Whether `rx` ends in the start of a reply to `request` whose rest is missing: in RTU
/// the request's address, then its function (or its exception) with fewer bytes than
/// the length rule gives; in ASCII a ':' without the CR LF that ends it.
fn starts_a_reply(mode: Mode, request: &[u8], rx: &[u8]) -> bool {
    match mode {
        Mode::Rtu => {
            let (Some(&address), Some(&fc)) = (request.first(), request.get(1)) else {
                return false;
            };
            (0..rx.len()).any(|i| {
                let rest = &rx[i..];
                if rest[0] != address {
                    return false;
                }
                match rest.get(1) {
                    // A lone address byte is a reply under way only at the start.
                    None => i == 0,
                    Some(&f) if f == fc || f == fc | function::EXCEPTION_BIT => {
                        let want = if f == function::LOOP_BACK {
                            Some(request.len())
                        } else {
                            rtu_frame_len(Direction::Response, rest)
                        };
                        match want {
                            Some(n) => n > rest.len() && n <= crate::codec::MAX_RTU_FRAME,
                            // The byte count is not in yet (03H), or the length of an
                            // unmodelled function's reply is unknown: only a count that
                            // is still missing says more is coming.
                            None => f == function::READ_HOLDING_REGISTERS && rest.len() < 3,
                        }
                    }
                    Some(_) => false,
                }
            })
        }
        Mode::Ascii => match rx.iter().rposition(|&c| c == ascii::START) {
            Some(s) => {
                !rx[s..].windows(2).any(|w| w == ascii::END) && rx.len() - s < MAX_ASCII_FRAME
            }
            None => false,
        },
    }
}

/// Arrival time of byte number `skip` of the received stream.
fn first_arrival_after(chunks: &[Chunk], skip: usize) -> Option<Duration> {
    let mut seen = 0;
    for c in chunks {
        if seen + c.bytes.len() > skip {
            return Some(c.at);
        }
        seen += c.bytes.len();
    }
    None
}

/// Splits received bytes into (leading, reply, trailing): the reply is the first frame
/// with a valid checksum that answers `request` (same function, or the exception of it).
pub fn find_reply(mode: Mode, request: &[u8], rx: &[u8]) -> (Vec<u8>, Option<Vec<u8>>, Vec<u8>) {
    match mode {
        Mode::Rtu => {
            let fc = request.get(1).copied().unwrap_or(0);
            for i in 0..rx.len() {
                let rest = &rx[i..];
                let Some(&f) = rest.get(1) else { break };
                if f != fc && f != fc | function::EXCEPTION_BIT {
                    continue;
                }
                // The deframer's length rule; a loop-back reply is as long as its request
                // (the rule knows two data bytes only); an unmodelled function ends wherever
                // a valid CRC does.
                let candidates: Vec<usize> = if f == function::LOOP_BACK {
                    vec![request.len()]
                } else {
                    match rtu_frame_len(Direction::Response, rest) {
                        Some(n) => vec![n],
                        None => (4..=rest.len()).collect(),
                    }
                };
                for n in candidates {
                    if n >= 4 && n <= rest.len() && crc16(&rest[..n]) == 0 {
                        return (
                            rx[..i].to_vec(),
                            Some(rest[..n].to_vec()),
                            rest[n..].to_vec(),
                        );
                    }
                }
            }
            (rx.to_vec(), None, Vec::new())
        }
        Mode::Ascii => {
            let mut from = 0;
            while let Some(s) = rx[from..].iter().position(|&c| c == ascii::START) {
                let s = from + s;
                let Some(e) = rx[s..].windows(2).position(|w| w == ascii::END) else {
                    break;
                };
                let frame = &rx[s..s + e + 2];
                if ascii::is_valid_frame(frame) {
                    return (
                        rx[..s].to_vec(),
                        Some(frame.to_vec()),
                        rx[s + e + 2..].to_vec(),
                    );
                }
                from = s + 1;
            }
            (rx.to_vec(), None, Vec::new())
        }
    }
}

/// How many whole frames (replies: RTU by length, ASCII ':' to CR LF) `bytes` hold.
fn count_frames(mode: Mode, bytes: &[u8]) -> usize {
    use crate::codec::deframe::{AsciiDeframer, Event, RtuDeframer, RtuFraming};
    use crate::codec::pdu::Direction;
    if bytes.is_empty() {
        return 0;
    }
    let mut n = 0;
    let mut count = |e: Event<'_>| {
        if matches!(e, Event::Frame(_)) {
            n += 1;
        }
    };
    match mode {
        Mode::Rtu => {
            let mut d = RtuDeframer::new(Direction::Response, RtuFraming::ByLength);
            d.push(bytes, &mut count);
            d.end_burst(&mut count);
        }
        Mode::Ascii => {
            let mut d = AsciiDeframer::new(u64::MAX);
            d.push(bytes, &mut count);
        }
    }
    n
}

#[cfg(test)]
#[path = "master_tests.rs"]
mod tests;
