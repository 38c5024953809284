//! The generator's own laws: the same seed gives the same bytes, every kind of fault is
//! planted, and the counts add up.

use super::*;
use crate::codec::timing::{LineSettings, Parity};
use crate::model::DriveModel;

fn cfg(seed: u64, secs: u64) -> DayConfig {
    DayConfig {
        span: Duration::from_secs(secs),
        line: LineSettings::new(115_200, 8, Parity::Even, 1),
        drives: 8,
        seed,
        start_unix_us: 1_767_225_600_000_000,
    }
}

fn day(seed: u64, secs: u64) -> (Truth, Vec<u8>) {
    generate(
        &cfg(seed, secs),
        DriveModel::builtin("f510").unwrap(),
        Vec::new(),
    )
    .unwrap()
}

#[test]
fn the_same_seed_gives_the_same_capture_and_another_seed_another() {
    let (a, fa) = day(7, 90);
    let (b, fb) = day(7, 90);
    let (_, fc) = day(8, 90);
    assert_eq!(fa, fb);
    assert_eq!(a.faults, b.faults);
    assert_ne!(fa, fc);
}

#[test]
fn every_kind_of_fault_is_planted_and_the_counts_add_up() {
    let (t, file) = day(1, 120);
    for kind in [
        FaultKind::Noise,
        FaultKind::Collision,
        FaultKind::SilentDrive,
        FaultKind::MasterRestart,
    ] {
        assert!(t.faults.iter().any(|f| f.kind == kind), "{kind:?} missing");
    }
    assert!(t.faults.windows(2).all(|w| w[0].at_s <= w[1].at_s));
    let silent = t
        .faults
        .iter()
        .find(|f| f.kind == FaultKind::SilentDrive)
        .unwrap();
    assert!(silent.unanswered > 0);
    let sum = |f: fn(&NodeTruth) -> u64| t.nodes.values().map(f).sum::<u64>();
    // Every packet is a request, a reply or a garbled reply.
    let collisions = t
        .faults
        .iter()
        .filter(|f| f.kind == FaultKind::Collision)
        .count() as u64;
    assert_eq!(
        t.packets,
        sum(|n| n.requests) + sum(|n| n.replies) + collisions
    );
    assert_eq!(sum(|n| n.requests), sum(|n| n.exchanges));
    // Each exception answers a read of a register not in the map; such a read may also
    // go unanswered (a silent drive, a collision).
    assert!(sum(|n| n.unmapped_reads) >= sum(|n| n.exceptions));
    assert!(t.heard_s >= 120.0 && t.heard_s < 125.0, "{}", t.heard_s);
    // The file holds the packets the truth counts, and their bytes.
    let mut packets = 0u64;
    let mut bytes = 0u64;
    for p in crate::capture::Reader::new(&file).unwrap() {
        let p = p.unwrap();
        packets += 1;
        bytes += p.data.len() as u64;
    }
    assert_eq!((packets, bytes), (t.packets, t.bytes));
}

#[test]
fn a_span_too_short_for_the_faults_is_refused() {
    let e = generate(
        &cfg(1, 30),
        DriveModel::builtin("f510").unwrap(),
        Vec::new(),
    )
    .unwrap_err();
    assert!(e.to_string().contains("at least 60 s"), "{e}");
}
