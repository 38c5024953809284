//! The traffic log: every frame in and out, with timestamps, in hex; human lines or JSON
//! lines, to stderr or a file.

use std::io::Write;
use std::time::{Instant, SystemTime};

use serde::Serialize;

use crate::codec::hex::Hex;

/// Which way bytes travelled, seen from the simulated drive.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Dir {
    /// Received from the master.
    In,
    /// Sent to the master.
    Out,
}

/// How a sink writes entries.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LogFormat {
    /// One human line per entry.
    Text,
    /// One JSON object per line.
    Json,
}

/// One log entry as JSON.
#[derive(Debug, Serialize)]
struct JsonEntry<'a> {
    time: String,
    elapsed_ms: f64,
    dir: Dir,
    event: &'a str,
    len: usize,
    hex: String,
    #[serde(skip_serializing_if = "str::is_empty")]
    note: &'a str,
}

/// Where entries go.
pub struct TrafficLog {
    start: Instant,
    sinks: Vec<(LogFormat, Box<dyn Write + Send>)>,
}

impl TrafficLog {
    /// A log with no sinks (records nothing).
    pub fn new() -> Self {
        TrafficLog {
            start: Instant::now(),
            sinks: Vec::new(),
        }
    }

    /// Adds a sink.
    pub fn with_sink(mut self, format: LogFormat, w: Box<dyn Write + Send>) -> Self {
        self.sinks.push((format, w));
        self
    }

    /// Records `bytes` travelling `dir` as `event` ("frame", "reply", "garbage", ...).
    /// A sink that cannot be written is an error: a log that silently loses entries is
    /// worse than none.
    pub fn record(
        &mut self,
        dir: Dir,
        event: &str,
        bytes: &[u8],
        note: &str,
    ) -> std::io::Result<()> {
        if self.sinks.is_empty() {
            return Ok(());
        }
        let time = humantime::format_rfc3339_micros(SystemTime::now()).to_string();
        let elapsed_ms = self.start.elapsed().as_secs_f64() * 1000.0;
        for (format, w) in &mut self.sinks {
            match format {
                LogFormat::Text => {
                    let arrow = match dir {
                        Dir::In => "<-",
                        Dir::Out => "->",
                    };
                    write!(w, "{time} {arrow} {event:<10} {}", Hex(bytes))?;
                    if !note.is_empty() {
                        write!(w, "  | {note}")?;
                    }
                    writeln!(w)?;
                }
                LogFormat::Json => {
                    let e = JsonEntry {
                        time: time.clone(),
                        elapsed_ms: (elapsed_ms * 1000.0).round() / 1000.0,
                        dir,
                        event,
                        len: bytes.len(),
                        hex: Hex(bytes).to_string(),
                        note,
                    };
                    serde_json::to_writer(&mut *w, &e)?;
                    writeln!(w)?;
                }
            }
            w.flush()?;
        }
        Ok(())
    }

    /// Writes a free-text line to the human sinks (start-up, disconnects).
    pub fn message(&mut self, text: &str) -> std::io::Result<()> {
        for (format, w) in &mut self.sinks {
            if *format == LogFormat::Text {
                writeln!(w, "# {text}")?;
                w.flush()?;
            }
        }
        Ok(())
    }
}

impl Default for TrafficLog {
    fn default() -> Self {
        Self::new()
    }
}
