//! A Modbus TCP connection recorded as Ethernet frames.

//! ([`Recorder::error`]): the run itself goes on.

use std::time::Instant;

use super::SharedRecorder;
use crate::capture::{self, Interface};

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
