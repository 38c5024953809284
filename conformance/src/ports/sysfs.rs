//! The Linux listing: every tty in sysfs that has a device behind it, the USB device above
//! it, its driver, its latency timer and its `/dev/serial/by-id` names.

use std::path::{Path, PathBuf};

use super::{Access, Kind, LatencyTimer, Port, PortsError, Roots, Usb};

/// The ttys under `roots.sys/class/tty` that are serial ports.
pub fn list(roots: &Roots) -> Result<Vec<Port>, PortsError> {
    let class = roots.sys.join("class/tty");
    let entries = match std::fs::read_dir(&class) {
        Ok(e) => e,
        // No sysfs (a chroot, a container without /sys): no ports, which the caller's
        // hint explains, rather than an error.
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(Vec::new()),
        Err(source) => {
            return Err(PortsError::Read {
                path: class,
                source,
            })
        }
    };
    let by_id = by_id(&roots.dev);
    let mut ports = Vec::new();
    for entry in entries.flatten() {
        let name = entry.file_name().to_string_lossy().into_owned();
        let tty = class.join(&name);
        let Some(port) = port(roots, &tty, &name, &by_id) else {
            continue;
        };
        ports.push(port);
    }
    Ok(ports)
}

fn read_trimmed(p: &Path) -> Option<String> {
    let t = std::fs::read_to_string(p).ok()?;
    let t = t.trim();
    (!t.is_empty()).then(|| t.to_string())
}

/// The port of tty `name`, or `None` for a tty that is not one: a virtual terminal or a
/// pseudo-terminal (no device behind it), or a legacy 8250 slot with no UART in it
/// (`type` 0, which the kernel creates for ttyS0..ttyS31 whether a UART is there or not).
fn port(roots: &Roots, tty: &Path, name: &str, by_id: &[(String, PathBuf)]) -> Option<Port> {
    let device = std::fs::canonicalize(tty.join("device")).ok()?;
    if device.components().any(|c| c.as_os_str() == "virtual") {
        return None;
    }
    if read_trimmed(&tty.join("type")).as_deref() == Some("0") {
        return None;
    }
    let driver = std::fs::read_link(tty.join("device/driver"))
        .ok()
        .and_then(|d| d.file_name().map(|n| n.to_string_lossy().into_owned()));
    // The USB device is the first folder above the tty with a vendor id, and never
    // above sysfs itself.
    let sys = std::fs::canonicalize(&roots.sys).unwrap_or_else(|_| roots.sys.clone());
    let usb_dir = device
        .ancestors()
        .take_while(|a| a.starts_with(&sys))
        .find(|a| a.join("idVendor").is_file());
    let kind = match (&usb_dir, device.to_string_lossy()) {
        (Some(_), _) => Kind::Usb,
        (None, d) if d.contains("/pci") && !d.contains("/pnp") => Kind::Pci,
        (None, d) if d.contains("/platform/") || d.contains("/pnp") => Kind::Platform,
        _ => Kind::Other,
    };
    let usb = usb_dir.map(|d| Usb {
        vid: read_trimmed(&d.join("idVendor")).unwrap_or_default(),
        pid: read_trimmed(&d.join("idProduct")).unwrap_or_default(),
        manufacturer: read_trimmed(&d.join("manufacturer")),
        product: read_trimmed(&d.join("product")),
        serial: read_trimmed(&d.join("serial")),
    });
    let latency_timer = read_trimmed(&tty.join("device/latency_timer"))
        .and_then(|t| t.parse::<u32>().ok())
        .map(|ms| {
            // The file a user writes to: the usb-serial bus's name for the same device,
            // which reads the same as the command the FTDI notes give.
            let bus = roots
                .sys
                .join("bus/usb-serial/devices")
                .join(name)
                .join("latency_timer");
            LatencyTimer {
                ms,
                file: if bus.exists() {
                    bus
                } else {
                    tty.join("device/latency_timer")
                },
            }
        });
    Some(Port {
        path: roots.dev.join(name),
        by_id: by_id
            .iter()
            .filter(|(target, _)| target == name)
            .map(|(_, link)| link.clone())
            .collect(),
        kind,
        driver,
        usb,
        latency_timer,
        access: Access::unknown(),
        lock: None,
    })
}

/// The links of `dev/serial/by-id`, as (the tty they point to, the link), sorted.
fn by_id(dev: &Path) -> Vec<(String, PathBuf)> {
    let dir = dev.join("serial/by-id");
    let mut out: Vec<(String, PathBuf)> = std::fs::read_dir(&dir)
        .into_iter()
        .flatten()
        .flatten()
        .filter_map(|e| {
            let target = std::fs::read_link(e.path()).ok()?;
            let tty = target.file_name()?.to_string_lossy().into_owned();
            Some((tty, e.path()))
        })
        .collect();
    out.sort();
    out
}
