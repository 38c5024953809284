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
    (agree, judged_apart)
}
