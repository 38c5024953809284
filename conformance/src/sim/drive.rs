//! The simulated drive: a model's rules plus state, and the fault-injection quirks.
//!
//! [`Drive::handle`] is pure apart from the drive's own state: it takes one request frame
//! and returns what goes on the line and when (an echo, a reply after the response delay),
//! so it is tested without any I/O. The server ([`super::server`]) moves the bytes.

use std::collections::BTreeMap;
use std::fmt;
use std::sync::Arc;
use std::time::{Duration, Instant};

use crate::codec::pdu::{Direction, Message, Pdu, Registers};
use crate::codec::{frame_parts, readdressed, Mode};
use crate::model::{Access, DriveModel, Expectation, Judgement, Role, SilenceReason};

/// A deliberate deviation from the model, so that the runner can prove it notices.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Quirk {
    /// The two CRC bytes of every reply are swapped (in ASCII: the two LRC characters).
    CrcSwap,
    /// Broadcast requests are answered (from address 00H).
    ReplyToBroadcast,
    /// Every exception reply carries the model's code plus one.
    WrongException,
    /// Every reply comes this many milliseconds late.
    LateReply(u64),
    /// Every Nth reply is not sent.
    DropEvery(u32),
    /// Every request is echoed back before the reply, as a half-duplex adapter without
    /// echo suppression does.
    LocalEcho,
    /// Three garbage bytes go on the line before every reply.
    GarbageBeforeReply,
    /// Every reply loses its last two bytes (RTU) or its last three characters (ASCII).
    TruncatedReply,
    /// Requests to any node address are answered.
    AnswerEveryAddress,
    /// Nothing is ever sent: an unplugged, unpowered or wrongly addressed drive.
    Dead,
    /// After this many frames (any address) nothing is sent any more: firmware that
    /// hangs mid-run.
    FreezeAfter(u64),
    /// A planted firmware bug: a 10H request whose byte count is larger than the data it
    /// carries, under a valid checksum, makes the drive silent for [`HANG_TIME`] (the
    /// length-field bug of CVE-2020-7584).
    HangOnByteCount,
    /// A planted firmware bug: reads of this register (as the map knows it, after
    /// aliases) return its value with the lowest bit flipped.
    WrongValueAt(u16),
    /// A planted firmware bug: the Nth frame in a row that arrives less than t3.5 after
    /// the previous one overflows the receiver; nothing is answered until
    /// [`OVERFLOW_RECOVERY`] passes without a frame. On an unpaced link (no line time, no
    /// t3.5), frames are back to back when they arrive in one read.
    OverflowAfter(u64),
    /// A planted firmware bug: an RTU frame with a silence over t1.5 (under t3.5) between
    /// two of its characters is taken whole instead of being discarded (Modbus over
    /// Serial Line V1.02, 2.5.1.1). Only a line with timing can show it (a real port, or
    /// the simulator's paced pseudo-terminal, which frames by silence).
    IgnoreT15,
    /// A planted firmware bug: a request for this drive that starts less than t3.5 + N
    /// characters after the end of a frame for another node (a request or a reply of
    /// another slave on the bus) is lost, as a receiver still busy with the other
    /// node's traffic loses it. The storm test (`fuzz --storm`) must catch it.
    BusyAfter(u64),
    /// A planted firmware bug: reads of this register return this value, whatever was
    /// written (a stuck sensor, a value out of the manual's range).
    StuckAt(u16, u16),
    /// A planted firmware bug: a read that covers this register gets exception 04H.
    ExceptionAt(u16),
}

/// How long the hang-on-byte-count quirk keeps the drive silent.
pub const HANG_TIME: Duration = Duration::from_secs(5);

/// The silence that ends the overflow-after quirk's overflow.
pub const OVERFLOW_RECOVERY: Duration = Duration::from_secs(1);

/// The quirks, with their spelling and what each does, for help text and docs.
pub const QUIRK_HELP: [(&str, &str); 19] = [
    (
        "crc-swap",
        "swap the two CRC bytes of every reply (ASCII: the two LRC characters)",
    ),
    (
        "reply-to-broadcast",
        "answer broadcast requests (from address 00)",
    ),
    (
        "wrong-exception",
        "answer every exception with the model's code plus one",
    ),
    ("late-reply=MS", "send every reply MS milliseconds late"),
    ("drop-every=N", "do not send every Nth reply"),
    (
        "local-echo",
        "echo every request before the reply (half-duplex adapter)",
    ),
    (
        "garbage-before-reply",
        "send three garbage bytes before every reply",
    ),
    (
        "truncated-reply",
        "cut the last 2 bytes (RTU) / 3 characters (ASCII) off every reply",
    ),
    (
        "answer-every-address",
        "answer requests to any node address",
    ),
    (
        "dead",
        "never send anything (unplugged, unpowered, wrong address)",
    ),
    (
        "freeze-after=N",
        "stop sending anything after N received frames (hung firmware)",
    ),
    (
        "slow=MS",
        "the same as late-reply=MS: replies within the timeout, but late",
    ),
    (
        "hang-on-byte-count",
        "planted bug: a 10H request whose byte count exceeds its data (valid checksum) silences the drive for 5 s",
    ),
    (
        "wrong-value-at=REG",
        "planted bug: reads of register REG (hex: 2520H, 0x2520) return the value with bit 0 flipped",
    ),
    (
        "overflow-after=N",
        "planted bug: the Nth frame in a row less than t3.5 after the previous one (unpaced: in the same read, written together) stops all answers until 1 s without a frame",
    ),
    (
        "ignore-t15",
        "planted bug: an RTU frame with a silence over t1.5 inside it is taken whole, not discarded (paced links only)",
    ),
    (
        "busy-after=N",
        "planted bug: a request that starts less than t3.5 + N characters after another node's frame is lost",
    ),
    (
        "stuck-at=REG:VALUE",
        "planted bug: reads of register REG return VALUE (hex: 2502H:9C41H), whatever was written",
    ),
    (
        "exception-at=REG",
        "planted bug: a read that covers register REG gets exception 04H",
    ),
];

/// A quirk that cannot be parsed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
#[error("unknown quirk {0:?}; the quirks are crc-swap, reply-to-broadcast, wrong-exception, late-reply=MS, drop-every=N, local-echo, garbage-before-reply, truncated-reply, answer-every-address, dead, freeze-after=N, slow=MS, hang-on-byte-count, wrong-value-at=REG, overflow-after=N, ignore-t15, busy-after=N, stuck-at=REG:VALUE, exception-at=REG")]
pub struct QuirkError(pub String);

impl std::str::FromStr for Quirk {
    type Err = QuirkError;

    fn from_str(s: &str) -> Result<Self, Self::Err> {
        let err = || QuirkError(s.to_string());
        let (name, arg) = match s.split_once('=') {
            Some((n, a)) => (n, Some(a)),
            None => (s, None),
        };
        let num = |a: Option<&str>| -> Result<u64, QuirkError> {
            a.and_then(|a| a.parse::<u64>().ok()).ok_or_else(err)
        };
        Ok(match (name, arg) {
            ("crc-swap", None) => Quirk::CrcSwap,
            ("reply-to-broadcast", None) => Quirk::ReplyToBroadcast,
            ("wrong-exception", None) => Quirk::WrongException,
            ("late-reply", a) => Quirk::LateReply(num(a)?),
            ("drop-every", a) => {
                let n = u32::try_from(num(a)?).map_err(|_| err())?;
                if n == 0 {
                    return Err(err());
                }
                Quirk::DropEvery(n)
            }
            ("local-echo", None) => Quirk::LocalEcho,
            ("garbage-before-reply", None) => Quirk::GarbageBeforeReply,
            ("truncated-reply", None) => Quirk::TruncatedReply,
            ("answer-every-address", None) => Quirk::AnswerEveryAddress,
            ("dead", None) => Quirk::Dead,
            ("freeze-after", a) => Quirk::FreezeAfter(num(a)?),
            // The name for a drive that answers within the timeout, but late.
            ("slow", a) => Quirk::LateReply(num(a)?),
            ("hang-on-byte-count", None) => Quirk::HangOnByteCount,
            ("wrong-value-at", Some(a)) => Quirk::WrongValueAt(parse_register(a).ok_or_else(err)?),
            ("overflow-after", a) => {
                let n = num(a)?;
                if n == 0 {
                    return Err(err());
                }
                Quirk::OverflowAfter(n)
            }
            ("ignore-t15", None) => Quirk::IgnoreT15,
            ("busy-after", a) => Quirk::BusyAfter(num(a)?),
            ("stuck-at", Some(a)) => {
                let (r, v) = a.split_once(':').ok_or_else(err)?;
                Quirk::StuckAt(
                    parse_register(r).ok_or_else(err)?,
                    parse_register(v).ok_or_else(err)?,
                )
            }
            ("exception-at", Some(a)) => Quirk::ExceptionAt(parse_register(a).ok_or_else(err)?),
            _ => return Err(err()),
        })
    }
}

impl fmt::Display for Quirk {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Quirk::CrcSwap => f.write_str("crc-swap"),
            Quirk::ReplyToBroadcast => f.write_str("reply-to-broadcast"),
            Quirk::WrongException => f.write_str("wrong-exception"),
            Quirk::LateReply(ms) => write!(f, "late-reply={ms}"),
            Quirk::DropEvery(n) => write!(f, "drop-every={n}"),
            Quirk::LocalEcho => f.write_str("local-echo"),
            Quirk::GarbageBeforeReply => f.write_str("garbage-before-reply"),
            Quirk::TruncatedReply => f.write_str("truncated-reply"),
            Quirk::AnswerEveryAddress => f.write_str("answer-every-address"),
            Quirk::Dead => f.write_str("dead"),
            Quirk::FreezeAfter(n) => write!(f, "freeze-after={n}"),
            Quirk::HangOnByteCount => f.write_str("hang-on-byte-count"),
            Quirk::WrongValueAt(r) => write!(f, "wrong-value-at={r:04X}H"),
            Quirk::OverflowAfter(n) => write!(f, "overflow-after={n}"),
            Quirk::IgnoreT15 => f.write_str("ignore-t15"),
            Quirk::BusyAfter(n) => write!(f, "busy-after={n}"),
            Quirk::StuckAt(r, v) => write!(f, "stuck-at={r:04X}H:{v:04X}H"),
            Quirk::ExceptionAt(r) => write!(f, "exception-at={r:04X}H"),
        }
    }
}

/// A register number as the manuals write it: `2520H`, `0x2520`, or decimal.
fn parse_register(text: &str) -> Option<u16> {
    let t = text.trim();
    if let Some(h) = t
        .strip_prefix("0x")
        .or_else(|| t.strip_prefix("0X"))
        .or_else(|| t.strip_suffix(['H', 'h']))
    {
        u16::from_str_radix(h, 16).ok()
    } else {
        t.parse().ok()
    }
}

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
mod tests {
    use super::*;
    use crate::model::Fault;

    fn drive(quirks: &[Quirk]) -> Drive {
        Drive::new(
            Arc::new(DriveModel::builtin("f510").unwrap()),
            1,
            Duration::from_millis(10),
        )
        .with_quirks(quirks)
    }

    fn req(mode: Mode, address: u8, pdu: Pdu<'_>) -> Vec<u8> {
        Message { address, pdu }.to_frame_vec(mode).unwrap()
    }

    fn reply(o: &Outcome) -> Option<&Transmission> {
        o.sends.iter().find(|s| s.kind == SendKind::Reply)
    }

    #[test]
    fn quirks_parse_and_print() {
        for (spelling, _) in QUIRK_HELP {
            let s = spelling
                .replace("=MS", "=200")
                .replace("=N", "=3")
                .replace("=REG", "=2502H")
                .replace(":VALUE", ":9C41H");
            let q: Quirk = s.parse().unwrap();
            // `slow=MS` is another spelling of `late-reply=MS`.
            let printed = s.replace("slow=", "late-reply=");
            assert_eq!(q.to_string(), printed);
            assert_eq!(printed.parse::<Quirk>().unwrap(), q);
        }
        assert_eq!(
            "wrong-value-at=0x0500".parse::<Quirk>().unwrap(),
            Quirk::WrongValueAt(0x0500)
        );
        assert!("overflow-after=0".parse::<Quirk>().is_err());
        assert!("wrong-value-at=FFFFFH".parse::<Quirk>().is_err());
        assert_eq!(
            "stuck-at=2502H:9C41H".parse::<Quirk>().unwrap(),
            Quirk::StuckAt(0x2502, 0x9C41)
        );
        assert_eq!(
            Quirk::StuckAt(0x2502, 0x9C41).to_string(),
            "stuck-at=2502H:9C41H"
        );
        assert!("stuck-at=2502H".parse::<Quirk>().is_err());
        assert_eq!(
            "exception-at=0x2521".parse::<Quirk>().unwrap(),
            Quirk::ExceptionAt(0x2521)
        );
        assert_eq!("freeze-after=7".parse::<Quirk>(), Ok(Quirk::FreezeAfter(7)));
        assert!("dead=1".parse::<Quirk>().is_err());
        assert!("drop-every=0".parse::<Quirk>().is_err());
        assert!("late-reply".parse::<Quirk>().is_err());
        assert!("crc".parse::<Quirk>().is_err());
    }

    #[test]
    fn the_example_exchanges_replay() {
        let mut d = drive(&[]);
        let now = Instant::now();
        // F510 03H example: read 0123H -> 1770H.
        let o = d.handle(
            Mode::Rtu,
            &[0x01, 0x03, 0x01, 0x23, 0x00, 0x01, 0x74, 0x3C],
            now,
        );
        assert_eq!(
            reply(&o).unwrap().bytes,
            [0x01, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50]
        );
        assert_eq!(reply(&o).unwrap().after, Duration::from_millis(10));
        // 06H example: echo.
        let w = [0x01, 0x06, 0x01, 0x02, 0x17, 0x70, 0x27, 0xE2];
        assert_eq!(reply(&d.handle(Mode::Rtu, &w, now)).unwrap().bytes, w);
        // 08H example: echo.
        let lb = [0x01, 0x08, 0x00, 0x00, 0xA5, 0x37, 0xDA, 0x8D];
        assert_eq!(reply(&d.handle(Mode::Rtu, &lb, now)).unwrap().bytes, lb);
        // 10H example: start and count.
        let m = [
            0x01, 0x10, 0x01, 0x01, 0x00, 0x02, 0x04, 0x00, 0x01, 0x17, 0x70, 0x60, 0x27,
        ];
        assert_eq!(
            reply(&d.handle(Mode::Rtu, &m, now)).unwrap().bytes,
            [0x01, 0x10, 0x01, 0x01, 0x00, 0x02, 0x11, 0xF4]
        );
    }

    #[test]
    fn state_follows_the_command_register() {
        let mut d = drive(&[]);
        let t0 = Instant::now();
        let w = |d: &mut Drive, r: u16, v: u16, t| {
            d.handle(
                Mode::Rtu,
                &req(
                    Mode::Rtu,
                    1,
                    Pdu::WriteSingle {
                        register: r,
                        value: v,
                    },
                ),
                t,
            )
        };
        w(&mut d, 0x2502, 6000, t0);
        assert_eq!(d.read_register(0x2523), 6000);
        assert_eq!(
            d.read_register(0x2520) & 0b1101,
            0b0100,
            "ready, not running"
        );
        w(&mut d, 0x2501, 0b11, t0); // run, reverse
        d.tick(t0 + Duration::from_millis(500));
        let half = d.read_register(0x2524);
        assert!((2900..=3100).contains(&half), "{half}");
        d.tick(t0 + Duration::from_secs(2));
        assert_eq!(d.read_register(0x2524), 6000);
        assert_eq!(d.read_register(0x2520) & 0b1111, 0b0111);
        w(&mut d, 0x2501, 0b100, t0 + Duration::from_secs(2)); // external fault
        assert_eq!(d.read_register(0x2520) & 0b1000, 0b1000);
        assert_eq!(d.read_register(0x2521), 27);
        w(&mut d, 0x2501, 0b1000, t0 + Duration::from_secs(2)); // fault reset
        assert_eq!(d.read_register(0x2521), 0);
        assert_eq!(d.read_register(0x252F), 0x0510);
        assert_eq!(d.read_register(0x2500), 0);
    }

    #[test]
    fn broadcast_writes_silently_and_other_nodes_are_ignored() {
        let mut d = drive(&[]);
        let now = Instant::now();
        let o = d.handle(
            Mode::Ascii,
            &req(
                Mode::Ascii,
                0,
                Pdu::WriteSingle {
                    register: 0x2502,
                    value: 0x0AAA,
                },
            ),
            now,
        );
        assert!(o.sends.is_empty());
        assert_eq!(d.read_register(0x2502), 0x0AAA);
        let o = d.handle(
            Mode::Rtu,
            &req(
                Mode::Rtu,
                2,
                Pdu::ReadRequest {
                    start: 0x2520,
                    count: 1,
                },
            ),
            now,
        );
        assert!(o.sends.is_empty());
    }

    #[test]
    fn stuck_at_and_exception_at_answer_reads_as_planted() {
        let now = Instant::now();
        let read = |start, count| req(Mode::Rtu, 1, Pdu::ReadRequest { start, count });
        let o = drive(&[Quirk::StuckAt(0x2502, 0x9C41)]).handle(Mode::Rtu, &read(0x2501, 2), now);
        assert_eq!(&reply(&o).unwrap().bytes[3..7], &[0x00, 0x00, 0x9C, 0x41]);
        let o = drive(&[Quirk::ExceptionAt(0x2521)]).handle(Mode::Rtu, &read(0x2520, 3), now);
        assert_eq!(&reply(&o).unwrap().bytes[..3], &[0x01, 0x83, 0x04]);
        // A read that does not cover the register is served.
        let o = drive(&[Quirk::ExceptionAt(0x2521)]).handle(Mode::Rtu, &read(0x2522, 2), now);
        assert_eq!(&reply(&o).unwrap().bytes[..3], &[0x01, 0x03, 0x04]);
    }

    #[test]
    fn each_quirk_changes_the_line() {
        let now = Instant::now();
        let read = req(
            Mode::Rtu,
            1,
            Pdu::ReadRequest {
                start: 0x2520,
                count: 1,
            },
        );
        let clean = reply(&drive(&[]).handle(Mode::Rtu, &read, now))
            .unwrap()
            .bytes
            .clone();

        let o = drive(&[Quirk::CrcSwap]).handle(Mode::Rtu, &read, now);
        let b = &reply(&o).unwrap().bytes;
        assert_eq!(b[..b.len() - 2], clean[..clean.len() - 2]);
        assert_eq!(
            (b[b.len() - 2], b[b.len() - 1]),
            (clean[clean.len() - 1], clean[clean.len() - 2])
        );

        let bc = req(
            Mode::Rtu,
            0,
            Pdu::WriteSingle {
                register: 0x2502,
                value: 1,
            },
        );
        let o = drive(&[Quirk::ReplyToBroadcast]).handle(Mode::Rtu, &bc, now);
        assert_eq!(reply(&o).unwrap().bytes[0], 0);

        let bad = req(
            Mode::Rtu,
            1,
            Pdu::Other {
                function: 4,
                data: &[0, 0, 0, 1],
            },
        );
        let o = drive(&[Quirk::WrongException]).handle(Mode::Rtu, &bad, now);
        assert_eq!(reply(&o).unwrap().bytes[..3], [1, 0x84, 2]);
        assert!(matches!(
            o.judgement.expect,
            Expectation::Exception {
                fault: Fault::IllegalFunction,
                code: 1
            }
        ));

        let o = drive(&[Quirk::LateReply(250)]).handle(Mode::Rtu, &read, now);
        assert_eq!(reply(&o).unwrap().after, Duration::from_millis(260));

        let mut d = drive(&[Quirk::DropEvery(2)]);
        assert!(reply(&d.handle(Mode::Rtu, &read, now)).is_some());
        assert!(reply(&d.handle(Mode::Rtu, &read, now)).is_none());
        assert!(reply(&d.handle(Mode::Rtu, &read, now)).is_some());

        let o = drive(&[Quirk::LocalEcho]).handle(Mode::Rtu, &read, now);
        assert_eq!(o.sends[0].bytes, read);
        assert_eq!(o.sends[0].kind, SendKind::Echo);

        let o = drive(&[Quirk::GarbageBeforeReply]).handle(Mode::Rtu, &read, now);
        assert_eq!(reply(&o).unwrap().bytes[3..], clean[..]);

        let o = drive(&[Quirk::TruncatedReply]).handle(Mode::Rtu, &read, now);
        assert_eq!(reply(&o).unwrap().bytes[..], clean[..clean.len() - 2]);

        let other = req(
            Mode::Rtu,
            9,
            Pdu::ReadRequest {
                start: 0x2520,
                count: 1,
            },
        );
        let o = drive(&[Quirk::AnswerEveryAddress]).handle(Mode::Rtu, &other, now);
        assert_eq!(reply(&o).unwrap().bytes[0], 9);
    }
}
