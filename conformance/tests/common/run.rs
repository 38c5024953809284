//! Running a program to its end from a test: `conformance` (or another program) with its
//! arguments, folder, environment and a bound on its time, and what it left: the exit
//! code, stdout and stderr. A run that outlives its bound is killed and fails the test.

use std::ffi::{OsStr, OsString};
use std::io::{Read, Write};
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::Duration;

use super::{bin, Kill};

/// How long a run may take when the test does not say: far above any run's time on a
/// loaded machine, so that only a hang reaches it.
pub const DEFAULT_LIMIT: Duration = Duration::from_secs(600);

/// A program to run once, built up as `Run::new(["check", "--sim", "f510"]).in_dir(..)
/// .env(..).timeout(..)`, then [`run`](Run::run).
pub struct Run {
    cmd: Command,
    limit: Duration,
    stdin: Option<Vec<u8>>,
    /// Whether the program is `conformance`, whose stderr must show no panic.
    ours: bool,
}

impl Run {
    /// `conformance ARGS`.
    pub fn new<I, S>(args: I) -> Run
    where
        I: IntoIterator<Item = S>,
        S: AsRef<OsStr>,
    {
        let mut cmd = Command::new(bin());
        cmd.args(args);
        Run {
            cmd,
            limit: DEFAULT_LIMIT,
            stdin: None,
            ours: true,
        }
    }

    /// `conformance` with the words of `line` (split at white space) as its arguments:
    /// `Run::words("check --sim f510 --mode rtu")`.
    pub fn words(line: &str) -> Run {
        Run::new(line.split_whitespace())
    }

    /// Another program (mbpoll, Python, a compiler) with `args`.
    pub fn program<I, S>(program: impl AsRef<OsStr>, args: I) -> Run
    where
        I: IntoIterator<Item = S>,
        S: AsRef<OsStr>,
    {
        let mut cmd = Command::new(program);
        cmd.args(args);
        Run {
            cmd,
            limit: DEFAULT_LIMIT,
            stdin: None,
            ours: false,
        }
    }

    /// One more argument.
    pub fn arg(mut self, arg: impl AsRef<OsStr>) -> Run {
        self.cmd.arg(arg);
        self
    }

    /// More arguments.
    pub fn args<I, S>(mut self, args: I) -> Run
    where
        I: IntoIterator<Item = S>,
        S: AsRef<OsStr>,
    {
        self.cmd.args(args);
        self
    }

    /// The working folder of the run.
    pub fn in_dir(mut self, dir: impl AsRef<Path>) -> Run {
        self.cmd.current_dir(dir);
        self
    }

    /// One variable of the run's environment.
    pub fn env(mut self, key: impl AsRef<OsStr>, value: impl AsRef<OsStr>) -> Run {
        self.cmd.env(key, value);
        self
    }

    /// One variable taken out of the run's environment.
    pub fn env_remove(mut self, key: impl AsRef<OsStr>) -> Run {
        self.cmd.env_remove(key);
        self
    }

    /// The bound on the run's time (else [`DEFAULT_LIMIT`]).
    pub fn timeout(mut self, limit: Duration) -> Run {
        self.limit = limit;
        self
    }

    /// What the program reads on its stdin (else nothing: stdin is closed).
    pub fn stdin(mut self, bytes: impl Into<Vec<u8>>) -> Run {
        self.stdin = Some(bytes.into());
        self
    }

    /// The command as built, for a program that runs in the background under a [`Kill`]
    /// guard (its stdin, stdout and stderr are the caller's to set).
    pub fn command(self) -> Command {
        self.cmd
    }

    /// Starts the program in the background under a [`Kill`] guard, its stdin, stdout
    /// and stderr this process's (as [`Command::spawn`] leaves them).
    pub fn spawn(mut self) -> Kill {
        Kill::spawn(&mut self.cmd)
    }

    /// Runs the program to its end (a run past its bound is killed and fails the test; so
    /// does a panic of `conformance`) and returns what it left.
    pub fn run(mut self) -> Ran {
        let shown = shown(&self.cmd);
        let mut child = Kill::spawn(
            self.cmd
                .stdin(if self.stdin.is_some() {
                    Stdio::piped()
                } else {
                    Stdio::null()
                })
                .stdout(Stdio::piped())
                .stderr(Stdio::piped()),
        );
        if let Some(bytes) = self.stdin.take() {
            let mut w = child.0.stdin.take().unwrap();
            // A thread, so that a program that writes before it reads cannot block us.
            std::thread::spawn(move || {
                let _ = w.write_all(&bytes);
            });
        }
        let reader = |mut r: Box<dyn Read + Send>| {
            std::thread::spawn(move || {
                let mut b = Vec::new();
                let _ = r.read_to_end(&mut b);
                b
            })
        };
        let out = reader(Box::new(child.0.stdout.take().unwrap()));
        let err = reader(Box::new(child.0.stderr.take().unwrap()));
        let status = child.wait_within(self.limit, &shown);
        let (out, err) = (out.join().unwrap(), err.join().unwrap());
        let ran = Ran {
            code: status.code(),
            stdout: String::from_utf8_lossy(&out).into_owned(),
            stderr: String::from_utf8_lossy(&err).into_owned(),
            bytes: out,
            shown,
        };
        if self.ours {
            assert!(!ran.stderr.contains("panicked"), "{ran}");
        }
        ran
    }
}

/// The command line as a failure message shows it.
fn shown(cmd: &Command) -> String {
    let program = Path::new(cmd.get_program());
    let name = if program == Path::new(bin()) {
        OsString::from("conformance")
    } else {
        program.as_os_str().to_owned()
    };
    std::iter::once(name.as_os_str())
        .chain(cmd.get_args())
        .map(|a| a.to_string_lossy())
        .collect::<Vec<_>>()
        .join(" ")
}

/// What a [`Run`] left.
pub struct Ran {
    /// The exit code (None: ended by a signal).
    pub code: Option<i32>,
    /// Stdout as text (invalid UTF-8 replaced).
    pub stdout: String,
    /// Stderr as text.
    pub stderr: String,
    /// Stdout as bytes.
    pub bytes: Vec<u8>,
    /// The command line, for messages.
    pub shown: String,
}

impl Ran {
    /// Asserts that the run exited with `code` (printing the command, stdout and stderr
    /// when it did not) and returns it.
    #[track_caller]
    pub fn expect(self, code: i32) -> Ran {
        assert_eq!(self.code, Some(code), "{self}");
        self
    }

    /// Asserts that the run exited 0: [`expect`](Ran::expect)`(0)`.
    #[track_caller]
    pub fn ok(self) -> Ran {
        self.expect(0)
    }

    /// Stdout then stderr, as one text.
    pub fn text(&self) -> String {
        format!("{}{}", self.stdout, self.stderr)
    }

    /// Stdout parsed as JSON (a failure shows both outputs).
    #[track_caller]
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_str(&self.stdout)
            .unwrap_or_else(|e| panic!("stdout is no JSON ({e}): {self}"))
    }
}

impl std::fmt::Display for Ran {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "{} exited {:?}\n--- stdout ---\n{}\n--- stderr ---\n{}",
            self.shown, self.code, self.stdout, self.stderr
        )
    }
}

impl Ran {
    /// The exit code, stdout and stderr, for a test that takes them apart.
    pub fn parts(self) -> (Option<i32>, String, String) {
        (self.code, self.stdout, self.stderr)
    }
}

/// The words of `line` (split at white space), as a command's arguments:
/// `check_device(&dir, &words("--sim f510 --mode rtu"), limit)`.
pub fn words(line: &str) -> Vec<&str> {
    line.split_whitespace().collect()
}

/// Runs `conformance ARGS`, bounded by `limit` (a hang fails the test), asserts it did
/// not panic; exit code, stdout, stderr.
pub fn run_bounded(args: &[&str], limit: Duration) -> (Option<i32>, String, String) {
    Run::new(args).timeout(limit).run().parts()
}

/// As [`Display`](std::fmt::Display): the command, its exit and both outputs, for `{o:?}`
/// in a failure message.
impl std::fmt::Debug for Ran {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        std::fmt::Display::fmt(self, f)
    }
}

/// A command line with holes: each part split at white space, so that literal words go
/// in one string and the values between them as they are:
/// `line(&["--sim f510 --mode", mode, "-c 3 --format csv"])`. A value that holds a
/// space (a frame written "01 03 ...") must not go through it: pass it apart.
pub fn line<'a>(parts: &[&'a str]) -> Vec<&'a str> {
    parts.iter().flat_map(|p| p.split_whitespace()).collect()
}
