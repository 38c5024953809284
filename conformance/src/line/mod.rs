//! The emulated multi-drop line: an RS-485 pair that several programs and simulated
//! drives share, as masters, drives and a listener share one on a real installation.
//! Not to be confused with [`crate::sim::bus`], which is a set of simulated drives that
//! answer by node address; those drives can sit on this line, each as an endpoint.
//!
//! - [`wire`]: the pair itself, bit by bit (pure): each endpoint's transmitter, the
//!   wired-AND of every driver, the noise, the receiver, collisions.
//! - [`station`]: an endpoint inside this process, as a [`crate::transport::Transport`],
//!   for the simulator's server loop ([`crate::sim::serve`]) to serve a drive on.
//! - [`run`]: the endpoints (pseudo-terminals and stations) around one wire, the loop
//!   that carries their bytes at the line's character time.
//! - [`log`]: the line's JSON-lines log, written as it goes.
//!
//! What the line does, and why:
//!
//! - **Every byte reaches every other endpoint**, when its last bit is in (a UART hands
//!   a character over after its stop bit). The writer does not hear itself: a half-duplex
//!   RS-485 transceiver disables its receiver while it drives the pair (DE and /RE tied,
//!   as on the usual adapters and on the drives). An endpoint can be given local echo
//!   ([`run::Endpoint::with_echo`]): two-wire adapters whose receiver stays on (/RE tied
//!   low) hand a master its own request back, and masters must cope; the runner already
//!   detects such an echo, so a test can give it one.
//! - **A collision** is two endpoints driving at once. On copper two drivers that
//!   disagree leave the differential voltage undetermined; here the line is the
//!   wired-AND of the bit streams (a low bit wins, as on an open-collector bus or a CAN
//!   bus). It is deterministic, so a test can predict it, and it damages as a real
//!   collision does: start bits of one sender inside another's character, data that is
//!   neither's, parity and framing errors. Listeners get what the receiver reads from the
//!   damaged level; the log records who collided, from when to when, and how many
//!   characters the listeners read from it.
//! - **Noise** flips each bit driven on the line with a given probability, drawn from a
//!   seeded [`crate::rng::Rng`] in bit order, so the same traffic with the same seed
//!   gives the same flips. An idle line is left alone (a terminated, biased pair idles at
//!   1); a flip can still start a character where none was sent, by turning a driven 1
//!   into 0.
//! - **Time** is the line's bit clock from the start of the run. Each character is placed
//!   at the bit at which its bytes reached the line, or right after its endpoint's
//!   previous character (a UART with a FIFO); every later moment is computed from that,
//!   not measured, so the log's schedule is exact even on a busy host. Unpaced
//!   ([`run::LineConfig::paced`] false), bytes go through at once, a plain N-way bridge:
//!   no timing, no collisions (noise still applies, character by character).

pub mod log;
mod own_rx;
pub mod run;
mod signal;
pub mod station;
pub mod wire;

pub use log::LineLog;
pub use run::{EmulatedLine, Endpoint, LineConfig, LineStats};
pub use station::Station;
pub use wire::{Collision, Event, Flip, Heard, LineChar, Wire};

/// Why the line cannot be built or run.
#[derive(Debug, thiserror::Error)]
pub enum LineError {
    /// More endpoints than a line carries.
    #[error("{asked} endpoints on one line: at most {max}")]
    TooManyEndpoints {
        /// How many were asked for.
        asked: usize,
        /// The most.
        max: usize,
    },
    /// An endpoint index out of range.
    #[error("no endpoint {endpoint}: the line has {count}")]
    NoSuchEndpoint {
        /// The index.
        endpoint: usize,
        /// How many there are.
        count: usize,
    },
    /// A noise rate outside 0..=1.
    #[error("noise rate {0}: expected a probability per bit, 0 to 1")]
    NoiseRate(f64),
    /// Two endpoints with one name.
    #[error("two endpoints named {0:?}: each name is one endpoint")]
    SameName(String),
    /// An endpoint could not be made, read or written.
    #[error("endpoint {name}: {what} failed: {source}")]
    Io {
        /// The endpoint.
        name: String,
        /// What was done.
        what: &'static str,
        /// The cause.
        source: std::io::Error,
    },
    /// The log could not be written.
    #[error("cannot write the line's log: {0}")]
    Log(#[source] std::io::Error),
}
