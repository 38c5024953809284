//! The serial ports of this machine, for `conformance ports`: which adapter is which
//! device path, what its USB latency timer does to RTU framing, and whether this user may
//! open it.
//!
//! On Linux the listing reads sysfs (`/sys/class/tty`, the USB device above each tty,
//! `/dev/serial/by-id`); elsewhere it asks `serialport`. Every root it reads (sysfs,
//! `/dev`, the lock folders) comes from [`Roots`], so a test can point it at a fake tree.
//! Nothing here opens a port: a listing never disturbs a line another program is using.

mod access;
pub mod latency;
mod render;
#[cfg(target_os = "linux")]
mod sysfs;

use std::path::{Path, PathBuf};

use serde::Serialize;

pub use access::{Access, Lock};
pub use render::{json, text};

/// Where the listing reads: sysfs, the device folder and the folders of UUCP lock files.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Roots {
    /// sysfs (`/sys`).
    pub sys: PathBuf,
    /// The device folder (`/dev`).
    pub dev: PathBuf,
    /// Where programs leave `LCK..<tty>` files (`/var/lock`, `/run/lock`).
    pub locks: Vec<PathBuf>,
}

impl Roots {
    /// This machine's own folders.
    pub fn system() -> Roots {
        Roots::under(Path::new("/"))
    }

    /// The same folders under another root (a fake tree for tests).
    pub fn under(root: &Path) -> Roots {
        Roots {
            sys: root.join("sys"),
            dev: root.join("dev"),
            locks: vec![root.join("var/lock"), root.join("run/lock")],
        }
    }
}

/// What kind of device a port is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Kind {
    /// A USB adapter (ttyUSB, ttyACM).
    Usb,
    /// A UART on a PCI card.
    Pci,
    /// A UART on the board or one the firmware announces (ttyS, ttyAMA).
    Platform,
    /// Anything else.
    Other,
}

/// The identity of a USB adapter, as its USB descriptors give it.
#[derive(Debug, Clone, Default, PartialEq, Eq, Serialize)]
pub struct Usb {
    /// Vendor id, four hex digits (`0403` is FTDI).
    pub vid: String,
    /// Product id, four hex digits.
    pub pid: String,
    /// The manufacturer string, where the adapter has one.
    pub manufacturer: Option<String>,
    /// The product string.
    pub product: Option<String>,
    /// The serial number, which tells two adapters of one kind apart.
    pub serial: Option<String>,
}

/// A USB adapter's latency timer: how long it holds received bytes before it sends them
/// to the computer.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct LatencyTimer {
    /// The timer, in milliseconds.
    pub ms: u32,
    /// The sysfs file that holds it (writing a number to it sets it).
    pub file: PathBuf,
}

/// One serial port.
#[derive(Debug, Clone, PartialEq, Eq, Serialize)]
pub struct Port {
    /// The device path (`/dev/ttyUSB0`).
    pub path: PathBuf,
    /// Its names under `/dev/serial/by-id`, which stay the same when adapters are plugged
    /// in another order.
    pub by_id: Vec<PathBuf>,
    /// What kind of device it is.
    pub kind: Kind,
    /// The kernel driver (`ftdi_sio`, `cp210x`, `ch341`, `cdc_acm`, `serial8250`).
    pub driver: Option<String>,
    /// The USB identity, for a USB adapter.
    pub usb: Option<Usb>,
    /// The latency timer, for an adapter whose driver has one (FTDI).
    pub latency_timer: Option<LatencyTimer>,
    /// Whether this user may open the port, and what to do if not.
    pub access: Access,
    /// A lock file another program left for the port, if any.
    pub lock: Option<Lock>,
}

impl Port {
    /// The file name of the device (`ttyUSB0`).
    pub fn name(&self) -> String {
        self.path
            .file_name()
            .map(|n| n.to_string_lossy().into_owned())
            .unwrap_or_default()
    }
}

/// Why the ports could not be listed.
#[derive(Debug, thiserror::Error)]
pub enum PortsError {
    /// A folder the listing needs could not be read.
    #[error("cannot read {path}: {source}")]
    Read {
        /// The folder.
        path: PathBuf,
        /// The cause.
        source: std::io::Error,
    },
    /// The operating system's own listing failed (outside Linux).
    #[error("the system's list of serial ports failed: {0}")]
    System(String),
}

/// The serial ports under `roots`, sorted by path; each with its access and lock found.
pub fn list(roots: &Roots) -> Result<Vec<Port>, PortsError> {
    #[cfg(target_os = "linux")]
    let mut ports = sysfs::list(roots)?;
    #[cfg(not(target_os = "linux"))]
    let mut ports = portable(roots)?;
    for p in &mut ports {
        p.access = access::access(&p.path);
        p.lock = access::lock(&roots.locks, &p.name());
    }
    ports.sort_by(|a, b| a.path.cmp(&b.path));
    Ok(ports)
}

/// Outside Linux: the ports `serialport` finds (it asks the system; no sysfs there).
#[cfg(not(target_os = "linux"))]
fn portable(_roots: &Roots) -> Result<Vec<Port>, PortsError> {
    use serialport::SerialPortType;
    let found = serialport::available_ports().map_err(|e| PortsError::System(e.to_string()))?;
    Ok(found
        .into_iter()
        .map(|info| {
            let (kind, usb) = match info.port_type {
                SerialPortType::UsbPort(u) => (
                    Kind::Usb,
                    Some(Usb {
                        vid: format!("{:04x}", u.vid),
                        pid: format!("{:04x}", u.pid),
                        manufacturer: u.manufacturer,
                        product: u.product,
                        serial: u.serial_number,
                    }),
                ),
                SerialPortType::PciPort => (Kind::Pci, None),
                _ => (Kind::Other, None),
            };
            Port {
                path: PathBuf::from(info.port_name),
                by_id: Vec::new(),
                kind,
                driver: None,
                usb,
                latency_timer: None,
                access: Access::unknown(),
                lock: None,
            }
        })
        .collect())
}

/// Why nothing was listed, for the hint after "no serial ports": a machine with
/// pseudo-terminals only (a container or a VM without USB passed through) is told so.
pub fn none_hint(roots: &Roots) -> String {
    let ptys = roots.dev.join("pts").is_dir() || roots.dev.join("ptmx").exists();
    let mut hint = String::new();
    if ptys {
        hint.push_str(
            "this machine has pseudo-terminals only (a container, or a virtual machine the USB adapter is not passed through to); ",
        );
    }
    hint.push_str(
        "plug the adapter in and look at `dmesg | tail` for the tty it got; without hardware, try the suite on the simulated drive: conformance check --sim f510",
    );
    hint
}
