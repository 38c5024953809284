//! What a watch holds per node, in fixed memory whatever its length: the last value of
//! each register and what changed, the counts of what was observed, a trend of each
//! register for the HTML report (thinned as it grows), and the round-trip times.

use std::collections::BTreeMap;
use std::time::Duration;

use crate::monitor::stats::Histogram;

/// Points a trend keeps at most; beyond, every other point goes and the trend keeps
/// one poll in twice as many.
pub const TREND_POINTS: usize = 600;

/// A register's values over time, thinned to at most [`TREND_POINTS`] points.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Trend {
    /// (seconds since the start, raw value), oldest first.
    pub points: Vec<(f64, u16)>,
    /// One point is kept for every `stride` values.
    stride: u64,
    /// Values since the last kept one.
    since: u64,
}

impl Trend {
    /// Adds the value read at `t` seconds.
    pub fn push(&mut self, t: f64, v: u16) {
        self.stride = self.stride.max(1);
        self.since += 1;
        if self.since < self.stride {
            return;
        }
        self.since = 0;
        self.points.push((t, v));
        if self.points.len() >= TREND_POINTS {
            let mut i = 0;
            self.points.retain(|_| {
                i += 1;
                i % 2 == 1
            });
            self.stride *= 2;
        }
    }
}

/// One watched register of one node.
#[derive(Debug, Clone, PartialEq)]
pub struct Cell {
    /// The register.
    pub register: u16,
    /// The last value read, if any.
    pub value: Option<u16>,
    /// Whether the last poll changed it (the first value read is no change).
    pub changed: bool,
    /// Changes seen.
    pub changes: u64,
    /// Whether the last value is outside the model's range.
    pub out_of_range: bool,
    /// Values read outside the model's range.
    pub out_of_range_count: u64,
    /// The reserved bits set in the last value (bit numbers).
    pub reserved_bits: Vec<u8>,
    /// Values read with a reserved bit set.
    pub reserved_count: u64,
    /// The value over time.
    pub trend: Trend,
}

impl Cell {
    /// An empty cell for `register`.
    pub fn new(register: u16) -> Self {
        Cell {
            register,
            value: None,
            changed: false,
            changes: 0,
            out_of_range: false,
            out_of_range_count: 0,
            reserved_bits: Vec::new(),
            reserved_count: 0,
            trend: Trend::default(),
        }
    }
}

/// What one node's polls came to.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct NodeStats {
    /// Polls made.
    pub polls: u64,
    /// Polls whose every read came back with values.
    pub whole: u64,
    /// The last poll's round trip.
    pub last_rtt: Option<Duration>,
    /// Round trips of whole polls.
    pub rtt: Histogram,
    /// Reads that got no reply.
    pub timeouts: u64,
    /// Reads whose reply had a wrong CRC or LRC.
    pub crc_errors: u64,
    /// Reads answered with an exception, by code.
    pub exceptions: BTreeMap<u8, u64>,
    /// Other findings of the judge on replies, by kind ("extra-bytes", "truncated").
    pub other: BTreeMap<&'static str, u64>,
    /// Values outside the model's range.
    pub out_of_range: u64,
    /// Values with a reserved bit set.
    pub reserved_bits: u64,
}

impl NodeStats {
    /// Exceptions of every code.
    pub fn exception_count(&self) -> u64 {
        self.exceptions.values().sum()
    }
}

/// One node's table: its cells and its statistics.
#[derive(Debug, Clone, PartialEq)]
pub struct NodeTable {
    /// The node address.
    pub node: u8,
    /// One cell per watched register, in the order watched.
    pub cells: Vec<Cell>,
    /// The statistics.
    pub stats: NodeStats,
}

impl NodeTable {
    /// An empty table of `registers` for `node`.
    pub fn new(node: u8, registers: &[u16]) -> Self {
        NodeTable {
            node,
            cells: registers.iter().map(|&r| Cell::new(r)).collect(),
            stats: NodeStats::default(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_trend_stays_within_its_points_and_keeps_the_ends_of_time() {
        let mut t = Trend::default();
        for i in 0..100_000u32 {
            t.push(f64::from(i), (i % 65_536) as u16);
        }
        assert!(t.points.len() < TREND_POINTS, "{}", t.points.len());
        assert_eq!(t.points[0].0, 0.0);
        // The last point kept is near the end: within one stride.
        let last = t.points.last().unwrap().0;
        assert!(last > 99_000.0, "{last}");
        assert!(t.points.windows(2).all(|w| w[0].0 < w[1].0));
    }
}
