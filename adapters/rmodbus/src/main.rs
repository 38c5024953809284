//! `rmodbus-adapter`: lets the conformance gate (`conformance gate --codec CMD`) test the
//! codec of the `rmodbus` crate. It speaks the line-delimited JSON protocol of
//! `adapters/PROTOCOL.md` on standard input and output: one request line in, one answer
//! line out, flushed at once. Logs go to standard error.
//!
//! The work is done by rmodbus; this file only moves lines. See `ops.rs` for which rmodbus
//! function serves which operation, and README.md for what rmodbus gets wrong.

mod ops;

use std::io::{self, BufRead, Write};

fn main() {
    ops::install_panic_hook();
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
                eprintln!("rmodbus-adapter: reading standard input failed: {e}");
                break;
            }
        }
        // A line that is not UTF-8 is not JSON either: handle_line answers it with an error.
        let text = String::from_utf8_lossy(&line);
        let text = text.trim();
        if text.is_empty() {
            // The gate never sends blank lines; an answer to one would carry no id and
            // would be taken as the (malformed) answer to the gate's next request.
            continue;
        }
        let answer = ops::handle_line(text);
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
