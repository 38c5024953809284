//! What `gate --codec` and `gate --master` share around their cases: `--list` and an
//! `--only` that matches nothing, the report begun from the adapter's hello, the progress
//! (a bar on a terminal, the `-o` file kept valid after every case), and the end of a run
//! (incomplete where the adapter exited twice or the run was interrupted, `--expect`
//! applied, the report written, the exit code).

use std::io::Write;
use std::path::PathBuf;
use std::process::ExitCode;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::SystemTime;

use anyhow::Context;
use conformance::gate::master::{MasterCase, MasterProgress};
use conformance::gate::{Case, GateProgress, Hello};
use conformance::report::{Codec, Report, ReportKind, RunOptions};
use conformance::runner::CheckResult;

use super::output::{finish, format_for, progress_bar, render, write_atomic, Format};

/// The options `gate` shares between codecs and masters.
pub struct Common {
    pub only: Vec<String>,
    pub list: bool,
    pub timeout: u64,
    pub format: Option<Format>,
    pub output: Option<PathBuf>,
    pub verbose: bool,
    pub quiet: bool,
    /// `--expect FILE`: known findings by case id.
    pub expect: super::expect_cmd::Loaded,
}

impl Common {
    /// What ends the command before any case runs: with `--list`, the cases (id padded to
    /// `width`, title) and their count; an error where `--only` leaves no case. `None`
    /// where the cases are to run.
    pub(super) fn before_run<'c>(
        &self,
        cases: impl ExactSizeIterator<Item = (&'c str, &'c str)>,
        width: usize,
    ) -> anyhow::Result<Option<ExitCode>> {
        let count = cases.len();
        if self.list {
            let mut out = std::io::stdout().lock();
            for (id, title) in cases {
                writeln!(out, "{id:<width$} {title}")?;
            }
            writeln!(out, "{count} cases")?;
            return Ok(Some(ExitCode::SUCCESS));
        }
        if count == 0 {
            anyhow::bail!(
                "no case matches --only {}; `--list` shows the case ids",
                self.only.join(" --only ")
            );
        }
        Ok(None)
    }

    /// The report of a run, begun now, of the adapter that said `hello` (run as `command`,
    /// as the user gave it).
    pub(super) fn report(&self, hello: &Hello, command: &str, seed: u64, count: usize) -> Report {
        Report {
            kind: ReportKind::Gate,
            codec: Some(Codec {
                adapter: hello.adapter.clone(),
                implementation: hello.implementation.clone(),
                version: hello.version.clone(),
                command: command.to_string(),
                supports: hello.supports.clone(),
                incidents: vec![],
                seed,
                count,
            }),
            started: humantime::format_rfc3339_seconds(SystemTime::now()).to_string(),
            options: RunOptions {
                timeout_ms: self.timeout,
                only: self.only.clone(),
                ..RunOptions::default()
            },
            ..Report::default()
        }
    }

    /// The progress of a run of `total` cases into `report`: a bar unless `--quiet` or
    /// stderr is not a terminal.
    pub(super) fn progress(&self, report: Report, total: usize) -> Progress<'_> {
        let bar = progress_bar(
            self.quiet,
            total as u64,
            "{bar:30} {pos}/{len} eta {eta} {wide_msg}",
        );
        Progress {
            report,
            bar,
            output: self.output.as_ref(),
            format: format_for(self.format, self.output.as_deref()),
            verbose: self.verbose,
            error: None,
        }
    }

    /// Ends a run of `total` cases: the report with the adapter's `incidents` and what
    /// `fill` adds, incomplete where the adapter exited twice or `stop` was set, then
    /// `--expect` applied and the report written (the command's exit code). An error
    /// writing the `-o` file during the run is returned instead.
    pub(super) fn end(
        &self,
        progress: Progress,
        incidents: &[String],
        total: usize,
        stop: &AtomicBool,
        fill: impl FnOnce(&mut Report),
    ) -> anyhow::Result<ExitCode> {
        if let Some(b) = &progress.bar {
            b.finish_and_clear();
        }
        let mut report = progress.report;
        if let Some(c) = report.codec.as_mut() {
            c.incidents = incidents.to_vec();
        }
        fill(&mut report);
        // An adapter that exited twice leaves the rest of the run undecided.
        let gone = report
            .results
            .iter()
            .filter(|r| r.summary.contains("the adapter is gone"))
            .count();
        report.complete = gone == 0;
        if gone > 0 {
            report.stopped = Some(format!(
                "the adapter exited twice; {gone} cases could not run"
            ));
        }
        if stop.load(Ordering::Relaxed) {
            report.complete = false;
            report.stopped = Some(format!(
                "interrupted after {} of {} cases",
                report.results.len(),
                total
            ));
        }
        report.finished = Some(humantime::format_rfc3339_seconds(SystemTime::now()).to_string());
        if let Some(e) = progress.error {
            return Err(e);
        }
        self.expect.apply(&mut report);
        finish(
            &report,
            format_for(self.format, self.output.as_deref()),
            self.verbose,
            self.output.as_deref(),
        )
    }
}

/// The flag Ctrl-C sets, for a run about to start its adapter.
pub(super) fn stop_flag() -> anyhow::Result<Arc<AtomicBool>> {
    let stop = super::interrupt::stop_flag()?;
    // An adapter that exits before it reads its hello (a missing module, a command not
    // found) closes the pipe the gate writes to: that write must fail and be reported,
    // not kill the gate with SIGPIPE (which main restores for `| head`).
    #[cfg(unix)]
    // SAFETY: sets the disposition of one signal to ignore; no handler runs.
    unsafe {
        libc::signal(libc::SIGPIPE, libc::SIG_IGN);
    }
    Ok(stop)
}

/// A run's report as its cases end, and its progress bar.
pub(super) struct Progress<'a> {
    report: Report,
    bar: Option<indicatif::ProgressBar>,
    output: Option<&'a PathBuf>,
    format: Format,
    verbose: bool,
    error: Option<anyhow::Error>,
}

impl Progress<'_> {
    fn started(&mut self, id: &str) {
        if let Some(b) = &self.bar {
            b.set_message(id.to_string());
        }
    }

    /// Keeps the result, and the `-o` file valid with it (the first error writing it is
    /// kept for the end of the run).
    fn finished(&mut self, result: &CheckResult) {
        self.report.results.push(result.clone());
        if let Some(b) = &self.bar {
            b.inc(1);
        }
        if let (Some(path), None) = (self.output, &self.error) {
            let res = render(&self.report, self.format, self.verbose).and_then(|s| {
                write_atomic(path, &s).with_context(|| format!("cannot write {}", path.display()))
            });
            if let Err(e) = res {
                self.error = Some(e);
            }
        }
    }
}

impl GateProgress for Progress<'_> {
    fn started(&mut self, case: &Case) {
        Progress::started(self, &case.id);
    }

    fn finished(&mut self, result: &CheckResult) {
        Progress::finished(self, result);
    }
}

impl MasterProgress for Progress<'_> {
    fn started(&mut self, case: &MasterCase) {
        Progress::started(self, &case.id);
    }

    fn finished(&mut self, result: &CheckResult) {
        Progress::finished(self, result);
    }
}
