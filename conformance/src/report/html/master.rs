//! The master gate's section of the HTML report: what was found on the master, by kind,
//! each with its cases (linked to their findings) and the one command that reproduces
//! the first.

use std::fmt::Write as _;

use super::esc;
use crate::gate::master::MasterSummary;
use crate::judge::Severity;

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
