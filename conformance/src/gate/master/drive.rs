//! The drive's end of the line in a master gate run: a thread that holds the master side
//! of a pseudo-terminal pair, frames the requests the master under test sends, answers
//! them as the model says a drive does, and misbehaves on purpose as the case's
//! [`Behaviour`] says. Every byte each way is logged with its time, and every frame sent
//! is kept with the register values it carried, so that the judge can tell which frame
//! (if any) a value the master reports came from.
//!
//! Register values are tags: every read reply carries values no other frame of the run
//! carries (a counter of frames sent), so a stale, shifted, duplicated or other node's
//! reply is recognisable in what the master reports.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::codec::ascii::Scratch;
use crate::codec::deframe::{AsciiDeframer, Event, RtuDeframer, RtuFraming};
use crate::codec::hex::Hex;
use crate::codec::pdu::{Direction, Message, Pdu, Registers};
use crate::codec::timing::later;
use crate::codec::timing::LineSettings;
use crate::codec::{self, Mode};
use crate::model::{DriveModel, Expectation};
use crate::transport::pty::PtyMaster;
use crate::transport::tcp::TcpTransport;
use crate::transport::{Transport, TransportError};

/// What the drive does with the requests of one operation.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Behaviour {
    /// What the model says.
    Normal,
    /// Exception `code` in place of a normal reply.
    Exception(u8),
    /// The normal reply, this long after the request (inside the master's timeout).
    Late(Duration),
    /// The normal reply held back until the gate releases it, after the master gave up
    /// (the stale reply).
    AfterTimeout,
    /// The normal reply held back until the master's next request arrives, then sent at
    /// once, before that request's own reply (the stale reply in flight).
    InFlight,
    /// A read answered with a 06H echo (a reply of another function).
    WrongFunction,
    /// Nothing.
    NoReply,
    /// The reply cut short.
    Truncated,
    /// The reply with a wrong CRC or LRC.
    BadChecksum,
    /// These bytes, a silence, then the reply.
    GarbageBefore(Vec<u8>),
    /// The reply, a silence, then these bytes.
    GarbageAfter(Vec<u8>),
    /// An exception reply with `code` and no CRC or LRC.
    ExceptionNoChecksum(u8),
    /// The reply as node `n` sends it (its address), and nothing from the node asked.
    OtherNode(u8),
    /// The reply in two parts with this silence between them.
    Split(Duration),
    /// The reply, a silence, and the same reply again.
    Twice,
    /// A broadcast is answered as if it were addressed to the drive.
    ReplyToBroadcast,
}

/// Which way bytes went.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Dir {
    /// From the master under test.
    FromMaster,
    /// From the gate's drive.
    ToMaster,
}

/// Bytes that went over the line at one time (since the run's origin).
#[derive(Debug, Clone)]
pub struct Chunk {
    /// When: for bytes from the master, when they were read; for bytes to it, just
    /// before they were written (the earliest the master can have had them).
    pub at: Duration,
    /// For bytes to the master, just after they were written (the latest they can have
    /// gone out); for bytes from it, `at`.
    pub done: Duration,
    /// Which way.
    pub dir: Dir,
    /// The bytes.
    pub bytes: Vec<u8>,
}

/// What a frame the drive sent is.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SentClass {
    /// A valid reply to the request, sent while the master waited.
    Reply,
    /// A valid reply sent after the master's operation had ended (a stale reply).
    Stale,
    /// A valid reply with another node's address.
    OtherNode,
    /// A reply with a wrong CRC or LRC.
    BadChecksum,
    /// A reply cut short.
    Truncated,
    /// An exception without its CRC or LRC.
    NoChecksum,
    /// Bytes that are no frame.
    Garbage,
    /// A second copy of a reply.
    Duplicate,
    /// A reply to a broadcast.
    BroadcastReply,
    /// A valid frame of another function than the request's.
    WrongFunction,
}

impl SentClass {
    /// Whether a master may take what the frame carries as the answer to its request.
    pub fn valid(self) -> bool {
        matches!(self, SentClass::Reply)
    }
}

/// A frame (or bytes) the drive sent.
#[derive(Debug, Clone)]
pub struct Sent {
    /// The request (by sequence number) it answers.
    pub for_seq: u32,
    /// The bytes.
    pub bytes: Vec<u8>,
    /// What it is.
    pub class: SentClass,
    /// Register values it carries (a read reply).
    pub values: Option<Vec<u16>>,
    /// Exception code it carries.
    pub exception: Option<u8>,
    /// When it went out; None while it is held or queued.
    pub at: Option<Duration>,
}

/// A request the drive received.
#[derive(Debug, Clone)]
pub struct Request {
    /// Sequence number in the run, from 1.
    pub seq: u32,
    /// When its first byte was read.
    pub start: Duration,
    /// When its last byte was read.
    pub end: Duration,
    /// Its bytes.
    pub bytes: Vec<u8>,
    /// Whether its checksum and format were valid.
    pub valid: bool,
    /// The address it carries (0 where it has none).
    pub address: u8,
}

#[derive(Default)]
struct State {
    behaviour: Option<Behaviour>,
    log: Vec<Chunk>,
    requests: Vec<Request>,
    sent: Vec<Sent>,
    /// Sends due: (when, index in `sent`, or bytes that are no frame of their own).
    queue: Vec<(Instant, usize)>,
    /// Indices in `sent` held back (the stale reply).
    held: Vec<usize>,
    /// Indices in `sent` held back until the next request (the stale reply in flight).
    in_flight: Vec<usize>,
    seq: u32,
    frames: u32,
    error: Option<String>,
    /// Times the drive's thread was not scheduled for longer than [`STALL`]: (from, to).
    stalls: Vec<(Duration, Duration)>,
}

/// A gap between two turns of the drive's loop (which turns at least every 5 ms) over
/// this is the host's doing: bytes waited unread, replies went out late. Recorded; the
/// run decides per case how long a stall it tolerates.
pub const STALL: Duration = Duration::from_millis(20);

/// The drive's end of the line.
pub struct DriveSide {
    state: Arc<Mutex<State>>,
    stop: Arc<AtomicBool>,
    thread: Option<JoinHandle<()>>,
    endpoint: Endpoint,
    origin: Instant,
    /// RTU or ASCII.
    pub mode: Mode,
    /// The line (its timing).
    pub line: LineSettings,
}

/// The silence the drive leaves between two things it sends on purpose apart (garbage
/// and the reply, a reply and its copy): over t3.5, and long enough for a host to see.
pub fn apart(line: &LineSettings) -> Duration {
    Duration::from_micros(line.t3_5_us() * 3).max(Duration::from_millis(10))
}

/// The tag values of read reply number `frame` (from 1) with `n` registers: no two
/// frames of a run of under 2048 frames share a value.
pub fn tags(frame: u32, n: usize) -> Vec<u16> {
    (0..n)
        .map(|i| 0x8000 | (((frame as u16) & 0x07FF) << 4) | (i as u16 & 0x0F))
        .collect()
}

fn lock(state: &Mutex<State>) -> MutexGuard<'_, State> {
    state.lock().unwrap_or_else(|e| e.into_inner())
}

/// Where the master reaches the drive.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Endpoint {
    /// A pseudo-terminal's slave path, opened as a serial port.
    Pty(PathBuf),
    /// RTU (or ASCII) frames over a TCP stream to this address (`tcp-rtu`).
    TcpRtu(std::net::SocketAddr),
    /// Modbus TCP (MBAP) at this address (`mbap`): the gate plays a Modbus TCP gateway
    /// with the drive behind it.
    Mbap(std::net::SocketAddr),
}

/// The kind of line the gate serves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum LineKind {
    /// A pseudo-terminal pair.
    Pty,
    /// A TCP listener on 127.0.0.1 carrying the serial frames as they are.
    TcpRtu,
    /// A TCP listener on 127.0.0.1 speaking Modbus TCP (MBAP): the drive's frames cross
    /// as a gateway passes them (the PDU, the request's transaction id, the unit id the
    /// address; a frame with a wrong CRC, cut short or with bytes around it does not
    /// cross).
    Mbap,
}

impl LineKind {
    /// As the protocol's `line.kind` spells it.
    pub fn key(self) -> &'static str {
        match self {
            LineKind::Pty => "pty",
            LineKind::TcpRtu => "tcp-rtu",
            LineKind::Mbap => "mbap",
        }
    }
}

/// The drive's end: a pty, or a TCP listener and the connection it accepted.
enum Link {
    Pty(PtyMaster),
    Tcp {
        listener: std::net::TcpListener,
        conn: Option<TcpTransport>,
    },
    Mbap(Box<MbapLink>),
}

/// The drive behind a Modbus TCP gateway: MBAP frames from the master become the RTU
/// frames the drive reads (unit id as the address, the PDU, a CRC), and each frame the
/// drive sends goes back as the gateway would pass it, under the transaction id of the
/// request it answers.
struct MbapLink {
    listener: std::net::TcpListener,
    conn: Option<std::net::TcpStream>,
    rx: Vec<u8>,
    /// RTU frames made of MBAP requests, not read by the drive yet.
    out: Vec<u8>,
    /// The transaction id of each request, by the drive's sequence number less one.
    transactions: Vec<u16>,
}

impl MbapLink {
    fn recv(&mut self, buf: &mut [u8], wait: Duration) -> Result<usize, TransportError> {
        use std::io::Read;
        if self.out.is_empty() {
            if self.conn.is_none() {
                match self.listener.accept() {
                    Ok((s, _)) => {
                        let _ = s.set_nonblocking(false);
                        let _ = s.set_nodelay(true);
                        self.conn = Some(s);
                        self.rx.clear();
                    }
                    Err(_) => {
                        std::thread::sleep(wait);
                        return Ok(0);
                    }
                }
            }
            let Some(c) = self.conn.as_mut() else {
                return Ok(0);
            };
            let _ = c.set_read_timeout(Some(wait.max(Duration::from_micros(100))));
            let mut tmp = [0u8; 512];
            match c.read(&mut tmp) {
                // The master closed its connection: wait for its next one.
                Ok(0) => {
                    self.conn = None;
                    return Ok(0);
                }
                Ok(n) => self.rx.extend_from_slice(&tmp[..n]),
                Err(e)
                    if matches!(
                        e.kind(),
                        std::io::ErrorKind::WouldBlock
                            | std::io::ErrorKind::TimedOut
                            | std::io::ErrorKind::Interrupted
                    ) => {}
                Err(_) => {
                    self.conn = None;
                    return Ok(0);
                }
            }
            use crate::codec::mbap::{frame_status, MbapFrame, MbapRepr, Status};
            loop {
                match frame_status(&self.rx) {
                    Ok(Status::Complete(n)) => {
                        if let Ok(r) =
                            MbapFrame::new_checked(&self.rx[..n]).and_then(|f| MbapRepr::parse(&f))
                        {
                            self.transactions.push(r.transaction);
                            let mut body = vec![r.unit];
                            body.extend_from_slice(r.pdu);
                            let crc = crate::codec::crc::crc16(&body).to_le_bytes();
                            self.out.extend_from_slice(&body);
                            self.out.extend_from_slice(&crc);
                        }
                        self.rx.drain(..n);
                    }
                    Ok(Status::Partial(_)) => break,
                    // A stream that cannot be followed past a bad header: a gateway
                    // closes it.
                    Err(_) => {
                        self.conn = None;
                        self.rx.clear();
                        break;
                    }
                }
            }
        }
        let n = buf.len().min(self.out.len());
        buf[..n].copy_from_slice(&self.out[..n]);
        self.out.drain(..n);
        Ok(n)
    }

    fn send(&mut self, bytes: &[u8], for_seq: u32) -> Result<(), TransportError> {
        use std::io::Write;
        let Some(c) = self.conn.as_mut() else {
            return Ok(());
        };
        // What a gateway's serial receiver passes: one whole frame with a right CRC.
        if bytes.len() < 4 || crate::codec::crc::crc16(bytes) != 0 {
            return Ok(());
        }
        let transaction = for_seq
            .checked_sub(1)
            .and_then(|i| self.transactions.get(i as usize))
            .or(self.transactions.last())
            .copied()
            .unwrap_or(0);
        let repr = crate::codec::mbap::MbapRepr {
            transaction,
            unit: bytes[0],
            pdu: &bytes[1..bytes.len() - 2],
        };
        let mut out = [0u8; crate::codec::mbap::MAX_ADU];
        let Ok(n) = repr.emit(&mut out) else {
            return Ok(());
        };
        if c.write_all(&out[..n]).is_err() {
            self.conn = None;
        }
        Ok(())
    }
}

impl Link {
    fn recv(&mut self, buf: &mut [u8], wait: Duration) -> Result<usize, TransportError> {
        match self {
            Link::Mbap(m) => m.recv(buf, wait),
            Link::Pty(p) => p.recv(buf, wait),
            Link::Tcp { listener, conn } => {
                if conn.is_none() {
                    match listener.accept() {
                        Ok((s, _)) => {
                            let _ = s.set_nonblocking(false);
                            *conn = TcpTransport::from_stream(s).ok();
                        }
                        Err(_) => {
                            std::thread::sleep(wait);
                            return Ok(0);
                        }
                    }
                }
                let Some(c) = conn.as_mut() else {
                    return Ok(0);
                };
                match c.recv(buf, wait) {
                    // The master closed its connection: wait for its next one.
                    Err(TransportError::Closed { .. }) => {
                        *conn = None;
                        Ok(0)
                    }
                    other => other,
                }
            }
        }
    }

    fn send(&mut self, bytes: &[u8], for_seq: u32) -> Result<(), TransportError> {
        match self {
            Link::Mbap(m) => m.send(bytes, for_seq),
            Link::Pty(p) => p.send(bytes),
            Link::Tcp { conn: Some(c), .. } => c.send(bytes),
            // Nobody connected: the bytes go nowhere, as on a line nobody listens to.
            Link::Tcp { conn: None, .. } => Ok(()),
        }
    }
}

impl DriveSide {
    /// Opens a pseudo-terminal pair and starts serving node `node` of `model` on it.
    pub fn start(
        model: Arc<DriveModel>,
        node: u8,
        mode: Mode,
        line: LineSettings,
    ) -> Result<Self, TransportError> {
        Self::start_on(model, node, mode, line, LineKind::Pty)
    }

    /// [`DriveSide::start`] on a line of `kind`.
    pub fn start_on(
        model: Arc<DriveModel>,
        node: u8,
        mode: Mode,
        line: LineSettings,
        kind: LineKind,
    ) -> Result<Self, TransportError> {
        let (link, endpoint) = match kind {
            LineKind::Pty => {
                let pty = PtyMaster::open(None)?;
                let path = pty.slave_path().to_path_buf();
                (Link::Pty(pty), Endpoint::Pty(path))
            }
            LineKind::TcpRtu => {
                let open_err = |source| TransportError::Open {
                    what: "a TCP listener on 127.0.0.1 for the master".into(),
                    source,
                };
                let listener = std::net::TcpListener::bind("127.0.0.1:0").map_err(open_err)?;
                listener.set_nonblocking(true).map_err(open_err)?;
                let addr = listener.local_addr().map_err(open_err)?;
                (
                    Link::Tcp {
                        listener,
                        conn: None,
                    },
                    Endpoint::TcpRtu(addr),
                )
            }
            LineKind::Mbap => {
                let open_err = |source| TransportError::Open {
                    what: "a Modbus TCP listener on 127.0.0.1 for the master".into(),
                    source,
                };
                let listener = std::net::TcpListener::bind("127.0.0.1:0").map_err(open_err)?;
                listener.set_nonblocking(true).map_err(open_err)?;
                let addr = listener.local_addr().map_err(open_err)?;
                (
                    Link::Mbap(Box::new(MbapLink {
                        listener,
                        conn: None,
                        rx: Vec::new(),
                        out: Vec::new(),
                        transactions: Vec::new(),
                    })),
                    Endpoint::Mbap(addr),
                )
            }
        };
        let state = Arc::new(Mutex::new(State::default()));
        let stop = Arc::new(AtomicBool::new(false));
        let origin = Instant::now();
        let mut server = Server {
            link,
            model,
            node,
            mode,
            line,
            state: state.clone(),
            origin,
        };
        let stop2 = stop.clone();
        let thread = std::thread::spawn(move || server.run(&stop2));
        Ok(DriveSide {
            state,
            stop,
            thread: Some(thread),
            endpoint,
            origin,
            mode,
            line,
        })
    }

    /// Where the master reaches the drive.
    pub fn endpoint(&self) -> &Endpoint {
        &self.endpoint
    }

    /// Time since the run's origin.
    pub fn now(&self) -> Duration {
        self.origin.elapsed()
    }

    /// What the drive does with the requests from now on.
    pub fn arm(&self, b: Behaviour) {
        lock(&self.state).behaviour = Some(b);
    }

    /// Forgets replies still held back (a case that ended before they went out).
    pub fn drop_held(&self) {
        let mut s = lock(&self.state);
        s.held.clear();
        s.in_flight.clear();
    }

    /// Sends the replies held back (the stale replies) now.
    pub fn release_held(&self) {
        let mut s = lock(&self.state);
        let held = std::mem::take(&mut s.held);
        let now = Instant::now();
        for i in held {
            s.sent[i].class = SentClass::Stale;
            s.queue.push((now, i));
        }
    }

    /// Queues bytes that are no reply (a busy line) every `pace`, from now.
    pub fn busy(&self, bytes: &[u8], pace: Duration) {
        let mut s = lock(&self.state);
        let now = Instant::now();
        for (k, b) in bytes.iter().enumerate() {
            let i = s.sent.len();
            s.sent.push(Sent {
                for_seq: 0,
                bytes: vec![*b],
                class: SentClass::Garbage,
                values: None,
                exception: None,
                at: None,
            });
            s.queue.push((
                later(
                    now,
                    pace.saturating_mul(u32::try_from(k).unwrap_or(u32::MAX)),
                ),
                i,
            ));
        }
    }

    /// Waits until everything queued was sent and then `quiet` more.
    pub fn settle(&self, quiet: Duration) {
        let deadline = Instant::now() + Duration::from_secs(10);
        while !lock(&self.state).queue.is_empty() && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(1));
        }
        std::thread::sleep(quiet);
    }

    /// The log, requests and frames sent, from `since` on (requests that began then or
    /// later; frames sent for them, or sent then or later).
    pub fn since(&self, since: Duration) -> (Vec<Chunk>, Vec<Request>, Vec<Sent>) {
        let s = lock(&self.state);
        let log = s.log.iter().filter(|c| c.at >= since).cloned().collect();
        let requests: Vec<Request> = s
            .requests
            .iter()
            .filter(|r| r.start >= since)
            .cloned()
            .collect();
        let first = requests.first().map_or(u32::MAX, |r| r.seq);
        let sent = s
            .sent
            .iter()
            .filter(|x| x.for_seq >= first || x.at.is_some_and(|a| a >= since))
            .cloned()
            .collect();
        (log, requests, sent)
    }

    /// Every frame sent so far (to look up values a master reports).
    pub fn all_sent(&self) -> Vec<Sent> {
        lock(&self.state).sent.clone()
    }

    /// The longest time from `from` on that the drive's thread was not scheduled (over
    /// [`STALL`]; zero if none).
    pub fn stalled_since(&self, from: Duration) -> Duration {
        lock(&self.state)
            .stalls
            .iter()
            .filter(|(_, to)| *to >= from)
            .map(|(a, b)| b.saturating_sub(*a))
            .max()
            .unwrap_or_default()
    }

    /// An error of the line, if the drive's thread met one.
    pub fn error(&self) -> Option<String> {
        lock(&self.state).error.clone()
    }
}

impl Drop for DriveSide {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
    }
}

struct Server {
    link: Link,
    model: Arc<DriveModel>,
    node: u8,
    mode: Mode,
    line: LineSettings,
    state: Arc<Mutex<State>>,
    origin: Instant,
}

enum Framer {
    // Boxed: the RTU deframer holds a frame's buffer, the ASCII one far more.
    Rtu(Box<RtuDeframer>),
    Ascii(Box<AsciiDeframer>),
}

impl Server {
    fn run(&mut self, stop: &AtomicBool) {
        let mut framer = match self.mode {
            Mode::Rtu => Framer::Rtu(Box::new(RtuDeframer::new(
                Direction::Request,
                RtuFraming::ByLength,
            ))),
            Mode::Ascii => Framer::Ascii(Box::default()),
        };
        let mut buf = [0u8; 1024];
        // Bytes of a request under way: when its first byte came.
        let mut started: Option<Duration> = None;
        let mut last_rx: Option<Instant> = None;
        let mut turn = self.origin.elapsed();
        while !stop.load(Ordering::Relaxed) {
            let now = self.origin.elapsed();
            if now.saturating_sub(turn) > STALL {
                lock(&self.state).stalls.push((turn, now));
            }
            turn = now;
            self.send_due();
            let wait = {
                let s = lock(&self.state);
                let next = s.queue.iter().map(|(t, _)| *t).min();
                next.map_or(Duration::from_millis(5), |t| {
                    t.saturating_duration_since(Instant::now())
                        .min(Duration::from_millis(5))
                })
            };
            let n = match self.link.recv(&mut buf, wait) {
                Ok(n) => n,
                Err(e) => {
                    lock(&self.state).error = Some(e.to_string());
                    std::thread::sleep(Duration::from_millis(5));
                    0
                }
            };
            if n == 0 {
                // A partial request abandoned for long: what it held is no frame.
                if last_rx.is_some_and(|t| t.elapsed() > Duration::from_millis(100)) {
                    let mut events = Vec::new();
                    match &mut framer {
                        Framer::Rtu(d) => d.flush(|e| events.push(owned(e))),
                        Framer::Ascii(d) => d.flush(|e| events.push(owned(e))),
                    }
                    let at = self.origin.elapsed();
                    for (bytes, valid) in events {
                        self.on_frame(started.unwrap_or(at), at, bytes, valid);
                    }
                    started = None;
                    last_rx = None;
                }
                continue;
            }
            let at = self.origin.elapsed();
            last_rx = Some(Instant::now());
            started.get_or_insert(at);
            lock(&self.state).log.push(Chunk {
                at,
                done: at,
                dir: Dir::FromMaster,
                bytes: buf[..n].to_vec(),
            });
            let mut events = Vec::new();
            match &mut framer {
                Framer::Rtu(d) => d.push(&buf[..n], |e| events.push(owned(e))),
                Framer::Ascii(d) => d.push(&buf[..n], |e| events.push(owned(e))),
            }
            let pending = match &framer {
                Framer::Rtu(d) => d.pending(),
                Framer::Ascii(d) => d.pending(),
            };
            for (bytes, valid) in events {
                self.on_frame(started.unwrap_or(at), at, bytes, valid);
            }
            started = (pending > 0).then_some(at);
            if pending == 0 {
                last_rx = None;
            }
        }
    }

    fn send_due(&mut self) {
        loop {
            let (k, next) = {
                let mut s = lock(&self.state);
                let now = Instant::now();
                let Some(k) = (0..s.queue.len())
                    .filter(|k| s.queue[*k].0 <= now)
                    .min_by_key(|k| s.queue[*k].0)
                else {
                    return;
                };
                let (_, i) = s.queue.remove(k);
                let at = self.origin.elapsed();
                s.sent[i].at = Some(at);
                let bytes = s.sent[i].bytes.clone();
                let for_seq = s.sent[i].for_seq;
                s.log.push(Chunk {
                    at,
                    done: at,
                    dir: Dir::ToMaster,
                    bytes: bytes.clone(),
                });
                (s.log.len() - 1, (bytes, for_seq))
            };
            let sent = self.link.send(&next.0, next.1);
            let done = self.origin.elapsed();
            let mut s = lock(&self.state);
            if let Some(c) = s.log.get_mut(k) {
                c.done = done;
            }
            if let Err(e) = sent {
                s.error = Some(e.to_string());
            }
        }
    }

    fn on_frame(&mut self, start: Duration, end: Duration, bytes: Vec<u8>, valid: bool) {
        let address = crate::judge::body_of(self.mode, &bytes).map_or(0, |b| b[0]);
        let mut s = lock(&self.state);
        s.seq += 1;
        let seq = s.seq;
        s.requests.push(Request {
            seq,
            start,
            end,
            bytes: bytes.clone(),
            valid,
            address,
        });
        if !valid {
            return;
        }
        let behaviour = s.behaviour.clone().unwrap_or(Behaviour::Normal);
        let broadcast = address == self.model.broadcast;
        if address != self.node && !broadcast {
            return;
        }
        // A reply held for the next request goes out now, and this request's own reply
        // a silence after it.
        let flight = std::mem::take(&mut s.in_flight);
        let base = if flight.is_empty() {
            Duration::ZERO
        } else {
            apart(&self.line)
        };
        // A drive still sending (the busy line) finishes that first, then answers.
        let busy_for = s
            .queue
            .iter()
            .map(|(t, _)| t.saturating_duration_since(Instant::now()))
            .max()
            .map_or(Duration::ZERO, |d| {
                d.saturating_add(Duration::from_millis(1))
            });
        let base = base.max(busy_for);
        {
            let now = Instant::now();
            for i in flight {
                s.sent[i].class = SentClass::Stale;
                s.queue.push((now, i));
            }
        }
        let as_addressed = if broadcast {
            if behaviour != Behaviour::ReplyToBroadcast {
                // The drive acts on a broadcast write and says nothing.
                return;
            }
            match codec::readdressed(self.mode, &bytes, self.node) {
                Ok(f) => f,
                Err(_) => return,
            }
        } else {
            bytes.clone()
        };
        let judgement = self.model.judge(self.node, self.mode, &as_addressed);
        let mut scratch: Scratch = [0; codec::MAX_RTU_FRAME];
        let Ok(request) = codec::decode(self.mode, &as_addressed, Direction::Request, &mut scratch)
        else {
            return;
        };
        let function = request.pdu.function_code();
        s.frames += 1;
        let frame_no = s.frames;
        let mut values = None;
        let mut exception = None;
        let mut value_bytes = Vec::new();
        let reply: Option<Message<'_>> = match (&judgement.expect, &behaviour) {
            (Expectation::Silence(_), _) => None,
            (_, Behaviour::Exception(code) | Behaviour::ExceptionNoChecksum(code)) => {
                exception = Some(*code);
                Some(Message {
                    address: self.node,
                    pdu: Pdu::Exception {
                        function,
                        code: *code,
                    },
                })
            }
            (Expectation::Exception { code, .. }, _) => {
                exception = Some(*code);
                Some(Message {
                    address: self.node,
                    pdu: Pdu::Exception {
                        function,
                        code: *code,
                    },
                })
            }
            (Expectation::Read(plan), _) => {
                let v = tags(frame_no, plan.registers.len());
                for x in &v {
                    value_bytes.extend_from_slice(&x.to_be_bytes());
                }
                values = Some(v);
                Registers::new(&value_bytes).ok().map(|r| Message {
                    address: self.node,
                    pdu: Pdu::ReadResponse { values: r },
                })
            }
            (Expectation::WriteMultiple, _) => match request.pdu {
                Pdu::WriteMultipleRequest { start, values } => Some(Message {
                    address: self.node,
                    pdu: Pdu::WriteMultipleResponse {
                        start,
                        count: values.len() as u16,
                    },
                }),
                _ => None,
            },
            // 06H and 08H: the echo.
            (Expectation::WriteSingle | Expectation::LoopBack, _) => Some(Message {
                address: self.node,
                pdu: request.pdu,
            }),
        };
        let Some(reply) = reply else {
            return;
        };
        let Ok(frame) = reply.to_frame_vec(self.mode) else {
            return;
        };
        let now = Instant::now();
        let gap = apart(&self.line);
        let class = if broadcast {
            SentClass::BroadcastReply
        } else {
            SentClass::Reply
        };
        let push = |s: &mut State, after: Duration, bytes: Vec<u8>, class: SentClass| {
            let i = s.sent.len();
            let carries = matches!(
                class,
                SentClass::Reply
                    | SentClass::Stale
                    | SentClass::OtherNode
                    | SentClass::BadChecksum
                    | SentClass::Duplicate
                    | SentClass::BroadcastReply
            );
            s.sent.push(Sent {
                for_seq: seq,
                bytes,
                class,
                values: if carries { values.clone() } else { None },
                exception: if carries || class == SentClass::NoChecksum {
                    exception
                } else {
                    None
                },
                at: None,
            });
            s.queue.push((later(now, base.saturating_add(after)), i));
            i
        };
        match behaviour {
            Behaviour::Normal | Behaviour::Exception(_) | Behaviour::ReplyToBroadcast => {
                push(&mut s, Duration::ZERO, frame, class);
            }
            Behaviour::Late(d) => {
                push(&mut s, d, frame, class);
            }
            Behaviour::AfterTimeout => {
                let i = push(&mut s, Duration::ZERO, frame, class);
                s.queue.retain(|(_, k)| *k != i);
                s.held.push(i);
            }
            // An exception in flight is no test: it carries nothing that tells it from
            // the next request's (no count, no values); it goes out at once.
            Behaviour::InFlight if exception.is_some() => {
                push(&mut s, Duration::ZERO, frame, class);
            }
            Behaviour::InFlight => {
                let i = push(&mut s, Duration::ZERO, frame, class);
                s.queue.retain(|(_, k)| *k != i);
                s.in_flight.push(i);
            }
            Behaviour::WrongFunction => {
                // The echo of a write of the first tag to the first register read.
                let (register, value) = match request.pdu {
                    Pdu::ReadRequest { start, .. } => (start, tags(frame_no, 1)[0]),
                    _ => (0, 0),
                };
                let echo = Message {
                    address: self.node,
                    pdu: Pdu::WriteSingle { register, value },
                };
                if let Ok(f) = echo.to_frame_vec(self.mode) {
                    push(&mut s, Duration::ZERO, f, SentClass::WrongFunction);
                }
            }
            Behaviour::NoReply => {}
            Behaviour::Truncated => {
                let cut = match self.mode {
                    Mode::Rtu => frame.len().saturating_sub(3),
                    Mode::Ascii => frame.len().saturating_sub(4),
                };
                push(
                    &mut s,
                    Duration::ZERO,
                    frame[..cut].to_vec(),
                    SentClass::Truncated,
                );
            }
            Behaviour::BadChecksum => {
                push(
                    &mut s,
                    Duration::ZERO,
                    bad_checksum(self.mode, &frame),
                    SentClass::BadChecksum,
                );
            }
            Behaviour::GarbageBefore(g) => {
                push(&mut s, Duration::ZERO, g, SentClass::Garbage);
                push(&mut s, gap, frame, class);
            }
            Behaviour::GarbageAfter(g) => {
                push(&mut s, Duration::ZERO, frame, class);
                push(&mut s, gap, g, SentClass::Garbage);
            }
            Behaviour::ExceptionNoChecksum(_) => {
                let body = [self.node, function | 0x80, exception.unwrap_or(0)];
                let bytes = match self.mode {
                    Mode::Rtu => body.to_vec(),
                    Mode::Ascii => {
                        let mut b = vec![b':'];
                        b.extend(format!("{}", HexUpper(&body)).bytes());
                        b.extend_from_slice(b"\r\n");
                        b
                    }
                };
                push(&mut s, Duration::ZERO, bytes, SentClass::NoChecksum);
            }
            Behaviour::OtherNode(n) => {
                if let Ok(f) = codec::readdressed(self.mode, &frame, n) {
                    push(&mut s, Duration::ZERO, f, SentClass::OtherNode);
                }
            }
            Behaviour::Split(d) => {
                let half = frame.len() / 2;
                // The first part carries the values (a master that takes them took the
                // whole frame); the second is the rest.
                push(&mut s, Duration::ZERO, frame[..half].to_vec(), class);
                push(&mut s, d, frame[half..].to_vec(), SentClass::Garbage);
            }
            Behaviour::Twice => {
                push(&mut s, Duration::ZERO, frame.clone(), class);
                push(&mut s, gap, frame, SentClass::Duplicate);
            }
        }
    }
}

/// The frame with its checksum made wrong (RTU: the last byte flipped; ASCII: the LRC's
/// characters of another value).
fn bad_checksum(mode: Mode, frame: &[u8]) -> Vec<u8> {
    let mut f = frame.to_vec();
    match mode {
        Mode::Rtu => {
            if let Some(b) = f.last_mut() {
                *b ^= 0xFF;
            }
        }
        Mode::Ascii => {
            // ':' body LRC CR LF: the LRC is the two characters before CR LF.
            let n = f.len();
            if n >= 5 {
                let hi = f[n - 4];
                f[n - 4] = if hi == b'0' { b'1' } else { b'0' };
            }
        }
    }
    f
}

/// Upper-case hex pairs without separators (an ASCII frame's characters).
struct HexUpper<'a>(&'a [u8]);

impl std::fmt::Display for HexUpper<'_> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        for b in self.0 {
            write!(f, "{b:02X}")?;
        }
        Ok(())
    }
}

/// An event's bytes, and whether they are a valid frame.
fn owned(e: Event<'_>) -> (Vec<u8>, bool) {
    (e.bytes().to_vec(), matches!(e, Event::Frame(_)))
}

/// One line of the log, for a report: "+12.3 ms master> 01 03 ...".
pub fn show_chunk(c: &Chunk) -> String {
    format!(
        "{:>9.1} ms {} {}",
        c.at.as_secs_f64() * 1000.0,
        match c.dir {
            Dir::FromMaster => "master>",
            Dir::ToMaster => "drive> ",
        },
        Hex(&c.bytes)
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn tags_differ_between_frames() {
        let a = tags(1, 3);
        let b = tags(2, 3);
        assert_eq!(a.len(), 3);
        assert!(a.iter().all(|x| !b.contains(x)));
    }

    #[test]
    fn a_bad_checksum_is_bad() {
        let f = [0x01, 0x03, 0x02, 0x00, 0x01, 0x79, 0x84];
        let mut scratch: Scratch = [0; codec::MAX_RTU_FRAME];
        assert!(codec::decode(Mode::Rtu, &f, Direction::Response, &mut scratch).is_ok());
        let b = bad_checksum(Mode::Rtu, &f);
        assert!(codec::decode(Mode::Rtu, &b, Direction::Response, &mut scratch).is_err());
    }
}
