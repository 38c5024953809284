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
//! 5. At the line's setting, an address that drew no valid frame is asked again, up to
//!    [`ScanConfig::retries`] more times, after the sweep: one lost or damaged reply
//!    (noise, a collision, a host that stalled) is not a missing device. Bytes that made
//!    no frame there are kept as [`Noise`], never dropped unsaid.
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
    /// How many more times an address that drew no valid frame at the line's setting is
    /// asked (after the sweep).
    pub retries: u32,
}

/// Bytes that made no frame, heard at the line's setting after a request (noise on the
/// line, a collision, or a reply damaged on its way).
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Noise {
    /// The address asked.
    pub address: u8,
    /// The bytes (at most [`probe::GARBAGE_KEPT`]).
    pub bytes: Vec<u8>,
}

/// How many times one try's request is sent again after this host broke it.
pub const HOST_RESENDS: u32 = 3;

/// The [`Noise`] records kept (the rest are counted in [`ScanReport::noise_more`]).
pub const NOISE_KEPT: usize = 32;

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
    /// Of them, tries that asked an address again.
    pub retried: u32,
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
    /// Of the tries, those that asked an address again (see [`ScanConfig::retries`]).
    pub retried: u64,
    /// Addresses found only when asked again.
    pub found_on_retry: Vec<u8>,
    /// Bytes that made no frame at the line's setting.
    pub noise: Vec<Noise>,
    /// Noise records not kept (beyond [`NOISE_KEPT`]).
    pub noise_more: u64,
    /// Requests sent again because this host broke them while pacing them onto a
    /// pseudo-terminal (not tries: no device saw them whole).
    pub host_resends: u64,
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
    host_resends: &mut u64,
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
    // A request this host broke while pacing it onto a pseudo-terminal (a stall over
    // t1.5 between two of its characters) is no try: a device drops it. Whatever comes
    // back within a try's time is drained, and the request is sent again.
    let mut resent = 0;
    while t.send_was_broken() && resent < HOST_RESENDS {
        resent += 1;
        *host_resends += 1;
        let end = Instant::now() + w.reply + w.rest;
        let mut chunk = [0u8; 256];
        loop {
            let now = Instant::now();
            if now >= end {
                break;
            }
            t.recv(&mut chunk, end - now)?;
        }
        t.send(&req)?;
    }
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
            retried: 0,
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
    let mut retried = 0u64;
    // Retries planned for each address at the line's setting, in all and not yet made.
    let mut asked_again = [0u32; 256];
    let mut pending = [0u32; 256];
    let mut found_on_retry: Vec<u8> = Vec::new();
    let mut noise: Vec<Noise> = Vec::new();
    let mut noise_more = 0u64;
    let mut host_resends = 0u64;
    let mut stopped = None;
    let mut current: Option<(LineSettings, crate::codec::Mode)> = None;

    while let Some((s, a)) = queue.pop_front() {
        if dead[s] || locked.is_some_and(|l| l != s) {
            continue;
        }
        // An address already tried is asked again only as a retry planned for it.
        let again = tried[s][usize::from(a)];
        if again {
            if locked != Some(s) || pending[usize::from(a)] == 0 {
                continue;
            }
            pending[usize::from(a)] -= 1;
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
        if again {
            retried += 1;
            results[s].retried += 1;
        }
        let outcome = try_one(
            link,
            &config.settings[s],
            &windows[s],
            a,
            slack,
            &mut current,
            &mut host_resends,
        )?;
        done_us += cost(s);
        // At the line's setting, an address that drew no valid frame is asked again
        // after the sweep (at most `retries` more times).
        let mut ask_again = |queue: &mut VecDeque<(usize, u8)>, total_us: &mut u64| {
            if locked == Some(s) && asked_again[usize::from(a)] < config.retries {
                asked_again[usize::from(a)] += 1;
                pending[usize::from(a)] += 1;
                queue.push_back((s, a));
                *total_us += cost(s);
            }
        };
        match outcome {
            Outcome::Silent => {
                if results[s].verdict == Verdict::Untried {
                    results[s].verdict = Verdict::Silent;
                }
                ask_again(&mut queue, &mut total_us);
            }
            Outcome::Garbage(bytes) => {
                if locked.is_some() {
                    // At the line's setting, garbage is noise on the line (or a reply
                    // damaged on its way), not a sign of another setting: kept, and the
                    // address asked again.
                    if noise.len() < NOISE_KEPT {
                        noise.push(Noise { address: a, bytes });
                    } else {
                        noise_more += 1;
                    }
                    ask_again(&mut queue, &mut total_us);
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
                    if again {
                        found_on_retry.push(h.address);
                    }
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
                    // The addresses tried here before it was known to be the line's
                    // were silent (garbage would have dropped the setting): they are
                    // asked again too, after the sweep.
                    if config.retries > 0 {
                        for &b in &config.addresses {
                            if tried[s][usize::from(b)] && b != a {
                                asked_again[usize::from(b)] += 1;
                                pending[usize::from(b)] += 1;
                                queue.push_back((s, b));
                            }
                        }
                    }
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
        retried,
        found_on_retry,
        noise,
        noise_more,
        host_resends,
        addresses: config.addresses.len(),
        elapsed: t0.elapsed(),
        stopped,
        response: config.response,
        slack,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::timing::Parity;
    use crate::codec::{frame_of_body, Mode};
    use crate::transport::{LinkKind, Transport};

    /// A line whose devices answer at once, from a script: `lost` replies to an address
    /// are lost (silence) and `damaged` come back with their CRC broken, before it
    /// answers whole.
    struct Scripted {
        present: Vec<u8>,
        lost: Vec<u8>,
        damaged: Vec<u8>,
        asked: Vec<u8>,
        pending: Vec<u8>,
        /// Sends this host breaks while pacing them (a device drops them).
        broken: Vec<u8>,
        last_broken: bool,
    }

    impl Transport for Scripted {
        fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
            let a = bytes[0];
            self.asked.push(a);
            self.last_broken = false;
            if let Some(i) = self.broken.iter().position(|&x| x == a) {
                self.broken.remove(i);
                self.last_broken = true;
                return Ok(());
            }
            if !self.present.contains(&a) {
                return Ok(());
            }
            if let Some(i) = self.lost.iter().position(|&x| x == a) {
                self.lost.remove(i);
                return Ok(());
            }
            let mut reply = frame_of_body(Mode::Rtu, &[a, 0x03, 0x02, 0x05, 0x10]).unwrap();
            if let Some(i) = self.damaged.iter().position(|&x| x == a) {
                self.damaged.remove(i);
                let last = reply.len() - 1;
                reply[last] ^= 0xFF;
            }
            self.pending = reply;
            Ok(())
        }
        fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
            if self.pending.is_empty() {
                std::thread::sleep(timeout.min(Duration::from_millis(1)));
                return Ok(0);
            }
            let n = self.pending.len().min(buf.len());
            buf[..n].copy_from_slice(&self.pending[..n]);
            self.pending.drain(..n);
            Ok(n)
        }
        fn discard_input(&mut self) -> Result<(), TransportError> {
            self.pending.clear();
            Ok(())
        }
        fn describe(&self) -> String {
            "scripted".into()
        }
        fn kind(&self) -> LinkKind {
            LinkKind::Memory
        }
        fn line_timing(&self) -> Option<LineSettings> {
            None
        }
        fn send_was_broken(&self) -> bool {
            self.last_broken
        }
    }

    impl ScanLink for Scripted {
        fn set_line(&mut self, _line: &LineSettings) -> Result<(), TransportError> {
            Ok(())
        }
        fn transport(&mut self) -> &mut dyn Transport {
            self
        }
        fn searchable(&self) -> bool {
            true
        }
        fn slack(&self) -> Duration {
            Duration::from_millis(1)
        }
        fn describe(&self) -> String {
            "scripted".into()
        }
    }

    fn line(present: &[u8], lost: &[u8], damaged: &[u8]) -> Scripted {
        Scripted {
            present: present.to_vec(),
            lost: lost.to_vec(),
            damaged: damaged.to_vec(),
            asked: Vec::new(),
            pending: Vec::new(),
            broken: Vec::new(),
            last_broken: false,
        }
    }

    fn config(retries: u32) -> ScanConfig {
        ScanConfig {
            settings: vec![Setting {
                line: LineSettings::new(9600, 8, Parity::Even, 1),
                mode: Mode::Rtu,
            }],
            addresses: (1..=6).collect(),
            first: vec![1],
            response: Duration::from_millis(1),
            reply_window: Some(Duration::from_millis(5)),
            retries,
        }
    }

    fn found(r: &ScanReport) -> Vec<u8> {
        r.found.iter().map(|f| f.address).collect()
    }

    #[test]
    fn a_lost_reply_is_asked_again_after_the_sweep_and_found() {
        let mut l = line(&[1, 2, 5], &[2], &[]);
        let r = scan(&mut l, &config(1), &AtomicBool::new(false), &mut |_| {}).unwrap();
        assert_eq!(found(&r), [1, 2, 5]);
        assert_eq!(r.found_on_retry, [2]);
        // The sweep, then each silent address once more (2, 3, 4, 6), in that order.
        assert_eq!(l.asked, [1, 2, 3, 4, 5, 6, 2, 3, 4, 6]);
        assert_eq!((r.tries, r.retried), (10, 4));
        assert_eq!((r.settings[0].tries, r.settings[0].retried), (10, 4));
        assert!(report::text(&r).contains("(6 of 6 addresses a setting at most)"));
        // Without retries the lost reply is a missing device: what the option is for.
        let mut l = line(&[1, 2, 5], &[2], &[]);
        let r = scan(&mut l, &config(0), &AtomicBool::new(false), &mut |_| {}).unwrap();
        assert_eq!(found(&r), [1, 5]);
        assert_eq!((r.tries, r.retried), (6, 0));
    }

    #[test]
    fn a_damaged_reply_at_the_line_setting_is_kept_as_noise_and_asked_again() {
        let mut l = line(&[1, 2, 5], &[], &[2, 2]);
        let r = scan(&mut l, &config(2), &AtomicBool::new(false), &mut |_| {}).unwrap();
        assert_eq!(found(&r), [1, 2, 5]);
        assert_eq!(r.found_on_retry, [2]);
        assert_eq!(r.noise.len(), 2, "{:?}", r.noise);
        assert!(r.noise.iter().all(|n| n.address == 2 && n.bytes.len() == 7));
        // The setting stays the line's: damage there is not a sign of another setting.
        assert_eq!(r.settings[0].verdict, Verdict::Answered);
        let text = report::text(&r);
        assert!(
            text.contains("after a read of node 02H: 02 03 02 05 10"),
            "{text}"
        );
        assert!(text.contains("found only then: 02H"), "{text}");
    }

    #[test]
    fn a_silent_first_address_is_asked_again_once_the_line_setting_is_known() {
        // Node 1's reply is lost before any device has answered: once node 2 fixes the
        // line's setting, node 1 is asked again.
        let mut l = line(&[1, 2], &[1], &[]);
        let r = scan(&mut l, &config(1), &AtomicBool::new(false), &mut |_| {}).unwrap();
        assert_eq!(found(&r), [1, 2]);
        assert_eq!(r.found_on_retry, [1]);
    }

    #[test]
    fn a_request_this_host_broke_is_sent_again_and_is_no_try() {
        let mut l = line(&[1, 2, 5], &[], &[]);
        l.broken = vec![2, 2];
        let r = scan(&mut l, &config(0), &AtomicBool::new(false), &mut |_| {}).unwrap();
        assert_eq!(found(&r), [1, 2, 5]);
        assert_eq!(l.asked, [1, 2, 2, 2, 3, 4, 5, 6]);
        assert_eq!((r.tries, r.host_resends), (6, 2));
        assert!(report::text(&r).contains("sent again: 2 requests this host broke"));
        // A host that breaks every send gives up after HOST_RESENDS: the try is silent.
        let mut l = line(&[1, 2], &[], &[]);
        l.broken = vec![2; 10];
        let r = scan(&mut l, &config(0), &AtomicBool::new(false), &mut |_| {}).unwrap();
        assert_eq!(found(&r), [1]);
        assert_eq!(r.host_resends, u64::from(HOST_RESENDS));
    }
}
