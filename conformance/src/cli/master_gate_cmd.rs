//! `conformance gate --master CMD`: judge a Modbus master through a master adapter.

use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use anyhow::Context;
use clap::Args;
use conformance::codec::Mode;
use conformance::gate::master::{self, MasterAdapter, MasterOptions, MasterSettings};

use super::common::{load_model, ParityArg};
use super::gate_run::Common;
use super::output::shell_quote;

/// Modes to run.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum ModesArg {
    /// RTU only.
    Rtu,
    /// ASCII only.
    Ascii,
    /// RTU, then ASCII.
    Both,
}

/// The line the gate serves.
#[derive(Debug, Clone, Copy, PartialEq, Eq, clap::ValueEnum)]
pub enum LineArg {
    /// A pseudo-terminal pair (the master opens it as a serial port).
    Pty,
    /// RTU or ASCII frames over TCP (the master connects to 127.0.0.1).
    TcpRtu,
    /// Modbus TCP (MBAP): the gate plays a Modbus TCP gateway with the drive behind it
    /// (RTU only; the faults that need a serial line are skipped).
    Mbap,
}

/// The options of `gate --master` (ignored with `--codec`).
#[derive(Debug, Args)]
pub struct MasterGateArgs {
    /// With --master: the drive model the gate plays.
    #[arg(long, default_value = "f510", value_name = "MODEL")]
    model: String,
    /// With --master: a model file instead of a built-in model.
    #[arg(long, value_name = "FILE")]
    model_file: Option<PathBuf>,
    /// With --master: the drive's node address.
    #[arg(long, default_value_t = 1, value_name = "N")]
    node: u8,
    /// With --master: the modes to run (the master's hello says which it speaks).
    #[arg(long, value_enum, default_value = "both")]
    mode: ModesArg,
    /// With --master: the master's own response timeout, in ms (sent in `open`).
    #[arg(long, value_name = "MS", default_value_t = 300)]
    master_timeout: u64,
    /// With --master: the master's own retries after a timeout (sent in `open`).
    #[arg(long, value_name = "N", default_value_t = 0)]
    retries: u32,
    /// With --master: the baud rate given to the master (the line's timing: t3.5).
    #[arg(short = 'b', long, default_value_t = 9600)]
    baud: u32,
    /// With --master: the parity given to the master. None by default, where bus, monitor
    /// and check take the TECO's 8E1: a pseudo-terminal has no parity bit, and pyserial
    /// (pymodbus, minimalmodbus) cannot open one with a parity (Linux clears PARENB and
    /// glibc's tcsetattr fails with EINVAL). `-P none -s 2` has the 11 bits a character of
    /// 8E1, so the same t3.5.
    #[arg(short = 'P', long, value_enum, default_value = "none")]
    parity: ParityArg,
    /// With --master: the stop bits given to the master (1 or 2).
    #[arg(short = 's', long = "stop-bits", default_value_t = 1, value_parser = clap::value_parser!(u8).range(1..=2))]
    stop_bits: u8,
    /// With --master: the line the gate serves (tcp-rtu has no line timing: no t3.5, no
    /// gaps).
    #[arg(long, value_enum, default_value = "pty")]
    line: LineArg,
    /// With --master: also answer with this exception code (hex, e.g. 05, 07, 0A, 0B)
    /// besides the model's own codes. Repeatable.
    #[arg(long, value_name = "HEX", value_parser = parse_code)]
    exception_code: Vec<u8>,
    /// With --master: close and open the master's line again before each case, so that
    /// what a fault leaves in a library (a reply one request late, bytes stuck in its
    /// buffer) is found in the case that caused it only. Without it a run shows what a
    /// master that never reopens does: the state is carried into the next cases.
    #[arg(long)]
    reopen_each_case: bool,
}

fn parse_code(s: &str) -> Result<u8, String> {
    super::common::parse_code(s, "an exception code")
}

pub fn run(
    command: &str,
    resolved: &str,
    args: &MasterGateArgs,
    common: Common,
) -> anyhow::Result<ExitCode> {
    let model = load_model(&args.model, args.model_file.as_deref(), args.node)?;
    let parity = match args.parity {
        ParityArg::None => conformance::codec::timing::Parity::None,
        ParityArg::Even => conformance::codec::timing::Parity::Even,
        ParityArg::Odd => conformance::codec::timing::Parity::Odd,
    };
    let line = conformance::codec::timing::LineSettings::new(args.baud, 8, parity, args.stop_bits);
    let modes = match args.mode {
        ModesArg::Rtu => vec![Mode::Rtu],
        ModesArg::Ascii => vec![Mode::Ascii],
        ModesArg::Both => vec![Mode::Rtu, Mode::Ascii],
    };
    let mut repro = format!("conformance gate --master {}", shell_quote(command));
    if args.model != "f510" || args.model_file.is_some() {
        match &args.model_file {
            Some(f) => repro.push_str(&format!(" --model-file {}", f.display())),
            None => repro.push_str(&format!(" --model {}", args.model)),
        }
    }
    if args.master_timeout != 300 {
        repro.push_str(&format!(" --master-timeout {}", args.master_timeout));
    }
    if args.retries != 0 {
        repro.push_str(&format!(" --retries {}", args.retries));
    }
    if args.baud != 9600 {
        repro.push_str(&format!(" -b {}", args.baud));
    }
    if parity != conformance::codec::timing::Parity::None {
        repro.push_str(&format!(" -P {}", parity.name()));
    }
    if args.stop_bits != 1 {
        repro.push_str(&format!(" -s {}", args.stop_bits));
    }
    for c in &args.exception_code {
        repro.push_str(&format!(" --exception-code {c:02X}"));
    }
    let line_kind = match args.line {
        LineArg::Pty => master::drive::LineKind::Pty,
        LineArg::TcpRtu => {
            repro.push_str(" --line tcp-rtu");
            master::drive::LineKind::TcpRtu
        }
        LineArg::Mbap => {
            repro.push_str(" --line mbap");
            master::drive::LineKind::Mbap
        }
    };
    let opts = MasterOptions {
        model,
        node: args.node,
        modes,
        only: common.only.clone(),
        settings: MasterSettings {
            timeout: Duration::from_millis(args.master_timeout),
            retries: args.retries,
        },
        line,
        repro,
        line_kind,
        extra_exceptions: args.exception_code.clone(),
        reopen: args.reopen_each_case,
    };
    let cases = master::cases(&opts);
    let rows = cases.iter().map(|c| (c.id.as_str(), c.title.as_str()));
    if let Some(code) = common.before_run(rows, 40)? {
        return Ok(code);
    }
    let stop = super::gate_run::stop_flag()?;
    let mut adapter = MasterAdapter::start(resolved, Duration::from_millis(common.timeout))?;
    let hello = adapter.adapter.hello.clone();
    let report = common.report(&hello, command, 0, 0);
    let mut progress = common.progress(report, cases.len());
    let run = master::run(&mut adapter, &opts, &cases, &stop, &mut progress)
        .context("the master gate could not run")?;
    common.end(
        progress,
        &adapter.adapter.incidents,
        cases.len(),
        &stop,
        |report| report.master = Some(master::summary(&run, &hello.raw, line_kind, line)),
    )
}
