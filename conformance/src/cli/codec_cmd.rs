//! `conformance decode` and `conformance encode`.

use std::process::ExitCode;

use anyhow::{bail, Context};
use clap::{Args, Subcommand};

use super::common::Number;
use conformance::codec::{
    self, ascii::Scratch, hex::parse_hex, hex::Hex, Direction, Message, Mode, Pdu, Registers,
    MAX_RTU_FRAME,
};

#[derive(Debug, Args)]
pub struct DecodeArgs {
    /// The frame is RTU (hex bytes).
    #[arg(long, conflicts_with = "ascii")]
    rtu: bool,
    /// The frame is ASCII: literal characters (":010301230001D7", CR LF optional) or the
    /// hex codes of the characters ("3A 30 31 ...").
    #[arg(long)]
    ascii: bool,
    /// Decode as a request (master to slave) only.
    #[arg(long, conflicts_with = "response")]
    request: bool,
    /// Decode as a response (slave to master) only.
    #[arg(long)]
    response: bool,
    /// The frame: hex with or without spaces ("01 03 01 23 00 01 74 3C"), or ASCII
    /// characters. Several words are joined.
    #[arg(required = true, num_args = 1..)]
    frame: Vec<String>,
}

/// Reads the frame argument into bytes and mode.
fn frame_bytes(args: &DecodeArgs) -> anyhow::Result<(Mode, Vec<u8>, Option<String>)> {
    let text = args.frame.join(" ");
    let trimmed = text.trim();
    let literal_ascii = trimmed.starts_with(':');
    if args.rtu && literal_ascii {
        bail!("--rtu given, but the frame starts with ':' (an ASCII frame)");
    }
    if literal_ascii {
        let mut chars = trimmed
            .replace("\\r", "\r")
            .replace("\\n", "\n")
            .into_bytes();
        let mut note = None;
        if !chars.ends_with(b"\r\n") {
            chars.extend_from_slice(b"\r\n");
            note = Some("CR LF appended: the frame was given without it".to_string());
        }
        return Ok((Mode::Ascii, chars, note));
    }
    let bytes = parse_hex(trimmed).with_context(|| format!("reading frame {trimmed:?}"))?;
    let mode = if args.ascii { Mode::Ascii } else { Mode::Rtu };
    Ok((mode, bytes, None))
}

pub fn decode(args: DecodeArgs) -> anyhow::Result<ExitCode> {
    let (mode, bytes, note) = frame_bytes(&args)?;
    match mode {
        Mode::Rtu => println!("RTU frame, {} bytes: {}", bytes.len(), Hex(&bytes)),
        Mode::Ascii => println!(
            "ASCII frame, {} characters: {:?}\n  as hex: {}",
            bytes.len(),
            String::from_utf8_lossy(&bytes),
            Hex(&bytes)
        ),
    }
    if let Some(n) = note {
        println!("  note: {n}");
    }
    let directions: &[Direction] = if args.request {
        &[Direction::Request]
    } else if args.response {
        &[Direction::Response]
    } else {
        &[Direction::Request, Direction::Response]
    };
    let mut best = 2u8;
    for &dir in directions {
        let mut scratch: Scratch = [0; MAX_RTU_FRAME];
        match codec::decode_unchecked(mode, &bytes, dir, &mut scratch) {
            Ok(u) => {
                println!("as {dir}:");
                for (k, v) in u.message.fields() {
                    println!("  {k:<16}{v}");
                }
                if u.checksum.is_valid() {
                    println!("  {:<16}{}", "checksum", u.checksum);
                    best = 0;
                } else {
                    println!("  {:<16}{}", "checksum", u.checksum);
                    let fixed = u.message.to_frame_vec(mode)?;
                    println!("  decoded unchecked; the correct frame is {}", Hex(&fixed));
                    if mode == Mode::Ascii {
                        println!("  (characters {:?})", String::from_utf8_lossy(&fixed));
                    }
                    best = best.min(1);
                }
            }
            Err(e) => println!("as {dir}: not a valid frame: {e}"),
        }
    }
    Ok(ExitCode::from(best))
}

/// Numbers, everywhere in `encode`: hex with H suffix or 0x prefix (2520H, 0x2520), as the
/// manuals, the reports and `decode` write them; a bare number is decimal (2520 is 09D8H).
/// A bare register number, value or code whose digits would be another value read as hex
/// gets a note on stderr.
#[derive(Debug, Args)]
#[command(
    after_help = "Numbers: hex with H suffix or 0x prefix (2520H, 0x2520), as the manuals, \
the reports and `decode` write them; a bare number is decimal (2520 is 09D8H), and a bare \
register number, value or code whose digits differ read as hex gets a note on stderr. \
--data is hex bytes.\n\nExamples:\n  conformance encode read --start 2520H --count 2\n  \
conformance encode --address 0x01 write --register 0x2502 --value 1770H\n  \
conformance encode loopback --data \"A5 37\""
)]
pub struct EncodeArgs {
    /// Node address (0 is broadcast): hex with H suffix or 0x prefix (0AH, 0x0A); a bare
    /// number is decimal.
    #[arg(short, long, value_parser = Number::<u8>::noted(), default_value = "1")]
    address: u8,
    #[command(subcommand)]
    message: EncodeMessage,
}

#[derive(Debug, Subcommand)]
enum EncodeMessage {
    /// 03H request: read holding registers.
    Read {
        /// First register: hex with H suffix or 0x prefix (2520H, 0x2520); a bare number
        /// is decimal (2520 is 09D8H).
        #[arg(long, value_parser = Number::<u16>::noted())]
        start: u16,
        /// Number of registers: a bare number is decimal (10); hex with H suffix or 0x
        /// prefix (0AH, 0x0A).
        #[arg(long, value_parser = Number::<u16>::quiet())]
        count: u16,
    },
    /// 03H response: the values read.
    ReadReply {
        /// Values, comma separated (1770H,0x0000): hex with H suffix or 0x prefix; a bare
        /// number is decimal (6000 is 1770H).
        #[arg(long, value_parser = Number::<u16>::noted(), value_delimiter = ',', required = true)]
        values: Vec<u16>,
    },
    /// 06H request (its normal response is the same frame).
    Write {
        /// Register: hex with H suffix or 0x prefix (2502H, 0x2502); a bare number is
        /// decimal (2502 is 09C6H).
        #[arg(long, value_parser = Number::<u16>::noted())]
        register: u16,
        /// Value: hex with H suffix or 0x prefix (1770H, 0x1770); a bare number is decimal
        /// (6000 is 1770H).
        #[arg(long, value_parser = Number::<u16>::noted())]
        value: u16,
    },
    /// 08H loop-back request (its normal response is the same frame).
    Loopback {
        /// Test code (sub-function): hex with H suffix or 0x prefix (0000H, 0x0000); a
        /// bare number is decimal.
        #[arg(long, value_parser = Number::<u16>::noted(), default_value = "0")]
        test_code: u16,
        /// Data bytes, always hex, with or without spaces ("A5 37", "A537").
        #[arg(long, default_value = "00 00")]
        data: String,
    },
    /// 10H request: write several registers.
    WriteMulti {
        /// First register: hex with H suffix or 0x prefix (2502H, 0x2502); a bare number
        /// is decimal (2502 is 09C6H).
        #[arg(long, value_parser = Number::<u16>::noted())]
        start: u16,
        /// Values, comma separated (1770H,0x0000): hex with H suffix or 0x prefix; a bare
        /// number is decimal (6000 is 1770H).
        #[arg(long, value_parser = Number::<u16>::noted(), value_delimiter = ',', required = true)]
        values: Vec<u16>,
    },
    /// 10H response: start and count echoed.
    WriteMultiReply {
        /// First register: hex with H suffix or 0x prefix (2502H, 0x2502); a bare number
        /// is decimal (2502 is 09C6H).
        #[arg(long, value_parser = Number::<u16>::noted())]
        start: u16,
        /// Number of registers: a bare number is decimal (10); hex with H suffix or 0x
        /// prefix (0AH, 0x0A).
        #[arg(long, value_parser = Number::<u16>::quiet())]
        count: u16,
    },
    /// Exception response.
    Exception {
        /// Function code of the failed request, without 80H: hex with H suffix or 0x
        /// prefix (03H, 0x10); a bare number is decimal (16 is 10H).
        #[arg(long, value_parser = Number::<u8>::noted())]
        function: u8,
        /// Exception code: hex with H suffix or 0x prefix (02H, 0x51); a bare number is
        /// decimal.
        #[arg(long, value_parser = Number::<u8>::noted())]
        code: u8,
    },
    /// Any function code with raw data.
    Raw {
        /// Function code: hex with H suffix or 0x prefix (41H, 0x41); a bare number is
        /// decimal.
        #[arg(long, value_parser = Number::<u8>::noted())]
        function: u8,
        /// Data bytes, always hex, with or without spaces ("25 20 00 01").
        #[arg(long, default_value = "")]
        data: String,
    },
}

pub fn encode(args: EncodeArgs) -> anyhow::Result<ExitCode> {
    let words = |v: &[u16]| v.iter().flat_map(|x| x.to_be_bytes()).collect::<Vec<u8>>();
    let (reg_bytes, raw): (Vec<u8>, Vec<u8>) = match &args.message {
        EncodeMessage::ReadReply { values } | EncodeMessage::WriteMulti { values, .. } => {
            (words(values), vec![])
        }
        EncodeMessage::Loopback { data, .. } | EncodeMessage::Raw { data, .. } => (
            vec![],
            parse_hex(data).with_context(|| format!("reading --data {data:?} (hex bytes)"))?,
        ),
        _ => (vec![], vec![]),
    };
    let pdu = match args.message {
        EncodeMessage::Read { start, count } => Pdu::ReadRequest { start, count },
        EncodeMessage::ReadReply { .. } => Pdu::ReadResponse {
            values: Registers::new(&reg_bytes)?,
        },
        EncodeMessage::Write { register, value } => Pdu::WriteSingle { register, value },
        EncodeMessage::Loopback { test_code, .. } => Pdu::LoopBack {
            test_code,
            data: &raw,
        },
        EncodeMessage::WriteMulti { start, .. } => Pdu::WriteMultipleRequest {
            start,
            values: Registers::new(&reg_bytes)?,
        },
        EncodeMessage::WriteMultiReply { start, count } => {
            Pdu::WriteMultipleResponse { start, count }
        }
        EncodeMessage::Exception { function, code } => {
            if function & 0x80 != 0 {
                bail!("--function {function:02X}: give the request's function code, without 80H");
            }
            Pdu::Exception { function, code }
        }
        EncodeMessage::Raw { function, .. } => Pdu::Other {
            function,
            data: &raw,
        },
    };
    let msg = Message {
        address: args.address,
        pdu,
    };
    let rtu = msg.to_rtu_vec()?;
    let ascii = msg.to_ascii_vec()?;
    println!("{msg}");
    println!("RTU    {}", Hex(&rtu));
    println!("ASCII  {:?}", String::from_utf8_lossy(&ascii));
    println!("       {}", Hex(&ascii));
    Ok(ExitCode::SUCCESS)
}
