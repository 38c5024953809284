//! Golden vectors: every example frame and checksum of the five manuals, exactly as
//! printed, with errata flagged and explained (see `vectors/README.md`).

pub mod corpus;
pub mod export;
pub mod model;
pub mod set;
pub mod verify;

pub use model::{Body, FrameVector, LoadError, Vector, VectorFile, Verdict, DOCUMENTS};
pub use set::VectorSet;
pub use verify::{missing, render, verify_all, verify_vector, VectorReport};
