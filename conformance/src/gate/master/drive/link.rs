//! The drive's end of the line: a pseudo-terminal, or a TCP listener and the MBAP
//! connection it accepted.

use std::time::Duration;

use crate::transport::pty::PtyMaster;
use crate::transport::tcp::TcpTransport;
use crate::transport::{Transport, TransportError};

/// The drive's end: a pty, or a TCP listener and the connection it accepted.
pub(super) enum Link {
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
pub(super) struct MbapLink {
    pub(super) listener: std::net::TcpListener,
    pub(super) conn: Option<std::net::TcpStream>,
    pub(super) rx: Vec<u8>,
    /// RTU frames made of MBAP requests, not read by the drive yet.
    pub(super) out: Vec<u8>,
    /// The transaction id of each request, by the drive's sequence number less one.
    pub(super) transactions: Vec<u16>,
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
    pub(super) fn recv(&mut self, buf: &mut [u8], wait: Duration) -> Result<usize, TransportError> {
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

    pub(super) fn send(&mut self, bytes: &[u8], for_seq: u32) -> Result<(), TransportError> {
        match self {
            Link::Mbap(m) => m.send(bytes, for_seq),
            Link::Pty(p) => p.send(bytes),
            Link::Tcp { conn: Some(c), .. } => c.send(bytes),
            // Nobody connected: the bytes go nowhere, as on a line nobody listens to.
            Link::Tcp { conn: None, .. } => Ok(()),
        }
    }
}
