//! `model export --to pymodbus-sim`: a description as pymodbus's simulator JSON (the file
//! `pymodbus.simulator --json_file` reads, pymodbus 3.x: `server_list` and `device_list`,
//! the device as `ModbusSimulatorContext` takes it).
//!
//! What the simulator can say of a device, and what it cannot:
//! - Holding registers only (`hr size` 65536, the other blocks 0, `shared blocks` false):
//!   every register the description serves is a `uint16` with its initial value (the
//!   description's initial values, example registers and identification value; 0 else);
//!   every other register is `invalid` (pymodbus answers exception 02H).
//! - `write` lists the read-write registers; a write elsewhere gets 02H from pymodbus.
//! - The server is a serial device at the description's first node address, silent to
//!   other addresses (`ignore_missing_devices`) and executing broadcasts unanswered
//!   (`broadcast_enable`), as Modbus over Serial Line V1.02 2.2 has it.
//! - pymodbus has no value bounds, no read or write limits below the specification's, no
//!   response time, no exception table of its own and no TECO command bits: what
//!   [`PymodbusExport::lost`] lists is what the round trip cannot keep.

use serde_json::{json, Value};

use crate::model::{Access, DriveModel};

/// pymodbus's simulator JSON for a description, and what it leaves out.
#[derive(Debug, Clone)]
pub struct PymodbusExport {
    /// The simulator's JSON file.
    pub json: Value,
    /// Registers served (uint16).
    pub served: usize,
    /// Of them, writable.
    pub writable: usize,
    /// Facts of the description the simulator cannot hold, in words.
    pub lost: Vec<String>,
}

/// How pymodbus's simulator holds one register.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Cell {
    Invalid,
    Served { value: u16, write: bool },
}

/// Runs of equal cells: (first, last, cell).
fn runs(cells: &[Cell]) -> Vec<(usize, usize, Cell)> {
    let mut out: Vec<(usize, usize, Cell)> = Vec::new();
    for (i, &c) in cells.iter().enumerate() {
        match out.last_mut() {
            Some((_, last, prev)) if *prev == c && *last + 1 == i => *last = i,
            _ => out.push((i, i, c)),
        }
    }
    out
}

/// The description `model` as pymodbus's simulator JSON.
pub fn export_pymodbus_sim(model: &DriveModel) -> PymodbusExport {
    let mut initial = vec![0u16; 0x1_0000];
    for (r, v, ..) in &model.example_registers {
        initial[usize::from(*r)] = *v;
    }
    for (r, v, _) in &model.initial_values {
        initial[usize::from(*r)] = *v;
    }
    if let Some((r, v)) = model
        .identification
        .as_ref()
        .and_then(|i| Some((i.register?, i.simulated)))
    {
        initial[usize::from(r)] = v;
    }
    let cells: Vec<Cell> = (0..=u16::MAX)
        .map(|r| match model.lookup(r) {
            None => Cell::Invalid,
            Some(info) => match info.access {
                // pymodbus has no write-only cell: a write-only register is served
                // read-write (its reads answered, where the device refuses them).
                Access::ReadWrite | Access::WriteOnly => Cell::Served {
                    value: initial[usize::from(info.register)],
                    write: true,
                },
                Access::ReadOnly | Access::Reserved => Cell::Served {
                    value: initial[usize::from(info.register)],
                    write: false,
                },
                // No Modbus access at all: the simulator's nearest is invalid (02H).
                Access::NoAccess => Cell::Invalid,
            },
        })
        .collect();
    let pair = |a: usize, b: usize| json!([a, b]);
    let mut invalid = Vec::new();
    let mut write = Vec::new();
    let mut uint16 = Vec::new();
    let (mut served, mut writable) = (0, 0);
    for (a, b, c) in runs(&cells) {
        match c {
            Cell::Invalid => invalid.push(pair(a, b)),
            Cell::Served { value, write: w } => {
                served += b - a + 1;
                uint16.push(json!({"addr": [a, b], "value": value, "action": null}));
                if w {
                    writable += b - a + 1;
                }
            }
        }
    }
    // The writable registers as runs of their own (value runs may cut them).
    let writes: Vec<Cell> = cells
        .iter()
        .map(|c| match c {
            Cell::Served { write: true, .. } => Cell::Served {
                value: 0,
                write: true,
            },
            _ => Cell::Invalid,
        })
        .collect();
    for (a, b, c) in runs(&writes) {
        if c != Cell::Invalid {
            write.push(pair(a, b));
        }
    }
    let mut lost = vec![
        "value bounds (a write out of range is stored, not refused)".to_string(),
        format!(
            "read and write limits ({} / {} registers in RTU): pymodbus takes the specification's 125 / 123",
            model.limits.read.rtu, model.limits.write.rtu
        ),
        match model.limits.response_time_ms {
            Some(ms) => format!("the response time ({ms} ms): pymodbus answers as soon as it can"),
            None => "the response time (not stated): pymodbus answers as soon as it can".to_string(),
        },
        "the exception table: pymodbus answers 01H, 02H, 03H, 04H as the specification numbers them"
            .to_string(),
    ];
    if !model.named.is_empty() {
        lost.push(
            "the command and monitor registers' roles (run, fault bits): their registers are plain values"
                .to_string(),
        );
    }
    if !model.aliases.is_empty() {
        lost.push(
            "alias spellings: the alias registers are separate registers with their own values"
                .to_string(),
        );
    }
    let device = json!({
        "setup": {
            "co size": 0,
            "di size": 0,
            "hr size": 0x1_0000,
            "ir size": 0,
            "shared blocks": false,
            "type exception": false,
            "defaults": {
                "value": {"bits": 0, "uint16": 0, "uint32": 0, "float32": 0.0, "float64": 0.0, "string": " "},
                "action": {"bits": null, "uint16": null, "uint32": null, "float32": null, "float64": null, "string": null},
            },
        },
        "invalid": invalid,
        "write": write,
        "uint16": uint16,
        "repeat": [],
    });
    let json = json!({
        "server_list": {
            "server": {
                "comm": "serial",
                "port": "/dev/ttyUSB0",
                "framer": "rtu",
                "baudrate": 9600,
                "bytesize": 8,
                "parity": "E",
                "stopbits": 1,
                "timeout": 0.05,
                // A serial device: silent to other nodes (pymodbus's default answers them
                // with 0BH, as a gateway), and a broadcast is executed, not answered.
                "ignore_missing_devices": true,
                "broadcast_enable": true,
                "device_id": model.addresses.start(),
            },
        },
        "device_list": {
            model.id.clone(): device,
        },
    });
    PymodbusExport {
        json,
        served,
        writable,
        lost,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_f510_map_as_pymodbus_cells() {
        let m = DriveModel::builtin("f510").unwrap();
        let out = export_pymodbus_sim(&m);
        let served = m.registers().count();
        assert_eq!(out.served, served);
        let dev = &out.json["device_list"]["f510"];
        assert_eq!(dev["setup"]["hr size"], 65536);
        // Every register is in exactly one of invalid and uint16.
        let mut seen = vec![0u8; 0x1_0000];
        for e in dev["invalid"].as_array().unwrap() {
            for r in e[0].as_u64().unwrap()..=e[1].as_u64().unwrap() {
                seen[r as usize] += 1;
            }
        }
        for e in dev["uint16"].as_array().unwrap() {
            let a = &e["addr"];
            for r in a[0].as_u64().unwrap()..=a[1].as_u64().unwrap() {
                seen[r as usize] += 1;
            }
        }
        assert!(seen.iter().all(|&n| n == 1));
        // The monitor block is served, read-only; the frequency command writable.
        let served_at = |r: u64, key: &str| {
            dev[key].as_array().unwrap().iter().any(|e| {
                let a = if e.is_array() { e } else { &e["addr"] };
                (a[0].as_u64().unwrap()..=a[1].as_u64().unwrap()).contains(&r)
            })
        };
        assert!(served_at(0x2520, "uint16") && !served_at(0x2520, "write"));
        assert!(served_at(0x2502, "write"));
        assert!(served_at(0xFFFF, "invalid"));
        assert_eq!(out.json["server_list"]["server"]["device_id"], 1);
    }
}
