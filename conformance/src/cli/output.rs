//! How every command hands over its result: the report formats and the choice among
//! them, writing a file so that it is always whole, the closing summary and exit code,
//! quoting a word for the reproduce lines that reports print, and the progress bar.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::Context;
use clap::ValueEnum;
use conformance::report::{csv, html, junit, text, Report};

/// A progress bar of `len` steps in `template` on stderr; none where `quiet` or stderr is
/// not a terminal (a log or a pipe gets no bar).
pub fn progress_bar(quiet: bool, len: u64, template: &str) -> Option<indicatif::ProgressBar> {
    use std::io::IsTerminal;
    (!quiet && std::io::stderr().is_terminal())
        .then(|| styled(indicatif::ProgressBar::new(len), template))
}

/// `bar` drawn in `template` (indicatif's plain bar where the template does not parse).
pub fn styled(bar: indicatif::ProgressBar, template: &str) -> indicatif::ProgressBar {
    bar.set_style(
        indicatif::ProgressStyle::with_template(template)
            .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
    );
    bar
}

/// Report format.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum Format {
    /// Human text: summary, then deviations first.
    Text,
    /// JSON (schema: vectors/schema/report.schema.json).
    Json,
    /// JUnit XML: one test case per check, deviations as failures.
    Junit,
    /// One self-contained HTML page: summary, deviations with their frames, plots, every
    /// check (filterable), the restore journal.
    Html,
    /// CSV: one row per check (id, mode, status, title, source, summary), RFC 4180.
    Csv,
}

/// What `--format` says where the option is left out.
pub const FORMAT_DEFAULT: &str = "Report format. Default: text; with -o, the format the file's extension names (.html, .json, .xml for JUnit, .csv; any other: text).";

/// The report's format: the one asked for, else the one `-o`'s extension names, else
/// text (a terminal gets text, never a page of HTML it did not ask for; `-o run.json`
/// gets JSON, not text in a file named .json).
pub fn format_for(asked: Option<Format>, output: Option<&Path>) -> Format {
    let by_extension = || {
        let ext = output?.extension()?.to_str()?.to_ascii_lowercase();
        Some(match ext.as_str() {
            "html" | "htm" => Format::Html,
            "json" => Format::Json,
            "xml" => Format::Junit,
            "csv" => Format::Csv,
            _ => return None,
        })
    };
    asked.or_else(by_extension).unwrap_or(Format::Text)
}

pub fn render(report: &Report, format: Format, verbose: bool) -> anyhow::Result<String> {
    Ok(match format {
        Format::Text => text(report, verbose),
        Format::Json => serde_json::to_string_pretty(&report.to_json())? + "\n",
        Format::Junit => junit(report),
        Format::Html => html(report),
        Format::Csv => csv(report),
    })
}

/// Writes `contents` to `path` through a temporary file and a rename, so that the file is
/// always a whole report. A path that is no regular file (`-o /dev/null`, `-o
/// /dev/stdout`, a pipe) is written in place: a rename would put a regular file where
/// the device was, for every program on the machine.
pub fn write_atomic(path: &Path, contents: &str) -> std::io::Result<()> {
    if std::fs::metadata(path).is_ok_and(|m| !m.is_file()) {
        let mut f = std::fs::OpenOptions::new().write(true).open(path)?;
        return f.write_all(contents.as_bytes());
    }
    let mut tmp = path.as_os_str().to_owned();
    tmp.push(".partial");
    let tmp = PathBuf::from(tmp);
    {
        let mut f = std::fs::File::create(&tmp)?;
        f.write_all(contents.as_bytes())?;
        f.sync_data()?;
    }
    std::fs::rename(&tmp, path)
}

/// Writes the final report to `output` (a one-line summary on stderr) or stdout, and
/// gives the exit code.
pub fn finish(
    report: &Report,
    format: Format,
    verbose: bool,
    output: Option<&Path>,
) -> anyhow::Result<ExitCode> {
    let rendered = render(report, format, verbose)?;
    match output {
        Some(path) => {
            write_atomic(path, &rendered)
                .with_context(|| format!("cannot write {}", path.display()))?;
            let s = report.summary();
            eprintln!(
                "{} {}: {} pass, {} deviations, {} observations, {} skipped, {} errors{}; report in {}",
                s.total,
                if report.kind == conformance::report::ReportKind::Gate { "cases" } else { "checks" },
                s.pass,
                s.deviation,
                s.observation,
                s.skip,
                s.error,
                if report.complete { "" } else { " [INCOMPLETE]" },
                path.display()
            );
            if let Some(e) = &report.expect {
                eprintln!(
                    "against {}: {} expected, {} new, {} unexpected passes{}; {} entries not applied",
                    e.path,
                    report.results.iter().filter(|r| report.is_expected(r)).count(),
                    report.unexpected_findings().len(),
                    report.unexpected_passes(),
                    if e.strict { " (strict)" } else { "" },
                    e.stale().count()
                );
            }
        }
        None => {
            let mut out = std::io::stdout().lock();
            out.write_all(rendered.as_bytes())?;
            out.flush()?;
        }
    }
    Ok(ExitCode::from(report.exit_code()))
}

/// `text` as one word for `sh -c`.
pub fn shell_quote(text: &str) -> String {
    format!("'{}'", text.replace('\'', "'\\''"))
}

/// "node 01" or "nodes 01, 05" (with `separator` between addresses) for a banner that
/// names the nodes a command serves or polls.
pub fn nodes_phrase(nodes: &[u8], separator: &str) -> String {
    let hex: Vec<String> = nodes.iter().map(|n| format!("{n:02X}")).collect();
    let s = if nodes.len() > 1 { "s" } else { "" };
    format!("node{s} {}", hex.join(separator))
}
