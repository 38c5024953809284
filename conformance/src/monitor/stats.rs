//! Per-node statistics of a listening session, in fixed memory: counters, errors by kind
//! and a response-time histogram of fixed buckets.

use std::collections::BTreeMap;
use std::time::Duration;

use serde_json::{json, Value};

/// Bucket width below [`FINE_LIMIT_US`].
const FINE_US: u64 = 100;
/// Fine buckets cover 0..100 ms.
const FINE_LIMIT_US: u64 = 100_000;
/// Bucket width from 100 ms to [`COARSE_LIMIT_US`].
const COARSE_US: u64 = 10_000;
/// Coarse buckets end at 5 s; slower replies share the last bucket.
const COARSE_LIMIT_US: u64 = 5_000_000;
const FINE: usize = (FINE_LIMIT_US / FINE_US) as usize;
const BUCKETS: usize = FINE + ((COARSE_LIMIT_US - FINE_LIMIT_US) / COARSE_US) as usize + 1;

/// Response times in fixed buckets: 0.1 ms up to 100 ms, 10 ms up to 5 s, one beyond.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Histogram {
    counts: Box<[u32]>,
    total: u64,
    max: Duration,
}

impl Default for Histogram {
    fn default() -> Self {
        Histogram {
            counts: vec![0; BUCKETS].into_boxed_slice(),
            total: 0,
            max: Duration::ZERO,
        }
    }
}

impl Histogram {
    /// Counts one response time.
    pub fn record(&mut self, d: Duration) {
        let us = u64::try_from(d.as_micros()).unwrap_or(u64::MAX);
        let i = if us < FINE_LIMIT_US {
            (us / FINE_US) as usize
        } else {
            (FINE + ((us - FINE_LIMIT_US) / COARSE_US) as usize).min(BUCKETS - 1)
        };
        self.counts[i] = self.counts[i].saturating_add(1);
        self.total += 1;
        self.max = self.max.max(d);
    }

    /// Response times counted.
    pub fn count(&self) -> u64 {
        self.total
    }

    /// The largest response time.
    pub fn max(&self) -> Option<Duration> {
        (self.total > 0).then_some(self.max)
    }

    /// The `p`-th percentile (0..=100), as the upper edge of its bucket (never above the
    /// largest time seen).
    pub fn percentile(&self, p: u32) -> Option<Duration> {
        if self.total == 0 {
            return None;
        }
        let rank = (self.total * u64::from(p)).div_ceil(100).max(1);
        let mut seen = 0u64;
        for (i, &c) in self.counts.iter().enumerate() {
            seen += u64::from(c);
            if seen >= rank {
                if i == BUCKETS - 1 {
                    return Some(self.max);
                }
                let upper = if i < FINE {
                    (i as u64 + 1) * FINE_US
                } else {
                    FINE_LIMIT_US + (i - FINE + 1) as u64 * COARSE_US
                };
                return Some(Duration::from_micros(upper).min(self.max));
            }
        }
        Some(self.max)
    }

    /// Non-empty buckets as (lower edge in ms, count), for plots.
    pub fn buckets(&self) -> Vec<(f64, u32)> {
        self.counts
            .iter()
            .enumerate()
            .filter(|(_, c)| **c > 0)
            .map(|(i, c)| {
                let lower = if i < FINE {
                    i as u64 * FINE_US
                } else {
                    FINE_LIMIT_US + (i - FINE) as u64 * COARSE_US
                };
                (lower as f64 / 1000.0, *c)
            })
            .collect()
    }
}

/// What one node did and what was found, over the session.
#[derive(Debug, Clone, Default, PartialEq, Eq)]
pub struct NodeStats {
    /// Requests the master sent to the node.
    pub requests: u64,
    /// Exchanges judged (a request with its reply, or its silence).
    pub exchanges: u64,
    /// Replies seen.
    pub replies: u64,
    /// Requests a reply was due to that got none within the window.
    pub timeouts: u64,
    /// Frames with a wrong CRC or LRC, either side.
    pub crc_errors: u64,
    /// Requests sent again (the same bytes after an unanswered one).
    pub retries: u64,
    /// Exchanges with a deviation.
    pub deviations: u64,
    /// Exchanges with an observation and no deviation.
    pub observations: u64,
    /// Findings by side and kind ("drive.wrong-exception", "master.no-t3.5").
    pub errors: BTreeMap<String, u64>,
    /// Response times.
    pub response: Histogram,
}

fn ms(d: Option<Duration>) -> Value {
    match d {
        Some(d) => json!((d.as_secs_f64() * 10_000.0).round() / 10.0),
        None => Value::Null,
    }
}

impl NodeStats {
    /// The statistics as the JSON report carries them.
    pub fn to_json(&self, address: u8) -> Value {
        let h = &self.response;
        json!({
            "address": format!("{address:02X}"),
            "requests": self.requests,
            "exchanges": self.exchanges,
            "replies": self.replies,
            "timeouts": self.timeouts,
            "crc_errors": self.crc_errors,
            "retries": self.retries,
            "deviations": self.deviations,
            "observations": self.observations,
            "errors": self.errors,
            "response_ms": {
                "count": h.count(),
                "p50": ms(h.percentile(50)),
                "p95": ms(h.percentile(95)),
                "p99": ms(h.percentile(99)),
                "max": ms(h.max()),
                "histogram": h.buckets().iter().map(|(lo, c)| json!([lo, c])).collect::<Vec<_>>(),
            },
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn percentiles_come_from_fixed_buckets() {
        let mut h = Histogram::default();
        assert_eq!(h.percentile(50), None);
        for ms in 1..=100u64 {
            h.record(Duration::from_millis(ms));
        }
        h.record(Duration::from_secs(60));
        assert_eq!(h.count(), 101);
        assert_eq!(h.max(), Some(Duration::from_secs(60)));
        let p50 = h.percentile(50).unwrap();
        assert!(
            p50 >= Duration::from_millis(51) && p50 <= Duration::from_micros(51_100),
            "{p50:?}"
        );
        assert_eq!(h.percentile(100), Some(Duration::from_secs(60)));
        assert_eq!(h.buckets().len(), 101);
    }
}
