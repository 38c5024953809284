//! `conformance monitor` running beside a test: started under a [`Kill`] guard, heard to
//! be listening, and its stderr read line by line as it comes (its live lines).

use std::io::{BufRead, BufReader, Read};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::mpsc::{self, Receiver};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::Duration;

use super::Kill;

/// The lines a child writes on one pipe, read by a thread as they come (so that it never
/// blocks on a full pipe): each kept, and sent on to the test.
pub struct Lines {
    said: Receiver<String>,
    all: Arc<Mutex<Vec<String>>>,
    reader: Option<JoinHandle<()>>,
}

impl Lines {
    /// Reads `pipe` to its end on a thread.
    pub fn read(pipe: impl Read + Send + 'static) -> Lines {
        let all = Arc::new(Mutex::new(Vec::new()));
        let (tx, said) = mpsc::channel();
        let kept = all.clone();
        let reader = std::thread::spawn(move || {
            for line in BufReader::new(pipe).lines().map_while(Result::ok) {
                kept.lock().unwrap().push(line.clone());
                let _ = tx.send(line);
            }
        });
        Lines {
            said,
            all,
            reader: Some(reader),
        }
    }

    /// The next line, within `limit` (None: none came).
    pub fn next_line(&self, limit: Duration) -> Option<String> {
        self.said.recv_timeout(limit).ok()
    }

    /// The lines read and not yet taken by [`next_line`](Lines::next_line).
    pub fn pending(&self) -> Vec<String> {
        self.said.try_iter().collect()
    }

    /// Every line read so far.
    pub fn all(&self) -> Vec<String> {
        self.all.lock().unwrap().clone()
    }

    /// Waits until the pipe is read to its end (the writer ended): every line.
    pub fn read_to_end(&mut self) -> Vec<String> {
        if let Some(r) = self.reader.take() {
            r.join().unwrap();
        }
        self.all()
    }
}

/// A running monitor: its guard, and its stderr's [`Lines`].
pub struct Monitor {
    /// The guard of the monitor process.
    pub guard: Kill,
    /// What it says on stderr.
    pub stderr: Lines,
}

impl Monitor {
    /// Starts `cmd` (stdin and stdout closed, stderr read here) and returns at once.
    pub fn spawn(mut cmd: Command) -> Monitor {
        let mut guard = Kill::spawn(
            cmd.stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(Stdio::piped()),
        );
        let stderr = Lines::read(guard.0.stderr.take().unwrap());
        Monitor { guard, stderr }
    }

    /// [`spawn`](Monitor::spawn), then [`until_listening`](Monitor::until_listening).
    pub fn start(cmd: Command) -> Monitor {
        let m = Monitor::spawn(cmd);
        m.until_listening();
        m
    }

    /// Waits (at most 30 s between lines) until the monitor says `listening on ...`,
    /// which it does once its port is open and has been read; the lines it said before.
    pub fn until_listening(&self) -> Vec<String> {
        let mut before = Vec::new();
        loop {
            let line = self
                .stderr
                .next_line(Duration::from_secs(30))
                .unwrap_or_else(|| panic!("the monitor never said it was listening: {before:?}"));
            if line.starts_with("listening on ") {
                return before;
            }
            before.push(line);
        }
    }

    /// Sends signal `s` to the monitor.
    pub fn signal(&self, s: nix::sys::signal::Signal) {
        let pid = nix::unistd::Pid::from_raw(i32::try_from(self.guard.0.id()).unwrap());
        nix::sys::signal::kill(pid, s).unwrap();
    }

    /// Waits (at most `limit`, else the test fails with "`what` hangs") for the monitor
    /// to end, then for its stderr to be read to the end: its status and every line it
    /// said.
    pub fn finish(&mut self, limit: Duration, what: &str) -> (ExitStatus, Vec<String>) {
        let status = self.guard.wait_within(limit, what);
        (status, self.stderr.read_to_end())
    }
}
