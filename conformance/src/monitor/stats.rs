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
        let i = Histogram::index(us);
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

    /// The histogram [`Histogram::buckets`] and [`Histogram::max`] describe, as a saved
    /// report gives them back: each bucket found by its lower edge (in ms), the counts of
    /// one bucket added up. Fixed memory whatever the list's length. `None` where an edge
    /// is not a number of milliseconds at or above 0.
    pub fn from_buckets(buckets: &[(f64, u32)], max: Option<Duration>) -> Option<Histogram> {
        let mut h = Histogram::default();
        for &(lower_ms, c) in buckets {
            if !(lower_ms.is_finite() && lower_ms >= 0.0) {
                return None;
            }
            // The edge was written in ms with at most three decimals; the middle of its
            // first 100 us finds the bucket whatever the rounding did.
            let us = (lower_ms * 1000.0).round().min(u64::MAX as f64) as u64;
            let i = Histogram::index(us.saturating_add(FINE_US / 2));
            h.counts[i] = h.counts[i].saturating_add(c);
            h.total += u64::from(c);
        }
        h.max = max.unwrap_or_default();
        Some(h)
    }

    /// The bucket of a time of `us` microseconds.
    fn index(us: u64) -> usize {
        if us < FINE_LIMIT_US {
            (us / FINE_US) as usize
        } else {
            (FINE + ((us - FINE_LIMIT_US) / COARSE_US) as usize).min(BUCKETS - 1)
        }
    }

    /// The width in ms of the bucket whose lower edge is `lower_ms` (the last one, which
    /// holds every slower reply, is given the width of the others beyond 100 ms).
    pub fn bucket_width_ms(lower_ms: f64) -> f64 {
        let us = if lower_ms * 1000.0 < FINE_LIMIT_US as f64 {
            FINE_US
        } else {
            COARSE_US
        };
        us as f64 / 1000.0
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
    /// The figures the text and HTML reports print for the node, in their order:
    /// requests, exchanges, replies, timeouts, CRC errors, retries, then the p50, p95,
    /// p99 and largest response time in ms with one decimal ("-" with no reply).
    pub fn figures(&self) -> [String; 10] {
        let h = &self.response;
        let ms = |d: Option<Duration>| {
            d.map_or("-".to_string(), |d| {
                format!("{:.1}", d.as_secs_f64() * 1000.0)
            })
        };
        [
            self.requests.to_string(),
            self.exchanges.to_string(),
            self.replies.to_string(),
            self.timeouts.to_string(),
            self.crc_errors.to_string(),
            self.retries.to_string(),
            ms(h.percentile(50)),
            ms(h.percentile(95)),
            ms(h.percentile(99)),
            ms(h.max()),
        ]
    }

    /// The findings as the text and HTML reports print them: `kind count`, joined by
    /// ", " (empty with none).
    pub fn findings_text(&self) -> String {
        let e: Vec<String> = self
            .errors
            .iter()
            .map(|(k, n)| format!("{k} {n}"))
            .collect();
        e.join(", ")
    }

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

/// `v[key]` as a whole number, or what is wrong with it (`path` names `v`).
pub(crate) fn count_of(v: &Value, key: &str, path: &str) -> Result<u64, String> {
    v.get(key)
        .and_then(Value::as_u64)
        .ok_or_else(|| format!("{path}.{key}: missing or not a whole number"))
}

/// `v[key]` as a duration written in ms, `None` where it is null or missing.
pub(crate) fn opt_ms_of(v: &Value, key: &str, path: &str) -> Result<Option<Duration>, String> {
    match v.get(key) {
        None | Some(Value::Null) => Ok(None),
        Some(x) => x
            .as_f64()
            .filter(|ms| ms.is_finite() && *ms >= 0.0 && *ms < 1e12)
            .map(|ms| Some(Duration::from_secs_f64(ms / 1000.0)))
            .ok_or_else(|| format!("{path}.{key}: {x} is not a number of milliseconds")),
    }
}

impl NodeStats {
    /// A node's statistics read back from [`NodeStats::to_json`]: its address and its
    /// statistics. The percentiles are not read: they follow from the histogram.
    pub fn from_json(v: &Value, path: &str) -> Result<(u8, NodeStats), String> {
        let address = v
            .get("address")
            .and_then(Value::as_str)
            .and_then(|a| u8::from_str_radix(a, 16).ok())
            .ok_or_else(|| format!("{path}.address: missing or not a node address in hex"))?;
        let errors = match v.get("errors") {
            None | Some(Value::Null) => BTreeMap::new(),
            Some(Value::Object(m)) => m
                .iter()
                .map(|(k, n)| {
                    n.as_u64()
                        .map(|n| (k.clone(), n))
                        .ok_or_else(|| format!("{path}.errors.{k}: not a whole number"))
                })
                .collect::<Result<_, _>>()?,
            Some(x) => return Err(format!("{path}.errors: {x} is not an object")),
        };
        let rp = format!("{path}.response_ms");
        let r = v
            .get("response_ms")
            .ok_or_else(|| format!("{rp}: missing"))?;
        let buckets = r
            .get("histogram")
            .and_then(Value::as_array)
            .ok_or_else(|| format!("{rp}.histogram: missing or not an array"))?
            .iter()
            .enumerate()
            .map(|(i, b)| {
                let pair = b.as_array().filter(|p| p.len() == 2);
                pair.and_then(|p| Some((p[0].as_f64()?, u32::try_from(p[1].as_u64()?).ok()?)))
                    .ok_or_else(|| {
                        format!("{rp}.histogram[{i}]: {b} is not [lower edge in ms, count]")
                    })
            })
            .collect::<Result<Vec<_>, _>>()?;
        let response = Histogram::from_buckets(&buckets, opt_ms_of(r, "max", &rp)?)
            .ok_or_else(|| format!("{rp}.histogram: a lower edge below 0 or not a number"))?;
        if response.count() != count_of(r, "count", &rp)? {
            return Err(format!(
                "{rp}.count: {} where the histogram holds {}",
                count_of(r, "count", &rp)?,
                response.count()
            ));
        }
        Ok((
            address,
            NodeStats {
                requests: count_of(v, "requests", path)?,
                exchanges: count_of(v, "exchanges", path)?,
                replies: count_of(v, "replies", path)?,
                timeouts: count_of(v, "timeouts", path)?,
                crc_errors: count_of(v, "crc_errors", path)?,
                retries: count_of(v, "retries", path)?,
                deviations: count_of(v, "deviations", path)?,
                observations: count_of(v, "observations", path)?,
                errors,
                response,
            },
        ))
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

    /// A node's statistics written to JSON and read back give the same JSON: the same
    /// counts, findings, percentiles and histogram (fine and coarse buckets, and the last
    /// one that holds every slower reply).
    #[test]
    fn statistics_read_back_as_they_were_written() {
        let mut s = NodeStats {
            requests: 9,
            exchanges: 8,
            replies: 7,
            timeouts: 1,
            crc_errors: 2,
            retries: 3,
            deviations: 4,
            observations: 5,
            errors: [("drive.late-reply".to_string(), 2)].into(),
            response: Histogram::default(),
        };
        for us in [
            0, 99, 100, 9_870, 12_345, 99_999, 100_000, 250_500, 4_999_999, 7_000_000,
        ] {
            s.response.record(Duration::from_micros(us));
        }
        let json = s.to_json(0x3A);
        let (a, back) = NodeStats::from_json(&json, "x").unwrap();
        assert_eq!(a, 0x3A);
        assert_eq!(back.to_json(0x3A), json);
        assert_eq!(back.response.buckets(), s.response.buckets());
        // Nothing heard: no histogram, no percentiles.
        let quiet = NodeStats::default().to_json(1);
        assert_eq!(
            NodeStats::from_json(&quiet, "x").unwrap().1.to_json(1),
            quiet
        );
    }

    #[test]
    fn a_broken_histogram_is_named() {
        let mut json = NodeStats::default().to_json(1);
        json["response_ms"]["histogram"] = serde_json::json!([[-1.0, 2]]);
        json["response_ms"]["count"] = 2.into();
        let e = NodeStats::from_json(&json, ".monitor.nodes[0]").unwrap_err();
        assert!(
            e.starts_with(".monitor.nodes[0].response_ms.histogram"),
            "{e}"
        );
        json["response_ms"]["histogram"] = serde_json::json!([[1.0, 2]]);
        json["response_ms"]["count"] = 3.into();
        let e = NodeStats::from_json(&json, ".monitor.nodes[0]").unwrap_err();
        assert!(e.contains("count: 3 where the histogram holds 2"), "{e}");
        json["address"] = "zz".into();
        assert!(NodeStats::from_json(&json, "n")
            .unwrap_err()
            .starts_with("n.address"));
    }
}
