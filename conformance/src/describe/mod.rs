//! Device descriptions in and out of other formats: a register map as integrators keep it
//! in a spreadsheet (CSV, [`import_csv`]), and pymodbus's simulator JSON
//! ([`export_pymodbus_sim`]), so that a device described here can be served by a
//! simulator nobody here wrote.
//!
//! Pure functions, text in and text (JSON) out, with typed errors: the command line
//! (`conformance model import` / `model export`) reads and writes the files. The
//! description written follows the device-description format, schema_version 2
//! (`blocks`, basis on every fact; see the guide's "Describing your own device").

mod csv_import;
mod pymodbus;

pub use csv_import::{import_csv, CsvError, ImportOptions, Imported};
pub use pymodbus::{export_pymodbus_sim, PymodbusExport};
