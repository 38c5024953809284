//! The simulated drive behind a simulated Modbus TCP gateway: MBAP on TCP, the drive's
//! RTU rules behind it.
//!
//! What a gateway to one RS-485 line does, and so what this does:
//!
//! - **several connections at once** (up to [`GatewayConfig::max_connections`]; one more
//!   is accepted and closed at once, with a log line), all against **one drive**: one
//!   state, one line. Requests are served one at a time in the order they come in, as a
//!   gateway's serial side can carry only one at a time; a request waits while another
//!   connection's request is on the line.
//! - a request goes on the line as the RTU frame of its unit id (as the node address),
//!   its PDU and a CRC, and is handled by [`Drive::handle`] exactly as on a serial link:
//!   the unit id that is the drive's node address is answered; unit 0 is a broadcast
//!   (executed, never answered, as on the line); any other unit id is a node nobody has.
//! - the drive's reply, a frame with a valid CRC from the unit asked, goes back after the
//!   drive's response delay, its address and CRC stripped, under the request's
//!   transaction and unit id. What a gateway's serial receiver would drop (a reply with a
//!   wrong CRC, from another address, an echo) does not cross.
//! - where no reply crosses for a unicast request (a unit id with no drive, a request the
//!   drive does not answer), the gateway waits [`GatewayConfig::target_timeout`] and
//!   answers exception 0BH (gateway target device failed to respond), or with
//!   [`NoReply::Silence`] sends nothing, as some gateways are configured to.
//! - a header that is not Modbus TCP (protocol id other than 0, a length field outside
//!   2..=254) is logged and the connection closed: the stream cannot be followed past it.

use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};

use super::bus::{Bus, Responder};
use super::drive::SendKind;
use super::log::{Dir, TrafficLog};
use super::server::SimError;
use crate::codec::crc::{crc16, CrcBytes};
use crate::codec::mbap::{
    frame_status, MbapFrame, MbapRepr, Status, GATEWAY_TARGET_FAILED, MAX_ADU,
};
use crate::codec::{Mode, MAX_RTU_FRAME};
use crate::transport::capture::{SharedRecorder, TcpRecording};
use crate::transport::sleep_until;

/// What the gateway sends when no reply from the drive crosses its line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum NoReply {
    /// Exception 0BH (gateway target device failed to respond) after the target timeout.
    Exception,
    /// Nothing.
    Silence,
}

/// How the simulated gateway behaves.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct GatewayConfig {
    /// What to send when the drive does not answer a unicast request.
    pub no_reply: NoReply,
    /// How long the gateway waits for the drive before it gives up on a request.
    pub target_timeout: Duration,
    /// Connections served at once.
    pub max_connections: usize,
}

impl Default for GatewayConfig {
    fn default() -> Self {
        GatewayConfig {
            no_reply: NoReply::Exception,
            target_timeout: Duration::from_millis(100),
            max_connections: 8,
        }
    }
}

/// What the gateway saw and did.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct GatewayStats {
    /// Connections accepted.
    pub connections: u64,
    /// Connections refused (over the limit).
    pub refused: u64,
    /// Requests received.
    pub requests: u64,
    /// Replies of the drive sent back.
    pub replies: u64,
    /// 0BH exceptions the gateway sent.
    pub gateway_exceptions: u64,
}

/// The line and what is on it: the drive, the log, the counts.
struct Line {
    drive: Bus,
    log: TrafficLog,
    stats: GatewayStats,
}

/// How a connection ended badly.
enum End {
    /// The log could not be written: the simulator stops.
    Log(std::io::Error),
    /// The client went away or the socket failed: this connection ends.
    Gone(std::io::Error),
}

fn lock(line: &Mutex<Line>) -> std::sync::MutexGuard<'_, Line> {
    // A connection thread that panicked leaves the drive usable.
    line.lock().unwrap_or_else(|p| p.into_inner())
}

/// Serves `drive` (one [`super::Drive`], or a [`Bus`] of them: each node address is the unit
/// id of the same number) behind a gateway on `listener` until `stop` is set; the log
/// goes to `log`. Returns the counts, or why it stopped (the log could not be written).
pub fn serve_gateway(
    listener: &TcpListener,
    drive: impl Into<Bus>,
    log: TrafficLog,
    config: &GatewayConfig,
    stop: &AtomicBool,
) -> Result<GatewayStats, SimError> {
    serve_gateway_recorded(listener, drive, log, config, stop, None)
}

/// [`serve_gateway`], recording each connection's TCP stream on `capture` (`simulate
/// --tcp --framing mbap --capture`): one interface a connection, the MBAP frames under
/// made-up Ethernet/IPv4/TCP headers.
pub fn serve_gateway_recorded(
    listener: &TcpListener,
    drive: impl Into<Bus>,
    log: TrafficLog,
    config: &GatewayConfig,
    stop: &AtomicBool,
    capture: Option<SharedRecorder>,
) -> Result<GatewayStats, SimError> {
    listener.set_nonblocking(true)?;
    let line = Mutex::new(Line {
        drive: drive.into(),
        log,
        stats: GatewayStats::default(),
    });
    let active = AtomicUsize::new(0);
    let halt = AtomicBool::new(false);
    let failure: Mutex<Option<std::io::Error>> = Mutex::new(None);
    let result = std::thread::scope(|scope| -> Result<(), SimError> {
        let done = || stop.load(Ordering::Relaxed) || halt.load(Ordering::Relaxed);
        // Any error here stops the connections too: the scope waits for them.
        let fail = |e: std::io::Error| {
            halt.store(true, Ordering::Relaxed);
            SimError::Log(e)
        };
        while !done() {
            let (stream, peer) = match listener.accept() {
                Ok(s) => s,
                Err(e) if e.kind() == ErrorKind::WouldBlock => {
                    std::thread::sleep(Duration::from_millis(10));
                    continue;
                }
                Err(e) => return Err(fail(e)),
            };
            let n = active.load(Ordering::Relaxed);
            let mut l = lock(&line);
            if n >= config.max_connections {
                l.stats.refused += 1;
                l.log
                    .message(&format!(
                        "connection from {peer} refused: {n} connections already (--connections)"
                    ))
                    .map_err(fail)?;
                drop(stream);
                continue;
            }
            l.stats.connections += 1;
            l.log
                .message(&format!(
                    "client connected: {peer} ({} of at most {})",
                    n + 1,
                    config.max_connections
                ))
                .map_err(fail)?;
            drop(l);
            active.fetch_add(1, Ordering::Relaxed);
            let (line, active, halt, failure) = (&line, &active, &halt, &failure);
            let recording = capture.as_ref().and_then(|rec| {
                let local = stream.local_addr().ok()?;
                Some(TcpRecording::serving(
                    rec.clone(),
                    local,
                    peer,
                    "simulated Modbus TCP gateway",
                ))
            });
            scope.spawn(move || {
                let end = connection(stream, recording, line, config, &|| {
                    stop.load(Ordering::Relaxed) || halt.load(Ordering::Relaxed)
                });
                let mut l = lock(line);
                let said = match end {
                    Ok(()) => l.log.message(&format!("client went away: {peer}")),
                    Err(End::Gone(e)) => l.log.message(&format!("connection {peer} ended: {e}")),
                    Err(End::Log(e)) => Err(e),
                };
                drop(l);
                if let Err(e) = said {
                    halt.store(true, Ordering::Relaxed);
                    *failure.lock().unwrap_or_else(|p| p.into_inner()) = Some(e);
                }
                active.fetch_sub(1, Ordering::Relaxed);
            });
        }
        Ok(())
    });
    result?;
    if let Some(e) = failure.into_inner().unwrap_or_else(|p| p.into_inner()) {
        return Err(SimError::Log(e));
    }
    Ok(line.into_inner().unwrap_or_else(|p| p.into_inner()).stats)
}

/// Serves one connection until it closes or `done` says to stop.
fn connection(
    mut stream: TcpStream,
    mut recording: Option<TcpRecording>,
    line: &Mutex<Line>,
    config: &GatewayConfig,
    done: &dyn Fn() -> bool,
) -> Result<(), End> {
    stream.set_nonblocking(false).map_err(End::Gone)?;
    stream.set_nodelay(true).map_err(End::Gone)?;
    stream
        .set_read_timeout(Some(Duration::from_millis(50)))
        .map_err(End::Gone)?;
    let mut rx = [0u8; 2 * MAX_ADU];
    let mut len = 0;
    while !done() {
        match frame_status(&rx[..len]) {
            Ok(Status::Complete(n)) => {
                let mut frame = [0u8; MAX_ADU];
                frame[..n].copy_from_slice(&rx[..n]);
                rx.copy_within(n..len, 0);
                len -= n;
                request(&mut stream, &mut recording, &frame[..n], line, config)?;
                continue;
            }
            Ok(Status::Partial(_)) => {}
            Err(e) => {
                let mut l = lock(line);
                l.log
                    .record(Dir::In, "dropped", &rx[..len], &e.to_string())
                    .map_err(End::Log)?;
                return Err(End::Gone(std::io::Error::new(
                    ErrorKind::InvalidData,
                    format!("{e}; closed, as the stream cannot be followed past it"),
                )));
            }
        }
        match stream.read(&mut rx[len..]) {
            Ok(0) => return Ok(()),
            Ok(n) => {
                if let Some(r) = &mut recording {
                    r.received(Instant::now(), &rx[len..len + n]);
                }
                len += n;
            }
            Err(e)
                if matches!(
                    e.kind(),
                    ErrorKind::WouldBlock | ErrorKind::TimedOut | ErrorKind::Interrupted
                ) => {}
            Err(e) => return Err(End::Gone(e)),
        }
    }
    Ok(())
}

/// One request: on the line, the drive's answer, back to the client.
fn request(
    stream: &mut TcpStream,
    recording: &mut Option<TcpRecording>,
    frame: &[u8],
    line: &Mutex<Line>,
    config: &GatewayConfig,
) -> Result<(), End> {
    let Ok(req) = MbapFrame::new_checked(frame).and_then(|v| MbapRepr::parse(&v)) else {
        // frame_status said it is whole; nothing else can come here.
        return Ok(());
    };
    let mut l = lock(line);
    let now = Instant::now();
    l.stats.requests += 1;
    // The request on the serial line: the unit id as the node address, the PDU, a CRC.
    let mut rtu = [0u8; MAX_RTU_FRAME];
    rtu[0] = req.unit;
    rtu[1..1 + req.pdu.len()].copy_from_slice(req.pdu);
    let body = 1 + req.pdu.len();
    let crc = CrcBytes::of(&rtu[..body]).wire();
    rtu[body..body + 2].copy_from_slice(&crc);
    l.drive.tick(now);
    let outcome = l.drive.handle(Mode::Rtu, &rtu[..body + 2], now);
    let mut note = format!(
        "transaction {:04X}H unit {}: {}: {}",
        req.transaction,
        req.unit,
        outcome.judgement.expect.describe(),
        outcome.judgement.detail
    );
    for q in &outcome.notes {
        note.push_str("; ");
        note.push_str(q);
    }
    l.log
        .record(Dir::In, "mbap", frame, &note)
        .map_err(End::Log)?;
    // What crosses the gateway's serial receiver: a reply frame with a valid CRC from
    // the unit asked.
    let reply = outcome.sends.iter().find(|s| {
        s.kind == SendKind::Reply
            && s.bytes.len() >= 4
            && s.bytes[0] == req.unit
            && crc16(&s.bytes) == 0
    });
    let mut out = [0u8; MAX_ADU];
    let (pdu_out, event, after): (Vec<u8>, &str, Instant) = match reply {
        Some(s) => (
            s.bytes[1..s.bytes.len() - 2].to_vec(),
            "reply",
            now + s.after,
        ),
        // A broadcast is never answered, by the drive or the gateway.
        None if req.unit == 0 => return Ok(()),
        None => match config.no_reply {
            NoReply::Exception => (
                vec![req.pdu[0] | 0x80, GATEWAY_TARGET_FAILED],
                "gateway-0b",
                now + config.target_timeout,
            ),
            NoReply::Silence => return Ok(()),
        },
    };
    let Ok(n) = (MbapRepr {
        transaction: req.transaction,
        unit: req.unit,
        pdu: &pdu_out,
    })
    .emit(&mut out) else {
        return Ok(());
    };
    // The line is busy until the answer is in: other connections wait.
    sleep_until(after);
    let at = Instant::now();
    stream.write_all(&out[..n]).map_err(End::Gone)?;
    if let Some(r) = recording {
        r.sent(at, &out[..n]);
    }
    if event == "reply" {
        l.stats.replies += 1;
    } else {
        l.stats.gateway_exceptions += 1;
    }
    let note = if event == "reply" {
        String::new()
    } else {
        format!(
            "no reply from unit {} within {} ms: the gateway answers 0BH (gateway target device failed to respond)",
            req.unit,
            config.target_timeout.as_millis()
        )
    };
    l.log
        .record(Dir::Out, event, &out[..n], &note)
        .map_err(End::Log)?;
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::DriveModel;
    use crate::sim::Drive;
    use crate::transport::mbap::{MbapGateway, UnitMap};
    use crate::transport::Transport;
    use std::sync::Arc;

    /// A gateway with an F510 at node 1 on a free port, stopped when the guard goes.
    fn start(config: GatewayConfig) -> (String, impl Drop) {
        struct Guard(Arc<AtomicBool>, Option<std::thread::JoinHandle<()>>);
        impl Drop for Guard {
            fn drop(&mut self) {
                self.0.store(true, Ordering::Relaxed);
                if let Some(h) = self.1.take() {
                    let _ = h.join();
                }
            }
        }
        let model = Arc::new(DriveModel::builtin("f510").unwrap());
        let drive = Drive::new(model, 1, Duration::from_millis(2));
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap().to_string();
        let stop = Arc::new(AtomicBool::new(false));
        let s = stop.clone();
        let h = std::thread::spawn(move || {
            serve_gateway(&l, drive, TrafficLog::new(), &config, &s).unwrap();
        });
        (addr, Guard(stop, Some(h)))
    }

    fn exchange(g: &mut MbapGateway, frame: &[u8], ms: u64) -> (Vec<u8>, Vec<String>) {
        g.discard_input().unwrap();
        g.send(frame).unwrap();
        let mut out = Vec::new();
        let mut buf = [0u8; 300];
        let deadline = Instant::now() + Duration::from_millis(ms);
        while Instant::now() < deadline {
            let n = g.recv(&mut buf, Duration::from_millis(10)).unwrap();
            out.extend_from_slice(&buf[..n]);
        }
        (out, g.take_notes())
    }

    fn rtu(body: &[u8]) -> Vec<u8> {
        let mut f = body.to_vec();
        f.extend_from_slice(&CrcBytes::of(body).wire());
        f
    }

    #[test]
    fn its_own_unit_is_answered_and_another_gets_0bh_after_the_timeout() {
        let (addr, _g) = start(GatewayConfig {
            target_timeout: Duration::from_millis(30),
            ..GatewayConfig::default()
        });
        let mut g =
            MbapGateway::connect(&addr, Duration::from_secs(2), UnitMap::new(1, 1)).unwrap();
        // The identification register of the F510: 0510H... read through the gateway.
        let (reply, notes) = exchange(&mut g, &rtu(&[0x01, 0x03, 0x25, 0x2F, 0x00, 0x01]), 150);
        assert_eq!(reply, rtu(&[0x01, 0x03, 0x02, 0x05, 0x10]));
        assert!(notes.is_empty(), "{notes:?}");
        // Node 7: nobody. Silence on the line; the gateway's 0BH is a note.
        let (reply, notes) = exchange(&mut g, &rtu(&[0x07, 0x03, 0x25, 0x2F, 0x00, 0x01]), 150);
        assert!(reply.is_empty(), "{reply:02X?}");
        assert!(notes[0].contains("exception 0BH"), "{notes:?}");
        // A broadcast write: no answer at all, and the value is taken.
        let (reply, notes) = exchange(&mut g, &rtu(&[0x00, 0x06, 0x25, 0x02, 0x0A, 0x0A]), 150);
        assert!(
            reply.is_empty() && notes.is_empty(),
            "{reply:02X?} {notes:?}"
        );
        let (reply, _) = exchange(&mut g, &rtu(&[0x01, 0x03, 0x25, 0x02, 0x00, 0x01]), 150);
        assert_eq!(reply, rtu(&[0x01, 0x03, 0x02, 0x0A, 0x0A]));
    }

    #[test]
    fn two_connections_share_one_drive() {
        let (addr, _g) = start(GatewayConfig::default());
        let mut a =
            MbapGateway::connect(&addr, Duration::from_secs(2), UnitMap::new(1, 1)).unwrap();
        let mut b =
            MbapGateway::connect(&addr, Duration::from_secs(2), UnitMap::new(1, 1)).unwrap();
        let write = rtu(&[0x01, 0x06, 0x25, 0x02, 0x04, 0xD2]);
        let (reply, _) = exchange(&mut a, &write, 150);
        assert_eq!(reply, write);
        let (reply, _) = exchange(&mut b, &rtu(&[0x01, 0x03, 0x25, 0x02, 0x00, 0x01]), 150);
        assert_eq!(reply, rtu(&[0x01, 0x03, 0x02, 0x04, 0xD2]));
    }

    #[test]
    fn with_silence_configured_an_absent_unit_gets_nothing() {
        let (addr, _g) = start(GatewayConfig {
            no_reply: NoReply::Silence,
            target_timeout: Duration::from_millis(10),
            ..GatewayConfig::default()
        });
        let mut g =
            MbapGateway::connect(&addr, Duration::from_secs(2), UnitMap::new(1, 1)).unwrap();
        let (reply, notes) = exchange(&mut g, &rtu(&[0x07, 0x03, 0x25, 0x2F, 0x00, 0x01]), 100);
        assert!(
            reply.is_empty() && notes.is_empty(),
            "{reply:02X?} {notes:?}"
        );
    }

    #[test]
    fn a_bad_header_closes_the_connection() {
        let (addr, _g) = start(GatewayConfig::default());
        let mut s = TcpStream::connect(&addr).unwrap();
        s.write_all(&[0, 1, 0, 9, 0, 6, 1, 3, 0x25, 0x20, 0, 1])
            .unwrap();
        s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        let mut b = [0u8; 16];
        // Closed without a reply: EOF (or a reset).
        assert!(matches!(s.read(&mut b), Ok(0) | Err(_)));
    }
}
