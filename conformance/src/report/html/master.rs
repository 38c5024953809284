//! The master gate's section of the HTML report: what was found on the master, by kind,
//! each with its cases (linked to their findings) and the one command that reproduces
//! the first.

use std::fmt::Write as _;

use crate::gate::master::MasterSummary;
use crate::judge::Severity;
use crate::report::markup::esc;
use crate::report::{Report, ReportKind};

/// The words a page uses for its results. A gate runs cases (as its text report says); a
/// master gate holds a master to what Modbus asks of one, with sources that are
/// specifications and known bugs of libraries, not the drive's manual.
pub(super) struct Words {
    /// One result: "check" or "case".
    pub one: &'static str,
    /// Results: "checks" or "cases".
    pub many: &'static str,
    /// What a deviation departs from: "from the manual", "in the master".
    pub from: &'static str,
    /// The label of a result's source.
    pub cite: &'static str,
    /// The deviations section when there are none.
    pub none: &'static str,
}

/// The words of `report`'s page.
pub(super) fn words(report: &Report) -> Words {
    match (report.kind, report.master.is_some()) {
        (ReportKind::Gate, true) => Words {
            one: "case",
            many: "cases",
            from: "in the master",
            cite: "Source",
            none: "None: in every case that ran the master did what Modbus asks of it.",
        },
        (ReportKind::Gate, false) => Words {
            one: "case",
            many: "cases",
            from: "from the manual",
            cite: "Source",
            none: "None: every case that ran agreed with the manual.",
        },
        _ => Words {
            one: "check",
            many: "checks",
            from: "from the manual",
            cite: "Manual",
            none: "None: every check that ran agreed with the manual.",
        },
    }
}

/// The section, or nothing when nothing was found.
pub(super) fn section(m: &MasterSummary, has_block: impl Fn(&str) -> bool) -> String {
    if m.kinds.is_empty() {
        return String::new();
    }
    let mut out = String::from(
        "<h2 id=\"found\">Found on the master, by kind</h2><p class=\"muted\">Each kind of failure once, with the cases it was seen in and the command that runs its first case again.</p><table class=\"found\"><thead><tr><th>kind</th><th>severity</th><th>cases</th><th>reproduce</th></tr></thead><tbody>",
    );
    for (kind, k) in &m.kinds {
        let (class, label) = match k.severity {
            Severity::Deviation => ("deviation", "DEVIATION"),
            Severity::Observation => ("observation", "OBSERVATION"),
        };
        let cases: Vec<String> = k
            .cases
            .iter()
            .map(|c| {
                if has_block(c) {
                    format!("<a href=\"#f-{0}\"><code>{0}</code></a>", esc(c))
                } else {
                    format!("<code>{}</code>", esc(c))
                }
            })
            .collect();
        let _ = write!(
            out,
            "<tr><td class=\"id\">{}</td><td><span class=\"badge {class}\">{label}</span></td><td>{}</td><td><code class=\"repro\">{}</code></td></tr>",
            esc(kind),
            cases.join(" "),
            esc(&k.repro)
        );
    }
    out.push_str("</tbody></table>");
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gate::master::KindSummary;
    use crate::report::fixtures;
    use crate::runner::Status;

    /// A master gate's page: its verdict, tiles and sections speak of cases and of the
    /// master, a source that is a library's issue is no "Manual:", and a card whose bytes
    /// hold no valid reply says so, not that no reply was found. A drive's page keeps its
    /// words.
    #[test]
    fn a_master_gate_page_speaks_of_cases_found_in_the_master() {
        let mut r = fixtures::one_node();
        r.kind = ReportKind::Gate;
        r.master = Some(MasterSummary::default());
        let stale = &mut r.results[1];
        stale.source = "pymodbus #2636, eModbus #74".into();
        stale.exchanges[0].reply = None;
        let page = super::super::html(&r);
        assert!(!page.contains("from the manual"), "{page}");
        assert!(!page.contains("Manual:"), "{page}");
        assert!(page.contains("<div class=\"cite\">Source: pymodbus #2636, eModbus #74</div>"));
        assert!(page.contains("2 deviations in the master"), "{page}");
        assert!(page.contains("<b>8</b>cases</div>"), "{page}");
        assert!(!page.contains("</b>checks</div>"), "{page}");
        assert!(page.contains("Every case (8)"), "{page}");
        assert!(!page.contains("no reply frame found"), "{page}");
        assert!(page.contains("none: what came (below) is no valid reply to this request"));

        let mut clean = r.clone();
        clean.results.retain(|c| c.status == Status::Pass);
        let page = super::super::html(&clean);
        assert!(page.contains("No deviations in the master"), "{page}");
        assert!(
            page.contains("the master did what Modbus asks of it"),
            "{page}"
        );

        let page = super::super::html(&fixtures::one_node());
        assert!(page.contains("2 deviations from the manual"), "{page}");
        assert!(page.contains("<div class=\"cite\">Manual: F510 manual, 4.3</div>"));
        assert!(page.contains("<b>8</b>checks</div>"), "{page}");
    }

    #[test]
    fn each_kind_is_a_row_with_its_cases_linked_where_they_have_a_finding() {
        let mut m = MasterSummary {
            modes: vec!["rtu".into()],
            lines: vec!["pty".into()],
            settings: Default::default(),
            kinds: Default::default(),
            line: "pty".into(),
            serial: None,
        };
        assert_eq!(section(&m, |_| true), "");
        m.kinds.insert(
            "stale-reply-taken".into(),
            KindSummary {
                severity: Severity::Deviation,
                cases: vec!["rtu.read.stale-in-flight".into(), "rtu.read.other".into()],
                example: "e".into(),
                repro: "conformance gate --master 'a & b' --only rtu.read.stale-in-flight".into(),
            },
        );
        let html = section(&m, |c| c == "rtu.read.stale-in-flight");
        assert!(
            html.contains("<td class=\"id\">stale-reply-taken</td>"),
            "{html}"
        );
        assert!(
            html.contains("<span class=\"badge deviation\">DEVIATION</span>"),
            "{html}"
        );
        assert!(html.contains(
            "<a href=\"#f-rtu.read.stale-in-flight\"><code>rtu.read.stale-in-flight</code></a> <code>rtu.read.other</code>"
        ), "{html}");
        assert!(html.contains("--master &#39;a &amp; b&#39;"), "{html}");
        assert_eq!(html.matches("<tr>").count(), 2);
    }
}
