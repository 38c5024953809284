//! Conformance and fuzz test suite for the Modbus serial protocol (RTU and ASCII) of the
//! TECO F510, A510, L510 and E510 AC drives.
//!
//! Layers, lowest first; a lower layer never uses a higher one:
//! - [`codec`]: CRC, LRC, frames, messages, streaming deframers. Pure, no I/O.
//! - [`capture`]: pcapng writer and pcap/pcapng reader (Wireshark's formats). Pure, no I/O
//!   beyond `std::io::Write`.
//! - [`vectors`]: the manuals' example frames as golden vectors (data under `vectors/`),
//!   checked by the codec.
//! - [`model`]: the drive models (data under `vectors/models/`) and their rules.
//! - [`describe`]: descriptions in and out of other formats: a register map in CSV, and
//!   pymodbus's simulator JSON (pure, text to text).
//! - [`requirements`]: every wire-testable statement of the manuals (data under
//!   `vectors/requirements/`), traced to the checks, vectors, model facts, monitor kinds
//!   and oracle classes that verify it (the tracing reads the runner's check list).
//! - [`transport`]: serial port, pseudo-terminal, TCP, in-memory links behind one trait.
//! - [`sim`]: the simulated drive, with fault injection.
//! - [`line`] (Unix): the emulated multi-drop RS-485 line that programs and simulated
//!   drives share (pseudo-terminals around one pair, collisions, noise).
//! - [`runner`]: the conformance checks, run as a Modbus master against a device.
//! - [`judge`]: one conversation (request, reply, timing) against the model: a verdict
//!   with the manual's citations; `check`, the fuzzer and `monitor` share it.
//! - [`fuzz`]: malformed and hostile traffic, every answer predicted by the model.
//! - [`gate`]: checks another Modbus codec through an adapter process.
//! - [`monitor`]: listens to a bus it never writes to and judges both sides of every
//!   conversation through the [`judge`] (beside the runner, below the reports).
//! - [`expect`]: expectations files (known, accepted results) and how a run stands
//!   against one; [`report`] records the outcome and gives the exit code by it.
//! - [`report`]: text, JSON and JUnit XML reports of a run.
//! - [`ports`]: the serial ports of this machine (sysfs on Linux), their USB identity,
//!   latency timer, access rights and locks (below the transports: it opens nothing).
//! - [`scan`]: finds the devices on a line (line settings, mode, node addresses).
//! - [`session`]: a whole run against a serial port, a TCP gateway or the in-process simulator.
//! - [`watch`]: polls named registers with reads only and judges every value through
//!   the [`judge`] and the model (beside [`monitor`]; its text, CSV, JSON lines and HTML
//!   are in [`report`]).
//! - [`params`]: a drive's parameters backed up to a file a person edits, compared, and
//!   restored with a plan, the runner's journal and an audit log (beside [`identify`]).
//! - [`identify`]: which model a device follows, from its answers to reads (beside
//!   [`session`]: it opens the target as a session does and uses the runner's master).
// `unsafe` is allowed in one module only: codec::crc_clmul (SIMD intrinsics).
#![deny(unsafe_code)]
#![warn(missing_docs)]

pub mod capture;
pub mod codec;
pub mod daybus;
pub mod describe;
pub mod expect;
pub mod fuzz;
pub mod gate;
pub mod identify;
pub mod judge;
pub mod learn;
#[cfg(unix)]
pub mod line;
pub mod model;
pub mod monitor;
pub mod oracle;
pub mod params;
pub mod ports;
pub mod report;
pub mod requirements;
pub mod rng;
pub mod runner;
pub mod scan;
pub mod seeds;
pub mod session;
pub mod sim;
pub mod transport;
pub mod vectors;
pub mod watch;
