//! Reports built in code for the renderers' tests: a run of one node, and a run of three
//! nodes on one bus (one of which stopped answering) with checks of the whole bus.

use std::time::Duration;

use super::{Device, NodeInfo, Report, RunOptions};
use crate::codec::Mode;
use crate::runner::{CheckResult, ExchangeRecord, Finding, RestoreRecord, Status};

/// One check result of `node`.
pub(crate) fn result(id: &str, status: Status, node: Option<u8>) -> CheckResult {
    let findings = match status {
        Status::Deviation => vec![Finding::deviation(format!("{id}: code 03 instead of 02"))],
        Status::Observation => vec![Finding::observation(format!("{id}: the manual is silent"))],
        _ => vec![],
    };
    let summary = match status {
        Status::Error if id.ends_with(".not-run") => {
            "not run: the device stopped answering".to_string()
        }
        Status::Skip => "skipped: read-only run".to_string(),
        _ => format!("{id} is {status}"),
    };
    let address = node.unwrap_or(1);
    CheckResult {
        id: id.into(),
        title: format!("title of {id}"),
        mode: if id.starts_with("ascii.") {
            Some(Mode::Ascii)
        } else {
            Some(Mode::Rtu)
        },
        source: "F510 manual, 4.3".into(),
        status,
        summary,
        findings,
        exchanges: vec![ExchangeRecord {
            request: vec![address, 3, 0, 0x39, 0, 1, 0x54, 7],
            expected: Some(vec![address, 0x83, 2, 0xC0, 0xF1]),
            received: vec![address, 0x83, 3, 1, 0x31],
            reply: Some(vec![address, 0x83, 3, 1, 0x31]),
            predicted: "exception 02H".into(),
            actual: "exception 03H".into(),
            latency: Some(Duration::from_micros(8_960 + u64::from(address) * 100)),
        }],
        duration: Duration::from_micros(21_500),
        node,
    }
}

/// A restore record of `register` (its original value 04D2H).
pub(crate) fn restore(
    node: Option<u8>,
    register: u16,
    restored: bool,
    changed: bool,
) -> RestoreRecord {
    RestoreRecord {
        node,
        register,
        original: 0x04D2,
        restored,
        changed,
        detail: if restored {
            "read back 04D2".into()
        } else {
            "no reply to the write back".into()
        },
    }
}

/// A finished run of node 01H of an F510 in both modes with `results` and `restore`.
pub(crate) fn base(results: Vec<CheckResult>, restore: Vec<RestoreRecord>) -> Report {
    Report {
        started: "2026-01-01T00:00:00Z".into(),
        finished: Some("2026-01-01T00:01:00Z".into()),
        complete: true,
        device: Device {
            model: "f510".into(),
            manual: "F510 manual".into(),
            address: 1,
            links: [("rtu".to_string(), "pty /dev/pts/3".to_string())].into(),
            line: "9600 baud 8E1".into(),
            identification: Some(0x0510),
            simulated: Some(vec![]),
            nodes: vec![],
            description: None,
        },
        options: RunOptions {
            modes: vec![Mode::Rtu, Mode::Ascii],
            timeout_ms: 1000,
            retries: 1,
            response_time_ms: Some(10.0),
            response_allowance_ms: Some(20),
            ..RunOptions::default()
        },
        results,
        restore,
        ..Report::default()
    }
}

/// A run of one node: every status, a lost tail, restore records of every kind.
pub(crate) fn one_node() -> Report {
    base(
        vec![
            result("rtu.map.group-0.first", Status::Pass, None),
            result("rtu.map.group-0.past-end", Status::Deviation, None),
            result("rtu.timing.silence", Status::Observation, None),
            result("rtu.write.single", Status::Skip, None),
            result("rtu.diag.echo", Status::Error, None),
            result("rtu.bus.broadcast-write", Status::Pass, None),
            result("ascii.map.group-0.first", Status::Pass, None),
            result("ascii.map.group-0.past-end", Status::Deviation, None),
        ],
        vec![
            restore(None, 0x2502, true, true),
            restore(None, 0x2503, true, false),
            restore(None, 0x2504, false, true),
        ],
    )
}

/// The nodes of [`several_nodes`].
pub(crate) const NODES: [u8; 3] = [1, 2, 5];

/// A run of three nodes (01H, 02H, 05H) on one bus: node 02H stopped answering part way
/// (its remaining checks "not run"), node 05H has a deviation node 01H has not, and the
/// checks of the whole bus ran once.
pub(crate) fn several_nodes() -> Report {
    let mut results = Vec::new();
    for &n in &NODES {
        let lost = n == 2;
        results.push(result("rtu.map.group-0.first", Status::Pass, Some(n)));
        results.push(result(
            "rtu.map.group-0.past-end",
            if n == 5 {
                Status::Deviation
            } else if lost {
                Status::Error
            } else {
                Status::Pass
            },
            Some(n),
        ));
        if lost {
            results.push(result("rtu.timing.not-run", Status::Error, Some(n)));
            results.push(result("rtu.diag.not-run", Status::Error, Some(n)));
        } else {
            results.push(result("rtu.timing.silence", Status::Observation, Some(n)));
            results.push(result("rtu.write.single", Status::Skip, Some(n)));
        }
    }
    results.push(result("rtu.bus.broadcast-write", Status::Pass, None));
    results.push(result("rtu.bus.other-address", Status::Deviation, None));
    results.push(result("rtu.bus.preflight", Status::Pass, None));
    let mut r = base(
        results,
        vec![
            restore(Some(1), 0x2502, true, true),
            restore(Some(2), 0x2502, false, true),
            restore(Some(5), 0x2502, true, false),
        ],
    );
    r.device.nodes = NODES
        .iter()
        .map(|&n| NodeInfo {
            address: n,
            identification: if n == 2 { None } else { Some(0x0510) },
            stopped: (n == 2).then(|| "no reply to 3 requests in a row".to_string()),
            quirks: if n == 5 {
                vec!["wrong-exception".into()]
            } else {
                vec![]
            },
        })
        .collect();
    r
}
