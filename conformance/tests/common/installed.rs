//! The binary as an installed copy: copied out of the build tree into a scratch folder and
//! run from another folder outside the checkout, so that a run which still reads a file of
//! the source tree (a vector, a model, a schema) fails here as it would for a user who
//! installed the package.

use std::path::{Path, PathBuf};
use std::process::Command;

/// A copy of the `conformance` binary in `<tmp>/<name>/bin`, run from `<tmp>/<name>/run`.
pub struct Installed {
    /// The folder holding both; removed when the guard goes.
    pub root: PathBuf,
    /// The copied binary.
    pub bin: PathBuf,
    /// The working folder of every run (empty at the start).
    pub cwd: PathBuf,
}

impl Installed {
    /// Copies the binary built for these tests into a fresh scratch folder named by `name`.
    pub fn new(name: &str) -> Installed {
        let root = std::env::temp_dir().join(format!(
            "conformance-installed-{}-{name}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&root);
        let (bin_dir, cwd) = (root.join("bin"), root.join("run"));
        std::fs::create_dir_all(&bin_dir).unwrap();
        std::fs::create_dir_all(&cwd).unwrap();
        let bin = bin_dir.join("conformance");
        std::fs::copy(super::bin(), &bin).unwrap();
        let repo = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
        assert!(
            !cwd.starts_with(repo),
            "the scratch folder {} is inside the checkout",
            cwd.display()
        );
        Installed { root, bin, cwd }
    }

    /// The command for `conformance ARGS` run from [`cwd`](Self::cwd), with nothing in its
    /// environment that points back at the build (cargo's variables are removed).
    pub fn command(&self, args: &[&str]) -> Command {
        let mut c = Command::new(&self.bin);
        c.args(args).current_dir(&self.cwd);
        for (k, _) in std::env::vars_os() {
            if k.to_string_lossy().starts_with("CARGO") {
                c.env_remove(k);
            }
        }
        c
    }

    /// Runs `cmd` (made by [`command`](Self::command)) to its end.
    ///
    /// The copy was written by this process, and a test beside it may fork at any moment:
    /// a child forked while the copy's file was open for writing holds that descriptor until
    /// it execs, and until then the kernel refuses to run the copy ("Text file busy",
    /// ETXTBSY). That is the build's race, not the binary's, so the run is tried again
    /// for up to two seconds; any other error, or the same one past that, fails the test.
    pub fn output(cmd: &mut Command) -> std::process::Output {
        let mut tries = 0;
        loop {
            match cmd.output() {
                Err(e) if e.kind() == std::io::ErrorKind::ExecutableFileBusy && tries < 100 => {
                    tries += 1;
                    std::thread::sleep(std::time::Duration::from_millis(20));
                }
                r => return r.unwrap_or_else(|e| panic!("running {cmd:?}: {e}")),
            }
        }
    }

    /// Runs `conformance ARGS` from [`cwd`](Self::cwd): exit code, stdout, stderr.
    pub fn run(&self, args: &[&str]) -> (Option<i32>, String, String) {
        let o = Self::output(&mut self.command(args));
        let text = |b: &[u8]| String::from_utf8_lossy(b).into_owned();
        assert!(
            !text(&o.stderr).contains("panicked"),
            "conformance {args:?} panicked: {}",
            text(&o.stderr)
        );
        (o.status.code(), text(&o.stdout), text(&o.stderr))
    }
}

impl Drop for Installed {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.root);
    }
}
