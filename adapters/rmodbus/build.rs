//! Records the rmodbus version that Cargo resolved (from the workspace's Cargo.lock) so that
//! the adapter can announce it in its hello answer.

use std::path::Path;

fn main() {
    let lock = Path::new(env!("CARGO_MANIFEST_DIR")).join("../../Cargo.lock");
    println!("cargo:rerun-if-changed={}", lock.display());
    println!("cargo:rerun-if-changed=build.rs");
    let text = std::fs::read_to_string(&lock).unwrap_or_default();
    let mut version = String::from("0.13");
    let mut in_rmodbus = false;
    for line in text.lines() {
        let line = line.trim();
        if line == "[[package]]" {
            in_rmodbus = false;
        } else if line == "name = \"rmodbus\"" {
            in_rmodbus = true;
        } else if in_rmodbus {
            if let Some(v) = line.strip_prefix("version = \"") {
                let v = v.trim_end_matches('"');
                if v.starts_with("0.13") {
                    version = v.to_string();
                }
            }
        }
    }
    println!("cargo:rustc-env=RMODBUS_VERSION={version}");
}
