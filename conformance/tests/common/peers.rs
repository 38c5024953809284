//! The peers the integration tests start and stop: the simulator (on a pseudo-terminal
//! or as a Modbus TCP gateway), pseudo-terminal pairs, pymodbus's serial and TCP
//! servers; the guard that kills and reaps each of them when the test ends, also when it
//! fails; and the waits for a path, a port or a banner to appear.

use std::io::{BufRead, BufReader, Read};
use std::path::{Path, PathBuf};
use std::process::{Command, ExitStatus, Stdio};
use std::sync::{mpsc, Arc};
use std::time::{Duration, Instant};

use super::{bin, need, note, python, Peer};

/// A child process that is killed and reaped when the guard goes, also when a test fails.
pub struct Kill(pub std::process::Child);

impl Kill {
    /// Starts `cmd` under the guard (a failure to start fails the test).
    pub fn spawn(cmd: &mut Command) -> Kill {
        Kill(
            cmd.spawn()
                .unwrap_or_else(|e| panic!("cannot start {cmd:?}: {e}")),
        )
    }

    /// Waits for the child to end; still running after `limit`, it fails the test with
    /// "`what` hangs" (the guard then kills it).
    pub fn wait_within(&mut self, limit: Duration, what: &str) -> ExitStatus {
        let t0 = Instant::now();
        loop {
            if let Some(s) = self.0.try_wait().unwrap() {
                return s;
            }
            assert!(t0.elapsed() < limit, "{what} hangs");
            std::thread::sleep(Duration::from_millis(20));
        }
    }

    /// What the child wrote on its piped stderr (after it ended).
    pub fn stderr_text(&mut self) -> String {
        let mut err = Vec::new();
        if let Some(s) = self.0.stderr.as_mut() {
            s.read_to_end(&mut err).unwrap();
        }
        String::from_utf8_lossy(&err).into_owned()
    }
}

impl Drop for Kill {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// Whether `cmd ARGS` runs and succeeds (its output thrown away).
pub fn runs(cmd: &str, args: &[&str]) -> bool {
    Command::new(cmd)
        .args(args)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success())
}

/// Waits (at most 10 s) for a path to appear.
pub fn wait_for(p: &Path) {
    let t0 = Instant::now();
    while !p.exists() {
        assert!(
            t0.elapsed() < Duration::from_secs(10),
            "{} did not appear",
            p.display()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

/// Waits (at most `limit`) until something listens on `addr`.
pub fn wait_listening(addr: &str, limit: Duration) {
    let t0 = Instant::now();
    while std::net::TcpStream::connect(addr).is_err() {
        assert!(t0.elapsed() < limit, "nothing listens on {addr}");
        std::thread::sleep(Duration::from_millis(30));
    }
}

/// A TCP port on 127.0.0.1 that was free a moment ago.
pub fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

/// Two pseudo-terminals joined back to back, linked at `dir/ttyA` and `dir/ttyB`: a line
/// between a device under test (on A) and the runner (on B), as `socat pty pty` makes one,
/// but with nothing to install. This process holds both masters and copies every byte
/// from one to the other on a thread, at once (no line timing), until the guard goes.
pub struct PtyPair {
    stop: Arc<std::sync::atomic::AtomicBool>,
    thread: Option<std::thread::JoinHandle<()>>,
    links: [PathBuf; 2],
}

impl Drop for PtyPair {
    fn drop(&mut self) {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        for l in &self.links {
            let _ = std::fs::remove_file(l);
        }
    }
}

/// One raw pseudo-terminal: its master, its slave (held open so that the master never
/// reads a hang-up while no program has the slave open) and the slave's path.
fn raw_pty() -> (std::os::fd::OwnedFd, std::os::fd::OwnedFd, PathBuf) {
    use nix::sys::termios::{cfmakeraw, tcgetattr, tcsetattr, SetArg};
    let pair = nix::pty::openpty(None, None).expect("openpty");
    let mut t = tcgetattr(&pair.slave).unwrap();
    cfmakeraw(&mut t);
    tcsetattr(&pair.slave, SetArg::TCSANOW, &t).unwrap();
    let path = nix::unistd::ttyname(&pair.slave).unwrap();
    (pair.master, pair.slave, path)
}

/// A [`PtyPair`] in `dir`: the guard and the paths of ends A and B.
pub fn pty_pair(dir: &Path) -> (PtyPair, PathBuf, PathBuf) {
    use nix::poll::{poll, PollFd, PollFlags, PollTimeout};
    use std::os::fd::AsFd;
    let (a, b) = (dir.join("ttyA"), dir.join("ttyB"));
    let (ma, sa, pa) = raw_pty();
    let (mb, sb, pb) = raw_pty();
    for (link, target) in [(&a, &pa), (&b, &pb)] {
        let _ = std::fs::remove_file(link);
        std::os::unix::fs::symlink(target, link).unwrap();
    }
    let stop = Arc::new(std::sync::atomic::AtomicBool::new(false));
    let halt = stop.clone();
    let thread = std::thread::spawn(move || {
        let _slaves = (sa, sb);
        let mut buf = [0u8; 4096];
        while !halt.load(std::sync::atomic::Ordering::Relaxed) {
            let mut fds = [
                PollFd::new(ma.as_fd(), PollFlags::POLLIN),
                PollFd::new(mb.as_fd(), PollFlags::POLLIN),
            ];
            match poll(&mut fds, PollTimeout::from(20u8)) {
                Ok(0) | Err(nix::errno::Errno::EINTR) => continue,
                Ok(_) => {}
                Err(e) => panic!("poll on the pty pair: {e}"),
            }
            let ready = fds.map(|f| f.revents().is_some_and(|r| r.intersects(PollFlags::POLLIN)));
            for (from, to, is_ready) in [(&ma, &mb, ready[0]), (&mb, &ma, ready[1])] {
                if !is_ready {
                    continue;
                }
                match nix::unistd::read(from, &mut buf) {
                    Ok(n) if n > 0 => {
                        let mut rest = &buf[..n];
                        while !rest.is_empty() {
                            match nix::unistd::write(to, rest) {
                                Ok(w) => rest = &rest[w..],
                                Err(nix::errno::Errno::EINTR | nix::errno::Errno::EAGAIN) => {}
                                Err(e) => panic!("write on the pty pair: {e}"),
                            }
                        }
                    }
                    // EIO: no program has that end open (the slave this thread holds
                    // keeps it from happening; tolerated all the same).
                    _ => std::thread::sleep(Duration::from_millis(5)),
                }
            }
        }
    });
    (
        PtyPair {
            stop,
            thread: Some(thread),
            links: [a.clone(), b.clone()],
        },
        a,
        b,
    )
}

/// Starts `conformance simulate --pty -q ARGS` and returns it with the pty slave path
/// (the first word of its first stdout line that starts with /dev/).
pub fn sim_pty(args: &[&str]) -> (Kill, String) {
    let mut child = Kill::spawn(
        Command::new(bin())
            .args(["simulate", "--pty", "-q"])
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null()),
    );
    let stdout = child.0.stdout.take().unwrap();
    let mut line = String::new();
    BufReader::new(stdout).read_line(&mut line).unwrap();
    let path = line
        .split_whitespace()
        .find(|w| w.starts_with("/dev/"))
        .unwrap_or_else(|| panic!("no pty path in {line:?}"))
        .to_string();
    (child, path)
}

/// A device on one end of a [`PtyPair`]: the guards (the device goes first, then the
/// line) and the runner's end of the line.
pub struct SerialPeer {
    pub device: Kill,
    pub line: PtyPair,
    pub port: PathBuf,
}

/// pymodbus's generic serial server (tests/interop/pymodbus_server.py) in `mode` on one
/// end of a [`PtyPair`] in `dir`, answering; None (after SKIPPED) when pymodbus is missing.
pub fn pymodbus_serial_server(dir: &Path, mode: &str) -> Option<SerialPeer> {
    pymodbus_serial_nodes(dir, mode, "1")
}

/// [`pymodbus_serial_server`] serving the node addresses `nodes` ("1,2"), each with its
/// own registers.
pub fn pymodbus_serial_nodes(dir: &Path, mode: &str, nodes: &str) -> Option<SerialPeer> {
    pymodbus_serial_with(dir, mode, nodes, 65535)
}

/// [`pymodbus_serial_nodes`] with holding registers 0000H..`registers`-1 only: a generic
/// device without the registers from `registers` up (reads there get exception 02H).
pub fn pymodbus_serial_with(
    dir: &Path,
    mode: &str,
    nodes: &str,
    registers: u32,
) -> Option<SerialPeer> {
    pymodbus_serial_args(dir, mode, nodes, &["--registers", &registers.to_string()])
}

/// [`pymodbus_serial_server`] at node 1 serving the holding-register blocks `blocks`
/// only ("0000-0FFF,2500-252F", hex): a read that leaves a block gets exception 02H.
pub fn pymodbus_serial_blocks(dir: &Path, mode: &str, blocks: &str) -> Option<SerialPeer> {
    pymodbus_serial_args(dir, mode, "1", &["--blocks", blocks])
}

/// [`pymodbus_serial_nodes`] with `extra` options of tests/interop/pymodbus_server.py.
fn pymodbus_serial_args(dir: &Path, mode: &str, nodes: &str, extra: &[&str]) -> Option<SerialPeer> {
    let first = nodes.split(',').next().unwrap_or("1");
    pymodbus_on_pty(
        dir,
        "pymodbus_server.py",
        &[],
        &[&[mode, "--address", nodes][..], extra].concat(),
        (mode, &["-P", "none", "-a", first]),
    )
}

/// The pymodbus server tests/interop/SCRIPT started as `SCRIPT BEFORE A AFTER` (A: the
/// path of end A of a [`PtyPair`] in `dir`); returns once the runner's end answers in
/// `answers` (a mode and the line options); None (after SKIPPED) when pymodbus is
/// missing.
fn pymodbus_on_pty(
    dir: &Path,
    script: &str,
    before: &[&str],
    after: &[&str],
    answers: (&str, &[&str]),
) -> Option<SerialPeer> {
    if !need(Peer::Pymodbus) {
        return None;
    }
    let (line, a, b) = pty_pair(dir);
    let server = format!("{}/tests/interop/{script}", env!("CARGO_MANIFEST_DIR"));
    let device = Kill::spawn(
        Command::new(python())
            .arg(server)
            .args(before)
            .arg(&a)
            .args(after)
            .stderr(Stdio::null()),
    );
    super::wait_until_answers(&b, answers.0, answers.1);
    Some(SerialPeer {
        device,
        line,
        port: b,
    })
}

/// pymodbus's simulator (tests/interop/pymodbus_sim_server.py) serving the simulator JSON
/// `sim` (as `model export --to pymodbus-sim` writes it) in RTU on one end of a
/// [`PtyPair`] in `dir`; None (after SKIPPED) when pymodbus is missing.
pub fn pymodbus_sim_serial(dir: &Path, sim: &Path) -> Option<SerialPeer> {
    pymodbus_on_pty(
        dir,
        "pymodbus_sim_server.py",
        &[sim.to_str().unwrap()],
        &[],
        ("rtu", &["-P", "none"]),
    )
}

/// pymodbus's generic Modbus TCP server (tests/interop/pymodbus_tcp_server.py) with one
/// unit id, listening on a free port of 127.0.0.1: the guard and its address; None
/// (after SKIPPED) when pymodbus is missing.
pub fn pymodbus_tcp_server(unit: u8) -> Option<(Kill, String)> {
    pymodbus_tcp_units(&unit.to_string())
}

/// [`pymodbus_tcp_server`] serving the unit ids `units` ("1,2"), each with its own
/// registers.
pub fn pymodbus_tcp_units(units: &str) -> Option<(Kill, String)> {
    if !need(Peer::Pymodbus) {
        return None;
    }
    let port = free_port().to_string();
    let server = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/tests/interop/pymodbus_tcp_server.py"
    );
    let guard = Kill::spawn(
        Command::new(python())
            .args([server, &port, "--unit", units])
            .stderr(Stdio::null()),
    );
    let addr = format!("127.0.0.1:{port}");
    wait_listening(&addr, Duration::from_secs(30));
    Some((guard, addr))
}

/// A running `conformance simulate --tcp 127.0.0.1:0 --framing mbap`, killed on drop; its
/// log is printed when the test fails.
pub struct GatewaySim {
    _child: Kill,
    pub addr: String,
    log: super::Lines,
}

impl GatewaySim {
    /// The simulated `model` at node `address` behind the gateway, with `extra` options
    /// of `simulate`; returns once its banner names the address it listens on.
    pub fn start(model: &str, address: u8, extra: &[&str]) -> GatewaySim {
        let mut child = Kill::spawn(
            Command::new(bin())
                .args(["simulate", "--model", model, "-a", &address.to_string()])
                .args(["--tcp", "127.0.0.1:0", "--framing", "mbap"])
                .args(extra)
                .stdin(Stdio::null())
                .stdout(Stdio::null())
                .stderr(Stdio::piped()),
        );
        let log = super::Lines::read(child.0.stderr.take().unwrap());
        let t0 = Instant::now();
        let addr = loop {
            let left = Duration::from_secs(10).saturating_sub(t0.elapsed());
            let line = log
                .next_line(left)
                .unwrap_or_else(|| panic!("no banner from the simulator: {:#?}", log.all()));
            if let Some(at) = line.find(" on tcp ") {
                let rest = &line[at + 8..];
                break rest[..rest.find(';').unwrap_or(rest.len())].to_string();
            }
        };
        GatewaySim {
            _child: child,
            addr,
            log,
        }
    }

    /// The port it listens on.
    pub fn port(&self) -> &str {
        self.addr.rsplit(':').next().unwrap()
    }
}

impl Drop for GatewaySim {
    fn drop(&mut self) {
        if std::thread::panicking() {
            let log: String = self.log.all().iter().map(|l| format!("{l}\n")).collect();
            note(&format!("--- simulator log ---\n{log}--- end ---"));
        }
    }
}

/// tests/libmodbus/NAME.c (a small libmodbus program) built into `dir`; `None` (after
/// SKIPPED) when libmodbus or a C compiler is missing.
pub fn libmodbus_program(dir: &Path, name: &str) -> Option<PathBuf> {
    if !need(Peer::Libmodbus) {
        return None;
    }
    let flags = Command::new("pkg-config")
        .args(["--cflags", "--libs", "libmodbus"])
        .output()
        .unwrap();
    assert!(flags.status.success());
    let flags = String::from_utf8(flags.stdout).unwrap();
    let exe = dir.join(format!("libmodbus-{name}"));
    let out = Command::new(super::cc())
        .args(["-Wall", "-Wextra", "-Werror", "-O2", "-o"])
        .arg(&exe)
        .arg(format!(
            "{}/tests/libmodbus/{name}.c",
            env!("CARGO_MANIFEST_DIR")
        ))
        .args(flags.split_whitespace())
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "cc {name}.c failed:\n{}",
        String::from_utf8_lossy(&out.stderr)
    );
    Some(exe)
}

/// libmodbus's RTU server (tests/libmodbus/server.c) built into `dir` and started with
/// `args` (ADDRESS [START COUNT]) on one end of a [`PtyPair`]: the guards and the
/// runner's end; None (after SKIPPED) when libmodbus or a C compiler is missing.
pub fn libmodbus_server(dir: &Path, args: &[&str]) -> Option<SerialPeer> {
    let exe = libmodbus_program(dir, "server")?;
    let (line, a, b) = pty_pair(dir);
    let mut server = Kill::spawn(
        Command::new(&exe)
            .arg(&a)
            .args(args)
            .stdout(Stdio::piped())
            .stderr(Stdio::null()),
    );
    // The server prints "ready" once the port is open, and nothing else on stdout.
    let stdout = server.0.stdout.take().unwrap();
    let (tx, rx) = mpsc::channel();
    std::thread::spawn(move || {
        let mut lines = BufReader::new(stdout).lines();
        let _ = tx.send(lines.next().and_then(Result::ok));
        assert!(lines.next().is_none(), "the server wrote more than 'ready'");
    });
    let ready = rx.recv_timeout(Duration::from_secs(10));
    assert_eq!(
        ready,
        Ok(Some("ready".to_string())),
        "the server did not start"
    );
    Some(SerialPeer {
        device: server,
        line,
        port: b,
    })
}

/// tshark's `-o` option: the user DLT table entry that maps link type 147 (RTU frames in
/// this suite's captures) to Wireshark's Modbus RTU dissector.
pub const TSHARK_USER_DLT: &str = r#"uat:user_dlts:"User 0 (DLT=147)","mbrtu","0","","0","""#;
