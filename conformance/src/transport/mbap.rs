//! A Modbus TCP gateway to an RS-485 line, seen from the runner as if it were the line.
//!
//! A real gateway takes a Modbus TCP request (MBAP header and PDU), puts the unit id in
//! front of the PDU as the node address, adds a CRC and sends that on the serial line;
//! the drive's reply goes back the other way, its address and CRC stripped. This
//! transport does the same in reverse, so that the runner and the fuzzer keep speaking
//! RTU frames and keep every judgement they make on them:
//!
//! - **send**: the bytes must be one RTU frame with a valid CRC (anything else, garbage,
//!   a partial frame, a wrong CRC, frames back to back, cannot cross a gateway, and is a
//!   [`TransportError::NotCarried`], never sent); its address and CRC are stripped, its
//!   PDU goes out under a fresh transaction id and the unit id of its address (see
//!   [`UnitMap`]).
//! - **receive**: MBAP frames are read by their length field, which is judged from the
//!   header alone against the 254 bound (nothing is sized by it); a protocol id other
//!   than 0, a reply to a transaction no request had, or from another unit than the
//!   request's, is a [`TransportError::Mbap`] with the header in hex. The reply to the
//!   request in flight is handed up as the RTU frame the drive sent on its line: the
//!   node address the request had, the PDU, a computed CRC.
//! - **gateway exceptions**: 0AH (gateway path unavailable) and 0BH (gateway target device
//!   failed to respond) are the gateway's, not the drive's: both say that nothing came
//!   back on the serial line (0AH: the request did not even get there). They are handed
//!   up as silence, which is what the line carried, so the runner's silence and liveness
//!   logic applies unchanged (an other-address read is silence, as on the line; a
//!   liveness probe answered 0BH is a probe not answered), and each is kept as a note
//!   ([`Transport::take_notes`]) that the exchange and the report show.
//! - **late replies**: a reply to an earlier request that the master stopped waiting for
//!   (a gateway whose own timeout is longer than the master's) is dropped with a note, as
//!   a second reply to one request is.

use std::io::{ErrorKind, Read, Write};
use std::net::TcpStream;
use std::time::{Duration, Instant};

use super::{LinkKind, Transport, TransportError};
use crate::codec::crc::CrcBytes;
use crate::codec::hex::Hex;
use crate::codec::mbap::{
    frame_status, gateway_exception_name, MbapFrame, MbapRepr, Status, MAX_ADU,
};
use crate::codec::rtu::RtuFrame;
use crate::codec::timing::LineSettings;
use crate::codec::MAX_RTU_FRAME;

/// Why the line's own checks and the fuzz cases that need them cannot run through a
/// gateway: the reason they are skipped with.
pub const GATEWAY_HIDES: &str =
    "not visible through a Modbus TCP gateway (MBAP carries no CRC/LRC and no line timing)";

/// Earlier transactions remembered, to tell a late reply from a stray one.
const EARLIER: usize = 16;
/// Notes kept between two [`Transport::take_notes`] calls; more are counted.
const MAX_NOTES: usize = 8;

/// Which unit id a node address goes to. The device's node address (`-a`) goes to the
/// unit id given (`--unit`); where the two differ, the unit id's own number goes to the
/// device's address, so that every node address still names exactly one unit id (the
/// other-address checks need a unit that is not the device). The broadcast address 0
/// is unit 0, which a gateway broadcasts on its line.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct UnitMap {
    address: u8,
    unit: u8,
}

impl UnitMap {
    /// The device at node `address` is unit `unit` of the gateway.
    pub fn new(address: u8, unit: u8) -> Self {
        UnitMap { address, unit }
    }

    /// The unit id of node `node` (the map is its own inverse: also the node of a unit).
    pub fn unit_of(&self, node: u8) -> u8 {
        match node {
            0 => 0,
            n if n == self.address => self.unit,
            n if n == self.unit => self.address,
            n => n,
        }
    }

    /// The device's unit id.
    pub fn unit(&self) -> u8 {
        self.unit
    }
}

#[derive(Debug, Clone, Copy)]
struct Pending {
    transaction: u16,
    unit: u8,
    node: u8,
}

#[derive(Debug, Clone, Copy)]
struct Earlier {
    transaction: u16,
    answered: bool,
}

/// A Modbus TCP gateway: RTU frames in, RTU frames out, MBAP on the wire.
pub struct MbapGateway {
    stream: TcpStream,
    peer: String,
    units: UnitMap,
    next: u16,
    waiting: Option<Pending>,
    earlier: [Option<Earlier>; EARLIER],
    earlier_at: usize,
    rx: [u8; 2 * MAX_ADU],
    rx_len: usize,
    out: [u8; MAX_RTU_FRAME],
    out_len: usize,
    out_pos: usize,
    notes: Vec<String>,
    more_notes: usize,
    recording: Option<super::capture::TcpRecording>,
}

impl MbapGateway {
    /// Records the connection on `recorder` (`--capture`): every MBAP frame written and
    /// every piece read, as TCP segments under made-up headers, which Wireshark decodes
    /// as Modbus/TCP.
    pub fn with_capture(mut self, recorder: super::capture::SharedRecorder) -> Self {
        let addrs = self
            .stream
            .local_addr()
            .and_then(|l| Ok((l, self.stream.peer_addr()?)));
        if let Ok((local, peer)) = addrs {
            self.recording = Some(super::capture::TcpRecording::new(
                recorder,
                local,
                peer,
                "Modbus TCP gateway",
            ));
        }
        self
    }

    /// Connects to the gateway at `addr` (HOST:PORT), waiting at most `timeout`.
    pub fn connect(addr: &str, timeout: Duration, units: UnitMap) -> Result<Self, TransportError> {
        let stream = super::tcp::connect_stream(addr, timeout)?;
        Self::from_stream(stream, units).map_err(|source| TransportError::Open {
            what: format!("tcp {addr}"),
            source,
        })
    }

    /// The gateway's address (HOST:PORT as connected), or `?` where the socket did not
    /// say.
    pub fn peer(&self) -> &str {
        &self.peer
    }

    /// Wraps a connected stream.
    pub fn from_stream(stream: TcpStream, units: UnitMap) -> std::io::Result<Self> {
        stream.set_nodelay(true)?;
        let peer = stream
            .peer_addr()
            .map(|a| a.to_string())
            .unwrap_or_else(|_| "?".into());
        Ok(MbapGateway {
            stream,
            peer,
            units,
            next: 1,
            waiting: None,
            earlier: [None; EARLIER],
            earlier_at: 0,
            rx: [0; 2 * MAX_ADU],
            rx_len: 0,
            out: [0; MAX_RTU_FRAME],
            out_len: 0,
            out_pos: 0,
            notes: Vec::new(),
            more_notes: 0,
            recording: None,
        })
    }

    fn io_err(&self, what: &'static str, source: std::io::Error) -> TransportError {
        super::tcp::stream_error(self.describe(), what, source)
    }

    fn note(&mut self, text: String) {
        if self.notes.len() < MAX_NOTES {
            self.notes.push(text);
        } else {
            self.more_notes += 1;
        }
    }

    /// The request in flight is given up on (the master sends the next one, or drops
    /// input): a reply to it from now on is late.
    fn give_up(&mut self) {
        if let Some(p) = self.waiting.take() {
            self.remember(p.transaction, false);
        }
    }

    fn remember(&mut self, transaction: u16, answered: bool) {
        self.earlier[self.earlier_at] = Some(Earlier {
            transaction,
            answered,
        });
        self.earlier_at = (self.earlier_at + 1) % EARLIER;
    }

    /// Reads what the connection has, waiting at most `timeout`; the bytes read.
    fn fill(&mut self, timeout: Duration) -> Result<usize, TransportError> {
        if self.rx_len == self.rx.len() {
            return Ok(0);
        }
        self.stream
            .set_read_timeout(Some(timeout.max(Duration::from_micros(1))))
            .map_err(|e| self.io_err("set timeout", e))?;
        match self.stream.read(&mut self.rx[self.rx_len..]) {
            Ok(0) => Err(TransportError::Closed {
                link: self.describe(),
            }),
            Ok(n) => {
                if let Some(r) = &mut self.recording {
                    r.received(Instant::now(), &self.rx[self.rx_len..self.rx_len + n]);
                }
                self.rx_len += n;
                Ok(n)
            }
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => Ok(0),
            Err(e) if e.kind() == ErrorKind::Interrupted => Ok(0),
            Err(e) => Err(self.io_err("read", e)),
        }
    }

    /// Takes every whole MBAP frame out of the input: the reply to the request in flight
    /// becomes the RTU frame to hand up; the rest become notes or errors.
    fn drain_frames(&mut self) -> Result<(), TransportError> {
        loop {
            let n = match frame_status(&self.rx[..self.rx_len]) {
                Ok(Status::Complete(n)) => n,
                Ok(Status::Partial(_)) => return Ok(()),
                Err(source) => {
                    // The stream cannot be followed past a bad header.
                    self.rx_len = 0;
                    return Err(TransportError::Mbap {
                        link: self.describe(),
                        source,
                    });
                }
            };
            let mut frame = [0u8; MAX_ADU];
            frame[..n].copy_from_slice(&self.rx[..n]);
            self.rx.copy_within(n..self.rx_len, 0);
            self.rx_len -= n;
            self.take_frame(&frame[..n])?;
        }
    }

    fn take_frame(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        let mbap_err = |this: &Self, source| TransportError::Mbap {
            link: this.describe(),
            source,
        };
        let view = MbapFrame::new_checked(bytes).map_err(|e| mbap_err(self, e))?;
        let reply = MbapRepr::parse(&view).map_err(|e| mbap_err(self, e))?;
        let header = view.header();
        match self.waiting {
            Some(p) if p.transaction == reply.transaction => {
                if reply.unit != p.unit {
                    return Err(mbap_err(
                        self,
                        crate::codec::mbap::MbapError::Unit {
                            expected: p.unit,
                            got: reply.unit,
                            header,
                        },
                    ));
                }
                self.waiting = None;
                self.remember(p.transaction, true);
                if let Some(code) = reply.gateway_exception() {
                    self.note(format!(
                        "the gateway answered exception {code:02X}H ({}) in place of node {:02X}'s reply ({}): nothing came back on its serial line",
                        gateway_exception_name(code),
                        p.node,
                        Hex(bytes)
                    ));
                    return Ok(());
                }
                // The RTU frame the drive put on its line: the request's node address,
                // the PDU, the CRC.
                let pdu = reply.pdu;
                self.out[0] = p.node;
                self.out[1..1 + pdu.len()].copy_from_slice(pdu);
                let body = 1 + pdu.len();
                let crc = CrcBytes::of(&self.out[..body]).wire();
                self.out[body..body + 2].copy_from_slice(&crc);
                self.out_len = body + 2;
                self.out_pos = 0;
                Ok(())
            }
            _ => {
                let found = self
                    .earlier
                    .iter_mut()
                    .flatten()
                    .find(|e| e.transaction == reply.transaction)
                    .map(|e| std::mem::replace(&mut e.answered, true));
                match found {
                    Some(answered) => {
                        self.note(format!(
                            "{} to transaction {:04X}H dropped ({})",
                            if answered {
                                "a second reply"
                            } else {
                                "a late reply (after the master had stopped waiting)"
                            },
                            reply.transaction,
                            Hex(bytes)
                        ));
                        Ok(())
                    }
                    None => Err(mbap_err(
                        self,
                        crate::codec::mbap::MbapError::Transaction {
                            expected: self.waiting.map(|p| p.transaction),
                            got: reply.transaction,
                            header,
                        },
                    )),
                }
            }
        }
    }
}

impl Transport for MbapGateway {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        let frame = RtuFrame::new_checked(bytes).and_then(|f| f.verify_crc().map(|()| f));
        let frame = frame.map_err(|e| TransportError::NotCarried {
            link: self.describe(),
            bytes: Hex(&bytes[..bytes.len().min(64)]).to_string(),
            why: format!("{e}; a Modbus TCP gateway carries one RTU frame with a valid CRC (its PDU), nothing else: {GATEWAY_HIDES}"),
        })?;
        self.give_up();
        let transaction = self.next;
        self.next = self.next.wrapping_add(1);
        let node = frame.address();
        let unit = self.units.unit_of(node);
        let pdu = &frame.body()[1..];
        let mut out = [0u8; MAX_ADU];
        let n = MbapRepr {
            transaction,
            unit,
            pdu,
        }
        .emit(&mut out)
        .map_err(|source| TransportError::Mbap {
            link: self.describe(),
            source,
        })?;
        let at = Instant::now();
        self.stream
            .write_all(&out[..n])
            .map_err(|e| self.io_err("write", e))?;
        if let Some(r) = &mut self.recording {
            r.sent(at, &out[..n]);
        }
        self.waiting = Some(Pending {
            transaction,
            unit,
            node,
        });
        Ok(())
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        let deadline = Instant::now() + timeout;
        loop {
            self.drain_frames()?;
            if self.out_pos < self.out_len {
                let n = buf.len().min(self.out_len - self.out_pos);
                buf[..n].copy_from_slice(&self.out[self.out_pos..self.out_pos + n]);
                self.out_pos += n;
                return Ok(n);
            }
            let left = deadline.saturating_duration_since(Instant::now());
            if left.is_zero() || self.fill(left)? == 0 {
                return Ok(0);
            }
        }
    }

    fn discard_input(&mut self) -> Result<(), TransportError> {
        self.give_up();
        self.out_len = 0;
        self.out_pos = 0;
        // Whole frames already here are late replies (or errors); a partial one stays,
        // as the start of the next frame on the stream.
        loop {
            self.drain_frames()?;
            if self.fill(Duration::from_micros(1))? == 0 {
                return self.drain_frames();
            }
        }
    }

    fn describe(&self) -> String {
        let unit = self.units.unit();
        if unit == self.units.address {
            format!("Modbus TCP gateway {} (MBAP, unit {unit})", self.peer)
        } else {
            format!(
                "Modbus TCP gateway {} (MBAP, unit {unit} for node {})",
                self.peer, self.units.address
            )
        }
    }

    fn kind(&self) -> LinkKind {
        LinkKind::Mbap
    }

    fn line_timing(&self) -> Option<LineSettings> {
        None
    }

    fn frames_only(&self) -> Option<&'static str> {
        Some(GATEWAY_HIDES)
    }

    fn take_notes(&mut self) -> Vec<String> {
        let mut notes = std::mem::take(&mut self.notes);
        if self.more_notes > 0 {
            notes.push(format!("and {} more such notes", self.more_notes));
            self.more_notes = 0;
        }
        notes
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::net::TcpListener;

    /// A gateway transport connected to a scripted server socket.
    fn pair(units: UnitMap) -> (MbapGateway, TcpStream) {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        let addr = l.local_addr().unwrap().to_string();
        let g = MbapGateway::connect(&addr, Duration::from_secs(2), units).unwrap();
        let (s, _) = l.accept().unwrap();
        s.set_read_timeout(Some(Duration::from_secs(2))).unwrap();
        (g, s)
    }

    fn read_request(s: &mut TcpStream) -> Vec<u8> {
        let mut head = [0u8; 6];
        s.read_exact(&mut head).unwrap();
        let len = usize::from(u16::from_be_bytes([head[4], head[5]]));
        let mut rest = vec![0u8; len];
        s.read_exact(&mut rest).unwrap();
        [head.to_vec(), rest].concat()
    }

    fn recv_all(g: &mut MbapGateway, ms: u64) -> Result<Vec<u8>, TransportError> {
        let mut out = Vec::new();
        let mut buf = [0u8; 64];
        let deadline = Instant::now() + Duration::from_millis(ms);
        while Instant::now() < deadline {
            let n = g.recv(&mut buf, Duration::from_millis(20))?;
            out.extend_from_slice(&buf[..n]);
        }
        Ok(out)
    }

    /// Sends READ through the gateway, answers it with `reply` (MBAP), and takes what
    /// the gateway hands up within 100 ms.
    fn answer_read(
        g: &mut MbapGateway,
        s: &mut TcpStream,
        reply: &[u8],
    ) -> Result<Vec<u8>, TransportError> {
        g.send(&READ).unwrap();
        read_request(s);
        s.write_all(reply).unwrap();
        recv_all(g, 100)
    }

    /// [`answer_read`] with a reply the gateway must refuse: its error, which says `says`.
    fn refused_read(
        g: &mut MbapGateway,
        s: &mut TcpStream,
        reply: &[u8],
        says: &str,
    ) -> TransportError {
        let e = answer_read(g, s, reply).unwrap_err();
        assert!(e.to_string().contains(says), "{e}");
        e
    }

    const READ: [u8; 8] = [0x01, 0x03, 0x25, 0x20, 0x00, 0x01, 0x8E, 0xCC];
    const REPLY: [u8; 7] = [0x01, 0x03, 0x02, 0x00, 0x04, 0xB9, 0x87];

    #[test]
    fn a_read_crosses_as_mbap_and_comes_back_as_rtu() {
        let (mut g, mut s) = pair(UnitMap::new(1, 1));
        g.send(&READ).unwrap();
        assert_eq!(
            read_request(&mut s),
            [0x00, 0x01, 0x00, 0x00, 0x00, 0x06, 0x01, 0x03, 0x25, 0x20, 0x00, 0x01]
        );
        s.write_all(&[
            0x00, 0x01, 0x00, 0x00, 0x00, 0x05, 0x01, 0x03, 0x02, 0x00, 0x04,
        ])
        .unwrap();
        assert_eq!(recv_all(&mut g, 100).unwrap(), REPLY);
        assert!(g.take_notes().is_empty());
        // The next request has the next transaction id.
        g.send(&READ).unwrap();
        assert_eq!(read_request(&mut s)[..2], [0x00, 0x02]);
        assert_eq!(g.frames_only(), Some(GATEWAY_HIDES));
        assert_eq!(g.kind(), LinkKind::Mbap);
    }

    #[test]
    fn the_unit_id_is_mapped_both_ways() {
        // Node 1 is unit 5; node 5 (another node) is then unit 1; broadcast stays 0.
        let m = UnitMap::new(1, 5);
        assert_eq!(
            (m.unit_of(1), m.unit_of(5), m.unit_of(0), m.unit_of(7)),
            (5, 1, 0, 7)
        );
        let (mut g, mut s) = pair(m);
        g.send(&READ).unwrap();
        let req = read_request(&mut s);
        assert_eq!(req[6], 5);
        s.write_all(&[
            0x00, 0x01, 0x00, 0x00, 0x00, 0x05, 0x05, 0x03, 0x02, 0x00, 0x04,
        ])
        .unwrap();
        // Handed up as node 1's reply, as the drive at node 1 sent it.
        assert_eq!(recv_all(&mut g, 100).unwrap(), REPLY);
        let described = g.describe();
        assert!(described.contains("unit 5 for node 1"), "{described}");
    }

    #[test]
    fn a_gateway_exception_is_silence_with_a_note() {
        let (mut g, mut s) = pair(UnitMap::new(1, 1));
        assert_eq!(
            answer_read(
                &mut g,
                &mut s,
                &[0x00, 0x01, 0x00, 0x00, 0x00, 0x03, 0x01, 0x83, 0x0B]
            )
            .unwrap(),
            b""
        );
        let notes = g.take_notes();
        assert_eq!(notes.len(), 1);
        assert!(
            notes[0].contains("exception 0BH (gateway target device failed to respond)"),
            "{notes:?}"
        );
        // An ordinary exception is the device's and crosses.
        let e = answer_read(
            &mut g,
            &mut s,
            &[0x00, 0x02, 0x00, 0x00, 0x00, 0x03, 0x01, 0x83, 0x02],
        )
        .unwrap();
        assert_eq!(e[..3], [0x01, 0x83, 0x02]);
        assert_eq!(crate::codec::crc16(&e), 0);
    }

    #[test]
    fn a_late_reply_is_dropped_with_a_note_and_a_stray_one_is_an_error() {
        let (mut g, mut s) = pair(UnitMap::new(1, 1));
        g.send(&READ).unwrap();
        read_request(&mut s);
        // The master gives up on transaction 1 and sends transaction 2.
        g.discard_input().unwrap();
        g.send(&READ).unwrap();
        read_request(&mut s);
        s.write_all(&[
            0x00, 0x01, 0x00, 0x00, 0x00, 0x05, 0x01, 0x03, 0x02, 0x00, 0x09,
        ])
        .unwrap();
        s.write_all(&[
            0x00, 0x02, 0x00, 0x00, 0x00, 0x05, 0x01, 0x03, 0x02, 0x00, 0x04,
        ])
        .unwrap();
        assert_eq!(recv_all(&mut g, 150).unwrap(), REPLY);
        let notes = g.take_notes();
        assert!(notes[0].starts_with("a late reply"), "{notes:?}");
        // A transaction id that no request had: an error with the header in hex.
        let stray = [
            0x77, 0x77, 0x00, 0x00, 0x00, 0x05, 0x01, 0x03, 0x02, 0x00, 0x04,
        ];
        let header = "MBAP reply header 77 77 00 00 00 05 01: transaction id 7777H";
        refused_read(&mut g, &mut s, &stray, header);
    }

    #[test]
    fn a_reply_from_another_unit_or_protocol_is_an_error() {
        let (mut g, mut s) = pair(UnitMap::new(1, 1));
        let other_unit = [
            0x00, 0x01, 0x00, 0x00, 0x00, 0x05, 0x02, 0x03, 0x02, 0x00, 0x04,
        ];
        let unit = "unit id 02H, the request went to unit 01H";
        refused_read(&mut g, &mut s, &other_unit, unit);
        let other_protocol = [0x00, 0x02, 0x00, 0x07, 0x00, 0x05];
        let e = refused_read(&mut g, &mut s, &other_protocol, "protocol id 0007H");
        assert!(matches!(e, TransportError::Mbap { .. }), "{e}");
    }

    #[test]
    fn what_a_gateway_cannot_carry_is_not_sent() {
        let (mut g, mut s) = pair(UnitMap::new(1, 1));
        let mut bad = READ;
        bad[7] ^= 0xFF;
        for bytes in [&bad[..], &READ[..4], &[0xFFu8, 0x00, 0xA5][..]] {
            let e = g.send(bytes).unwrap_err();
            assert!(matches!(e, TransportError::NotCarried { .. }), "{e}");
            assert!(e.to_string().contains(GATEWAY_HIDES), "{e}");
        }
        // Nothing reached the gateway.
        s.set_read_timeout(Some(Duration::from_millis(50))).unwrap();
        let mut b = [0u8; 8];
        assert!(s.read(&mut b).is_err());
    }

    #[test]
    fn a_reply_in_pieces_is_put_together() {
        let (mut g, mut s) = pair(UnitMap::new(1, 1));
        g.send(&READ).unwrap();
        read_request(&mut s);
        let reply = [
            0x00, 0x01, 0x00, 0x00, 0x00, 0x05, 0x01, 0x03, 0x02, 0x00, 0x04,
        ];
        let h = std::thread::spawn(move || {
            for b in reply {
                s.write_all(&[b]).unwrap();
                std::thread::sleep(Duration::from_millis(3));
            }
            s
        });
        assert_eq!(recv_all(&mut g, 200).unwrap(), REPLY);
        drop(h.join().unwrap());
        // The gateway closed the connection: said so, not an empty read.
        assert!(matches!(
            recv_all(&mut g, 100),
            Err(TransportError::Closed { .. })
        ));
    }
}
