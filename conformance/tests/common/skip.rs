//! The programs nobody here wrote that the tests use as peers (mbpoll, libmodbus, pymodbus,
//! minimalmodbus, Chromium, a C compiler, jsmodbus, tshark), how a test asks for one, and what
//! happens when one is missing.
//!
//! A test asks with [`need`]. When the peer is here, it runs. When it is not, the test
//! prints `SKIPPED: <binary>::<test>: <why>` past the output capture, records the skip
//! for the summary that `tests/what_was_skipped.rs` prints at the end of `cargo test`,
//! and returns: it passes having done nothing, and the summary says so. Under CI (the
//! environment variable `CI` set) a missing peer is a failure instead, since `.ci/run`
//! installs every one, unless `CONFORMANCE_PEERS=none` hides them all on purpose: CI
//! runs the tests that use peers once that way too, to prove that a fresh machine with
//! only the Rust toolchain passes the README's test command.
//!
//! `scripts/install-peers` installs every peer: the Debian packages, the Python peers
//! (pinned) into a virtual environment under `target/peers/venv` that [`python`] finds
//! with no activation step, and jsmodbus with `npm ci`.

use std::io::Write;
use std::path::PathBuf;
use std::process::{Command, Stdio};
use std::sync::OnceLock;

/// The one command that installs every peer.
pub const INSTALL: &str = "scripts/install-peers";

/// A program nobody here wrote that some tests use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Peer {
    /// mbpoll, a Modbus master for the command line (Debian `mbpoll`).
    Mbpoll,
    /// libmodbus's headers and library, built against with `cc` (Debian `libmodbus-dev`,
    /// `pkg-config`, `gcc`).
    Libmodbus,
    /// A C compiler (`$CC`, else `cc`; Debian `gcc`).
    CCompiler,
    /// Headless Chromium (Debian `chromium`).
    Chromium,
    /// pymodbus 3.16.1 with pyserial 3.5 (PyPI), for [`python`].
    Pymodbus,
    /// minimalmodbus 2.1.1 (PyPI), for [`python`].
    Minimalmodbus,
    /// jsmodbus under Node.js (`npm ci` in adapters/jsmodbus).
    Jsmodbus,
    /// tshark, Wireshark's command-line decoder (Debian `tshark`).
    Tshark,
}

impl Peer {
    /// What the peer is and where it comes from, as a skip line says it.
    pub fn what(self) -> &'static str {
        match self {
            Peer::Mbpoll => "mbpoll (Debian package mbpoll)",
            Peer::Libmodbus => {
                "libmodbus-dev with pkg-config and a C compiler (Debian packages libmodbus-dev pkg-config gcc)"
            }
            Peer::CCompiler => "a C compiler ($CC, else cc; Debian package gcc)",
            Peer::Chromium => "chromium (Debian package chromium)",
            Peer::Pymodbus => "pymodbus==3.16.1 and pyserial==3.5 (PyPI)",
            Peer::Minimalmodbus => "minimalmodbus==2.1.1 and pyserial==3.5 (PyPI)",
            Peer::Jsmodbus => "jsmodbus under Node.js (npm ci in adapters/jsmodbus)",
            Peer::Tshark => "tshark (Debian package tshark)",
        }
    }

    /// Whether the peer works here: Ok, or what was tried and what it said.
    fn probe(self) -> Result<(), String> {
        match self {
            Peer::Mbpoll => succeeds(Command::new("mbpoll").arg("-V")),
            Peer::Tshark => succeeds(Command::new("tshark").arg("--version")),
            Peer::CCompiler => succeeds(Command::new(cc()).arg("--version")),
            Peer::Libmodbus => {
                succeeds(Command::new(cc()).arg("--version"))?;
                succeeds(Command::new("pkg-config").args(["--exists", "libmodbus"]))
            }
            Peer::Chromium => chromium().map(|_| ()).ok_or_else(|| {
                "none of chromium, chromium-browser, google-chrome is on the PATH".into()
            }),
            Peer::Pymodbus => succeeds(Command::new(python()).args([
                "-c",
                "import pymodbus, serial; assert pymodbus.__version__ == '3.16.1', pymodbus.__version__",
            ])),
            Peer::Minimalmodbus => succeeds(
                Command::new(python()).args(["-c", "import minimalmodbus, serial"]),
            ),
            Peer::Jsmodbus => {
                let module = concat!(
                    env!("CARGO_MANIFEST_DIR"),
                    "/../adapters/jsmodbus/node_modules/jsmodbus/package.json"
                );
                succeeds(Command::new("node").arg("--version"))?;
                if std::path::Path::new(module).exists() {
                    Ok(())
                } else {
                    Err(format!("{module} is missing"))
                }
            }
        }
    }
}

/// Runs `cmd` with its output captured: Ok when it succeeds, else why not (its last line
/// of stderr, or the error of starting it).
fn succeeds(cmd: &mut Command) -> Result<(), String> {
    let shown = std::iter::once(cmd.get_program())
        .chain(cmd.get_args())
        .map(|a| a.to_string_lossy())
        .collect::<Vec<_>>()
        .join(" ");
    let shown = if shown.len() > 60 {
        cmd.get_program().to_string_lossy().into_owned()
    } else {
        shown
    };
    match cmd.stdin(Stdio::null()).output() {
        Ok(o) if o.status.success() => Ok(()),
        Ok(o) => {
            let err = String::from_utf8_lossy(&o.stderr);
            match err.lines().rev().find(|l| !l.trim().is_empty()) {
                Some(last) => Err(format!("{shown}: {} ({})", last.trim(), o.status)),
                None => Err(format!("{shown}: {}", o.status)),
            }
        }
        Err(e) => Err(format!("cannot run {shown}: {e}")),
    }
}

/// Whether `CONFORMANCE_PEERS=none` hides every peer (what a fresh machine looks like).
pub fn peers_hidden() -> bool {
    std::env::var("CONFORMANCE_PEERS").is_ok_and(|v| v == "none")
}

/// Whether `peer` is here. When it is not (or every peer is hidden), the test is skipped:
/// see the module notes. Each peer is probed once per test binary.
pub fn need(peer: Peer) -> bool {
    static PROBED: OnceLock<std::sync::Mutex<std::collections::HashMap<Peer, Result<(), String>>>> =
        OnceLock::new();
    if peers_hidden() {
        return missing(&format!(
            "needs {} (hidden by CONFORMANCE_PEERS=none)",
            peer.what()
        ));
    }
    let result = PROBED
        .get_or_init(Default::default)
        .lock()
        .unwrap()
        .entry(peer)
        .or_insert_with(|| peer.probe())
        .clone();
    match result {
        Ok(()) => true,
        Err(why) => missing(&format!("needs {} [{why}]", peer.what())),
    }
}

/// Whether every one of `peers` is here (each missing one is named in the skip line).
pub fn need_all(peers: &[Peer]) -> bool {
    peers.iter().all(|p| need(*p))
}

/// Reports that a test cannot run for want of `what`: under CI (unless the peers are
/// hidden on purpose) this fails the test; otherwise it prints `SKIPPED: <test>: <what>`,
/// records the skip for the summary, and returns false so that the test can return.
pub fn missing(what: &str) -> bool {
    let test = test_name();
    if std::env::var_os("CI").is_some() && !peers_hidden() {
        panic!("FAILED: {test}: {what} (CI is set, so a missing peer is an error; {INSTALL} installs every peer)");
    }
    super::note(&format!("SKIPPED: {test}: {what}"));
    record(&test, what);
    false
}

/// `binary::test`, as a skip line names a test.
pub fn test_name() -> String {
    let binary = std::env::current_exe()
        .ok()
        .and_then(|p| p.file_stem().map(|s| s.to_string_lossy().into_owned()))
        .map(|s| match s.rsplit_once('-') {
            // Cargo names test executables NAME-HASH.
            Some((name, hash)) if hash.chars().all(|c| c.is_ascii_hexdigit()) => name.into(),
            _ => s,
        })
        .unwrap_or_else(|| "?".into());
    let thread = std::thread::current();
    format!("{binary}::{}", thread.name().unwrap_or("?"))
}

/// The folder where the test binaries of one `cargo test` run record their skips: keyed
/// by the parent process (cargo), so that the summary reads this run's skips only.
pub fn skips_dir_of(parent: u32) -> PathBuf {
    PathBuf::from(env!("CARGO_TARGET_TMPDIR"))
        .join("skips")
        .join(parent.to_string())
}

fn record(test: &str, what: &str) {
    let dir = skips_dir_of(std::os::unix::process::parent_id());
    let write = || -> std::io::Result<()> {
        std::fs::create_dir_all(&dir)?;
        let mut f = std::fs::OpenOptions::new()
            .create(true)
            .append(true)
            .open(dir.join(format!("{}.tsv", std::process::id())))?;
        // One write per line, so that tests of one binary running at once do not mix.
        f.write_all(format!("{test}\t{}\n", what.replace(['\t', '\n'], " ")).as_bytes())
    };
    if let Err(e) = write() {
        super::note(&format!(
            "note: cannot record the skip in {}: {e}",
            dir.display()
        ));
    }
}

/// The Python that has the Python peers: the virtual environment `scripts/install-peers`
/// makes under `target/peers/venv`, where it exists; `$PEERS_PYTHON` where set; else
/// `python3` from the PATH.
pub fn python() -> String {
    if let Ok(p) = std::env::var("PEERS_PYTHON") {
        return p;
    }
    let venv = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../target/peers/venv/bin/python"
    );
    if std::path::Path::new(venv).exists() {
        venv.to_string()
    } else {
        "python3".to_string()
    }
}

/// The C compiler: `$CC`, else `cc`.
pub fn cc() -> String {
    std::env::var("CC").unwrap_or_else(|_| "cc".to_string())
}

/// The Chromium binary on the PATH, if any.
pub fn chromium() -> Option<&'static str> {
    ["chromium", "chromium-browser", "google-chrome"]
        .into_iter()
        .find(|b| {
            Command::new(b)
                .arg("--version")
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .status()
                .is_ok_and(|s| s.success())
        })
}
