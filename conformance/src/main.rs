//! `conformance`: the command line of the TECO Modbus conformance suite.
//!
//! Exit codes: 0 success (frames valid, vectors behave as their verdicts say);
//! 1 the command ran and found a problem (a checksum mismatch, a vector that fails);
//! 2 the command could not run (bad arguments, unreadable input).

mod cli;

use std::process::ExitCode;

use clap::Parser;

fn main() -> ExitCode {
    // Output piped into `head` should end the program quietly, as in other Unix tools,
    // not panic on a broken pipe.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let args = cli::Cli::parse();
    match cli::run(args) {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {err:#}");
            ExitCode::from(2)
        }
    }
}
