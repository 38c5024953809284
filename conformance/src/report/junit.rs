//! JUnit XML: one test suite per mode, one test case per check; deviations are failures,
//! errors are errors, skips are skipped, observations pass with their text in
//! `system-out`. A run of several nodes on one bus has one suite per node
//! (`f510.node-05`) and one for the checks of the whole bus (`f510.bus`), the test cases
//! named by check id.

use std::fmt::Write as _;

use super::markup::esc_xml as esc;
use super::Report;
use crate::runner::{CheckResult, Status};

fn body(c: &CheckResult) -> String {
    let mut s = format!("source: {}\n", c.source);
    for f in &c.findings {
        let _ = writeln!(s, "{:?}: {}", f.severity, f.text);
    }
    for e in &c.exchanges {
        let _ = writeln!(s, "request:  {}", crate::codec::hex::Hex(&e.request));
        if let Some(x) = &e.expected {
            let _ = writeln!(s, "expected: {}", crate::codec::hex::Hex(x));
        }
        let _ = writeln!(s, "received: {}", crate::codec::hex::Hex(&e.received));
    }
    s
}

/// The properties that name the description the device was judged by: its file
/// (`built-in`), title and SHA-256; none in a report that does not record it.
fn description(r: &Report) -> Vec<(&'static str, String)> {
    match &r.device.description {
        Some(s) => vec![
            ("description", s.file_or_builtin().to_string()),
            ("description_title", s.title.clone()),
            ("description_sha256", s.sha256.clone()),
        ],
        None => Vec::new(),
    }
}

/// The report as JUnit XML.
pub fn junit(r: &Report) -> String {
    let s = r.summary();
    let total_time: f64 = r.results.iter().map(|c| c.duration.as_secs_f64()).sum();
    let mut o = String::from("<?xml version=\"1.0\" encoding=\"UTF-8\"?>\n");
    let _ = writeln!(
        o,
        "<testsuites name=\"{}\" tests=\"{}\" failures=\"{}\" errors=\"{}\" skipped=\"{}\" time=\"{:.3}\">",
        esc(&format!(
            "teco-modbus-conformance {}",
            match &r.codec {
                Some(c) => format!("gate {} {}", c.implementation, c.version),
                None => r.device.model.clone(),
            }
        )),
        s.total,
        r.results
            .iter()
            .filter(|c| matches!(case(r, c), Case::Failure | Case::StrictUnexpectedPass))
            .count(),
        s.error + usize::from(!r.complete),
        s.skip
            + r.results
                .iter()
                .filter(|c| case(r, c) == Case::Expected)
                .count(),
        total_time
    );
    // One suite per id prefix: "rtu", "ascii" for a drive; "vector", "diff" for a gate.
    let prefix = |c: &CheckResult| c.id.split('.').next().unwrap_or("run").to_string();
    let mut modes: Vec<String> = r.results.iter().map(prefix).collect();
    modes.dedup();
    let subject = match &r.codec {
        Some(c) => c.implementation.clone(),
        None => r.device.model.clone(),
    };
    let nodes = r.node_summaries();
    if nodes.is_empty() {
        for mode in modes {
            let cases: Vec<&CheckResult> = r.results.iter().filter(|c| prefix(c) == mode).collect();
            let name = format!("{subject}.{mode}");
            let properties: Vec<(&str, String)> = match &r.codec {
                Some(c) => vec![
                    ("implementation", c.implementation.clone()),
                    ("version", c.version.clone()),
                    ("adapter", c.adapter.clone()),
                    ("command", c.command.clone()),
                    ("seed", format!("{:#x}", c.seed)),
                    ("count", c.count.to_string()),
                    ("complete", r.complete.to_string()),
                ],
                None => [
                    ("model", r.device.model.clone()),
                    ("manual", r.device.manual.clone()),
                    ("address", format!("{:02X}", r.device.address)),
                    (
                        "link",
                        r.device.links.get(&mode).cloned().unwrap_or_default(),
                    ),
                    ("line", r.device.line.clone()),
                    (
                        "identification",
                        r.device
                            .identification
                            .map(|v| format!("{v:04X}"))
                            .unwrap_or_default(),
                    ),
                    ("complete", r.complete.to_string()),
                ]
                .into_iter()
                .chain(description(r))
                .collect(),
            };
            suite(&mut o, r, &name, &cases, &properties);
        }
    }
    // A run of several nodes: one suite per node, one for the checks of the whole bus.
    let links = r
        .device
        .links
        .iter()
        .map(|(m, l)| format!("{m}: {l}"))
        .collect::<Vec<_>>()
        .join("; ");
    for (node, c) in nodes {
        if node.is_none() && c.total == 0 {
            continue;
        }
        let cases: Vec<&CheckResult> = r.results.iter().filter(|x| x.node == node).collect();
        let info = node.and_then(|n| r.device.nodes.iter().find(|x| x.address == n));
        let (name, address) = match node {
            Some(n) => (format!("{subject}.node-{n:02X}"), format!("{n:02X}")),
            None => (
                format!("{subject}.bus"),
                r.device
                    .nodes
                    .iter()
                    .map(|n| format!("{:02X}", n.address))
                    .collect::<Vec<_>>()
                    .join(" "),
            ),
        };
        let mut properties: Vec<(&str, String)> = vec![
            ("model", r.device.model.clone()),
            ("manual", r.device.manual.clone()),
            ("address", address),
            ("link", links.clone()),
            ("line", r.device.line.clone()),
        ];
        properties.extend(description(r));
        if let Some(i) = info {
            properties.push((
                "identification",
                i.identification
                    .map(|v| format!("{v:04X}"))
                    .unwrap_or_default(),
            ));
            if !i.quirks.is_empty() {
                properties.push(("quirks", i.quirks.join(" ")));
            }
            if let Some(why) = &i.stopped {
                properties.push(("stopped", why.clone()));
            }
        }
        properties.push(("complete", r.complete.to_string()));
        suite(&mut o, r, &name, &cases, &properties);
    }
    if !r.complete {
        let _ = writeln!(
            o,
            "  <testsuite name=\"run\" tests=\"1\" failures=\"0\" errors=\"1\" skipped=\"0\">\n    <testcase classname=\"run\" name=\"complete\">\n      <error type=\"incomplete\" message=\"{}\"/>\n    </testcase>\n  </testsuite>",
            esc(r.stopped.as_deref().unwrap_or("the run did not finish"))
        );
    }
    o.push_str("</testsuites>\n");
    o
}

/// One `<testsuite>` of `cases`.
fn suite(
    o: &mut String,
    r: &Report,
    name: &str,
    cases: &[&CheckResult],
    properties: &[(&str, String)],
) {
    let count = |k: Case| cases.iter().filter(|c| case(r, c) == k).count();
    let _ = writeln!(
        o,
        "  <testsuite name=\"{}\" tests=\"{}\" failures=\"{}\" errors=\"{}\" skipped=\"{}\" time=\"{:.3}\" timestamp=\"{}\">",
        esc(name),
        cases.len(),
        count(Case::Failure) + count(Case::StrictUnexpectedPass),
        count(Case::Status(Status::Error)),
        count(Case::Status(Status::Skip)) + count(Case::Expected),
        cases.iter().map(|c| c.duration.as_secs_f64()).sum::<f64>(),
        esc(&r.started)
    );
    let _ = writeln!(o, "    <properties>");
    for (k, v) in properties {
        let _ = writeln!(o, "      <property name=\"{k}\" value=\"{}\"/>", esc(v));
    }
    if let Some(e) = &r.expect {
        let _ = writeln!(
            o,
            "      <property name=\"expectations\" value=\"{}{}\"/>",
            esc(&e.path),
            if e.strict { " (strict)" } else { "" }
        );
    }
    let _ = writeln!(o, "    </properties>");
    for c in cases {
        let _ = write!(
            o,
            "    <testcase classname=\"{}\" name=\"{}\" time=\"{:.3}\"",
            esc(name),
            esc(&c.id),
            c.duration.as_secs_f64()
        );
        let mark = r.expectation(c);
        let why = |m: &crate::expect::Mark| {
            format!(
                "expected {} ({}:{}): {}{}",
                m.expected.key(),
                r.expect.as_ref().map(|e| e.path.as_str()).unwrap_or(""),
                m.line,
                m.reason,
                m.ticket
                    .as_deref()
                    .map(|t| format!(" [{t}]"))
                    .unwrap_or_default()
            )
        };
        // What goes inside the test case, after its properties.
        let inner: Option<String> = match (case(r, c), mark) {
            // An expected result is skipped, as pytest reports an xfail: not a failure,
            // and not counted as a pass.
            (Case::Expected, Some(m)) => Some(format!(
                "      <skipped type=\"expected\" message=\"{}\"/>\n      <system-out>{}: {}</system-out>",
                esc(&why(m)),
                c.status,
                esc(&body(c))
            )),
            (Case::StrictUnexpectedPass, Some(m)) => Some(format!(
                "      <failure type=\"unexpected-pass\" message=\"UNEXPECTED PASS: {}\">{}</failure>",
                esc(&why(m)),
                esc(&c.summary)
            )),
            (Case::Status(Status::Pass), Some(m)) => Some(format!(
                "      <system-out>UNEXPECTED PASS: {}</system-out>",
                esc(&why(m))
            )),
            _ => match c.status {
                Status::Pass => None,
                Status::Deviation => Some(format!(
                    "      <failure type=\"deviation\" message=\"{}\">{}</failure>",
                    esc(&c.summary),
                    esc(&body(c))
                )),
                Status::Error => Some(format!(
                    "      <error type=\"error\" message=\"{}\">{}</error>",
                    esc(&c.summary),
                    esc(&body(c))
                )),
                Status::Skip => Some(format!(
                    "      <skipped message=\"{}\"/>",
                    esc(&c.summary)
                )),
                Status::Observation => Some(format!(
                    "      <system-out>OBSERVATION: {}</system-out>",
                    esc(&body(c))
                )),
            },
        };
        // The requirements of the manual this check verifies, as pytest's
        // record_property writes test case properties.
        let reqs = crate::requirements::for_check(&r.device.model, &c.id);
        if inner.is_none() && reqs.is_empty() {
            let _ = writeln!(o, "/>");
            continue;
        }
        let _ = writeln!(o, ">");
        if !reqs.is_empty() {
            let _ = writeln!(o, "      <properties>");
            for id in reqs {
                let _ = writeln!(
                    o,
                    "        <property name=\"requirement\" value=\"{}\"/>",
                    esc(id)
                );
            }
            let _ = writeln!(o, "      </properties>");
        }
        if let Some(inner) = inner {
            let _ = writeln!(o, "{inner}");
        }
        let _ = writeln!(o, "    </testcase>");
    }
    let _ = writeln!(o, "  </testsuite>");
}

/// How a check counts in JUnit: its status, or how an expectations file marks it.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Case {
    Status(Status),
    /// A deviation no expectation accepts.
    Failure,
    /// A result an expectation accepts: skipped.
    Expected,
    /// A pass expected to deviate, under --strict-expect: a failure.
    StrictUnexpectedPass,
}

fn case(r: &Report, c: &CheckResult) -> Case {
    use crate::expect::MarkKind;
    match r.expectation(c).map(|m| m.kind) {
        Some(MarkKind::Expected) => Case::Expected,
        Some(MarkKind::UnexpectedPass) if r.expect.as_ref().is_some_and(|e| e.strict) => {
            Case::StrictUnexpectedPass
        }
        _ if c.status == Status::Deviation => Case::Failure,
        _ => Case::Status(c.status),
    }
}
