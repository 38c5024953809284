//! How a long command is stopped: Ctrl-C (SIGINT), and SIGTERM and SIGHUP, which `timeout`,
//! CI runners, systemd and a closed terminal send, all set one flag. Every long command
//! (check, fuzz, scan, identify, simulate, gate) polls it between its steps (a check, a
//! fuzz case, a probe, a served frame): it stops after the current one, restores what it
//! wrote, and writes a whole report marked incomplete (exit 2; simulate exits 0).
//!
//! One handler per process (the `ctrlc` crate allows one), installed on first use; a
//! command that asks twice (`check --model auto` identifies, then checks) gets the same
//! flag.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, OnceLock};

use anyhow::Context;

static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();

/// The flag that SIGINT, SIGTERM and SIGHUP set, with the handler installed.
pub fn stop_flag() -> anyhow::Result<Arc<AtomicBool>> {
    if let Some(flag) = FLAG.get() {
        return Ok(flag.clone());
    }
    let flag = Arc::new(AtomicBool::new(false));
    let set = flag.clone();
    ctrlc::set_handler(move || {
        // The handler runs on ctrlc's own thread, not in the signal context: printing is
        // safe. Said once, so that a user who presses Ctrl-C twice sees why it goes on.
        if !set.swap(true, Ordering::Relaxed) {
            eprintln!("interrupted: stopping after the current step (check, case or probe)");
        }
    })
    .context("cannot install the handler of Ctrl-C, SIGTERM and SIGHUP")?;
    Ok(FLAG.get_or_init(|| flag).clone())
}
