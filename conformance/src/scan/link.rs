//! What a scan talks through: a serial port whose line settings it changes from try to
//! try, or a link whose line it cannot change (a gateway: a raw RTU/ASCII-over-TCP
//! server today; an MBAP gateway is one more [`ScanLink`] over its transport).

use std::time::Duration;

use crate::codec::timing::LineSettings;
use crate::codec::Mode;
use crate::transport::capture::{Captured, SharedRecorder};
use crate::transport::serial::SerialTransport;
use crate::transport::{LinkKind, Transport, TransportError};

/// A link a scan can set line settings on (or not).
pub trait ScanLink {
    /// Sets the line to `line`, where the link has a line this side controls; a gateway
    /// ignores it (its serial side is set in the gateway).
    fn set_line(&mut self, line: &LineSettings) -> Result<(), TransportError>;
    /// The setting tried from now on (its line was set by [`ScanLink::set_line`]): a link
    /// that records (`--capture`) starts a new interface for it.
    fn setting(&mut self, _mode: crate::codec::Mode, _line: &LineSettings) {}
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
    port: Port<SerialTransport>,
    path: String,
    kind: LinkKind,
}

/// A link's transport, recorded or not. Recording starts at the first setting, so that
/// each setting's frames go to an interface described by it.
enum Port<T: Transport> {
    Plain(T),
    ToRecord(T, SharedRecorder),
    Recorded(Box<Captured<T>>),
    /// Only while changing from one to the other, inside [`Port::setting`].
    Moving,
}

impl<T: Transport + 'static> Port<T> {
    fn recorded(self, recorder: SharedRecorder) -> Self {
        match self {
            Port::Plain(p) => Port::ToRecord(p, recorder),
            other => other,
        }
    }

    fn inner(&mut self) -> Option<&mut T> {
        match self {
            Port::Plain(p) | Port::ToRecord(p, _) => Some(p),
            Port::Recorded(c) => Some(c.inner_mut()),
            Port::Moving => None,
        }
    }

    fn transport(&mut self) -> Option<&mut dyn Transport> {
        match self {
            Port::Plain(p) | Port::ToRecord(p, _) => Some(p),
            Port::Recorded(c) => Some(c.as_mut()),
            Port::Moving => None,
        }
    }

    fn describe(&self) -> String {
        match self {
            Port::Plain(p) | Port::ToRecord(p, _) => p.describe(),
            Port::Recorded(c) => c.describe(),
            Port::Moving => "scan link".to_string(),
        }
    }

    fn setting(&mut self, mode: Mode, line: &LineSettings) {
        *self = match std::mem::replace(self, Port::Moving) {
            Port::ToRecord(p, rec) => Port::Recorded(Box::new(Captured::new(p, rec, mode, *line))),
            Port::Recorded(mut c) => {
                c.retarget(mode, *line);
                Port::Recorded(c)
            }
            other => other,
        };
    }
}

/// What a moved-out port answers (never seen: the port is moved back at once).
fn moved() -> TransportError {
    TransportError::Closed {
        link: "scan link (moved)".into(),
    }
}

impl SerialLink {
    /// Wraps an open port.
    pub fn new(port: SerialTransport, path: &str) -> Self {
        let kind = port.kind();
        SerialLink {
            port: Port::Plain(port),
            path: path.to_string(),
            kind,
        }
    }

    /// Records every try on `recorder` (`scan --capture`), one interface a setting.
    pub fn recorded(mut self, recorder: SharedRecorder) -> Self {
        self.port = std::mem::replace(&mut self.port, Port::Moving).recorded(recorder);
        self
    }
}

impl ScanLink for SerialLink {
    fn set_line(&mut self, line: &LineSettings) -> Result<(), TransportError> {
        let port = self.port.inner().ok_or_else(moved)?;
        if port.line() != *line {
            port.set_line(*line)?;
        }
        self.transport().discard_input()
    }

    fn setting(&mut self, mode: Mode, line: &LineSettings) {
        self.port.setting(mode, line);
    }

    fn transport(&mut self) -> &mut dyn Transport {
        // The port is moved out only inside `Port::setting`, and back before it returns.
        self.port
            .transport()
            .expect("the scan's port is in place between settings")
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
    transport: Port<Box<dyn Transport>>,
    slack: Duration,
    description: Option<String>,
}

impl FixedLink {
    /// Wraps a transport; `slack` is what the network and the gateway may add.
    pub fn new(transport: Box<dyn Transport>, slack: Duration) -> Self {
        FixedLink {
            transport: Port::Plain(transport),
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

    /// Records the frames of every try on `recorder` (`scan --capture`), one interface a
    /// setting (a Modbus TCP gateway records its TCP stream itself:
    /// [`crate::transport::mbap::MbapGateway::with_capture`]).
    pub fn recorded(mut self, recorder: SharedRecorder) -> Self {
        self.transport = std::mem::replace(&mut self.transport, Port::Moving).recorded(recorder);
        self
    }
}

impl ScanLink for FixedLink {
    fn set_line(&mut self, _line: &LineSettings) -> Result<(), TransportError> {
        self.transport().discard_input()
    }

    fn setting(&mut self, mode: Mode, line: &LineSettings) {
        self.transport.setting(mode, line);
    }

    fn transport(&mut self) -> &mut dyn Transport {
        // The transport is moved out only inside `Port::setting`, and back before it
        // returns.
        self.transport
            .transport()
            .expect("the scan's transport is in place between settings")
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
