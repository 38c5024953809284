//! The line's log: one JSON object a line (who sent which bytes when, collisions, noise
//! flips, characters read damaged, bytes an endpoint could not take), and optionally one
//! human line a record on stderr. Written as it goes, so a long run keeps its memory flat.
//!
//! Times are microseconds since the line started (`t_us`): on a paced line they are the
//! line's schedule (the bit at which a character started), not when this host got round
//! to it; unpaced, when the bytes were read.

use std::io::Write;

use serde::Serialize;

use super::LineError;
use crate::codec::hex::Hex;

/// One endpoint as the start record lists it.
#[derive(Debug, Clone, Serialize)]
pub struct EndpointInfo {
    /// Its name (the index, or the name given with --link).
    pub name: String,
    /// The pseudo-terminal a program opens; None for an endpoint inside this process.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub path: Option<String>,
    /// What sits there, for endpoints inside this process ("f510 node 01H").
    #[serde(skip_serializing_if = "Option::is_none")]
    pub device: Option<String>,
    /// Whether it hears its own bytes.
    #[serde(skip_serializing_if = "std::ops::Not::not")]
    pub echo: bool,
}

/// One record of the log.
#[derive(Debug, Clone, Serialize)]
#[serde(tag = "event", rename_all = "lowercase")]
pub enum Record {
    /// The line started.
    Start {
        /// Always 0.
        t_us: u64,
        /// Line settings ("9600 8E1").
        line: String,
        /// One character's time in microseconds.
        char_us: u64,
        /// Whether bytes go at the line's character time.
        paced: bool,
        /// Probability of a flip per driven bit.
        noise: f64,
        /// The noise's seed.
        seed: u64,
        /// The endpoints, in index order.
        endpoints: Vec<EndpointInfo>,
    },
    /// Bytes an endpoint wrote, as they went on the line.
    Tx {
        /// When the first started.
        t_us: u64,
        /// Who wrote them.
        from: String,
        /// The bytes.
        hex: String,
        /// Paced: when each one started.
        #[serde(skip_serializing_if = "Option::is_none")]
        at_us: Option<Vec<u64>>,
    },
    /// Two or more endpoints drove the line at once.
    Collision {
        /// The first bit driven by two.
        t_us: u64,
        /// After the last one.
        end_us: u64,
        /// Who drove during it.
        endpoints: Vec<String>,
        /// Characters the listeners read from it.
        chars: u64,
        /// What they read (at most 256).
        line_hex: String,
    },
    /// The noise flipped a bit.
    Noise {
        /// When.
        t_us: u64,
        /// Who drove it.
        from: Vec<String>,
        /// The character of the first of them.
        byte: String,
        /// Which of its bits (0: the start bit; then data from the least significant,
        /// parity, stop).
        bit: u8,
    },
    /// A character the listeners read damaged outside a collision (noise, or an error).
    Damaged {
        /// Its start bit.
        t_us: u64,
        /// What they read.
        hex: String,
        /// "parity" or "framing", if the receiver saw one.
        #[serde(skip_serializing_if = "Option::is_none")]
        error: Option<&'static str>,
    },
    /// An endpoint whose reader does not keep up (nobody reads its pseudo-terminal, or
    /// not fast enough): bytes for it were dropped, as a UART's overrun drops them.
    Overrun {
        /// When the first was dropped.
        t_us: u64,
        /// The endpoint.
        to: String,
        /// How many in this write.
        dropped: u64,
    },
    /// The line stopped.
    Stop {
        /// When.
        t_us: u64,
        /// Characters read off the line.
        chars: u64,
        /// Collisions.
        collisions: u64,
        /// Bits flipped.
        flips: u64,
        /// Bytes dropped for endpoints that did not read.
        dropped: u64,
    },
}

impl Record {
    fn text(&self) -> String {
        let ms = |us: u64| us as f64 / 1000.0;
        match self {
            Record::Start {
                line,
                paced,
                noise,
                seed,
                endpoints,
                ..
            } => format!(
                "line {line}, {}, noise {noise} (seed {seed}); endpoints: {}",
                if *paced { "paced" } else { "unpaced" },
                endpoints
                    .iter()
                    .map(|e| match (&e.path, &e.device) {
                        (Some(p), _) => format!("{} {p}", e.name),
                        (None, Some(d)) => format!("{} ({d})", e.name),
                        (None, None) => e.name.clone(),
                    })
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
            Record::Tx { t_us, from, hex, .. } => {
                format!("{:>12.3} ms {from:<8} -> {hex}", ms(*t_us))
            }
            Record::Collision {
                t_us,
                end_us,
                endpoints,
                chars,
                line_hex,
            } => format!(
                "{:>12.3} ms COLLISION {} for {:.3} ms: {chars} characters read damaged: {line_hex}",
                ms(*t_us),
                endpoints.join(" + "),
                ms(end_us.saturating_sub(*t_us))
            ),
            Record::Noise {
                t_us,
                from,
                byte,
                bit,
            } => format!(
                "{:>12.3} ms noise: bit {bit} of {byte}H from {} flipped",
                ms(*t_us),
                from.join(" + ")
            ),
            Record::Damaged { t_us, hex, error } => format!(
                "{:>12.3} ms line read {hex}H damaged{}",
                ms(*t_us),
                error.map_or(String::new(), |e| format!(" ({e} error)"))
            ),
            Record::Overrun { t_us, to, dropped } => format!(
                "{:>12.3} ms {to} does not read: {dropped} bytes for it dropped",
                ms(*t_us)
            ),
            Record::Stop {
                t_us,
                chars,
                collisions,
                flips,
                dropped,
            } => format!(
                "stopped after {:.3} s: {chars} characters, {collisions} collisions, {flips} bits flipped, {dropped} bytes dropped",
                *t_us as f64 / 1e6
            ),
        }
    }
}

/// Where the records go.
#[derive(Default)]
pub struct LineLog {
    json: Option<Box<dyn Write + Send>>,
    text: Option<Box<dyn Write + Send>>,
}

impl LineLog {
    /// A log that records nothing.
    pub fn new() -> Self {
        LineLog::default()
    }

    /// Also writes JSON lines to `w`.
    pub fn with_json(mut self, w: Box<dyn Write + Send>) -> Self {
        self.json = Some(w);
        self
    }

    /// Also writes one human line a record to `w` (prefixed `# `).
    pub fn with_text(mut self, w: Box<dyn Write + Send>) -> Self {
        self.text = Some(w);
        self
    }

    /// Writes `r`. A sink that cannot be written is an error: a log that silently loses
    /// records is worse than none.
    pub fn record(&mut self, r: &Record) -> Result<(), LineError> {
        if let Some(w) = self.json.as_mut() {
            serde_json::to_writer(&mut *w, r).map_err(|e| LineError::Log(e.into()))?;
            w.write_all(b"\n").map_err(LineError::Log)?;
        }
        if let Some(w) = self.text.as_mut() {
            writeln!(w, "# {}", r.text()).map_err(LineError::Log)?;
        }
        Ok(())
    }

    /// Flushes every sink.
    pub fn flush(&mut self) -> Result<(), LineError> {
        for w in [self.json.as_mut(), self.text.as_mut()]
            .into_iter()
            .flatten()
        {
            w.flush().map_err(LineError::Log)?;
        }
        Ok(())
    }
}

/// Bytes in the log's hex.
pub(crate) fn hex(bytes: &[u8]) -> String {
    Hex(bytes).to_string()
}
