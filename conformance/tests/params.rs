//! `conformance params` against a device in another process: the simulator on a
//! pseudo-terminal (`simulate --pty --log`, whose log shows every frame the device
//! received), and pymodbus's serial server described by a model file. The round trip in
//! RTU and ASCII (backup, three changes by `send`, a diff that names exactly those three,
//! a restore that writes exactly three frames each read back, a second backup equal to
//! the first), a dry run and a refused confirmation that write nothing, a restore stopped
//! by an exception with what the audit log and the journal then say, and a SIGTERM in
//! the middle of a restore that leaves the audit log whole and the device undone.

mod common;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Duration;

use common::{bin, line, run_bounded, sim_pty, Kill, Scratch};
use conformance::codec::hex::{parse_hex, Hex};
use conformance::codec::pdu::{Message, Pdu};
use conformance::codec::Mode;
use conformance::judge::body_of;
use conformance::params::Backup;

const LIMIT: Duration = Duration::from_secs(120);

fn mode_of(mode: &str) -> Mode {
    match mode {
        "ascii" => Mode::Ascii,
        _ => Mode::Rtu,
    }
}

/// `conformance ARGS` (bounded): exit code, stdout, stderr.
fn conformance(args: &[&str]) -> (Option<i32>, String, String) {
    run_bounded(args, LIMIT)
}

/// A device the runner reaches through `link` (the model or description it reads, the
/// port, the line and the mode), killed with its guard.
struct Device {
    _guard: Option<Kill>,
    link: Vec<String>,
}

impl Device {
    /// The simulator started with `sim` (the words of each part, as [`line`] takes them),
    /// reached in RTU with `model` (the words of the model or description options).
    fn sim(sim: &[&str], model: &[&str]) -> Device {
        let (guard, port) = sim_pty(&line(sim));
        Device::reached(
            Some(guard),
            &[&line(model)[..], &["--port", &port, "--mode", "rtu"]].concat(),
        )
    }

    /// A device (under `guard`, where this test started it) reached through `link`,
    /// which names the mode.
    fn reached(guard: Option<Kill>, link: &[&str]) -> Device {
        assert!(link.contains(&"--mode"), "{link:?}");
        Device {
            _guard: guard,
            link: link.iter().map(|w| w.to_string()).collect(),
        }
    }

    /// The mode the link names.
    fn mode(&self) -> &str {
        let at = self.link.iter().position(|w| w == "--mode").unwrap();
        &self.link[at + 1]
    }

    /// The F510 simulator in RTU, logging every frame to `log`.
    fn f510_logged(log: &Path) -> Device {
        Device::sim(
            &["--model f510 --log", log.to_str().unwrap()],
            &["--model f510"],
        )
    }

    /// `first` followed by the link options.
    fn args<'a>(&'a self, first: &[&'a str]) -> Vec<&'a str> {
        first
            .iter()
            .copied()
            .chain(self.link.iter().map(String::as_str))
            .collect()
    }

    /// `conformance FIRST LINK` (bounded): exit code, stdout, stderr.
    fn run(&self, first: &[&str]) -> (Option<i32>, String, String) {
        conformance(&self.args(first))
    }

    /// `params backup -o to`, which must exit 0: its stdout and stderr.
    fn backup(&self, to: &Path) -> (String, String) {
        let (code, out, err) = self.run(&["params", "backup", "-o", to.to_str().unwrap()]);
        assert_eq!(code, Some(0), "{out}{err}");
        (out, err)
    }

    /// `params restore BACKUP EXTRA`, which must exit `code`: its stdout and stderr.
    fn restore(&self, backup: &Path, extra: &[&str], code: i32) -> (String, String) {
        let args = [&["params", "restore", backup.to_str().unwrap()], extra].concat();
        let (exit, out, err) = self.run(&args);
        assert_eq!(exit, Some(code), "{out}{err}");
        (out, err)
    }

    /// `send` of the 06H frame writing `value` to `register`, which must exit 0.
    fn write(&self, register: u16, value: u16) {
        let frame = write_frame(mode_of(self.mode()), register, value);
        let (code, out, err) = self.run(&["send", &frame]);
        assert_eq!(code, Some(0), "send {register:04X}: {out}{err}");
    }
}

/// The F510 simulator in a fresh scratch folder `name`, logging to `sim.jsonl` there, and
/// backed up to `a.toml` there: the folder, the log, the device and the backup.
fn backed_up(name: &str) -> (Scratch, PathBuf, Device, PathBuf) {
    let d = Scratch::new(name);
    let (log, a) = (d.join("sim.jsonl"), d.join("a.toml"));
    let dev = Device::f510_logged(&log);
    dev.backup(&a);
    (d, log, dev, a)
}

/// The frames the simulator received, in order, as their bodies (address, function,
/// data), from its JSON log.
fn received(log: &Path, mode: Mode) -> Vec<Vec<u8>> {
    std::fs::read_to_string(log)
        .unwrap()
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .filter(|r| r["dir"] == "in" && r["event"] == "frame")
        .filter_map(|r| body_of(mode, &parse_hex(r["hex"].as_str()?).ok()?))
        .collect()
}

/// The write frames (06H, 10H) among `frames`: (first register, values).
fn writes(frames: &[Vec<u8>]) -> Vec<(u16, Vec<u16>)> {
    frames
        .iter()
        .filter_map(|b| match b.get(1) {
            Some(0x06) => Some((
                u16::from_be_bytes([b[2], b[3]]),
                vec![u16::from_be_bytes([b[4], b[5]])],
            )),
            Some(0x10) => Some((
                u16::from_be_bytes([b[2], b[3]]),
                b[7..]
                    .chunks(2)
                    .map(|c| u16::from_be_bytes([c[0], c[1]]))
                    .collect(),
            )),
            _ => None,
        })
        .collect()
}

/// [`writes`], where a write sent again at once (the runner sends a request again when
/// this host delayed its reply past the timeout on a pseudo-terminal) counts once: the
/// same frame twice is the same write, and the device holds the same value.
fn distinct_writes(frames: &[Vec<u8>]) -> Vec<(u16, Vec<u16>)> {
    let mut w = writes(frames);
    let all = w.len();
    w.dedup();
    if w.len() < all {
        common::note(&format!(
            "note: {} write(s) were sent again (the host delayed a reply)",
            all - w.len()
        ));
    }
    w
}

/// Whether a 03H read covering `register` comes after the frame at `i` and before the
/// next write.
fn read_back_after(frames: &[Vec<u8>], i: usize, register: u16) -> bool {
    frames[i + 1..]
        .iter()
        .take_while(|b| !matches!(b.get(1), Some(0x06 | 0x10)))
        .any(|b| {
            b.get(1) == Some(&0x03) && {
                let start = u16::from_be_bytes([b[2], b[3]]);
                let count = u16::from_be_bytes([b[4], b[5]]);
                (start..start + count).contains(&register)
            }
        })
}

/// The frame writing `value` to `register` at node 1, as `send` takes it (hex bytes).
fn write_frame(mode: Mode, register: u16, value: u16) -> String {
    let f = Message {
        address: 1,
        pdu: Pdu::WriteSingle { register, value },
    }
    .to_frame_vec(mode)
    .unwrap();
    Hex(&f).to_string()
}

fn backup_of(path: &Path) -> Backup {
    Backup::parse(&std::fs::read_to_string(path).unwrap()).unwrap()
}

/// The audit log's lines, each parsed (a line that does not parse fails the test).
fn audit_lines(path: &Path) -> Vec<serde_json::Value> {
    let text = std::fs::read_to_string(path).unwrap_or_default();
    assert!(
        text.is_empty() || text.ends_with('\n'),
        "a cut line: {text:?}"
    );
    text.lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l:?}")))
        .collect()
}

/// The three registers the round trip changes (apart, so three 06H writes) and the
/// values it gives them.
const CHANGES: [(u16, u16); 3] = [(0x0301, 5), (0x0410, 7), (0x0C20, 9)];

/// The round trip against `dev`; `log` is the device's frame log, where it has one.
fn round_trip(d: &Path, dev: &Device, log: Option<&Path>) {
    let mode = dev.mode();
    let m = mode_of(mode);
    let a = d.join("a.toml");
    dev.backup(&a);
    let before = backup_of(&a);
    assert_eq!(before.header.mode.as_deref(), Some(mode));
    for (r, v) in CHANGES {
        assert_ne!(before.values()[&r], v, "{r:04X} already holds {v}");
        dev.write(r, v);
    }
    let (code, out, err) = dev.run(&["params", "diff", a.to_str().unwrap(), "live"]);
    assert_eq!(code, Some(1), "{out}{err}");
    let named: Vec<&str> = out.lines().filter(|l| l.starts_with("differs:")).collect();
    assert_eq!(named.len(), 3, "{out}");
    for ((r, v), line) in CHANGES.iter().zip(&named) {
        assert!(
            line.contains(&format!("{r:04X}H")) && line.contains(&format!("B {v} ")),
            "{line}"
        );
    }
    assert!(!out.contains("only in"), "{out}");
    let seen = log.map_or(0, |l| received(l, m).len());
    let (out, _) = dev.restore(&a, &["--yes"], 0);
    assert!(out.contains("written and verified: 3 "), "{out}");
    let audit = audit_lines(&d.join("conformance-audit.jsonl"));
    assert_eq!(audit.len(), 3, "{audit:?}");
    for ((r, v), line) in CHANGES.iter().zip(&audit) {
        assert_eq!(line["register"], format!("{r:04X}"));
        assert_eq!(
            (line["old"].as_u64(), line["verified"].as_bool()),
            (Some(u64::from(*v)), Some(true))
        );
        assert_eq!(
            line["request"], line["reply"],
            "06H is answered by its echo"
        );
    }
    if let Some(log) = log {
        let frames = received(log, m)[seen..].to_vec();
        let w = distinct_writes(&frames);
        let want: Vec<(u16, Vec<u16>)> = CHANGES
            .iter()
            .map(|(r, _)| (*r, vec![before.values()[r]]))
            .collect();
        assert_eq!(w, want, "exactly three writes, of the backup's values");
        for (i, b) in frames.iter().enumerate() {
            if matches!(b.get(1), Some(0x06 | 0x10)) {
                let r = u16::from_be_bytes([b[2], b[3]]);
                assert!(read_back_after(&frames, i, r), "{r:04X}H is not read back");
            }
        }
    }
    let b = d.join("b.toml");
    dev.backup(&b);
    let after = backup_of(&b);
    assert_eq!(after.values(), before.values());
    assert_eq!(
        (
            after.header.model,
            after.header.node,
            after.header.identification
        ),
        (
            before.header.model,
            before.header.node,
            before.header.identification
        )
    );
}

fn sim_round_trip(mode: &str) {
    let d = Scratch::new(&format!("round-{mode}"));
    let log = d.join("sim.jsonl");
    let (sim, port) = sim_pty(&line(&[
        "--model f510 -m",
        mode,
        "--log",
        log.to_str().unwrap(),
    ]));
    let dev = Device::reached(
        Some(sim),
        &line(&["--model f510 --port", &port, "--mode", mode]),
    );
    round_trip(&d, &dev, Some(&log));
}

#[test]
fn the_round_trip_in_rtu_restores_exactly_the_three_changed_parameters() {
    sim_round_trip("rtu");
}

#[test]
fn the_round_trip_in_ascii_restores_exactly_the_three_changed_parameters() {
    sim_round_trip("ascii");
}

#[test]
fn a_dry_run_and_a_restore_without_yes_off_a_terminal_write_nothing() {
    let (d, log, dev, a) = backed_up("dry");
    dev.write(0x0301, 5);
    let seen = received(&log, Mode::Rtu).len();
    let (out, _) = dev.restore(&a, &["--dry-run"], 0);
    assert!(
        out.contains("plan: 1 writes") && out.contains("01 06 03 01 00 00 D8 4E"),
        "{out}"
    );
    assert!(out.contains("dry run: nothing written"), "{out}");
    // stdin is not a terminal here: no --yes, no writes.
    let (_, err) = dev.restore(&a, &[], 2);
    assert!(err.contains("refusing to write without --yes"), "{err}");
    let frames = received(&log, Mode::Rtu)[seen..].to_vec();
    assert!(!frames.is_empty(), "the restores read the device");
    assert_eq!(writes(&frames), vec![], "nothing written");
    assert!(!d.join("conformance-audit.jsonl").exists());
}

#[test]
fn a_line_for_a_read_only_or_command_register_is_refused_naming_the_line() {
    let d = Scratch::new("refuse");
    for (line, says) in [
        (
            "0C10 = 5",
            "0C10H (group 12) is read-only in the f510 model",
        ),
        ("2501 = 1", "2501H (Operation signal) is command"),
    ] {
        let f = d.join("x.toml");
        std::fs::write(
            &f,
            format!("[device]\nmodel = \"f510\"\nnode = 1\n\n[\"group 3\"]\n0301 = 0\n{line}\n"),
        )
        .unwrap();
        let (code, out, err) = conformance(&common::line(&[
            "params restore",
            f.to_str().unwrap(),
            "--sim f510 --mode rtu --yes",
        ]));
        assert_eq!(code, Some(2), "{out}{err}");
        assert!(err.contains(&format!("line 7: {line}: {says}")), "{err}");
        assert!(!out.contains("plan:"), "{out}");
    }
}

/// `acme-x100.json` (the guide's example description) with its settings block cut
/// around `0012H`, which becomes `access` (read-only: the device that refuses a write
/// its description, the unchanged file, allows; write-only: one that refuses a read).
/// Its simulator answers after 5 ms (`--delay 5`), not the description's 50 ms, so that
/// a backup of its 4112 registers takes seconds, not half a minute.
fn refusing_description(d: &Path, access: &str) -> (PathBuf, PathBuf) {
    let src = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../vectors/models/examples/acme-x100.json"
    );
    let text = std::fs::read_to_string(src).unwrap();
    let mut v: serde_json::Value = serde_json::from_str(&text).unwrap();
    let blocks = v["blocks"].as_array_mut().unwrap();
    let settings = blocks.remove(0);
    let part = |first: &str, last: &str, access: &str| {
        let mut b = settings.clone();
        b["first"] = first.into();
        b["last"] = last.into();
        b["access"] = access.into();
        b
    };
    blocks.insert(0, part("0013", "0FFF", "read-write"));
    blocks.insert(0, part("0012", "0012", access));
    blocks.insert(0, part("0000", "0011", "read-write"));
    let device = d.join(format!("device-{access}.json"));
    std::fs::write(&device, serde_json::to_string_pretty(&v).unwrap()).unwrap();
    (PathBuf::from(src), device)
}

#[test]
fn an_exception_mid_restore_stops_it_and_the_audit_log_and_journal_say_what_was_written() {
    let d = Scratch::new("exception");
    let (described, device) = refusing_description(&d, "read-only");
    let log = d.join("sim.jsonl");
    let dev = Device::sim(
        &[
            "--delay 5 --model-file",
            device.to_str().unwrap(),
            "--log",
            log.to_str().unwrap(),
        ],
        &["--model-file", described.to_str().unwrap()],
    );
    let a = d.join("a.toml");
    dev.backup(&a);
    // Three values to restore, the middle one to the register the device refuses.
    let text = std::fs::read_to_string(&a)
        .unwrap()
        .replace("\n0010 = 0 ", "\n0010 = 11")
        .replace("\n0012 = 0 ", "\n0012 = 12")
        .replace("\n0014 = 0 ", "\n0014 = 13");
    std::fs::write(&a, text).unwrap();
    let seen = received(&log, Mode::Rtu).len();
    let (out, _) = dev.restore(&a, &["--yes"], 1);
    common::assert_contains_all(
        &out,
        &[
            "plan: 3 writes",
            "REFUSED: exception 02H",
            "written and verified: 1 (0010H)",
            "not written: 2 (0012H 0014H)",
            "journal: node 01 0010H was 0000H: written",
            "journal: node 01 0012H was 0000H: refused, unchanged",
        ],
    );
    assert!(!out.contains("journal: node 01 0014H"), "{out}");
    assert!(out.contains("to resume"), "{out}");
    let audit = audit_lines(&d.join("conformance-audit.jsonl"));
    let said: Vec<(String, bool)> = audit
        .iter()
        .map(|l| {
            (
                l["register"].as_str().unwrap().to_string(),
                l["verified"].as_bool().unwrap(),
            )
        })
        .collect();
    assert_eq!(said, vec![("0010".into(), true), ("0012".into(), false)]);
    assert!(
        audit[1]["reply"].as_str().unwrap().starts_with("01 86 02"),
        "{:?}",
        audit[1]
    );
    let frames = received(&log, Mode::Rtu)[seen..].to_vec();
    assert_eq!(
        distinct_writes(&frames),
        vec![(0x0010, vec![11]), (0x0012, vec![12])]
    );
}

/// Starts `conformance ARGS` with its output to files in `d`.
fn spawn(d: &Path, args: &[&str]) -> Kill {
    Kill::spawn(
        std::process::Command::new(bin())
            .args(args)
            .stdin(std::process::Stdio::null())
            .stdout(std::fs::File::create(d.join("stdout")).unwrap())
            .stderr(std::fs::File::create(d.join("stderr")).unwrap()),
    )
}

#[test]
fn sigterm_during_a_restore_leaves_the_audit_log_whole_and_undoes_what_was_written() {
    let d = Scratch::new("sigterm");
    let dev = Device::sim(&["--model f510"], &["--model f510"]);
    let a = d.join("a.toml");
    dev.backup(&a);
    let before = backup_of(&a);
    // Every other parameter changed: hundreds of single writes, far more than go out
    // before the signal.
    let mut text = String::new();
    let mut n = 0;
    for l in std::fs::read_to_string(&a).unwrap().lines() {
        match l.split_once(" = 0 ") {
            Some((r, rest)) if r.len() == 4 && !r.starts_with('#') => {
                n += 1;
                let v = if n % 2 == 0 { "1" } else { "0" };
                text.push_str(&format!("{r} = {v} {rest}\n"));
            }
            _ => {
                text.push_str(l);
                text.push('\n');
            }
        }
    }
    let target = d.join("target.toml");
    std::fs::write(&target, text).unwrap();
    let audit = d.join("audit.jsonl");
    let mut child = spawn(
        &d,
        &dev.args(&[
            "params",
            "restore",
            target.to_str().unwrap(),
            "--yes",
            "--audit",
            audit.to_str().unwrap(),
        ]),
    );
    let t0 = std::time::Instant::now();
    while audit_lines(&audit).len() < 2 {
        assert!(t0.elapsed() < LIMIT, "no audit lines");
        assert!(
            child.0.try_wait().unwrap().is_none(),
            "the restore ended before the signal"
        );
        std::thread::sleep(Duration::from_millis(5));
    }
    nix::sys::signal::kill(
        nix::unistd::Pid::from_raw(child.0.id() as i32),
        nix::sys::signal::Signal::SIGTERM,
    )
    .unwrap();
    let status = child.wait_within(LIMIT, "the interrupted restore");
    let out = std::fs::read_to_string(d.join("stdout")).unwrap();
    assert_eq!(status.code(), Some(2), "{out}");
    assert!(
        out.contains("interrupted: what this restore wrote is undone"),
        "{out}"
    );
    let lines = audit_lines(&audit);
    let written: Vec<&serde_json::Value> = lines.iter().filter(|l| l["undo"] == false).collect();
    let undone: Vec<&serde_json::Value> = lines.iter().filter(|l| l["undo"] == true).collect();
    assert!(
        written.len() >= 2 && written.len() < n / 2,
        "{} written",
        written.len()
    );
    // Each register written is put back, newest first, by the runner's restore.
    let mut back: Vec<&str> = undone
        .iter()
        .map(|l| l["register"].as_str().unwrap())
        .collect();
    back.reverse();
    let wrote: Vec<&str> = written
        .iter()
        .map(|l| l["register"].as_str().unwrap())
        .collect();
    assert_eq!(back, wrote);
    assert!(
        undone
            .iter()
            .all(|l| l["verified"] == true && l["new"] == 0),
        "{undone:?}"
    );
    let b = d.join("b.toml");
    dev.backup(&b);
    assert_eq!(
        backup_of(&b).values(),
        before.values(),
        "the device is as before"
    );
}

#[test]
fn the_round_trip_against_pymodbus_described_by_a_model_file() {
    let d = Scratch::new("pymodbus");
    let Some(peer) = common::pymodbus_serial_blocks(&d, "rtu", "0000-0FFF,2500-252F") else {
        return;
    };
    let model = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../vectors/models/examples/pymodbus-server.json"
    );
    let port = peer.port.to_str().unwrap();
    let dev = Device::reached(
        None,
        &[
            "--model-file",
            model,
            "--port",
            port,
            "-P",
            "none",
            "--mode",
            "rtu",
        ],
    );
    round_trip(&d, &dev, None);
    let a = backup_of(&d.join("a.toml"));
    let v: BTreeMap<u16, u16> = a.values();
    assert_eq!(v.len(), 0x1000 + 0x30, "both blocks, every register");
    // Consecutive changes: one 10H write, which pymodbus confirms and holds.
    for (r, v) in [(0x0801, 1), (0x0802, 2), (0x0803, 3)] {
        dev.write(r, v);
    }
    let audit = d.join("fc10.jsonl");
    let file = d.join("a.toml");
    let (code, out, err) = dev.run(&[
        "params",
        "restore",
        file.to_str().unwrap(),
        "--yes",
        "--audit",
        audit.to_str().unwrap(),
    ]);
    assert_eq!(code, Some(0), "{out}{err}");
    let lines = audit_lines(&audit);
    assert_eq!(lines.len(), 3, "{lines:?}");
    assert!(
        lines
            .iter()
            .all(|l| l["function"] == "10" && l["verified"] == true),
        "{lines:?}"
    );
    assert!(
        lines[0]["reply"]
            .as_str()
            .unwrap()
            .starts_with("01 10 08 01 00 03"),
        "{lines:?}"
    );
}

#[test]
fn consecutive_changes_are_restored_by_one_10h_write_and_read_back() {
    let (d, log, dev, a) = backed_up("fc10");
    for (r, v) in [(0x0301, 1), (0x0302, 2), (0x0303, 3)] {
        dev.write(r, v);
    }
    let seen = received(&log, Mode::Rtu).len();
    let (out, _) = dev.restore(&a, &["--yes"], 0);
    common::assert_contains_all(
        &out,
        &[
            "plan: 1 writes",
            "write 10H 0301H (3-01) 1 -> 0, 0302H (3-02) 2 -> 0, 0303H (3-03) 3 -> 0",
        ],
    );
    let frames = received(&log, Mode::Rtu)[seen..].to_vec();
    assert_eq!(distinct_writes(&frames), vec![(0x0301, vec![0, 0, 0])]);
    let i = frames.iter().position(|b| b[1] == 0x10).unwrap();
    assert!((0x0301..=0x0303).all(|r| read_back_after(&frames, i, r)));
    let audit = audit_lines(&d.join("conformance-audit.jsonl"));
    assert_eq!(audit.len(), 3, "one line per register");
    assert!(audit
        .iter()
        .all(|l| l["function"] == "10" && l["request"] == audit[0]["request"]));
    // The 10H reply echoes start and count: 01 10 03 01 00 03 and its CRC.
    assert!(
        audit[0]["reply"]
            .as_str()
            .unwrap()
            .starts_with("01 10 03 01 00 03"),
        "{:?}",
        audit[0]
    );
}

#[test]
fn on_a_terminal_a_restore_asks_once_and_writes_only_after_yes() {
    if !common::tool_or_skip(
        common::runs("script", &["--version"]),
        "script (util-linux), to give the restore a terminal",
    ) {
        return;
    }
    let (_d, log, dev, a) = backed_up("ask");
    let link = dev.link.join(" ");
    let text = std::fs::read_to_string(&a)
        .unwrap()
        .replace("\n0301 = 0 ", "\n0301 = 3 ");
    std::fs::write(&a, text).unwrap();
    // script(1) runs the restore on a pseudo-terminal of its own and types our answer.
    let ask = |answer: &str| {
        let cmd = format!("{} params restore {} {link}", bin(), a.display());
        let mut child = Kill::spawn(
            std::process::Command::new("script")
                .args(["-qec", &cmd, "/dev/null"])
                .stdin(std::process::Stdio::piped())
                .stdout(std::process::Stdio::piped())
                .stderr(std::process::Stdio::null()),
        );
        use std::io::{Read, Write};
        child
            .0
            .stdin
            .take()
            .unwrap()
            .write_all(answer.as_bytes())
            .unwrap();
        let status = child.wait_within(LIMIT, "the restore on a terminal");
        let mut out = String::new();
        child
            .0
            .stdout
            .take()
            .unwrap()
            .read_to_string(&mut out)
            .unwrap();
        (status.code(), out)
    };
    let (code, out) = ask("n\n");
    assert_eq!(code, Some(2), "{out}");
    assert_eq!(out.matches("[y/N]").count(), 1, "asked once: {out}");
    assert!(out.contains("not confirmed: nothing written"), "{out}");
    assert_eq!(writes(&received(&log, Mode::Rtu)), vec![]);
    let (code, out) = ask("y\n");
    assert_eq!(code, Some(0), "{out}");
    assert_eq!(
        distinct_writes(&received(&log, Mode::Rtu)),
        vec![(0x0301, vec![3])]
    );
}

#[test]
fn a_register_the_device_refuses_to_read_is_a_comment_of_the_backup_and_stops_no_other() {
    let d = Scratch::new("unread");
    let (described, device) = refusing_description(&d, "write-only");
    let dev = Device::sim(
        &["--delay 5 --model-file", device.to_str().unwrap()],
        &["--model-file", described.to_str().unwrap()],
    );
    let a = d.join("a.toml");
    let (out, err) = dev.backup(&a);
    assert!(
        out.contains("1 refused by the device, as comments"),
        "{out}"
    );
    assert!(
        err.contains("note: 0012H (settings) not read: reading 1 from 0012H"),
        "{err}"
    );
    let text = std::fs::read_to_string(&a).unwrap();
    assert!(
        text.contains("\n# 0012 not read: reading 1 from 0012H"),
        "{text}"
    );
    let b = backup_of(&a);
    assert!(!b.values().contains_key(&0x0012));
    assert!(b.values().contains_key(&0x0011) && b.values().contains_key(&0x0013));
    // The live side lacks it: a diff says so (a firmware that stopped serving one).
    std::fs::write(
        &a,
        text.replace("\n# 0012 not read", "\n0012 = 0 # not read"),
    )
    .unwrap();
    let (code, out, err) = dev.run(&["params", "diff", a.to_str().unwrap(), "live"]);
    assert_eq!(code, Some(1), "{out}{err}");
    assert!(out.contains("only in A: 0012H (settings)"), "{out}");
    // A restore cannot plan a register it cannot read: it refuses, naming the line.
    let (_, err) = dev.restore(&a, &["--yes"], 2);
    assert!(err.contains("the device refuses to read 0012H"), "{err}");
}
