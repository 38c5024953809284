//! Values judged only after a write seen on the bus set them, and which replies
//! confirm a write.

use super::*;

#[test]
fn values_are_judged_only_after_a_write_seen_on_the_bus_set_them() {
    let model = DriveModel::builtin("f510").unwrap();
    // A writable parameter (not a command register, which the drive may change itself).
    let value = 1u16;
    let reg = writable_parameter(&model, value);
    let mut m = monitor(Mode::Rtu, &[1]);
    let w = write(1, reg, value);
    run(
        &mut m,
        &[
            // Before any write, any value passes.
            (0, &read(1, reg, 1)),
            (15, &values(1, &[value + 5])),
            (100, &w),
            (112, &w),
            (200, &read(1, reg, 1)),
            (215, &values(1, &[value + 5])),
        ],
    );
    let k = kinds(&m, 1);
    assert_eq!(k, ["drive.wrong-value"], "{reg:04X}H");
    assert_eq!(m.nodes()[&1].deviations, 1);
}

#[test]
fn a_write_the_drive_confirmed_early_sets_the_value_all_the_same() {
    // pymodbus's server echoes a write 1.5 ms after it at 9600 baud: an early reply, a
    // finding on timing, yet the drive took the value, and a read of it later returns it.
    let model = DriveModel::builtin("f510").unwrap();
    let reg = writable_parameter(&model, 1);
    let w = write(1, reg, 1);
    // 2 set and confirmed, then 1 written and answered with `answer` (ms, bytes), then
    // a read that returns 1.
    let after = |answer: (u64, &[u8])| {
        let mut m = monitor(Mode::Rtu, &[1]);
        run(
            &mut m,
            &[
                (0, &write(1, reg, 2)),
                (12, &write(1, reg, 2)),
                (100, &w),
                answer,
                (200, &read(1, reg, 1)),
                (215, &values(1, &[1])),
            ],
        )
    };
    let lines = after((101, &w));
    assert!(
        lines[1].issues.contains(&"drive.early-reply".to_string()),
        "{:?}",
        lines[1]
    );
    assert_eq!(lines[1].status, VerdictStatus::Deviation);
    assert_eq!(lines[2].issues, Vec::<String>::new(), "{:?}", lines[2]);
    // The same write refused (an exception), or echoed with a bad CRC, teaches nothing:
    // the value set before holds.
    let mut damaged = w.clone();
    *damaged.last_mut().unwrap() ^= 1;
    for answer in [exception(1, 0x06, 3), damaged] {
        let lines = after((112, &answer));
        assert!(
            lines[2].issues.contains(&"drive.wrong-value".to_string()),
            "{answer:02X?}: {:?}",
            lines[2]
        );
    }
}

#[test]
fn a_write_is_confirmed_by_its_normal_reply_only() {
    use super::exchange::confirms_write;
    let w = write(1, 0x2502, 0x04D2);
    assert!(confirms_write(Mode::Rtu, &w, &w));
    assert!(!confirms_write(Mode::Rtu, &w, &write(1, 0x2502, 0x04D3)));
    assert!(!confirms_write(Mode::Rtu, &w, &exception(1, 0x06, 3)));
    let mut bad = w.clone();
    *bad.last_mut().unwrap() ^= 1;
    assert!(!confirms_write(Mode::Rtu, &w, &bad));
    // 10H: the reply carries the start and the count.
    let values = Registers::new(&[0, 1, 0, 2]).unwrap();
    let q = frame(
        Mode::Rtu,
        1,
        Pdu::WriteMultipleRequest {
            start: 0x2501,
            values,
        },
    );
    let ack = |count| {
        frame(
            Mode::Rtu,
            1,
            Pdu::WriteMultipleResponse {
                start: 0x2501,
                count,
            },
        )
    };
    assert!(confirms_write(Mode::Rtu, &q, &ack(2)));
    assert!(!confirms_write(Mode::Rtu, &q, &ack(1)));
    // ASCII: a request in lower case is confirmed by the echo in upper case, as the
    // judge expects it (the characters differ, the message is the same).
    let upper = frame(
        Mode::Ascii,
        1,
        Pdu::WriteSingle {
            register: 0x250A,
            value: 0x00AB,
        },
    );
    let lower = upper.to_ascii_lowercase();
    assert_ne!(lower, upper);
    assert!(confirms_write(Mode::Ascii, &lower, &upper));
}
