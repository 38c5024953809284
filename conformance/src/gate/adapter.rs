//! Talking to an adapter: a child process that speaks the line-delimited JSON protocol of
//! `adapters/PROTOCOL.md` on its standard input and output.
//!
//! Each call sends one request line and waits for the answer with the same id. A late
//! answer to an earlier request is discarded; a timeout or a malformed answer fails that
//! call only; an adapter that exits is restarted once, and after a second exit every
//! further call fails.

use std::io::{BufRead, BufReader, Read, Write};
use std::process::{Child, ChildStdin, Command, Stdio};
use std::sync::mpsc::{sync_channel, Receiver, RecvTimeoutError};
use std::sync::{Arc, Mutex};
use std::thread;
use std::time::{Duration, Instant};

use serde_json::{json, Value};

/// Protocol version the gate speaks.
pub const PROTOCOL: u64 = 1;

/// Longest answer line the gate reads (bytes, its `\n` included); a longer one is
/// malformed, and the gate never holds more of it than this (adapters/PROTOCOL.md states
/// the limit).
pub const MAX_LINE: usize = 1 << 20;

/// Answer lines read ahead of the gate: an adapter that writes lines nobody asked for
/// waits (its pipe fills) rather than growing the gate's memory.
pub const LINES_QUEUED: usize = 16;

/// Longest stderr line kept (bytes); the rest of a longer one is left out.
const MAX_STDERR_LINE: usize = 4096;

/// How long the gate waits for an adapter that closed its output to exit before it
/// kills it.
const EXIT_WAIT: Duration = Duration::from_secs(2);

/// The least time the gate waits for the hello's answer (the adapter's start).
pub const HANDSHAKE_TIMEOUT: Duration = Duration::from_secs(10);

/// Consecutive timeouts after which a hung adapter is restarted.
const HUNG_AFTER: u32 = 3;

/// Why an adapter could not be started or used at all.
#[derive(Debug, thiserror::Error)]
pub enum AdapterError {
    /// The command could not be started.
    #[error("cannot start the adapter {command:?}: {source}")]
    Spawn {
        /// The command.
        command: String,
        /// The cause.
        source: std::io::Error,
    },
    /// The handshake failed.
    #[error(
        "adapter {command:?}: handshake failed: {problem}{}\nhint: {hint}",
        shown(stderr)
    )]
    Handshake {
        /// The command.
        command: String,
        /// What went wrong.
        problem: String,
        /// What the adapter wrote on its stderr before it failed (its first and last
        /// lines), empty if nothing.
        stderr: Vec<String>,
        /// What to do about it.
        hint: String,
    },
}

/// The adapter's stderr lines under the error, indented.
fn shown(stderr: &[String]) -> String {
    if stderr.is_empty() {
        return "; it wrote nothing on stderr".into();
    }
    let mut s = String::from("; it wrote on stderr:");
    for line in stderr {
        s.push_str("\n  | ");
        s.push_str(line);
    }
    s
}

/// What to do about an adapter that failed its handshake, from what it wrote on stderr.
pub fn handshake_hint(command: &str, stderr: &[String]) -> String {
    let said = |what: &str| stderr.iter().any(|l| l.contains(what));
    if said("Cannot find module") || said("MODULE_NOT_FOUND") {
        "a Node.js module is missing: install the adapter's packages in its folder first \
         (for jsmodbus: `(cd adapters/jsmodbus && npm ci)`; see its README.md)"
            .into()
    } else if said("ModuleNotFoundError") || said("No module named") {
        "a Python module is missing: install the adapter's requirements (`pip install -r \
         adapters/<name>/requirements.txt`, see its README.md), or run the adapter with the \
         Python that has them"
            .into()
    } else if said(": not found") || said("No such file or directory") || said("command not found")
    {
        "the command was not found: check its path (a Rust adapter is built first, e.g. \
         `cargo build --release -p rmodbus-adapter`; this suite's own codec is \
         `--codec \"conformance adapter\"`)"
            .into()
    } else {
        format!(
            "run the adapter by itself to see why: echo '{{\"id\":0,\"op\":\"hello\",\"protocol\":{PROTOCOL}}}' | {command}"
        )
    }
}

/// Lines kept from the start and from the end of an adapter's stderr before its
/// handshake: a Node error leads with its message, a Python traceback ends with it.
const STDERR_HEAD: usize = 12;
const STDERR_TAIL: usize = 12;

/// An adapter's stderr: held back until its handshake succeeds (so that a failed start
/// is told once, in the error, with a hint), then passed through to ours.
#[derive(Default)]
struct StderrState {
    head: Vec<String>,
    tail: std::collections::VecDeque<String>,
    left_out: usize,
    pass_through: bool,
    ended: bool,
}

impl StderrState {
    fn keep(&mut self, line: String) {
        if self.head.len() < STDERR_HEAD {
            self.head.push(line);
            return;
        }
        self.tail.push_back(line);
        if self.tail.len() > STDERR_TAIL {
            self.tail.pop_front();
            self.left_out += 1;
        }
    }

    fn lines(&self) -> Vec<String> {
        let mut out = self.head.clone();
        if self.left_out > 0 {
            out.push(format!("... ({} lines left out)", self.left_out));
        }
        out.extend(self.tail.iter().cloned());
        out
    }
}

type Stderr = Arc<Mutex<StderrState>>;

/// Reads the adapter's stderr on a thread into `state` (or straight through, once it
/// passes through).
fn watch_stderr(pipe: std::process::ChildStderr, state: Stderr) {
    thread::spawn(move || {
        let mut reader = BufReader::new(pipe);
        let mut buf = Vec::new();
        loop {
            let line = match read_line(&mut reader, &mut buf, MAX_STDERR_LINE) {
                Ok(Some(RawLine::Whole)) => String::from_utf8_lossy(&buf).trim_end().to_string(),
                Ok(Some(RawLine::TooLong)) => format!(
                    "{} ... (a line over {MAX_STDERR_LINE} bytes, cut)",
                    String::from_utf8_lossy(&buf[..buf.len().min(200)]).trim_end()
                ),
                Ok(None) | Err(_) => break,
            };
            let Ok(mut s) = state.lock() else { break };
            if s.pass_through {
                drop(s);
                eprintln!("{line}");
            } else {
                s.keep(line);
            }
        }
        if let Ok(mut s) = state.lock() {
            s.ended = true;
        }
    });
}

/// Why one call failed.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum CallError {
    /// No answer within the timeout.
    #[error("no answer within {0} ms")]
    Timeout(u128),
    /// An answer that is not a protocol answer.
    #[error("malformed answer: {0}")]
    Malformed(String),
    /// The adapter exited; it was restarted (or could not be).
    #[error("the adapter exited ({0})")]
    Crashed(String),
    /// The adapter had exited twice: no more calls.
    #[error("the adapter is gone (it exited twice)")]
    Gone,
    /// The adapter does not support the operation.
    #[error("unsupported by the adapter")]
    Unsupported,
    /// The adapter answered with an error.
    #[error("the adapter failed: {0}")]
    Failed(String),
}

/// What the adapter said in its handshake.
#[derive(Debug, Clone, PartialEq, Eq, Default)]
pub struct Hello {
    /// The adapter's name.
    pub adapter: String,
    /// The implementation it wraps.
    pub implementation: String,
    /// Its version.
    pub version: String,
    /// Operations supported ("decode", "encode:rtu", ...).
    pub supports: Vec<String>,
    /// The whole answer, for fields a role adds (a master's `lines` and `modes`).
    pub raw: Value,
}

impl Hello {
    /// Whether `op` is supported in `mode` ("decode" and "rtu": "decode" or "decode:rtu").
    pub fn supports(&self, op: &str, mode: Option<&str>) -> bool {
        self.supports
            .iter()
            .any(|s| s == op || mode.is_some_and(|m| *s == format!("{op}:{m}")))
    }
}

impl Hello {
    /// Reads the adapter's answer to the hello: refused unless it says `ok` and speaks
    /// [`PROTOCOL`]; fields of the wrong type read as absent.
    pub fn from_answer(v: Value) -> Result<Hello, String> {
        if v.get("ok") != Some(&Value::Bool(true)) {
            return Err(format!("the adapter refused protocol {PROTOCOL}: {v}"));
        }
        if v.get("protocol").and_then(Value::as_u64) != Some(PROTOCOL) {
            return Err(format!(
                "the adapter speaks protocol {:?}, the gate {PROTOCOL}",
                v.get("protocol")
            ));
        }
        let s = |k: &str| v.get(k).and_then(Value::as_str).unwrap_or("").to_string();
        Ok(Hello {
            adapter: s("adapter"),
            implementation: s("implementation"),
            version: s("version"),
            supports: string_list(&v, "supports"),
            raw: v,
        })
    }
}

/// The strings of the JSON array under `key` of an adapter's answer or a saved report;
/// absent, not an array, or an element not a string reads as nothing (an adapter's hello
/// and the reports read leniently).
pub fn string_list(v: &Value, key: &str) -> Vec<String> {
    v.get(key)
        .and_then(Value::as_array)
        .map(|a| {
            a.iter()
                .filter_map(|x| x.as_str().map(String::from))
                .collect()
        })
        .unwrap_or_default()
}

/// One line the adapter wrote on its standard output, as the gate reads it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Line {
    /// A line of UTF-8 text, without its line end.
    Text(String),
    /// A line over [`MAX_LINE`] bytes (the rest of it was skipped, never held).
    TooLong,
    /// A line that is not UTF-8: where the first bad byte is, and up to 16 bytes from it.
    NotUtf8 {
        /// Its offset in the line.
        at: usize,
        /// The bytes from there.
        bytes: Vec<u8>,
    },
}

/// How [`read_line`] ended.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum RawLine {
    /// A whole line (or the last bytes before the end of the input) is in the buffer.
    Whole,
    /// The line was longer than the limit: the buffer holds its first `limit` bytes, and
    /// the rest was read and dropped a piece at a time.
    TooLong,
}

/// Reads one line of at most `limit` bytes from `reader` into `buf` (cleared first);
/// `None` at the end of the input. Never holds more than `limit` bytes of a line and the
/// reader's own buffer, however long the line is.
pub fn read_line(
    reader: &mut impl BufRead,
    buf: &mut Vec<u8>,
    limit: usize,
) -> std::io::Result<Option<RawLine>> {
    buf.clear();
    let n = reader
        .by_ref()
        .take(limit as u64 + 1)
        .read_until(b'\n', buf)?;
    if n == 0 {
        return Ok(None);
    }
    if buf.len() <= limit {
        return Ok(Some(RawLine::Whole));
    }
    // Over the limit: its end may be the byte past it, already read; else the rest of the
    // line is skipped from the reader's buffer, a piece at a time.
    let ended = buf.last() == Some(&b'\n');
    buf.truncate(limit);
    if !ended {
        loop {
            let (used, found) = {
                let piece = reader.fill_buf()?;
                if piece.is_empty() {
                    break;
                }
                match memchr::memchr(b'\n', piece) {
                    Some(i) => (i + 1, true),
                    None => (piece.len(), false),
                }
            };
            reader.consume(used);
            if found {
                break;
            }
        }
    }
    Ok(Some(RawLine::TooLong))
}

/// Reads the adapter's next answer line from `reader` (see [`read_line`] and
/// [`MAX_LINE`]); `None` at the end of its output.
pub fn next_line(reader: &mut impl BufRead, buf: &mut Vec<u8>) -> Option<Line> {
    next_line_within(reader, buf, MAX_LINE)
}

/// [`next_line`] with a limit of `limit` bytes in place of [`MAX_LINE`] (the fuzz target
/// reaches the limit with short inputs).
pub fn next_line_within(
    reader: &mut impl BufRead,
    buf: &mut Vec<u8>,
    limit: usize,
) -> Option<Line> {
    match read_line(reader, buf, limit) {
        Ok(Some(RawLine::Whole)) => Some(match std::str::from_utf8(buf) {
            Ok(text) => Line::Text(text.trim_end().to_string()),
            Err(e) => {
                let at = e.valid_up_to();
                Line::NotUtf8 {
                    at,
                    bytes: buf[at..buf.len().min(at + 16)].to_vec(),
                }
            }
        }),
        Ok(Some(RawLine::TooLong)) => Some(Line::TooLong),
        Ok(None) | Err(_) => None,
    }
}

/// What one answer line is to a call waiting for answer `id`.
#[derive(Debug, Clone, PartialEq)]
pub enum Heard {
    /// Its answer.
    Answer(Value),
    /// A late answer to an earlier request: dropped, the call waits on.
    Late,
    /// A line that is no answer to it: the call fails with this.
    Error(CallError),
}

/// Judges one line the adapter wrote while the gate waits for answer `id` (0: the
/// hello). Total: every line is an answer, a late one, or a typed error that shows the
/// offending text or bytes.
pub fn hear(line: &Line, id: u64) -> Heard {
    let text = match line {
        Line::TooLong => {
            return Heard::Error(CallError::Malformed(format!(
                "an answer line over {MAX_LINE} bytes"
            )))
        }
        Line::NotUtf8 { at, bytes } => {
            return Heard::Error(CallError::Malformed(format!(
                "an answer line that is not UTF-8: at byte {at}, {}",
                crate::codec::hex::Hex(bytes)
            )))
        }
        Line::Text(t) => t,
    };
    let v: Value = match serde_json::from_str(text) {
        Ok(v) => v,
        Err(e) => {
            let shown: String = text.chars().take(200).collect();
            return Heard::Error(CallError::Malformed(format!("not JSON ({e}): {shown:?}")));
        }
    };
    match v.get("id").and_then(Value::as_u64) {
        Some(got) if got == id => Heard::Answer(v),
        // A late answer to an earlier request: drop it.
        Some(got) if got < id || (id == 0 && got > 0) => Heard::Late,
        other => Heard::Error(CallError::Malformed(format!(
            "answer id {other:?}, expected {id}: {}",
            text.chars().take(200).collect::<String>()
        ))),
    }
}

struct Process {
    child: Child,
    stdin: ChildStdin,
    lines: Receiver<Line>,
    stderr: Stderr,
}

impl Process {
    /// From now on the adapter's stderr goes straight to ours (what it held back first).
    fn pass_stderr_through(&self) {
        if let Ok(mut s) = self.stderr.lock() {
            for line in s.lines() {
                eprintln!("{line}");
            }
            *s = StderrState {
                pass_through: true,
                ..StderrState::default()
            };
        }
    }

    /// What the adapter wrote on stderr so far; waits a moment for the end of it when
    /// the adapter has exited (the reading thread may be behind).
    fn stderr_lines(&mut self) -> Vec<String> {
        let exited = matches!(self.child.try_wait(), Ok(Some(_)));
        let deadline = Instant::now() + Duration::from_secs(2);
        loop {
            match self.stderr.lock() {
                Ok(s) if s.ended || !exited || Instant::now() >= deadline => return s.lines(),
                Ok(_) => {}
                Err(_) => return Vec::new(),
            }
            thread::sleep(Duration::from_millis(10));
        }
    }
}

/// Kills the adapter and everything in its process group, and reaps it.
fn kill(child: &mut Child) {
    #[cfg(unix)]
    if let Ok(pid) = i32::try_from(child.id()) {
        let _ = nix::sys::signal::killpg(
            nix::unistd::Pid::from_raw(pid),
            nix::sys::signal::Signal::SIGKILL,
        );
    }
    let _ = child.kill();
    let _ = child.wait();
}

/// The child's exit status, waiting at most `wait` for it to exit, then killing it.
fn wait_or_kill(child: &mut Child, wait: Duration) -> String {
    let deadline = Instant::now() + wait;
    loop {
        match child.try_wait() {
            Ok(Some(s)) => return s.to_string(),
            Ok(None) if Instant::now() < deadline => thread::sleep(Duration::from_millis(10)),
            Ok(None) => {
                kill(child);
                return format!(
                    "it closed its output and did not exit within {} ms: killed",
                    wait.as_millis()
                );
            }
            Err(e) => return e.to_string(),
        }
    }
}

/// A running adapter.
pub struct Adapter {
    command: String,
    timeout: Duration,
    process: Option<Process>,
    next_id: u64,
    exits: u32,
    timeouts: u32,
    /// Until the first handshake succeeds: an adapter that fails to start is reported
    /// (with its stderr), not restarted.
    starting: bool,
    /// The handshake.
    pub hello: Hello,
    /// Crashes and restarts, for the report.
    pub incidents: Vec<String>,
    /// Fields the hello carries besides `op` and `protocol` (a master's `"role"`).
    hello_extra: Value,
    /// A request sent again after a restart, before the next call (a master's `open`).
    reopen: Option<Value>,
}

/// Starts `command`; its stderr is held back until [`Process::pass_stderr_through`], or
/// passes through at once with `pass_through`.
fn spawn(command: &str, pass_through: bool) -> Result<Process, std::io::Error> {
    let mut cmd = Command::new("sh");
    cmd.arg("-c")
        .arg(command)
        .stdin(Stdio::piped())
        .stdout(Stdio::piped())
        .stderr(Stdio::piped());
    // Its own process group, so that killing it also kills what the shell started.
    #[cfg(unix)]
    std::os::unix::process::CommandExt::process_group(&mut cmd, 0);
    let mut child = cmd.spawn()?;
    let stdin = child
        .stdin
        .take()
        .ok_or_else(|| std::io::Error::other("no stdin"))?;
    let stdout = child
        .stdout
        .take()
        .ok_or_else(|| std::io::Error::other("no stdout"))?;
    let stderr: Stderr = Arc::new(Mutex::new(StderrState {
        pass_through,
        ..StderrState::default()
    }));
    if let Some(pipe) = child.stderr.take() {
        watch_stderr(pipe, stderr.clone());
    }
    let (tx, rx) = sync_channel(LINES_QUEUED);
    thread::spawn(move || {
        let mut reader = BufReader::new(stdout);
        let mut buf = Vec::new();
        while let Some(line) = next_line(&mut reader, &mut buf) {
            if tx.send(line).is_err() {
                return;
            }
            // A huge line's buffer is not kept for the short ones after it.
            if buf.capacity() > 64 * 1024 {
                buf = Vec::new();
            }
        }
    });
    Ok(Process {
        child,
        stdin,
        lines: rx,
        stderr,
    })
}

impl Adapter {
    /// Starts `command` (through `sh -c`) and shakes hands.
    pub fn start(command: &str, timeout: Duration) -> Result<Self, AdapterError> {
        Self::start_with(command, timeout, json!({}))
    }

    /// [`Adapter::start`] with `extra` fields in the hello (`{"role": "master"}`).
    pub fn start_with(
        command: &str,
        timeout: Duration,
        extra: Value,
    ) -> Result<Self, AdapterError> {
        let process = spawn(command, false).map_err(|source| AdapterError::Spawn {
            command: command.to_string(),
            source,
        })?;
        let mut a = Adapter {
            command: command.to_string(),
            timeout,
            process: Some(process),
            next_id: 1,
            exits: 0,
            timeouts: 0,
            starting: true,
            hello: Hello::default(),
            incidents: Vec::new(),
            hello_extra: extra,
            reopen: None,
        };
        match a.handshake() {
            Ok(hello) => a.hello = hello,
            Err(problem) => {
                let stderr = a
                    .process
                    .as_mut()
                    .map(Process::stderr_lines)
                    .unwrap_or_default();
                return Err(AdapterError::Handshake {
                    command: command.to_string(),
                    hint: handshake_hint(command, &stderr),
                    problem,
                    stderr,
                });
            }
        }
        if let Some(p) = &a.process {
            p.pass_stderr_through();
        }
        a.starting = false;
        Ok(a)
    }

    fn handshake(&mut self) -> Result<Hello, String> {
        // The first answer comes after the adapter's start: an interpreter importing a large
        // library can take seconds on a loaded CI machine, so it gets at least
        // HANDSHAKE_TIMEOUT, whatever the per-case timeout.
        let per_case = self.timeout;
        self.timeout = per_case.max(HANDSHAKE_TIMEOUT);
        let mut hello = json!({"op": "hello", "protocol": PROTOCOL});
        if let (Some(h), Some(extra)) = (hello.as_object_mut(), self.hello_extra.as_object()) {
            for (k, v) in extra {
                h.insert(k.clone(), v.clone());
            }
        }
        let answer = self.raw_call_with_id(0, hello);
        self.timeout = per_case;
        let v = answer.map_err(|e| e.to_string())?;
        Hello::from_answer(v)
    }

    /// The time each answer is waited for.
    pub fn timeout(&self) -> Duration {
        self.timeout
    }

    /// Sets the time each answer is waited for (a master's worst case changes with its
    /// settings).
    pub fn set_timeout(&mut self, timeout: Duration) {
        self.timeout = timeout;
    }

    /// A request to send again, once, after the adapter is restarted (a master's `open`:
    /// a restarted adapter has no line open). Its answer is not judged.
    pub fn set_reopen(&mut self, request: Option<Value>) {
        self.reopen = request;
    }

    /// The command.
    pub fn command(&self) -> &str {
        &self.command
    }

    /// The adapter exited or its input closed: restarted once (see [`Adapter::restart`]),
    /// except at the start, where the failure is the error.
    fn exited(&mut self, why: String) -> CallError {
        if self.starting {
            CallError::Crashed(why)
        } else {
            self.restart(why)
        }
    }

    fn restart(&mut self, why: String) -> CallError {
        if let Some(mut p) = self.process.take() {
            kill(&mut p.child);
        }
        self.exits += 1;
        if self.exits > 1 {
            self.incidents
                .push(format!("{why}; exited a second time, not restarted"));
            return CallError::Crashed(why);
        }
        match spawn(&self.command, true) {
            Ok(p) => {
                self.process = Some(p);
                match self.handshake() {
                    Ok(_) => {
                        self.incidents.push(format!("{why}; restarted"));
                        if let Some(open) = self.reopen.clone() {
                            if let Err(e) = self.raw_call(open) {
                                self.incidents.push(format!(
                                    "after the restart, opening its line again failed: {e}"
                                ));
                            }
                        }
                    }
                    Err(e) => {
                        self.incidents
                            .push(format!("{why}; restarted, but the handshake failed: {e}"));
                        self.process = None;
                        self.exits = 2;
                    }
                }
            }
            Err(e) => {
                self.incidents
                    .push(format!("{why}; could not restart: {e}"));
                self.exits = 2;
            }
        }
        CallError::Crashed(why)
    }

    fn raw_call(&mut self, request: Value) -> Result<Value, CallError> {
        let id = self.next_id;
        self.next_id += 1;
        self.raw_call_with_id(id, request)
    }

    /// The handshake always has id 0 (also after a restart); requests count from 1.
    fn raw_call_with_id(&mut self, id: u64, mut request: Value) -> Result<Value, CallError> {
        request["id"] = json!(id);
        let Some(p) = self.process.as_mut() else {
            return Err(CallError::Gone);
        };
        let mut line = request.to_string();
        line.push('\n');
        if let Err(e) = p
            .stdin
            .write_all(line.as_bytes())
            .and_then(|_| p.stdin.flush())
        {
            // At the start, an adapter that could not even read its hello has usually
            // exited: its end of output and exit status (read below) say so, whichever
            // of the two pipes the race closed first.
            if !self.starting {
                let status = p.child.try_wait().ok().flatten();
                return Err(self.exited(format!(
                    "writing to it failed ({e}){}",
                    status.map(|s| format!(", {s}")).unwrap_or_default()
                )));
            }
        }
        let deadline = crate::codec::timing::later(Instant::now(), self.timeout);
        loop {
            let left = deadline.saturating_duration_since(Instant::now());
            let p = self.process.as_mut().ok_or(CallError::Gone)?;
            match p.lines.recv_timeout(left) {
                Ok(line) => match hear(&line, id) {
                    Heard::Answer(v) => {
                        self.timeouts = 0;
                        return Ok(v);
                    }
                    Heard::Late => continue,
                    Heard::Error(e) => return Err(e),
                },
                Err(RecvTimeoutError::Timeout) => {
                    self.timeouts += 1;
                    if self.timeouts >= HUNG_AFTER {
                        self.timeouts = 0;
                        let _ =
                            self.restart(format!("{HUNG_AFTER} requests in a row got no answer"));
                    }
                    return Err(CallError::Timeout(self.timeout.as_millis()));
                }
                Err(RecvTimeoutError::Disconnected) => {
                    // An adapter that closed its output but does not exit is killed: the
                    // gate does not wait on it for ever.
                    let status = wait_or_kill(&mut p.child, EXIT_WAIT);
                    return Err(self.exited(format!("its output closed: {status}")));
                }
            }
        }
    }

    /// Sends one request (without id) and returns the answer of an `ok` call.
    pub fn call(&mut self, request: Value) -> Result<Value, CallError> {
        let v = self.raw_call(request)?;
        match v.get("ok") {
            Some(Value::Bool(true)) => Ok(v),
            Some(Value::Bool(false)) => {
                let e = v
                    .get("error")
                    .and_then(Value::as_str)
                    .unwrap_or("")
                    .to_string();
                if e == "unsupported" {
                    Err(CallError::Unsupported)
                } else {
                    Err(CallError::Failed(e))
                }
            }
            _ => Err(CallError::Malformed(format!("no \"ok\" field: {v}"))),
        }
    }
}

impl Drop for Adapter {
    fn drop(&mut self) {
        if let Some(mut p) = self.process.take() {
            drop(p.stdin);
            // Give it a moment to exit on end of input, then make sure.
            let deadline = Instant::now() + Duration::from_millis(500);
            loop {
                match p.child.try_wait() {
                    Ok(Some(_)) => break,
                    Ok(None) if Instant::now() < deadline => {
                        thread::sleep(Duration::from_millis(10))
                    }
                    _ => {
                        kill(&mut p.child);
                        break;
                    }
                }
            }
        }
    }
}
