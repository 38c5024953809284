//! Recording a link as a pcapng capture (`--capture FILE.pcapng`).
//!
//! [`Recorder`] owns the file: one interface per link opened (a run in both modes opens
//! two), and the label of what is running now (a check id), for the comments on frames
//! damaged on purpose. [`Captured`] wraps any [`Transport`] and records, on the
//! recorder it shares:
//!
//! - each `send` as one outbound packet, stamped with the time it started; each piece of a
//!   `send_pieces` as its own packet (the pieces after the first flagged "wrong
//!   inter-frame gap", bit 27): a receiver that frames by silence sees them so;
//! - received bytes grouped into inbound packets: a packet ends where the line was silent
//!   for the frame gap (t3.5, at least 5 ms, as the master frames) or where this side
//!   sends. On a link whose timing is the host's (a pseudo-terminal, TCP) a silence
//!   inside a frame whose length its function tells (and whose checksum is not right
//!   yet) is the host's delivery, not the line's: the frame is held whole unless the
//!   silence passes the master's timeout ([`Captured::holding_frames_for`]; [`HOST_STALL`] by default). A
//!   packet's time is that of the read that brought its first bytes, less their
//!   transmission time where the line's timing is known, and never before the end of the
//!   last frame sent (a reply cannot begin before its request ended).
//!
//! An outbound packet's time is when its first character went on the line: where the
//! transport knows when the last one left ([`Transport::sent_at`], a paced link), that
//! less the frame's transmission time.
//!
//! Each packet whose checksum is wrong (RTU CRC, ASCII LRC or delimiters) carries the
//! CRC-error bit (24); an outbound one also a comment naming the label (the check) that
//! damaged it. Bytes waiting when the caller discards input (a late reply it gave up on)
//! are read into the capture first, then dropped.
//! A write to the file that fails stops the recording and is reported once, at the end
//! ([`Recorder::error`]): the run itself goes on.

use std::io::Write;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant, SystemTime};

use super::{LineTags, LinkKind, Transport, TransportError};
use crate::capture::{self, Interface, PacketMeta, PcapngWriter};
use crate::codec::timing::later;
use crate::codec::timing::LineSettings;
use crate::codec::Mode;

/// A reply the simulator began this much later than due, or more, is marked in the
/// capture as late by this host ([`capture::LATE_ON_HOST`]): less is the pacing's jitter.
pub const LATE_NOTED: Duration = Duration::from_millis(1);

/// The longest silence inside a frame that a host's delivery is taken to cause on a link
/// without the line's timing.
pub const HOST_STALL: Duration = Duration::from_millis(200);

/// The capture file of a run, shared by the links it opens.
pub struct Recorder {
    writer: Option<PcapngWriter<Box<dyn Write + Send>>>,
    origin: Instant,
    origin_us: u64,
    label: Option<String>,
    error: Option<String>,
    packets: u64,
}

/// A recorder shared by the transports of a run and the command that labels the checks.
pub type SharedRecorder = Arc<Mutex<Recorder>>;

impl Recorder {
    /// Starts a capture on `sink` (a section header naming `application`).
    pub fn new(
        sink: Box<dyn Write + Send>,
        application: &str,
    ) -> Result<Self, capture::WriteError> {
        let origin_us = SystemTime::now()
            .duration_since(SystemTime::UNIX_EPOCH)
            .map(|d| d.as_micros() as u64)
            .unwrap_or(0);
        Ok(Recorder {
            writer: Some(PcapngWriter::new(sink, application)?),
            origin: Instant::now(),
            origin_us,
            label: None,
            error: None,
            packets: 0,
        })
    }

    /// Shares it.
    pub fn shared(self) -> SharedRecorder {
        Arc::new(Mutex::new(self))
    }

    /// What runs now (a check id, a fuzz case), named in the comment of frames it damages
    /// on purpose; None between checks.
    pub fn set_label(&mut self, label: Option<String>) {
        self.label = label;
    }

    /// The first write that failed, if one did (the recording stopped there).
    pub fn error(&self) -> Option<&str> {
        self.error.as_deref()
    }

    /// Packets written.
    pub fn packets(&self) -> u64 {
        self.packets
    }

    /// Describes a link; None once the recording failed.
    fn interface(&mut self, iface: &Interface) -> Option<u32> {
        let w = self.writer.as_mut()?;
        match w.add_interface(iface) {
            Ok(i) => Some(i),
            Err(e) => {
                self.fail(e);
                None
            }
        }
    }

    fn fail(&mut self, e: capture::WriteError) {
        self.error.get_or_insert_with(|| e.to_string());
        self.writer = None;
    }

    /// Writes one packet that started at `at`, with a comment: why it is damaged (after
    /// the label of what runs now), or else a note as it is.
    fn record(
        &mut self,
        interface: u32,
        at: Instant,
        bytes: &[u8],
        flags: u32,
        why: Option<&str>,
        note: Option<&str>,
    ) {
        let comment = match (why, &self.label) {
            (Some(why), Some(label)) => Some(format!("{label}: {why}")),
            (Some(why), None) => Some(why.to_string()),
            _ => None,
        };
        // Both where a whole ASCII frame is also marked (a reply begun late by the host).
        let comment = match (comment, note) {
            (Some(c), Some(n)) => Some(format!("{c}; {n}")),
            (c, n) => c.or_else(|| n.map(str::to_string)),
        };
        let since = at.saturating_duration_since(self.origin).as_micros() as u64;
        let meta = PacketMeta {
            interface,
            timestamp_us: self.origin_us + since,
            flags,
            comment,
        };
        let Some(w) = self.writer.as_mut() else {
            return;
        };
        match w.write_packet(&meta, bytes) {
            Ok(()) => self.packets += 1,
            Err(e) => self.fail(e),
        }
    }
}

/// A Modbus TCP connection recorded as Ethernet frames, with made-up Ethernet, IPv4 and
/// TCP headers around the stream's bytes ([`crate::capture::tcp`]): Wireshark decodes
/// them as Modbus/TCP with no settings. One segment a write, one a read.
pub struct TcpRecording {
    recorder: SharedRecorder,
    interface: Option<u32>,
    flow: capture::tcp::TcpFlow,
    /// Whether this side is the connection's client (the suite's master), or its server
    /// (the simulated gateway).
    client: bool,
}

impl TcpRecording {
    /// Starts recording the connection from `local` to `peer` on `recorder`: a new
    /// Ethernet interface (its description names the real addresses and `what`), and the
    /// handshake. An IPv6 address is written as 127.0.0.1.
    pub fn new(
        recorder: SharedRecorder,
        local: std::net::SocketAddr,
        peer: std::net::SocketAddr,
        what: &str,
    ) -> Self {
        Self::start(recorder, local, peer, what, true)
    }

    /// As [`TcpRecording::new`], for the server's side of a connection (the simulated
    /// gateway): what it sends goes from the server (written with port 502), what it
    /// receives from the client `peer`.
    pub fn serving(
        recorder: SharedRecorder,
        local: std::net::SocketAddr,
        peer: std::net::SocketAddr,
        what: &str,
    ) -> Self {
        Self::start(recorder, local, peer, what, false)
    }

    fn start(
        recorder: SharedRecorder,
        local: std::net::SocketAddr,
        peer: std::net::SocketAddr,
        what: &str,
        client: bool,
    ) -> Self {
        let (from, to) = if client { (local, peer) } else { (peer, local) };
        let v4 = |a: std::net::SocketAddr| match a.ip() {
            std::net::IpAddr::V4(ip) => ip,
            std::net::IpAddr::V6(_) => std::net::Ipv4Addr::LOCALHOST,
        };
        let iface = Interface {
            link_type: capture::tcp::LINKTYPE_ETHERNET,
            name: format!("tcp {peer}"),
            description: format!(
                "{what}: TCP {from} -> {to}, written with made-up Ethernet/IPv4/TCP headers (server port written as {}; MACs, sequence numbers and handshake made up)",
                capture::tcp::MODBUS_TCP_PORT
            ),
        };
        let interface = recorder.lock().ok().and_then(|mut r| r.interface(&iface));
        let mut flow = capture::tcp::TcpFlow::new((v4(from), from.port()), v4(to));
        let now = Instant::now();
        if let (Some(i), Ok(mut r)) = (interface, recorder.lock()) {
            for p in flow.handshake() {
                r.record(i, now, &p, 0, None, None);
            }
        }
        TcpRecording {
            recorder,
            interface,
            flow,
            client,
        }
    }

    /// Records bytes written to the connection, at `at`.
    pub fn sent(&mut self, at: Instant, bytes: &[u8]) {
        self.segment(true, at, bytes);
    }

    /// Records bytes read from the connection, at `at`.
    pub fn received(&mut self, at: Instant, bytes: &[u8]) {
        self.segment(false, at, bytes);
    }

    fn segment(&mut self, outbound: bool, at: Instant, bytes: &[u8]) {
        let Some(i) = self.interface else {
            return;
        };
        // The flow counts from the client's side: what this side sends comes from the
        // client when this side is the client.
        let packet = self.flow.data(outbound == self.client, bytes);
        let flags = if outbound {
            capture::FLAG_OUTBOUND
        } else {
            capture::FLAG_INBOUND
        };
        if let Ok(mut r) = self.recorder.lock() {
            r.record(i, at, &packet, flags, None, None);
        }
    }
}

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
    pub fn as_tap(mut self) -> Self {
        self.inbound_flag = 0;
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
            self.record(at, &bytes, self.inbound_flag, late.as_deref());
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
        if n > 0 {
            if self.inbound_at.is_none() {
                let on_line = self.char_time.map_or(Duration::ZERO, |c| c * n as u32);
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
fn line_silence(between: Duration, n: usize, char_time: Option<Duration>) -> Duration {
    let on_line = char_time.map_or(Duration::ZERO, |c| {
        c.saturating_mul(u32::try_from(n).unwrap_or(u32::MAX))
    });
    between.saturating_sub(on_line)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::capture::{Reader, FLAG_INBOUND, FLAG_OUTBOUND, FLAG_WRONG_GAP};
    use crate::codec::timing::Parity;
    use crate::transport::memory;

    /// A sink the test reads back after the recorder wrote to it.
    #[derive(Clone, Default)]
    struct Sink(Arc<Mutex<Vec<u8>>>);

    impl Write for Sink {
        fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
            self.0.lock().unwrap().extend_from_slice(b);
            Ok(b.len())
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }

    const REQUEST: [u8; 8] = [0x01, 0x03, 0x01, 0x23, 0x00, 0x01, 0x74, 0x3C];
    const REPLY: [u8; 7] = [0x01, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50];
    const EXCEPTION: [u8; 5] = [0x01, 0x83, 0x02, 0xC0, 0xF1];

    fn drain(t: &mut impl Transport, wait: Duration) -> usize {
        let mut buf = [0u8; 64];
        t.recv(&mut buf, wait).unwrap()
    }

    #[test]
    fn sends_and_receives_become_packets_with_directions_flags_and_comments() {
        let sink = Sink::default();
        let rec = Recorder::new(Box::new(sink.clone()), "test")
            .unwrap()
            .shared();
        let (a, mut b) = memory::pair();
        let line = LineSettings::new(9600, 8, Parity::Even, 1);
        let mut a = Captured::new(a, rec.clone(), Mode::Rtu, line);
        rec.lock()
            .unwrap()
            .set_label(Some("check rtu.bad-crc".into()));
        a.send(&REQUEST).unwrap();
        // A reply the host delivers in two parts 20 ms apart (over the 5 ms frame gap):
        // its length says it is not whole after the first part, so it is one packet.
        b.send(&REPLY[..3]).unwrap();
        assert_eq!(drain(&mut a, Duration::from_millis(200)), 3);
        std::thread::sleep(Duration::from_millis(20));
        b.send(&REPLY[3..]).unwrap();
        assert_eq!(drain(&mut a, Duration::from_millis(200)), 4);
        // A whole frame after a silence: a new packet.
        std::thread::sleep(Duration::from_millis(20));
        b.send(&EXCEPTION).unwrap();
        assert_eq!(drain(&mut a, Duration::from_millis(200)), 5);
        assert_eq!(drain(&mut a, Duration::from_millis(20)), 0);
        let mut bad = REQUEST;
        bad[7] ^= 0xFF;
        a.send(&bad).unwrap();
        a.send_pieces(&[&REQUEST[..4], &REQUEST[4..]], Duration::from_millis(2))
            .unwrap();
        drop(a);
        let data = sink.0.lock().unwrap().clone();
        let packets: Vec<_> = Reader::new(&data)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        let seen: Vec<(&[u8], u32)> = packets
            .iter()
            .map(|p| (p.data, p.flags.unwrap_or(0)))
            .collect();
        assert_eq!(
            seen,
            vec![
                (&REQUEST[..], FLAG_OUTBOUND),
                (&REPLY[..], FLAG_INBOUND),
                (&EXCEPTION[..], FLAG_INBOUND),
                (&bad[..], FLAG_OUTBOUND | capture::FLAG_CRC_ERROR),
                (&REQUEST[..4], FLAG_OUTBOUND | capture::FLAG_CRC_ERROR),
                (
                    &REQUEST[4..],
                    FLAG_OUTBOUND | capture::FLAG_CRC_ERROR | FLAG_WRONG_GAP
                ),
            ]
        );
        assert!(packets
            .iter()
            .all(|p| p.link_type == capture::LINKTYPE_USER0));
        assert_eq!(packets[0].comment, None);
        assert_eq!(packets[1].comment, None);
        assert_eq!(
            packets[3].comment,
            Some("check rtu.bad-crc: sent with a wrong CRC on purpose")
        );
        assert!(packets[5]
            .comment
            .is_some_and(|c| c.starts_with("check rtu.bad-crc: ") && c.contains("piece 2 of 2")));
        // Times: in order, the reply after the request, the exception 20 ms or more after
        // the reply's first part.
        let t: Vec<u64> = packets.iter().map(|p| p.timestamp_ns.unwrap()).collect();
        assert!(t.windows(2).all(|w| w[0] <= w[1]), "{t:?}");
        assert!(t[2] - t[1] >= 40_000_000, "{t:?}");
        assert_eq!(rec.lock().unwrap().packets(), 6);
        assert_eq!(rec.lock().unwrap().error(), None);
    }

    /// 9600 8E1 (1146 us a character, a 5 ms frame gap): four characters read 7 ms after
    /// the read before came within the last 4.6 ms, so the line was silent 2.4 ms at most
    /// (no frame gap); one character 7 ms later leaves 5.9 ms (a frame gap); with the
    /// host's timing only, the time between reads is all there is.
    #[test]
    fn the_silence_between_reads_leaves_out_the_time_the_characters_took() {
        let c = Some(Duration::from_micros(1146));
        let ms = Duration::from_millis;
        assert_eq!(
            line_silence(ms(7), 4, c),
            Duration::from_micros(7000 - 4584)
        );
        assert_eq!(
            line_silence(ms(7), 1, c),
            Duration::from_micros(7000 - 1146)
        );
        assert_eq!(line_silence(ms(7), 0, c), ms(7));
        assert_eq!(line_silence(ms(3), 10, c), Duration::ZERO);
        assert_eq!(line_silence(ms(7), 4, None), ms(7));
        assert_eq!(line_silence(ms(7), usize::MAX, c), Duration::ZERO);
    }

    #[test]
    fn a_tap_records_requests_and_replies_apart_and_without_direction() {
        let sink = Sink::default();
        let rec = Recorder::new(Box::new(sink.clone()), "test")
            .unwrap()
            .shared();
        let (a, mut b) = memory::pair();
        let line = LineSettings::new(9600, 8, Parity::Even, 1);
        let mut a = Captured::new(a, rec, Mode::Rtu, line).as_tap();
        // A request read as a reply would be 42 bytes long (byte count 25H): its right
        // CRC says it is whole.
        let request = [0x01, 0x03, 0x25, 0x20, 0x00, 0x01, 0x8E, 0xCC];
        b.send(&request).unwrap();
        assert_eq!(drain(&mut a, Duration::from_millis(200)), 8);
        std::thread::sleep(Duration::from_millis(20));
        b.send(&REPLY).unwrap();
        assert_eq!(drain(&mut a, Duration::from_millis(200)), 7);
        drop(a);
        let data = sink.0.lock().unwrap().clone();
        let packets: Vec<_> = Reader::new(&data)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        let seen: Vec<(&[u8], Option<u32>)> = packets.iter().map(|p| (p.data, p.flags)).collect();
        assert_eq!(seen, vec![(&request[..], None), (&REPLY[..], None)]);
    }

    /// The rest of a reply read long after its first part (the reading host stalled) is
    /// the same packet, as the master that waits its timeout for it takes it whole.
    #[test]
    fn a_reply_read_in_two_parts_by_a_stalled_host_is_one_packet_while_the_master_waits() {
        let sink = Sink::default();
        let rec = Recorder::new(Box::new(sink.clone()), "test")
            .unwrap()
            .shared();
        let (a, mut b) = memory::pair();
        let line = LineSettings::new(9600, 8, Parity::Even, 1);
        let mut a =
            Captured::new(a, rec, Mode::Rtu, line).holding_frames_for(Duration::from_secs(30));
        a.send(&REQUEST).unwrap();
        b.send(&REPLY[..4]).unwrap();
        let mut got = 0;
        while got < 4 {
            got += drain(&mut a, Duration::from_millis(100));
        }
        // Longer than HOST_STALL, far shorter than the hold.
        std::thread::sleep(HOST_STALL + Duration::from_millis(100));
        b.send(&REPLY[4..]).unwrap();
        while got < REPLY.len() {
            got += drain(&mut a, Duration::from_millis(100));
        }
        a.send(&REQUEST).unwrap();
        drop(a);
        let data = sink.0.lock().unwrap().clone();
        let packets: Vec<_> = Reader::new(&data)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        let datas: Vec<&[u8]> = packets.iter().map(|p| p.data).collect();
        assert_eq!(datas, [&REQUEST[..], &REPLY[..], &REQUEST[..]]);
        assert_eq!(packets[1].flags.unwrap_or(0) & capture::FLAG_CRC_ERROR, 0);
    }

    #[test]
    fn bytes_discarded_by_the_caller_are_in_the_capture_first() {
        let sink = Sink::default();
        let rec = Recorder::new(Box::new(sink.clone()), "test")
            .unwrap()
            .shared();
        let (a, mut b) = memory::pair();
        let line = LineSettings::new(9600, 8, Parity::Even, 1);
        let mut a = Captured::new(a, rec, Mode::Rtu, line);
        a.send(&REQUEST).unwrap();
        b.send(&REPLY).unwrap();
        std::thread::sleep(Duration::from_millis(10));
        a.discard_input().unwrap();
        assert_eq!(drain(&mut a, Duration::from_millis(10)), 0);
        drop(a);
        let data = sink.0.lock().unwrap().clone();
        let packets: Vec<_> = Reader::new(&data)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(packets.len(), 2);
        assert_eq!(packets[1].data, &REPLY);
        assert_eq!(packets[1].direction, Some(capture::Direction::Inbound));
    }

    #[test]
    fn a_failing_file_stops_the_recording_and_says_why_once() {
        struct Full;
        impl Write for Full {
            fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
                Err(std::io::Error::other("disk full"))
            }
            fn flush(&mut self) -> std::io::Result<()> {
                Ok(())
            }
        }
        // The section header goes to a sink that fails from the first packet on.
        struct Once(bool);
        impl Write for Once {
            fn write(&mut self, b: &[u8]) -> std::io::Result<usize> {
                if self.0 {
                    Full.write(b)
                } else {
                    Ok(b.len())
                }
            }
            fn flush(&mut self) -> std::io::Result<()> {
                self.0 = true;
                Ok(())
            }
        }
        let rec = Recorder::new(Box::new(Once(false)), "test")
            .unwrap()
            .shared();
        let (a, _b) = memory::pair();
        let mut a = Captured::new(
            a,
            rec.clone(),
            Mode::Rtu,
            LineSettings::new(9600, 8, Parity::Even, 1),
        );
        // The link goes on working; the recording stopped at the interface block.
        a.send(&REQUEST).unwrap();
        a.send(&REQUEST).unwrap();
        let r = rec.lock().unwrap();
        assert_eq!(r.packets(), 0);
        assert!(
            r.error().is_some_and(|e| e.contains("disk full")),
            "{:?}",
            r.error()
        );
    }

    /// An in-memory link that says what a paced link says: its first `broken` sends were
    /// broken by its host ([`Transport::send_was_broken`]), and the simulator at its other
    /// end told when it began its replies (`starts`, [`Transport::peer_reply_starts`]).
    struct Shaped {
        inner: memory::MemoryEnd,
        broken: u32,
        sends: u32,
        starts: Option<crate::transport::ReplyStarts>,
    }

    impl Shaped {
        fn new(inner: memory::MemoryEnd) -> Self {
            Shaped {
                inner,
                broken: 0,
                sends: 0,
                starts: None,
            }
        }
    }

    impl Transport for Shaped {
        fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
            self.sends += 1;
            self.inner.send(bytes)
        }
        fn recv(&mut self, buf: &mut [u8], t: Duration) -> Result<usize, TransportError> {
            self.inner.recv(buf, t)
        }
        fn discard_input(&mut self) -> Result<(), TransportError> {
            self.inner.discard_input()
        }
        fn describe(&self) -> String {
            "a paced link".into()
        }
        fn line_timing(&self) -> Option<LineSettings> {
            None
        }
        fn kind(&self) -> LinkKind {
            LinkKind::Pty
        }
        fn send_was_broken(&self) -> bool {
            self.sends <= self.broken
        }
        fn peer_reply_starts(&self) -> Option<crate::transport::ReplyStarts> {
            self.starts.clone()
        }
    }

    /// A link whose host stalled inside a send (on a line whose receiver is not told the
    /// silences, see [`Transport::send_was_broken`]): each broken send is its own outbound
    /// packet flagged "wrong inter-frame gap" (bit 27) with a comment saying the host broke
    /// it, which [`capture::broken_by_host`] reads back; the next, whole send is plain.
    #[test]
    fn a_send_the_host_broke_is_flagged_and_commented_and_the_next_one_is_not() {
        let sink = Sink::default();
        let rec = Recorder::new(Box::new(sink.clone()), "test")
            .unwrap()
            .shared();
        let (a, _b) = memory::pair();
        let line = LineSettings::new(9600, 8, Parity::Even, 1);
        let link = Shaped {
            broken: 2,
            ..Shaped::new(a)
        };
        let mut a = Captured::new(link, rec.clone(), Mode::Rtu, line);
        for _ in 0..3 {
            a.send(&REQUEST).unwrap();
        }
        drop(a);
        let data = sink.0.lock().unwrap().clone();
        let packets: Vec<_> = Reader::new(&data)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        let broken: Vec<bool> = packets
            .iter()
            .map(|p| capture::broken_by_host(p.flags, p.comment))
            .collect();
        assert_eq!(broken, [true, true, false]);
        assert!(packets.iter().all(|p| p.data == REQUEST));
        assert_eq!(packets[0].flags, Some(FLAG_OUTBOUND | FLAG_WRONG_GAP));
        assert_eq!(packets[2].flags, Some(FLAG_OUTBOUND));
        // ASCII is not broken by a silence under its 1 s timeout: nothing is flagged.
        let sink = Sink::default();
        let rec = Recorder::new(Box::new(sink.clone()), "test")
            .unwrap()
            .shared();
        let (a, _b) = memory::pair();
        let link = Shaped {
            broken: 1,
            ..Shaped::new(a)
        };
        let mut a = Captured::new(link, rec, Mode::Ascii, line);
        a.send(b":010300000001FB\r\n").unwrap();
        drop(a);
        let data = sink.0.lock().unwrap().clone();
        let p: Vec<_> = Reader::new(&data)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(p.len(), 1);
        assert!(!capture::broken_by_host(p[0].flags, p[0].comment));
    }

    /// Where the simulator at the other end says when it began its replies, a reply is
    /// recorded at that time (whenever this host read it); one it began 30 ms after it was
    /// due carries a comment that says so, which [`capture::late_on_host`] reads back; one
    /// on time carries none, and a start from before the request (an earlier reply's) is
    /// not taken for this one's.
    #[test]
    fn a_reply_the_simulators_host_began_late_is_recorded_when_it_began_and_marked() {
        let sink = Sink::default();
        let rec = Recorder::new(Box::new(sink.clone()), "test")
            .unwrap()
            .shared();
        let (a, mut b) = memory::pair();
        let starts = crate::transport::ReplyStarts::default();
        let line = LineSettings::new(9600, 8, Parity::Even, 1);
        let link = Shaped {
            starts: Some(starts.clone()),
            ..Shaped::new(a)
        };
        let mut a = Captured::new(link, rec, Mode::Rtu, line);
        let after = Duration::from_millis(10);
        let mut began = Vec::new();
        let mut slack = Duration::ZERO;
        for late in [Duration::from_millis(30), Duration::ZERO] {
            // An earlier reply's start, before this request: not this reply's.
            crate::transport::push_reply_start(
                &starts,
                crate::transport::ReplyStart {
                    at: Instant::now(),
                    after,
                },
            );
            std::thread::sleep(Duration::from_millis(2));
            let before = Instant::now();
            a.send(&REQUEST).unwrap();
            let sent = Instant::now();
            slack = slack.max(sent - before);
            let at = sent + after + late;
            began.push((before, at));
            crate::transport::push_reply_start(&starts, crate::transport::ReplyStart { at, after });
            while Instant::now() < at {
                std::thread::sleep(Duration::from_millis(1));
            }
            b.send(&REPLY).unwrap();
            // Read well after it came (this host busy too).
            std::thread::sleep(Duration::from_millis(40));
            assert_eq!(drain(&mut a, Duration::from_millis(200)), 7);
        }
        drop(a);
        let data = sink.0.lock().unwrap().clone();
        let packets: Vec<_> = Reader::new(&data)
            .unwrap()
            .collect::<Result<_, _>>()
            .unwrap();
        assert_eq!(packets.len(), 4);
        let late = capture::late_on_host(packets[1].comment).expect("the late reply is marked");
        // Late by 30 ms from the end of the request as the recorder's clock read it (a
        // little before this test's own reading of it).
        assert!(
            late >= Duration::from_millis(30)
                && late <= Duration::from_millis(30) + slack + Duration::from_millis(1),
            "{late:?}"
        );
        assert_eq!(packets[3].comment, None);
        // Recorded when the simulator began, not when this host read them (40 ms later).
        let t = |i: usize| Duration::from_nanos(packets[i].timestamp_ns.unwrap());
        for (k, i) in [1usize, 3].into_iter().enumerate() {
            let took = t(i) - t(i - 1);
            let meant = began[k].1 - began[k].0;
            assert!(
                took.abs_diff(meant) < Duration::from_millis(1),
                "packet {i}: {took:?} against {meant:?}"
            );
        }
    }
}
