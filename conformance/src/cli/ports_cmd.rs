//! `conformance ports`: which serial port is which adapter, before anything is sent.

use std::path::PathBuf;
use std::process::ExitCode;

use clap::{Args, ValueEnum};
use conformance::ports::{self, Roots};

/// Arguments of `conformance ports`.
#[derive(Debug, Args)]
#[command(after_help = "\
For a USB adapter with a latency timer (FTDI), it says what the timer does to RTU framing at \
9600, 19200, 38400 and 115200 baud and gives the command that sets it to 1 ms. For every port, \
whether you may open it (the group dialout on Debian and Ubuntu) and a lock file another program \
holds on it, by its pid. Nothing is opened or sent.

Exit codes: 0 ports were listed; 1 none were found (with a hint); 2 the listing failed.")]
pub struct PortsArgs {
    /// Output: text for people, or JSON for scripts.
    #[arg(long, value_enum, default_value_t = Format::Text)]
    format: Format,
    /// Read sys/, dev/, var/lock and run/lock under DIR in place of / (a fake tree for
    /// tests).
    #[arg(long, value_name = "DIR", hide = true)]
    root: Option<PathBuf>,
}

/// Output format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
enum Format {
    /// One block a port, then the count.
    Text,
    /// `{"count", "hint", "ports": [...]}`.
    Json,
}

/// Runs `conformance ports`.
pub fn run(args: PortsArgs) -> anyhow::Result<ExitCode> {
    let roots = match &args.root {
        Some(r) => Roots::under(r),
        None => Roots::system(),
    };
    let found = ports::list(&roots)?;
    match args.format {
        Format::Text => print!("{}", ports::text(&found, &roots)),
        Format::Json => println!(
            "{}",
            serde_json::to_string_pretty(&ports::json(&found, &roots))?
        ),
    }
    Ok(if found.is_empty() {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}
