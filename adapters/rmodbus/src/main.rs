//! `rmodbus-adapter`: lets the conformance gate (`conformance gate --codec CMD`) test the
//! codec of the `rmodbus` crate. It speaks the line-delimited JSON protocol of
//! `adapters/PROTOCOL.md` on standard input and output: one request line in, one answer
//! line out, flushed at once. Logs go to standard error.
//!
//! The work is done by rmodbus; this file only moves lines. See `ops.rs` for which rmodbus
//! function serves which operation, and README.md for what rmodbus gets wrong.

mod ops;

fn main() {
    adapter_lines::install_panic_hook("rmodbus-adapter");
    adapter_lines::serve("rmodbus-adapter", ops::handle_line);
}
