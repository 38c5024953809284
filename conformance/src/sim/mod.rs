//! The simulated drive: a model's rules plus state, served over any transport.
//!
//! - [`drive`]: the drive itself ([`Drive::handle`]: one request in, transmissions out)
//!   and the fault-injection [`Quirk`]s.
//! - [`bus`]: several drives at distinct node addresses on one line (per-node state and
//!   quirks, `QUIRK@NODE`).
//! - [`server`]: the loop that reads a transport, deframes requests, answers after the
//!   response delay and logs the traffic. Bad input never stops it.
//! - [`line_clock`]: arrival times on the paced pseudo-terminal, which frames RTU by
//!   silence as a real line does.
//! - [`log`]: the traffic log.
//! - [`mbap`]: the drive behind a simulated Modbus TCP gateway (MBAP on TCP, several
//!   connections against one drive).

pub mod bus;
pub mod drive;
pub mod line_clock;
pub mod log;
pub mod mbap;
pub mod server;

pub use bus::{Bus, BusError, PlantedQuirk, Responder};
pub use drive::{Drive, Outcome, Quirk, SendKind, Transmission, QUIRK_HELP};
pub use log::{Dir, LogFormat, TrafficLog};
pub use server::{serve, serve_with_gap, ServeStats, SimError};
