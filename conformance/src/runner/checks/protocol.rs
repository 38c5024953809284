//! The protocol around the registers: unserved functions and the exception numbering,
//! loop-back, broadcast and other nodes, bad checksums, garbage and partial frames.

use std::time::Duration;

use super::*;

pub(super) fn functions(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    let source = cite_rule(model, crate::model::Fault::IllegalFunction);
    for fc in [0x04u8, 0x41] {
        out.push(probe_check(
            format!("{m}.function.{fc:02X}"),
            format!("Send function {fc:02X}H, which the drive does not serve"),
            source.clone(),
            false,
            move |ctx| {
                ctx.frame(Pdu::Other {
                    function: fc,
                    data: &[0x25, 0x20, 0x00, 0x01],
                })
            },
        ));
    }
    if model.exception_codes.is_empty() {
        out.push(undescribed_field(
            model,
            format!("{m}.exception-numbering"),
            "Exception numbering: 01H..05H or 51H..55H, as the description's table".to_string(),
            "exception_codes",
        ));
        return;
    }
    out.push(check(
        format!("{m}.exception-numbering"),
        format!(
            "Exception numbering: the manual numbers its codes {}",
            if model.numbers_exceptions_from_51() { "51H..55H" } else { "01H..05H" }
        ),
        format!("{}, {}", model.manual, model.exception_codes_source.as_deref().unwrap_or("exception-code table")),
        false,
        false,
        move |ctx| {
            let p = ctx.probe(ctx.frame(Pdu::Other { function: 0x04, data: &[0x25, 0x20, 0x00, 0x01] }), None)?;
            let code = p.exchange.reply.as_ref().and_then(|r| crate::judge::body_of(ctx.mode, r)).and_then(|b| (b.len() == 3 && b[1] & 0x80 != 0).then_some(b[2]));
            let want51 = ctx.model.numbers_exceptions_from_51();
            let mut v = verdict(&[&p], String::new());
            v.findings.retain(|_| false);
            match code {
                None => v.findings.push(Finding::deviation(format!(
                    "no exception reply to function 04H: {}",
                    p.comparison.actual
                ))),
                Some(c) => {
                    let style = match c {
                        0x01..=0x05 => Some(false),
                        0x51..=0x55 => Some(true),
                        _ => None,
                    };
                    let name = |s: bool| if s { "51H..55H" } else { "01H..05H" };
                    match style {
                        Some(s) if s == want51 => v.pass_summary = format!("the device answers {c:02X}H: numbered {} as the manual says", name(s)),
                        Some(s) => v.findings.push(Finding::deviation(format!(
                            "the manual numbers exceptions {}, the device answered {c:02X}H ({} numbering)",
                            name(want51),
                            name(s)
                        ))),
                        None => v.findings.push(Finding::deviation(format!(
                            "the device answered code {c:02X}H, in neither numbering (01H..05H, 51H..55H)"
                        ))),
                    }
                }
            }
            Ok(v)
        },
    ));
}

pub(super) fn loop_back(model: &DriveModel, m: &str, seed: u64, out: &mut Vec<Check>) {
    let mut rng = Rng::new(seed ^ 0x08);
    let source = cite_or(model, model.loop_back_fact.as_ref(), "loop_back");
    for i in 0..3 {
        let r = rng.next_u64();
        // Any test code but the ones that restart, silence or reconfigure the device's
        // communications (0001H, 0003H, 0004H), which only --allow-restart sends.
        let test_code = match (i, (r >> 32) as u16) {
            (2, c) if RESTARTING.contains(&c) => c ^ 0x0100,
            (2, c) => c,
            _ => 0,
        };
        let data = [(r & 0xFF) as u8, ((r >> 8) & 0xFF) as u8];
        out.push(probe_check(
            format!("{m}.loop-back.{}", i + 1),
            format!(
                "Loop-back (08H) with test code {test_code:04X}H and data {}",
                Hex(&data)
            ),
            if test_code == 0 {
                source.clone()
            } else {
                format!(
                    "{source}; {}",
                    cite_or(model, model.loop_back_other_fact.as_ref(), "loop_back")
                )
            },
            false,
            move |ctx| {
                ctx.frame(Pdu::LoopBack {
                    test_code,
                    data: &data,
                })
            },
        ));
    }
}

/// 08H sub-functions that restart (0001H), reconfigure (0003H, the ASCII delimiter) or
/// silence (0004H, Force Listen Only Mode) a device's communications.
pub(super) const RESTARTING: [u16; 3] = [0x0001, 0x0003, 0x0004];

/// The Modbus serial line diagnostics sub-functions that only read or clear counters
/// (Modbus over Serial Line V1.02, 6.1 and the application protocol's 6.8).
const DIAGNOSTICS: [(u16, &str); 11] = [
    (0x0002, "return diagnostic register"),
    (0x000A, "clear counters and diagnostic register"),
    (0x000B, "return bus message count"),
    (0x000C, "return bus communication error count"),
    (0x000D, "return bus exception error count"),
    (0x000E, "return server message count"),
    (0x000F, "return server no response count"),
    (0x0010, "return server NAK count"),
    (0x0011, "return server busy count"),
    (0x0012, "return bus character overrun count"),
    (0x0014, "clear overrun counter and flag"),
];

/// 08H with the other sub-functions: what the device does with test codes the manual
/// does not show (the model decides; the legacy note documents "any values").
pub(super) fn diagnostics(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    let source = format!(
        "{}; Modbus application protocol V1.1b3, 6.8 (08H sub-functions)",
        cite_or(model, model.loop_back_other_fact.as_ref(), "loop_back")
    );
    out.push(check(
        format!("{m}.diagnostics.sub-functions"),
        "08H with the diagnostics sub-functions that read or clear counters (0002H, 000AH..0012H, 0014H)".to_string(),
        source.clone(),
        false,
        false,
        |ctx| {
            let mut probes = Vec::new();
            let mut did = Vec::new();
            for (code, _) in DIAGNOSTICS {
                let p = ctx.probe(
                    ctx.frame(Pdu::LoopBack { test_code: code, data: &[0, 0] }),
                    None,
                )?;
                did.push(format!("{code:04X}H {}", short_answer(ctx.mode, &p)));
                probes.push(p);
            }
            let refs: Vec<&Probed> = probes.iter().collect();
            let mut v = verdict(&refs, String::new());
            // One observation for the whole table instead of one per sub-function.
            let decided = v
                .findings
                .iter()
                .any(|f| f.severity == super::super::Severity::Observation);
            v.findings
                .retain(|f| f.severity == super::super::Severity::Deviation);
            let table = did.join(", ");
            if decided {
                v.findings.push(Finding::observation(format!(
                    "the manual shows test code 0000H only; the device: {table} (the model echoes every test code, a decision; with data 0000H a frame that comes back unchanged is an echo or a counter of 0000H: the two look alike)"
                )));
            }
            v.pass_summary = format!("every test code comes back unchanged, as the manual says: {table}");
            Ok(v)
        },
    ));
    let restart_source = format!(
        "{source}; Modbus over Serial Line V1.02, 6.1: 0001H restarts the port, 0004H forces Listen Only Mode until 0001H"
    );
    let mut restart = check(
        format!("{m}.diagnostics.restart"),
        "08H 0001H (Restart Communications Option): the device answers, restarts its port, and answers again".to_string(),
        restart_source.clone(),
        false,
        false,
        |ctx| {
            let p = ctx.probe(
                ctx.frame(Pdu::LoopBack { test_code: 0x0001, data: &[0, 0] }),
                None,
            )?;
            let mut v = verdict(&[&p], pass_text(&p));
            std::thread::sleep(super::super::liveness::RESTART_SETTLE);
            if !back_after_restart(ctx)? {
                return Err(RunError::DeviceLost(format!(
                    "the device did not answer for {} s after 08H 0001H (restart communications); power-cycle it",
                    RESTART_WAIT.as_secs()
                )));
            }
            v.pass_summary.push_str("; it answers again after the restart");
            Ok(v)
        },
    );
    restart.restarts = true;
    out.push(restart);
    let mut listen = check(
        format!("{m}.diagnostics.listen-only"),
        "08H 0004H (Force Listen Only Mode): does the device stop answering; then 0001H brings it back".to_string(),
        restart_source,
        false,
        false,
        |ctx| {
            let req = ctx.frame(Pdu::LoopBack { test_code: 0x0004, data: &[0, 0] });
            // Straight to the master: silence is the point here, not a lost device.
            let ex = ctx.master.exchange(&req, true)?;
            let read = ctx.frame(Pdu::ReadRequest { start: 0x2520, count: 1 });
            let probe = match super::super::liveness::liveness_register(ctx.model, ctx.opts.address, ctx.mode) {
                Some(r) => ctx.frame(Pdu::ReadRequest { start: r, count: 1 }),
                None => read,
            };
            let after = ctx.master.exchange(&probe, true)?;
            let answered_04 = !ex.after_echo().is_empty();
            let silent = after.after_echo().is_empty();
            let text = if silent {
                // Listen only: 0001H ends it (no reply is due while listening only).
                let wake = ctx.frame(Pdu::LoopBack { test_code: 0x0001, data: &[0, 0] });
                let _ = ctx.master.exchange(&wake, false)?;
                std::thread::sleep(super::super::liveness::RESTART_SETTLE);
                if !back_after_restart(ctx)? {
                    return Err(RunError::DeviceLost(format!(
                        "the device stopped answering after 08H 0004H (Force Listen Only Mode) and did not answer for {} s after 0001H; power-cycle it",
                        RESTART_WAIT.as_secs()
                    )));
                }
                format!(
                    "after 0004H ({}) the device stopped answering, as Listen Only Mode does; 0001H brought it back",
                    if answered_04 { "which it answered" } else { "unanswered, as the Modbus specification says" }
                )
            } else {
                format!(
                    "the device kept answering after 0004H ({}): it does not implement Listen Only Mode",
                    if answered_04 { format!("answered {}", crate::judge::describe_reply(ctx.mode, ex.after_echo())) } else { "unanswered".to_string() }
                )
            };
            Ok(Verdict {
                findings: vec![Finding::observation(text)],
                ..Verdict::default()
            })
        },
    );
    listen.restarts = true;
    out.push(listen);
}

/// How long a device may take to answer again after a restart of its communications.
const RESTART_WAIT: Duration = Duration::from_secs(10);

/// Probes until the device answers again, up to [`RESTART_WAIT`].
fn back_after_restart(ctx: &mut Ctx<'_>) -> Result<bool, RunError> {
    let until = std::time::Instant::now() + RESTART_WAIT;
    loop {
        if ctx.liveness()? {
            return Ok(true);
        }
        if std::time::Instant::now() >= until {
            return Ok(false);
        }
    }
}

/// What the device did, in a few words: echo, exception NN, no reply, ...
fn short_answer(mode: Mode, p: &Probed) -> String {
    let Some(reply) = &p.exchange.reply else {
        return if p.exchange.after_echo().is_empty() {
            "no reply".into()
        } else {
            "invalid reply".into()
        };
    };
    if *reply == p.exchange.request {
        return "same frame back".into();
    }
    match crate::judge::body_of(mode, reply) {
        Some(b) if b.len() == 3 && b[1] & 0x80 != 0 => format!("exception {:02X}H", b[2]),
        _ => format!("answered {}", show(mode, reply)),
    }
}

pub(super) fn addressing(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    let bsource = cite_or(
        model,
        model.silence.get(&crate::model::SilenceReason::Broadcast),
        "silence.broadcast",
    );
    let probe = probe_register(model);
    let first = out.len();
    if let Some(f) = model.register_with_role(Role::FrequencyCommand) {
        out.push(check(
            format!("{m}.broadcast.write"),
            format!("Broadcast (node 00H) a write of the frequency command {f:04X}H: no reply, and the value is taken"),
            bsource.clone(),
            true,
            false,
            move |ctx| {
                // Every node of the bus takes a broadcast: each is journalled first (so
                // each gets its value back) and read back after.
                // A node whose register cannot be read first is left out of the
                // read-back (said as an observation); with none left, the run cannot tell.
                let mut nodes = Vec::new();
                let mut origs = Vec::new();
                let mut unread = Vec::new();
                // Nodes that refused the read with an exception the manual does not
                // predict: a deviation of that node (evidence, not "could not tell").
                let mut refused = Verdict::default();
                for &n in &ctx.opts.bus.clone() {
                    match ctx.remember_at(n, f)? {
                        Ok(v) => {
                            nodes.push(n);
                            origs.push(v);
                        }
                        Err(e) if ctx.opts.bus.len() == 1 => return Ok(Verdict::setup_failed(&format!("read {f:04X}H first"), e)),
                        Err(e) => {
                            let what = format!("read {f:04X}H of node {n:02X}H first");
                            let v = Verdict::setup_failed(&what, e);
                            match (v.error, v.skip) {
                                (Some(why), _) | (None, Some(why)) => unread.push(format!("{why}: the broadcast's effect on it is not judged")),
                                (None, None) => {
                                    refused.findings.extend(v.findings);
                                    refused.exchanges.extend(v.exchanges);
                                }
                            }
                        }
                    }
                }
                if nodes.is_empty() {
                    if unread.is_empty() {
                        return Ok(refused);
                    }
                    return Ok(Verdict {
                        error: Some(unread.join("; ")),
                        ..refused
                    });
                }
                let value = if origs.contains(&0x0A0A) { 0x0B0B } else { 0x0A0A };
                let bc = ctx.probe(ctx.frame_to(0, Pdu::WriteSingle { register: f, value }), None)?;
                let mut probes = vec![bc];
                for &n in &nodes {
                    let rb = ctx.probe_at(
                        n,
                        ctx.frame_to(n, Pdu::ReadRequest { start: f, count: 1 }),
                        Some((vec![Some(value)], write_fact())),
                    )?;
                    probes.push(rb);
                }
                let refs: Vec<&Probed> = probes.iter().collect();
                let who = if ctx.opts.bus.len() > 1 {
                    format!("{f:04X}H of nodes {} reads {value:04X}H", node_list(&nodes))
                } else {
                    format!("{f:04X}H reads {value:04X}H")
                };
                let mut v = verdict(&refs, format!("no reply to the broadcast, and {who}"));
                v.findings.extend(unread.into_iter().map(Finding::observation));
                v.findings.extend(refused.findings);
                v.exchanges.extend(refused.exchanges);
                Ok(v)
            },
        ));
    }
    out.push(probe_check(
        format!("{m}.broadcast.read"),
        format!("Broadcast (node 00H) a read of {probe:04X}H: no reply"),
        bsource,
        false,
        move |ctx| {
            ctx.frame_to(
                0,
                Pdu::ReadRequest {
                    start: probe,
                    count: 1,
                },
            )
        },
    ));
    out.push(probe_check(
        format!("{m}.other-address"),
        format!("Read {probe:04X}H from another node address: no reply"),
        cite_or(
            model,
            model
                .silence
                .get(&crate::model::SilenceReason::OtherAddress),
            "silence.other-address",
        ),
        false,
        move |ctx| {
            ctx.frame_to(
                ctx.opts.other_address,
                Pdu::ReadRequest {
                    start: probe,
                    count: 1,
                },
            )
        },
    ));
    for c in &mut out[first..] {
        c.bus = true;
    }
}

/// "01H, 02H and 05H".
fn node_list(nodes: &[u8]) -> String {
    let names: Vec<String> = nodes.iter().map(|n| format!("{n:02X}H")).collect();
    match names.split_last() {
        Some((last, rest)) if !rest.is_empty() => format!("{} and {last}", rest.join(", ")),
        _ => names.join(""),
    }
}

pub(super) fn line(model: &DriveModel, mode: Mode, m: &str, seed: u64, out: &mut Vec<Check>) {
    let csource = cite_or(
        model,
        model.silence.get(&crate::model::SilenceReason::BadChecksum),
        "silence.bad-checksum",
    );
    let probe = probe_register(model);
    let (name, what) = match mode {
        Mode::Rtu => ("bad-crc", "CRC"),
        Mode::Ascii => ("bad-lrc", "LRC"),
    };
    let mut bad = probe_check(
        format!("{m}.{name}"),
        format!("Read {probe:04X}H with a wrong {what}: no reply"),
        csource,
        false,
        move |ctx| {
            let mut f = ctx.frame(Pdu::ReadRequest {
                start: probe,
                count: 1,
            });
            let n = f.len();
            match ctx.mode {
                Mode::Rtu => f[n - 1] ^= 0xFF,
                // Change the LRC's last hex digit to another hex digit.
                Mode::Ascii => f[n - 3] = if f[n - 3] == b'0' { b'1' } else { b'0' },
            }
            f
        },
    );
    bad.needs_line = true;
    out.push(bad);
    let recover = "Modbus over Serial Line V1.02, 2.5.1.1 and 2.5.2.1: a receiver drops what is not a frame and takes the next frame".to_string();
    let mut rng = Rng::new(seed ^ 0x6A);
    let garbage: Vec<u8> = match mode {
        // Random bytes; the pause after them is a silence over t3.5, so a device that
        // frames by silence sees them as one bad frame.
        Mode::Rtu => (0..12).map(|_| rng.byte()).collect(),
        // Printable characters other than ':', CR and LF.
        Mode::Ascii => (0..12)
            .map(|_| b"ABCDEFGHIJ0123456789#!"[rng.below(22) as usize])
            .collect(),
    };
    let mut garbage_check = check(
        format!("{m}.garbage-then-frame"),
        format!(
            "Send 12 garbage bytes ({}), pause, then read {:04X}H: the device recovers",
            show(mode, &garbage),
            probe
        ),
        recover.clone(),
        false,
        false,
        move |ctx| {
            ctx.send_raw(&garbage, Duration::from_millis(30))?;
            let p = ctx.probe(
                ctx.frame(Pdu::ReadRequest {
                    start: probe,
                    count: 1,
                }),
                None,
            )?;
            Ok(verdict(
                &[&p],
                "the device answered the frame after the garbage".into(),
            ))
        },
    );
    garbage_check.needs_line = true;
    out.push(garbage_check);
    let mut partial = check(
        format!("{m}.partial-then-frame"),
        "Send the first half of a frame, pause, then a whole frame: the device answers the whole one".to_string(),
        recover,
        false,
        false,
        move |ctx| {
            let f = ctx.frame(Pdu::ReadRequest { start: probe, count: 1 });
            let half = f[..f.len() / 2].to_vec();
            // ASCII: the next ':' restarts the frame; RTU: the pause ends the partial frame.
            let pause = if ctx.mode == Mode::Ascii { Duration::from_millis(5) } else { Duration::from_millis(30) };
            ctx.send_raw(&half, pause)?;
            let p = ctx.probe(f, None)?;
            Ok(verdict(&[&p], "the device answered the whole frame".into()))
        },
    );
    partial.needs_line = true;
    out.push(partial);
}

/// The register the protocol checks read (broadcast, other address, bad checksum,
/// recovery): the TECO status register 2520H where the description serves it, else the
/// first register it serves for reading.
fn probe_register(model: &DriveModel) -> u16 {
    let readable = |r: u16| {
        model
            .lookup(r)
            .is_some_and(|i| !matches!(i.access, Access::NoAccess | Access::WriteOnly))
    };
    if readable(0x2520) {
        return 0x2520;
    }
    model
        .registers()
        .map(|(r, _)| r)
        .find(|&r| readable(r))
        .unwrap_or(0x2520)
}
