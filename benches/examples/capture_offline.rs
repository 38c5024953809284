//! Offline speed: `monitor --capture-in` (read and judge a capture) against tshark's
//! decode of the same file, both timed in the same run.
//!
//! Writes a pcapng capture of N frames (default 1,000,000: half requests, half replies,
//! node 1 of an F510 at 9600 8E1, reads of the state signal and parameters and writes of
//! the frequency command, each answered after 10 ms, 50 ms between exchanges), then times:
//!
//! - ours: reading the file and judging every exchange through the monitor, in process
//!   (what `monitor --capture-in` does, without the report);
//! - tshark: `tshark -r FILE -o <user DLT 147 = mbrtu>` with its summary lines to
//!   /dev/null (a decode of every frame, no judging), when tshark is on the PATH.
//!
//! ```sh
//! cargo run --release -p conformance-benches --example capture_offline            # 1M frames
//! cargo run --release -p conformance-benches --example capture_offline -- 200000  # fewer
//! ```
//!
//! With `CAPTURE_OFFLINE_KEEP=1` in the environment the capture is kept (its path is
//! printed), to time the CLI on the same file:
//! `conformance monitor --capture-in FILE --model f510 -a 1 --quiet -o /dev/null`.
use std::io::BufWriter;
use std::path::Path;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use conformance::capture::{Direction, Interface, PacketMeta, PcapngWriter, LINKTYPE_USER0};
use conformance::codec::pdu::{Message, Pdu, Registers};
use conformance::codec::timing::{LineSettings, Parity};
use conformance::codec::Mode;
use conformance::model::DriveModel;
use conformance::monitor::{replay, Monitor, MonitorConfig};

const USER_DLT: &str = r#"uat:user_dlts:"User 0 (DLT=147)","mbrtu","0","","0","""#;

fn rtu(pdu: Pdu<'_>) -> Vec<u8> {
    Message { address: 1, pdu }.to_frame_vec(Mode::Rtu).unwrap()
}

/// The exchanges the generated bus repeats: (request, reply).
fn exchanges() -> Vec<(Vec<u8>, Vec<u8>)> {
    let read = |start: u16, values: &[u16]| {
        let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
        (
            rtu(Pdu::ReadRequest {
                start,
                count: values.len() as u16,
            }),
            rtu(Pdu::ReadResponse {
                values: Registers::new(&bytes).unwrap(),
            }),
        )
    };
    let write = rtu(Pdu::WriteSingle {
        register: 0x2502,
        value: 0x1194,
    });
    vec![
        read(0x2520, &[0x0000]),
        (write.clone(), write),
        read(0x2502, &[0x1194]),
        read(0x2520, &[0x0000]),
    ]
}

/// Writes the capture of `frames` frames to `path`.
fn generate(path: &Path, frames: u64, line: LineSettings) {
    let file = std::fs::File::create(path).unwrap();
    let mut w = PcapngWriter::new(BufWriter::new(file), "capture_offline bench").unwrap();
    w.add_interface(&Interface {
        link_type: LINKTYPE_USER0,
        name: "generated".into(),
        description: format!("rtu {line}, generated"),
    })
    .unwrap();
    let ex = exchanges();
    let char_us = line.char_time_us();
    let mut t = 1_700_000_000_000_000u64;
    for i in 0..frames / 2 {
        let (req, rep) = &ex[i as usize % ex.len()];
        for (bytes, dir) in [(req, Direction::Outbound), (rep, Direction::Inbound)] {
            let meta = PacketMeta {
                timestamp_us: t,
                flags: dir.flag(),
                ..PacketMeta::default()
            };
            w.write_packet(&meta, bytes).unwrap();
            // The frame on the line, then 10 ms (the reply) or 50 ms (the next request).
            t += char_us * bytes.len() as u64
                + if dir == Direction::Outbound {
                    10_000
                } else {
                    50_000
                };
        }
    }
}

fn per_s(n: u64, d: Duration) -> f64 {
    n as f64 / d.as_secs_f64()
}

fn main() {
    let frames: u64 = std::env::args()
        .nth(1)
        .map(|a| a.parse().expect("a number of frames"))
        .unwrap_or(1_000_000);
    let line = LineSettings::new(9600, 8, Parity::Even, 1);
    let dir = std::env::temp_dir().join(format!("capture-offline-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("bus.pcapng");
    let t0 = Instant::now();
    generate(&path, frames, line);
    let size = std::fs::metadata(&path).unwrap().len();
    println!(
        "generated {frames} frames, {:.1} MB, in {:.2} s: {}",
        size as f64 / 1e6,
        t0.elapsed().as_secs_f64(),
        path.display()
    );

    // Ours: read the file and judge every exchange.
    let t0 = Instant::now();
    let file = std::fs::File::open(&path).unwrap();
    let mut mon = Monitor::new(
        DriveModel::builtin("f510").unwrap(),
        MonitorConfig::new(Mode::Rtu, line, vec![1]),
    )
    .unwrap();
    // As `monitor --capture-in --quiet` without --log: no live lines to make.
    mon.set_live(false);
    // Read a part at a time, as `monitor --capture-in` does.
    let r = replay::replay_from(file, &mut mon, |_| {}).unwrap();
    let ours = t0.elapsed();
    assert_eq!(r.packets, frames);
    let node = &mon.nodes()[&1];
    assert_eq!(node.requests, frames / 2);
    let lines = node.exchanges;
    println!(
        "ours:   {} frames read and judged in {:.3} s: {:.0} frames/s ({} exchanges, {} deviations)",
        r.packets,
        ours.as_secs_f64(),
        per_s(r.packets, ours),
        lines,
        mon.deviations()
    );

    // tshark: decode only.
    let have_tshark = Command::new("tshark")
        .arg("--version")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    if have_tshark {
        let t0 = Instant::now();
        let status = Command::new("tshark")
            .arg("-r")
            .arg(&path)
            .args(["-o", USER_DLT])
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .status()
            .unwrap();
        let theirs = t0.elapsed();
        assert!(status.success());
        println!(
            "tshark: {frames} frames decoded in {:.3} s: {:.0} frames/s",
            theirs.as_secs_f64(),
            per_s(frames, theirs)
        );
        println!(
            "ours / tshark: {:.1}x",
            theirs.as_secs_f64() / ours.as_secs_f64()
        );
    } else {
        println!("tshark: not on the PATH (Debian package tshark); not measured");
    }
    if std::env::var_os("CAPTURE_OFFLINE_KEEP").is_some() {
        // To time the CLI on the same file: `conformance monitor --capture-in FILE ...`.
        println!("kept: {}", path.display());
    } else {
        let _ = std::fs::remove_dir_all(&dir);
    }
}
