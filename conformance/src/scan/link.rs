//! What a scan talks through: a serial port whose line settings it changes from try to
//! try, or a link whose line it cannot change (a gateway: a raw RTU/ASCII-over-TCP
//! server today; an MBAP gateway is one more [`ScanLink`] over its transport).

use std::time::Duration;

use crate::codec::timing::LineSettings;
use crate::transport::serial::SerialTransport;
use crate::transport::{LinkKind, Transport, TransportError};

/// A link a scan can set line settings on (or not).
pub trait ScanLink {
    /// Sets the line to `line`, where the link has a line this side controls; a gateway
    /// ignores it (its serial side is set in the gateway).
    fn set_line(&mut self, line: &LineSettings) -> Result<(), TransportError>;
    /// The transport to send and receive on.
    fn transport(&mut self) -> &mut dyn Transport;
    /// Whether the line settings can be searched from here (false for a gateway: only
    /// node addresses, and the modes where the gateway passes frames through, are
    /// searched).
    fn searchable(&self) -> bool;
    /// Time the link may add to a reply: a USB adapter's latency timer, a gateway's
    /// network, the host's scheduler.
    fn slack(&self) -> Duration;
    /// "serial /dev/ttyUSB0", "tcp 10.0.0.7:4001".
    fn describe(&self) -> String;
}

/// A serial port (or the slave side of a pseudo-terminal), reconfigured per setting.
pub struct SerialLink {
    port: SerialTransport,
    path: String,
    kind: LinkKind,
}

impl SerialLink {
    /// Wraps an open port.
    pub fn new(port: SerialTransport, path: &str) -> Self {
        let kind = port.kind();
        SerialLink {
            port,
            path: path.to_string(),
            kind,
        }
    }
}

impl ScanLink for SerialLink {
    fn set_line(&mut self, line: &LineSettings) -> Result<(), TransportError> {
        if self.port.line() != *line {
            self.port.set_line(*line)?;
        }
        self.port.discard_input()
    }

    fn transport(&mut self) -> &mut dyn Transport {
        &mut self.port
    }

    fn searchable(&self) -> bool {
        true
    }

    fn slack(&self) -> Duration {
        match self.kind {
            // USB serial adapters hand over received bytes when their latency timer
            // runs out (FTDI: 16 ms by default).
            LinkKind::Serial => Duration::from_millis(20),
            _ => Duration::from_millis(5),
        }
    }

    fn describe(&self) -> String {
        format!("{} {}", self.kind, self.path)
    }
}

/// A link whose line settings are set elsewhere (a TCP gateway).
pub struct FixedLink {
    transport: Box<dyn Transport>,
    slack: Duration,
    description: Option<String>,
}

impl FixedLink {
    /// Wraps a transport; `slack` is what the network and the gateway may add.
    pub fn new(transport: Box<dyn Transport>, slack: Duration) -> Self {
        FixedLink {
            transport,
            slack,
            description: None,
        }
    }

    /// Names the link `description` in the scan's result, in place of the transport's
    /// own description (which speaks of one request's target, where a sweep has many:
    /// the unit ids of a Modbus TCP gateway).
    pub fn described_as(mut self, description: String) -> Self {
        self.description = Some(description);
        self
    }
}

impl ScanLink for FixedLink {
    fn set_line(&mut self, _line: &LineSettings) -> Result<(), TransportError> {
        self.transport.discard_input()
    }

    fn transport(&mut self) -> &mut dyn Transport {
        self.transport.as_mut()
    }

    fn searchable(&self) -> bool {
        false
    }

    fn slack(&self) -> Duration {
        self.slack
    }

    fn describe(&self) -> String {
        match &self.description {
            Some(d) => d.clone(),
            None => self.transport.describe(),
        }
    }
}
