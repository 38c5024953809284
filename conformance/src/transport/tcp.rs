//! RTU or ASCII frames over TCP, as serial-to-Ethernet gateways carry them (no MBAP
//! header: the bytes are the serial line's).

use std::io::{ErrorKind, Read, Write};
use std::net::{TcpListener, TcpStream, ToSocketAddrs};
use std::time::Duration;

use super::{LinkKind, Transport, TransportError};
use crate::codec::timing::LineSettings;

/// Connects to `addr` (HOST:PORT), trying each address it resolves to, waiting at most
/// `timeout` for each.
pub(crate) fn connect_stream(addr: &str, timeout: Duration) -> Result<TcpStream, TransportError> {
    let open_err = |source: std::io::Error| TransportError::Open {
        what: format!("tcp {addr}"),
        source,
    };
    let mut last = None;
    for a in addr.to_socket_addrs().map_err(open_err)? {
        match TcpStream::connect_timeout(&a, timeout) {
            Ok(stream) => return Ok(stream),
            Err(e) => last = Some(e),
        }
    }
    Err(open_err(last.unwrap_or_else(|| {
        std::io::Error::new(ErrorKind::NotFound, "the address resolves to nothing")
    })))
}

/// A TCP connection carrying serial frames.
pub struct TcpTransport {
    stream: TcpStream,
    peer: String,
}

impl TcpTransport {
    /// Connects to `addr` (HOST:PORT), waiting at most `timeout`.
    pub fn connect(addr: &str, timeout: Duration) -> Result<Self, TransportError> {
        let stream = connect_stream(addr, timeout)?;
        Self::from_stream(stream).map_err(|source| TransportError::Open {
            what: format!("tcp {addr}"),
            source,
        })
    }

    /// Wraps an accepted or connected stream.
    pub fn from_stream(stream: TcpStream) -> std::io::Result<Self> {
        stream.set_nodelay(true)?;
        let peer = stream
            .peer_addr()
            .map(|a| a.to_string())
            .unwrap_or_else(|_| "?".into());
        Ok(TcpTransport { stream, peer })
    }

    /// Waits for one client on `listener`.
    pub fn accept(listener: &TcpListener) -> Result<Self, TransportError> {
        let what = listener
            .local_addr()
            .map(|a| format!("tcp {a}"))
            .unwrap_or_else(|_| "tcp listener".into());
        listener
            .accept()
            .and_then(|(s, _)| Self::from_stream(s))
            .map_err(|source| TransportError::Open { what, source })
    }

    fn err(&self, what: &'static str, source: std::io::Error) -> TransportError {
        stream_error(self.describe(), what, source)
    }
}

impl Transport for TcpTransport {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.stream
            .write_all(bytes)
            .map_err(|e| self.err("write", e))
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        let t = timeout.max(Duration::from_micros(1));
        self.stream
            .set_read_timeout(Some(t))
            .map_err(|e| self.err("set timeout", e))?;
        match self.stream.read(buf) {
            Ok(0) if !buf.is_empty() => Err(TransportError::Closed {
                link: self.describe(),
            }),
            Ok(n) => Ok(n),
            Err(e) if matches!(e.kind(), ErrorKind::WouldBlock | ErrorKind::TimedOut) => Ok(0),
            Err(e) if e.kind() == ErrorKind::Interrupted => Ok(0),
            Err(e) => Err(self.err("read", e)),
        }
    }

    fn discard_input(&mut self) -> Result<(), TransportError> {
        let mut buf = [0u8; 256];
        while self.recv(&mut buf, Duration::from_micros(1))? > 0 {}
        Ok(())
    }

    fn describe(&self) -> String {
        format!("tcp {}", self.peer)
    }

    fn kind(&self) -> LinkKind {
        LinkKind::Tcp
    }

    fn line_timing(&self) -> Option<LineSettings> {
        None
    }
}

/// A TCP stream's error as a transport error: the peer going away is
/// [`TransportError::Closed`], anything else an I/O error on `link`.
pub(crate) fn stream_error(
    link: String,
    what: &'static str,
    source: std::io::Error,
) -> TransportError {
    match source.kind() {
        ErrorKind::BrokenPipe
        | ErrorKind::ConnectionReset
        | ErrorKind::ConnectionAborted
        | ErrorKind::UnexpectedEof => TransportError::Closed { link },
        _ => TransportError::Io { what, link, source },
    }
}
