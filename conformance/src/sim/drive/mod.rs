//! The simulated drive: a model's rules plus state, and the fault-injection quirks.
//!
//! [`Drive::handle`] is pure apart from the drive's own state: it takes one request frame
//! and returns what goes on the line and when (an echo, a reply after the response delay),
//! so it is tested without any I/O. The server ([`super::server`]) moves the bytes.
//!
//! The quirks, their spelling and their help are in `quirk.rs`.

use std::collections::BTreeMap;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::codec::pdu::{Direction, Message, Pdu, Registers};
use crate::codec::{frame_parts, readdressed, Mode};
use crate::model::{Access, DriveModel, Expectation, Judgement, Role, SilenceReason};

mod quirk;

pub use quirk::{Quirk, QuirkError, HANG_TIME, OVERFLOW_RECOVERY, QUIRK_HELP};

/// What a transmission is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SendKind {
    /// The request echoed back (local-echo quirk).
    Echo,
    /// The drive's reply.
    Reply,
}

/// Bytes the drive puts on the line, `after` the end of the request.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Transmission {
    /// Delay after the end of the request.
    pub after: Duration,
    /// The bytes.
    pub bytes: Vec<u8>,
    /// Echo or reply.
    pub kind: SendKind,
}

/// What the drive did with one request.
#[derive(Debug, Clone)]
pub struct Outcome {
    /// The model's judgement of the request.
    pub judgement: Judgement,
    /// What goes on the line, in order.
    pub sends: Vec<Transmission>,
    /// Quirks that changed the behaviour, and other remarks for the log.
    pub notes: Vec<String>,
}

/// Output frequency slew of the simulated motor: 60.00 Hz a second. A decision of the
/// simulator (a real drive follows its acceleration time parameters).
pub const RAMP_HUNDREDTHS_HZ_PER_S: f64 = 6000.0;

/// A simulated drive of one model at one node address.
pub struct Drive {
    model: Arc<DriveModel>,
    address: u8,
    quirks: Vec<Quirk>,
    response_delay: Duration,
    values: BTreeMap<u16, u16>,
    running: bool,
    reverse: bool,
    fault_code: u16,
    output: f64,
    last_tick: Option<Instant>,
    replies: u64,
    frames: u64,
    /// The frame gap under which frames count as back to back (t3.5 of the line).
    t3_5: Duration,
    /// Time of one character on the line (zero where the link has no timing).
    char_time: Duration,
    last_frame: Option<Instant>,
    close_frames: u64,
    overflowed: bool,
    silent_until: Option<Instant>,
    /// Time of one character of the line, paced or not (the busy-after quirk's unit).
    line_char_time: Duration,
    /// When the last frame for another node was handled (the busy-after quirk).
    last_foreign: Option<Instant>,
}

impl Drive {
    /// A drive of `model` at node `address`, answering after `response_delay`.
    pub fn new(model: Arc<DriveModel>, address: u8, response_delay: Duration) -> Self {
        let mut values = BTreeMap::new();
        for (r, v, ..) in &model.example_registers {
            values.insert(*r, *v);
        }
        for (r, v, _) in &model.initial_values {
            values.insert(*r, *v);
        }
        Drive {
            model,
            address,
            quirks: Vec::new(),
            response_delay,
            values,
            running: false,
            reverse: false,
            fault_code: 0,
            output: 0.0,
            last_tick: None,
            replies: 0,
            frames: 0,
            t3_5: Duration::from_micros(
                crate::codec::timing::LineSettings::new(
                    9600,
                    8,
                    crate::codec::timing::Parity::Even,
                    1,
                )
                .t3_5_us(),
            ),
            char_time: Duration::ZERO,
            last_frame: None,
            close_frames: 0,
            overflowed: false,
            silent_until: None,
            line_char_time: Duration::from_micros(
                crate::codec::timing::LineSettings::new(
                    9600,
                    8,
                    crate::codec::timing::Parity::Even,
                    1,
                )
                .char_time_us(),
            ),
            last_foreign: None,
        }
    }

    /// Sets the line whose t3.5 the overflow-after quirk measures gaps against; with
    /// `paced`, frames take their characters' time on the line.
    pub fn with_line(mut self, line: crate::codec::timing::LineSettings, paced: bool) -> Self {
        self.t3_5 = Duration::from_micros(line.t3_5_us());
        self.line_char_time = Duration::from_micros(line.char_time_us());
        self.char_time = if paced {
            Duration::from_micros(line.char_time_us())
        } else {
            Duration::ZERO
        };
        self
    }

    /// The planted bugs that silence the drive: whether `frame`, received at `now`, is
    /// ignored, and why.
    fn planted_silence(&mut self, mode: Mode, frame: &[u8], now: Instant) -> Option<String> {
        let previous = self.last_frame.replace(now);
        if let Some(n) = self.quirks.iter().find_map(|q| match q {
            Quirk::OverflowAfter(n) => Some(*n),
            _ => None,
        }) {
            let since = previous.map(|p| now.saturating_duration_since(p));
            if self.overflowed && since.is_some_and(|s| s >= OVERFLOW_RECOVERY) {
                self.overflowed = false;
                self.close_frames = 0;
            }
            // The gap before this frame: the time since the previous one ended, less this
            // frame's own time on the line.
            let on_line = self.char_time * u32::try_from(frame.len()).unwrap_or(u32::MAX);
            let close = if self.char_time.is_zero() {
                // An unpaced link has no line time and no t3.5 to keep: frames are back
                // to back when they came in one read (written together).
                since.is_some_and(|s| s.is_zero())
            } else {
                since.is_some_and(|s| s.saturating_sub(on_line) < self.t3_5)
            };
            self.close_frames = if close { self.close_frames + 1 } else { 0 };
            if self.close_frames >= n {
                self.overflowed = true;
            }
            if self.overflowed {
                return Some(format!(
                    "quirk overflow-after={n}: receiver overflowed; silent until {} ms without a frame",
                    OVERFLOW_RECOVERY.as_millis()
                ));
            }
        }
        if let Some(until) = self.silent_until {
            if now < until {
                return Some("quirk hang-on-byte-count: hung".to_string());
            }
            self.silent_until = None;
        }
        if self.has(Quirk::HangOnByteCount) {
            if let Ok(parts) = frame_parts(mode, frame) {
                let b = &parts.body;
                let for_me = b.first().is_some_and(|&a| a == self.address || a == 0);
                if parts.checksum.is_valid()
                    && for_me
                    && b.len() >= 7
                    && b[1] == crate::codec::pdu::function::WRITE_MULTIPLE_REGISTERS
                    && usize::from(b[6]) > b.len() - 7
                {
                    self.silent_until = Some(now + HANG_TIME);
                    return Some(format!(
                        "quirk hang-on-byte-count: byte count {} over the {} data bytes; silent for {} s",
                        b[6],
                        b.len() - 7,
                        HANG_TIME.as_secs()
                    ));
                }
            }
        }
        None
    }

    /// The busy-after quirk: whether `frame`, handled at `now`, is lost because it
    /// follows another node's frame too closely, and why.
    fn busy_after(&mut self, mode: Mode, frame: &[u8], now: Instant) -> Option<String> {
        let n = self.quirks.iter().find_map(|q| match q {
            Quirk::BusyAfter(n) => Some(*n),
            _ => None,
        })?;
        let address = frame_address(mode, frame)?;
        if address != self.address && address != 0 {
            self.last_foreign = Some(now);
            return None;
        }
        let previous = self.last_foreign?;
        // Both frames are handled the same time after their ends: the gap between them
        // is the time between, less this frame's own time on the line.
        let on_line = self.char_time * u32::try_from(frame.len()).unwrap_or(u32::MAX);
        let gap = now
            .saturating_duration_since(previous)
            .saturating_sub(on_line);
        let window = self.t3_5 + self.line_char_time * u32::try_from(n).unwrap_or(u32::MAX);
        (gap < window).then(|| {
            format!(
                "quirk busy-after={n}: request lost, {} us after another node's frame (under t3.5 + {n} characters = {} us)",
                gap.as_micros(),
                window.as_micros()
            )
        })
    }

    /// Adds fault-injection quirks.
    pub fn with_quirks(mut self, quirks: &[Quirk]) -> Self {
        self.quirks.extend_from_slice(quirks);
        self
    }

    /// The model.
    pub fn model(&self) -> &DriveModel {
        &self.model
    }

    /// The node address.
    pub fn address(&self) -> u8 {
        self.address
    }

    /// The quirks in force.
    pub fn quirks(&self) -> &[Quirk] {
        &self.quirks
    }

    fn has(&self, q: Quirk) -> bool {
        self.quirks.contains(&q)
    }

    fn late(&self) -> Duration {
        self.quirks
            .iter()
            .find_map(|q| match q {
                Quirk::LateReply(ms) => Some(Duration::from_millis(*ms)),
                _ => None,
            })
            .unwrap_or_default()
    }

    fn drop_every(&self) -> Option<u32> {
        self.quirks.iter().find_map(|q| match q {
            Quirk::DropEvery(n) => Some(*n),
            _ => None,
        })
    }

    /// Advances the motor: the output frequency moves toward the frequency command while
    /// running without a fault, toward zero otherwise.
    pub fn tick(&mut self, now: Instant) {
        let dt = match self.last_tick {
            Some(t) => now.saturating_duration_since(t).as_secs_f64(),
            None => 0.0,
        };
        self.last_tick = Some(now);
        let target = if self.running && self.fault_code == 0 {
            f64::from(self.frequency_command())
        } else {
            0.0
        };
        let step = RAMP_HUNDREDTHS_HZ_PER_S * dt;
        if (target - self.output).abs() <= step {
            self.output = target;
        } else if target > self.output {
            self.output += step;
        } else {
            self.output -= step;
        }
    }

    /// The frequency command as the drive uses it: the value written to the command
    /// register, at the model's resolution (the A510 drops the hundredths over 300 Hz).
    fn frequency_command(&self) -> u16 {
        let written = self
            .model
            .register_with_role(Role::FrequencyCommand)
            .and_then(|r| self.values.get(&r).copied())
            .unwrap_or(0);
        self.model.frequency_in_use(written)
    }

    /// What the identification register reads: the description's value, or the value
    /// it gives the simulator.
    fn identification_value(&self) -> u16 {
        self.model
            .identification
            .as_ref()
            .map_or(0, |i| i.simulated)
    }

    /// Whether `register` is the description's identification register.
    fn is_identification(&self, register: u16) -> bool {
        self.model
            .identification
            .as_ref()
            .is_some_and(|i| i.register == Some(register))
    }

    /// The value a read of `register` (as the map knows it) returns now.
    pub fn read_register(&self, register: u16) -> u16 {
        let Some(info) = self.model.lookup(register) else {
            return 0;
        };
        if info.access == Access::Reserved {
            return 0;
        }
        let bit = |b: Option<u8>, on: bool| match b {
            Some(b) if on => 1u16 << b,
            _ => 0,
        };
        match self.model.named(info.register).and_then(|n| n.role) {
            Some(Role::Status) => {
                let bits = &self.model.bits;
                bit(bits.running, self.running && self.fault_code == 0)
                    | bit(bits.status_reverse, self.reverse)
                    | bit(bits.ready, self.fault_code == 0)
                    | bit(bits.fault, self.fault_code != 0)
            }
            Some(Role::FaultCode) => self.fault_code,
            Some(Role::FrequencyCommandMonitor) => self.frequency_command(),
            Some(Role::OutputFrequency) => self
                .model
                .frequency_in_use(self.output.round().clamp(0.0, 65535.0) as u16),
            Some(Role::Identification) => self.identification_value(),
            // A v2 description's identification register may sit in a plain block.
            _ if self.is_identification(info.register) => self.identification_value(),
            _ => self.values.get(&info.register).copied().unwrap_or(0),
        }
    }

    fn write_register(&mut self, register: u16, value: u16) {
        self.values.insert(register, value);
        if self.model.named(register).and_then(|n| n.role) == Some(Role::Operation) {
            let bits = self.model.bits;
            let on = |b: Option<u8>| b.is_some_and(|b| value & (1 << b) != 0);
            if on(bits.fault_reset) {
                self.fault_code = 0;
            }
            if on(bits.external_fault) {
                self.fault_code = self.model.external_fault_code.as_ref().map_or(1, |c| c.0);
            }
            self.running = on(bits.run);
            self.reverse = on(bits.reverse);
        }
    }

    /// Handles one request frame received in `mode` (checksum included) at `now`.
    pub fn handle(&mut self, mode: Mode, frame: &[u8], now: Instant) -> Outcome {
        self.tick(now);
        self.frames += 1;
        let mut notes = Vec::new();
        let mut sends = Vec::new();
        if self.has(Quirk::LocalEcho) {
            sends.push(Transmission {
                after: Duration::ZERO,
                bytes: frame.to_vec(),
                kind: SendKind::Echo,
            });
            notes.push("quirk local-echo: request echoed".to_string());
        }
        let frozen = self.quirks.iter().find_map(|q| match q {
            Quirk::Dead => Some("quirk dead: nothing sent".to_string()),
            Quirk::FreezeAfter(n) if self.frames > *n => Some(format!(
                "quirk freeze-after={n}: frame {} ignored",
                self.frames
            )),
            _ => None,
        });
        let frozen = frozen
            .or_else(|| self.planted_silence(mode, frame, now))
            .or_else(|| self.busy_after(mode, frame, now));
        if let Some(note) = frozen {
            // A dead or hung drive neither acts on a request nor answers it.
            // The echo, if any, is the adapter's: it still comes.
            notes.push(note);
            return Outcome {
                judgement: self.model.judge(self.address, mode, frame),
                sends,
                notes,
            };
        }
        let mut judgement = self.model.judge(self.address, mode, frame);
        // A device that does not serve this mode does not take the frame for one.
        if !self.model.serves_mode(mode) {
            notes.push(format!(
                "{} is not in the description's modes: frame ignored",
                mode.to_string().to_uppercase()
            ));
            return Outcome {
                judgement,
                sends,
                notes,
            };
        }
        let request_address = frame_address(mode, frame);
        if judgement.expect == Expectation::Silence(SilenceReason::OtherAddress)
            && self.has(Quirk::AnswerEveryAddress)
        {
            if let Some(a) = request_address {
                judgement = self.model.judge(a, mode, frame);
                notes.push(format!(
                    "quirk answer-every-address: answering for node {a:02X}"
                ));
            }
        }
        if let Some(plan) = &judgement.write {
            for &(r, v) in &plan.writes {
                self.write_register(r, v);
            }
        }
        // What to answer: the judgement, or for the reply-to-broadcast quirk what the
        // drive would answer if the request were addressed to it.
        let mut reply_to = judgement.expect.clone();
        if judgement.expect == Expectation::Silence(SilenceReason::Broadcast)
            && self.has(Quirk::ReplyToBroadcast)
        {
            if let Ok(readdressed) = readdressed(mode, frame, self.address) {
                reply_to = self.model.judge(self.address, mode, &readdressed).expect;
                notes.push("quirk reply-to-broadcast: answering a broadcast".to_string());
            }
        }
        let reply = self.build_reply(mode, frame, &reply_to, request_address.unwrap_or(0));
        if let Some(mut bytes) = reply {
            self.replies += 1;
            if let Some(n) = self.drop_every() {
                if self.replies.is_multiple_of(u64::from(n)) {
                    notes.push(format!(
                        "quirk drop-every={n}: reply {} not sent",
                        self.replies
                    ));
                    return Outcome {
                        judgement,
                        sends,
                        notes,
                    };
                }
            }
            if self.has(Quirk::CrcSwap) {
                swap_checksum(mode, &mut bytes);
                notes.push("quirk crc-swap: checksum bytes swapped".to_string());
            }
            if self.has(Quirk::TruncatedReply) {
                let cut = if mode == Mode::Rtu { 2 } else { 3 };
                bytes.truncate(bytes.len().saturating_sub(cut));
                notes.push(format!("quirk truncated-reply: last {cut} bytes cut"));
            }
            if self.has(Quirk::GarbageBeforeReply) {
                let garbage: &[u8] = match mode {
                    Mode::Rtu => &[0xFF, 0x00, 0xA5],
                    Mode::Ascii => b"#@!",
                };
                bytes.splice(0..0, garbage.iter().copied());
                notes.push("quirk garbage-before-reply: 3 bytes before the reply".to_string());
            }
            let late = self.late();
            if !late.is_zero() {
                notes.push(format!("quirk late-reply: {} ms late", late.as_millis()));
            }
            sends.push(Transmission {
                after: self.response_delay + late,
                bytes,
                kind: SendKind::Reply,
            });
        }
        Outcome {
            judgement,
            sends,
            notes,
        }
    }

    fn build_reply(
        &mut self,
        mode: Mode,
        frame: &[u8],
        expect: &Expectation,
        address: u8,
    ) -> Option<Vec<u8>> {
        let body = frame_parts(mode, frame).ok()?.body;
        let request = Message::parse_body(&body, Direction::Request).ok();
        let function = body.get(1).copied().unwrap_or(0);
        let mut values = Vec::new();
        let pdu = match expect {
            Expectation::Read(plan)
                if plan
                    .registers
                    .iter()
                    .any(|r| self.quirks.contains(&Quirk::ExceptionAt(*r))) =>
            {
                Pdu::Exception {
                    function: function & 0x7F,
                    code: 0x04,
                }
            }
            Expectation::Read(plan) => {
                for &r in &plan.registers {
                    let mut v = self.read_register(r);
                    if let Some(Quirk::StuckAt(_, stuck)) = self
                        .quirks
                        .iter()
                        .find(|q| matches!(q, Quirk::StuckAt(at, _) if *at == r))
                    {
                        v = *stuck;
                    }
                    if self.quirks.contains(&Quirk::WrongValueAt(r)) {
                        v ^= 1;
                    }
                    values.extend_from_slice(&v.to_be_bytes());
                }
                Pdu::ReadResponse {
                    values: Registers::new(&values).ok()?,
                }
            }
            Expectation::WriteSingle | Expectation::LoopBack => request?.pdu,
            Expectation::WriteMultiple => match request?.pdu {
                Pdu::WriteMultipleRequest { start, values } => Pdu::WriteMultipleResponse {
                    start,
                    count: u16::try_from(values.len()).ok()?,
                },
                _ => return None,
            },
            Expectation::Exception { code, .. } => {
                let code = if self.has(Quirk::WrongException) {
                    code.wrapping_add(1)
                } else {
                    *code
                };
                Pdu::Exception {
                    function: function & 0x7F,
                    code,
                }
            }
            Expectation::Silence(_) => return None,
        };
        Message { address, pdu }.to_frame_vec(mode).ok()
    }
}

fn frame_address(mode: Mode, frame: &[u8]) -> Option<u8> {
    frame_parts(mode, frame).ok().map(|p| p.body[0])
}

fn swap_checksum(mode: Mode, bytes: &mut [u8]) {
    let n = bytes.len();
    match mode {
        Mode::Rtu if n >= 2 => bytes.swap(n - 2, n - 1),
        Mode::Ascii if n >= 4 => bytes.swap(n - 4, n - 3),
        _ => {}
    }
}

#[cfg(test)]
mod tests;
