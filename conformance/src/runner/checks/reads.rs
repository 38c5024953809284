//! Reads: the manual's examples, the identification register, the register map (first,
//! last, past the end, gaps, '-' registers, reserved) and the read and write counts.

use super::*;

pub(super) fn examples(
    model: &DriveModel,
    vectors: Option<&VectorFile>,
    mode: Mode,
    out: &mut Vec<Check>,
) {
    let Some(file) = vectors else { return };
    for v in &file.vectors {
        let Body::Frame(fv) = &v.body else { continue };
        if fv.direction != FileDirection::Request || Mode::from(fv.mode) != mode {
            continue;
        }
        let Some(request) = fv.correct_bytes() else {
            continue;
        };
        let response_id = v.id.replace(".request", ".response");
        let response = file
            .vectors
            .iter()
            .find(|r| r.id == response_id)
            .and_then(|r| match &r.body {
                Body::Frame(rf) => rf.correct_bytes(),
                _ => None,
            });
        let judgement = model.judge(1, mode, &request);
        let plan_writes = judgement
            .write
            .clone()
            .map(|w| w.writes)
            .unwrap_or_default();
        let op = model.register_with_role(Role::Operation);
        let bits = model.bits;
        let motion = plan_writes.iter().any(|&(r, val)| {
            Some(r) == op
                && [bits.run, bits.external_fault]
                    .iter()
                    .flatten()
                    .any(|b| val & (1 << b) != 0)
        });
        let writes = !plan_writes.is_empty();
        let id = format!("{mode}.example.{}", v.id);
        let title = format!(
            "Replay the manual's example request {} ({}){}",
            v.id,
            show(mode, &request),
            if v.verdict == crate::vectors::Verdict::Consistent {
                String::new()
            } else {
                " as corrected".to_string()
            }
        );
        let source = v.source.clone();
        out.push(check(id, title, source, writes, motion, move |ctx| {
            // Address the device, not the manual's node 01.
            let mut frame = request.clone();
            if ctx.opts.address != 1 {
                frame = crate::codec::readdressed(ctx.mode, &request, ctx.opts.address)
                    .unwrap_or(frame);
            }
            for &(r, _) in &plan_writes {
                if let Err(e) = ctx.remember(r)? {
                    return Ok(Verdict::skip(format!(
                        "cannot read the value of {r:04X}H to restore it, so the example is not replayed: {e}"
                    )));
                }
            }
            let p = ctx.probe(frame, None)?;
            let mut v = verdict(&[&p], pass_text(&p));
            if let (Some(reply), Some(manual)) = (&p.exchange.reply, &response) {
                if ctx.opts.address == 1 && reply != manual && p.comparison.findings.is_empty() {
                    v.findings.push(Finding::observation(format!(
                        "the manual's example response is {}; the device answered {} (a read's values are the state of the drive, not of the protocol)",
                        show(ctx.mode, manual),
                        show(ctx.mode, reply)
                    )));
                }
                if ctx.opts.address == 1 && reply == manual {
                    v.pass_summary = format!("the device answered the manual's example response {}", show(ctx.mode, manual));
                }
            }
            Ok(v)
        }));
    }
}

pub(super) fn identification(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    let Some(id) = &model.identification else {
        out.push(undescribed_field(
            model,
            format!("{m}.identification"),
            "Read the identification register".to_string(),
            "identification",
        ));
        return;
    };
    let register = id.register.unwrap_or(0x252F);
    let id_fact = id.fact.clone();
    let documented = id.value;
    let source = cite(model, &id.fact);
    let title = match documented {
        Some(v) => {
            format!("Read the identification register {register:04X}H (the manual gives {v:04X}H)")
        }
        None => format!("Read the identification register {register:04X}H"),
    };
    out.push(check(
        format!("{m}.identification"),
        title,
        source,
        false,
        false,
        move |ctx| {
            let known = documented.map(|v| (vec![Some(v)], id_fact.clone()));
            let frame = ctx.frame(Pdu::ReadRequest {
                start: register,
                count: 1,
            });
            let p = ctx.probe(frame, known)?;
            let value = p.read_values().and_then(|v| v.first().copied());
            ctx.identification = value;
            let mut v = verdict(&[&p], pass_text(&p));
            match (value, documented) {
                (Some(x), Some(d)) if x == d => {
                    v.pass_summary = format!("{register:04X}H reads {x:04X}H, as the manual says")
                }
                (Some(x), None)
                    if p.comparison
                        .findings
                        .iter()
                        .all(|f| f.severity == super::super::Severity::Observation) =>
                {
                    v.findings
                        .retain(|f| f.severity != super::super::Severity::Observation);
                    v.findings.push(Finding::observation(format!(
                        "{register:04X}H reads {x:04X}H; the manual gives no value"
                    )))
                }
                _ => {}
            }
            Ok(v)
        },
    ));
}

/// A check that reads `count` registers from `start` and judges the answer against the
/// model (the map's probes of one register, the reads across two blocks).
fn read_check(id: String, title: String, source: String, start: u16, count: u16) -> Check {
    probe_check(id, title, source, false, move |ctx| {
        ctx.frame(Pdu::ReadRequest { start, count })
    })
}

pub(super) fn map(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    for g in &model.groups {
        if g.name.starts_with("example") {
            continue;
        }
        let name = slug(&g.name);
        let source = format!("{}, {}", model.manual, g.source);
        let accessible: Vec<u16> = g.registers.iter().flat_map(|r| r.clone()).collect();
        let (Some(&first), Some(&last)) = (accessible.first(), accessible.last()) else {
            continue;
        };
        for (which, r) in [("first", first), ("last", last)] {
            out.push(read_check(
                format!("{m}.map.{name}.{which}"),
                format!("Read the {which} register of {} ({r:04X}H)", g.name),
                source.clone(),
                r,
                1,
            ));
        }
        if g.parameter_group.is_none() {
            let count = u16::try_from(g.span.clone().count()).unwrap_or(u16::MAX);
            let start = *g.span.start();
            out.push(probe_check(
                format!("{m}.map.{name}.whole"),
                format!("Read the whole {} block ({start:04X}H, {count} registers, within the mode's limit)", g.name),
                source.clone(),
                false,
                move |ctx| {
                    let limit = ctx.model.limits.read.get(ctx.mode);
                    ctx.frame(Pdu::ReadRequest { start, count: count.min(limit) })
                },
            ));
        }
        let past = g.span.end().wrapping_add(1);
        if model.lookup(past).is_none() {
            out.push(read_check(
                format!("{m}.map.{name}.past-end"),
                format!(
                    "Read one register past the end of {} ({past:04X}H, not in the map)",
                    g.name
                ),
                source.clone(),
                past,
                1,
            ));
        }
        for w in g.registers.windows(2) {
            let gap = w[0].end() + 1;
            if model.lookup(gap).is_none() {
                out.push(read_check(
                    format!("{m}.map.{name}.gap-{gap:04X}"),
                    format!("Read {gap:04X}H, in a gap of {} (not in the table)", g.name),
                    source.clone(),
                    gap,
                    1,
                ));
            }
        }
        if let Some(na) = g.no_access.first() {
            let r = *na.start();
            out.push(read_check(
                format!("{m}.map.{name}.no-access-{r:04X}"),
                format!("Read {r:04X}H, marked '-' (no Modbus access) in {}", g.name),
                source.clone(),
                r,
                1,
            ));
        }
    }
    // Reserved registers read 0000H (a decision).
    if let Some(r) = model
        .named
        .iter()
        .find(|n| n.access == Access::Reserved)
        .map(|n| n.register)
    {
        let Some(rule) = model.rule(crate::model::Fault::ReservedWrite) else {
            out.push(undescribed_field(
                model,
                format!("{m}.map.reserved-reads-zero"),
                format!("Read the reserved register {r:04X}H"),
                "exceptions.reserved-write",
            ));
            return;
        };
        let fact = rule.fact.clone();
        out.push(check(
            format!("{m}.map.reserved-reads-zero"),
            format!("Read the reserved register {r:04X}H"),
            cite(model, &fact),
            false,
            false,
            move |ctx| {
                let frame = ctx.frame(Pdu::ReadRequest { start: r, count: 1 });
                let p = ctx.probe(frame, Some((vec![Some(0)], fact.clone())))?;
                Ok(verdict(
                    &[&p],
                    format!("{r:04X}H reads 0000H (model decision)"),
                ))
            },
        ));
    }
}

pub(super) fn counts(model: &DriveModel, mode: Mode, m: &str, out: &mut Vec<Check>) {
    let limit = model.limits.read.get(mode);
    let runs = readable_runs(model);
    let start = runs
        .iter()
        .find(|(_, n)| *n > limit)
        .or_else(|| runs.iter().max_by_key(|(_, n)| *n))
        .map(|(s, _)| *s)
        .unwrap_or(0);
    let source = cite(model, &model.limits.read.fact);
    for (name, count) in [
        ("zero", 0),
        ("one", 1),
        ("limit", limit),
        ("over-limit", limit + 1),
    ] {
        out.push(probe_check(
            format!("{m}.read-count.{name}"),
            format!("Read {count} registers from {start:04X}H (the {mode} read limit is {limit})"),
            source.clone(),
            false,
            move |ctx| ctx.frame(Pdu::ReadRequest { start, count }),
        ));
    }
    // Same-group rule: a read across the command and monitor blocks.
    if let (Some(c), Some(mon)) = (model.group("command"), model.group("monitor")) {
        let from = *c.span.end();
        if *mon.span.start() == from + 1 {
            out.push(read_check(
                format!("{m}.same-group"),
                format!("Read 2 registers from {from:04X}H, across the command and monitor blocks"),
                cite(model, &model.limits.same_group_fact),
                from,
                2,
            ));
        }
    }
    // The same rule between two adjacent blocks of a description (v2): a read across
    // them is served unless limits.same_group says a block is a group.
    if model.group("command").is_none() {
        if let Some(w) = model
            .blocks
            .windows(2)
            .find(|w| w[0].span.end().checked_add(1) == Some(*w[1].span.start()))
        {
            let from = *w[0].span.end();
            let names = |b: &crate::model::Block| {
                b.name
                    .clone()
                    .unwrap_or_else(|| format!("block {:04X}", b.span.start()))
            };
            out.push(read_check(
                format!("{m}.same-group"),
                format!(
                    "Read 2 registers from {from:04X}H, across the blocks {} and {}",
                    names(&w[0]),
                    names(&w[1])
                ),
                cite(model, &model.limits.same_group_fact),
                from,
                2,
            ));
        }
    }
    // Write counts: a value-preserving write of the limit, a write of 0, and one over
    // the limit (a frame over 80 bytes).
    let wlimit = model.limits.write.get(mode);
    let wsource = cite(model, &model.limits.write.fact);
    let wstart = runs
        .iter()
        .find(|(s, n)| {
            *n > wlimit
                && model
                    .lookup(*s)
                    .is_some_and(|i| i.access == Access::ReadWrite)
                && (0..=wlimit).all(|k| {
                    model
                        .lookup(s + k)
                        .is_some_and(|i| i.access == Access::ReadWrite)
                })
        })
        .map(|(s, _)| *s);
    if let Some(wstart) = wstart {
        for (name, count) in [("limit", wlimit), ("over-limit", wlimit + 1)] {
            let title = if name == "limit" {
                format!("Write {count} registers from {wstart:04X}H with the values they hold (the {mode} write limit is {wlimit}), and read them back")
            } else {
                format!("Write {count} registers from {wstart:04X}H with the values they hold: one over the limit, a frame over {} bytes", model.limits.max_frame_in(mode))
            };
            let src = if name == "limit" {
                wsource.clone()
            } else {
                format!(
                    "{wsource}; {}",
                    cite_or(
                        model,
                        model
                            .silence
                            .get(&crate::model::SilenceReason::FrameTooLong),
                        "silence.frame-too-long"
                    )
                )
            };
            out.push(check(
                format!("{m}.write-count.{name}"),
                title,
                src,
                true,
                false,
                move |ctx| {
                    let values = match read_in_pieces(ctx, wstart, count)? {
                        Ok(v) => v,
                        Err(e) => {
                            return Ok(Verdict::setup_failed(
                                "read the values to write back first",
                                e,
                            ))
                        }
                    };
                    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
                    let Ok(regs) = Registers::new(&bytes) else {
                        return Ok(Verdict::error("internal: odd register bytes"));
                    };
                    let frame = ctx.frame(Pdu::WriteMultipleRequest {
                        start: wstart,
                        values: regs,
                    });
                    let p = ctx.probe(frame, None)?;
                    let mut v = verdict(&[&p], pass_text(&p));
                    // The values must be unchanged either way.
                    let after = match read_in_pieces(ctx, wstart, count)? {
                        Ok(x) => x,
                        Err(e) => {
                            v.findings
                                .push(Finding::deviation(format!("read-back failed: {e}")));
                            return Ok(v);
                        }
                    };
                    if after != values {
                        v.findings.push(Finding::deviation(format!(
                            "the registers changed: before {:04X?}, after {:04X?}",
                            values, after
                        )));
                    }
                    Ok(v)
                },
            ));
        }
    }
    out.push(probe_check(
        format!("{m}.write-count.zero"),
        "Write 0 registers (10H with count 0)".to_string(),
        wsource,
        true,
        move |ctx| {
            ctx.frame(Pdu::WriteMultipleRequest {
                start: wstart.unwrap_or(0),
                values: Registers::new(&[]).unwrap_or_else(|_| unreachable_regs()),
            })
        },
    ));
}

fn unreachable_regs() -> Registers<'static> {
    // Registers::new only fails on an odd length; the empty slice is even.
    match Registers::new(&[]) {
        Ok(r) => r,
        Err(_) => unreachable!("an empty register list is valid"),
    }
}

/// `count` registers from `start`, read in pieces of at most the mode's read limit (a
/// write may cover more than one read can); the first piece refused or unanswered ends it.
fn read_in_pieces(
    ctx: &mut Ctx<'_>,
    start: u16,
    count: u16,
) -> Result<Result<Vec<u16>, crate::runner::SetupError>, RunError> {
    let limit = ctx.model.limits.read.get(ctx.mode);
    let mut values = Vec::new();
    let mut at = 0u16;
    while at < count {
        let n = (count - at).min(limit);
        match ctx.read(start + at, n)? {
            Ok(v) => values.extend(v),
            Err(e) => return Ok(Err(e)),
        }
        at += n;
    }
    Ok(Ok(values))
}
