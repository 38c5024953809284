//! What every HTML page of the suite shares: escaping text for HTML, and the inline
//! style sheet (nothing fetched from anywhere).

use std::fmt::Write as _;

/// Escapes text for HTML element content and attribute values.
pub(crate) fn esc(s: &str) -> String {
    escape(s, "&#39;", false)
}

/// Escapes text for XML (JUnit): `&apos;` for the apostrophe, and the control characters
/// XML 1.0 cannot carry shown as `\xNN`.
pub(crate) fn esc_xml(s: &str) -> String {
    escape(s, "&apos;", true)
}

/// The one escaper of HTML and XML text; the two differ only in the apostrophe's entity
/// and in whether control characters (other than newline and tab) are written out.
fn escape(s: &str, apostrophe: &str, controls: bool) -> String {
    let mut out = String::with_capacity(s.len());
    for c in s.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str(apostrophe),
            c if controls && (c as u32) < 0x20 && !matches!(c, '\n' | '\t') => {
                let _ = write!(out, "\\x{:02X}", c as u32);
            }
            c => out.push(c),
        }
    }
    out
}

/// Bytes in hex in a `hex` span, the ones at `diff` marked; `empty` stands for no bytes.
pub(crate) fn hex_marked(bytes: &[u8], diff: &[usize], empty: &str) -> String {
    let mut out = String::from("<span class=\"hex\">");
    for (i, b) in bytes.iter().enumerate() {
        if i > 0 {
            out.push(' ');
        }
        if diff.contains(&i) {
            let _ = write!(out, "<span class=\"d\">{b:02X}</span>");
        } else {
            let _ = write!(out, "{b:02X}");
        }
    }
    if bytes.is_empty() {
        out.push_str(empty);
    }
    out.push_str("</span>");
    out
}

pub(crate) const CSS: &str = r#"
:root{--pass:#4caf50;--dev:#d32f2f;--obs:#f0a800;--skip:#b0b0b0;--err:#7b1fa2;--ink:#1d232b;--muted:#5f6b7a;--line:#d8dde3;--bg:#f6f7f9}
*{box-sizing:border-box}
body{font:14px/1.45 system-ui,-apple-system,"Segoe UI",Roboto,"DejaVu Sans",sans-serif;color:var(--ink);margin:0;background:var(--bg)}
main{max-width:1200px;margin:0 auto;padding:20px 28px 40px;background:#fff;min-height:100vh}
h1{font-size:22px;margin:0 0 4px}
h2{font-size:17px;margin:28px 0 10px;padding-bottom:4px;border-bottom:2px solid var(--line)}
h3{font-size:15px;margin:0 0 4px}
code,.hex,td.id{font-family:ui-monospace,"DejaVu Sans Mono",Menlo,Consolas,monospace;font-size:12.5px}
.muted{color:var(--muted)}
.small{font-size:11px;fill:var(--muted)}
.verdict{display:inline-block;padding:3px 12px;border-radius:4px;font-weight:600;color:#fff;margin:6px 0}
.verdict.ok{background:var(--pass)}.verdict.bad{background:var(--dev)}.verdict.incomplete{background:var(--err)}
.tiles{display:flex;gap:10px;flex-wrap:wrap;margin:12px 0}
.tile{border:1px solid var(--line);border-left:6px solid var(--skip);border-radius:4px;padding:6px 14px;min-width:110px}
.tile b{display:block;font-size:22px}
.tile.pass{border-left-color:var(--pass)}.tile.deviation{border-left-color:var(--dev)}.tile.observation{border-left-color:var(--obs)}.tile.error{border-left-color:var(--err)}
.facts{display:grid;grid-template-columns:repeat(auto-fit,minmax(340px,1fr));gap:4px 28px;align-items:start}
table.found td.id{white-space:nowrap}table.found code.repro{font-size:11.5px;overflow-wrap:anywhere}
.facts table td:first-child{color:var(--muted);white-space:nowrap;padding-right:12px;vertical-align:top}
table{border-collapse:collapse;width:100%}
th,td{text-align:left;padding:4px 8px;border-bottom:1px solid var(--line);vertical-align:top}
.facts td{border:none;padding:2px 0;overflow-wrap:anywhere}
th{background:#eef1f4;font-weight:600}
td.num,th.num{text-align:right;font-variant-numeric:tabular-nums}
.badge{display:inline-block;min-width:88px;text-align:center;padding:1px 6px;border-radius:3px;font-size:11.5px;font-weight:600;color:#fff}
.badge.pass{background:var(--pass)}.badge.deviation{background:var(--dev)}.badge.observation{background:var(--obs);color:#222}.badge.skip{background:var(--skip);color:#222}.badge.error{background:var(--err)}
.finding{border:1px solid var(--line);border-left:6px solid var(--dev);border-radius:4px;padding:10px 14px;margin:10px 0;page-break-inside:avoid}
.finding.observation{border-left-color:var(--obs);padding:3px 12px;margin:3px 0}.finding.error{border-left-color:var(--err)}
.finding summary{cursor:pointer;list-style:none}.finding summary h3,.finding summary div{display:inline}.finding summary div{margin-left:8px}
.finding .cite{color:var(--muted);font-size:12.5px}
.finding ul{margin:6px 0 8px 18px;padding:0}
.frames{margin-top:6px}
.frames td{border:none;padding:1px 8px 1px 0}
.frames td:first-child{color:var(--muted);width:90px}
.hex span.d{background:#ffd5d5;color:#a00000;font-weight:700;border-radius:2px;outline:1px solid #e88}
.ex{border-top:1px dashed var(--line);padding-top:6px;margin-top:6px}
.controls{display:flex;gap:10px;align-items:center;flex-wrap:wrap;margin:8px 0}
.controls input,.controls select{font:inherit;padding:3px 6px}
#checks{table-layout:fixed}#checks td{font-size:13px;overflow-wrap:anywhere}#checks th:nth-child(1){width:24%}#checks th:nth-child(2){width:6%}#checks th:nth-child(3){width:11%}#checks th:nth-child(4){width:22%}#checks th:nth-child(6){width:8%}
#checks tbody tr:hover{background:#f3f6fa}
#checks tr.deviation td.id{color:var(--dev);font-weight:600}
svg.plot{width:100%;height:auto;display:block;margin:6px 0 14px;font-family:inherit}
svg .lab{font-size:12px;fill:var(--ink)}
svg .axis{stroke:#555;stroke-width:1}
svg .tick{stroke:#555}
svg .grid{stroke:#e4e7eb}
svg .bar{fill:#5b8cc9}svg .bar.late{fill:var(--dev)}
svg .median{stroke:#1d3f6e;stroke-dasharray:2 2}
svg .limit{stroke:#2a7a2a;stroke-width:1.5;stroke-dasharray:6 3}
svg .limit.late{stroke:var(--dev)}
svg .limit-t{fill:#2a7a2a}svg .late-t{fill:var(--dev)}
svg .band0{fill:#f3f6fa}svg .band1{fill:#fbf7ee}
svg .dot{stroke:#fff;stroke-width:.5}
svg .silent{stroke-width:1.5;fill:none}
svg .cell.none{fill:#fff;stroke:#ddd;stroke-dasharray:3 2}
.legend{display:flex;gap:14px;flex-wrap:wrap;font-size:12px;color:var(--muted)}
.legend i{display:inline-block;width:12px;height:12px;border-radius:2px;margin-right:4px;vertical-align:-2px}
nav.toc{font-size:12.5px;margin-bottom:10px}nav.toc a{color:#1d5fa8;text-decoration:none}
footer{margin-top:30px;color:var(--muted);font-size:12px}
@media print{body{background:#fff}main{padding:0;max-width:none}.controls{display:none}#checks tr{display:table-row!important}a{color:inherit;text-decoration:none}}
"#;
