//! `conformance --version`: the version, the commit the binary was built from, and the
//! CRC paths this CPU runs, as the codec's dispatcher chose them (a bug report about speed
//! or a checksum then says which code computed it).

use conformance::codec::crc::{crc16_tier, CrcPath};
use conformance::codec::crc_clmul::PATH_ENV;

/// The commit, or why there is none (recorded by build.rs).
pub const COMMIT: &str = env!("CONFORMANCE_COMMIT");

/// The text of `conformance --version` (`-V` prints the first line only).
pub fn long() -> String {
    let tier = crc16_tier();
    let supported: Vec<&str> = CrcPath::supported().map(CrcPath::name).collect();
    let cap = match std::env::var(PATH_ENV) {
        Ok(v) => format!("; capped by {PATH_ENV}={v}"),
        Err(_) => String::new(),
    };
    format!(
        "{version}\ncommit: {COMMIT}\ncrc: {tier} path for long inputs (this CPU runs: {supported}{cap})\ntarget: {arch}-{os}",
        version = env!("CARGO_PKG_VERSION"),
        tier = tier.name(),
        supported = supported.join(", "),
        arch = std::env::consts::ARCH,
        os = std::env::consts::OS,
    )
}
