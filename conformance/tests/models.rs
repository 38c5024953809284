//! The drive models: every file loads and round-trips, the tables say what the manuals
//! say, the limits follow from the 80-byte frame, and the rules give what the model's
//! facts say for each kind of request. Every example request of the manuals is served by
//! its model.

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

fn write(m: &DriveModel, register: u16, value: u16) -> Expectation {
    m.judge(
        1,
        Mode::Rtu,
        &frame(Mode::Rtu, 1, Pdu::WriteSingle { register, value }),
    )
    .expect
}

fn exception(m: &DriveModel, fault: Fault) -> Expectation {
    Expectation::Exception {
        fault,
        code: m.rule(fault).code,
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
    assert_eq!(model("l510").identification.value, Some(0x0110));
    assert_eq!(f.identification.value, None);
    assert_eq!(f.identification.fact.basis, Basis::Decision);

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
    assert_eq!(
        read(&f, Mode::Rtu, 0x0000, 38),
        exception(&f, Fault::IllegalCount)
    );
    assert!(read(&f, Mode::Ascii, 0x0000, 17).replies());
    assert_eq!(
        read(&f, Mode::Ascii, 0x0000, 18),
        exception(&f, Fault::IllegalCount)
    );
    assert_eq!(
        read(&f, Mode::Rtu, 0x0000, 0),
        exception(&f, Fault::IllegalCount)
    );
    assert_eq!(
        read(&f, Mode::Rtu, 0x0039, 1),
        exception(&f, Fault::IllegalRegister)
    );
    assert_eq!(
        read(&f, Mode::Rtu, 0x0038, 2),
        exception(&f, Fault::IllegalRegister)
    );
    assert_eq!(
        read(&f, Mode::Rtu, 0x252F, 2),
        exception(&f, Fault::IllegalRegister)
    );
    assert_eq!(
        read(&f, Mode::Rtu, 0x251F, 2),
        exception(&f, Fault::CrossesGroup)
    );
    assert_eq!(
        read(&f, Mode::Rtu, 0xFFFF, 2),
        exception(&f, Fault::IllegalRegister)
    );
    let e = model("e510");
    assert_eq!(
        read(&e, Mode::Rtu, 0x0013, 2),
        exception(&e, Fault::NoAccess)
    );
    // The A510 caps RTU reads at 32.
    let a = model("a510");
    assert_eq!(
        read(&a, Mode::Rtu, 0x0000, 33),
        exception(&a, Fault::IllegalCount)
    );
    assert_eq!(a.rule(Fault::IllegalCount).code, 4);
}

#[test]
fn writes_follow_the_access_of_each_register() {
    let f = model("f510");
    assert_eq!(write(&f, 0x2502, 0x1770), Expectation::WriteSingle);
    assert_eq!(
        write(&f, 0x2502, 0xFFFF),
        exception(&f, Fault::DataOutOfRange)
    );
    assert_eq!(write(&f, 0x2520, 0), exception(&f, Fault::ReadOnly));
    assert_eq!(f.rule(Fault::ReadOnly).code, 2);
    assert_eq!(write(&f, 0x2500, 0), exception(&f, Fault::ReservedWrite));
    assert_eq!(write(&f, 0x0039, 0), exception(&f, Fault::IllegalRegister));
    let e = model("e510");
    assert_eq!(e.rule(Fault::ReadOnly).code, 5);
    assert_eq!(write(&e, 0x0014, 0), exception(&e, Fault::NoAccess));
    let l = model("l510-legacy");
    assert_eq!(write(&l, 0x2520, 0), exception(&l, Fault::ReadOnly));
    assert_eq!(l.rule(Fault::ReadOnly).code, 0x55);
    let j = l.judge(
        1,
        Mode::Rtu,
        &frame(
            Mode::Rtu,
            1,
            Pdu::WriteSingle {
                register: 0xA002,
                value: 0x1770,
            },
        ),
    );
    assert_eq!(j.expect, Expectation::WriteSingle);
    assert_eq!(j.write.unwrap().writes, vec![(0x2502, 0x1770)]);

    // 10H: count over the limit is a frame over 80 bytes, which gets no reply.
    let values = vec![0u8; 72];
    let long = frame(
        Mode::Rtu,
        1,
        Pdu::WriteMultipleRequest {
            start: 0,
            values: Registers::new(&values).unwrap(),
        },
    );
    assert_eq!(long.len(), 81);
    assert_eq!(
        f.judge(1, Mode::Rtu, &long).expect,
        Expectation::Silence(SilenceReason::FrameTooLong)
    );
    let ok = frame(
        Mode::Rtu,
        1,
        Pdu::WriteMultipleRequest {
            start: 0,
            values: Registers::new(&values[..70]).unwrap(),
        },
    );
    assert_eq!(
        f.judge(1, Mode::Rtu, &ok).expect,
        Expectation::WriteMultiple
    );
}

#[test]
fn silence_broadcast_and_exceptions_by_function() {
    let f = model("f510");
    let req = frame(
        Mode::Rtu,
        1,
        Pdu::ReadRequest {
            start: 0x2520,
            count: 1,
        },
    );
    assert_eq!(
        f.judge(2, Mode::Rtu, &req).expect,
        Expectation::Silence(SilenceReason::OtherAddress)
    );
    let mut bad = req.clone();
    bad[7] ^= 1;
    assert_eq!(
        f.judge(1, Mode::Rtu, &bad).expect,
        Expectation::Silence(SilenceReason::BadChecksum)
    );
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
    let bc_read = frame(
        Mode::Rtu,
        0,
        Pdu::ReadRequest {
            start: 0x2520,
            count: 1,
        },
    );
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
        assert_eq!(
            j.expect,
            Expectation::Exception {
                fault: Fault::IllegalFunction,
                code: want
            }
        );
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
    let run = |args: &[&str]| {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_conformance"))
            .args(args)
            .output()
            .unwrap();
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        String::from_utf8(o.stdout).unwrap()
    };
    let all = run(&["model", "e510"]);
    assert!(
        all.contains("illegal-function: exception 01H  [documented]"),
        "{all}"
    );
    assert!(all.contains("147 marked '-'"), "{all}");
    assert!(all.contains("20-07: printed 1404H"), "{all}");
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
