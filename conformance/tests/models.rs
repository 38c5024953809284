//! The drive models: every file loads and round-trips, the tables say what the manuals
//! say, the limits follow from the 80-byte frame, and the rules give what the model's
//! facts say for each kind of request. Every example request of the manuals is served by
//! its model.

mod common;
use common::Run;

use conformance::codec::pdu::{Message, Pdu, Registers};
use conformance::codec::Mode;
use conformance::model::{
    read_response_len, write_request_len, Access, Basis, DriveModel, Expectation, Fault, ModelFile,
    SilenceReason, MODELS,
};
use conformance::vectors::model::FileDirection;
use conformance::vectors::{Body, VectorSet, Verdict};

fn model(id: &str) -> DriveModel {
    DriveModel::builtin(id).unwrap_or_else(|e| panic!("{id}: {e}"))
}

fn frame(mode: Mode, address: u8, pdu: Pdu<'_>) -> Vec<u8> {
    Message { address, pdu }.to_frame_vec(mode).unwrap()
}

fn read(m: &DriveModel, mode: Mode, start: u16, count: u16) -> Expectation {
    m.judge(1, mode, &frame(mode, 1, Pdu::ReadRequest { start, count }))
        .expect
}

/// An RTU 03H request to node `address`.
fn rtu_read(address: u8, start: u16, count: u16) -> Vec<u8> {
    frame(Mode::Rtu, address, Pdu::ReadRequest { start, count })
}

/// An RTU 06H request to node 1.
fn rtu_write(register: u16, value: u16) -> Vec<u8> {
    frame(Mode::Rtu, 1, Pdu::WriteSingle { register, value })
}

/// An RTU 10H request to node 1 (`values` the registers' bytes).
fn rtu_write_multiple(start: u16, values: &[u8]) -> Vec<u8> {
    let values = Registers::new(values).unwrap();
    frame(Mode::Rtu, 1, Pdu::WriteMultipleRequest { start, values })
}

fn write(m: &DriveModel, register: u16, value: u16) -> Expectation {
    m.judge(1, Mode::Rtu, &rtu_write(register, value)).expect
}

/// The exception of `fault` with `code`, as a description that states no code gets it.
fn answered(fault: Fault, code: u8) -> Expectation {
    Expectation::Exception { fault, code }
}

fn exception(m: &DriveModel, fault: Fault) -> Expectation {
    Expectation::Exception {
        fault,
        code: m.answer_code(fault),
    }
}

#[test]
fn every_model_loads_and_round_trips() {
    for (id, text) in DriveModel::builtin_files() {
        let file: ModelFile = serde_json::from_str(text).unwrap();
        // Unknown fields would be dropped by serde: the round trip catches them.
        let original: serde_json::Value = serde_json::from_str(text).unwrap();
        let again = serde_json::to_value(&file).unwrap();
        assert_eq!(
            original, again,
            "{id}: the file has fields the format does not know"
        );
        let m = DriveModel::from_file(&file).unwrap();
        assert_eq!(m.id, *id);
    }
    assert_eq!(DriveModel::builtin_files().len(), MODELS.len());
}

#[test]
fn a_broken_model_is_rejected_with_the_reason() {
    let text = DriveModel::builtin_files()[0].1;
    let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
    v["exceptions"]["read-only"]["code"] = "07".into();
    let err = DriveModel::from_json("f510", &v.to_string()).unwrap_err();
    assert!(
        err.to_string()
            .contains("07 is not in the exception-code table"),
        "{err}"
    );

    let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
    v["limits"]["read_registers"]["rtu"] = 38.into();
    let err = DriveModel::from_json("f510", &v.to_string()).unwrap_err();
    assert!(err.to_string().contains("81-byte response"), "{err}");

    let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
    v["parameter_groups"][1]["registers"][0] = "0200-0203".into();
    let err = DriveModel::from_json("f510", &v.to_string()).unwrap_err();
    assert!(err.to_string().contains("outside the group"), "{err}");

    let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
    v["exceptions"]["crosses-group"]
        .as_object_mut()
        .unwrap()
        .remove("why");
    let err = DriveModel::from_json("f510", &v.to_string()).unwrap_err();
    assert!(err.to_string().contains("a decision needs a why"), "{err}");

    let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
    v["registers"].as_array_mut().unwrap().remove(5);
    let err = DriveModel::from_json("f510", &v.to_string()).unwrap_err();
    assert!(
        err.to_string().contains("every register of the block"),
        "{err}"
    );
}

#[test]
fn limits_follow_from_the_80_byte_frame() {
    for id in MODELS {
        let m = model(id);
        assert_eq!(m.limits.max_frame, 80);
        for mode in [Mode::Rtu, Mode::Ascii] {
            let r = m.limits.read.get(mode);
            let w = m.limits.write.get(mode);
            assert!(read_response_len(mode, r) <= 80);
            assert!(write_request_len(mode, w) <= 80);
            assert!(write_request_len(mode, w + 1) > 80, "{id} {mode}");
            if id != "a510" || mode == Mode::Ascii {
                assert!(read_response_len(mode, r + 1) > 80, "{id} {mode}");
            }
        }
    }
    // The legacy note states the limits; the rule gives the same numbers.
    let legacy = model("l510-legacy");
    assert_eq!((legacy.limits.read.rtu, legacy.limits.read.ascii), (37, 17));
    assert_eq!(
        (legacy.limits.write.rtu, legacy.limits.write.ascii),
        (35, 15)
    );
    assert_eq!(legacy.limits.read.fact.basis, Basis::Documented);
    assert_eq!(model("f510").limits.read.fact.basis, Basis::Derived);
    // A510: "04 Register number is over 32" caps RTU reads at 32, a decision.
    let a = model("a510");
    assert_eq!(
        (a.limits.read.rtu, a.limits.read.fact.basis),
        (32, Basis::Decision)
    );
}

#[test]
fn tables_say_what_the_manuals_say() {
    let f = model("f510");
    assert_eq!(f.addresses, 1..=0xFE);
    assert_eq!(model("l510-legacy").addresses, 1..=0x20);
    assert_eq!(f.functions, [3, 6, 8, 0x10]);
    assert_eq!(f.exception_meaning(3), Some("Number error"));
    assert_eq!(model("e510").exception_meaning(5), Some("Write mode error"));
    assert!(model("l510-legacy").numbers_exceptions_from_51());
    assert!(!f.numbers_exceptions_from_51());
    assert_eq!(model("l510").identification.unwrap().value, Some(0x0110));
    assert_eq!(f.identification.as_ref().unwrap().value, None);
    assert_eq!(
        f.identification.as_ref().unwrap().fact.basis,
        Basis::Decision
    );

    // F510 parameter groups: 0-00..0-56, 2-00..2-19 and 2-33..2-34, no group 19.
    let groups: Vec<_> = f.parameter_groups().collect();
    assert_eq!(groups.len(), 24);
    assert_eq!(groups[0].registers, vec![0x0000..=0x0038]);
    assert_eq!(groups[2].registers, vec![0x0200..=0x0213, 0x0221..=0x0222]);
    assert!(f.lookup(0x1300).is_none());
    assert_eq!(f.lookup(0x2520).unwrap().access, Access::ReadOnly);
    assert_eq!(f.lookup(0x2500).unwrap().access, Access::Reserved);
    assert_eq!(f.lookup(0x2502).unwrap().access, Access::ReadWrite);
    // E510 marks registers "-": 0-20..0-25 among them.
    let e = model("e510");
    assert_eq!(e.lookup(0x0014).unwrap().access, Access::NoAccess);
    assert_eq!(e.lookup(0x001A).unwrap().access, Access::ReadWrite);
    // 20-07 printed 1404H (a misprint): the model uses 1407H.
    assert_eq!(e.lookup(0x1407).unwrap().access, Access::ReadWrite);
    // 6-33..6-40 are missing from the source.
    assert!(e.lookup(0x0621).is_none());
    // Legacy A0xxH is an alias of 25xxH.
    let l = model("l510-legacy");
    let a = l.lookup(0xA002).unwrap();
    assert!(a.via_alias);
    assert_eq!(a.register, 0x2502);
}

#[test]
fn reads_follow_the_map_and_the_limits() {
    let f = model("f510");
    let plan = |e: Expectation| match e {
        Expectation::Read(p) => p.registers,
        other => panic!("expected a read, got {other:?}"),
    };
    assert_eq!(plan(read(&f, Mode::Rtu, 0x2520, 16)).len(), 16);
    assert_eq!(plan(read(&f, Mode::Rtu, 0x0000, 37)).len(), 37);
    assert!(read(&f, Mode::Ascii, 0x0000, 17).replies());
    // Reads a model refuses, with the fault it answers for each.
    for (id, mode, start, count, fault) in [
        ("f510", Mode::Rtu, 0x0000, 38, Fault::IllegalCount),
        ("f510", Mode::Ascii, 0x0000, 18, Fault::IllegalCount),
        ("f510", Mode::Rtu, 0x0000, 0, Fault::IllegalCount),
        ("f510", Mode::Rtu, 0x0039, 1, Fault::IllegalRegister),
        ("f510", Mode::Rtu, 0x0038, 2, Fault::IllegalRegister),
        ("f510", Mode::Rtu, 0x252F, 2, Fault::IllegalRegister),
        ("f510", Mode::Rtu, 0x251F, 2, Fault::CrossesGroup),
        ("f510", Mode::Rtu, 0xFFFF, 2, Fault::IllegalRegister),
        ("e510", Mode::Rtu, 0x0013, 2, Fault::NoAccess),
        // The A510 caps RTU reads at 32.
        ("a510", Mode::Rtu, 0x0000, 33, Fault::IllegalCount),
    ] {
        let m = model(id);
        let case = format!("{id} {mode:?} {count} from {start:04X}H");
        assert_eq!(read(&m, mode, start, count), exception(&m, fault), "{case}");
    }
    let a = model("a510");
    assert_eq!(a.answer_code(Fault::IllegalCount), 4);
}

#[test]
fn writes_follow_the_access_of_each_register() {
    let f = model("f510");
    assert_eq!(write(&f, 0x2502, 0x1770), Expectation::WriteSingle);
    // Writes a model refuses, with the fault it answers for each.
    for (id, register, value, fault) in [
        ("f510", 0x2502, 0xFFFF, Fault::DataOutOfRange),
        ("f510", 0x2520, 0, Fault::ReadOnly),
        ("f510", 0x2500, 0, Fault::ReservedWrite),
        ("f510", 0x0039, 0, Fault::IllegalRegister),
        ("e510", 0x0014, 0, Fault::NoAccess),
        ("l510-legacy", 0x2520, 0, Fault::ReadOnly),
    ] {
        let m = model(id);
        let case = format!("{id}: {value:04X}H to {register:04X}H");
        assert_eq!(write(&m, register, value), exception(&m, fault), "{case}");
    }
    assert_eq!(f.answer_code(Fault::ReadOnly), 2);
    assert_eq!(model("e510").answer_code(Fault::ReadOnly), 5);
    let l = model("l510-legacy");
    assert_eq!(l.answer_code(Fault::ReadOnly), 0x55);
    let j = l.judge(1, Mode::Rtu, &rtu_write(0xA002, 0x1770));
    assert_eq!(j.expect, Expectation::WriteSingle);
    assert_eq!(j.write.unwrap().writes, vec![(0x2502, 0x1770)]);

    // 10H: count over the limit is a frame over 80 bytes, which gets no reply.
    let values = vec![0u8; 72];
    let long = rtu_write_multiple(0, &values);
    assert_eq!(long.len(), 81);
    let silent = Expectation::Silence(SilenceReason::FrameTooLong);
    assert_eq!(f.judge(1, Mode::Rtu, &long).expect, silent);
    let ok = rtu_write_multiple(0, &values[..70]);
    assert_eq!(
        f.judge(1, Mode::Rtu, &ok).expect,
        Expectation::WriteMultiple
    );
}

#[test]
fn silence_broadcast_and_exceptions_by_function() {
    let f = model("f510");
    let req = rtu_read(1, 0x2520, 1);
    let mut bad = req.clone();
    bad[7] ^= 1;
    // Node 2 hears node 1's request; node 1 hears its request with a byte of its CRC off.
    for (node, bytes, why) in [
        (2, &req, SilenceReason::OtherAddress),
        (1, &bad, SilenceReason::BadChecksum),
    ] {
        let got = f.judge(node, Mode::Rtu, bytes).expect;
        assert_eq!(got, Expectation::Silence(why), "{why:?}");
    }
    let bc = frame(
        Mode::Ascii,
        0,
        Pdu::WriteSingle {
            register: 0x2502,
            value: 0x0100,
        },
    );
    let j = f.judge(1, Mode::Ascii, &bc);
    assert_eq!(j.expect, Expectation::Silence(SilenceReason::Broadcast));
    assert_eq!(j.write.unwrap().writes, vec![(0x2502, 0x0100)]);
    let bc_read = rtu_read(0, 0x2520, 1);
    let j = f.judge(1, Mode::Rtu, &bc_read);
    assert_eq!(j.expect, Expectation::Silence(SilenceReason::Broadcast));
    assert!(j.write.is_none());
    let other = frame(
        Mode::Rtu,
        1,
        Pdu::Other {
            function: 0x04,
            data: &[0, 0, 0, 1],
        },
    );
    for id in MODELS {
        let m = model(id);
        let j = m.judge(1, Mode::Rtu, &other);
        let want = if id == "l510-legacy" { 0x51 } else { 0x01 };
        assert_eq!(j.expect, answered(Fault::IllegalFunction, want));
        assert_eq!(j.basis(), Basis::Documented);
    }
}

#[test]
fn every_example_request_of_the_manuals_is_served_by_its_model() {
    let set = VectorSet::builtin().unwrap();
    let mut checked = 0;
    for (file, v) in set.iter() {
        let Body::Frame(fv) = &v.body else { continue };
        if fv.direction != FileDirection::Request
            || v.verdict == Verdict::Erratum && fv.corrected.is_none()
        {
            continue;
        }
        let m = model(&file.document);
        let bytes = fv
            .correct_bytes()
            .unwrap_or_else(|| panic!("{}: no usable bytes", v.id));
        let j = m.judge(1, fv.mode.into(), &bytes);
        assert!(
            matches!(
                j.expect,
                Expectation::Read(_)
                    | Expectation::WriteSingle
                    | Expectation::WriteMultiple
                    | Expectation::LoopBack
            ),
            "{}: {} ({})",
            v.id,
            j.expect.describe(),
            j.detail
        );
        checked += 1;
    }
    assert!(checked >= 35, "{checked} example requests checked");
}

#[test]
fn the_command_line_shows_a_model_and_its_decisions() {
    let run = |args: &[&str]| Run::new(args).run().ok().stdout;
    let all = run(&["model", "e510"]);
    common::assert_contains_all(
        &all,
        &[
            "illegal-function: exception 01H  [documented]",
            "147 marked '-'",
            "20-07: printed 1404H",
        ],
    );
    let decisions = run(&["model", "e510", "--decisions"]);
    assert!(
        decisions.contains("no-access: exception 02H  [decision]"),
        "{decisions}"
    );
    assert!(!decisions.contains("[documented]") && !decisions.contains("[derived]"));
    let every = run(&["model"]);
    for m in MODELS {
        assert!(every.contains(&format!("{m} — ")), "{m}");
    }
}

fn write_multiple(m: &DriveModel, start: u16, values: &[u16]) -> Expectation {
    let bytes: Vec<u8> = values.iter().flat_map(|v| v.to_be_bytes()).collect();
    m.judge(1, Mode::Rtu, &rtu_write_multiple(start, &bytes))
        .expect
}

/// F510's own tables: 2502H takes 0..400.00 Hz (Metasys 'AO1 Set frequency Register 2502H
/// Hz R/W 0 ~ 400.00'), documented; 9C40H is accepted and 9C41H is out of range.
#[test]
fn f510_frequency_command_max_is_400_hz_documented() {
    let f = model("f510");
    let (r, max, fact) = f.frequency_command_max().unwrap();
    assert_eq!((r, max), (0x2502, 0x9C40));
    assert_eq!(fact.basis, Basis::Documented);
    let source = fact.source.as_deref().unwrap();
    common::assert_contains_all(
        source,
        &[
            "AO1 Set frequency Register 2502H Hz R/W 0 ~ 400.00",
            "line 3115",
        ],
    );
    let named = f.named(0x2502).unwrap();
    assert!(named.max_lines.as_deref().unwrap().contains("3115"));
    assert!(
        named.max_notes.iter().any(|n| n.contains("0 - 60")),
        "the BACnet AO0 row is noted"
    );

    assert_eq!(write(&f, 0x2502, 0x9C40), Expectation::WriteSingle);
    assert_eq!(
        write_multiple(&f, 0x2502, &[0x9C40]),
        Expectation::WriteMultiple
    );
    for v in [0x9C41, 0xE9FC, 0xFFFF] {
        assert_eq!(
            write(&f, 0x2502, v),
            exception(&f, Fault::DataOutOfRange),
            "{v:04X}"
        );
        assert_eq!(
            write_multiple(&f, 0x2502, &[v]),
            exception(&f, Fault::DataOutOfRange),
            "{v:04X}"
        );
    }
    let j = f.judge(1, Mode::Rtu, &rtu_write(0x2502, 0x9C41));
    assert!(j.facts.contains(fact), "the judgement cites the max");
    // The other models keep 599.00 Hz, a decision; those that borrow it say so.
    for id in ["a510", "l510", "e510", "l510-legacy"] {
        let m = model(id);
        let (_, max, fact) = m.frequency_command_max().unwrap();
        assert_eq!(max, 0xE9FC, "{id}");
        assert_eq!(fact.basis, Basis::Decision, "{id}");
    }
    for id in ["a510", "l510-legacy"] {
        let m = model(id);
        let why = m.frequency_command_max().unwrap().2.why.clone().unwrap();
        assert!(why.contains("borrows"), "{id}: {why}");
    }
    // 2505H/2506H: 'AO1 (0 ~ 1000)' in the Modbus chapter.
    assert_eq!(write(&f, 0x2505, 1000), Expectation::WriteSingle);
    assert_eq!(
        write(&f, 0x2506, 1001),
        exception(&f, Fault::DataOutOfRange)
    );
}

/// F510's Metasys table marks 12-16, 12-17, 12-18, 12-24, 12-25, 12-26 and 12-45 'R':
/// writes get the read-only rule (06H and 10H), reads are served.
#[test]
fn f510_read_only_parameters_refuse_writes_and_serve_reads() {
    let f = model("f510");
    let expected: Vec<u16> = vec![0x0C10, 0x0C11, 0x0C12, 0x0C18, 0x0C19, 0x0C1A, 0x0C2D];
    let listed: Vec<u16> = f.read_only_parameters().map(|(r, _)| r).collect();
    assert_eq!(listed, expected);
    for (r, fact) in f.read_only_parameters() {
        assert_eq!(fact.basis, Basis::Documented);
        let source = fact.source.as_deref().unwrap();
        common::assert_contains_all(source, &["MetaSys", "not the Modbus chapter"]);
        let number = format!("12-{:02}", r & 0xFF);
        assert!(source.contains(&number), "{r:04X}: {source}");
        assert!(f.read_only_parameter(r).unwrap().lines.is_some());

        assert_eq!(f.lookup(r).unwrap().access, Access::ReadOnly, "{r:04X}");
        assert_eq!(write(&f, r, 0), exception(&f, Fault::ReadOnly), "{r:04X}");
        assert_eq!(
            write_multiple(&f, r, &[0]),
            exception(&f, Fault::ReadOnly),
            "{r:04X}"
        );
        let j = f.judge(1, Mode::Rtu, &rtu_write(r, 1));
        assert!(
            j.facts.contains(fact),
            "{r:04X}: the judgement cites the mark"
        );
        assert!(j.detail.contains(&number), "{}", j.detail);
        assert!(j.write.is_none());
        match read(&f, Mode::Rtu, r, 1) {
            Expectation::Read(p) => assert_eq!(p.registers, vec![r]),
            other => panic!("{r:04X}: read gives {other:?}"),
        }
    }
    // A 10H write that covers a read-only parameter is refused as a whole; its
    // neighbours stay writable, and a read across them is served.
    assert_eq!(
        write_multiple(&f, 0x0C0E, &[0, 0, 0, 0]),
        exception(&f, Fault::ReadOnly)
    );
    assert_eq!(write(&f, 0x0C0F, 0), Expectation::WriteSingle);
    assert_eq!(write(&f, 0x0C13, 0), Expectation::WriteSingle);
    assert!(read(&f, Mode::Rtu, 0x0C00, 37).replies());
    // The other models mark none.
    for id in ["a510", "l510", "e510", "l510-legacy"] {
        let m = model(id);
        assert_eq!(m.read_only_parameters().count(), 0, "{id}");
        assert_ne!(
            m.lookup(0x0C10).map(|i| i.access),
            Some(Access::ReadOnly),
            "{id}"
        );
    }
    assert_eq!(write(&model("a510"), 0x0C10, 0), Expectation::WriteSingle);
}

/// A510: 'If the maximum output frequency of the motor is over 300Hz the frequency
/// resolution is 0.1Hz'. The model accepts 30001 (7531H), 2502H keeps it, the drive uses
/// 30000.
#[test]
fn a510_resolution_over_300_hz_is_a_tenth_of_a_hertz() {
    let a = model("a510");
    let res = a.frequency_resolution().unwrap();
    assert_eq!((res.above, res.step), (30000, 10));
    assert_eq!(res.fact.basis, Basis::Documented);
    assert!(res.fact.source.as_deref().unwrap().contains("over 300Hz"));
    assert_eq!(res.handling.basis, Basis::Decision);
    assert_eq!(write(&a, 0x2502, 30001), Expectation::WriteSingle);
    assert_eq!(a.frequency_in_use(30001), 30000);
    assert_eq!(a.frequency_in_use(30019), 30010);
    assert_eq!(a.frequency_in_use(30000), 30000);
    assert_eq!(a.frequency_in_use(29999), 29999);
    assert_eq!(a.frequency_in_use(1234), 1234);
    // The other models have no such rule.
    assert!(model("f510").frequency_resolution().is_none());
    assert_eq!(model("f510").frequency_in_use(30001), 30001);
}

#[test]
fn read_only_parameter_entries_are_checked_on_load() {
    let text = DriveModel::builtin_files()[0].1;
    let broken = |f: &dyn Fn(&mut serde_json::Value)| {
        let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
        f(&mut v);
        DriveModel::from_json("f510", &v.to_string())
            .unwrap_err()
            .to_string()
    };
    let e =
        broken(&|v| v["parameter_access"]["read_only"][0]["parameters"] = "12-16..12-19".into());
    assert!(e.contains("group x 100H + number"), "{e}");
    let e = broken(&|v| {
        v["parameter_access"]["read_only"][0]["registers"] = "0C4D".into();
        v["parameter_access"]["read_only"][0]["parameters"] = "12-77".into();
    });
    assert!(e.contains("not a listed parameter register"), "{e}");
    let e = broken(&|v| {
        v["parameter_access"]["read_only"][1]["registers"] = "0C12".into();
        v["parameter_access"]["read_only"][1]["parameters"] = "12-18".into();
    });
    assert!(e.contains("overlaps"), "{e}");
    let e = broken(&|v| {
        v["parameter_access"]["read_only"][0]
            .as_object_mut()
            .unwrap()
            .remove("source");
    });
    assert!(e.contains("a documented fact needs a source"), "{e}");
    let e = broken(&|v| {
        let r = v["registers"]
            .as_array_mut()
            .unwrap()
            .iter_mut()
            .find(|r| r["register"] == "2520")
            .unwrap();
        r["max"] = serde_json::json!({"value": "0001", "basis": "documented", "source": "x"});
    });
    assert!(e.contains("needs a read-write register"), "{e}");
}

/// The device (RTU only, two plain blocks), as JSON to change in each test.
fn v2_device() -> serde_json::Value {
    serde_json::json!({
        "schema_version": 2,
        "model": "device-x",
        "title": "device X data sheet",
        "modes": ["rtu"],
        "functions": {"codes": ["03", "06", "10"], "basis": "documented", "source": "data sheet 2"},
        "blocks": [
            {"first": "0000", "last": "0FFF", "basis": "documented", "source": "data sheet 3"},
            {"first": "2500", "last": "252F", "basis": "documented", "source": "data sheet 3"}
        ]
    })
}

/// The loader's own error (lint, which runs first on every load, words some of the same
/// faults its way: `tests/model_lint.rs`).
fn v2_error(v: &serde_json::Value) -> conformance::model::ModelError {
    DriveModel::from_json_unlinted("device-x", &v.to_string()).unwrap_err()
}

#[test]
fn a_v2_description_with_nothing_optional_loads_with_the_specification_s_defaults() {
    let m = DriveModel::from_json("device-x", &v2_device().to_string()).unwrap();
    assert_eq!(m.modes(), [Mode::Rtu]);
    assert_eq!(
        m.manual, "device X data sheet",
        "manual defaults to the title"
    );
    assert_eq!((m.broadcast, m.addresses.clone()), (0, 1..=0xF7));
    assert_eq!(m.addresses_fact.basis, Basis::Derived);
    assert_eq!(m.lookup(0x0FFF).map(|i| i.access), Some(Access::ReadWrite));
    assert_eq!(m.lookup(0x1000), None);
    assert_eq!(m.lookup(0x252F).map(|i| i.access), Some(Access::ReadWrite));
    // A block is a plain range: a read across 0000H..0FFFH needs no TECO group.
    assert!(matches!(
        read(&m, Mode::Rtu, 0x0F90, 0x70),
        Expectation::Read(_)
    ));
    // A read past the map: the Modbus code, but the judgement says which rule is missing
    // and binds no device.
    let j = m.judge(1, Mode::Rtu, &rtu_read(1, 0x1000, 1));
    assert_eq!(j.expect, answered(Fault::IllegalRegister, 0x02));
    assert_eq!(j.missing, ["exceptions.illegal-register"]);
    assert_eq!(j.basis(), Basis::Decision);
    assert_eq!(
        j.missing_reason().as_deref(),
        Some("the description has no exceptions.illegal-register")
    );
    let over = m.judge(1, Mode::Rtu, &rtu_read(1, 0, 126));
    assert_eq!(over.expect, answered(Fault::IllegalCount, 0x03));
    let broadcast = m.judge(1, Mode::Rtu, &rtu_read(0, 0, 1));
    assert_eq!(
        broadcast.expect,
        Expectation::Silence(SilenceReason::Broadcast)
    );
    assert_eq!(broadcast.missing, ["silence.broadcast"]);
    // A served read rests on stated facts only.
    let ok = m.judge(1, Mode::Rtu, &rtu_read(1, 0, 1));
    assert!(ok.missing.is_empty());
    assert_eq!(ok.basis(), Basis::Documented);
}

#[test]
fn v2_block_access_and_bounds_decide_writes_and_reads() {
    let mut v = v2_device();
    v["blocks"][0]["max"] = "7FFF".into();
    v["blocks"][0]["min"] = "0010".into();
    v["blocks"][1]["access"] = "read-only".into();
    v["blocks"].as_array_mut().unwrap().push(serde_json::json!(
        {"first": "3000", "last": "300F", "access": "write-only", "basis": "documented", "source": "s"}
    ));
    v["blocks"].as_array_mut().unwrap().push(serde_json::json!(
        {"first": "4000", "last": "400F", "access": "reserved", "basis": "documented", "source": "s"}
    ));
    let m = DriveModel::from_json("device-x", &v.to_string()).unwrap();
    assert_eq!(write(&m, 0x0001, 0x7FFF), Expectation::WriteSingle);
    assert_eq!(write(&m, 0x3000, 0xFFFF), Expectation::WriteSingle);
    // Out of the block's bounds, read-only, and reserved (served by no function).
    for (register, value, fault) in [
        (0x0001, 0x8000, Fault::DataOutOfRange),
        (0x0001, 0x000F, Fault::DataOutOfRange),
        (0x2500, 0, Fault::ReadOnly),
        (0x4000, 0, Fault::IllegalRegister),
    ] {
        let case = format!("{value:04X}H to {register:04X}H");
        assert_eq!(write(&m, register, value), exception(&m, fault), "{case}");
    }
    // Write-only, and reserved.
    for start in [0x3000, 0x4000] {
        let got = read(&m, Mode::Rtu, start, 1);
        assert_eq!(got, exception(&m, Fault::IllegalRegister), "{start:04X}H");
    }
    assert_eq!(m.blocks.len(), 4);
    assert_eq!(m.blocks[3].access, Access::Reserved);
}

/// A change to a description, in a table of broken descriptions.
type Change = Box<dyn Fn(&mut serde_json::Value)>;

#[test]
fn v2_errors_name_the_field_s_path() {
    let cases: Vec<(Change, &str, &str)> = vec![
        (
            Box::new(|v| v["blocks"][1]["last"] = "2400".into()),
            "blocks[1].last",
            "2400 is before first 2500",
        ),
        (
            Box::new(|v| v["blocks"][1]["first"] = "0FFF".into()),
            "",
            "overlap",
        ),
        (
            Box::new(|v| v["blocks"][0]["access"] = "sometimes".into()),
            "blocks[0].access",
            "not read-write",
        ),
        (
            Box::new(|v| v["blocks"][0]["max"] = "12".into()),
            "blocks[0].max",
            "four upper-case hex digits",
        ),
        (
            Box::new(|v| v["modes"] = serde_json::json!([])),
            "modes",
            "at least one",
        ),
        (
            Box::new(|v| v["modes"] = serde_json::json!(["rtu", "rtu"])),
            "modes[1]",
            "listed twice",
        ),
        (
            Box::new(|v| v["modes"] = serde_json::json!(["tcp"])),
            "modes[0]",
            "not \"rtu\"",
        ),
        (
            Box::new(|v| v["schema_version"] = 3.into()),
            "schema_version",
            "not supported",
        ),
        (
            Box::new(|v| v["model"] = "Device X".into()),
            "model",
            "not an id",
        ),
        (
            Box::new(
                |v| v["limits"] = serde_json::json!({"read_registers": {"rtu": 126, "ascii": 125, "basis": "documented", "source": "s"}}),
            ),
            "limits.read_registers.rtu",
            "257-byte response",
        ),
        (
            Box::new(
                |v| v["identification"] = serde_json::json!({"register": "1000", "value": null, "basis": "documented", "source": "s"}),
            ),
            "identification.register",
            "not in the map",
        ),
        (
            Box::new(
                |v| v["exceptions"] = serde_json::json!({"illegal-count": {"code": "03", "basis": "documented", "source": "s"}}),
            ),
            "exceptions.illegal-count.code",
            "not in the exception-code table",
        ),
        (
            Box::new(
                |v| v["exceptions"] = serde_json::json!({"too-long": {"code": "03", "basis": "documented", "source": "s"}}),
            ),
            "exceptions.too-long",
            "unknown fault kind",
        ),
        (
            Box::new(|v| v["blocks"][0]["basis"] = "observed".into()),
            "blocks[0]",
            "needs the request",
        ),
        (
            Box::new(|v| {
                v["parameter_groups"] =
                    serde_json::json!([{"group": 1, "registers": ["0100-0101"], "source": "s"}])
            }),
            "naming",
            "group x 100H + number",
        ),
    ];
    for (change, path, text) in cases {
        let mut v = v2_device();
        change(&mut v);
        let e = v2_error(&v);
        let shown = e.to_string();
        assert!(shown.contains(text), "{shown}");
        if !path.is_empty() {
            assert_eq!(e.path(), Some(path), "{shown}");
            assert!(shown.contains(&format!(": {path}: ")), "{shown}");
        }
    }
    // An observed fact with its request loads, and binds like a documented one.
    let mut v = v2_device();
    v["blocks"][0] = serde_json::json!({"first": "0000", "last": "0FFF", "basis": "observed",
        "request": "01 03 00 00 00 7D 85 EB", "reply": "01 03 FA 00 00"});
    let m = DriveModel::from_json("device-x", &v.to_string()).unwrap();
    assert_eq!(m.blocks[0].fact.basis, Basis::Observed);
    assert!(Basis::Observed.binding());
    assert!(m.blocks[0]
        .fact
        .citation()
        .contains("request 01 03 00 00 00 7D 85 EB"));
}

#[test]
fn a_copied_f510_file_keeps_its_example_register_inside_a_v2_block() {
    // Item 3 of issue 34: the F510's example register 0123H, left in a file copied from
    // f510.json, lies inside the new block 0000H..0FFFH.
    let mut v: serde_json::Value = serde_json::from_str(DriveModel::builtin_files()[0].1).unwrap();
    v["schema_version"] = 2.into();
    v["model"] = "copied".into();
    for k in [
        "parameter_groups",
        "groups",
        "registers",
        "identification",
        "parameter_access",
    ] {
        v.as_object_mut().unwrap().remove(k);
    }
    v["exceptions"].as_object_mut().unwrap().remove("no-access");
    v["blocks"] = v2_device()["blocks"].clone();
    let m = DriveModel::from_json("copied", &v.to_string()).unwrap();
    assert_eq!(m.lookup(0x0123).map(|i| i.access), Some(Access::ReadWrite));
    assert_eq!(m.example_registers.len(), 1);
    // With another access it contradicts the block: an overlap.
    v["example_registers"][0]["access"] = "read-only".into();
    let e = DriveModel::from_json_unlinted("copied", &v.to_string()).unwrap_err();
    assert!(e.to_string().contains("overlap"), "{e}");
    // Lint, first on every load, says so too, naming the entry and the block.
    let e = DriveModel::from_json("copied", &v.to_string()).unwrap_err();
    assert!(
        e.to_string().contains(
            "example_registers[0].access: example register 0123H is read-only but blocks[0]"
        ),
        "{e}"
    );
}

#[test]
fn a_v1_file_keeps_every_field_it_requires() {
    let text = DriveModel::builtin_files()[0].1;
    for field in ["loop_back", "silence", "identification", "limits", "manual"] {
        let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
        v.as_object_mut().unwrap().remove(field);
        let e = DriveModel::from_json_unlinted("f510", &v.to_string()).unwrap_err();
        assert_eq!(e.path(), Some(field), "{e}");
        assert!(e.to_string().contains("schema_version 1 requires"), "{e}");
    }
    let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
    v["modes"] = serde_json::json!(["rtu"]);
    let e = DriveModel::from_json_unlinted("f510", &v.to_string()).unwrap_err();
    assert_eq!(e.path(), Some("modes"), "{e}");
    let mut v: serde_json::Value = serde_json::from_str(text).unwrap();
    v["blocks"] = serde_json::json!([]);
    let e = DriveModel::from_json_unlinted("f510", &v.to_string()).unwrap_err();
    assert!(e.to_string().contains("schema_version 2 field"), "{e}");
}

#[test]
fn adjacent_v2_blocks_are_one_range_unless_same_group_says_a_block_is_a_group() {
    let mut v = v2_device();
    v["blocks"][1]["first"] = "1000".into();
    v["blocks"][1]["last"] = "10FF".into();
    let m = DriveModel::from_json("device-x", &v.to_string()).unwrap();
    assert!(matches!(
        read(&m, Mode::Rtu, 0x0FFF, 2),
        Expectation::Read(_)
    ));
    v["limits"] =
        serde_json::json!({"same_group": {"value": true, "basis": "documented", "source": "s"}});
    let m = DriveModel::from_json("device-x", &v.to_string()).unwrap();
    assert_eq!(
        read(&m, Mode::Rtu, 0x0FFF, 2),
        exception(&m, Fault::CrossesGroup)
    );
}
