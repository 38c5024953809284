//! The monitor's verdicts against `check`'s, exchange by exchange: `check`'s JSON report
//! on one side, the monitor's `--log` (one JSON line per exchange) on the other, both of
//! the same traffic (a bus the monitor listened to, or a capture of the run).

use serde_json::Value;

/// Drive-side kinds that are about timing, which `check` judges over a whole mode (its
/// response-time and line-timing checks), not per exchange; and the model's decisions.
pub const TIMING_KINDS: &[&str] = &[
    "drive.early-reply",
    "drive.late-reply",
    "drive.gap-in-reply",
    "drive.decision",
];

/// Finds every exchange of `check` in `heard`, in order (the same request and what came
/// back: the runner's own probes between checks are heard too, and are not in the
/// report), and asserts that for each the two agree on whether the device's answer
/// differs from the manual's: check, differing bytes, an answer where none is due or none
/// where one is, bytes that are no reply; the monitor, a finding on the drive's side that
/// is not about timing. Checks named in `apart` (id, reason) may disagree. Returns how
/// many exchanges agreed and how many were judged apart.
pub fn exchanges(
    who: &str,
    check: &Value,
    heard: &[Value],
    apart: &[(&str, &str)],
) -> (usize, usize) {
    exchanges_on_bus(who, check, heard, apart, &[])
}

/// [`exchanges`] of traffic on an emulated bus whose log (`bus_log`, its records) says
/// where the host handed bytes over late. An exchange the two judge apart, or that the
/// monitor's log lacks, while the host handed the bytes of its request or its reply over
/// t1.5 or more late (a gap inside a frame that the line did not have, which splits or
/// damages the frame the listener hears) is the host's, not a disagreement: it is noted
/// with its `late` record (each record excuses one exchange), and at most one exchange in
/// ten (rounded up) may be excused so.
pub fn exchanges_on_bus(
    who: &str,
    check: &Value,
    heard: &[Value],
    apart: &[(&str, &str)],
    bus_log: &[Value],
) -> (usize, usize) {
    let t1_5 = super::bus_silences(bus_log).map_or(u64::MAX, |s| s.0);
    // Each late record excuses one exchange at most: a run repeats its requests, and one
    // record must not excuse every exchange with the same bytes.
    let mut late: Vec<Option<LateFrame>> =
        late_frames(bus_log, t1_5).into_iter().map(Some).collect();
    let mut host_late = |request: &str, received: &str| -> Option<String> {
        late.iter_mut()
            .find(|l| {
                l.as_ref().is_some_and(|l| {
                    l.request == request && (received.is_empty() || l.reply == received)
                })
            })
            .and_then(Option::take)
            .map(|l| l.record)
    };
    let mut excused = 0usize;
    let (mut agree, mut judged_apart, mut next) = (0, 0, 0);
    let mut disagree = Vec::new();
    for c in check["checks"].as_array().unwrap() {
        let id = c["id"].as_str().unwrap();
        for e in c["exchanges"].as_array().unwrap() {
            let request = e["request"].as_str().unwrap();
            let received = e["received"].as_str().unwrap_or("");
            // The same request and what came back: the runner's own probes between
            // checks (a read of 2520H) are heard too, and are not in the report.
            let Some(k) = heard[next..]
                .iter()
                .position(|h| h["request"] == request && h["received"] == received)
            else {
                if let Some(record) = host_late(request, received) {
                    excused += 1;
                    super::note(&format!(
                        "{who}: {id}'s request {request} -> {received} is not in the monitor's log as such: the host handed it over late ({record})"
                    ));
                    continue;
                }
                let same: Vec<String> = heard[next..]
                    .iter()
                    .filter(|h| h["request"] == request)
                    .map(|h| format!("{} -> {} {}", h["request"], h["received"], h["issues"]))
                    .collect();
                let around: Vec<String> = heard
                    [next.saturating_sub(2)..(next + 6).min(heard.len())]
                    .iter()
                    .map(|h| {
                        format!(
                            "{} -> {} {} {}",
                            h["request"], h["received"], h["issues"], h["notes"]
                        )
                    })
                    .collect();
                panic!(
                    "{who}: {id}'s request {request} -> {received} is not in the monitor's log after line {next}; the same request there: {same:#?}; the lines there: {around:#?}"
                );
            };
            let h = &heard[next + k];
            next += k + 1;
            // Bytes that differ, an answer where none is due, or none where one is.
            let silence_due = e["predicted"].as_str().unwrap().starts_with("no reply");
            let check_differs = !e["differs_at"].as_array().unwrap().is_empty()
                || silence_due != received.is_empty()
                || (!received.is_empty() && e["reply"].is_null());
            let monitor_differs = h["issues"].as_array().unwrap().iter().any(|k| {
                let k = k.as_str().unwrap();
                k.starts_with("drive.") && !TIMING_KINDS.contains(&k)
            });
            if check_differs == monitor_differs {
                agree += 1;
            } else if apart.iter().any(|(i, _)| *i == id) {
                judged_apart += 1;
            } else if let Some(record) = host_late(request, received) {
                excused += 1;
                super::note(&format!(
                    "{who}: {id}: {request} -> {received} judged apart while the host handed it over late ({record}): the monitor heard {}",
                    h["issues"]
                ));
            } else {
                disagree.push(format!(
                    "{id}: {request} -> {received}: check {}, monitor {}",
                    if check_differs {
                        "differs"
                    } else {
                        "agrees with the manual"
                    },
                    h["issues"]
                ));
                // The lines before it, as the monitor heard them.
                for e in &heard[next.saturating_sub(7)..next] {
                    disagree.push(format!(
                        "    heard {} -> {} {} {}",
                        e["request"], e["received"], e["issues"], e["notes"]
                    ));
                }
            }
        }
    }
    assert_eq!(disagree, Vec::<String>::new(), "{who}");
    // One in ten, rounded up (so one of a few).
    assert!(
        excused <= (agree + excused).div_ceil(10),
        "{who}: {excused} exchanges excused by the host's lateness, of {}: more than one in ten",
        agree + excused
    );
    (agree, judged_apart)
}

/// A `late` record of a bus log, with the exchange its characters fell in.
pub struct LateFrame {
    /// The master's frame of the exchange (hex).
    pub request: String,
    /// The frame after it: its reply, or "" where none.
    pub reply: String,
    /// Whether the late characters fell in the master's frame (and so may have split
    /// the request), rather than in the reply.
    pub in_request: bool,
    /// The `late` record.
    pub record: String,
}

/// The frames of a bus log (`bus_log`, its records) whose bytes the host handed over
/// `min_us` or more late, one per `late` record that falls in a frame: the master's frame
/// (`from` "master") at or before it, and the frame after that.
pub fn late_frames(bus_log: &[Value], min_us: u64) -> Vec<LateFrame> {
    let char_us = bus_log
        .iter()
        .find(|r| r["event"] == "start")
        .and_then(|r| r["char_us"].as_u64())
        .unwrap_or(0);
    let tx: Vec<&Value> = bus_log.iter().filter(|r| r["event"] == "tx").collect();
    let span = |r: &Value| -> (u64, u64) {
        let at = r["at_us"].as_array();
        let first = at.and_then(|a| a.first()?.as_u64()).unwrap_or(0);
        let last = at.and_then(|a| a.last()?.as_u64()).unwrap_or(first);
        (first, last + char_us)
    };
    let mut out = Vec::new();
    for late in bus_log
        .iter()
        .filter(|r| r["event"] == "late" && r["by_us"].as_u64().is_some_and(|b| b >= min_us))
    {
        let t = late["t_us"].as_u64().unwrap_or(0);
        let Some(i) = tx.iter().position(|r| {
            let (a, b) = span(r);
            (a..=b).contains(&t)
        }) else {
            continue;
        };
        // The exchange the frame is in: the master's frame at or before it, and the one
        // after that.
        let Some(m) = (0..=i).rev().find(|&j| tx[j]["from"] == "master") else {
            continue;
        };
        let hex = |r: Option<&&Value>| r.and_then(|r| r["hex"].as_str()).unwrap_or("").to_string();
        let reply = tx.get(m + 1).filter(|r| r["from"] != "master");
        out.push(LateFrame {
            request: hex(tx.get(m)),
            reply: hex(reply),
            in_request: i == m,
            record: late.to_string(),
        });
    }
    out
}
