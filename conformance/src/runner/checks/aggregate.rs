//! Checks over every exchange of a mode: response time, line timing, exception codes.

use std::time::Duration;

use super::*;

pub(super) fn aggregates(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    match (
        model.limits.response_time_ms,
        &model.limits.response_time_fact,
    ) {
        (Some(stated), Some(fact)) => response_time(model, m, stated, fact, out),
        _ => out.push(undescribed_field(
            model,
            format!("{m}.response-time"),
            "Response time of every reply of this mode against the description's".to_string(),
            "limits.response_time_ms",
        )),
    }
    timing_and_codes(model, m, out);
}

fn response_time(model: &DriveModel, m: &str, stated: u64, fact: &Fact, out: &mut Vec<Check>) {
    out.push(check(
        format!("{m}.response-time"),
        format!("Response time of every reply of this mode against the manual's {stated} ms"),
        cite(model, fact),
        false,
        false,
        move |ctx| {
            if ctx.latencies.is_empty() {
                return Ok(Verdict::skip("no replies were measured"));
            }
            let mut l = ctx.latencies.clone();
            l.sort();
            let median = l[l.len() / 2];
            let max = l[l.len() - 1];
            // Below 4800 baud t3.5 is longer than the manuals' 10 ms: no reply may start
            // sooner, so t3.5 is the response time a drive can keep there.
            let line = ctx.line_timing();
            let manual = ctx.model.response_time_on(line.as_ref());
            // The first byte of a reply is received one character time after it starts
            // (a UART hands over a byte after its stop bit).
            let first_char = line.map_or(Duration::ZERO, |l| Duration::from_micros(l.char_time_us()));
            let limit = manual + first_char + ctx.opts.response_allowance;
            let ms = |d: Duration| d.as_secs_f64() * 1000.0;
            let stats = format!(
                "median {:.1} ms, max {:.1} ms over {} replies (manual: {} ms{}; allowance for host and adapter {} ms)",
                ms(median),
                ms(max),
                l.len(),
                stated,
                if manual.as_millis() > u128::from(stated) {
                    format!(", t3.5 on this line: {:.1} ms", ms(manual))
                } else {
                    String::new()
                },
                ctx.opts.response_allowance.as_millis()
            );
            // Through a gateway every delay holds the gateway's serial transmission of
            // request and reply and its own processing: the device's share cannot be told.
            if let Some(why) = ctx.frames_only() {
                return Ok(Verdict::skip(format!(
                    "the device's own response time is {why}: each delay measured holds the gateway's serial transmission and processing ({stats})"
                )));
            }
            let mut v = Verdict { pass_summary: stats.clone(), ..Verdict::default() };
            let late = l.iter().filter(|d| **d > limit).count();
            if median > limit {
                v.findings.push(Finding::deviation(format!("replies are late: {stats}")));
            } else if max > limit && ctx.link_kind() == crate::transport::LinkKind::Pty {
                // On a pseudo-terminal the other end is a program on this host (the
                // simulator): a few late replies are as likely this host's scheduling
                // as the device's (issue 24: 1 to 8 of 221 on a loaded machine). The
                // median, which a stall does not move, is judged; the tail is not.
                v.pass_summary = format!(
                    "{stats}; {late} replies over {:.0} ms not judged: on a pseudo-terminal the other end is a program on this host, and a few late replies may be its scheduling (the median is judged)",
                    ms(limit)
                );
            } else if max > limit {
                v.findings.push(Finding::observation(format!("{late} replies took longer than {:.0} ms: {stats}", ms(limit))));
            }
            Ok(v)
        },
    ));
}

fn timing_and_codes(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    let ascii = m == "ascii";
    let (title, source) = if ascii {
        (
            "Silence between the characters of replies (at most 1 s), on a line with timing",
            "Modbus over Serial Line V1.02, 2.5.2.1 (up to 1 s between the characters of an ASCII frame; no t1.5 or t3.5 in ASCII)",
        )
    } else {
        (
            "Silence inside replies (at most t1.5) and before them (at least t3.5), on a line with timing",
            "Modbus over Serial Line V1.02, 2.5.1.1 (t1.5, t3.5)",
        )
    };
    let mut line_timing = check(
        format!("{m}.line-timing"),
        title.to_string(),
        source.to_string(),
        false,
        false,
        move |ctx| {
            let Some(line) = ctx.line_timing() else {
                return Ok(Verdict::skip(
                    "the link has no line timing (a pseudo-terminal without pacing, or TCP): gaps are the host's, not the device's",
                ));
            };
            if ctx.gap_replies == 0 {
                return Ok(Verdict::skip("no replies were measured"));
            }
            // On an emulated line (the simulator's paced pseudo-terminal) this host paces
            // the characters and reads them: a sender that wrote late, or a reader that
            // woke late after a reply's last byte (274 ms seen with every core busy),
            // makes a gap inside a reply that no device made. There only the silence
            // before replies is judged (a stall can delay a reply, never hasten it).
            let on_pty = ctx.link_kind() == crate::transport::LinkKind::Pty;
            let t15 = Duration::from_micros(line.t1_5_us());
            let t35 = Duration::from_micros(line.t3_5_us());
            if ascii {
                // ASCII frames are delimited by ':' and CR LF: only the 1 s between
                // characters applies (a gap over it ends the frame at the receiver).
                let mut v = Verdict {
                    pass_summary: format!(
                        "{} replies: largest silence between characters {} us (ASCII allows up to 1 s)",
                        ctx.gap_replies,
                        ctx.max_gap.as_micros()
                    ),
                    ..Verdict::default()
                };
                if let Some((req, gap)) = ctx.gaps.first().filter(|_| !on_pty) {
                    v.findings.push(Finding::deviation(format!(
                        "{} replies had a silence over 1 s between two characters; the first, to request {req}, had {} us; Modbus over Serial Line V1.02, 2.5.2.1",
                        ctx.gaps.len(),
                        gap.as_micros()
                    )));
                }
                return Ok(v);
            }
            let mut v = Verdict {
                pass_summary: format!(
                    "{} replies: largest gap inside a reply {} us (t1.5 = {} us), none sooner than t3.5 = {} us",
                    ctx.gap_replies,
                    ctx.max_gap.as_micros(),
                    t15.as_micros(),
                    t35.as_micros()
                ),
                ..Verdict::default()
            };
            if on_pty {
                v.pass_summary = format!(
                    "{} replies, none sooner than t3.5 = {} us; gaps inside replies not judged: on a pseudo-terminal this host paces and reads the characters, so they are its scheduling (largest {} us{})",
                    ctx.gap_replies,
                    t35.as_micros(),
                    ctx.max_gap.as_micros(),
                    match ctx.peer_lateness() {
                        Some(late) => format!(
                            "; the simulator's paced writes came up to {:.1} ms late",
                            late.as_secs_f64() * 1000.0
                        ),
                        None => String::new(),
                    }
                );
            } else if let Some((req, gap)) = ctx.gaps.first() {
                v.findings.push(Finding::deviation(format!(
                    "{} replies had a silence over t1.5 ({} us + allowance {} us) inside them; the first, to request {req}, had {} us",
                    ctx.gaps.len(),
                    t15.as_micros(),
                    ctx.opts.gap_allowance.as_micros(),
                    gap.as_micros()
                )));
            }
            // The host reads the end of its request a little late (the write returns after
            // the bytes left): one character time of tolerance.
            let tolerance = Duration::from_micros(line.char_time_us());
            let early: Vec<&Duration> = ctx
                .latencies
                .iter()
                .filter(|l| l.saturating_add(tolerance) < t35)
                .collect();
            if let Some(first) = early.iter().min() {
                v.findings.push(Finding::deviation(format!(
                    "{} replies began less than t3.5 ({} us, less a tolerance of one character, {} us) after the request ended; the earliest after {} us",
                    early.len(),
                    t35.as_micros(),
                    tolerance.as_micros(),
                    first.as_micros()
                )));
            }
            Ok(v)
        },
    );
    line_timing.needs_line = true;
    out.push(line_timing);
    if model.exception_codes.is_empty() {
        out.push(undescribed_field(
            model,
            format!("{m}.exception-codes"),
            "Exception codes the device sent during this mode's checks, against the description's table".to_string(),
            "exception_codes",
        ));
        return;
    }
    out.push(check(
        format!("{m}.exception-codes"),
        "Exception codes the device sent during this mode's checks, against the manual's table"
            .to_string(),
        format!(
            "{}, {}",
            model.manual,
            model
                .exception_codes_source
                .as_deref()
                .unwrap_or("exception-code table")
        ),
        false,
        false,
        |ctx| {
            let table: Vec<u8> = ctx.model.exception_codes.iter().map(|(c, _)| *c).collect();
            let seen: Vec<u8> = ctx.codes_seen.iter().copied().collect();
            let hex = |v: &[u8]| {
                v.iter()
                    .map(|c| format!("{c:02X}"))
                    .collect::<Vec<_>>()
                    .join(" ")
            };
            let foreign: Vec<u8> = seen
                .iter()
                .copied()
                .filter(|c| !table.contains(c))
                .collect();
            let unseen: Vec<u8> = table
                .iter()
                .copied()
                .filter(|c| !seen.contains(c))
                .collect();
            let mut v = Verdict {
                pass_summary: format!("table {}; sent {}", hex(&table), hex(&seen)),
                ..Verdict::default()
            };
            if !foreign.is_empty() {
                v.findings.push(Finding::deviation(format!(
                    "the device sent exception codes that are not in the manual's table ({}): {}",
                    hex(&table),
                    hex(&foreign)
                )));
            }
            if !unseen.is_empty() {
                v.findings.push(Finding::observation(format!(
                    "codes of the table that no check elicited: {} (sent: {})",
                    hex(&unseen),
                    hex(&seen)
                )));
            }
            Ok(v)
        },
    ));
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::timing::{LineSettings, Parity};
    use crate::runner::{Options, Status};
    use crate::transport::{memory, LinkKind, Transport, TransportError};

    /// A memory link that says it carries a line's timing, of `kind` (a pseudo-terminal
    /// to this host's simulator, or a serial port), with a peer whose paced writes came
    /// `late` (on a pseudo-terminal).
    struct Emulated(memory::MemoryEnd, LinkKind, Duration);

    impl Transport for Emulated {
        fn send(&mut self, b: &[u8]) -> Result<(), TransportError> {
            self.0.send(b)
        }
        fn recv(&mut self, b: &mut [u8], t: Duration) -> Result<usize, TransportError> {
            self.0.recv(b, t)
        }
        fn discard_input(&mut self) -> Result<(), TransportError> {
            self.0.discard_input()
        }
        fn describe(&self) -> String {
            "emulated".into()
        }
        fn kind(&self) -> LinkKind {
            self.1
        }
        fn line_timing(&self) -> Option<LineSettings> {
            Some(LineSettings::new(9600, 8, Parity::Even, 1))
        }
        fn peer_lateness(&self) -> Option<Duration> {
            (self.1 == LinkKind::Pty).then_some(self.2)
        }
    }

    /// Runs aggregate `id` over a context on a `kind` link whose replies had one gap of
    /// 60 ms inside them and the given latencies.
    fn aggregate_with(id: &str, kind: LinkKind, latencies: &[u64]) -> crate::runner::CheckResult {
        let model = DriveModel::builtin("f510").unwrap();
        let mut opts = Options {
            read_only: true,
            allow_motion: false,
            allow_restart: false,
            ..Options::for_listing()
        };
        opts.timing.timeout = Duration::from_millis(100);
        opts.timing.silence = Duration::from_millis(50);
        opts.timing.derive_silence = false;
        let (a, _b) = memory::pair();
        let link = Emulated(a, kind, Duration::from_millis(2));
        let mut ctx = Ctx::new(&model, None, Mode::Rtu, &opts, Box::new(link));
        ctx.gap_replies = latencies.len();
        ctx.gaps
            .push(("01 03 25 20 00 01 8E CC".into(), Duration::from_millis(60)));
        ctx.max_gap = Duration::from_millis(60);
        ctx.latencies = latencies
            .iter()
            .map(|&ms| Duration::from_millis(ms))
            .collect();
        let mut out = Vec::new();
        aggregates(&model, "rtu", &mut out);
        let check = out.iter().find(|c| c.id == id).unwrap();
        let v = (check.run)(&mut ctx).unwrap();
        crate::runner::run::result_of(check, Mode::Rtu, v, Duration::ZERO)
    }

    #[test]
    fn gaps_inside_replies_on_a_pseudo_terminal_are_the_hosts() {
        // On a serial port a 60 ms gap inside a reply is the device's deviation.
        let r = aggregate_with("rtu.line-timing", LinkKind::Serial, &[10, 10, 10]);
        assert_eq!(r.status, Status::Deviation, "{}", r.summary);
        assert!(r.summary.contains("silence over t1.5"), "{}", r.summary);
        // On a pseudo-terminal this host paced and read the characters, even where the
        // simulator's writes were on time (a reader that woke late: issue 24); the check
        // says so and passes what it can still judge (no reply before t3.5).
        let r = aggregate_with("rtu.line-timing", LinkKind::Pty, &[10, 10, 10]);
        assert_eq!(r.status, Status::Pass, "{}", r.summary);
        assert!(r.summary.contains("not judged"), "{}", r.summary);
        // A reply before t3.5 is judged everywhere: a stall delays, it never hastens.
        let r = aggregate_with("rtu.line-timing", LinkKind::Pty, &[1, 10, 10]);
        assert_eq!(r.status, Status::Deviation, "{}", r.summary);
        assert!(r.summary.contains("less than t3.5"), "{}", r.summary);
    }

    #[test]
    fn a_few_late_replies_on_a_pseudo_terminal_are_not_judged() {
        // Limit: 10 ms + one character + 20 ms allowance. One reply of five late.
        let tail = [9, 9, 9, 9, 60];
        let r = aggregate_with("rtu.response-time", LinkKind::Serial, &tail);
        assert_eq!(r.status, Status::Observation, "{}", r.summary);
        let r = aggregate_with("rtu.response-time", LinkKind::Pty, &tail);
        assert_eq!(r.status, Status::Pass, "{}", r.summary);
        assert!(
            r.summary.contains("1 replies over 31 ms not judged"),
            "{}",
            r.summary
        );
        // Replies late as a rule (the late-reply quirk) are a deviation everywhere.
        let late = [60, 60, 60, 9, 60];
        for kind in [LinkKind::Serial, LinkKind::Pty] {
            let r = aggregate_with("rtu.response-time", kind, &late);
            assert_eq!(r.status, Status::Deviation, "{kind}: {}", r.summary);
        }
    }
}
