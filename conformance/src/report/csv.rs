//! CSV: one row per check (id, mode, status, title, source, summary; a run of several nodes
//! has a `node` column first), quoted as RFC 4180
//! says (CRLF line ends; a field with a comma, a quote or a line break is quoted, its
//! quotes doubled), for spreadsheets and test records.

use super::Report;

/// One CSV field: quoted when it holds a comma, a quote or a line break.
pub(crate) fn field(s: &str) -> String {
    if s.contains([',', '"', '\n', '\r']) {
        format!("\"{}\"", s.replace('"', "\"\""))
    } else {
        s.to_string()
    }
}

/// The report as CSV, with a header row. A run of several nodes has a first column more,
/// `node`: the node's address in hex ("05"), empty for the checks of the whole bus.
pub fn csv(report: &Report) -> String {
    let nodes = !report.device.nodes.is_empty();
    let mut out = String::from(if nodes {
        "node,id,mode,status,title,source,summary"
    } else {
        "id,mode,status,title,source,summary"
    });
    // A run with --expect: how each result stands against the file (expected,
    // unexpected-pass, changed, or new for a deviation no entry accepts) and the entry.
    let expect = report.expect.as_ref();
    let new: std::collections::BTreeSet<String> = report
        .unexpected_findings()
        .iter()
        .map(|x| x.key())
        .collect();
    if expect.is_some() {
        out.push_str(",expectation,expectation_entry");
    }
    out.push_str("\r\n");
    for r in &report.results {
        if nodes {
            if let Some(n) = r.node {
                out.push_str(&format!("{n:02X}"));
            }
            out.push(',');
        }
        let mode = r.mode.map(|m| m.to_string()).unwrap_or_default();
        let row = [
            r.id.as_str(),
            mode.as_str(),
            &r.status.to_string(),
            r.title.as_str(),
            r.source.as_str(),
            r.summary.as_str(),
        ]
        .map(field)
        .join(",");
        out.push_str(&row);
        if let Some(e) = expect {
            let (outcome, entry) = match report.expectation(r) {
                Some(m) => (m.kind.key(), format!("{}:{}: {}", e.path, m.line, m.reason)),
                None if new.contains(&r.key()) => ("new", String::new()),
                None => ("", String::new()),
            };
            out.push(',');
            out.push_str(outcome);
            out.push(',');
            out.push_str(&field(&entry));
        }
        out.push_str("\r\n");
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::Mode;
    use crate::runner::{CheckResult, Status};

    fn result(id: &str, summary: &str) -> CheckResult {
        CheckResult {
            id: id.into(),
            title: "Read \"first\", then last".into(),
            mode: Some(Mode::Rtu),
            source: "F510 manual, 4.3".into(),
            status: Status::Deviation,
            summary: summary.into(),
            findings: vec![],
            exchanges: vec![],
            duration: std::time::Duration::ZERO,
            node: None,
        }
    }

    #[test]
    fn fields_with_commas_quotes_and_line_breaks_are_quoted() {
        let report = Report {
            results: vec![
                result("rtu.plain", "plain"),
                result("rtu.odd", "line one\nline two, \"quoted\""),
            ],
            ..Report::default()
        };
        let out = csv(&report);
        let lines: Vec<&str> = out.split("\r\n").collect();
        assert_eq!(lines[0], "id,mode,status,title,source,summary");
        assert_eq!(
            lines[1],
            "rtu.plain,rtu,DEVIATION,\"Read \"\"first\"\", then last\",\"F510 manual, 4.3\",plain"
        );
        assert_eq!(
            lines[2],
            "rtu.odd,rtu,DEVIATION,\"Read \"\"first\"\", then last\",\"F510 manual, 4.3\",\"line one\nline two, \"\"quoted\"\"\""
        );
        assert_eq!(lines[3], "");
        assert_eq!(lines.len(), 4);
    }
}
