//! Finding the devices on a line: which line settings, mode and node addresses answer.
//!
//! A scan sends reads only (03H, one register: [`probe::ID_REGISTER`], the manuals'
//! identification register) and listens for a short window after each
//! ([`probe::Windows`]: the response time, two character times and the link's slack).
//!
//! Strategy, in order:
//! 1. Every setting ([`settings::Search`], most likely first) with the first addresses
//!    (the manuals' default node address 01H): most drives are found here, at a cost of
//!    one try a setting.
//! 2. The rest of the address range, tier by tier of baud rates ([`settings::tier`]):
//!    for each address, every setting of the tier (the common speeds first), so that a
//!    device at a low address is found early whatever its setting.
//! 3. Garbage (bytes that deframe to no valid frame) after a request means a device
//!    talks at another setting: that setting is dropped for the rest of the scan, and
//!    the address that drew the garbage is tried next at every setting left.
//! 4. Once a valid frame is heard, the setting is the line's (the devices of one bus
//!    share it): the rest of the address range is swept at that setting only, and the
//!    scan ends.
//!
//! Through a gateway ([`link::ScanLink::searchable`] false) the line is set in the
//! gateway: only the addresses (and the modes, where the gateway passes frames
//! through) are searched.

pub mod link;
pub mod probe;
pub mod report;
pub mod settings;

use std::collections::VecDeque;
use std::sync::atomic::{AtomicBool, Ordering};
use std::time::{Duration, Instant};

use crate::codec::timing::LineSettings;
use crate::model::{DriveModel, MODELS};
use crate::transport::TransportError;

use link::ScanLink;
use probe::{request, sift, Answer, Heard, Windows};
use settings::Setting;

/// What to scan.
#[derive(Debug, Clone)]
pub struct ScanConfig {
    /// Settings, most likely first.
    pub settings: Vec<Setting>,
    /// The node addresses (the range asked for), in order.
    pub addresses: Vec<u8>,
    /// Addresses tried at every setting before the rest of the range (the manuals'
    /// default node address).
    pub first: Vec<u8>,
    /// The device's response time (the manuals': 10 ms).
    pub response: Duration,
    /// A reply window given instead of the derived one.
    pub reply_window: Option<Duration>,
}

/// A device found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Found {
    /// The node address that answered.
    pub address: u8,
    /// The node address asked (differs for a device that answers for others).
    pub asked: u8,
    /// The setting.
    pub setting: Setting,
    /// What it answered.
    pub answer: Answer,
    /// The reply's bytes.
    pub frame: Vec<u8>,
    /// Whether the request came back first (local echo of a 2-wire adapter).
    pub echo: bool,
    /// Models whose identification value this is (documented or this suite's
    /// simulator's), with the basis.
    pub models: Vec<String>,
}

/// What became of a setting.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// Not tried (the scan ended first).
    Untried,
    /// Tried; nothing came back.
    Silent,
    /// Bytes that made no frame came back after a request to `address`: a device talks
    /// at another setting; dropped.
    Garbage {
        /// The address asked.
        address: u8,
        /// The bytes (at most 64).
        bytes: Vec<u8>,
    },
    /// A device answered.
    Answered,
    /// Not tried further: another setting answered.
    Dropped,
}

/// One setting's share of the scan.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct SettingResult {
    /// The setting.
    pub setting: Setting,
    /// Tries made at it.
    pub tries: u32,
    /// What became of it.
    pub verdict: Verdict,
    /// Its windows.
    pub windows: Windows,
}

/// The result of a scan.
#[derive(Debug, Clone)]
pub struct ScanReport {
    /// The link.
    pub link: String,
    /// Whether the line settings were searched (false: a gateway).
    pub searchable: bool,
    /// Devices found.
    pub found: Vec<Found>,
    /// Every setting, in the order of the search.
    pub settings: Vec<SettingResult>,
    /// Tries made.
    pub tries: u64,
    /// Addresses in the range.
    pub addresses: usize,
    /// Time taken.
    pub elapsed: Duration,
    /// Why it ended early, if it did ("interrupted").
    pub stopped: Option<String>,
    /// The response time the windows assume.
    pub response: Duration,
    /// The link's slack.
    pub slack: Duration,
}

/// Progress of a scan, in microseconds of planned wire time (tries at slow settings
/// weigh more), so that an ETA is right.
#[derive(Debug, Clone, Copy)]
pub struct Progress<'a> {
    /// Wire time of the tries made.
    pub done_us: u64,
    /// Wire time of every try planned (shrinks when settings are dropped).
    pub total_us: u64,
    /// The try being made.
    pub setting: &'a Setting,
    /// Its address.
    pub address: u8,
    /// Devices found so far.
    pub found: usize,
}

/// The models whose identification register holds `value`.
pub fn models_with_identification(value: u16) -> Vec<String> {
    let mut out = Vec::new();
    for id in MODELS {
        let Some(ident) = DriveModel::builtin(id).ok().and_then(|m| m.identification) else {
            continue;
        };
        if ident.register != Some(probe::ID_REGISTER) {
            continue;
        }
        if ident.value == Some(value) {
            out.push(format!("{id} (the manual's value)"));
        } else if ident.value.is_none() && ident.simulated == value {
            out.push(format!(
                "{id} (this suite's simulator; the manual gives no value)"
            ));
        }
    }
    out
}

enum Outcome {
    Silent,
    Garbage(Vec<u8>),
    Answered(Vec<Heard>, bool),
}

fn try_one(
    link: &mut dyn ScanLink,
    setting: &Setting,
    w: &Windows,
    address: u8,
    slack: Duration,
    current: &mut Option<(LineSettings, crate::codec::Mode)>,
) -> Result<Outcome, TransportError> {
    if current.map(|c| c.0) != Some(setting.line) {
        link.set_line(&setting.line)?;
    }
    if *current != Some((setting.line, setting.mode)) {
        link.setting(setting.mode, &setting.line);
        *current = Some((setting.line, setting.mode));
    }
    let req = request(setting.mode, address);
    let t = link.transport();
    t.send(&req)?;
    let sent = t.sent_at().unwrap_or_else(Instant::now);
    let mut heard: Vec<u8> = Vec::new();
    let mut chunk = [0u8; 256];
    let first_deadline = sent + w.reply;
    let mut last_rx = None;
    loop {
        let now = Instant::now();
        if now >= first_deadline {
            break;
        }
        let n = t.recv(&mut chunk, first_deadline - now)?;
        if n > 0 {
            heard.extend_from_slice(&chunk[..n]);
            last_rx = Some(Instant::now());
            break;
        }
    }
    let Some(first) = last_rx else {
        return Ok(Outcome::Silent);
    };
    // The rest of the reply: until the whole reply could have come, or the line has been
    // quiet for t3.5 and the slack after the last byte.
    let quiet = w.t3_5 + slack;
    let end = first + w.rest;
    let mut last = first;
    while heard.len() < 1024 {
        let now = Instant::now();
        if now >= end || now.duration_since(last) >= quiet {
            break;
        }
        let wait = (end - now).min(quiet.saturating_sub(now.duration_since(last)));
        let n = t.recv(&mut chunk, wait.max(Duration::from_micros(100)))?;
        if n > 0 {
            heard.extend_from_slice(&chunk[..n]);
            last = Instant::now();
        }
    }
    let s = sift(setting.mode, &req, &heard);
    if !s.frames.is_empty() {
        return Ok(Outcome::Answered(s.frames, s.echo));
    }
    if s.garbage.is_empty() {
        // Only the local echo of the request came back.
        return Ok(Outcome::Silent);
    }
    Ok(Outcome::Garbage(s.garbage))
}

/// Runs a scan on `link`. `progress` is told each try before it is made. A transport
/// error ends the scan with that error (the port went away).
pub fn scan(
    link: &mut dyn ScanLink,
    config: &ScanConfig,
    stop: &AtomicBool,
    progress: &mut dyn FnMut(Progress<'_>),
) -> Result<ScanReport, TransportError> {
    let t0 = Instant::now();
    let slack = link.slack();
    let n = config.settings.len();
    let windows: Vec<Windows> = config
        .settings
        .iter()
        .map(|s| Windows::of(s, config.response, slack, config.reply_window))
        .collect();
    let cost = |s: usize| u64::try_from(windows[s].bound().as_micros()).unwrap_or(u64::MAX);
    let mut results: Vec<SettingResult> = config
        .settings
        .iter()
        .zip(&windows)
        .map(|(s, w)| SettingResult {
            setting: *s,
            tries: 0,
            verdict: Verdict::Untried,
            windows: *w,
        })
        .collect();

    // The plan: the first addresses at every setting, then the rest tier by tier.
    let first: Vec<u8> = config
        .first
        .iter()
        .copied()
        .filter(|a| config.addresses.contains(a))
        .collect();
    let mut queue: VecDeque<(usize, u8)> = VecDeque::new();
    for s in 0..n {
        for &a in &first {
            queue.push_back((s, a));
        }
    }
    let mut tiers: Vec<usize> = config
        .settings
        .iter()
        .map(|s| settings::tier(s.line.baud))
        .collect();
    tiers.sort_unstable();
    tiers.dedup();
    for tier in tiers {
        for &a in config.addresses.iter().filter(|a| !first.contains(a)) {
            for s in 0..n {
                if settings::tier(config.settings[s].line.baud) == tier {
                    queue.push_back((s, a));
                }
            }
        }
    }
    let mut total_us: u64 = queue.iter().map(|&(s, _)| cost(s)).sum();
    let mut done_us: u64 = 0;
    let mut tried = vec![[false; 256]; n];
    let mut dead = vec![false; n];
    let mut locked: Option<usize> = None;
    let mut found: Vec<Found> = Vec::new();
    let mut tries = 0u64;
    let mut stopped = None;
    let mut current: Option<(LineSettings, crate::codec::Mode)> = None;

    while let Some((s, a)) = queue.pop_front() {
        if dead[s] || tried[s][usize::from(a)] || locked.is_some_and(|l| l != s) {
            continue;
        }
        if stop.load(Ordering::Relaxed) {
            stopped = Some("interrupted".to_string());
            break;
        }
        progress(Progress {
            done_us,
            total_us,
            setting: &config.settings[s],
            address: a,
            found: found.len(),
        });
        tried[s][usize::from(a)] = true;
        tries += 1;
        results[s].tries += 1;
        let outcome = try_one(
            link,
            &config.settings[s],
            &windows[s],
            a,
            slack,
            &mut current,
        )?;
        done_us += cost(s);
        match outcome {
            Outcome::Silent => {
                if results[s].verdict == Verdict::Untried {
                    results[s].verdict = Verdict::Silent;
                }
            }
            Outcome::Garbage(bytes) => {
                if locked.is_some() {
                    // At the line's setting, garbage is noise on the line, not a sign.
                    continue;
                }
                dead[s] = true;
                results[s].verdict = Verdict::Garbage { address: a, bytes };
                // A device talked after a request to `a`: try `a` next at every setting
                // left.
                for other in (0..n).rev() {
                    if !dead[other] && !tried[other][usize::from(a)] {
                        queue.push_front((other, a));
                    }
                }
                total_us = done_us
                    + queue
                        .iter()
                        .filter(|&&(q, b)| !dead[q] && !tried[q][usize::from(b)])
                        .map(|&(q, _)| cost(q))
                        .sum::<u64>();
            }
            Outcome::Answered(frames, echo) => {
                results[s].verdict = Verdict::Answered;
                for h in frames {
                    if found
                        .iter()
                        .any(|f| f.address == h.address && f.setting == config.settings[s])
                    {
                        continue;
                    }
                    let models = match h.answer {
                        Answer::Value(v) => models_with_identification(v),
                        _ => Vec::new(),
                    };
                    found.push(Found {
                        address: h.address,
                        asked: a,
                        setting: config.settings[s],
                        answer: h.answer,
                        frame: h.frame,
                        echo,
                        models,
                    });
                }
                if locked.is_none() {
                    // The line's setting: sweep the rest of the range here, and end.
                    locked = Some(s);
                    queue = config
                        .addresses
                        .iter()
                        .filter(|&&b| !tried[s][usize::from(b)])
                        .map(|&b| (s, b))
                        .collect();
                    total_us = done_us + queue.iter().map(|&(q, _)| cost(q)).sum::<u64>();
                    for (i, r) in results.iter_mut().enumerate() {
                        if i != s && r.verdict == Verdict::Untried {
                            r.verdict = Verdict::Dropped;
                        }
                    }
                }
            }
        }
    }
    found.sort_by_key(|f| f.address);
    Ok(ScanReport {
        link: link.describe(),
        searchable: link.searchable(),
        found,
        settings: results,
        tries,
        addresses: config.addresses.len(),
        elapsed: t0.elapsed(),
        stopped,
        response: config.response,
        slack,
    })
}
