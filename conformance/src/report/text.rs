//! The human report: a summary line, then deviations (with both frames and the differing
//! bytes marked), observations, errors, skips, and the restore. A run of several nodes on
//! one bus adds a summary line per node and one for the bus checks, and gives the results
//! in a section per node and one for the bus (each ordered as a run of one node is); its
//! restore lines name their node.

use std::fmt::Write as _;

use super::{diff_positions, Report, Summary};
use crate::codec::hex::Hex;
use crate::codec::Mode;
use crate::expect::{EntryState, MarkKind};
use crate::runner::{CheckResult, ExchangeRecord, Status};

/// `text` up to its first "; " outside parentheses (all of it if there is none).
fn first_clause(text: &str) -> &str {
    let mut depth = 0usize;
    for (i, c) in text.char_indices() {
        match c {
            '(' => depth += 1,
            ')' => depth = depth.saturating_sub(1),
            ';' if depth == 0 => return &text[..i],
            _ => {}
        }
    }
    text
}

/// The report as text; `verbose` also lists every passing check and every exchange.
pub fn text(r: &Report, verbose: bool) -> String {
    let mut o = String::new();
    let s = r.summary();
    let d = &r.device;
    let gate = r.kind == super::ReportKind::Gate;
    let _ = writeln!(
        o,
        "TECO Modbus {} ({} {})",
        if r.master.is_some() {
            "master gate report"
        } else if r.kind == super::ReportKind::Monitor {
            "bus monitor report"
        } else if gate {
            "codec gate report"
        } else {
            "conformance report"
        },
        env!("CARGO_PKG_NAME"),
        env!("CARGO_PKG_VERSION")
    );
    let _ = writeln!(
        o,
        "RESULT: {}{}",
        counts(&s, if gate { "cases" } else { "checks" }),
        if r.complete { "" } else { "  [INCOMPLETE]" }
    );
    expect_header(&mut o, r);
    if let Some(c) = &r.codec {
        let _ = writeln!(
            o,
            "{}{} {} (adapter {}; supports {})",
            if r.master.is_some() {
                "master:  "
            } else {
                "codec:   "
            },
            c.implementation,
            c.version,
            c.adapter,
            c.supports.join(" ")
        );
        let _ = writeln!(o, "command: {}", c.command);
        match &r.master {
            Some(m) => {
                for l in m.text_lines() {
                    let _ = writeln!(o, "{l}");
                }
            }
            None => {
                let _ = writeln!(
                    o,
                    "cases:   golden vectors, and {} differential cases from seed {:#x}",
                    c.count, c.seed
                );
            }
        }
        for i in &c.incidents {
            let _ = writeln!(o, "adapter: {i}");
        }
    }
    if !gate {
        let _ = writeln!(
            o,
            "device:  {} ({}), {}{}{}",
            d.model,
            d.manual,
            if d.nodes.is_empty() && r.kind == super::ReportKind::Monitor {
                // Nothing heard and no -a: there is no node to name.
                "no node heard".to_string()
            } else if d.nodes.is_empty() {
                format!("node {:02X}", d.address)
            } else {
                format!(
                    "{} node{} on one bus: {}",
                    d.nodes.len(),
                    plural(d.nodes.len()),
                    d.nodes
                        .iter()
                        .map(|n| format!("{:02X}", n.address))
                        .collect::<Vec<_>>()
                        .join(" ")
                )
            },
            match d.identification {
                Some(v) if d.nodes.is_empty() => format!(", identification {v:04X}H"),
                _ => String::new(),
            },
            match &d.simulated {
                Some(q) if q.is_empty() => ", simulated by this suite".to_string(),
                Some(q) => format!(", simulated by this suite with quirks: {}", q.join(" ")),
                None => String::new(),
            }
        );
        node_lines(&mut o, r);
        for (mode, link) in &d.links {
            let _ = writeln!(o, "link:    {mode}: {link}");
        }
        let _ = writeln!(o, "line:    {}", d.line);
        // A built-in model is named by the suite's version on the first line; a
        // description read from a file by its file, title and hash.
        if let Some(s) = d.description.as_ref().filter(|s| s.file.is_some()) {
            let _ = writeln!(
                o,
                "model:   {}, {:?}, sha256 {}",
                s.file_or_builtin(),
                s.title,
                s.sha256
            );
        }
    }
    let _ = writeln!(
        o,
        "run:     {} .. {}; {}{}{}; {}{}",
        r.started,
        r.finished.as_deref().unwrap_or("(running)"),
        if r.complete { "complete" } else { "INCOMPLETE" },
        match &r.stopped {
            Some(why) => format!(" (stopped: {why})"),
            None => String::new(),
        },
        if r.options.read_only {
            ", read-only"
        } else if r.options.allow_motion {
            ", motion allowed"
        } else {
            ""
        },
        r.timeout_phrase(),
        if r.options.only.is_empty() {
            String::new()
        } else {
            format!(", only {}", r.options.only.join(" "))
        }
    );
    if let Some(m) = &r.monitor {
        for l in m.text_lines() {
            let _ = writeln!(o, "heard:   {l}");
        }
    }
    for (mode, b) in &r.budget {
        if b.host_reruns > 0 {
            let _ = writeln!(
                o,
                "stalls:  {mode}: {} run(s) of a check again, because this host stalled under it (up to {} runs each; their time is in the budget)",
                b.host_reruns,
                crate::runner::HOST_STALL_RUNS
            );
        }
        // Not the device's: each was sent again (a capture marks them). At the end of the
        // line, so that a page's example with the line's tail elided still matches.
        let broken = match b.line.broken_sends {
            0 => String::new(),
            n => format!("; {n} send(s) broken by this host as they left (it stalled while pacing them: a silence over t1.5 inside), sent again"),
        };
        if let Some(why) = b.no_bound {
            // Behind a Modbus TCP gateway, or on a pseudo-terminal: no line to bound by.
            let _ = writeln!(
                o,
                "budget:  {mode}: {:.1} s for {} frames; no line bound: {}{broken}",
                b.wall.as_secs_f64(),
                b.line.frames,
                why.reason()
            );
            continue;
        }
        let _ = writeln!(
            o,
            "budget:  {mode}: {:.1} s for {} frames; the line and the device need {:.1} s ({:.0}%: bytes at the character time, t3.5 before each frame, the device's response delays, its longest delay for each of {} silences){broken}",
            b.wall.as_secs_f64(),
            b.line.frames,
            b.bound.as_secs_f64(),
            b.efficiency() * 100.0,
            b.line.silences
        );
    }
    if r.kind == super::ReportKind::Fuzz {
        // Each mode's campaign in one line (cases, rate, findings): the first clause of
        // its result, which is listed in full with the passing checks (--verbose).
        for c in r
            .results
            .iter()
            .filter(|c| c.id.starts_with("fuzz.") && c.id.ends_with(".campaign"))
        {
            let mode = c.mode.map(|m| m.to_string()).unwrap_or_default();
            let _ = writeln!(o, "fuzz:    {mode}: {}", first_clause(&c.summary));
        }
    }
    let sections = r.node_summaries();
    if sections.is_empty() {
        let all: Vec<&CheckResult> = r.results.iter().collect();
        results(&mut o, r, &all, verbose);
    }
    for (node, c) in &sections {
        // A node of a monitor's -a that was never heard has its line above, and nothing
        // to list.
        if c.total == 0 && (node.is_none() || r.kind == super::ReportKind::Monitor) {
            continue;
        }
        let stopped = node
            .and_then(|n| r.device.nodes.iter().find(|x| x.address == n))
            .and_then(|i| i.stopped.as_deref());
        let _ = writeln!(
            o,
            "\n=== {}: {}{} ===",
            section_name(*node),
            counts(c, "checks"),
            stopped
                .map(|w| format!("; stopped: {w}"))
                .unwrap_or_default()
        );
        let all: Vec<&CheckResult> = r.results.iter().filter(|x| x.node == *node).collect();
        results(&mut o, r, &all, verbose);
    }
    stale_entries(&mut o, r);
    if !r.restore.is_empty() {
        let bad = r.unrestored().len();
        let unchanged = r
            .restore
            .iter()
            .filter(|x| x.restored && !x.changed)
            .count();
        let _ = writeln!(
            o,
            "\nRESTORE ({} register{} journalled: {} changed by the run, restored and verified; {} unchanged, verified{}){}",
            r.restore.len(),
            plural(r.restore.len()),
            r.restore.len() - bad - unchanged,
            unchanged,
            if bad > 0 {
                format!(", {bad} NOT RESTORED")
            } else {
                String::new()
            },
            if verbose || bad > 0 {
                ""
            } else {
                ": --verbose lists them"
            }
        );
        for x in r.restore.iter().filter(|x| verbose || !x.restored) {
            let _ = writeln!(
                o,
                "  {}{:04X}H {} {}",
                x.node
                    .map(|n| format!("node {n:02X}H "))
                    .unwrap_or_default(),
                x.register,
                match (x.restored, x.changed) {
                    (true, false) => "=  ",
                    (true, true) => "ok ",
                    _ => "NOT",
                },
                x.detail
            );
        }
    }
    o
}

/// The results of one section (the whole run, or one node, or the bus): deviations (with
/// their frames), errors, observations, skips, and the passes (`verbose`) or their count.
fn results(o: &mut String, r: &Report, list: &[&CheckResult], verbose: bool) {
    let pass = list.iter().filter(|c| c.status == Status::Pass).count();
    let section = |o: &mut String, status: Status, heading: &str, exchanges: bool| {
        // Expected results have a section of their own (with an expectations file, the
        // deviations listed here are the new ones).
        let all: Vec<&CheckResult> = list
            .iter()
            .copied()
            .filter(|c| c.status == status && !r.is_expected(c))
            .collect();
        if all.is_empty() {
            return;
        }
        let _ = writeln!(o, "\n{heading} ({})", all.len());
        // Checks that never ran because the device stopped answering say one thing: one
        // line for all of them (--verbose lists them).
        let (not_run, items): (Vec<&CheckResult>, Vec<&CheckResult>) = all
            .into_iter()
            .partition(|c| status == Status::Error && c.summary.starts_with("not run: "));
        if let Some(first) = not_run.first() {
            let _ = writeln!(
                o,
                "  {} checks {}{}",
                not_run.len(),
                first.summary,
                if verbose {
                    format!(
                        ": {}",
                        not_run
                            .iter()
                            .map(|c| c.id.as_str())
                            .collect::<Vec<_>>()
                            .join(" ")
                    )
                } else {
                    " (--verbose lists them)".to_string()
                }
            );
        }
        for c in items {
            let _ = writeln!(o, "  [{}] {}", c.id, c.title);
            let _ = writeln!(o, "      source   {}", c.source);
            if c.findings.is_empty() {
                let _ = writeln!(o, "      {:<8} {}", "result", c.summary);
            }
            for f in &c.findings {
                let label = match f.severity {
                    crate::runner::Severity::Deviation => "deviates",
                    crate::runner::Severity::Observation => "observed",
                };
                let _ = writeln!(o, "      {label:<8} {}", f.text);
            }
            if let Some(m) = r.expectation(c) {
                let _ = writeln!(
                    o,
                    "      expected {} ({}): {}",
                    m.expected.key(),
                    entry_at(r, m.line),
                    m.reason
                );
            }
            if exchanges || verbose {
                for e in &c.exchanges {
                    exchange(o, c.mode, e);
                }
            }
        }
    };
    section(
        o,
        Status::Deviation,
        if r.expect.is_some() {
            "NEW DEVIATIONS"
        } else {
            "DEVIATIONS"
        },
        true,
    );
    expected_results(o, r, list);
    section(o, Status::Error, "ERRORS", true);
    section(o, Status::Observation, "OBSERVATIONS", false);
    let skipped: Vec<&CheckResult> = list
        .iter()
        .copied()
        .filter(|c| c.status == Status::Skip)
        .collect();
    if !skipped.is_empty() {
        let _ = writeln!(o, "\nSKIPPED ({})", skipped.len());
        for c in skipped {
            let _ = writeln!(o, "  [{}] {}", c.id, c.summary);
        }
    }
    if verbose {
        section(o, Status::Pass, "PASSED", false);
    } else if pass > 0 {
        let _ = writeln!(o, "\nPASSED ({pass}): --verbose lists them");
    }
}

/// With an expectations file: the file, and how the run stands against it.
fn expect_header(o: &mut String, r: &Report) {
    let Some(e) = &r.expect else { return };
    let count = |k: MarkKind| e.marks.values().filter(|m| m.kind == k).count();
    let stale = e.stale().count();
    let _ = writeln!(
        o,
        "EXPECT:  {}: {} expected, {} new, {} unexpected pass{}{}, {} changed; {} of {} entr{} not applied{}",
        e.path,
        count(MarkKind::Expected),
        r.unexpected_findings().len(),
        r.unexpected_passes(),
        if r.unexpected_passes() == 1 { "" } else { "es" },
        if e.strict { " (strict: they fail the run)" } else { "" },
        count(MarkKind::Changed),
        stale,
        e.entries.len(),
        if e.entries.len() == 1 { "y" } else { "ies" },
        if stale > 0 { " (listed below)" } else { "" },
    );
}

/// "expect.toml:12".
fn entry_at(r: &Report, line: usize) -> String {
    match &r.expect {
        Some(e) => format!("{}:{line}", e.path),
        None => format!("line {line}"),
    }
}

/// The results an expectations file accepts, and its unexpected passes.
fn expected_results(o: &mut String, r: &Report, list: &[&CheckResult]) {
    let marked = |k: MarkKind| -> Vec<(&CheckResult, &crate::expect::Mark)> {
        list.iter()
            .filter_map(|c| r.expectation(c).filter(|m| m.kind == k).map(|m| (*c, m)))
            .filter(|(c, m)| m.kind != MarkKind::Expected || r.is_expected(c))
            .collect()
    };
    let passes = marked(MarkKind::UnexpectedPass);
    if !passes.is_empty() {
        let _ = writeln!(o, "\nUNEXPECTED PASSES ({})", passes.len());
        for (c, m) in passes {
            let _ = writeln!(
                o,
                "  [{}] UNEXPECTED PASS: expected {} ({}): {}{}",
                c.id,
                m.expected.key(),
                entry_at(r, m.line),
                m.reason,
                m.ticket
                    .as_deref()
                    .map(|t| format!(" [{t}]"))
                    .unwrap_or_default()
            );
        }
    }
    let expected = marked(MarkKind::Expected);
    if !expected.is_empty() {
        let _ = writeln!(o, "\nEXPECTED ({})", expected.len());
        for (c, m) in expected {
            let _ = writeln!(
                o,
                "  [{}] {}: {} ({}{})",
                c.id,
                c.status,
                m.reason,
                entry_at(r, m.line),
                m.ticket
                    .as_deref()
                    .map(|t| format!(", {t}"))
                    .unwrap_or_default()
            );
            let _ = writeln!(o, "      result   {}", c.summary);
        }
    }
}

/// Entries of the expectations file that did not apply: expired, matched nothing, or
/// for another device.
fn stale_entries(o: &mut String, r: &Report) {
    let Some(e) = &r.expect else { return };
    let stale: Vec<_> = e.stale().collect();
    if stale.is_empty() {
        return;
    }
    let _ = writeln!(o, "\nEXPECTATIONS NOT APPLIED ({})", stale.len());
    for x in stale {
        let why = match x.state {
            EntryState::Expired => format!(
                "EXPIRED on {} (today {}): no longer applies",
                x.entry.expires.map(|d| d.to_string()).unwrap_or_default(),
                e.today
            ),
            EntryState::Unmatched => "matched nothing in this run".to_string(),
            EntryState::OtherDevice => format!(
                "for identification {}, not this device's",
                x.entry
                    .identification
                    .map(|v| format!("{v:04X}H"))
                    .unwrap_or_default()
            ),
            EntryState::NotFound => {
                "UNEXPECTED PASS: a complete campaign did not find it again".to_string()
            }
            EntryState::Applied => String::new(),
        };
        let _ = writeln!(
            o,
            "  {}:{} {} ({}): {why}",
            e.path, x.entry.line, x.entry.target, x.entry.reason
        );
    }
}

/// "8 checks: 3 pass, 2 deviations, 1 observation, 1 skipped, 1 error".
fn counts(s: &Summary, noun: &str) -> String {
    format!(
        "{} {noun}: {} pass, {} deviation{}, {} observation{}, {} skipped, {} error{}",
        s.total,
        s.pass,
        s.deviation,
        plural(s.deviation),
        s.observation,
        plural(s.observation),
        s.skip,
        s.error,
        plural(s.error),
    )
}

/// A section of a run of several nodes: "node 05H", or the checks of the whole bus.
fn section_name(node: Option<u8>) -> String {
    match node {
        Some(n) => format!("node {n:02X}H"),
        None => "bus (broadcast and other-address checks, run once)".to_string(),
    }
}

/// In a run of several nodes: one line per node (identification, counts, why it stopped)
/// and one for the checks of the whole bus.
fn node_lines(o: &mut String, r: &Report) {
    for (node, c) in r.node_summaries() {
        let info = node.and_then(|n| r.device.nodes.iter().find(|x| x.address == n));
        let mut facts = Vec::new();
        if r.kind == super::ReportKind::Monitor {
            // A monitor reads no identification; a node of -a may not have been heard.
            let heard = r
                .monitor
                .as_ref()
                .is_some_and(|m| m.nodes.iter().any(|(a, _)| Some(*a) == node));
            if !heard {
                let _ = writeln!(
                    o,
                    "{:<10}nothing heard to or from it",
                    node.map(|n| format!("node {n:02X}H:")).unwrap_or_default()
                );
                continue;
            }
        } else if let Some(i) = info {
            facts.push(match i.identification {
                Some(v) => format!("identification {v:04X}H"),
                None => "identification not read".to_string(),
            });
            if !i.quirks.is_empty() {
                facts.push(format!("quirks: {}", i.quirks.join(" ")));
            }
        }
        let _ = writeln!(
            o,
            "{:<10}{}{}{}",
            match node {
                Some(n) => format!("node {n:02X}H:"),
                None => "bus:".to_string(),
            },
            if facts.is_empty() {
                String::new()
            } else {
                format!("{}; ", facts.join(", "))
            },
            counts(&c, "checks"),
            match info.and_then(|i| i.stopped.as_deref()) {
                Some(why) => format!("; stopped: {why}"),
                None => String::new(),
            }
        );
    }
}

fn plural(n: usize) -> &'static str {
    if n == 1 {
        ""
    } else {
        "s"
    }
}

fn exchange(o: &mut String, mode: Option<Mode>, e: &ExchangeRecord) {
    let ascii = mode == Some(Mode::Ascii);
    let show = |b: &[u8]| {
        if ascii {
            format!("{:?}", String::from_utf8_lossy(b))
        } else {
            Hex(b).to_string()
        }
    };
    let _ = writeln!(o, "      request  {}", show(&e.request));
    let _ = writeln!(o, "      model    {}", e.predicted);
    if let Some(x) = &e.expected {
        let _ = writeln!(o, "      expected {}", show(x));
    }
    if e.received.is_empty() && e.reply.is_none() && !e.actual.is_empty() {
        // A gate case: the adapter's answer.
        let _ = writeln!(o, "      answer   {}", e.actual);
    } else {
        let received = if e.received.is_empty() {
            "(nothing)".to_string()
        } else {
            show(&e.received)
        };
        let _ = writeln!(o, "      received {received}");
    }
    if let (Some(x), Some(reply)) = (&e.expected, &e.reply) {
        let diffs = diff_positions(x, reply);
        if !diffs.is_empty() {
            if reply != &e.received {
                let _ = writeln!(o, "      reply    {}", show(reply));
            }
            // Mark the differing bytes under the reply (hex: 3 columns a byte; ASCII: one
            // column a character after the opening quote).
            let width = if ascii { 1 } else { 3 };
            let offset = if ascii { 1 } else { 0 };
            let len = reply.len().max(x.len());
            let mut marks = vec![b' '; offset + len * width];
            for i in diffs {
                let at = offset + i * width;
                for k in 0..width.min(2) {
                    if let Some(m) = marks.get_mut(at + k) {
                        *m = b'^';
                    }
                }
            }
            let _ = writeln!(
                o,
                "               {}",
                String::from_utf8_lossy(&marks).trim_end()
            );
        }
    }
    if let Some(l) = e.latency {
        let _ = writeln!(o, "      latency  {:.1} ms", l.as_secs_f64() * 1000.0);
    }
}

#[cfg(test)]
mod tests {
    use super::first_clause;

    #[test]
    fn the_first_clause_skips_semicolons_in_parentheses() {
        assert_eq!(
            first_clause("30 cases in 0.1 s (486.4 cases/s; no bound (x)), 0 finding signature(s); timing damage not sent; brisk"),
            "30 cases in 0.1 s (486.4 cases/s; no bound (x)), 0 finding signature(s)"
        );
        assert_eq!(first_clause("no answer"), "no answer");
        assert_eq!(first_clause("a) b; c"), "a) b");
    }
}
