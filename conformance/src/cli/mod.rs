//! Argument parsing and dispatch. Each subcommand lives in its own module.

#[cfg(unix)]
mod bus_cmd;
mod capture_cmd;
mod check_cmd;
mod codec_cmd;
mod common;
mod expect_cmd;
mod fuzz_cmd;
mod gate_cmd;
mod gate_run;
mod generate_cmd;
mod identify_cmd;
mod interrupt;
mod link;
mod master_gate_cmd;
mod model_cmd;
mod model_io_cmd;
mod model_learn_cmd;
mod monitor_cmd;
mod output;
mod params_cmd;
mod ports_cmd;
mod report_cmd;
mod requirements_cmd;
mod scan_cmd;
mod send_cmd;
mod simulate_cmd;
mod vectors_cmd;
mod version;
mod watch_cmd;

use std::process::ExitCode;

use clap::{CommandFactory, FromArgMatches, Parser, Subcommand};

/// Conformance and fuzz test suite for the Modbus RTU/ASCII protocol of TECO F510, A510,
/// L510 and E510 AC drives.
#[derive(Debug, Parser)]
#[command(name = "conformance", version, about, long_about = None)]
#[command(
    after_help = "Exit codes: 0 ok; 1 a problem was found (bad checksum, failing vector); 2 the command could not run.\n\nCtrl-C, SIGTERM and SIGHUP stop a long command. check, fuzz, scan, identify and gate stop after their current check, case or probe: what they wrote is restored and the report is whole, marked incomplete (exit 2). monitor stops listening and writes its whole report (exit 0 or 1, by what it heard). watch ends after its current poll with its summary (exit 0, or 1 where an exception or a value out of range was seen). bus and simulate stop and remove their links (exit 0)."
)]
pub struct Cli {
    #[command(subcommand)]
    command: Command,
}

#[derive(Debug, Subcommand)]
enum Command {
    /// Decode one RTU or ASCII frame and check its checksum and length fields.
    Decode(codec_cmd::DecodeArgs),
    /// Build a frame from fields and print it in RTU hex and ASCII.
    Encode(codec_cmd::EncodeArgs),
    /// The golden vectors transcribed from the manuals: list, verify, export.
    Vectors(vectors_cmd::VectorsArgs),
    /// Show a device description (a drive model) with the basis of each fact, or lint one
    /// (`model lint FILE`).
    Model(model_cmd::ModelArgs),
    /// Run a simulated drive on a serial port, a pseudo-terminal or TCP.
    Simulate(simulate_cmd::SimulateArgs),
    /// An emulated multi-drop RS-485 line: pseudo-terminals for masters, listeners and
    /// devices, simulated drives on it, collisions and noise, and its log.
    #[cfg(unix)]
    Bus(bus_cmd::BusArgs),
    /// Probe a real or simulated drive and report every deviation from its manual.
    Check(check_cmd::CheckArgs),
    /// Which of the five models a device follows, from its answers to reads only: the
    /// evidence for and against each model, and a verdict.
    Identify(identify_cmd::IdentifyArgs),
    /// Send malformed and hostile traffic to a real or simulated drive, predict every
    /// answer from its model, detect hangs, and minimize what is found.
    Fuzz(fuzz_cmd::FuzzArgs),
    /// Send raw frames (hex) to a device and show what comes back, with timestamps and the
    /// model's prediction.
    Send(send_cmd::SendArgs),
    /// Make captures: `capture synth` writes a day of a bus (a master polling drives, rare
    /// faults at known times) with its truth, for `monitor --capture-in` to be held to.
    Capture(capture_cmd::CaptureArgs),
    /// Listen to a bus others drive, never send a byte, and judge both the drives and the
    /// master against the manual (passive conformance).
    Monitor(monitor_cmd::MonitorArgs),
    /// Poll named registers of one or more drives (reads only) and judge every value
    /// against the model as it changes: a live table, CSV, JSON lines or an HTML trend.
    Watch(watch_cmd::WatchArgs),
    /// A drive's parameters: back them up to a file a person edits, compare two sets
    /// (files, a live device, the model), restore a file with a plan and an audit log.
    Params(params_cmd::ParamsArgs),
    /// The serial ports of this machine: which adapter is which path, its USB latency
    /// timer and what it does to RTU framing, and whether you may open it.
    Ports(ports_cmd::PortsArgs),
    /// Find the devices on a line: line settings, mode and node addresses (reads only).
    Scan(scan_cmd::ScanArgs),
    /// Check another Modbus codec (--codec) or master (--master) through an adapter
    /// (adapters/PROTOCOL.md).
    Gate(gate_cmd::GateArgs),
    /// Render a saved JSON report as text (the default), HTML, JUnit XML, CSV or JSON.
    Report(report_cmd::ReportArgs),
    /// The manuals' requirements (every wire-testable statement, with its quote), what
    /// verifies each, and the coverage per document.
    Requirements(requirements_cmd::RequirementsArgs),
    /// What changed between two runs of the same model (e.g. two firmware versions).
    Diff(report_cmd::DiffArgs),
    /// A starting expectations file (--expect) from a run's JSON report: one entry per
    /// deviation or finding, to give reasons and tickets.
    Expect(expect_cmd::ExpectCmdArgs),
    /// This suite's codec behind the adapter protocol, on stdin/stdout (the reference
    /// adapter: `conformance gate --codec "conformance adapter"`).
    Adapter(gate_cmd::AdapterArgs),
    /// The completion script for a shell (bash, zsh, fish, elvish, powershell), on stdout.
    Completions(generate_cmd::CompletionsArgs),
    /// Man pages and completion scripts into a folder, for packaging.
    #[command(hide = true)]
    Generate(generate_cmd::GenerateArgs),
}

/// Parses the command line: as [`Parser::parse`], with `--version` saying the commit and
/// the CRC paths of this CPU, which are only known at run time.
pub fn parse() -> Cli {
    let long: &'static str = Box::leak(version::long().into_boxed_str());
    let matches = Cli::command().long_version(long).get_matches();
    Cli::from_arg_matches(&matches).unwrap_or_else(|e| e.exit())
}

/// Runs the parsed command.
pub fn run(cli: Cli) -> anyhow::Result<ExitCode> {
    match cli.command {
        Command::Decode(a) => codec_cmd::decode(a),
        Command::Encode(a) => codec_cmd::encode(a),
        Command::Vectors(a) => vectors_cmd::run(a),
        Command::Model(a) => model_cmd::run(a),
        Command::Requirements(a) => requirements_cmd::run(a),
        Command::Simulate(a) => simulate_cmd::run(a),
        #[cfg(unix)]
        Command::Bus(a) => bus_cmd::run(a),
        Command::Check(a) => check_cmd::run(a),
        Command::Identify(a) => identify_cmd::run(a),
        Command::Fuzz(a) => fuzz_cmd::run(a),
        Command::Send(a) => send_cmd::run(a),
        Command::Scan(a) => scan_cmd::run(a),
        Command::Watch(a) => watch_cmd::run(a),
        Command::Params(a) => params_cmd::run(a),
        Command::Ports(a) => ports_cmd::run(a),
        Command::Monitor(a) => monitor_cmd::run(a),
        Command::Capture(a) => capture_cmd::run(a),
        Command::Gate(a) => gate_cmd::run(a),
        Command::Adapter(a) => gate_cmd::adapter(a),
        Command::Report(a) => report_cmd::report(a),
        Command::Diff(a) => report_cmd::diff(a),
        Command::Expect(a) => expect_cmd::run(a),
        Command::Completions(a) => generate_cmd::completions(a),
        Command::Generate(a) => generate_cmd::generate(a),
    }
}
