//! A whole learn against a fake device with TECO-like blocks, and its draft.

use std::sync::atomic::AtomicBool;

use super::map::tests::Fake;
use super::map::MapConfig;
use super::*;

fn learn_fake(fake: &mut Fake, allow_write: bool) -> (Learned, Result<(), LearnError>) {
    learn_range(fake, allow_write, 0x2FFF)
}

fn learn_range(fake: &mut Fake, allow_write: bool, last: u16) -> (Learned, Result<(), LearnError>) {
    let cfg = LearnConfig {
        node: 1,
        map: MapConfig {
            first: 0,
            last,
            stride: 16,
        },
        max_requests: 20_000,
        allow_write,
        other_address: 0xF7,
    };
    let stop = AtomicBool::new(false);
    let mut learned = Learned::new("fake".into(), "9600 8N1".into(), Mode::Rtu, 1, cfg.map);
    let r = learn(fake, &cfg, &stop, &mut |_| {}, &mut learned);
    (learned, r)
}

#[test]
fn a_draft_holds_what_the_device_showed_with_its_requests() {
    let mut fake = Fake::new(
        &[(0x0000, 0x0038), (0x2500, 0x251F), (0x2520, 0x252F)],
        37,
        true,
    );
    let (learned, r) = learn_fake(&mut fake, false);
    r.unwrap();
    let d = draft::draft(&learned, "acme-x100", "2026-11-27");
    assert_eq!(d["schema_version"], 2);
    assert_eq!(d["modes"], serde_json::json!(["rtu"]));
    let blocks: Vec<(String, String)> = d["blocks"]
        .as_array()
        .unwrap()
        .iter()
        .map(|b| {
            (
                b["first"].as_str().unwrap().into(),
                b["last"].as_str().unwrap().into(),
            )
        })
        .collect();
    assert_eq!(
        blocks,
        [
            ("0000".into(), "0038".into()),
            ("2500".into(), "251F".into()),
            ("2520".into(), "252F".into())
        ]
    );
    for b in d["blocks"].as_array().unwrap() {
        assert_eq!(b["basis"], "observed");
        assert!(b["request"].as_str().unwrap().starts_with("01 03 "), "{b}");
        assert!(b.get("access").is_none());
    }
    assert_eq!(d["functions"]["codes"], serde_json::json!(["03", "08"]));
    assert_eq!(d["exceptions"]["illegal-function"]["code"], "01");
    assert_eq!(d["exceptions"]["illegal-register"]["code"], "02");
    assert_eq!(d["exceptions"]["illegal-count"]["code"], "03");
    assert_eq!(d["exceptions"]["crosses-group"]["code"], "02");
    // The count exception is shown by a read one over the limit.
    assert!(d["exceptions"]["illegal-count"]["request"]
        .as_str()
        .unwrap()
        .starts_with("01 03 00 00 00 26 "));
    assert_eq!(d["limits"]["read_registers"]["rtu"], 37);
    assert_eq!(d["limits"]["same_group"]["value"], true);
    assert_eq!(d["limits"]["response_time_ms"]["value"], 3);
    let codes: Vec<&str> = d["exception_codes"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| c["code"].as_str().unwrap())
        .collect();
    assert_eq!(codes, ["01", "02", "03"]);
    // The fake answers broadcasts and other nodes with silence, bad checksums too.
    for reason in ["broadcast", "other-address", "bad-checksum"] {
        assert_eq!(d["silence"][reason]["basis"], "observed", "{reason}");
    }
    assert_eq!(d["loop_back"]["data_bytes"], 2);
    assert_eq!(d["parameter_access"]["basis"], "decision");
    // The fake's values are the register xor 5A5AH: 252FH holds 7F75H, no model's value.
    assert_eq!(d["identification"]["register"], "252F");
    assert_eq!(d["identification"]["value"], "7F75");
    assert!(d["notes"]
        .as_str()
        .unwrap()
        .contains("without --allow-write"));
}

#[test]
fn an_interrupted_learn_keeps_what_it_found() {
    let mut fake = Fake::new(&[(0x0000, 0x0FFF)], 125, false);
    let cfg = LearnConfig {
        node: 1,
        map: MapConfig::default(),
        max_requests: 20_000,
        allow_write: false,
        other_address: 0xF7,
    };
    let stop = AtomicBool::new(false);
    let mut learned = Learned::new("fake".into(), "9600 8N1".into(), Mode::Rtu, 1, cfg.map);
    let mut n = 0;
    let r = learn(
        &mut fake,
        &cfg,
        &stop,
        &mut |_| {
            n += 1;
            if n == 50 {
                stop.store(true, std::sync::atomic::Ordering::Relaxed);
            }
        },
        &mut learned,
    );
    assert!(matches!(r, Err(LearnError::Interrupted)), "{r:?}");
    assert_eq!(learned.stopped.as_deref(), Some("interrupted"));
    let d = draft::draft(&learned, "learned", "2026-11-27");
    assert_eq!(d["blocks"][0]["first"], "0000");
    assert!(d["notes"]
        .as_str()
        .unwrap()
        .contains("Learning stopped early: interrupted"));
}

/// A device that answers a broadcast and another node (with exception 04H, as pymodbus
/// does) has no silence to state, and those answers are no response time of its own:
/// here they come late, and the p99 (of a few replies: the largest) stays the device's
/// 3 ms.
#[test]
fn answers_to_a_broadcast_and_another_node_are_not_timed() {
    let mut fake = Fake::new(&[(0x0000, 0x00FF)], 125, false);
    fake.answers_everyone = Some(std::time::Duration::from_millis(400));
    let (learned, r) = learn_range(&mut fake, false, 0x00FF);
    assert!(
        learned.timed < 100,
        "{} replies: the p99 is not the largest",
        learned.timed
    );
    r.unwrap();
    let d = draft::draft(&learned, "learned", "2026-11-27");
    assert_eq!(
        d["limits"]["response_time_ms"]["value"], 3,
        "{}",
        d["limits"]
    );
    assert!(d["silence"].get("broadcast").is_none());
    assert!(d["silence"].get("other-address").is_none());
    assert_eq!(d["silence"]["bad-checksum"]["basis"], "observed");
    let notes = d["notes"].as_str().unwrap();
    assert!(
        notes.contains("broadcast: the device did not keep silent"),
        "{notes}"
    );
}
