//! A scratch folder for one test: made fresh, removed when the test passes, kept (and its
//! path printed) when the test fails or TECO_KEEP is set, so that what the run wrote can
//! be looked at.

use std::path::{Path, PathBuf};

/// A folder under the system's temporary folder named for the test binary, the test's
/// own `name` and this process, removed on drop unless the thread is panicking (or it
/// was made to be [`kept`](Scratch::kept)).
pub struct Scratch(PathBuf, bool);

impl Scratch {
    /// A fresh, empty `<tmp>/conformance-<binary>-<name>-<pid>` (what an earlier run left
    /// there is removed first).
    pub fn new(name: &str) -> Scratch {
        let d = std::env::temp_dir().join(format!(
            "conformance-{}-{name}-{}",
            binary(),
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap_or_else(|e| panic!("cannot make {}: {e}", d.display()));
        Scratch(d, false)
    }

    /// A fresh, empty `target/tmp/<binary>-<name>` that stays after the test, for what a
    /// person looks at after the run (a screenshot); the next run empties it.
    pub fn kept(name: &str) -> Scratch {
        let d = PathBuf::from(env!("CARGO_TARGET_TMPDIR")).join(format!("{}-{name}", binary()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap_or_else(|e| panic!("cannot make {}: {e}", d.display()));
        Scratch(d, true)
    }

    /// The folder.
    pub fn path(&self) -> &Path {
        &self.0
    }
}

impl std::ops::Deref for Scratch {
    type Target = Path;
    fn deref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<Path> for Scratch {
    fn as_ref(&self) -> &Path {
        &self.0
    }
}

impl AsRef<std::ffi::OsStr> for Scratch {
    fn as_ref(&self) -> &std::ffi::OsStr {
        self.0.as_os_str()
    }
}

impl Drop for Scratch {
    fn drop(&mut self) {
        if self.1 {
            return;
        }
        // TECO_KEEP keeps every folder, to read what a passing test wrote (learn's drafts).
        if std::thread::panicking() || std::env::var_os("TECO_KEEP").is_some() {
            super::note(&format!("kept for a look: {}", self.0.display()));
        } else {
            let _ = std::fs::remove_dir_all(&self.0);
        }
    }
}

/// The test binary's name (`capture` for tests/capture.rs).
fn binary() -> String {
    let test = super::test_name();
    test.split("::").next().unwrap_or("test").to_string()
}
