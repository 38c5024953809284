//! Writes: value-preserving writes read back, the frequency command, the two-word
//! register, and writes the device must refuse (read-only, reserved, out of range), each
//! read back to show that a refused write changed nothing.

use super::*;

pub(super) fn writes(model: &DriveModel, mode: Mode, m: &str, out: &mut Vec<Check>) {
    let _ = mode;
    blocks(model, m, out);
    // A value-preserving write to the first parameter of every group, read back.
    for g in model.parameter_groups() {
        let Some(r) = g.registers.first().map(|r| *r.start()) else {
            continue;
        };
        let source = format!("{}, {}", model.manual, g.source);
        out.push(preserving_write(
            format!("{m}.write.{}", slug(&g.name)),
            format!("Write the first parameter of {} ({r:04X}H) with the value it holds, and read it back", g.name),
            source,
            r,
        ));
    }
    let fc = model.register_with_role(Role::FrequencyCommand);
    let mirror = model.register_with_role(Role::FrequencyCommandMonitor);
    if let Some(f) = fc {
        let named = model.named(f).cloned();
        let source = named
            .as_ref()
            .and_then(|n| n.fact.source.clone())
            .unwrap_or_default();
        out.push(check(
            format!("{m}.write.frequency-command"),
            format!(
                "Write the frequency command {f:04X}H (12.34 Hz), read it back and its monitor"
            ),
            format!("{}, {source}", model.manual),
            true,
            false,
            move |ctx| {
                if let Err(e) = ctx.remember(f)? {
                    return Ok(Verdict::setup_failed(&format!("read {f:04X}H first"), e));
                }
                let value = 1234;
                let w = ctx.probe(ctx.frame(Pdu::WriteSingle { register: f, value }), None)?;
                let rb = ctx.probe(
                    ctx.frame(Pdu::ReadRequest { start: f, count: 1 }),
                    Some((vec![Some(value)], write_fact())),
                )?;
                let mut probes = vec![w, rb];
                if let Some(mon) = mirror {
                    // The monitor shows the command only when the frequency source is
                    // communication: a parameter the manual's chapter does not cover.
                    probes.push(ctx.probe(
                        ctx.frame(Pdu::ReadRequest {
                            start: mon,
                            count: 1,
                        }),
                        Some((vec![Some(value)], mirror_fact())),
                    )?);
                }
                let refs: Vec<&Probed> = probes.iter().collect();
                Ok(verdict(
                    &refs,
                    format!("{f:04X}H takes 04D2H and reads it back"),
                ))
            },
        ));
        out.push(refused_write(
            format!("{m}.write.out-of-range"),
            format!("Write FFFFH (655.35 Hz) to the frequency command {f:04X}H, and read it back"),
            cite_rule(model, crate::model::Fault::DataOutOfRange),
            Target::stored(f),
            single_write(f, 0xFFFF),
        ));
        if let Some((_, max, fact)) = model.frequency_command_max() {
            let source = cite(model, fact);
            out.push(check(
                format!("{m}.write.frequency-max"),
                format!("Write the frequency command's maximum {max:04X}H ({}.{:02} Hz) to {f:04X}H, and read it back", max / 100, max % 100),
                source.clone(),
                true,
                false,
                move |ctx| {
                    if let Err(e) = ctx.remember(f)? {
                        return Ok(Verdict::setup_failed(&format!("read {f:04X}H first"), e));
                    }
                    let w = ctx.probe(ctx.frame(Pdu::WriteSingle { register: f, value: max }), None)?;
                    let rb = ctx.probe(
                        ctx.frame(Pdu::ReadRequest { start: f, count: 1 }),
                        Some((vec![Some(max)], write_fact())),
                    )?;
                    Ok(verdict(&[&w, &rb], format!("{f:04X}H takes its maximum {max:04X}H and reads it back")))
                },
            ));
            if let Some(over) = max.checked_add(1) {
                out.push(refused_write(
                    format!("{m}.write.frequency-over-max"),
                    format!("Write {over:04X}H, one over the frequency command's maximum, to {f:04X}H, and read it back"),
                    source,
                    Target::stored(f),
                    single_write(f, over),
                ));
            }
        }
    }
    // Two-word register (12-00 at 2510H/2511H), value-preserving, by 10H.
    if let (Some(hi), Some(lo)) = (
        model.register_with_role(Role::TwoWordHigh),
        model.register_with_role(Role::TwoWordLow),
    ) {
        if lo == hi + 1 {
            let source = model
                .named(hi)
                .and_then(|n| n.fact.source.clone())
                .unwrap_or_default();
            out.push(check(
                format!("{m}.write.two-word"),
                format!("Write the two-word register {hi:04X}H/{lo:04X}H (10H) with its value, and read it back"),
                format!("{}, {source}", model.manual),
                true,
                false,
                move |ctx| {
                    let a = match ctx.remember(hi)? {
                        Ok(v) => v,
                        Err(e) => return Ok(Verdict::setup_failed(&format!("read {hi:04X}H first"), e)),
                    };
                    let b = match ctx.remember(lo)? {
                        Ok(v) => v,
                        Err(e) => return Ok(Verdict::setup_failed(&format!("read {lo:04X}H first"), e)),
                    };
                    let bytes = [a.to_be_bytes(), b.to_be_bytes()].concat();
                    let Ok(values) = Registers::new(&bytes) else {
                        return Ok(Verdict::error("internal: odd register bytes"));
                    };
                    let w = ctx.probe(ctx.frame(Pdu::WriteMultipleRequest { start: hi, values }), None)?;
                    let rb = ctx.probe(
                        ctx.frame(Pdu::ReadRequest { start: hi, count: 2 }),
                        Some((vec![Some(a), Some(b)], write_fact())),
                    )?;
                    Ok(verdict(&[&w, &rb], format!("{hi:04X}H/{lo:04X}H accept {a:04X} {b:04X} and read them back")))
                },
            ));
        }
    }
    if let Some(ro) = model.register_with_role(Role::Status) {
        // Not journalled: 2520H is state, not a stored value, and writing it back at the
        // end would be a second write to a read-only register.
        out.push(refused_write(
            format!("{m}.write.read-only"),
            format!("Write 0000H to the monitor register {ro:04X}H (read-only), and read it back"),
            cite_rule(model, crate::model::Fault::ReadOnly),
            Target::state(ro),
            single_write(ro, 0),
        ));
    }
    if let Some(res) = model
        .named
        .iter()
        .find(|n| n.access == Access::Reserved)
        .map(|n| n.register)
    {
        out.push(refused_write(
            format!("{m}.write.reserved"),
            format!("Write 0000H to the reserved register {res:04X}H, and read it back"),
            cite_rule(model, crate::model::Fault::ReservedWrite),
            Target::stored(res),
            single_write(res, 0),
        ));
    }
    // Parameters the manual marks read-only (F510's Metasys table): 06H and 10H writes of
    // another value are refused and change nothing.
    if let Some((r, fact)) = model.read_only_parameters().next() {
        let mut source = cite(model, fact);
        if let Some(lines) = model.read_only_parameter(r).and_then(|p| p.lines.as_ref()) {
            source.push_str(&format!(" ({lines})"));
        }
        let name = model.describe(r);
        out.push(refused_write(
            format!("{m}.write.read-only-parameter"),
            format!(
                "Write another value to the read-only parameter {name} (06H), and read it back"
            ),
            source.clone(),
            Target::stored(r),
            move |ctx, before| {
                let value = before.first().copied().flatten().unwrap_or(0) ^ 1;
                ctx.frame(Pdu::WriteSingle { register: r, value })
            },
        ));
        out.push(refused_write(
            format!("{m}.write-multi.read-only-parameter"),
            format!(
                "Write another value to the read-only parameter {name} with 10H, and read it back"
            ),
            source,
            Target::stored(r),
            move |ctx, before| {
                let value = before.first().copied().flatten().unwrap_or(0) ^ 1;
                let bytes = value.to_be_bytes();
                match Registers::new(&bytes) {
                    Ok(values) => ctx.frame(Pdu::WriteMultipleRequest { start: r, values }),
                    Err(_) => Vec::new(),
                }
            },
        ));
    }
}

/// The register a refused write aims at, as its read-back sees it.
#[derive(Debug, Clone, Copy)]
pub(super) struct Target {
    register: u16,
    /// A stored value (journalled, so that a device that takes the write gets it back);
    /// otherwise state that the drive keeps by itself (a status word), which only counts
    /// as changed when it took the value written.
    stored: bool,
}

impl Target {
    pub(super) fn stored(register: u16) -> Self {
        Target {
            register,
            stored: true,
        }
    }

    pub(super) fn state(register: u16) -> Self {
        Target {
            register,
            stored: false,
        }
    }
}

/// A write the device must refuse, read before and after: a refused write (an exception
/// reply) must leave the register as it was (Modbus application protocol V1.1b3, 7: the
/// exception response reports that the request was not executed; SunSpec's EXC-1 test
/// reads back after every rejected write for the same reason). A stored register is
/// journalled first, so a device that takes the write gets its value back at the end.
/// `build` gets the values read before (None where the read failed).
/// The writes a v2 description's blocks predict: a value-preserving write to the first
/// register of each writable block (read back where it can be read), a write to a
/// read-only block, and writes just outside a block's bounds, each refused.
fn blocks(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    for b in &model.blocks {
        let r = *b.span.start();
        let label = b.name.clone().unwrap_or_else(|| format!("block {r:04X}"));
        let name = slug(&label);
        let source = cite(model, &b.fact);
        match b.access {
            Access::ReadWrite => out.push(preserving_write(
                format!("{m}.write.{name}"),
                format!("Write the first register of {label} ({r:04X}H) with the value it holds, and read it back"),
                source.clone(),
                r,
            )),
            Access::ReadOnly => out.push(refused_write(
                format!("{m}.write.{name}.read-only"),
                format!("Write the value it holds to {r:04X}H of {label} (read-only), and read it back"),
                format!(
                    "{source}; {}",
                    cite_rule(model, crate::model::Fault::ReadOnly)
                ),
                Target::state(r),
                move |ctx, before| {
                    ctx.frame(Pdu::WriteSingle { register: r, value: before.first().copied().flatten().unwrap_or(0) })
                },
            )),
            _ => {}
        }
        let outside = [
            ("over-max", b.max.and_then(|x| x.checked_add(1))),
            ("under-min", b.min.and_then(|x| x.checked_sub(1))),
        ];
        for (which, value) in outside {
            let Some(value) = value else { continue };
            out.push(refused_write(
                format!("{m}.write.{name}.{which}"),
                format!("Write {value:04X}H to {r:04X}H, outside the bounds of {label}, and read it back"),
                format!(
                    "{source}; {}",
                    cite_rule(model, crate::model::Fault::DataOutOfRange)
                ),
                Target::stored(r),
                single_write(r, value),
            ));
        }
    }
}

/// A value-preserving write: `r` read (and journalled), written back with 06H, read
/// again, the value expected unchanged (a parameter group's first register; a writable
/// block's first register).
fn preserving_write(id: String, title: String, source: String, r: u16) -> Check {
    check(id, title, source, true, false, move |ctx| {
        let orig = match ctx.remember(r)? {
            Ok(v) => v,
            Err(e) => return Ok(Verdict::setup_failed(&format!("read {r:04X}H first"), e)),
        };
        let w = ctx.probe(
            ctx.frame(Pdu::WriteSingle {
                register: r,
                value: orig,
            }),
            None,
        )?;
        let rb = ctx.probe(
            ctx.frame(Pdu::ReadRequest { start: r, count: 1 }),
            Some((vec![Some(orig)], write_fact())),
        )?;
        Ok(verdict(
            &[&w, &rb],
            format!("{r:04X}H accepted {orig:04X}H and reads it back"),
        ))
    })
}

/// The frame of a refused write: 06H of `value` to `register`, whatever was read before.
fn single_write(
    register: u16,
    value: u16,
) -> impl Fn(&Ctx<'_>, &[Option<u16>]) -> Vec<u8> + 'static {
    move |ctx, _| ctx.frame(Pdu::WriteSingle { register, value })
}

pub(super) fn refused_write(
    id: String,
    title: String,
    source: String,
    target: Target,
    build: impl Fn(&Ctx<'_>, &[Option<u16>]) -> Vec<u8> + 'static,
) -> Check {
    check(id, title, source, true, false, move |ctx| {
        let r = target.register;
        let before = if target.stored {
            match ctx.remember_current(r)? {
                Ok(v) => Some(v),
                Err(e) => {
                    return Ok(Verdict::setup_failed(
                        &format!("read {r:04X}H first (so that a write could be undone)"),
                        e,
                    ))
                }
            }
        } else {
            ctx.read(r, 1)?.ok().map(|v| v[0])
        };
        let frame = build(ctx, &[before]);
        let written = written_value(ctx, &frame);
        let p = ctx.probe(frame, None)?;
        let mut v = verdict(&[&p], pass_text(&p));
        let refused = is_exception(ctx, &p);
        if !refused {
            // Taken (a deviation or an observation already says so), or no reply: the
            // journal puts a taken value back.
            return Ok(v);
        }
        let Some(before) = before else {
            v.pass_summary
                .push_str("; not read back (the read before it failed)");
            return Ok(v);
        };
        let rb = ctx.probe(ctx.frame(Pdu::ReadRequest { start: r, count: 1 }), None)?;
        v.exchanges.push(rb.record());
        match rb.read_values().and_then(|x| x.first().copied()) {
            Some(after) if after == before => {
                v.pass_summary
                    .push_str(&format!("; {r:04X}H still reads {before:04X}H"));
            }
            Some(after) if !target.stored && Some(after) != written => {
                v.pass_summary.push_str(&format!(
                    "; {r:04X}H reads {after:04X}H (was {before:04X}H): state the drive keeps, not the value written"
                ));
            }
            Some(after) => v.findings.push(Finding::deviation(format!(
                "the device refused the write with an exception, but {r:04X}H changed: {before:04X}H before, {after:04X}H after (a refused write must change nothing: Modbus application protocol V1.1b3, 7)"
            ))),
            None => v.findings.push(Finding::deviation(format!(
                "reading {r:04X}H back after the refused write: {}",
                rb.comparison.actual
            ))),
        }
        Ok(v)
    })
}

/// Whether the device's reply to `p` is an exception.
fn is_exception(ctx: &Ctx<'_>, p: &Probed) -> bool {
    p.exchange
        .reply
        .as_ref()
        .and_then(|r| crate::judge::body_of(ctx.mode, r))
        .is_some_and(|b| b.len() == 3 && b[1] & 0x80 != 0)
}

/// The value a 06H (or one-register 10H) frame writes.
fn written_value(ctx: &Ctx<'_>, frame: &[u8]) -> Option<u16> {
    let body = crate::judge::body_of(ctx.mode, frame)?;
    match crate::codec::pdu::Message::parse_body(&body, crate::codec::pdu::Direction::Request)
        .ok()?
        .pdu
    {
        Pdu::WriteSingle { value, .. } => Some(value),
        Pdu::WriteMultipleRequest { values, .. } => values.iter().next(),
        _ => None,
    }
}
