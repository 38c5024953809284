//! How a long command is stopped: Ctrl-C (SIGINT), and SIGTERM and SIGHUP, which `timeout`,
//! CI runners, systemd and a closed terminal send, all set one flag. Every long command
//! polls it between its steps. check, fuzz, scan, identify and gate stop after the current
//! one (a check, a fuzz case, a probe), restore what they wrote, and write a whole report
//! marked incomplete (exit 2); monitor stops listening and writes its report as at the end
//! of its input; watch ends after its current poll with its summary (exit 0, or 1 where
//! it saw an exception or a value out of range); bus and simulate stop and remove their
//! links (exit 0).
//!
//! One handler per process (the `ctrlc` crate allows one), installed on first use; a
//! command that asks twice (`check --model auto` identifies, then checks) gets the same
//! flag. What the handler says is the command's: each asks with its own [`Stopping`].

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, OnceLock};

use anyhow::Context;

static FLAG: OnceLock<Arc<AtomicBool>> = OnceLock::new();
static SAYS: Mutex<Stopping> = Mutex::new(Stopping::AfterStep);

/// What a command does when it is interrupted, which the handler says on stderr once.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Stopping {
    /// check, fuzz, scan, identify, gate: the current step ends, then the report.
    AfterStep,
    /// monitor: the listening ends and the report is written.
    Listening,
    /// bus: the line stops and the links go.
    Bus,
    /// simulate: the simulator stops and its link goes.
    Simulator,
    /// watch: the current poll ends, then the summary.
    Watching,
}

impl Stopping {
    /// The line the handler prints.
    pub fn words(self) -> &'static str {
        match self {
            Stopping::AfterStep => {
                "interrupted: stopping after the current step (check, case or probe)"
            }
            Stopping::Listening => {
                "interrupted: the monitor stops listening and writes its report of what it heard"
            }
            Stopping::Bus => "interrupted: the bus stops and removes its links",
            Stopping::Simulator => "interrupted: the simulator stops and removes its link",
            Stopping::Watching => {
                "interrupted: the watch ends after the current poll, with its summary"
            }
        }
    }
}

/// The flag that SIGINT, SIGTERM and SIGHUP set, with the handler installed; the handler
/// says what a command that stops after its current step does.
pub fn stop_flag() -> anyhow::Result<Arc<AtomicBool>> {
    stop_flag_saying(Stopping::AfterStep)
}

/// [`stop_flag`] for a command that stops as `stopping` says.
pub fn stop_flag_saying(stopping: Stopping) -> anyhow::Result<Arc<AtomicBool>> {
    *SAYS.lock().unwrap_or_else(|e| e.into_inner()) = stopping;
    if let Some(flag) = FLAG.get() {
        return Ok(flag.clone());
    }
    let flag = Arc::new(AtomicBool::new(false));
    let set = flag.clone();
    ctrlc::set_handler(move || {
        // The handler runs on ctrlc's own thread, not in the signal context: printing is
        // safe. Said once, so that a user who presses Ctrl-C twice sees why it goes on.
        if !set.swap(true, Ordering::Relaxed) {
            let says = *SAYS.lock().unwrap_or_else(|e| e.into_inner());
            eprintln!("{}", says.words());
        }
    })
    .context("cannot install the handler of Ctrl-C, SIGTERM and SIGHUP")?;
    Ok(FLAG.get_or_init(|| flag).clone())
}
