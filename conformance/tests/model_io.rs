//! `model import --from csv` and `model export --to pymodbus-sim`, run as a user runs
//! them; the export's round trip through pymodbus's simulator.

mod common;

use std::time::Duration;

use common::{run_bounded, Ran, Run, Scratch};

/// A description, exported, served by pymodbus's simulator, then checked against the same
/// description: no deviation beyond what pymodbus does differently, each of which the
/// expectations file `tests/interop/pymodbus-sim.expect.toml` names with its reason.
#[test]
fn an_exported_description_served_by_pymodbus_checks_clean() {
    let d = Scratch::new("roundtrip");
    let sim = d.join("f510-sim.json");
    let description = concat!(env!("CARGO_MANIFEST_DIR"), "/../vectors/models/f510.json");
    let (code, _, err) = Run::words("model export --to pymodbus-sim --model-file")
        .arg(description)
        .arg("-o")
        .arg(&sim)
        .timeout(Duration::from_secs(30))
        .run()
        .parts();
    assert_eq!(code, Some(0), "{err}");
    // What pymodbus cannot hold is said.
    assert!(err.contains("not held by pymodbus: value bounds"), "{err}");
    let Some(peer) = common::pymodbus_sim_serial(&d, &sim) else {
        return;
    };
    let (code, v) = check_against(&d, description, &peer);
    let deviations = common::with_status(&v, &["deviation", "error"]);
    assert_eq!(code, Some(0), "{}", deviations.join("\n"));
    let counts = &v["expectations"]["counts"];
    assert_eq!(counts["unexpected"], 0, "{counts}");
    // pymodbus's own differences are there, each accepted by its entry; the rest passes.
    assert_eq!(counts["expected"], 8, "{counts}\n{}", deviations.join("\n"));
    for id in [
        "rtu.broadcast.write",
        "rtu.other-address",
        "rtu.map.monitor.whole",
    ] {
        let c = v["checks"]
            .as_array()
            .unwrap()
            .iter()
            .find(|c| c["id"] == id);
        assert_eq!(c.map(|c| &c["status"]), Some(&"pass".into()), "{id}: {c:?}");
    }
}

/// `check --model-file DESCRIPTION` in RTU against pymodbus's simulator serving it
/// (`peer`), with pymodbus's own differences accepted by
/// `tests/interop/pymodbus-sim.expect.toml`: the exit code and the report.
fn check_against(
    d: &std::path::Path,
    description: &str,
    peer: &common::SerialPeer,
) -> (Option<i32>, serde_json::Value) {
    common::check_device(
        d,
        &[
            "--model-file",
            description,
            "--port",
            peer.port.to_str().unwrap(),
            "--mode",
            "rtu",
            "-P",
            "none",
            "--expect",
            concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/tests/interop/pymodbus-sim.expect.toml"
            ),
        ],
        Duration::from_secs(600),
    )
}

/// The map of the device (holding registers 0000H..0FFFH and 2500H..252FH), as an
/// integrator keeps it.
const MAP: &str = "\
Register,Name,Access,Min,Max,Unit,Scale,Comment\r
0x0000-0x0FFF,settings,rw,,,,,the parameter table\r
2500H,frequency command,rw,0,6000,0.01 Hz,0.01,\r
2501H-252FH,monitor,r,,,,,\r
";

/// A scratch folder `name` holding [`MAP`] as X100.csv: the folder and the map's path.
fn the_map(name: &str) -> (Scratch, std::path::PathBuf) {
    let d = Scratch::new(name);
    let map = d.join("X100.csv");
    std::fs::write(&map, MAP).unwrap();
    (d, map)
}

#[test]
fn a_register_map_imports_as_blocks_citing_its_rows() {
    let (d, map) = the_map("import");
    let out = d.join("x100.json");
    let (code, _, err) = Run::words("model import --from csv")
        .arg(&map)
        .arg("-o")
        .arg(&out)
        .arg("--title")
        .arg("Acme X100 register map")
        .timeout(Duration::from_secs(30))
        .run()
        .parts();
    assert_eq!(code, Some(0), "{err}");
    assert!(
        err.contains("x100: 3 blocks from") && err.contains("(columns not imported: comment)"),
        "{err}"
    );
    let text = std::fs::read_to_string(&out).unwrap();
    // Fields in the format's order, for the person who edits the file next.
    assert!(
        text.starts_with("{\n  \"schema_version\": 2,\n  \"model\": \"x100\","),
        "{text}"
    );
    let v: serde_json::Value = serde_json::from_str(&text).unwrap();
    assert_eq!(v["title"], "Acme X100 register map");
    assert_eq!(v["modes"], serde_json::json!(["rtu"]));
    assert_eq!(
        v["blocks"],
        serde_json::json!([
            {"first": "0000", "last": "0FFF", "name": "settings", "access": "read-write",
             "basis": "documented", "source": "X100.csv row 2"},
            {"first": "2500", "last": "2500", "name": "frequency command", "access": "read-write",
             "min": "0000", "max": "1770", "unit": "0.01 Hz", "scale": 0.01,
             "basis": "documented", "source": "X100.csv row 3"},
            {"first": "2501", "last": "252F", "name": "monitor", "access": "read-only",
             "basis": "documented", "source": "X100.csv row 4"},
        ])
    );
}

#[test]
fn a_bad_register_map_exits_1_naming_row_and_column_and_an_unreadable_one_2() {
    let d = Scratch::new("import-bad");
    let map = d.join("bad.csv");
    std::fs::write(&map, "register,access\n0x0000-0x0FFF,rw\n2500H,sometimes\n").unwrap();
    let Ran {
        stdout: out,
        stderr: err,
        ..
    } = Run::words("model import --from csv")
        .arg(&map)
        .timeout(Duration::from_secs(30))
        .run()
        .expect(1);
    assert!(out.is_empty(), "{out}");
    assert!(
        err.contains("bad.csv row 3, column access: \"sometimes\" is not an access"),
        "{err}"
    );
    let (code, _, err) = Run::words("model import --from csv")
        .arg(d.join("none.csv").to_str().unwrap())
        .timeout(Duration::from_secs(30))
        .run()
        .parts();
    assert_eq!(code, Some(2), "{err}");
    assert!(err.contains("cannot read"), "{err}");
}

/// The whole way a user goes: a register map, imported; the description served by
/// pymodbus's simulator; `check --model-file` of the description against it. Needs the
/// schema_version 2 loader (branch i34-format) to load the imported description.
#[test]
fn an_imported_map_served_by_pymodbus_checks_clean() {
    let (d, map) = the_map("import-roundtrip");
    let description = d.join("x100.json");
    let description = description.to_str().unwrap();
    let sim = d.join("x100-sim.json");
    for args in [
        vec![
            "model",
            "import",
            "--from",
            "csv",
            map.to_str().unwrap(),
            "-o",
            description,
        ],
        vec![
            "model",
            "export",
            "--to",
            "pymodbus-sim",
            "--model-file",
            description,
            "-o",
            sim.to_str().unwrap(),
        ],
    ] {
        let (code, _, err) = run_bounded(&args, Duration::from_secs(30));
        assert_eq!(code, Some(0), "{args:?}: {err}");
    }
    let Some(peer) = common::pymodbus_sim_serial(&d, &sim) else {
        return;
    };
    let (code, v) = check_against(&d, description, &peer);
    assert_eq!(code, Some(0), "{v}");
    assert_eq!(v["device"]["model"], "x100");
}
