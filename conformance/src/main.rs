//! `conformance`: the command line of the TECO Modbus conformance suite.
//!
//! Exit codes: 0 success (frames valid, vectors behave as their verdicts say);
//! 1 the command ran and found a problem (a checksum mismatch, a vector that fails);
//! 2 the command could not run (bad arguments, unreadable input).

mod cli;

use std::process::ExitCode;

fn main() -> ExitCode {
    // Output piped into `head` should end the program quietly, as in other Unix tools,
    // not panic on a broken pipe.
    #[cfg(unix)]
    // SAFETY: restoring the default disposition of SIGPIPE before any thread starts.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_DFL);
    }
    let args = cli::parse();
    match cli::run(args) {
        Ok(code) => code,
        Err(err) => {
            eprintln!("error: {}", chain(&err));
            ExitCode::from(2)
        }
    }
}

/// The error and its causes joined by ": ", as anyhow's `{:#}` does, but a cause that the
/// text already ends with is said once: the library's errors name their cause in their
/// own message ("cannot open /dev/ttyUSB9: No such file or directory") and also return
/// it as their source, which `{:#}` would print a second time.
fn chain(err: &anyhow::Error) -> String {
    let mut out = String::new();
    for cause in err.chain() {
        let text = cause.to_string();
        if out.ends_with(&text) {
            continue;
        }
        if !out.is_empty() {
            out.push_str(": ");
        }
        out.push_str(&text);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::chain;

    #[derive(Debug, thiserror::Error)]
    #[error("cannot open {what}: {source}")]
    struct Open {
        what: String,
        source: std::io::Error,
    }

    #[test]
    fn a_cause_already_in_the_message_is_said_once() {
        let open = Open {
            what: "/nonexistent".into(),
            source: std::io::Error::new(std::io::ErrorKind::NotFound, "No such file or directory"),
        };
        let err = anyhow::Error::new(open);
        assert_eq!(
            format!("{err:#}"),
            "cannot open /nonexistent: No such file or directory: No such file or directory"
        );
        assert_eq!(
            chain(&err),
            "cannot open /nonexistent: No such file or directory"
        );
        // A context above it, and a cause the message does not name, are kept.
        let err = err.context("check");
        assert_eq!(
            chain(&err),
            "check: cannot open /nonexistent: No such file or directory"
        );
        let err =
            anyhow::Error::new(std::io::Error::other("disk full")).context("cannot write r.json");
        assert_eq!(chain(&err), "cannot write r.json: disk full");
    }
}
