//! Arguments shared by several commands: numbers in hex or decimal, the serial line as
//! mbpoll spells it, the model and the transmission mode.

use clap::{Args, ValueEnum};
use conformance::codec::timing::{LineSettings, Parity};
use conformance::codec::Mode;
use conformance::model::DriveModel;

/// A 16-bit number: 0x2520, 2520H or decimal 9504.
pub fn parse_u16(s: &str) -> Result<u16, String> {
    let t = s.trim();
    let parsed = if let Some(h) = t.strip_prefix("0x").or_else(|| t.strip_prefix("0X")) {
        u16::from_str_radix(h, 16)
    } else if let Some(h) = t.strip_suffix('H').or_else(|| t.strip_suffix('h')) {
        u16::from_str_radix(h, 16)
    } else {
        t.parse::<u16>()
    };
    parsed.map_err(|e| format!("{s:?} is not a 16-bit number (0x2520, 2520H or 9504): {e}"))
}

/// An 8-bit number, spelled as for [`parse_u16`].
pub fn parse_u8(s: &str) -> Result<u8, String> {
    let v = parse_u16(s)?;
    u8::try_from(v).map_err(|_| format!("{s:?} does not fit in one byte (00..FF)"))
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
