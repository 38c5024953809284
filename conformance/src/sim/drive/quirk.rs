//! The fault-injection quirks: a deliberate deviation from the model each, spelt as on
//! the command line (`late-reply=MS`, `stuck-at=REG:VALUE`, ...).

use std::fmt;
use std::time::Duration;

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
