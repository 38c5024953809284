//! Arguments shared by several commands: numbers in hex or decimal, the serial line as
//! mbpoll spells it, the model and the transmission mode.
//!
//! The number rule, everywhere: `2520H`, `2520h`, `0x2520` are hex, as the manuals and
//! the reports write registers; a bare number is decimal (`2520` is 09D8H), kept so for
//! the command lines written before hex was accepted. Options that take register
//! numbers, values or codes print a note on stderr when a bare number's digits would be
//! another value read as hex.

use std::ffi::OsStr;
use std::marker::PhantomData;

use clap::builder::TypedValueParser;
use clap::{Args, ValueEnum};
use conformance::codec::timing::{LineSettings, Parity};
use conformance::codec::Mode;
use conformance::model::DriveModel;

/// How numbers are spelled on the command line; every numeric option's help says it.
pub const NUMBER_RULE: &str =
    "hex with H suffix or 0x prefix (2520H, 0x2520); a bare number is decimal (9504)";

/// Why a number on the command line was refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum NumberError {
    /// Not a number in any of the accepted spellings.
    #[error("{text:?} is not a number: write {}", NUMBER_RULE)]
    NotANumber {
        /// The text given.
        text: String,
    },
    /// A number too large for the field.
    #[error("{text:?} is over {max:X}H ({max}), the largest value of this field")]
    TooLarge {
        /// The text given.
        text: String,
        /// The largest value the field holds.
        max: u16,
    },
}

/// Reads a number spelled as [`NUMBER_RULE`] says: `2520H`, `2520h`, `0x2520`, `0X2520`
/// are hex, a bare number of digits is decimal; at most `max`.
pub fn parse_number(text: &str, max: u16) -> Result<u16, NumberError> {
    let t = text.trim();
    let (digits, radix) = if let Some(h) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        (h, 16)
    } else if let Some(h) = t.strip_suffix(['H', 'h']) {
        (h, 16)
    } else {
        (t, 10)
    };
    if digits.is_empty() || !digits.chars().all(|c| c.is_digit(radix)) {
        return Err(NumberError::NotANumber { text: text.into() });
    }
    let too_large = || NumberError::TooLarge {
        text: text.into(),
        max,
    };
    // Only digits of the radix are left, so the one possible error is an overflow.
    let v = u64::from_str_radix(digits, radix).map_err(|_| too_large())?;
    u16::try_from(v)
        .ok()
        .filter(|&v| v <= max)
        .ok_or_else(too_large)
}

/// Reads a function or exception code, always hex (`03`, `83H`, `0x10`): 01..7F, the codes
/// a request can carry; `what` names it in the error ("a function code").
pub fn parse_code(text: &str, what: &str) -> Result<u8, String> {
    let t = text.trim().trim_end_matches(['h', 'H']);
    let t = t.strip_prefix("0x").unwrap_or(t);
    match u8::from_str_radix(t, 16) {
        Ok(c) if (1..0x80).contains(&c) => Ok(c),
        _ => Err(format!("{text:?} is not {what} (hex 01..7F)")),
    }
}

/// The note for a bare number whose digits, read as hex, are another value of the field:
/// `note: --start 2520 is decimal (09D8H); write 2520H or 0x2520 for hex`. `None` where
/// the number is spelled as hex or reads the same both ways (0..9).
pub fn decimal_note(option: &str, text: &str, value: u16, max: u16) -> Option<String> {
    let t = text.trim();
    if t.is_empty() || !t.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    let hex = u64::from_str_radix(t, 16)
        .ok()
        .filter(|&h| h <= u64::from(max))?;
    if hex == u64::from(value) {
        return None;
    }
    let width = if max > 0xFF { 4 } else { 2 };
    Some(format!(
        "note: {option} {t} is decimal ({value:0width$X}H); write {t}H or 0x{t} for hex"
    ))
}

/// A field of the width of `T` (u8 or u16).
pub trait Width: Copy + TryFrom<u16> + Send + Sync + 'static {
    /// The largest value.
    const MAX: u16;
}

impl Width for u8 {
    const MAX: u16 = 0xFF;
}

impl Width for u16 {
    const MAX: u16 = 0xFFFF;
}

/// The value parser of a numeric option: [`parse_number`], and, with `note`, the
/// [`decimal_note`] on stderr for a bare number that would differ as hex.
#[derive(Debug, Clone, Copy)]
pub struct Number<T> {
    note: bool,
    width: PhantomData<T>,
}

impl<T: Width> Number<T> {
    /// A register number, value or code: a bare number that reads differently as hex
    /// gets the note.
    pub const fn noted() -> Self {
        Number {
            note: true,
            width: PhantomData,
        }
    }

    /// A quantity or an address people give in decimal: no note.
    pub const fn quiet() -> Self {
        Number {
            note: false,
            width: PhantomData,
        }
    }
}

impl<T: Width> TypedValueParser for Number<T> {
    type Value = T;

    fn parse_ref(
        &self,
        cmd: &clap::Command,
        arg: Option<&clap::Arg>,
        value: &OsStr,
    ) -> Result<T, clap::Error> {
        // Through clap's own parser of a function, for its usual error text:
        // "invalid value '25G0H' for '--start <START>': ...".
        let n = (|s: &str| parse_number(s, T::MAX)).parse_ref(cmd, arg, value)?;
        if self.note {
            let text = value.to_string_lossy();
            let option = arg
                .and_then(|a| a.get_long())
                .map_or_else(|| "value".to_string(), |l| format!("--{l}"));
            if let Some(note) = decimal_note(&option, &text, n, T::MAX) {
                eprintln!("{note}");
            }
        }
        T::try_from(n)
            .map_err(|_| clap::Error::new(clap::error::ErrorKind::ValueValidation).with_cmd(cmd))
    }
}

/// How durations are spelled on the command line; every option that takes one says it.
pub const DURATION_RULE: &str =
    "a bare number is seconds (90, 1.5); or with a unit: 90s, 2m, 1h30m, 500ms, 2900us";

/// Reads a duration spelled as [`DURATION_RULE`] says: a bare number (digits, at most one
/// decimal point) is seconds, anything else is read by humantime (`90s`, `2m`, `1h 30m`).
pub fn parse_duration(text: &str) -> Result<std::time::Duration, String> {
    let t = text.trim();
    let bare = !t.is_empty()
        && t.bytes().all(|b| b.is_ascii_digit() || b == b'.')
        && t.bytes().filter(|&b| b == b'.').count() <= 1
        && t != ".";
    if bare {
        return t
            .parse::<f64>()
            .ok()
            .and_then(|s| std::time::Duration::try_from_secs_f64(s).ok())
            .ok_or_else(|| format!("{text:?} is too long a duration"));
    }
    humantime::parse_duration(t)
        .map_err(|e| format!("{text:?} is not a duration ({e}); {DURATION_RULE}"))
}

/// Transmission mode.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ModeArg {
    /// Binary frames with CRC-16.
    Rtu,
    /// Hex-character frames with LRC.
    Ascii,
}

impl From<ModeArg> for Mode {
    fn from(m: ModeArg) -> Mode {
        match m {
            ModeArg::Rtu => Mode::Rtu,
            ModeArg::Ascii => Mode::Ascii,
        }
    }
}

/// Parity, as mbpoll spells it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ParityArg {
    /// No parity bit.
    None,
    /// Even parity.
    Even,
    /// Odd parity.
    Odd,
}

/// The serial line, as mbpoll spells it.
#[derive(Debug, Clone, Args)]
pub struct LineArgs {
    /// Baud rate.
    #[arg(short = 'b', long = "baud", default_value_t = 9600)]
    pub baud: u32,
    /// Parity.
    #[arg(short = 'P', long = "parity", value_enum, default_value = "even")]
    pub parity: ParityArg,
    /// Data bits (7 or 8; RTU needs 8).
    #[arg(short = 'd', long = "data-bits", default_value_t = 8, value_parser = clap::value_parser!(u8).range(7..=8))]
    pub data_bits: u8,
    /// Stop bits (1 or 2).
    #[arg(short = 's', long = "stop-bits", default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    pub stop_bits: u8,
    #[command(flatten)]
    pub rts: RtsArgs,
}

/// RS-485 direction control by RTS, for adapters whose driver enable hangs on RTS.
#[derive(Debug, Clone, Args)]
pub struct RtsArgs {
    /// RS-485 direction control: raise RTS while sending, drop it when the last bit has
    /// left (tcdrain, then one character time). For adapters with DE/RE on RTS (plain
    /// MAX485 boards); adapters with automatic direction control (most FTDI and CH340
    /// RS-485 adapters) do not need it. Serial ports only (a pseudo-terminal has no RTS).
    #[arg(long)]
    pub rts: bool,
    /// With --rts: keep RTS up this many microseconds longer after the last character
    /// (as libmodbus's RTS delay, which mbpoll's -R/-F use), for slow transceivers.
    #[arg(long, value_name = "US", requires = "rts")]
    pub rts_delay: Option<u64>,
}

impl RtsArgs {
    /// Refuses --rts without a serial port (`port`: the --port given, if any): a
    /// pseudo-terminal, TCP or the simulator has no RTS line.
    pub fn needs_port(&self, port: Option<&str>) -> anyhow::Result<()> {
        if self.rts && port.is_none() {
            anyhow::bail!("--rts drives the RTS line of a serial port: give --port PATH");
        }
        Ok(())
    }

    /// The direction control asked for, if any.
    pub fn control(&self) -> Option<conformance::transport::serial::RtsControl> {
        self.rts
            .then(|| conformance::transport::serial::RtsControl {
                extra: std::time::Duration::from_micros(self.rts_delay.unwrap_or(0)),
            })
    }
}

impl LineArgs {
    /// The line settings.
    pub fn settings(&self) -> LineSettings {
        let parity = match self.parity {
            ParityArg::None => Parity::None,
            ParityArg::Even => Parity::Even,
            ParityArg::Odd => Parity::Odd,
        };
        LineSettings::new(self.baud, self.data_bits, parity, self.stop_bits)
    }
}

/// Loads the built-in model `id`, or a model file given instead, and checks that
/// `address` is one of its node addresses.
pub fn load_model(
    id: &str,
    file: Option<&std::path::Path>,
    address: u8,
) -> anyhow::Result<DriveModel> {
    let model = match file {
        Some(path) => DriveModel::from_path(path)?,
        None => DriveModel::builtin(id)?,
    };
    if !model.addresses.contains(&address) {
        anyhow::bail!(
            "address {:02X} is outside the {} model's node addresses {:02X}..{:02X}",
            address,
            model.id,
            model.addresses.start(),
            model.addresses.end()
        );
    }
    Ok(model)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bare_number_is_seconds_and_units_are_humantime() {
        use std::time::Duration;
        assert_eq!(parse_duration("90"), Ok(Duration::from_secs(90)));
        assert_eq!(parse_duration(" 90 "), Ok(Duration::from_secs(90)));
        assert_eq!(parse_duration("1.5"), Ok(Duration::from_millis(1500)));
        assert_eq!(parse_duration("0"), Ok(Duration::ZERO));
        assert_eq!(parse_duration("90s"), Ok(Duration::from_secs(90)));
        assert_eq!(parse_duration("2m"), Ok(Duration::from_secs(120)));
        assert_eq!(parse_duration("1h 30m"), Ok(Duration::from_secs(5400)));
        assert_eq!(parse_duration("2900us"), Ok(Duration::from_micros(2900)));
        for bad in ["", ".", "1.2.3", "-5", "5 parsecs", "s"] {
            let e = parse_duration(bad).unwrap_err();
            assert!(e.starts_with(&format!("{bad:?} is not a duration")), "{e}");
            assert!(e.contains("a bare number is seconds"), "{e}");
        }
        assert!(parse_duration("1e400").is_err());
    }

    #[test]
    fn hex_with_h_or_0x_and_bare_decimal() {
        for t in ["2520H", "2520h", "0x2520", "0X2520", " 2520H "] {
            assert_eq!(parse_number(t, 0xFFFF), Ok(0x2520), "{t}");
        }
        assert_eq!(parse_number("2520", 0xFFFF), Ok(2520));
        assert_eq!(parse_number("FFH", 0xFF), Ok(0xFF));
        assert_eq!(parse_number("0", 0xFF), Ok(0));
    }

    #[test]
    fn bad_numbers_name_the_text() {
        for t in [
            "", "H", "0x", "25G0H", "+5", "-1", "0x2520H", "2520HH", "12 34",
        ] {
            assert_eq!(
                parse_number(t, 0xFFFF),
                Err(NumberError::NotANumber { text: t.into() }),
                "{t}"
            );
        }
        let e = parse_number("0x100", 0xFF).unwrap_err();
        assert_eq!(
            e.to_string(),
            "\"0x100\" is over FFH (255), the largest value of this field"
        );
        assert!(matches!(
            parse_number("99999999999999999999999", 0xFFFF),
            Err(NumberError::TooLarge { .. })
        ));
        assert!(parse_number("25G0H", 0xFFFF)
            .unwrap_err()
            .to_string()
            .starts_with("\"25G0H\" is not a number: write hex with H suffix"));
    }

    #[test]
    fn the_note_only_for_bare_numbers_that_differ_as_hex() {
        assert_eq!(
            decimal_note("--start", "2520", 2520, 0xFFFF).as_deref(),
            Some("note: --start 2520 is decimal (09D8H); write 2520H or 0x2520 for hex")
        );
        assert_eq!(
            decimal_note("--address", "10", 10, 0xFF).as_deref(),
            Some("note: --address 10 is decimal (0AH); write 10H or 0x10 for hex")
        );
        // Spelled as hex, the same both ways, or too large as hex for the field.
        assert_eq!(decimal_note("--start", "2520H", 0x2520, 0xFFFF), None);
        assert_eq!(decimal_note("--start", "0x2520", 0x2520, 0xFFFF), None);
        assert_eq!(decimal_note("--start", "9", 9, 0xFFFF), None);
        assert_eq!(decimal_note("--address", "200", 200, 0xFF), None);
        assert_eq!(decimal_note("--start", "65535", 65535, 0xFFFF), None);
    }
}

/// Node addresses of one bus: `-a 1,2,5`, ranges `-a 1-4,9`; each decimal as in mbpoll,
/// or hex with H suffix or 0x prefix. In order given, no repeats, no 0 (broadcast) in a
/// list of several.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeList(pub Vec<u8>);

impl NodeList {
    /// The first node (the only one where a command takes one).
    pub fn first(&self) -> u8 {
        self.0.first().copied().unwrap_or(1)
    }
}

/// Parses a [`NodeList`].
pub fn parse_nodes(text: &str) -> Result<NodeList, String> {
    let mut out: Vec<u8> = Vec::new();
    let one = |s: &str| -> Result<u8, String> {
        let n = parse_number(s.trim(), 255).map_err(|e| e.to_string())?;
        u8::try_from(n).map_err(|_| format!("{s:?} is over 255"))
    };
    for part in text.split(',') {
        if part.trim().is_empty() {
            return Err(format!("{text:?}: an empty entry (write 1,2,5 or 1-4)"));
        }
        let (a, b) = match part.split_once('-') {
            Some((a, b)) => (one(a)?, one(b)?),
            None => {
                let a = one(part)?;
                (a, a)
            }
        };
        if a > b {
            return Err(format!("{part:?}: the range runs backwards"));
        }
        for n in a..=b {
            if out.contains(&n) {
                return Err(format!("node {n} is named twice"));
            }
            out.push(n);
        }
    }
    if out.len() > 1 && out.contains(&0) {
        return Err("0 is the broadcast address, not a node: leave it out of a list".into());
    }
    Ok(NodeList(out))
}

#[cfg(test)]
mod node_list_tests {
    use super::*;

    #[test]
    fn lists_ranges_and_refusals() {
        assert_eq!(parse_nodes("1").unwrap().0, [1]);
        assert_eq!(parse_nodes("1,2,5").unwrap().0, [1, 2, 5]);
        assert_eq!(parse_nodes("3-5,0AH").unwrap().0, [3, 4, 5, 10]);
        assert_eq!(parse_nodes("0x10").unwrap().0, [16]);
        assert!(parse_nodes("1,1").unwrap_err().contains("twice"));
        assert!(parse_nodes("5-3").unwrap_err().contains("backwards"));
        assert!(parse_nodes("0,1").unwrap_err().contains("broadcast"));
        assert!(parse_nodes("1,,2").is_err());
        assert!(parse_nodes("256").is_err());
        assert!(parse_nodes("x").is_err());
    }
}

/// Points the symbolic link `link` (`--link`) at `target`. A symbolic link already there
/// (one a killed run left) is replaced; anything else is refused, never deleted.
/// `refused` (after "--link PATH: ") and `replaced` (what cannot be replaced) word the
/// two errors as the command has always said them.
#[cfg(unix)]
pub fn point_link(
    link: &std::path::Path,
    target: &std::path::Path,
    refused: &str,
    replaced: &str,
) -> anyhow::Result<()> {
    use anyhow::Context;
    if let Ok(meta) = std::fs::symlink_metadata(link) {
        if !meta.file_type().is_symlink() {
            anyhow::bail!("--link {}: {refused}", link.display());
        }
        std::fs::remove_file(link)
            .with_context(|| format!("cannot replace {replaced} {}", link.display()))?;
    }
    std::os::unix::fs::symlink(target, link)
        .with_context(|| format!("cannot link {} to {}", link.display(), target.display()))
}
