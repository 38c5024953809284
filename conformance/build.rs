//! Records the git commit the binary is built from, for `conformance --version`.
//!
//! A package built outside a checkout (from a source tarball, or a wheel's sdist) has no
//! git to ask: the packaging then sets `CONFORMANCE_BUILD_COMMIT`, and a build with
//! neither says so in the version text rather than printing a blank.

use std::path::PathBuf;
use std::process::Command;

/// The variable a packager sets to the commit when there is no git checkout to ask.
const COMMIT_ENV: &str = "CONFORMANCE_BUILD_COMMIT";

fn git(args: &[&str]) -> Option<String> {
    let out = Command::new("git").args(args).output().ok()?;
    if !out.status.success() {
        return None;
    }
    let text = String::from_utf8(out.stdout).ok()?.trim().to_string();
    (!text.is_empty()).then_some(text)
}

fn main() {
    println!("cargo:rerun-if-changed=build.rs");
    println!("cargo:rerun-if-env-changed={COMMIT_ENV}");
    let given = std::env::var(COMMIT_ENV)
        .ok()
        .filter(|c| !c.trim().is_empty());
    let commit = match (given, git(&["rev-parse", "HEAD"])) {
        (Some(c), _) => format!("{} (given by {COMMIT_ENV})", c.trim()),
        (None, Some(head)) => {
            // Built again when HEAD moves (a commit, a checkout), and only then: the
            // files git keeps HEAD and the branch in, wherever this checkout's git
            // directory is (a worktree keeps HEAD apart from the branches).
            let mut watched = vec!["HEAD".to_string(), "packed-refs".to_string()];
            watched.extend(git(&["symbolic-ref", "-q", "HEAD"]));
            for name in watched {
                if let Some(p) = git(&["rev-parse", "--git-path", &name]) {
                    let p = PathBuf::from(p);
                    if p.exists() {
                        println!("cargo:rerun-if-changed={}", p.display());
                    }
                }
            }
            head
        }
        (None, None) => {
            format!("unknown (built outside a git checkout, and {COMMIT_ENV} was not set)")
        }
    };
    println!("cargo:rustc-env=CONFORMANCE_COMMIT={commit}");
}
