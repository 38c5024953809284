//! SIGTERM (what `timeout`, CI runners and systemd send) stops a long command as Ctrl-C
//! does: after the current exchange, with what it wrote restored and a whole report
//! marked incomplete (exit 2); the simulator ends and removes its --link.
#![cfg(unix)]

mod common;

use std::io::{BufRead, BufReader};
use std::path::{Path, PathBuf};
use std::process::Stdio;
use std::time::{Duration, Instant};

use common::{assert_contains_all, bin, words, Kill, Run, Scratch};
use nix::sys::signal::{kill, Signal};
use nix::unistd::Pid;

/// Waits (at most 120 s, for a loaded machine) until `ready` holds.
fn wait_until(what: &str, mut ready: impl FnMut() -> bool) {
    let t0 = Instant::now();
    while !ready() {
        assert!(
            t0.elapsed() < Duration::from_secs(120),
            "{what} did not happen"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

fn term(child: &Kill) {
    kill(Pid::from_raw(child.0.id() as i32), Signal::SIGTERM).unwrap();
}

/// The report at `path`: whole JSON, valid against the report schema.
fn whole_report(path: &Path, stderr: &str) -> serde_json::Value {
    let text = std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{e}: {stderr}"));
    let v: serde_json::Value =
        serde_json::from_str(&text).unwrap_or_else(|e| panic!("not whole JSON ({e}): {stderr}"));
    common::schema_valid(&v);
    v
}

/// A long command of the binary running in a fresh scratch folder named for it, writing
/// its JSON report there (stdout closed, stderr kept for when it has ended).
struct Long {
    /// The command's name (the first of its arguments), as a failure names it.
    cmd: String,
    /// Its JSON report, `<cmd>.json` in the folder.
    out: PathBuf,
    /// The simulator's log, `sim.jsonl` in the folder (written with `--sim-log` only).
    log: PathBuf,
    run: Kill,
    _dir: Scratch,
}

impl Long {
    /// `conformance ARGS --format json --quiet -o DIR/<cmd>.json`.
    fn start(args: &[&str]) -> Long {
        Long::spawn(args, false)
    }

    /// [`start`](Long::start) with `--sim-log DIR/sim.jsonl` after ARGS: the simulator
    /// writes a line per frame, flushed, so the test sees when the exchanges have begun.
    fn start_logged(args: &[&str]) -> Long {
        Long::spawn(args, true)
    }

    fn spawn(args: &[&str], sim_log: bool) -> Long {
        let cmd = args[0].to_string();
        let d = Scratch::new(&cmd);
        let (out, log) = (d.join(format!("{cmd}.json")), d.join("sim.jsonl"));
        let mut c = Run::new(args).command();
        if sim_log {
            c.arg("--sim-log").arg(&log);
        }
        let run = Kill::spawn(
            c.args(["--format", "json", "--quiet", "-o"])
                .arg(&out)
                .stdout(Stdio::null())
                .stderr(Stdio::piped()),
        );
        Long {
            cmd,
            out,
            log,
            run,
            _dir: d,
        }
    }

    /// Once `ready` holds (what `doing` names has begun), SIGTERM to the command, which
    /// must end within 120 s: how it ended and its stderr.
    fn terminated(
        &mut self,
        doing: &str,
        ready: impl Fn(&Long) -> bool,
    ) -> (std::process::ExitStatus, String) {
        wait_until(doing, || ready(self));
        term(&self.run);
        let status = self.run.wait_within(
            Duration::from_secs(120),
            &format!("{} after SIGTERM", self.cmd),
        );
        (status, self.run.stderr_text())
    }
}

/// `conformance simulate ...` as `sim` says, on a pseudo-terminal, its stdout read up to
/// its first line (the pty's path, which the caller checks), its stderr as `stderr` says.
fn simulate(sim: Run, stderr: Stdio) -> (Kill, String) {
    let mut sim = Kill::spawn(sim.command().stdout(Stdio::piped()).stderr(stderr));
    let mut first = String::new();
    BufReader::new(sim.0.stdout.take().unwrap())
        .read_line(&mut first)
        .unwrap();
    (sim, first)
}

#[test]
fn sigterm_ends_a_fuzz_run_with_a_whole_report_marked_incomplete() {
    let mut run = Long::start_logged(&words("fuzz --sim f510 --mode rtu --cases 100000"));
    // The simulator's log (a line per frame, flushed) grows past the preflight once
    // cases are being exchanged.
    let (status, stderr) = run.terminated("the fuzz exchanges", |r| {
        std::fs::read_to_string(&r.log).is_ok_and(|t| t.lines().count() >= 20)
    });
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(stderr.contains("interrupted"), "{stderr}");
    let v = whole_report(&run.out, &stderr);
    assert_eq!(v["complete"], false);
    assert_eq!(v["stopped"], "interrupted");
    assert_eq!(v["exit_code"], 2);
    let cases = v["fuzz"]["modes"][0]["cases"].as_u64().unwrap();
    assert!(cases > 0 && cases < 100_000, "{cases} cases");
    // The journal of the registers it may write is restored and verified.
    for r in v["restore"].as_array().unwrap() {
        assert_eq!(r["restored"], true, "{r}");
    }
}

#[test]
fn sigterm_ends_a_check_restoring_what_it_wrote() {
    let mut run = Long::start(&words("check --sim f510 --mode rtu"));
    // The report is rewritten after every check: wait until a writing check has run
    // (the manual's example of 10H writes 0101H and 0102H).
    let wrote = "rtu.example.f510.10.rtu.request";
    let (status, stderr) = run.terminated("the writing checks", |r| {
        std::fs::read_to_string(&r.out).is_ok_and(|t| t.contains(wrote))
    });
    assert_eq!(status.code(), Some(2), "{stderr}");
    let v = whole_report(&run.out, &stderr);
    assert_eq!(v["complete"], false, "{stderr}");
    assert_eq!(v["stopped"], "interrupted");
    assert_eq!(v["exit_code"], 2);
    let checks = v["checks"].as_array().unwrap().len();
    assert!(checks < 151, "stopped early: {checks} checks");
    let restore = v["restore"].as_array().unwrap();
    assert!(!restore.is_empty(), "no restore record: {stderr}");
    for r in restore {
        assert_eq!(r["restored"], true, "{r}");
        assert!(
            r["detail"].as_str().unwrap().contains("read back") || r["changed"] == false,
            "not verified: {r}"
        );
    }
    assert!(
        restore
            .iter()
            .any(|r| r["register"] == "0101" && r["changed"] == true),
        "the write of 0101H is not restored: {restore:?}"
    );
}

#[test]
fn sigterm_ends_the_simulator_and_removes_its_link() {
    let d = Scratch::new("simulate");
    let link = d.join("drive");
    let (mut sim, first) = simulate(
        Run::words("simulate --model f510 --pty --link").arg(&link),
        Stdio::piped(),
    );
    assert!(first.starts_with("/dev/"), "{first:?}");
    assert_eq!(
        std::fs::read_link(&link).unwrap(),
        PathBuf::from(first.trim())
    );
    // It serves through the link.
    let sent = Run::words("send --model f510 --mode rtu --port")
        .arg(&link)
        .arg("01 03 25 20 00 01 8E CC")
        .run();
    let said = sent.stdout.as_str();
    assert_eq!(sent.code, Some(0), "{said}");
    assert!(said.contains("device: node 01 03 read response"), "{said}");
    term(&sim);
    let status = sim.wait_within(Duration::from_secs(30), "simulate after SIGTERM");
    let stderr = sim.stderr_text();
    assert_eq!(status.code(), Some(0), "{stderr}");
    assert!(
        stderr.contains("stopped: ") && stderr.contains("frames received"),
        "{stderr}"
    );
    assert!(
        stderr.contains("interrupted: the simulator stops and removes its link"),
        "{stderr}"
    );
    common::assert_links_gone(&[&link]);
}

#[test]
fn the_simulator_replaces_a_stale_link_but_never_a_file() {
    let d = Scratch::new("stale");
    let link = d.join("drive");
    std::os::unix::fs::symlink("/dev/pts/nonexistent", &link).unwrap();
    let (mut sim, first) = simulate(
        Run::words("simulate --pty -q --link").arg(&link),
        Stdio::null(),
    );
    assert_eq!(
        std::fs::read_link(&link).unwrap(),
        PathBuf::from(first.trim())
    );
    kill(Pid::from_raw(sim.0.id() as i32), Signal::SIGINT).unwrap();
    sim.wait_within(Duration::from_secs(30), "simulate after SIGINT");
    common::assert_links_gone(&[&link]);

    let file = d.join("notes.txt");
    std::fs::write(&file, "keep me").unwrap();
    let stderr = Run::words("simulate --pty --link")
        .arg(&file)
        .timeout(Duration::from_secs(30))
        .run()
        .expect(2)
        .stderr;
    assert!(stderr.contains("is not a symbolic link"), "{stderr}");
    assert_eq!(std::fs::read_to_string(&file).unwrap(), "keep me");
}

#[test]
fn sigterm_ends_a_gate_run_with_a_whole_report_marked_incomplete() {
    let codec = format!("{} adapter", bin());
    // The adapter command has a space: it goes apart, as one argument.
    let mut run = Long::start(&[
        "gate",
        "--codec",
        &codec,
        "--no-vectors",
        "--count",
        "20000",
    ]);
    // The report is rewritten after every case.
    let (status, stderr) = run.terminated("the gate cases", |r| r.out.exists());
    assert_eq!(status.code(), Some(2), "{stderr}");
    let v = whole_report(&run.out, &stderr);
    assert_eq!(v["complete"], false);
    let stopped = v["stopped"].as_str().unwrap();
    assert!(stopped.starts_with("interrupted after "), "{stopped}");
    assert!(stopped.ends_with(" of 20000 cases"), "{stopped}");
    let n = v["checks"].as_array().unwrap().len();
    assert!(n > 0 && n < 20_000, "{n} cases");
}

#[test]
fn sigterm_ends_identify_with_its_report_not_run() {
    // Slow replies: the probes take seconds, the signal comes among them.
    let mut run = Long::start_logged(&words(
        "identify --sim f510 --mode rtu --quirk late-reply=300",
    ));
    let (status, stderr) = run.terminated("the identify probes", |r| {
        std::fs::metadata(&r.log).is_ok_and(|m| m.len() > 0)
    });
    assert_eq!(status.code(), Some(2), "{stderr}");
    let v = common::json_file(&run.out);
    assert_eq!(v["verdict"]["result"], "not-run", "{}", v["verdict"]);
    assert_eq!(v["verdict"]["text"], "could not identify: interrupted");
}

#[test]
fn sigterm_ends_a_scan_with_the_tries_made() {
    // One drive at an address the scan reaches late; its traffic log on stderr shows
    // when the scan's requests arrive.
    let (mut sim, pty) = simulate(
        Run::words("simulate --model f510 --pty -a 200"),
        Stdio::piped(),
    );
    let mut traffic = BufReader::new(sim.0.stderr.take().unwrap()).lines();
    let mut run = Long::start(&["scan", "--port", pty.trim()]);
    // The first request the drive hears.
    let heard = traffic.any(|l| l.is_ok_and(|l| l.contains("<- ")));
    assert!(heard, "the simulator heard nothing");
    let (status, stderr) = run.terminated("the scan's tries", |_| true);
    assert_eq!(status.code(), Some(2), "{stderr}");
    assert!(
        stderr.contains("scan interrupted: the result covers the tries made"),
        "{stderr}"
    );
    let v = common::json_file(&run.out);
    assert_eq!(v["stopped"], "interrupted");
    assert!(v["found"].as_array().unwrap().is_empty(), "{}", v["found"]);
}

/// monitor and bus say what they do when stopped, not what check does: SIGTERM ends the
/// monitor's listening with its whole report (exit 0, nothing heard), and the bus with its
/// links removed (exit 0).
#[test]
fn sigterm_ends_monitor_and_bus_each_in_its_own_words() {
    let d = Scratch::new("monitor-bus");
    let (master, tap) = (d.join("master"), d.join("tap"));
    // The bus prints its endpoints once its handler is in place.
    let mut bus = common::Bus::linked_with_stderr(&[("master", &master), ("tap", &tap)], &[]);
    for ((name, path), want) in bus.ends.iter().zip(["master", "tap"]) {
        assert_eq!(name, want);
        assert!(path.starts_with("/dev/"), "{name} {}", path.display());
    }

    let report = d.join("monitor.json");
    let mut monitor = common::Monitor::start(
        Run::words("monitor --model f510 -a 1 --mode rtu -b 9600")
            .args(["-P", "even", "--format", "json", "-o"])
            .arg(&report)
            .arg("--port")
            .arg(&tap)
            .command(),
    );
    monitor.signal(Signal::SIGTERM);
    let (status, said) = monitor.finish(Duration::from_secs(60), "monitor after SIGTERM");
    let said = said.join("\n");
    assert_eq!(status.code(), Some(0), "{said}");
    assert!(
        said.contains("interrupted: the monitor stops listening and writes its report"),
        "{said}"
    );
    assert!(!said.contains("check, case or probe"), "{said}");
    let v = whole_report(&report, &said);
    assert_eq!(
        v["monitor"]["ended"], "interrupted (Ctrl-C or SIGTERM)",
        "{:#}",
        v["monitor"]
    );

    term(&bus.guard);
    let status = bus
        .guard
        .wait_within(Duration::from_secs(60), "bus after SIGTERM");
    let stderr = bus.guard.stderr_text();
    assert_eq!(status.code(), Some(0), "{stderr}");
    assert!(
        stderr.contains("interrupted: the bus stops and removes its links"),
        "{stderr}"
    );
    assert!(!stderr.contains("check, case or probe"), "{stderr}");
    common::assert_links_gone(&[&master, &tap]);
}

/// The top-level help names monitor and bus under Ctrl-C and SIGTERM, with what each kind
/// of command does then and its exit code.
#[test]
fn the_help_says_what_each_long_command_does_when_stopped() {
    let o = Run::words("--help").run();
    let help = o.stdout.as_str();
    let at = help
        .find("Ctrl-C, SIGTERM and SIGHUP")
        .expect("no word on signals");
    let part = &help[at..];
    assert_contains_all(
        part,
        &[
            "check, fuzz, scan, identify and gate stop after their current check, case or probe",
            "marked incomplete (exit 2)",
            "monitor stops listening and writes its whole report (exit 0 or 1",
            "bus and simulate stop and remove their links (exit 0)",
        ],
    );
}
