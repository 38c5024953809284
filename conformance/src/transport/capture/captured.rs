//! A transport whose traffic is recorded: sends as outbound packets, received bytes
//! grouped into inbound packets by the line's silences and the frames' lengths.

//! ([`Recorder::error`]): the run itself goes on.

use std::time::{Duration, Instant};

use super::{SharedRecorder, HOST_STALL, LATE_NOTED};
use crate::capture::{self, Interface};
use crate::codec::timing::later;
use crate::codec::timing::LineSettings;
use crate::codec::Mode;
use crate::transport::{LineTags, LinkKind, Transport, TransportError};

/// Whether `frame` carries a right checksum for `mode`.
fn checksum_ok(mode: Mode, frame: &[u8]) -> bool {
    match mode {
        Mode::Rtu => frame.len() >= 4 && crate::codec::crc::crc16_frame_ok(frame),
        Mode::Ascii => crate::codec::ascii::is_valid_frame(frame),
    }
}

/// A transport whose traffic is recorded (see the module's documentation).
pub struct Captured<T: Transport> {
    inner: T,
    recorder: SharedRecorder,
    interface: Option<u32>,
    mode: Mode,
    char_time: Option<Duration>,
    gap: Duration,
    inbound: Vec<u8>,
    inbound_at: Option<Instant>,
    /// How late this host made the simulator begin the reply held, where it said so.
    inbound_late: Option<(Duration, Duration)>,
    last_read: Option<Instant>,
    last_sent: Option<Instant>,
    host_timing: bool,
    /// How long a part of a frame is held for its rest on a link with the host's timing
    /// ([`Captured::holding_frames_for`]).
    hold: Duration,
    inbound_flag: u32,
    /// The line's character time, from the settings it was made with.
    line_char: Duration,
    /// A tap ([`Captured::as_tap`]): its first packet is marked where it was read before
    /// any read came back empty.
    tap: bool,
    /// The start is past: a read came back empty (the line was heard quiet), or the
    /// first packet was begun (and marked or not).
    started: bool,
    /// The packet held was read before the line was heard quiet.
    inbound_mid_traffic: bool,
}

impl<T: Transport> Captured<T> {
    /// Records `inner`, a link carrying `mode` frames at `line`, on `recorder`, as a new
    /// interface described by the link, the mode and the line.
    pub fn new(inner: T, recorder: SharedRecorder, mode: Mode, line: LineSettings) -> Self {
        let name = inner.describe();
        let description = format!("{mode} {line}, {name}");
        let iface = Interface {
            link_type: capture::link_type_of(mode),
            name,
            description,
        };
        let interface = recorder.lock().ok().and_then(|mut r| r.interface(&iface));
        let char_time = inner
            .line_timing()
            .map(|l| Duration::from_micros(l.char_time_us()));
        Captured {
            recorder,
            interface,
            mode,
            char_time,
            gap: Duration::from_millis(5).max(Duration::from_micros(line.t3_5_us())),
            inbound: Vec::new(),
            inbound_at: None,
            inbound_late: None,
            last_read: None,
            last_sent: None,
            host_timing: inner.kind() != LinkKind::Serial,
            hold: HOST_STALL,
            inner,
            inbound_flag: capture::FLAG_INBOUND,
            line_char: Duration::from_micros(line.char_time_us()),
            tap: false,
            started: false,
            inbound_mid_traffic: false,
        }
    }

    /// The link it records, to change its settings (`scan` sets each line setting in
    /// turn); call [`Captured::retarget`] after.
    pub fn inner_mut(&mut self) -> &mut T {
        &mut self.inner
    }

    /// The link now carries `mode` frames at `line` (a scan's next setting): what is held
    /// is written, and the frames from here on go to a new interface described by the
    /// mode and the line, under the mode's link type.
    pub fn retarget(&mut self, mode: Mode, line: LineSettings) {
        self.flush_inbound();
        let name = self.inner.describe();
        let iface = Interface {
            link_type: capture::link_type_of(mode),
            description: format!("{mode} {line}, {name}"),
            name,
        };
        self.interface = self
            .recorder
            .lock()
            .ok()
            .and_then(|mut r| r.interface(&iface));
        self.mode = mode;
        self.line_char = Duration::from_micros(line.char_time_us());
        self.char_time = self
            .inner
            .line_timing()
            .map(|l| Duration::from_micros(l.char_time_us()));
        self.gap = Duration::from_millis(5).max(Duration::from_micros(line.t3_5_us()));
    }

    /// Holds a part of a frame for its rest as long as `wait` (the master's timeout: how
    /// long it waits after a byte for the next one of an unfinished reply), not only
    /// [`HOST_STALL`], on a link with the host's timing. A master starved by a busy host
    /// reads a reply's rest long after the line carried it and takes the reply whole: the
    /// capture must too, or `monitor --capture-in` judges two damaged frames where the
    /// master judged one good one.
    pub fn holding_frames_for(mut self, wait: Duration) -> Self {
        self.hold = wait.max(HOST_STALL);
        self
    }

    /// For a tap that hears both sides of a bus (`monitor`): what it receives is written
    /// without a direction (flags bits 0-1 `00`, "not known"), as a single-direction
    /// sniffer's file is.
    ///
    /// A tap hears a line at its settings: where the link has no timing of its own (a
    /// pseudo-terminal of `conformance bus`, which paces the line), a packet is dated back
    /// from its first read one character time of the line a byte, as the monitor dates
    /// that read's bytes, so that a file judged offline has the live monitor's times (a
    /// backlog of 150 bytes read at once, dated at the read, ended 86 ms after the packet
    /// that followed it, and the file was judged `master.no-t3.5`). Its first packet,
    /// where it was read before any read came back empty, is marked
    /// ([`capture::HEARD_MID_TRAFFIC`]): listening began while the line was busy.
    pub fn as_tap(mut self) -> Self {
        self.inbound_flag = 0;
        self.tap = true;
        self
    }

    fn record(&mut self, at: Instant, bytes: &[u8], mut flags: u32, why: Option<&str>) {
        let Some(interface) = self.interface else {
            return;
        };
        if !checksum_ok(self.mode, bytes) {
            flags |= capture::FLAG_CRC_ERROR;
        }
        // Wireshark has no Modbus ASCII dissector: a whole ASCII frame says what it is in
        // RTU in its comment, which a reader can paste into anything that decodes RTU.
        let note = match self.mode {
            Mode::Ascii => {
                let mut rtu = [0u8; crate::codec::MAX_RTU_FRAME];
                crate::codec::ascii_to_rtu(bytes, &mut rtu)
                    .ok()
                    .map(|n| format!("as RTU: {}", crate::codec::hex::Hex(&rtu[..n])))
            }
            _ => None,
        };
        if let Ok(mut r) = self.recorder.lock() {
            r.record(interface, at, bytes, flags, why, note.as_deref());
        }
    }

    /// Records one outbound frame; a wrong checksum is named as damage on purpose.
    fn record_sent(&mut self, at: Instant, bytes: &[u8], flags: u32, why: Option<String>) {
        let damaged = (!checksum_ok(self.mode, bytes)).then_some(match self.mode {
            Mode::Rtu => "sent with a wrong CRC on purpose",
            Mode::Ascii => "sent with a wrong LRC or framing on purpose",
        });
        let why = match (why, damaged) {
            (Some(w), Some(d)) => Some(format!("{d}; {w}")),
            (Some(w), None) => Some(w),
            (None, d) => d.map(str::to_string),
        };
        self.record(at, bytes, capture::FLAG_OUTBOUND | flags, why.as_deref());
    }

    /// Whether the inbound bytes held start a frame that is not whole yet, on a link whose
    /// timing is the host's: not a frame with a right checksum already, and shorter than
    /// the length its function tells as a request or as a reply (RTU; a master receives
    /// replies, a simulated drive requests, a tap both), or without its CR LF (ASCII).
    fn holds_part_of_a_frame(&self) -> bool {
        if !self.host_timing || checksum_ok(self.mode, &self.inbound) {
            return false;
        }
        let len = self.inbound.len();
        match self.mode {
            // Too short to tell its length: under the shortest frame (address, function,
            // CRC).
            Mode::Rtu => {
                len < 4
                    || [
                        crate::codec::Direction::Request,
                        crate::codec::Direction::Response,
                    ]
                    .into_iter()
                    .any(|d| {
                        matches!(
                            crate::codec::deframe::bus_rtu_frame_len(d, &self.inbound),
                            Some(n) if len < n
                        )
                    })
            }
            Mode::Ascii => self.inbound.first() == Some(&b':') && !self.inbound.ends_with(b"\r\n"),
        }
    }

    /// When a transmission of `len` characters that started at `before` (the clock read
    /// before the write) began on the line.
    fn sent_start(&self, before: Instant, len: usize) -> Instant {
        match (self.inner.sent_at(), self.char_time) {
            (Some(end), Some(c)) => end
                .checked_sub(c * len as u32)
                .map_or(before, |s| s.max(before)),
            _ => before,
        }
    }

    /// Where the other end says when it began its replies ([`Transport::peer_reply_starts`]):
    /// when the reply whose first bytes were read at `now` began (never before the end of
    /// the request), and, where this host made it begin [`LATE_NOTED`] or more after it
    /// was due, how late and how long after the request it was due. Starts before the
    /// last request are the replies to earlier ones, and are dropped; a start after `now`
    /// is a later reply's (what was read is something else: an echo).
    fn reply_start(&mut self, now: Instant) -> Option<(Instant, Option<(Duration, Duration)>)> {
        let sent = self.last_sent?;
        let queue = self.inner.peer_reply_starts()?;
        let mut q = queue.lock().ok()?;
        while q.front().is_some_and(|s| s.at < sent) {
            q.pop_front();
        }
        let start = *q.front().filter(|s| s.at <= now)?;
        q.pop_front();
        let due = later(sent, start.after);
        let late = start.at.saturating_duration_since(due);
        Some((
            start.at,
            (late >= LATE_NOTED).then_some((late, start.after)),
        ))
    }

    /// Writes the inbound packet held, if any.
    fn flush_inbound(&mut self) {
        if let Some(at) = self.inbound_at.take() {
            let bytes = std::mem::take(&mut self.inbound);
            let late = self.inbound_late.take().map(|(late, after)| {
                format!(
                    "{}: {} us (the simulator on this host was due to begin it {:.1} ms after the request)",
                    capture::LATE_ON_HOST,
                    late.as_micros(),
                    after.as_secs_f64() * 1000.0
                )
            });
            let why = if std::mem::take(&mut self.inbound_mid_traffic) {
                Some(format!(
                    "{}: listening began while the line was busy, so this may begin inside a frame",
                    capture::HEARD_MID_TRAFFIC
                ))
            } else {
                late
            };
            self.record(at, &bytes, self.inbound_flag, why.as_deref());
            self.inbound = bytes;
            self.inbound.clear();
        }
    }
}

impl<T: Transport> Drop for Captured<T> {
    fn drop(&mut self) {
        self.flush_inbound();
    }
}

impl<T: Transport> Transport for Captured<T> {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.flush_inbound();
        let before = Instant::now();
        let r = self.inner.send(bytes);
        let at = self.sent_start(before, bytes.len());
        self.last_sent = Some(self.inner.sent_at().unwrap_or_else(Instant::now));
        // A send this host stalled inside is not the frame the line carried, and the
        // master sends it again: marked so, a reader of the file does not take it for a
        // request the device left unanswered (issue 33). ASCII is not broken by a silence
        // under its 1 s timeout (as `Master` judges it).
        if r.is_ok() && self.mode == Mode::Rtu && self.inner.send_was_broken() {
            let why = format!(
                "{}: this host stalled while pacing it (a silence over t1.5 inside it), so a receiver that frames by silence dropped it; sent again",
                capture::BROKEN_BY_HOST
            );
            self.record_sent(at, bytes, capture::FLAG_WRONG_GAP, Some(why));
        } else {
            self.record_sent(at, bytes, 0, None);
        }
        r
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        let n = self.inner.recv(buf, timeout)?;
        let now = Instant::now();
        if let Some(t) = self.last_read {
            let silence = line_silence(now.saturating_duration_since(t), n, self.char_time);
            if !self.inbound.is_empty()
                && silence >= self.gap
                && (silence >= self.hold || !self.holds_part_of_a_frame())
            {
                self.flush_inbound();
            }
        }
        if n == 0 {
            self.started = true;
        } else {
            if self.inbound_at.is_none() {
                self.inbound_mid_traffic = self.tap && !std::mem::replace(&mut self.started, true);
                // (Where packets end is left to the link's own timing: a tap's dating
                // by the line's settings moves no packet's bounds.)
                let on_line = self
                    .char_time
                    .or(self.tap.then_some(self.line_char))
                    .map_or(Duration::ZERO, |c| c * n as u32);
                let mut at = now.checked_sub(on_line).unwrap_or(now);
                if let Some(sent) = self.last_sent {
                    at = at.max(sent);
                }
                // The simulator at the other end of an emulated line says when it began
                // the reply: that is when the line carried it, whenever this host read it.
                if let Some((start, late)) = self.reply_start(now) {
                    at = start;
                    self.inbound_late = late;
                }
                self.inbound_at = Some(at);
            }
            self.inbound.extend_from_slice(&buf[..n]);
            self.last_read = Some(now);
        }
        Ok(n)
    }

    fn discard_input(&mut self) -> Result<(), TransportError> {
        // What is waiting was on the line (a late reply the master gives up on): it is
        // read into the capture before it is dropped. Bounded: a peer that never stops
        // sending cannot hold the caller here.
        let mut buf = [0u8; 512];
        for _ in 0..64 {
            if self.recv(&mut buf, Duration::ZERO)? == 0 {
                break;
            }
        }
        self.flush_inbound();
        self.inner.discard_input()
    }

    fn describe(&self) -> String {
        self.inner.describe()
    }

    fn kind(&self) -> LinkKind {
        self.inner.kind()
    }

    fn sent_at(&self) -> Option<Instant> {
        self.inner.sent_at()
    }

    fn peer_lateness(&self) -> Option<Duration> {
        self.inner.peer_lateness()
    }

    fn send_was_broken(&self) -> bool {
        self.inner.send_was_broken()
    }

    fn line_timing(&self) -> Option<LineSettings> {
        self.inner.line_timing()
    }

    fn line_tags(&self) -> Option<LineTags> {
        self.inner.line_tags()
    }

    fn send_pieces(
        &mut self,
        pieces: &[&[u8]],
        gap: Duration,
    ) -> Result<Vec<Duration>, TransportError> {
        self.flush_inbound();
        let start = Instant::now();
        let r = self.inner.send_pieces(pieces, gap);
        self.last_sent = Some(self.inner.sent_at().unwrap_or_else(Instant::now));
        // The pieces' start times: from the gaps as they left, and each piece's time on
        // the line where it is known.
        let gaps = r.as_ref().map(|g| g.as_slice()).unwrap_or(&[]);
        let mut at = start;
        for (i, p) in pieces.iter().enumerate() {
            let flags = if i > 0 { capture::FLAG_WRONG_GAP } else { 0 };
            let why = Some(format!(
                "piece {} of {} sent with {} µs of silence between pieces on purpose",
                i + 1,
                pieces.len(),
                gap.as_micros()
            ));
            self.record_sent(at, p, flags, why);
            let on_line = self
                .char_time
                .map_or(Duration::ZERO, |c| c * p.len() as u32);
            at += on_line + gaps.get(i).copied().unwrap_or(gap);
        }
        r
    }

    fn frames_only(&self) -> Option<&'static str> {
        self.inner.frames_only()
    }

    fn take_notes(&mut self) -> Vec<String> {
        self.inner.take_notes()
    }
}

/// The most the line can have been silent between two reads `between` apart, the second
/// of which returned `n` characters of `char_time` each (unknown: the time between the
/// reads): those characters took their time on the line before the read returned, so a
/// reader that was late (descheduled) and got at once what came meanwhile does not take
/// that for a silence.
pub(super) fn line_silence(between: Duration, n: usize, char_time: Option<Duration>) -> Duration {
    let on_line = char_time.map_or(Duration::ZERO, |c| {
        c.saturating_mul(u32::try_from(n).unwrap_or(u32::MAX))
    });
    between.saturating_sub(on_line)
}
