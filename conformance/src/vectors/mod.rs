//! Golden vectors: every example frame and checksum of the five manuals, exactly as
//! printed, with errata flagged and explained (see `vectors/README.md`); also the CRC
//! program and the exception rule the manuals print.

pub mod corpus;
pub mod export;
pub mod listing;
pub mod model;
pub mod outcome;
pub mod set;
pub mod verify;

pub use model::{Body, FrameVector, LoadError, Vector, VectorFile, Verdict, DOCUMENTS};
pub use set::VectorSet;
pub use verify::{missing, render, render_in, verify_all, verify_vector, VectorReport};
