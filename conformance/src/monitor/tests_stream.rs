//! A capture read a part at a time ([`replay_from`](super::replay::replay_from)) against
//! the same capture read whole ([`replay`]): the same packets, verdicts and faults, for
//! parts of every size, files cut anywhere and damaged length fields.

use std::time::Duration;

use super::replay::{guess_mode, guess_mode_chunked, replay, replay_chunked};
use super::tests::{everything, varied_traffic};
use super::*;
use crate::capture::{Direction as CapDirection, Interface, PacketMeta, PcapngWriter};
use crate::codec::timing::Parity;

fn line() -> LineSettings {
    LineSettings::new(9600, 8, Parity::Even, 1)
}

fn monitor_on(line: LineSettings) -> Monitor {
    Monitor::new(
        crate::model::DriveModel::builtin("f510").unwrap(),
        MonitorConfig {
            gap_allowance: Duration::from_millis(5),
            ..MonitorConfig::new(Mode::Rtu, line, vec![1])
        },
    )
    .unwrap()
}

/// The varied traffic as a pcapng capture: two sections, two interfaces in the second,
/// directions, a comment, and a Simple Packet Block.
fn pcapng(cycles: u64) -> Vec<u8> {
    let traffic = varied_traffic(cycles);
    let half = traffic.len() / 2;
    let mut out = Vec::new();
    for (part, frames) in [&traffic[..half], &traffic[half..]].into_iter().enumerate() {
        let mut w = PcapngWriter::new(Vec::new(), "tests_stream").unwrap();
        for i in 0..=part {
            w.add_interface(&Interface {
                link_type: crate::capture::LINKTYPE_USER0,
                name: format!("if{i}"),
                description: "rtu".into(),
            })
            .unwrap();
        }
        for (k, (t, f)) in frames.iter().enumerate() {
            let meta = PacketMeta {
                interface: (k % (part + 1)) as u32,
                timestamp_us: 1_700_000_000_000_000 + t * 1000,
                flags: if k % 2 == 0 {
                    CapDirection::Outbound.flag()
                } else {
                    CapDirection::Inbound.flag()
                },
                comment: (k % 7 == 0).then(|| "a comment".to_string()),
            };
            w.write_packet(&meta, f).unwrap();
        }
        out.extend(w.into_inner());
    }
    // A Simple Packet Block (no time): a reply to nothing.
    let spb_data = [0x01, 0x03, 0x02, 0x00, 0x00, 0xB8, 0x44];
    let len = 16 + 8u32;
    out.extend_from_slice(&0x0000_0003u32.to_le_bytes());
    out.extend_from_slice(&len.to_le_bytes());
    out.extend_from_slice(&(spb_data.len() as u32).to_le_bytes());
    out.extend_from_slice(&spb_data);
    out.push(0);
    out.extend_from_slice(&len.to_le_bytes());
    out
}

/// The varied traffic as a classic pcap (big-endian, nanoseconds).
fn pcap(cycles: u64) -> Vec<u8> {
    let mut v = Vec::new();
    v.extend_from_slice(&0xA1B2_3C4Du32.to_be_bytes());
    v.extend_from_slice(&[0, 2, 0, 4]);
    for x in [0u32, 0, 65535, 147] {
        v.extend_from_slice(&x.to_be_bytes());
    }
    for (t, f) in varied_traffic(cycles) {
        let t_us = t * 1000;
        let sec = 1_700_000_000 + t_us / 1_000_000;
        let ns = t_us % 1_000_000 * 1000;
        for x in [sec, ns, f.len() as u64, f.len() as u64] {
            v.extend_from_slice(&(x as u32).to_be_bytes());
        }
        v.extend_from_slice(&f);
    }
    v
}

/// Everything a replay gives, read whole or `chunk` bytes at a time.
fn judged(data: &[u8], chunk: Option<usize>) -> String {
    let mut m = monitor_on(line());
    let mut lines = Vec::new();
    let r = match chunk {
        None => replay(data, &mut m, |l| lines.push(l.clone())),
        Some(c) => replay_chunked(data, c, &mut m, |l| lines.push(l.clone())),
    };
    match r {
        Ok(r) => format!("{r:?}\n{}", everything(&m, &lines)),
        Err(e) => format!("error {e:?}"),
    }
}

/// `data` read `chunk` bytes at a time, for each of `chunks`, is judged as `whole` (the
/// judgement of it read whole); `case` starts the message of a failure.
fn assert_judged_alike(data: &[u8], whole: &str, chunks: &[usize], case: &str) {
    for &chunk in chunks {
        let part = judged(data, Some(chunk));
        assert!(part == whole, "{case}chunk {chunk}:\n{part}\n---\n{whole}");
    }
}

#[test]
fn a_capture_read_a_part_at_a_time_is_judged_as_read_whole() {
    for data in [pcapng(3), pcap(3)] {
        let whole = judged(&data, None);
        assert!(whole.contains("stopped: None"), "{whole}");
        let chunks = [1, 2, 3, 5, 7, 13, 64, 100, 1000, 4096, 1 << 20];
        assert_judged_alike(&data, &whole, &chunks, "");
    }
}

/// Cut anywhere, or with a length field damaged: the same packets judged and the same
/// fault, at the same offset of the file.
#[test]
fn a_capture_cut_or_damaged_gives_the_same_fault_read_a_part_at_a_time() {
    for data in [pcapng(1), pcap(1)] {
        let mut faults = 0;
        for cut in (0..data.len()).step_by(3) {
            let d = &data[..cut];
            let whole = judged(d, None);
            faults += usize::from(whole.contains("stopped: Some") || whole.contains("error"));
            assert_judged_alike(d, &whole, &[1, 7, 64, 1000], &format!("cut {cut}, "));
        }
        assert!(faults > data.len() / 6, "{faults}");
        for at in (0..data.len()).step_by(5) {
            let mut d = data.clone();
            d[at] ^= 0x5A;
            let whole = judged(&d, None);
            assert_judged_alike(&d, &whole, &[3, 64, 1000], &format!("damaged at {at}, "));
        }
    }
}

#[test]
fn the_mode_is_guessed_alike_a_part_at_a_time() {
    for data in [pcapng(1), pcap(1)] {
        for cut in [0, 3, 10, 30, 100, 300, data.len()] {
            let d = &data[..cut.min(data.len())];
            let whole = format!("{:?}", guess_mode(d));
            for chunk in [1, 7, 1000] {
                assert_eq!(
                    format!("{:?}", guess_mode_chunked(d, chunk)),
                    whole,
                    "cut {cut}"
                );
            }
        }
    }
}
