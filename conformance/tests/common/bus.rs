//! `conformance bus` running beside a test until it ends, with its pseudo-terminals,
//! under a [`Kill`] guard.

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::sync::mpsc;
use std::time::Duration;

use super::{Kill, Run};

/// A running `conformance bus -q ARGS`, killed and reaped when it goes, and its
/// pseudo-terminals (name, path) as it printed them.
pub struct Bus {
    /// The guard of the bus process.
    pub guard: Kill,
    /// Its endpoints with a pseudo-terminal, in the order it printed them.
    pub ends: Vec<(String, PathBuf)>,
}

impl Bus {
    /// Starts `conformance bus -q ARGS` and reads its first `ptys` lines of stdout (one an
    /// endpoint: its name and path). Its stdout stays open while it runs (a bus whose
    /// stdout is gone ends).
    pub fn start(args: &[&str], ptys: usize) -> Bus {
        Bus::start_with(args, ptys, Stdio::inherit())
    }

    /// [`start`](Bus::start) with the bus's stderr piped, for the test to read once the bus
    /// has ended (`guard.stderr_text()`).
    pub fn start_with_stderr(args: &[&str], ptys: usize) -> Bus {
        Bus::start_with(args, ptys, Stdio::piped())
    }

    /// [`start`](Bus::start) with an endpoint for each of `links` (its name and the path of
    /// the link to its pseudo-terminal, which is there when this returns) and then `args`.
    pub fn linked(links: &[(&str, &Path)], args: &[&str]) -> Bus {
        Bus::linked_with(links, args, Stdio::inherit())
    }

    /// [`linked`](Bus::linked) with the bus's stderr piped, as
    /// [`start_with_stderr`](Bus::start_with_stderr).
    pub fn linked_with_stderr(links: &[(&str, &Path)], args: &[&str]) -> Bus {
        Bus::linked_with(links, args, Stdio::piped())
    }

    fn linked_with(links: &[(&str, &Path)], args: &[&str], stderr: Stdio) -> Bus {
        let named: Vec<String> = links
            .iter()
            .map(|(name, path)| format!("{name}={}", path.display()))
            .collect();
        let mut all: Vec<&str> = named.iter().flat_map(|l| ["--link", l.as_str()]).collect();
        all.extend(args);
        let bus = Bus::start_with(&all, links.len(), stderr);
        for (_, path) in links {
            super::wait_for(path);
        }
        bus
    }

    fn start_with(args: &[&str], ptys: usize, stderr: Stdio) -> Bus {
        let mut guard = Kill::spawn(
            Run::words("bus -q")
                .args(args)
                .command()
                .stdin(Stdio::null())
                .stdout(Stdio::piped())
                .stderr(stderr),
        );
        let stdout = guard.0.stdout.take().unwrap();
        let (tx, rx) = mpsc::channel();
        std::thread::spawn(move || {
            for line in BufReader::new(stdout).lines().map_while(Result::ok) {
                if tx.send(line).is_err() {
                    break;
                }
            }
        });
        let ends = (0..ptys)
            .map(|_| {
                let line = rx
                    .recv_timeout(Duration::from_secs(20))
                    .expect("the bus printed no endpoint");
                let mut w = line.split_whitespace();
                let name = w.next().unwrap().to_string();
                let path = PathBuf::from(w.next().unwrap_or_else(|| panic!("{line:?}")));
                (name, path)
            })
            .collect();
        Bus { guard, ends }
    }

    /// Stops the bus with SIGTERM; it must exit 0 within 10 s.
    pub fn terminate(&mut self) {
        terminate(&mut self.guard, "conformance bus");
    }
}

/// Sends SIGTERM to the guarded process; it must exit 0 within 10 s.
pub fn terminate(child: &mut Kill, what: &str) {
    let pid = nix::unistd::Pid::from_raw(i32::try_from(child.0.id()).unwrap());
    nix::sys::signal::kill(pid, nix::sys::signal::Signal::SIGTERM).unwrap();
    let status = child.wait_within(Duration::from_secs(10), &format!("{what} after SIGTERM"));
    assert_eq!(status.code(), Some(0), "{status:?}");
}

/// Asserts that none of `links` is left: a bus or a simulator removes its `--link`s on
/// its way out.
#[track_caller]
pub fn assert_links_gone(links: &[&Path]) {
    for l in links {
        assert!(
            std::fs::symlink_metadata(l).is_err(),
            "the link {} is left behind",
            l.display()
        );
    }
}
