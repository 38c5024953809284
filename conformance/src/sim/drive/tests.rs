//! The simulated drive on frames built by the test: no port, no clock.

use super::*;
use crate::model::Fault;

fn drive(quirks: &[Quirk]) -> Drive {
    Drive::new(
        Arc::new(DriveModel::builtin("f510").unwrap()),
        1,
        Duration::from_millis(10),
    )
    .with_quirks(quirks)
}

fn req(mode: Mode, address: u8, pdu: Pdu<'_>) -> Vec<u8> {
    Message { address, pdu }.to_frame_vec(mode).unwrap()
}

/// An RTU read of 2520H, one register, to `address`.
fn read_2520(address: u8) -> Vec<u8> {
    let pdu = Pdu::ReadRequest {
        start: 0x2520,
        count: 1,
    };
    req(Mode::Rtu, address, pdu)
}

fn reply(o: &Outcome) -> Option<&Transmission> {
    o.sends.iter().find(|s| s.kind == SendKind::Reply)
}

#[test]
fn quirks_parse_and_print() {
    for (spelling, _) in QUIRK_HELP {
        let s = spelling
            .replace("=MS", "=200")
            .replace("=N", "=3")
            .replace("=REG", "=2502H")
            .replace(":VALUE", ":9C41H");
        let q: Quirk = s.parse().unwrap();
        // `slow=MS` is another spelling of `late-reply=MS`.
        let printed = s.replace("slow=", "late-reply=");
        assert_eq!(q.to_string(), printed);
        assert_eq!(printed.parse::<Quirk>().unwrap(), q);
    }
    assert_eq!(
        "wrong-value-at=0x0500".parse::<Quirk>().unwrap(),
        Quirk::WrongValueAt(0x0500)
    );
    assert!("overflow-after=0".parse::<Quirk>().is_err());
    assert!("wrong-value-at=FFFFFH".parse::<Quirk>().is_err());
    assert_eq!(
        "stuck-at=2502H:9C41H".parse::<Quirk>().unwrap(),
        Quirk::StuckAt(0x2502, 0x9C41)
    );
    assert_eq!(
        Quirk::StuckAt(0x2502, 0x9C41).to_string(),
        "stuck-at=2502H:9C41H"
    );
    assert!("stuck-at=2502H".parse::<Quirk>().is_err());
    assert_eq!(
        "exception-at=0x2521".parse::<Quirk>().unwrap(),
        Quirk::ExceptionAt(0x2521)
    );
    assert_eq!("freeze-after=7".parse::<Quirk>(), Ok(Quirk::FreezeAfter(7)));
    assert!("dead=1".parse::<Quirk>().is_err());
    assert!("drop-every=0".parse::<Quirk>().is_err());
    assert!("late-reply".parse::<Quirk>().is_err());
    assert!("crc".parse::<Quirk>().is_err());
}

#[test]
fn the_example_exchanges_replay() {
    let mut d = drive(&[]);
    let now = Instant::now();
    // F510 03H example: read 0123H -> 1770H.
    let o = d.handle(
        Mode::Rtu,
        &[0x01, 0x03, 0x01, 0x23, 0x00, 0x01, 0x74, 0x3C],
        now,
    );
    assert_eq!(
        reply(&o).unwrap().bytes,
        [0x01, 0x03, 0x02, 0x17, 0x70, 0xB6, 0x50]
    );
    assert_eq!(reply(&o).unwrap().after, Duration::from_millis(10));
    // 06H example: echo.
    let w = [0x01, 0x06, 0x01, 0x02, 0x17, 0x70, 0x27, 0xE2];
    assert_eq!(reply(&d.handle(Mode::Rtu, &w, now)).unwrap().bytes, w);
    // 08H example: echo.
    let lb = [0x01, 0x08, 0x00, 0x00, 0xA5, 0x37, 0xDA, 0x8D];
    assert_eq!(reply(&d.handle(Mode::Rtu, &lb, now)).unwrap().bytes, lb);
    // 10H example: start and count.
    let m = [
        0x01, 0x10, 0x01, 0x01, 0x00, 0x02, 0x04, 0x00, 0x01, 0x17, 0x70, 0x60, 0x27,
    ];
    assert_eq!(
        reply(&d.handle(Mode::Rtu, &m, now)).unwrap().bytes,
        [0x01, 0x10, 0x01, 0x01, 0x00, 0x02, 0x11, 0xF4]
    );
}

#[test]
fn state_follows_the_command_register() {
    let mut d = drive(&[]);
    let t0 = Instant::now();
    let w = |d: &mut Drive, r: u16, v: u16, t| {
        d.handle(
            Mode::Rtu,
            &req(
                Mode::Rtu,
                1,
                Pdu::WriteSingle {
                    register: r,
                    value: v,
                },
            ),
            t,
        )
    };
    w(&mut d, 0x2502, 6000, t0);
    assert_eq!(d.read_register(0x2523), 6000);
    assert_eq!(
        d.read_register(0x2520) & 0b1101,
        0b0100,
        "ready, not running"
    );
    w(&mut d, 0x2501, 0b11, t0); // run, reverse
    d.tick(t0 + Duration::from_millis(500));
    let half = d.read_register(0x2524);
    assert!((2900..=3100).contains(&half), "{half}");
    d.tick(t0 + Duration::from_secs(2));
    assert_eq!(d.read_register(0x2524), 6000);
    assert_eq!(d.read_register(0x2520) & 0b1111, 0b0111);
    w(&mut d, 0x2501, 0b100, t0 + Duration::from_secs(2)); // external fault
    assert_eq!(d.read_register(0x2520) & 0b1000, 0b1000);
    assert_eq!(d.read_register(0x2521), 27);
    w(&mut d, 0x2501, 0b1000, t0 + Duration::from_secs(2)); // fault reset
    assert_eq!(d.read_register(0x2521), 0);
    assert_eq!(d.read_register(0x252F), 0x0510);
    assert_eq!(d.read_register(0x2500), 0);
}

#[test]
fn broadcast_writes_silently_and_other_nodes_are_ignored() {
    let mut d = drive(&[]);
    let now = Instant::now();
    let o = d.handle(
        Mode::Ascii,
        &req(
            Mode::Ascii,
            0,
            Pdu::WriteSingle {
                register: 0x2502,
                value: 0x0AAA,
            },
        ),
        now,
    );
    assert!(o.sends.is_empty());
    assert_eq!(d.read_register(0x2502), 0x0AAA);
    let o = d.handle(Mode::Rtu, &read_2520(2), now);
    assert!(o.sends.is_empty());
}

#[test]
fn stuck_at_and_exception_at_answer_reads_as_planted() {
    let now = Instant::now();
    let read = |start, count| req(Mode::Rtu, 1, Pdu::ReadRequest { start, count });
    let o = drive(&[Quirk::StuckAt(0x2502, 0x9C41)]).handle(Mode::Rtu, &read(0x2501, 2), now);
    assert_eq!(&reply(&o).unwrap().bytes[3..7], &[0x00, 0x00, 0x9C, 0x41]);
    let o = drive(&[Quirk::ExceptionAt(0x2521)]).handle(Mode::Rtu, &read(0x2520, 3), now);
    assert_eq!(&reply(&o).unwrap().bytes[..3], &[0x01, 0x83, 0x04]);
    // A read that does not cover the register is served.
    let o = drive(&[Quirk::ExceptionAt(0x2521)]).handle(Mode::Rtu, &read(0x2522, 2), now);
    assert_eq!(&reply(&o).unwrap().bytes[..3], &[0x01, 0x03, 0x04]);
}

#[test]
fn each_quirk_changes_the_line() {
    let now = Instant::now();
    let read = read_2520(1);
    let clean = reply(&drive(&[]).handle(Mode::Rtu, &read, now))
        .unwrap()
        .bytes
        .clone();

    let o = drive(&[Quirk::CrcSwap]).handle(Mode::Rtu, &read, now);
    let b = &reply(&o).unwrap().bytes;
    assert_eq!(b[..b.len() - 2], clean[..clean.len() - 2]);
    assert_eq!(
        (b[b.len() - 2], b[b.len() - 1]),
        (clean[clean.len() - 1], clean[clean.len() - 2])
    );

    let bc = req(
        Mode::Rtu,
        0,
        Pdu::WriteSingle {
            register: 0x2502,
            value: 1,
        },
    );
    let o = drive(&[Quirk::ReplyToBroadcast]).handle(Mode::Rtu, &bc, now);
    assert_eq!(reply(&o).unwrap().bytes[0], 0);

    let bad = req(
        Mode::Rtu,
        1,
        Pdu::Other {
            function: 4,
            data: &[0, 0, 0, 1],
        },
    );
    let o = drive(&[Quirk::WrongException]).handle(Mode::Rtu, &bad, now);
    assert_eq!(reply(&o).unwrap().bytes[..3], [1, 0x84, 2]);
    assert!(matches!(
        o.judgement.expect,
        Expectation::Exception {
            fault: Fault::IllegalFunction,
            code: 1
        }
    ));

    let o = drive(&[Quirk::LateReply(250)]).handle(Mode::Rtu, &read, now);
    assert_eq!(reply(&o).unwrap().after, Duration::from_millis(260));

    let mut d = drive(&[Quirk::DropEvery(2)]);
    assert!(reply(&d.handle(Mode::Rtu, &read, now)).is_some());
    assert!(reply(&d.handle(Mode::Rtu, &read, now)).is_none());
    assert!(reply(&d.handle(Mode::Rtu, &read, now)).is_some());

    let o = drive(&[Quirk::LocalEcho]).handle(Mode::Rtu, &read, now);
    assert_eq!(o.sends[0].bytes, read);
    assert_eq!(o.sends[0].kind, SendKind::Echo);

    let o = drive(&[Quirk::GarbageBeforeReply]).handle(Mode::Rtu, &read, now);
    assert_eq!(reply(&o).unwrap().bytes[3..], clean[..]);

    let o = drive(&[Quirk::TruncatedReply]).handle(Mode::Rtu, &read, now);
    assert_eq!(reply(&o).unwrap().bytes[..], clean[..clean.len() - 2]);

    let other = read_2520(9);
    let o = drive(&[Quirk::AnswerEveryAddress]).handle(Mode::Rtu, &other, now);
    assert_eq!(reply(&o).unwrap().bytes[0], 9);
}
