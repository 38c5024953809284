//! What the Rust codec adapters (`rmodbus-adapter`, `modbus-core-adapter`) share: the
//! line loop of `adapters/PROTOCOL.md` (one request line in, one answer line out,
//! flushed at once) and the panic a request raised, kept for its answer. What each
//! adapter answers is its own; only the moving of lines and panics is here, so that a
//! fix to the loop (blank lines, a gate gone away) is made once.

use std::any::Any;
use std::cell::RefCell;
use std::fmt::Display;
use std::io::{self, BufRead, Write};
use std::panic::{self, AssertUnwindSafe};

thread_local! {
    /// The last panic's message and location, kept by the hook for the answer.
    static LAST_PANIC: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// Makes panics short one-line logs on standard error (`NAME: message at file:line`) and
/// keeps their text for [`guarded`].
pub fn install_panic_hook(name: &'static str) {
    panic::set_hook(Box::new(move |info| {
        let text = info.to_string().replace('\n', " ");
        eprintln!("{name}: {text}");
        LAST_PANIC.with(|p| *p.borrow_mut() = Some(text));
    }));
}

/// Runs `f`, catching a panic: `Err` holds its text (the hook's, else the payload's;
/// `None` where neither says anything), so that the adapter can answer it (a decode
/// that panics is a rejection, "raised", not a crash of the adapter).
pub fn guarded<T>(f: impl FnOnce() -> T) -> Result<T, Option<String>> {
    LAST_PANIC.with(|p| p.borrow_mut().take());
    panic::catch_unwind(AssertUnwindSafe(f)).map_err(|payload| {
        LAST_PANIC
            .with(|p| p.borrow_mut().take())
            .or_else(|| payload_text(payload.as_ref()))
    })
}

fn payload_text(payload: &(dyn Any + Send)) -> Option<String> {
    payload
        .downcast_ref::<&str>()
        .map(|s| (*s).to_string())
        .or_else(|| payload.downcast_ref::<String>().cloned())
}

/// Answers every non-blank line of standard input with `answer(line)` on standard
/// output, flushed at once, until the input ends or the gate goes away. `name` prefixes
/// the one log line a failed read leaves on standard error.
pub fn serve<A: Display>(name: &str, mut answer: impl FnMut(&str) -> A) {
    let stdin = io::stdin();
    let mut input = stdin.lock();
    let stdout = io::stdout();
    let mut line = Vec::new();
    loop {
        line.clear();
        match input.read_until(b'\n', &mut line) {
            Ok(0) => break,
            Ok(_) => {}
            Err(e) => {
                eprintln!("{name}: reading standard input failed: {e}");
                break;
            }
        }
        // A line that is not UTF-8 is not JSON either: the adapter answers it with an
        // error.
        let text = String::from_utf8_lossy(&line);
        let text = text.trim();
        if text.is_empty() {
            // The gate never sends blank lines; an answer to one would carry no id and
            // would be taken as the (malformed) answer to the gate's next request.
            continue;
        }
        let answer = answer(text);
        let mut out = stdout.lock();
        if writeln!(out, "{answer}")
            .and_then(|()| out.flush())
            .is_err()
        {
            // The gate has gone away.
            break;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_panic_is_caught_with_its_text() {
        assert_eq!(guarded(|| 7), Ok(7));
        let caught = guarded(|| -> u8 { panic!("the frame is too short") });
        assert_eq!(caught, Err(Some("the frame is too short".to_string())));
    }
}
