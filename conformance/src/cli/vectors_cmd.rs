//! `conformance vectors list|verify|export`.

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context};
use clap::{Args, Subcommand, ValueEnum};
use conformance::vectors::{self, export::export_json, VectorSet, Verdict};

#[derive(Debug, Args)]
pub struct VectorsArgs {
    /// Read the vector files from this directory instead of the copies built into the
    /// binary (flags.json and <document>.json).
    #[arg(long, global = true)]
    dir: Option<PathBuf>,
    #[command(subcommand)]
    command: VectorsCommand,
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum VerdictArg {
    Consistent,
    Erratum,
    Incomplete,
}

impl From<VerdictArg> for Verdict {
    fn from(v: VerdictArg) -> Verdict {
        match v {
            VerdictArg::Consistent => Verdict::Consistent,
            VerdictArg::Erratum => Verdict::Erratum,
            VerdictArg::Incomplete => Verdict::Incomplete,
        }
    }
}

#[derive(Debug, Clone, Copy, ValueEnum)]
enum ExportFormat {
    Json,
}

#[derive(Debug, Subcommand)]
enum VectorsCommand {
    /// A table of the vectors.
    List {
        /// Only this document: f510, a510, l510, e510, l510-legacy.
        #[arg(long)]
        model: Option<String>,
        /// Only vectors with this flag.
        #[arg(long)]
        flag: Option<String>,
        /// Only vectors with this verdict.
        #[arg(long, value_enum)]
        verdict: Option<VerdictArg>,
        /// Print each vector's decoded rendering too.
        #[arg(long)]
        long: bool,
    },
    /// Check every vector with the codec; exit 0 only when each behaves as its verdict says
    /// and no document lacks an item.
    Verify {
        /// Print only the vectors that fail, and the summary.
        #[arg(short, long)]
        quiet: bool,
    },
    /// Write every vector and the flags table as one JSON document.
    Export {
        /// Output format.
        #[arg(long, value_enum, default_value = "json")]
        format: ExportFormat,
        /// Write to this file instead of standard output.
        #[arg(long, short)]
        output: Option<PathBuf>,
    },
    /// Write seed inputs for the fuzz targets, made from the vectors, into
    /// DIR/<target>/ (e.g. fuzz/corpus).
    SeedCorpus {
        /// Directory to write into (created if missing).
        #[arg(value_name = "OUT_DIR")]
        out: PathBuf,
    },
}

fn load(dir: &Option<PathBuf>) -> anyhow::Result<VectorSet> {
    Ok(match dir {
        Some(d) => VectorSet::load_dir(d)
            .with_context(|| format!("loading vectors from {}", d.display()))?,
        None => VectorSet::builtin().context("loading the built-in vectors")?,
    })
}

pub fn run(args: VectorsArgs) -> anyhow::Result<ExitCode> {
    let set = load(&args.dir)?;
    match args.command {
        VectorsCommand::List {
            model,
            flag,
            verdict,
            long,
        } => {
            if let Some(m) = &model {
                if !vectors::DOCUMENTS.contains(&m.as_str()) {
                    bail!("--model {m:?}: expected one of {:?}", vectors::DOCUMENTS);
                }
            }
            if let Some(f) = &flag {
                if !set.flags.flags.contains_key(f) {
                    bail!(
                        "--flag {f:?}: not a flag; flags are {:?}",
                        set.flags.flags.keys().collect::<Vec<_>>()
                    );
                }
            }
            let verdict: Option<Verdict> = verdict.map(Into::into);
            println!("{:<34} {:<16} {:<11} flags", "id", "type", "verdict");
            let mut n = 0;
            for (file, v) in set.iter() {
                if model.as_ref().is_some_and(|m| *m != file.document)
                    || flag.as_ref().is_some_and(|f| !v.flags.contains(f))
                    || verdict.is_some_and(|x| x != v.verdict)
                {
                    continue;
                }
                n += 1;
                println!(
                    "{:<34} {:<16} {:<11} {}",
                    v.id,
                    v.body.type_name(),
                    v.verdict.to_string(),
                    v.flags.join(",")
                );
                if long {
                    print!("{}", vectors::render_in(&set, v));
                }
            }
            println!("{n} vectors");
            Ok(ExitCode::SUCCESS)
        }
        VectorsCommand::Verify { quiet } => {
            let reports = vectors::verify_all(&set);
            let missing = vectors::missing(&set);
            let failed: Vec<_> = reports.iter().filter(|r| !r.passed()).collect();
            println!("{:<34} {:<11} {:<40} result", "id", "verdict", "flags");
            for r in &reports {
                if !quiet || !r.passed() {
                    println!(
                        "{:<34} {:<11} {:<40} {}",
                        r.id,
                        r.verdict.to_string(),
                        r.flags.join(","),
                        if r.passed() { "ok" } else { "FAIL" }
                    );
                    for p in &r.problems {
                        println!("    - {p}");
                    }
                }
            }
            for m in &missing {
                println!("missing: {m}");
            }
            let count = |v: Verdict| reports.iter().filter(|r| r.verdict == v).count();
            println!(
                "{} vectors: {} consistent, {} erratum, {} incomplete; {} behave as their verdict says, {} do not; {} required items missing",
                reports.len(),
                count(Verdict::Consistent),
                count(Verdict::Erratum),
                count(Verdict::Incomplete),
                reports.len() - failed.len(),
                failed.len(),
                missing.len()
            );
            Ok(if failed.is_empty() && missing.is_empty() {
                ExitCode::SUCCESS
            } else {
                ExitCode::from(1)
            })
        }
        VectorsCommand::SeedCorpus { out } => {
            let texts = match &args.dir {
                Some(d) => vectors::DOCUMENTS
                    .iter()
                    .map(|doc| {
                        let name = format!("{doc}.json");
                        let path = d.join(&name);
                        std::fs::read_to_string(&path)
                            .with_context(|| format!("reading {}", path.display()))
                            .map(|t| (name, t))
                    })
                    .collect::<anyhow::Result<Vec<_>>>()?,
                None => VectorSet::builtin_texts(),
            };
            let seeds = conformance::seeds::seeds(&set, &texts);
            for s in &seeds {
                let target_dir = out.join(s.target);
                std::fs::create_dir_all(&target_dir)
                    .with_context(|| format!("creating {}", target_dir.display()))?;
                let path = target_dir.join(&s.name);
                std::fs::write(&path, &s.bytes)
                    .with_context(|| format!("writing {}", path.display()))?;
            }
            println!("{} seeds written under {}", seeds.len(), out.display());
            Ok(ExitCode::SUCCESS)
        }
        VectorsCommand::Export { format, output } => {
            let ExportFormat::Json = format;
            let doc = export_json(&set);
            let text = serde_json::to_string_pretty(&doc)? + "\n";
            match output {
                Some(path) => std::fs::write(&path, text)
                    .with_context(|| format!("writing {}", path.display()))?,
                None => std::io::stdout().lock().write_all(text.as_bytes())?,
            }
            Ok(ExitCode::SUCCESS)
        }
    }
}
