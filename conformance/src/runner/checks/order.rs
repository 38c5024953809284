//! Requests that break two rules at once, to show which rule the device checks first.
//!
//! The manuals do not say; the Modbus application protocol V1.1b3 does, in the state
//! diagram of each function (6.3 for 03H, 6.12 for 10H; 7 for the function code): the
//! function code first (01), then the quantity (03), then the address (02), then the
//! execution (04). The model follows that order, so a device that agrees PASSes, and one
//! that checks in another order is an OBSERVATION naming the rule it checked first.

use super::*;
use crate::model::Fault;

/// The first register after `from` that the model does not map.
fn unmapped_after(model: &DriveModel, from: u16) -> Option<u16> {
    (from..=u16::MAX).find(|&r| model.lookup(r).is_none())
}

pub(super) fn order(model: &DriveModel, mode: Mode, m: &str, out: &mut Vec<Check>) {
    let spec = "Modbus application protocol V1.1b3, 6.3, 6.12 and 7 (state diagrams: function code, then quantity, then address)";
    let _ = mode;
    let Some(unmapped) = model
        .group("monitor")
        .and_then(|g| unmapped_after(model, *g.span.end()))
        .or_else(|| unmapped_after(model, 0))
    else {
        return;
    };
    let cases: [(&str, String, Fault, Fault, bool, Builder); 3] = [
        (
            "read-count-zero-unmapped",
            format!("Read 0 registers from {unmapped:04X}H (not in the map): count and address are both wrong"),
            Fault::IllegalCount,
            Fault::IllegalRegister,
            false,
            Box::new(move |ctx: &Ctx<'_>| ctx.frame(Pdu::ReadRequest { start: unmapped, count: 0 })),
        ),
        (
            "write-count-zero-unmapped",
            format!("Write 0 registers (10H) at {unmapped:04X}H (not in the map): count and address are both wrong"),
            Fault::IllegalCount,
            Fault::IllegalRegister,
            true,
            Box::new(move |ctx: &Ctx<'_>| match Registers::new(&[]) {
                Ok(values) => ctx.frame(Pdu::WriteMultipleRequest { start: unmapped, values }),
                Err(_) => Vec::new(),
            }),
        ),
        (
            "unserved-function-count-zero",
            "Send function 04H (not served) with a count of 0: function and count are both wrong".to_string(),
            Fault::IllegalFunction,
            Fault::IllegalCount,
            false,
            Box::new(|ctx: &Ctx<'_>| {
                ctx.frame(Pdu::Other {
                    function: 0x04,
                    data: &[0x25, 0x20, 0x00, 0x00],
                })
            }),
        ),
    ];
    for (name, title, first, second, writes, build) in cases {
        let (Some(rule_a), Some(rule_b)) = (model.rule(first), model.rule(second)) else {
            let fields = [first, second]
                .into_iter()
                .filter(|f| model.rule(*f).is_none())
                .map(|f| format!("exceptions.{}", f.key()))
                .collect();
            out.push(undescribed_check(
                format!("{m}.order.{name}"),
                title,
                spec.to_string(),
                fields,
            ));
            continue;
        };
        let source = format!(
            "{spec}; {}: {} {:02X}H, {} {:02X}H",
            model.manual, first, rule_a.code, second, rule_b.code
        );
        let (a, b) = (rule_a.code, rule_b.code);
        out.push(check(
            format!("{m}.order.{name}"),
            title,
            source,
            writes,
            false,
            move |ctx| {
                let p = ctx.probe(build(ctx), None)?;
                let mut v = verdict(&[&p], pass_text(&p));
                let code = p
                    .exchange
                    .reply
                    .as_ref()
                    .and_then(|r| crate::judge::body_of(ctx.mode, r))
                    .and_then(|body| (body.len() == 3 && body[1] & 0x80 != 0).then_some(body[2]));
                match code {
                    Some(c) if a == b && c == a => {
                        v.findings.retain(|f| !is_about_the_code(f));
                        v.pass_summary = format!(
                            "exception {c:02X}H; both rules give {c:02X}H here, so the order cannot be told"
                        );
                    }
                    Some(c) if c == a => {
                        v.findings.retain(|f| !is_about_the_code(f));
                        v.pass_summary = format!(
                            "exception {c:02X}H: the device checks the {first} rule before the {second} rule, in the Modbus application protocol's order"
                        );
                    }
                    Some(c) if c == b => {
                        // The code is explained here; what else is wrong with the reply
                        // (bytes around it, its timing) stays.
                        v.findings.retain(|f| !is_about_the_code(f));
                        let or_serves = if first == Fault::IllegalFunction {
                            " (or it serves this function, which the manual does not list: see the function checks)"
                        } else {
                            ""
                        };
                        v.findings.push(Finding::observation(format!(
                            "exception {c:02X}H: the device checks the {second} rule before the {first} rule{or_serves}; the Modbus application protocol checks {first} first ({a:02X}H)"
                        )));
                    }
                    // Another code, a normal reply, silence: the plain comparison says it.
                    _ => {}
                }
                Ok(v)
            },
        ));
    }
}

type Builder = Box<dyn Fn(&Ctx<'_>) -> Vec<u8>>;

/// Whether a finding of the plain comparison is about which exception code came (the
/// model's prediction against the code, or the note that the prediction is a decision),
/// which the order check replaces with its own account.
fn is_about_the_code(f: &Finding) -> bool {
    f.text.starts_with("manual: ") || f.text.starts_with("the manual does not settle this")
}
