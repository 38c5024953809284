//! Laws of the codec as functions of arbitrary bytes, shared by the fuzz targets (`fuzz/`)
//! and by the tests that replay their crash and regression inputs under plain
//! `cargo test`.
//!
//! Each function **panics when the codec breaks a law**: that is its purpose, as a test
//! oracle. Nothing in the codec calls these.
//!
//! One file a family of laws: `frames.rs` (the RTU, ASCII and MBAP frame parsers),
//! `deframers.rs` (the streaming deframers), `crc.rs` (the CRC paths against the manuals'
//! loop), `roundtrip.rs` (owned messages encoded and decoded again), `files.rs` (the
//! loaders of vector files and captures) and `model.rs` (the simulated drive and `model
//! lint`); the laws of the listener, the adapters and the hand-written files sit next to
//! the code they check (`fuzzing.rs` in their rooms).

use crate::codec::{Direction, MAX_ASCII_FRAME, MAX_RTU_FRAME};

mod crc;
mod deframers;
mod files;
mod frames;
mod model;
mod roundtrip;

pub use crc::crc_differential;
pub use deframers::{ascii_deframer, rtu_deframer};
pub use files::{capture_reader, vector_loader};
pub use frames::{ascii_frame, mbap_frame, rtu_frame};
pub use model::{drive, model_lint};
pub use roundtrip::{roundtrip, roundtrip_bytes, OwnedMessage, OwnedPdu};

const DIRECTIONS: [Direction; 2] = [Direction::Request, Direction::Response];

/// Output buffers the oracles reuse: large arrays on the stack cost every execution an
/// AddressSanitizer fake-stack frame, and a `Vec` a heap allocation.
struct Scratch {
    rtu: [u8; MAX_RTU_FRAME],
    rtu2: [u8; MAX_RTU_FRAME],
    rtu3: [u8; MAX_RTU_FRAME],
    ascii: [u8; MAX_ASCII_FRAME],
    ascii2: [u8; MAX_ASCII_FRAME],
}

thread_local! {
    static SCRATCH: std::cell::RefCell<Box<Scratch>> = std::cell::RefCell::new(Box::new(Scratch {
        rtu: [0; MAX_RTU_FRAME],
        rtu2: [0; MAX_RTU_FRAME],
        rtu3: [0; MAX_RTU_FRAME],
        ascii: [0; MAX_ASCII_FRAME],
        ascii2: [0; MAX_ASCII_FRAME],
    }));
}

fn with_scratch<R>(f: impl FnOnce(&mut Scratch) -> R) -> R {
    SCRATCH.with(|s| f(&mut s.borrow_mut()))
}

/// An oracle: checks the laws on one input, panicking when one breaks.
pub type Oracle = fn(&[u8]);

/// The fuzz targets by name, each with its oracle: the one list the fuzz crate, the seed
/// corpus writer and the regression replay share.
pub const TARGETS: [(&str, Oracle); 18] = [
    ("rtu_frame", rtu_frame),
    ("ascii_frame", ascii_frame),
    ("rtu_deframer", rtu_deframer),
    ("ascii_deframer", ascii_deframer),
    ("vector_loader", vector_loader),
    ("roundtrip", roundtrip_bytes),
    ("crc_differential", crc_differential),
    ("drive", drive),
    ("mbap_frame", mbap_frame),
    ("capture_reader", capture_reader),
    ("model_lint", model_lint),
    // Issue 37: the listener, the adapter protocols and the hand-written files; their
    // laws sit next to the code they check.
    ("monitor_stream", crate::monitor::fuzzing::monitor_stream),
    ("tap_framer", crate::monitor::fuzzing::tap_framer),
    ("line_search", crate::monitor::fuzzing::line_search),
    ("adapter_protocol", crate::gate::fuzzing::adapter_protocol),
    (
        "expectations_file",
        crate::expect::fuzzing::expectations_file,
    ),
    (
        "requirements_file",
        crate::requirements::fuzzing::requirements_file,
    ),
    ("model_file", crate::model::fuzzing::model_file),
];
