use std::collections::BTreeMap;

use super::*;
use crate::codec::Mode;
use crate::model::DriveModel;

fn f510() -> DriveModel {
    DriveModel::builtin("f510").unwrap()
}

fn header() -> Header {
    Header {
        model: "f510".into(),
        node: 1,
        identification: Some(0x0510),
        time: "2026-11-28T02:00:00Z".into(),
        mode: Some("rtu".into()),
    }
}

/// Every parameter with a value of its own (register x 3, cut to 16 bits).
fn values(params: &[Parameter]) -> BTreeMap<u16, u16> {
    params
        .iter()
        .map(|p| (p.register, p.register.wrapping_mul(3)))
        .collect()
}

#[test]
fn the_parameters_are_the_groups_less_the_command_monitor_and_no_access_registers() {
    let m = f510();
    let ps = parameters(&m);
    assert!(ps.iter().all(|p| p.register < 0x2500), "{:?}", ps.last());
    assert!(find(&ps, 0x0301).is_some_and(|p| p.writable && p.name == "3-01"));
    assert!(find(&ps, 0x0C10).is_some_and(|p| !p.writable && p.name == "12-16"));
    let e = DriveModel::builtin("e510").unwrap();
    let pe = parameters(&e);
    // 0014H..0019H are marked "-" in the E510's group 0.
    assert!(find(&pe, 0x0013).is_some() && find(&pe, 0x0014).is_none());
}

#[test]
fn a_backup_is_toml_and_reads_back_as_written() {
    let m = f510();
    let ps = parameters(&m);
    let v = values(&ps);
    let text = Backup::write(&m, &header(), &ps, &v, &BTreeMap::new());
    let toml: toml::Table = toml::from_str(&text).expect("any TOML reader reads a backup");
    assert_eq!(toml["device"]["model"].as_str(), Some("f510"));
    assert_eq!(
        toml["group 3"]["0301"].as_integer(),
        Some(i64::from(0x0301u16 * 3))
    );
    let b = Backup::parse(&text).unwrap();
    assert_eq!(b.header, header());
    let writable: BTreeMap<u16, u16> = v
        .iter()
        .filter(|(r, _)| find(&ps, **r).unwrap().writable)
        .map(|(r, v)| (*r, *v))
        .collect();
    assert_eq!(b.values(), writable, "read-only parameters are comments");
    assert_eq!(b.group_of(0x0301), Some("group 3"));
}

#[test]
fn a_value_in_a_unit_has_as_many_decimals_as_its_scale() {
    let mut p = Parameter {
        register: 0,
        group: "g".into(),
        name: "speed".into(),
        unit: Some("Hz".into()),
        scale: Some(0.01),
        writable: true,
        bounds: (None, None),
    };
    assert_eq!(p.in_unit(4500).as_deref(), Some("45.00 Hz"));
    assert_eq!(p.comment(4500), "speed, Hz: 45.00 Hz");
    p.scale = None;
    assert_eq!(p.in_unit(7).as_deref(), Some("7 Hz"));
    p.unit = None;
    assert_eq!(p.in_unit(7), None);
}

fn error_of(text: &str) -> FileError {
    Backup::parse(text).unwrap_err()
}

const HEAD: &str = "[device]\nmodel = \"f510\"\nnode = 1\n";

#[test]
fn errors_name_the_line_and_column_and_show_what_was_found_in_hex() {
    let e = error_of(&format!("{HEAD}[\"group 3\"]\n0301 = x5\n"));
    assert_eq!(
        e,
        FileError::Syntax {
            line: 5,
            column: 8,
            expected: "a value: a decimal number, 0x and hex digits, or a string".into(),
            found: "\"x5\" (78 35)".into()
        }
    );
    for (line, starts) in [
        (
            "0301 = 70000",
            "line 5, column 8: expected a register value 0..=65535, found 70000",
        ),
        (
            "301 = 1",
            "line 5, column 1: expected a register: 4 hex digits",
        ),
        (
            "0301 = 1 2",
            "line 5, column 10: expected the end of the line",
        ),
    ] {
        let e = error_of(&format!("{HEAD}[\"group 3\"]\n{line}\n"));
        assert!(e.to_string().starts_with(starts), "{line}: {e}");
    }
    let e = error_of(&format!("{HEAD}[\"group 3\"]\n0301 = 1\n0301 = 2\n"));
    assert_eq!(
        e,
        FileError::Duplicate {
            line: 6,
            register: 0x0301,
            first: 5
        }
    );
    let e = error_of("0301 = 1\n");
    assert!(e
        .to_string()
        .starts_with("line 1, column 1: expected a table"));
    let e = error_of("[device]\nnode = 1\n");
    assert!(e.to_string().contains("no model"), "{e}");
    let e = error_of("[device]\nmodel = \"f510\nnode = 1\n");
    assert!(
        e.to_string()
            .contains("line 2, column 14: expected the closing"),
        "{e}"
    );
    let e = error_of("[device]\nmodle = \"f510\"\n");
    assert!(
        e.to_string()
            .contains("line 2, column 1: expected model, node"),
        "{e}"
    );
    // A control character is shown for what it is.
    let e = error_of(&format!("{HEAD}[\"group 3\"]\n0301 =\u{7} 1\n"));
    assert!(e.to_string().contains("(07 20 31)"), "{e}");
}

#[test]
fn a_group_table_given_again_takes_its_lines_into_that_group() {
    let b = Backup::parse(&format!(
        "{HEAD}[\"group 3\"]\n0301 = 1\n[\"group 4\"]\n0401 = 2\n[\"group 3\"]\n0302 = 3\n"
    ))
    .unwrap();
    assert_eq!(b.group_of(0x0302), Some("group 3"));
    assert_eq!(b.groups.len(), 2);
}

#[test]
fn every_cut_and_byte_change_of_a_backup_is_read_or_refused_without_a_panic() {
    let m = DriveModel::builtin("l510").unwrap();
    let ps = parameters(&m);
    let text = Backup::write(&m, &header(), &ps, &values(&ps), &BTreeMap::new());
    let bytes = text.as_bytes();
    for cut in 0..bytes.len().min(3000) {
        let _ = Backup::parse(&String::from_utf8_lossy(&bytes[..cut]));
    }
    let mut rng = crate::rng::Rng::new(36);
    for _ in 0..3000 {
        let mut b = bytes.to_vec();
        let at = rng.below(b.len() as u64) as usize;
        b[at] = rng.below(256) as u8;
        let _ = Backup::parse(&String::from_utf8_lossy(&b));
    }
}

#[test]
fn a_restore_refuses_the_command_block_read_only_and_unknown_registers_by_name() {
    let m = f510();
    let ps = parameters(&m);
    assert_eq!(refusal(&m, &ps, 0x0301, 5), None);
    let w = refusal(&m, &ps, 0x2501, 1).unwrap();
    assert!(w.contains("2501H (Operation signal) is command"), "{w}");
    assert!(w.contains("never writes the command block"), "{w}");
    let w = refusal(&m, &ps, 0x0C10, 1).unwrap();
    assert!(w.contains("0C10H") && w.contains("read-only"), "{w}");
    let w = refusal(&m, &ps, 0x7000, 1).unwrap();
    assert!(w.contains("not in the f510 model's map"), "{w}");
}

#[test]
fn reads_stay_within_a_group_and_the_models_limit_and_cover_every_parameter() {
    let m = f510();
    let ps = parameters(&m);
    for mode in [Mode::Rtu, Mode::Ascii] {
        let plan = read_plan(&m, mode, &ps);
        let limit = m.limits.read.get(mode);
        let mut covered = Vec::new();
        for (start, count) in &plan {
            assert!(
                *count >= 1 && *count <= limit,
                "{start:04X} x{count} in {mode}"
            );
            let first = find(&ps, *start).unwrap();
            for r in *start..start + count {
                assert_eq!(find(&ps, r).unwrap().group, first.group, "{r:04X}");
                covered.push(r);
            }
        }
        let all: Vec<u16> = ps.iter().map(|p| p.register).collect();
        assert_eq!(covered, all, "{mode}");
    }
}

#[test]
fn writes_are_06h_alone_and_10h_for_consecutive_registers_within_the_limit() {
    let m = f510();
    let ps = parameters(&m);
    let p = |r| find(&ps, r).unwrap();
    let changes = vec![
        (p(0x0301), 0, 5),
        (p(0x0305), 0, 6),
        (p(0x0306), 1, 7),
        (p(0x0307), 2, 8),
        (p(0x0410), 0, 9),
    ];
    let w = write_plan(&m, Mode::Rtu, 1, &changes).unwrap();
    let shape: Vec<(u8, u16, usize)> = w
        .iter()
        .map(|w| (w.function, w.start, w.new.len()))
        .collect();
    assert_eq!(
        shape,
        vec![(0x06, 0x0301, 1), (0x10, 0x0305, 3), (0x06, 0x0410, 1)]
    );
    assert_eq!(w[0].hex(), "01 06 03 01 00 05 18 4D");
    assert_eq!(w[1].old, vec![0, 1, 2]);
    assert_eq!(
        w[1].hex(),
        crate::codec::hex::Hex(
            &crate::codec::pdu::Message {
                address: 1,
                pdu: crate::codec::pdu::Pdu::WriteMultipleRequest {
                    start: 0x0305,
                    values: crate::codec::pdu::Registers::new(&[0, 6, 0, 7, 0, 8]).unwrap()
                }
            }
            .to_frame_vec(Mode::Rtu)
            .unwrap()
        )
        .to_string()
    );
    // A run longer than the model's limit is cut there.
    let long: Vec<(&Parameter, u16, u16)> = (0..0x29).map(|i| (p(0x0300 + i), 0, 1)).collect();
    let w = write_plan(&m, Mode::Ascii, 1, &long).unwrap();
    assert!(w
        .iter()
        .all(|w| w.new.len() <= usize::from(m.limits.write.ascii)));
    assert_eq!(w.iter().map(|w| w.new.len()).sum::<usize>(), 0x29);
}

#[test]
fn a_model_without_06h_writes_one_register_by_10h() {
    let mut m = f510();
    m.functions.retain(|f| *f != 0x06);
    let ps = parameters(&m);
    let w = write_plan(&m, Mode::Rtu, 1, &[(find(&ps, 0x0301).unwrap(), 0, 5)]).unwrap();
    assert_eq!((w[0].function, w[0].new.len()), (0x10, 1));
    m.functions.retain(|f| *f != 0x10);
    assert!(matches!(
        write_plan(&m, Mode::Rtu, 1, &[(find(&ps, 0x0301).unwrap(), 0, 5)]),
        Err(PlanError::NoWriteFunction { .. })
    ));
}

#[test]
fn a_diff_names_the_differing_parameters_and_what_only_one_side_has() {
    let m = f510();
    let ps = parameters(&m);
    let side = |v: &[(u16, u16)], partial| Side {
        label: String::new(),
        values: v.iter().copied().collect(),
        partial,
    };
    let a = side(&[(0x0301, 0), (0x0302, 4), (0x0410, 1)], false);
    let b = side(&[(0x0301, 5), (0x0302, 4), (0x0411, 1)], false);
    let d = diff(&ps, &a, &b);
    assert_eq!(d.differ.len(), 1);
    assert_eq!(
        (
            d.differ[0].register,
            d.differ[0].name.as_str(),
            d.differ[0].group.as_str()
        ),
        (0x0301, "3-01", "group 3")
    );
    assert_eq!(
        (d.only_a.clone(), d.only_b.clone()),
        (vec![0x0410], vec![0x0411])
    );
    assert!(d.any());
    // The model's side states few values: the others are not compared, not missing.
    let model = side(&[(0x0302, 4)], true);
    let d = diff(&ps, &a, &model);
    assert!(!d.any());
    assert_eq!((d.compared, d.not_stated), (1, 2));
}
