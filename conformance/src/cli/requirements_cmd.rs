//! `conformance requirements`: the manuals' requirements, what verifies each, and the
//! coverage per document.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use conformance::report::requirements as render;
use conformance::requirements::trace::{self, Universe};
use conformance::requirements::Catalogue;

use super::output::write_atomic;

const AFTER_HELP: &str = "\
Every statement of the five manuals' Modbus chapters that a tester could observe on the
wire is a requirement with an id (f510.REQ-012), its quote and line in the manual, and
the checks, golden vectors, model facts, monitor kinds and fuzz oracle classes that verify
it (vectors/requirements/<document>.json). Coverage, per document:
  check              verified by a check of `conformance check`
  vectors-or-model   covered only by the golden vectors, the model's facts or the fuzz oracle
  passive-only       verifiable only by listening (`conformance monitor`)
  not-on-wire        not observable on the wire (wiring, keypad, what the motor does)
  uncovered          nothing covers it; the reason says why

Examples:
  conformance requirements                       the coverage of all five manuals
  conformance requirements --doc f510 --matrix   and every requirement with its links
  conformance requirements --format html -o requirements.html
  conformance requirements --format csv --doc l510-legacy > l510-legacy.csv

Reports of `check` name the requirements each check verifies (JSON `requirements`, JUnit
properties, HTML links and a coverage section).

Exit codes: 0 printed; 1 a link names nothing that exists, or a check verifies no
requirement (--verify); 2 the command could not run.";

/// Output formats.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum ReqFormat {
    /// The coverage per document (and the matrix with --matrix).
    Text,
    /// Every requirement with its coverage, and the counts.
    Json,
    /// A page with the coverage and the matrix.
    Html,
    /// One row per requirement.
    Csv,
}

#[derive(Debug, Args)]
#[command(after_help = AFTER_HELP)]
pub struct RequirementsArgs {
    /// Only this document: f510, a510, l510, e510, l510-legacy.
    #[arg(long, value_name = "D")]
    doc: Option<String>,
    /// Output format (default: from the extension of -o, else text).
    #[arg(long, value_enum)]
    format: Option<ReqFormat>,
    /// With text: every requirement, its coverage and its links (the traceability matrix).
    #[arg(long)]
    matrix: bool,
    /// Also resolve every link against the checks, vectors, model facts, monitor kinds and
    /// oracle classes that exist, and list every check that verifies no requirement.
    #[arg(long)]
    verify: bool,
    /// Write here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
}

pub fn run(args: RequirementsArgs) -> anyhow::Result<ExitCode> {
    let all = Catalogue::builtin().context("a built-in requirements file is broken")?;
    let cats: Vec<&Catalogue> = match &args.doc {
        None => all.iter().collect(),
        Some(d) => match all.iter().find(|c| &c.document == d) {
            Some(c) => vec![c],
            None => bail!(
                "no document '{d}': the documents are {}",
                all.iter()
                    .map(|c| c.document.as_str())
                    .collect::<Vec<_>>()
                    .join(", ")
            ),
        },
    };
    let format = args.format.unwrap_or_else(|| {
        match args
            .output
            .as_ref()
            .and_then(|p| p.extension())
            .and_then(|e| e.to_str())
        {
            Some("json") => ReqFormat::Json,
            Some("html" | "htm") => ReqFormat::Html,
            Some("csv") => ReqFormat::Csv,
            _ => ReqFormat::Text,
        }
    });
    let mut text = match format {
        ReqFormat::Text => render::text(&cats, args.matrix),
        ReqFormat::Json => {
            let mut s = serde_json::to_string_pretty(&render::json(&cats))?;
            s.push('\n');
            s
        }
        ReqFormat::Html => render::html(&cats),
        ReqFormat::Csv => render::csv(&cats),
    };
    let mut problems = 0usize;
    if args.verify {
        let mut report = String::new();
        for cat in &cats {
            let u = Universe::of(cat, &all).map_err(anyhow::Error::msg)?;
            for p in trace::problems(cat, &u) {
                problems += 1;
                report.push_str(&format!("{}: {}\n", p.id, p.text));
            }
        }
        if problems == 0 {
            report.push_str(
                "every link names something that exists; every check verifies a requirement\n",
            );
        }
        if format == ReqFormat::Text {
            text.push_str(&report);
        } else {
            eprint!("{report}");
        }
    }
    match &args.output {
        Some(p) => {
            write_atomic(p, &text).with_context(|| format!("cannot write {}", p.display()))?
        }
        None => {
            let mut out = std::io::stdout().lock();
            // A closed pipe (`| head`) is not an error of this command.
            let _ = out.write_all(text.as_bytes());
        }
    }
    Ok(if problems > 0 {
        ExitCode::from(1)
    } else {
        ExitCode::SUCCESS
    })
}
