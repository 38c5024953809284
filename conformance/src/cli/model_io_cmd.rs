//! `conformance model import` and `model export`: a description from a register map kept
//! in a spreadsheet, and a description as pymodbus's simulator JSON.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};
use clap::{Args, ValueEnum};
use conformance::describe::{export_pymodbus_sim, import_csv, ImportOptions};
use conformance::model::DriveModel;

use super::output::write_atomic;

const IMPORT_HELP: &str = "\
Examples:
  conformance model import --from csv map.csv -o x100.json --model acme-x100 --title \"Acme X100 manual rev C\"
  conformance model import --from csv map.csv --hex-registers --modes rtu,ascii

The map's columns, by their header (any case, any order; other columns are not imported):
  register   the first register: 0x2500, 2500H, or decimal 9472; or a range 2500H-25FFH
  last       the range's last register (instead of a range in register)
  name       text
  access     read-write (rw), read-only (r), write-only (w), reserved; empty: read-write
  min, max   bounds of written values: 0x1770, 1770H, or decimal 6000
  unit       text (0.01 Hz)
  scale      a number: value = raw x scale
A bare register number is decimal unless --hex-registers. Each row is one block, cited as
\"MAP.csv row N\" (N as the spreadsheet numbers rows: the header is row 1). Blank rows and
rows starting with # are skipped. The description written is schema_version 2: the map,
the modes and functions given here; every other fact is the format's default or absent.

Exit codes: 0 written; 1 the map has errors (each names its row and column); 2 the file
could not be read or written.";

const EXPORT_HELP: &str = "\
Examples:
  conformance model export --to pymodbus-sim --model f510 -o f510-sim.json
  conformance model export --to pymodbus-sim --model-file x100.json -o x100-sim.json
  pymodbus.simulator --json_file x100-sim.json --modbus_server server --modbus_device acme-x100

pymodbus's simulator serves what it can hold of a description: every register of the map
as a holding register with its initial value, the read-write ones writable, every other
register refused (exception 02H), at node device_id (the description's first address). It
cannot hold value bounds, read or write limits, response times, an exception table or the
command bits: the command lists them on stderr. The server entry is an RTU serial server
on /dev/ttyUSB0 at 9600 8E1: edit it for your line.";

/// Formats a description comes from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum From {
    /// A register map as CSV: register, name, access, min, max, unit, scale.
    Csv,
}

/// Formats a description goes to.
#[derive(Debug, Clone, Copy, PartialEq, Eq, ValueEnum)]
pub enum To {
    /// pymodbus's simulator JSON (pymodbus.simulator --json_file).
    PymodbusSim,
}

/// `model import`.
#[derive(Debug, Args)]
#[command(after_help = IMPORT_HELP)]
pub struct ImportArgs {
    /// The format of the file.
    #[arg(long, value_enum)]
    from: From,
    /// The register map.
    #[arg(value_name = "MAP.csv")]
    file: PathBuf,
    /// Write the description here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
    /// The description's model id (default: the map's file name, in lower case).
    #[arg(long, value_name = "ID")]
    model: Option<String>,
    /// The description's title (default: "register map MAP.csv").
    #[arg(long, value_name = "TEXT")]
    title: Option<String>,
    /// The modes the device speaks: rtu, ascii or rtu,ascii.
    #[arg(
        long,
        value_name = "MODES",
        default_value = "rtu",
        value_delimiter = ','
    )]
    modes: Vec<String>,
    /// The function codes the device serves, hex (03,06,10); a register map does not say.
    #[arg(long, value_name = "HEX,..", default_value = "03,06,10", value_delimiter = ',', value_parser = parse_function)]
    functions: Vec<u8>,
    /// A bare number in the register and last columns is hex (2500-25FF), not decimal.
    #[arg(long)]
    hex_registers: bool,
}

/// `model export`.
#[derive(Debug, Args)]
#[command(after_help = EXPORT_HELP)]
pub struct ExportArgs {
    /// The format to write.
    #[arg(long, value_enum)]
    to: To,
    /// A built-in model: f510, a510, l510, e510, l510-legacy.
    #[arg(
        long,
        value_name = "MODEL",
        required_unless_present = "model_file",
        conflicts_with = "model_file"
    )]
    model: Option<String>,
    /// A description (model file).
    #[arg(long, value_name = "FILE")]
    model_file: Option<PathBuf>,
    /// Write the simulator's JSON here instead of stdout.
    #[arg(short, long, value_name = "FILE")]
    output: Option<PathBuf>,
}

fn parse_function(s: &str) -> Result<u8, String> {
    super::common::parse_code(s, "a function code")
}

/// The model id a file's name gives: lower case, other characters as `-`.
fn id_of(path: &Path) -> String {
    let stem = path
        .file_stem()
        .map(|s| s.to_string_lossy().to_ascii_lowercase())
        .unwrap_or_default();
    let id: String = stem
        .chars()
        .map(|c| {
            if c.is_ascii_lowercase() || c.is_ascii_digit() || "._-".contains(c) {
                c
            } else {
                '-'
            }
        })
        .take(64)
        .collect();
    let id = id.trim_start_matches(['.', '_', '-']).to_string();
    if id.is_empty() {
        "device".into()
    } else {
        id
    }
}

fn write_out(output: Option<&Path>, text: &str) -> anyhow::Result<()> {
    match output {
        Some(path) => {
            write_atomic(path, text).with_context(|| format!("cannot write {}", path.display()))
        }
        None => {
            let mut out = std::io::stdout().lock();
            out.write_all(text.as_bytes())?;
            Ok(out.flush()?)
        }
    }
}

/// `model import`.
pub fn import(args: ImportArgs) -> anyhow::Result<ExitCode> {
    let From::Csv = args.from;
    let text = std::fs::read_to_string(&args.file)
        .with_context(|| format!("cannot read {}", args.file.display()))?;
    let name = args
        .file
        .file_name()
        .map(|n| n.to_string_lossy().to_string())
        .unwrap_or_else(|| args.file.display().to_string());
    let options = ImportOptions {
        model: args.model.clone().unwrap_or_else(|| id_of(&args.file)),
        title: args
            .title
            .clone()
            .unwrap_or_else(|| format!("register map {name}")),
        source_name: name,
        modes: args
            .modes
            .iter()
            .map(|m| m.trim().to_ascii_lowercase())
            .collect(),
        functions: args.functions.clone(),
        hex_registers: args.hex_registers,
    };
    let imported = match import_csv(&text, &options) {
        Ok(i) => i,
        Err(e) => {
            eprintln!("error: {e}");
            return Ok(ExitCode::from(1));
        }
    };
    write_out(args.output.as_deref(), &imported.text)?;
    eprintln!(
        "{}: {} block{} from {}{}{}",
        options.model,
        imported.blocks,
        if imported.blocks == 1 { "" } else { "s" },
        args.file.display(),
        if imported.ignored_columns.is_empty() {
            String::new()
        } else {
            format!(
                " (columns not imported: {})",
                imported.ignored_columns.join(", ")
            )
        },
        args.output
            .as_deref()
            .map(|p| format!("; written to {}", p.display()))
            .unwrap_or_default()
    );
    Ok(ExitCode::SUCCESS)
}

/// `model export`.
pub fn export(args: ExportArgs) -> anyhow::Result<ExitCode> {
    let To::PymodbusSim = args.to;
    let model = match (&args.model, &args.model_file) {
        (_, Some(path)) => DriveModel::from_path(path)?,
        (Some(id), None) => DriveModel::builtin(id)?,
        (None, None) => bail!("give the description: --model MODEL or --model-file FILE"),
    };
    let out = export_pymodbus_sim(&model);
    let json = serde_json::to_string_pretty(&out.json)? + "\n";
    write_out(args.output.as_deref(), &json)?;
    eprintln!(
        "{}: {} registers served ({} writable) by pymodbus's simulator{}",
        model.id,
        out.served,
        out.writable,
        args.output
            .as_deref()
            .map(|p| format!("; written to {}", p.display()))
            .unwrap_or_default()
    );
    for l in &out.lost {
        eprintln!("  not held by pymodbus: {l}");
    }
    Ok(ExitCode::SUCCESS)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_from_file_names() {
        assert_eq!(id_of(Path::new("maps/Acme X100.csv")), "acme-x100");
        assert_eq!(id_of(Path::new("_map.csv")), "map");
        assert_eq!(id_of(Path::new("Ü.csv")), "device");
    }
}
