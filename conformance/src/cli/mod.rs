//! Argument parsing and dispatch. Each subcommand lives in its own module.

mod codec_cmd;
mod vectors_cmd;

use std::process::ExitCode;

use clap::{Parser, Subcommand};

/// Conformance and fuzz test suite for the Modbus RTU/ASCII protocol of TECO F510, A510,
/// L510 and E510 AC drives.
#[derive(Debug, Parser)]
#[command(name = "conformance", version, about, long_about = None)]
#[command(
    after_help = "Exit codes: 0 ok; 1 a problem was found (bad checksum, failing vector); 2 the command could not run."
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Decode one RTU or ASCII frame and check its checksum and length fields.
    Decode(codec_cmd::DecodeArgs),
    /// Build a frame from fields and print it in RTU hex and ASCII.
    Encode(codec_cmd::EncodeArgs),
    /// The golden vectors transcribed from the manuals: list, verify, export.
    Vectors(vectors_cmd::VectorsArgs),
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Decode(a) => codec_cmd::decode(a),
        Command::Encode(a) => codec_cmd::encode(a),
        Command::Vectors(a) => vectors_cmd::run(a),
    }
}
