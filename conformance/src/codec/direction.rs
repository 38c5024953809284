//! The direction a frame travels: what parsing a frame needs first (a request and a
//! response of one function code have different layouts), and what its errors name.

use std::fmt;

/// Whether a frame travels from master to slave or back.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Direction {
    /// Master to slave.
    Request,
    /// Slave to master (normal or exception response).
    Response,
}

impl fmt::Display for Direction {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Direction::Request => "request",
            Direction::Response => "response",
        })
    }
}
