//! The parts of the page only a run of several nodes on one bus has: the table of the
//! nodes (each with its counts, and a link that filters the checks to it), the node
//! column and filter of the table of checks, and the node of each restored register.
//! A run of one node has none of them, so its page is what it was before.

use std::fmt::Write;

use crate::report::markup::esc;
use crate::report::Report;
use crate::runner::CheckResult;

macro_rules! w {
    ($out:expr, $($arg:tt)*) => {{
        // Writing to a String cannot fail.
        let _ = write!($out, $($arg)*);
    }};
}

/// Column widths of the table of checks with its node column (second).
pub(super) const CSS: &str = "#checks.nodes th:nth-child(1){width:22%}#checks.nodes th:nth-child(2){width:5%}#checks.nodes th:nth-child(3){width:6%}#checks.nodes th:nth-child(4){width:11%}#checks.nodes th:nth-child(5){width:20%}#checks.nodes th:nth-child(6){width:auto}#checks.nodes th:nth-child(7){width:8%}\n#nodes td a{color:#1d5fa8}.node{display:inline-block;font-size:11.5px;font-weight:600;border:1px solid var(--line);border-radius:3px;padding:0 5px;margin-right:6px;color:var(--muted)}\n";

/// The filter of the table of checks, with the node select; a link can preselect it
/// (`#node=05&status=deviation`), also after the page loaded (the node table's links).
pub(super) const SCRIPT: &str = r#"
(function(){
var q=document.getElementById('q'),st=document.getElementById('fs'),md=document.getElementById('fm'),nd=document.getElementById('fn'),n=document.getElementById('shown');
function f(){var t=q.value.toLowerCase(),s=st.value,m=md.value,k=nd.value,c=0;
document.querySelectorAll('#checks tbody tr').forEach(function(r){
var ok=(!s||r.dataset.status===s)&&(!m||r.dataset.mode===m)&&(!k||r.dataset.node===k)&&(!t||r.dataset.id.toLowerCase().indexOf(t)>=0);
r.style.display=ok?'':'none';if(ok)c++;});n.textContent=c;}
function h(){var x=location.hash.slice(1);if(x.indexOf('=')>0){st.value='';md.value='';nd.value='';q.value='';x.split('&').forEach(function(kv){var p=kv.split('='),v=p[1]||'';try{v=decodeURIComponent(v);}catch(e){}if(p[0]==='status')st.value=v;if(p[0]==='mode')md.value=v;if(p[0]==='node')nd.value=v;if(p[0]==='id')q.value=v;});f();}}
[q,st,md,nd].forEach(function(e){e.addEventListener('input',f);e.addEventListener('change',f);});window.addEventListener('hashchange',h);h();f();
})();
"#;

/// The value of a check's `data-node`: its node in hex, or `bus`.
pub(super) fn node_value(r: &CheckResult) -> String {
    match r.node {
        Some(n) => format!("{n:02X}"),
        None => "bus".into(),
    }
}

/// The label of a check's node, shown next to its id: `node 05H` or `bus`.
pub(super) fn node_label(node: Option<u8>) -> String {
    match node {
        Some(n) => format!("node {n:02X}H"),
        None => "bus".into(),
    }
}

/// The table of the nodes and of the checks of the whole bus.
pub(super) fn table(out: &mut String, report: &Report) {
    let monitor = report.kind == super::super::ReportKind::Monitor;
    let intro = if monitor {
        "Each node heard on the bus, its drive's side and its master's side judged on every exchange; address 00 is the broadcasts. A link filters the table of every check to the node."
    } else {
        "Each node was checked in turn; the checks of the whole bus (broadcasts, another address) ran once. A link filters the table of every check to the node."
    };
    out.push_str("<h2 id=\"nodes-h\">Nodes on the bus</h2><p class=\"muted\">");
    out.push_str(intro);
    out.push_str("</p><table id=\"nodes\"><thead><tr><th>node</th><th>identification</th><th class=\"num\">checks</th><th class=\"num\">pass</th><th class=\"num\">deviations</th><th class=\"num\">observations</th><th class=\"num\">skipped</th><th class=\"num\">errors</th><th>notes</th></tr></thead><tbody>");
    for (node, s) in report.node_summaries() {
        let info = node.and_then(|n| report.device.nodes.iter().find(|x| x.address == n));
        let value = match node {
            Some(n) => format!("{n:02X}"),
            None => "bus".into(),
        };
        let mut notes = Vec::new();
        if let Some(i) = info {
            if !i.quirks.is_empty() {
                notes.push(format!("quirks: <b>{}</b>", esc(&i.quirks.join(", "))));
            }
            if let Some(why) = &i.stopped {
                notes.push(format!(
                    "<span class=\"badge error\">STOPPED</span> {}",
                    esc(why)
                ));
            }
        } else if node.is_none() {
            notes.push("broadcast and other-address checks, run once".into());
        }
        // A node a monitor was told of (-a) but never heard: no frame to or from it.
        if monitor
            && node.is_some()
            && !report
                .monitor
                .as_ref()
                .is_some_and(|m| m.nodes.iter().any(|(a, _)| Some(*a) == node))
        {
            notes.push("nothing heard to or from it".into());
        }
        w!(
            out,
            "<tr class=\"{cls}\" data-node=\"{value}\"><td class=\"id\"><a href=\"#node={value}\">{label}</a></td><td class=\"id\">{ident}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{notes}</td></tr>",
            s.total,
            s.pass,
            s.deviation,
            s.observation,
            s.skip,
            s.error,
            cls = if s.deviation > 0 {
                "deviation"
            } else if s.error > 0 {
                "error"
            } else {
                "pass"
            },
            label = esc(&node_label(node)),
            ident = match info {
                // A monitor only listens: it reads no identification register.
                Some(_) if monitor => "<i class=\"muted\">not asked (listened only)</i>".into(),
                Some(i) => i
                    .identification
                    .map(|v| format!("{v:04X}H"))
                    .unwrap_or_else(|| "<i class=\"muted\">not read</i>".into()),
                None => String::new(),
            },
            notes = notes.join("; ")
        );
    }
    out.push_str("</tbody></table>");
}

/// The node select of the filter.
pub(super) fn select(out: &mut String, report: &Report) {
    out.push_str("<label>node <select id=\"fn\"><option value=\"\">any</option>");
    for n in &report.device.nodes {
        w!(
            out,
            "<option value=\"{:02X}\">{:02X}H</option>",
            n.address,
            n.address
        );
    }
    out.push_str("<option value=\"bus\">bus</option></select></label>");
}
