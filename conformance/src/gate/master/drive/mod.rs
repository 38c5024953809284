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
//!
//! The line itself (a pty, or MBAP on TCP) is `link.rs`; the loop that frames requests
//! and answers them is `server.rs`.

use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex, MutexGuard};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use crate::codec::hex::Hex;
use crate::codec::timing::later;
use crate::codec::timing::LineSettings;
use crate::codec::Mode;
use crate::model::DriveModel;
use crate::transport::pty::PtyMaster;
use crate::transport::TransportError;

mod link;
mod server;

use link::{Link, MbapLink};
use server::Server;

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
                let (listener, addr) =
                    listen_locally("a TCP listener on 127.0.0.1 for the master")?;
                (
                    Link::Tcp {
                        listener,
                        conn: None,
                    },
                    Endpoint::TcpRtu(addr),
                )
            }
            LineKind::Mbap => {
                let (listener, addr) =
                    listen_locally("a Modbus TCP listener on 127.0.0.1 for the master")?;
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

/// A non-blocking listener on a free port of 127.0.0.1, for the master to connect to;
/// `what` names it in the error.
fn listen_locally(
    what: &str,
) -> Result<(std::net::TcpListener, std::net::SocketAddr), TransportError> {
    let open_err = |source| TransportError::Open {
        what: what.into(),
        source,
    };
    let listener = std::net::TcpListener::bind("127.0.0.1:0").map_err(open_err)?;
    listener.set_nonblocking(true).map_err(open_err)?;
    let addr = listener.local_addr().map_err(open_err)?;
    Ok((listener, addr))
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
}
