//! The identification as people and machines read it: text (verdict first, then the
//! score of each model with the probes it missed, then every probe with the request, the
//! reply and which models predicted it) and JSON; and as one check result, which heads
//! the report of `check --model auto`.

use std::fmt::Write as _;
use std::time::Duration;

use serde_json::{json, Value};

use super::{Identification, ProbeResult, Verdict};
use crate::codec::hex::Hex;
use crate::judge::show;
use crate::runner::{CheckResult, Finding, Status};

/// The verdict in one line.
pub fn headline(id: &Identification) -> String {
    let score = |m: &str| id.scores.iter().find(|s| s.model == m);
    let of = |m: &str| {
        score(m)
            .map(|s| format!("{} of {} answers predicted", s.predicted, s.probes))
            .unwrap_or_default()
    };
    let runner_up = |best: &[String]| {
        let mut rest: Vec<_> = id
            .scores
            .iter()
            .filter(|s| !best.contains(&s.model))
            .collect();
        rest.sort_by_key(|s| s.misses.len());
        rest.first()
            .map(|s| format!("; next: {} with {} of {}", s.model, s.predicted, s.probes))
            .unwrap_or_default()
    };
    match &id.verdict {
        Verdict::One(m) => format!(
            "{m} ({}): {}{}",
            score(m).map(|s| s.manual.as_str()).unwrap_or(""),
            of(m),
            runner_up(std::slice::from_ref(m))
        ),
        Verdict::Ambiguous(ms) => format!(
            "ambiguous between {}: each predicted {}{}",
            ms.join(", "),
            of(&ms[0]),
            runner_up(ms)
        ),
        Verdict::NoneOfThem { nearest } => format!(
            "none of the five: no model predicts the answers (nearest: {}, {}, missed {})",
            nearest.join(", "),
            nearest.first().map(|m| of(m)).unwrap_or_default(),
            nearest
                .first()
                .and_then(|m| score(m))
                .map(|s| s.misses.join(" "))
                .unwrap_or_default()
        ),
        Verdict::NotRun(why) => format!("could not identify: {why}"),
    }
}

fn models_where(id: &Identification, p: &ProbeResult, fit: bool) -> Vec<String> {
    id.models
        .iter()
        .zip(&p.fits)
        .filter(|(_, f)| **f == fit)
        .map(|(m, _)| m.clone())
        .collect()
}

/// The text report.
pub fn text(id: &Identification) -> String {
    let mut s = String::new();
    let _ = writeln!(
        s,
        "TECO model identification (teco-modbus-conformance {})",
        env!("CARGO_PKG_VERSION")
    );
    let _ = writeln!(s, "VERDICT: {}", headline(id));
    let _ = writeln!(
        s,
        "device:  node {:02X}{}",
        id.address,
        match &id.simulated {
            Some((m, q)) if q.is_empty() => format!(", simulated by this suite ({m})"),
            Some((m, q)) => format!(", simulated by this suite ({m}, quirks: {})", q.join(", ")),
            None => String::new(),
        }
    );
    for l in &id.links {
        let _ = writeln!(
            s,
            "link:    {}: {}{}",
            l.mode,
            l.link,
            if l.echo == Some(true) {
                " (local echo: stripped)"
            } else {
                ""
            }
        );
    }
    let _ = writeln!(s, "line:    {}", id.line);
    // Descriptions given with --model-file: each named by its file, title and hash (the
    // built-in five by the suite's version on the first line).
    for (m, src) in id.models.iter().zip(&id.sources) {
        if let Some(file) = &src.file {
            let _ = writeln!(
                s,
                "model:   {m} from {file}, {:?}, sha256 {}",
                src.title, src.sha256
            );
        }
    }
    let per_mode: Vec<String> = id
        .links
        .iter()
        .map(|l| {
            format!(
                "{}: {} reads chosen from {} on which the models disagree",
                l.mode,
                id.probes.iter().filter(|p| p.mode == l.mode).count(),
                l.candidates
            )
        })
        .collect();
    let _ = writeln!(
        s,
        "probes:  {}; reads (03H) only, nothing written",
        per_mode.join("; ")
    );
    let _ = writeln!(s, "run:     {} .. {}", id.started, id.finished);
    let _ = writeln!(s);
    let _ = writeln!(s, "SCORES (answers each model predicted exactly)");
    for sc in &id.scores {
        let against = if sc.misses.is_empty() {
            "predicted every answer".to_string()
        } else {
            format!("missed {}", sc.misses.join(" "))
        };
        let _ = writeln!(
            s,
            "  {:<12} {:>3}/{:<3} {against}",
            sc.model, sc.predicted, sc.probes
        );
    }
    for st in &id.statics {
        let _ = writeln!(s, "  against {}: {}", st.model, st.text);
    }
    if id.tolerance > 0 {
        let _ = writeln!(
            s,
            "  (--tolerance {}: a model may miss that many answers and still be named)",
            id.tolerance
        );
    }
    let _ = writeln!(s);
    let _ = writeln!(s, "EVIDENCE ({} probes)", id.probes.len());
    for p in &id.probes {
        let c = &p.probe.candidate;
        let _ = writeln!(
            s,
            "  [{}] {}: read {} from {:04X}H ({})",
            p.id,
            c.kind.key(),
            c.count,
            c.start,
            c.why
        );
        let _ = writeln!(s, "      request  {}", show(p.mode, &p.exchange.request));
        let _ = writeln!(
            s,
            "      reply    {}",
            match &p.exchange.reply {
                Some(r) => format!("{} = {}", show(p.mode, r), p.answer),
                None if p.exchange.received.is_empty() => "nothing (no reply)".to_string(),
                None => format!("{} = {}", show(p.mode, &p.exchange.received), p.answer),
            }
        );
        let yes = models_where(id, p, true);
        let no = models_where(id, p, false);
        let _ = writeln!(
            s,
            "      for      {}",
            if yes.is_empty() {
                "no model".to_string()
            } else {
                yes.join(" ")
            }
        );
        // Against: the models that predicted something else, grouped by what.
        let mut groups: Vec<(String, Vec<String>)> = Vec::new();
        for m in &no {
            let Some(mp) = p.probe.predictions.iter().find(|x| &x.model == m) else {
                continue;
            };
            let what = format!("{} ({}; {})", mp.prediction, mp.detail, mp.basis);
            match groups.iter_mut().find(|(w, _)| *w == what) {
                Some((_, ms)) => ms.push(m.clone()),
                None => groups.push((what, vec![m.clone()])),
            }
        }
        for (what, ms) in groups {
            let _ = writeln!(s, "      against  {}: predicted {what}", ms.join(" "));
        }
    }
    if let Verdict::One(m) = &id.verdict {
        if let Some((sim, _)) = &id.simulated {
            if sim != m {
                let _ = writeln!(
                    s,
                    "\nNOTE: the simulator runs {sim}, and the answers were those of {m}"
                );
            }
        }
    }
    s
}

/// The JSON report (schema: `vectors/schema/identify.schema.json`).
pub fn json(id: &Identification) -> Value {
    let probes: Vec<Value> = id
        .probes
        .iter()
        .map(|p| {
            let c = &p.probe.candidate;
            json!({
                "id": p.id,
                "mode": p.mode.to_string(),
                "kind": c.kind.key(),
                "start": format!("{:04X}", c.start),
                "count": c.count,
                "why": c.why,
                "request": Hex(&p.exchange.request).to_string(),
                "received": Hex(&p.exchange.received).to_string(),
                "reply": p.exchange.reply.as_ref().map(|b| Hex(b).to_string()),
                "answer": p.answer.describe(),
                "latency_ms": p.exchange.latency.map(|d| (d.as_secs_f64() * 1e6).round() / 1e3),
                "predictions": p.probe.predictions.iter().zip(&p.fits).map(|(mp, fit)| json!({
                    "model": mp.model,
                    "prediction": mp.prediction.describe(),
                    "detail": mp.detail,
                    "basis": mp.basis.to_string(),
                    "fits": fit,
                })).collect::<Vec<_>>(),
            })
        })
        .collect();
    json!({
        "schema": "teco-modbus-conformance/identify",
        "schema_version": 1,
        "kind": "identify",
        "tool": format!("teco-modbus-conformance {}", env!("CARGO_PKG_VERSION")),
        "started": id.started,
        "finished": id.finished,
        "verdict": {
            "result": id.verdict.key(),
            "models": id.verdict.models(),
            "text": headline(id),
            "exit_code": id.verdict.exit_code(),
        },
        "device": {
            "address": format!("{:02X}", id.address),
            "line": id.line,
            "simulated": id.simulated.as_ref().map(|(m, q)| json!({"model": m, "quirks": q})),
        },
        "links": id.links.iter().map(|l| json!({
            "mode": l.mode.to_string(),
            "link": l.link,
            "preflight": l.preflight,
            "candidates": l.candidates,
            "echo": l.echo,
        })).collect::<Vec<_>>(),
        "tolerance": id.tolerance,
        "candidates": id.models.iter().zip(&id.sources).map(|(m, s)| json!({
            "model": m,
            "file": s.file,
            "title": s.title,
            "sha256": s.sha256,
        })).collect::<Vec<_>>(),
        "scores": id.scores.iter().map(|s| json!({
            "model": s.model,
            "manual": s.manual,
            "predicted": s.predicted,
            "probes": s.probes,
            "misses": s.misses,
        })).collect::<Vec<_>>(),
        "static": id.statics.iter().map(|s| json!({"model": s.model, "text": s.text})).collect::<Vec<_>>(),
        "probes": probes,
    })
}

/// The identification as one check result ("identify"), PASS when it named one model:
/// the head of the report of `check --model auto`.
pub fn check_result(id: &Identification, took: Duration) -> CheckResult {
    let (status, findings) = match &id.verdict {
        Verdict::One(_) => (Status::Pass, vec![]),
        Verdict::NotRun(why) => (Status::Error, vec![Finding::deviation(why.clone())]),
        _ => (Status::Error, vec![Finding::deviation(headline(id))]),
    };
    CheckResult {
        id: "identify".into(),
        title: "Which manual the device follows (--model auto), from reads only".into(),
        mode: None,
        source: format!(
            "the five models ({}): the probes on which their predictions differ",
            id.models.join(", ")
        ),
        status,
        summary: headline(id),
        findings,
        exchanges: id.probes.iter().map(|p| p.exchange.clone()).collect(),
        duration: took,
        node: None,
    }
}
