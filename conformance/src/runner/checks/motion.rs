//! Checks that move the motor (run/stop, external fault): only with --allow-motion.

use std::time::Duration;

use super::*;

pub(super) fn motion(model: &DriveModel, m: &str, out: &mut Vec<Check>) {
    let (Some(op), Some(st)) = (
        model.register_with_role(Role::Operation),
        model.register_with_role(Role::Status),
    ) else {
        return;
    };
    let bits = model.bits;
    let fc = model.register_with_role(Role::FrequencyCommand);
    let outf = model.register_with_role(Role::OutputFrequency);
    let src = model
        .named(op)
        .and_then(|n| n.fact.source.clone())
        .unwrap_or_default();
    let source = format!("{}, {src}", model.manual);
    if let (Some(run), Some(running)) = (bits.run, bits.running) {
        out.push(check(
            format!("{m}.motion.run-stop"),
            format!("Run at 10.00 Hz ({op:04X}H bit {run}), watch {st:04X}H and the output frequency, then stop"),
            source.clone(),
            true,
            true,
            move |ctx| {
                let mut findings = Vec::new();
                for r in [Some(op), fc].into_iter().flatten() {
                    if let Err(e) = ctx.remember(r)? {
                        return Ok(Verdict::setup_failed(&format!("read {r:04X}H first"), e));
                    }
                }
                if let Some(f) = fc {
                    if let Err(e) = ctx.write(f, 1000)? {
                        return Ok(Verdict::setup_failed(&format!("write 03E8H (10.00 Hz) to {f:04X}H first"), e));
                    }
                }
                let w = command(ctx, op, 1 << run, &mut findings)?;
                std::thread::sleep(Duration::from_millis(300));
                status_bit(ctx, (st, running, "running"), true, "the run command", &mut findings)?;
                if let Some(o) = outf {
                    let mut moving = false;
                    for _ in 0..30 {
                        if let Ok(v) = ctx.read(o, 1)? {
                            if v[0] > 0 {
                                moving = true;
                                break;
                            }
                        }
                        std::thread::sleep(Duration::from_millis(100));
                    }
                    if !moving {
                        findings.push(Finding::observation(format!("the output frequency {o:04X}H stayed 0 for 3 s after the run command (acceleration time?)")));
                    }
                }
                let s = command(ctx, op, 0, &mut findings)?;
                let mut stopped = false;
                for _ in 0..100 {
                    if let Ok(v) = ctx.read(st, 1)? {
                        if v[0] & (1 << running) == 0 {
                            stopped = true;
                            break;
                        }
                    }
                    std::thread::sleep(Duration::from_millis(100));
                }
                if !stopped {
                    findings.push(Finding::deviation(format!("{st:04X}H bit {running} (running) still set 10 s after the stop command")));
                }
                Ok(Verdict {
                    findings,
                    exchanges: vec![w.record(), s.record()],
                    pass_summary: format!("{st:04X}H bit {running} follows the run command, the output frequency rises, and the drive stops"),
                    ..Verdict::default()
                })
            },
        ));
    }
    if let (Some(ef), Some(reset), Some(fault)) =
        (bits.external_fault, bits.fault_reset, bits.fault)
    {
        let code = model.external_fault_code.clone();
        let fault_reg = model.register_with_role(Role::FaultCode);
        out.push(check(
            format!("{m}.motion.external-fault"),
            format!("Raise an external fault ({op:04X}H bit {ef}), read {st:04X}H and the fault code, then reset it (bit {reset})"),
            source,
            true,
            true,
            move |ctx| {
                let mut findings = Vec::new();
                if let Err(e) = ctx.remember(op)? {
                    return Ok(Verdict::setup_failed(&format!("read {op:04X}H first"), e));
                }
                let w = command(ctx, op, 1 << ef, &mut findings)?;
                std::thread::sleep(Duration::from_millis(200));
                status_bit(ctx, (st, fault, "fault"), true, "the external fault", &mut findings)?;
                if let (Some(fr), Some((c, fact))) = (fault_reg, &code) {
                    match ctx.read(fr, 1)? {
                        Ok(v) if v[0] == *c && fact.basis == Basis::Decision => {
                            findings.push(Finding::observation(format!(
                                "fault code {fr:04X}H reads {c}, as the model decides ({})",
                                fact.citation()
                            )))
                        }
                        Ok(v) if v[0] == *c => {}
                        Ok(v) => findings.push(Finding {
                            severity: super::super::Severity::of(fact.basis),
                            text: format!("fault code {fr:04X}H reads {} (model: {c}, {})", v[0], fact.citation()),
                        }),
                        Err(e) => findings.push(Finding::deviation(e.to_string())),
                    }
                }
                let r = command(ctx, op, 1 << reset, &mut findings)?;
                std::thread::sleep(Duration::from_millis(200));
                let _ = ctx.write(op, 0)?;
                status_bit(ctx, (st, fault, "fault"), false, "the fault reset", &mut findings)?;
                Ok(Verdict {
                    findings,
                    exchanges: vec![w.record(), r.record()],
                    pass_summary: format!("{st:04X}H bit {fault} shows the external fault and clears on reset"),
                    ..Verdict::default()
                })
            },
        ));
    }
}

/// Writes `value` to the operation register `op` as a probed exchange, its findings kept.
fn command(
    ctx: &mut Ctx<'_>,
    op: u16,
    value: u16,
    findings: &mut Vec<Finding>,
) -> Result<Probed, RunError> {
    let p = ctx.probe(
        ctx.frame(Pdu::WriteSingle {
            register: op,
            value,
        }),
        None,
    )?;
    findings.extend(p.comparison.findings.clone());
    Ok(p)
}

/// Reads the status register `st` after `after` ("the run command") and holds its bit
/// `bit` (named `name`) to `set`: a deviation if it differs or the read fails.
fn status_bit(
    ctx: &mut Ctx<'_>,
    (st, bit, name): (u16, u8, &str),
    set: bool,
    after: &str,
    findings: &mut Vec<Finding>,
) -> Result<(), RunError> {
    match ctx.read(st, 1)? {
        Ok(v) if (v[0] & (1 << bit) != 0) == set => {}
        Ok(v) => findings.push(Finding::deviation(format!(
            "after {after} {st:04X}H reads {:04X}H: bit {bit} ({name}) is {}",
            v[0],
            if set { "0" } else { "still 1" }
        ))),
        Err(e) => findings.push(Finding::deviation(e.to_string())),
    }
    Ok(())
}
