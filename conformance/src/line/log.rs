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
use crate::capture::{self, Interface, PacketMeta, PcapngWriter};
use crate::codec::hex::{parse_hex, Hex};
use crate::codec::Mode;

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
    /// The host did not run the line's loop in time (a busy machine): characters reached
    /// their listeners more than t1.5 after the line carried them, so what an endpoint
    /// measures of the silences around them is not the line's. One record per run of
    /// such characters.
    Late {
        /// When the first of them ended on the line.
        t_us: u64,
        /// How many.
        chars: u64,
        /// The most any of them was late, in microseconds.
        by_us: u64,
    },
    /// An endpoint's program set its port (`bus --emulate-line`): what it hears from
    /// now on.
    Settings {
        /// When it was seen.
        t_us: u64,
        /// The endpoint.
        endpoint: String,
        /// The settings read from its port ("19200 8O1"; "unknown" where they cannot be
        /// read).
        line: String,
        /// "the line" (its UART reads the line's characters) or "its own UART" (other
        /// settings: it reads what a UART at them makes of the line).
        hears: &'static str,
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
        /// Runs of characters handed to their listeners late (`late` records).
        #[serde(skip_serializing_if = "is_zero")]
        late: u64,
    },
}

fn is_zero(n: &u64) -> bool {
    *n == 0
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
            Record::Late { t_us, chars, by_us } => format!(
                "{:>12.3} ms the host ran late: {chars} characters reached their listeners up to {:.3} ms after the line carried them (silences measured on the endpoints then are not the line's)",
                ms(*t_us),
                ms(*by_us)
            ),
            Record::Settings {
                t_us,
                endpoint,
                line,
                hears,
            } => format!(
                "{:>12.3} ms {endpoint} set its port to {line}: it hears {hears}",
                ms(*t_us)
            ),
            Record::Stop {
                t_us,
                chars,
                collisions,
                flips,
                dropped,
                late,
            } => format!(
                "stopped after {:.3} s: {chars} characters, {collisions} collisions, {flips} bits flipped, {dropped} bytes dropped{}",
                *t_us as f64 / 1e6,
                if *late > 0 {
                    format!("; the host ran late {late} times (see the `late` records)")
                } else {
                    String::new()
                }
            ),
        }
    }
}

/// Where the records go.
#[derive(Default)]
pub struct LineLog {
    json: Option<Box<dyn Write + Send>>,
    text: Option<Box<dyn Write + Send>>,
    capture: Option<LineCapture>,
}

/// The line as a pcapng capture (`bus --capture`): one interface per endpoint, holding
/// what that endpoint sent (outbound from its side), and one for the line itself, holding
/// what listeners read from collisions and damaged characters.
struct LineCapture {
    writer: PcapngWriter<Box<dyn Write + Send>>,
    mode: Mode,
    /// Wall-clock microseconds at the line's start (`t_us` 0).
    origin_us: u64,
    /// Interface of each endpoint, by name, then the line's.
    interfaces: Vec<String>,
}

impl LineCapture {
    fn interface(&self, name: &str) -> u32 {
        let line = self.interfaces.len().saturating_sub(1);
        self.interfaces
            .iter()
            .position(|n| n == name)
            .unwrap_or(line) as u32
    }

    fn record(&mut self, r: &Record) -> Result<(), capture::WriteError> {
        let packet = |t_us: u64, interface: u32, flags: u32, comment: Option<String>| PacketMeta {
            interface,
            timestamp_us: self.origin_us.saturating_add(t_us),
            flags,
            comment,
        };
        let (meta, bytes) = match r {
            Record::Start {
                line, endpoints, ..
            } => {
                self.origin_us = std::time::SystemTime::now()
                    .duration_since(std::time::SystemTime::UNIX_EPOCH)
                    .map(|d| d.as_micros() as u64)
                    .unwrap_or(0);
                for e in endpoints {
                    let what = e.path.as_deref().or(e.device.as_deref()).unwrap_or("");
                    self.writer.add_interface(&Interface {
                        link_type: capture::link_type_of(self.mode),
                        name: e.name.clone(),
                        description: format!("{} {line}, endpoint {} {what}", self.mode, e.name),
                    })?;
                    self.interfaces.push(e.name.clone());
                }
                self.writer.add_interface(&Interface {
                    link_type: capture::link_type_of(self.mode),
                    name: "line".into(),
                    description: format!(
                        "{} {line}, what listeners read from collisions and damaged characters",
                        self.mode
                    ),
                })?;
                self.interfaces.push(String::new());
                return Ok(());
            }
            Record::Tx {
                t_us, from, hex, ..
            } => {
                let bytes = parse_hex(hex).unwrap_or_default();
                let mut flags = capture::FLAG_OUTBOUND;
                if !checksum_ok(self.mode, &bytes) {
                    flags |= capture::FLAG_CRC_ERROR;
                }
                (packet(*t_us, self.interface(from), flags, None), bytes)
            }
            Record::Collision {
                t_us,
                endpoints,
                chars,
                line_hex,
                ..
            } => (
                packet(
                    *t_us,
                    self.interface(""),
                    FLAG_SYMBOL_ERROR,
                    Some(format!(
                        "collision of {}: {chars} characters read damaged",
                        endpoints.join(", ")
                    )),
                ),
                parse_hex(line_hex).unwrap_or_default(),
            ),
            Record::Damaged { t_us, hex, error } => (
                packet(
                    *t_us,
                    self.interface(""),
                    FLAG_SYMBOL_ERROR,
                    Some(format!(
                        "a character read damaged{}",
                        error.map(|e| format!(" ({e} error)")).unwrap_or_default()
                    )),
                ),
                parse_hex(hex).unwrap_or_default(),
            ),
            _ => return Ok(()),
        };
        self.writer.write_packet(&meta, &bytes)
    }
}

/// `epb_flags` bit 31: symbol error (a character the line damaged).
const FLAG_SYMBOL_ERROR: u32 = 1 << 31;

/// Whether `frame` carries a right checksum for `mode`.
fn checksum_ok(mode: Mode, frame: &[u8]) -> bool {
    match mode {
        Mode::Rtu => frame.len() >= 4 && crate::codec::crc::crc16_frame_ok(frame),
        Mode::Ascii => crate::codec::ascii::is_valid_frame(frame),
    }
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

    /// Also writes the line as a pcapng capture to `w`, its frames under the link type of
    /// `mode` (see [`crate::capture`]).
    pub fn with_capture(mut self, w: Box<dyn Write + Send>, mode: Mode) -> Result<Self, LineError> {
        let writer = PcapngWriter::new(w, "conformance bus").map_err(capture_error)?;
        self.capture = Some(LineCapture {
            writer,
            mode,
            origin_us: 0,
            interfaces: Vec::new(),
        });
        Ok(self)
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
        if let Some(c) = self.capture.as_mut() {
            c.record(r).map_err(capture_error)?;
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

fn capture_error(e: capture::WriteError) -> LineError {
    match e {
        capture::WriteError::Io(e) => LineError::Log(e),
        other => LineError::Log(std::io::Error::other(other.to_string())),
    }
}

/// Bytes in the log's hex.
pub(crate) fn hex(bytes: &[u8]) -> String {
    Hex(bytes).to_string()
}
