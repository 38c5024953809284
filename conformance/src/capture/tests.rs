//! Byte fixtures: construct, parse, round trip, and every error of the reader and writer.

use super::read::BlockKind;
use super::*;

const APP: &str = "test";

fn written(packets: &[(PacketMeta, Vec<u8>)], ifaces: &[Interface]) -> Vec<u8> {
    let mut w = PcapngWriter::new(Vec::new(), APP).unwrap();
    for i in ifaces {
        w.add_interface(i).unwrap();
    }
    for (m, d) in packets {
        w.write_packet(m, d).unwrap();
    }
    w.into_inner()
}

fn rtu_iface() -> Interface {
    Interface {
        link_type: LINKTYPE_USER0,
        name: "pty /dev/pts/3".into(),
        description: "rtu 9600 8E1".into(),
    }
}

fn ascii_iface() -> Interface {
    Interface {
        link_type: LINKTYPE_USER1,
        name: "pty /dev/pts/4".into(),
        description: "ascii 9600 7E1".into(),
    }
}

const READ: [u8; 8] = [0x01, 0x03, 0x00, 0x00, 0x00, 0x01, 0x84, 0x0A];

fn le32(b: &[u8], at: usize) -> u32 {
    u32::from_le_bytes([b[at], b[at + 1], b[at + 2], b[at + 3]])
}

#[test]
fn construct_blocks_have_the_layout_of_the_spec() {
    let meta = PacketMeta {
        interface: 0,
        timestamp_us: 0x1_0000_0002,
        flags: FLAG_OUTBOUND | FLAG_CRC_ERROR,
        comment: Some("bad".into()),
    };
    let f = written(&[(meta, READ.to_vec())], &[rtu_iface()]);
    // Section header: type, length, byte-order magic, version 1.0, section length -1.
    assert_eq!(le32(&f, 0), 0x0A0D_0D0A);
    let shb_len = le32(&f, 4) as usize;
    assert_eq!(le32(&f, 8), 0x1A2B_3C4D);
    assert_eq!(&f[12..16], &[1, 0, 0, 0]);
    assert_eq!(&f[16..24], &[0xFF; 8]);
    assert_eq!(le32(&f, shb_len - 4) as usize, shb_len);
    // Interface: link type 147, snaplen 0, if_tsresol = 6 among its options.
    let idb = shb_len;
    assert_eq!(le32(&f, idb), 1);
    let idb_len = le32(&f, idb + 4) as usize;
    assert_eq!(&f[idb + 8..idb + 12], &[147, 0, 0, 0]);
    let idb_bytes = &f[idb..idb + idb_len];
    assert!(idb_bytes.windows(5).any(|w| w == [9, 0, 1, 0, 6]));
    assert!(idb_bytes.windows(12).any(|w| w == b"rtu 9600 8E1"));
    // Enhanced packet: interface 0, timestamp high then low, lengths 8, the bytes.
    let epb = idb + idb_len;
    assert_eq!(le32(&f, epb), 6);
    let epb_len = le32(&f, epb + 4) as usize;
    assert_eq!(epb + epb_len, f.len());
    assert_eq!(le32(&f, epb + 8), 0);
    assert_eq!(le32(&f, epb + 12), 1);
    assert_eq!(le32(&f, epb + 16), 2);
    assert_eq!(le32(&f, epb + 20), 8);
    assert_eq!(le32(&f, epb + 24), 8);
    assert_eq!(&f[epb + 28..epb + 36], &READ);
    // epb_flags (code 2, length 4), then the comment (code 1, "bad" padded), then end.
    assert_eq!(&f[epb + 36..epb + 44], &[2, 0, 4, 0, 0x02, 0, 0, 0x01]);
    assert_eq!(&f[epb + 44..epb + 52], &[1, 0, 3, 0, b'b', b'a', b'd', 0]);
    assert_eq!(&f[epb + 52..epb + 56], &[0, 0, 0, 0]);
    assert_eq!(le32(&f, epb + epb_len - 4) as usize, epb_len);
}

#[test]
fn round_trip_keeps_bytes_times_directions_flags_and_comments() {
    let frames: Vec<(PacketMeta, Vec<u8>)> = vec![
        (
            PacketMeta {
                interface: 0,
                timestamp_us: 1_700_000_000_000_001,
                flags: FLAG_OUTBOUND,
                comment: None,
            },
            READ.to_vec(),
        ),
        (
            PacketMeta {
                interface: 0,
                timestamp_us: 1_700_000_000_004_000,
                flags: FLAG_INBOUND | FLAG_CRC_ERROR | FLAG_WRONG_GAP,
                comment: Some("rtu.crc.bad-request".into()),
            },
            vec![0x01, 0x83, 0x02, 0xC0, 0xF1, 0x00, 0x01],
        ),
        (
            PacketMeta {
                interface: 1,
                timestamp_us: 1_700_000_000_009_999,
                flags: 0,
                comment: None,
            },
            b":010300000001FB\r\n".to_vec(),
        ),
        (
            PacketMeta {
                interface: 0,
                timestamp_us: 1,
                flags: FLAG_OUTBOUND,
                comment: None,
            },
            Vec::new(),
        ),
    ];
    let f = written(&frames, &[rtu_iface(), ascii_iface()]);
    let r = Reader::new(&f).unwrap();
    assert!(r.is_pcapng());
    let back: Vec<Packet<'_>> = r.collect::<Result<_, _>>().unwrap();
    assert_eq!(back.len(), frames.len());
    for (p, (m, d)) in back.iter().zip(&frames) {
        assert_eq!(p.data, &d[..]);
        assert_eq!(p.original_len as usize, d.len());
        assert_eq!(p.interface, m.interface);
        assert_eq!(p.timestamp_ns, Some(m.timestamp_us * 1000));
        assert_eq!(p.flags, (m.flags != 0).then_some(m.flags));
        assert_eq!(p.comment, m.comment.as_deref());
        assert_eq!(
            p.link_type,
            [LINKTYPE_USER0, LINKTYPE_USER1][m.interface as usize]
        );
    }
    assert_eq!(back[0].direction, Some(Direction::Outbound));
    assert_eq!(back[1].direction, Some(Direction::Inbound));
    assert_eq!(back[2].direction, None);
}

/// A classic pcap file, by hand: header then records.
fn pcap(big: bool, nanos: bool, link: u32, records: &[(u32, u32, &[u8])]) -> Vec<u8> {
    // A field in the file's byte order, from its little-endian bytes.
    let put = |v: &mut Vec<u8>, le: &[u8]| {
        if big {
            v.extend(le.iter().rev());
        } else {
            v.extend_from_slice(le);
        }
    };
    let w32 = |v: &mut Vec<u8>, x: u32| put(v, &x.to_le_bytes());
    let w16 = |v: &mut Vec<u8>, x: u16| put(v, &x.to_le_bytes());
    let mut v = Vec::new();
    w32(&mut v, if nanos { 0xA1B2_3C4D } else { 0xA1B2_C3D4 });
    w16(&mut v, 2);
    w16(&mut v, 4);
    w32(&mut v, 0);
    w32(&mut v, 0);
    w32(&mut v, 65535);
    w32(&mut v, link);
    for (s, frac, d) in records {
        w32(&mut v, *s);
        w32(&mut v, *frac);
        w32(&mut v, d.len() as u32);
        w32(&mut v, d.len() as u32);
        v.extend_from_slice(d);
    }
    v
}

#[test]
fn pcap_both_byte_orders_and_resolutions() {
    for big in [false, true] {
        for nanos in [false, true] {
            let f = pcap(big, nanos, 147, &[(10, 500, &READ), (11, 7, &READ[..3])]);
            let r = Reader::new(&f).unwrap();
            assert!(!r.is_pcapng());
            let p: Vec<_> = r.collect::<Result<_, _>>().unwrap();
            let unit = if nanos { 1 } else { 1000 };
            assert_eq!(p.len(), 2, "big {big} nanos {nanos}");
            assert_eq!(p[0].timestamp_ns, Some(10_000_000_000 + 500 * unit));
            assert_eq!(p[1].timestamp_ns, Some(11_000_000_000 + 7 * unit));
            assert_eq!(p[0].data, &READ);
            assert_eq!(p[1].data, &READ[..3]);
            assert_eq!((p[0].link_type, p[0].direction), (147, None));
        }
    }
    // The FCS bits above the link type are not part of it.
    let f = pcap(false, false, 0x1000_0000 | 148, &[]);
    assert_eq!(Reader::new(&f).unwrap().count(), 0);
}

/// A big-endian pcapng file by hand: two interfaces, nanosecond and 2^-10 s resolution.
fn pcapng_big_endian() -> Vec<u8> {
    let mut v = Vec::new();
    let block = |v: &mut Vec<u8>, kind: u32, body: &[u8]| {
        let len = (body.len() + 12) as u32;
        v.extend_from_slice(&kind.to_be_bytes());
        v.extend_from_slice(&len.to_be_bytes());
        v.extend_from_slice(body);
        v.extend_from_slice(&len.to_be_bytes());
    };
    let mut shb = Vec::new();
    shb.extend_from_slice(&0x1A2B_3C4Du32.to_be_bytes());
    shb.extend_from_slice(&[0, 1, 0, 0]);
    shb.extend_from_slice(&[0xFF; 8]);
    block(&mut v, 0x0A0D_0D0A, &shb);
    // Interface 0: link 147, if_tsresol 9 (ns).
    block(
        &mut v,
        1,
        &[0, 147, 0, 0, 0, 0, 0, 0, 0, 9, 0, 1, 9, 0, 0, 0, 0, 0, 0, 0],
    );
    // Interface 1: link 148, if_tsresol 0x8A (2^-10 s), no end-of-options.
    block(
        &mut v,
        1,
        &[0, 148, 0, 0, 0, 0, 0, 0, 0, 9, 0, 1, 0x8A, 0, 0, 0],
    );
    // An unknown block type (custom block) is skipped.
    block(&mut v, 0x0000_0BAD, &[1, 2, 3, 4]);
    // Enhanced packet blocks, big-endian words: interface, timestamp high and low,
    // captured and original length; then the data (padded to 4) and any options.
    let epb = |words: [u32; 5], padded: &[u8], options: &[u8]| {
        let mut b: Vec<u8> = words.iter().flat_map(|w| w.to_be_bytes()).collect();
        b.extend_from_slice(padded);
        b.extend_from_slice(options);
        b
    };
    let mut flags = vec![0, 2, 0, 4];
    flags.extend_from_slice(&(FLAG_INBOUND | FLAG_CRC_ERROR).to_be_bytes());
    block(
        &mut v,
        6,
        &epb([0, 0, 1_500, 3, 3], &[0xAA, 0xBB, 0xCC, 0], &flags),
    );
    block(&mut v, 6, &epb([1, 0, 2048, 1, 1], &[b':', 0, 0, 0], &[]));
    // A simple packet block on interface 0: no time.
    block(&mut v, 3, &[0, 0, 0, 2, 0x11, 0x22, 0, 0]);
    v
}

#[test]
fn pcapng_big_endian_with_two_resolutions() {
    let f = pcapng_big_endian();
    let p: Vec<_> = Reader::new(&f).unwrap().collect::<Result<_, _>>().unwrap();
    assert_eq!(p.len(), 3);
    assert_eq!(p[0].timestamp_ns, Some(1_500));
    assert_eq!(p[0].data, &[0xAA, 0xBB, 0xCC]);
    assert_eq!(p[0].direction, Some(Direction::Inbound));
    assert_eq!(p[0].flags, Some(FLAG_INBOUND | FLAG_CRC_ERROR));
    assert_eq!((p[1].interface, p[1].link_type), (1, 148));
    // 2048 units of 2^-10 s: 2 s.
    assert_eq!(p[1].timestamp_ns, Some(2_000_000_000));
    assert_eq!(p[2].timestamp_ns, None);
    assert_eq!(p[2].data, &[0x11, 0x22]);
}

#[test]
fn every_cut_is_whole_packets_or_a_truncation_at_the_cut_block() {
    let frames: Vec<(PacketMeta, Vec<u8>)> = (0..4u8)
        .map(|i| {
            (
                PacketMeta {
                    interface: 0,
                    timestamp_us: u64::from(i),
                    flags: FLAG_OUTBOUND,
                    comment: (i == 2).then(|| "cut".to_string()),
                },
                vec![i; usize::from(i) * 3 + 1],
            )
        })
        .collect();
    let f = written(&frames, &[rtu_iface()]);
    // Block boundaries, from the lengths.
    let mut bounds = vec![0usize];
    while *bounds.last().unwrap() < f.len() {
        let at = *bounds.last().unwrap();
        bounds.push(at + le32(&f, at + 4) as usize);
    }
    for cut in 0..f.len() {
        let part = &f[..cut];
        let r = match Reader::new(part) {
            Ok(r) => r,
            Err(e) => {
                assert!(cut < 4, "{cut}: {e}");
                continue;
            }
        };
        let items: Vec<_> = r.collect();
        let last_start = *bounds.iter().filter(|b| **b <= cut).max().unwrap();
        let whole_packets = bounds
            .iter()
            .filter(|b| **b <= cut)
            .count()
            .saturating_sub(3);
        if bounds.contains(&cut) {
            assert!(items.iter().all(|i| i.is_ok()), "cut {cut}");
            assert_eq!(items.len(), whole_packets, "cut {cut}");
        } else {
            let (last, rest) = items.split_last().unwrap();
            assert!(rest.iter().all(|i| i.is_ok()));
            match last {
                Err(ReadError::Truncated { offset, .. }) => {
                    assert_eq!(*offset as usize, last_start, "cut {cut}")
                }
                other => panic!("cut {cut}: {other:?}"),
            }
        }
    }
}

/// The errors of a file whose first block is a section header and whose second block is
/// `second` (little-endian), with one interface described before it.
fn with_block(kind: u32, body: &[u8], trailing_len: Option<u32>) -> Vec<u8> {
    let mut f = written(&[], &[rtu_iface()]);
    let len = (body.len() + 12) as u32;
    f.extend_from_slice(&kind.to_le_bytes());
    f.extend_from_slice(&len.to_le_bytes());
    f.extend_from_slice(body);
    f.extend_from_slice(&trailing_len.unwrap_or(len).to_le_bytes());
    f
}

fn first_error(f: &[u8]) -> ReadError {
    match Reader::new(f) {
        Err(e) => e,
        Ok(r) => r
            .filter_map(Result::err)
            .next()
            .expect("an error is reported"),
    }
}

fn epb_body(iface: u32, captured: u32, data: &[u8]) -> Vec<u8> {
    let mut b = Vec::new();
    for x in [iface, 0, 0, captured, captured] {
        b.extend_from_slice(&x.to_le_bytes());
    }
    b.extend_from_slice(data);
    b
}

#[test]
fn every_read_error_names_its_offset_and_block() {
    let base = written(&[], &[rtu_iface()]).len() as u64;
    // Not a capture.
    let e = first_error(b"GIF89a..");
    assert_eq!(
        e,
        ReadError::NotACapture {
            found: "47494638".into()
        }
    );
    assert!(e.to_string().contains("at byte 0"));
    // Too short for any magic; a pcap header cut short.
    assert!(matches!(
        first_error(&[0x0A, 0x0D]),
        ReadError::Truncated {
            offset: 0,
            block: BlockKind::FileHeader,
            ..
        }
    ));
    let p = pcap(false, false, 147, &[]);
    assert!(matches!(
        first_error(&p[..20]),
        ReadError::Truncated {
            offset: 0,
            block: BlockKind::FileHeader,
            needed: 24,
            available: 20
        }
    ));
    // A pcap version 3; a pcap record cut short in its header and in its data.
    let mut v3 = p.clone();
    v3[4] = 3;
    assert!(matches!(
        first_error(&v3),
        ReadError::Version { major: 3, .. }
    ));
    let p = pcap(false, false, 147, &[(1, 2, &READ)]);
    assert_eq!(
        first_error(&p[..30]),
        ReadError::Truncated {
            offset: 24,
            block: BlockKind::PcapRecord,
            needed: 16,
            available: 6
        }
    );
    assert_eq!(
        first_error(&p[..p.len() - 1]),
        ReadError::Truncated {
            offset: 24,
            block: BlockKind::PcapRecord,
            needed: 24,
            available: 23
        }
    );
    // A huge length field is a truncation, not an allocation.
    let mut huge = p.clone();
    huge[32..36].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    assert!(matches!(
        first_error(&huge),
        ReadError::Truncated {
            offset: 24,
            needed: 0x1_0000_0000,
            ..
        }
    ));
    // Bad byte-order magic.
    let mut bo = written(&[], &[]);
    bo[8] = 0x55;
    assert!(matches!(
        first_error(&bo),
        ReadError::BadByteOrder { offset: 0, .. }
    ));
    // Section version 2.
    let mut sv = written(&[], &[]);
    sv[12] = 2;
    assert!(matches!(
        first_error(&sv),
        ReadError::Version {
            offset: 0,
            block: BlockKind::Section,
            major: 2,
            ..
        }
    ));
    // Block length not a multiple of 4, or under the minimum.
    let mut bl = with_block(6, &epb_body(0, 4, &READ[..4]), None);
    bl[base as usize + 4] = 33;
    assert_eq!(
        first_error(&bl),
        ReadError::BadLength {
            offset: base,
            block: BlockKind::EnhancedPacket,
            length: 33,
            minimum: 32
        }
    );
    assert!(matches!(
        first_error(&with_block(6, &[0; 8], None)),
        ReadError::BadLength {
            length: 20,
            minimum: 32,
            ..
        }
    ));
    // A huge block length is a truncation.
    let mut hb = with_block(6, &epb_body(0, 4, &READ[..4]), None);
    hb[base as usize + 4..base as usize + 8].copy_from_slice(&0xFFFF_FFF0u32.to_le_bytes());
    assert!(matches!(
        first_error(&hb),
        ReadError::Truncated { offset, block: BlockKind::EnhancedPacket, needed: 0xFFFF_FFF0, .. } if offset == base
    ));
    // Trailing length differs.
    let e = first_error(&with_block(6, &epb_body(0, 4, &READ[..4]), Some(40)));
    assert_eq!(
        e,
        ReadError::LengthMismatch {
            offset: base,
            block: BlockKind::EnhancedPacket,
            leading: 36,
            trailing: 40
        }
    );
    assert!(e.to_string().contains(&format!("at byte {base}")));
    assert!(e.to_string().contains("Enhanced Packet Block"));
    // Interface 1 never described.
    assert_eq!(
        first_error(&with_block(6, &epb_body(1, 4, &READ[..4]), None)),
        ReadError::UnknownInterface {
            offset: base,
            block: BlockKind::EnhancedPacket,
            interface: 1,
            described: 1
        }
    );
    // A simple packet before any interface.
    let mut no_if = written(&[], &[]);
    let nb = no_if.len() as u64;
    no_if.extend_from_slice(&[3, 0, 0, 0, 16, 0, 0, 0, 0, 0, 0, 0, 16, 0, 0, 0]);
    assert!(matches!(
        first_error(&no_if),
        ReadError::UnknownInterface { offset, block: BlockKind::SimplePacket, .. } if offset == nb
    ));
    // Captured length past the block; a simple packet longer than its block.
    assert_eq!(
        first_error(&with_block(6, &epb_body(0, 9, &READ), None)),
        ReadError::PacketTooLong {
            offset: base,
            block: BlockKind::EnhancedPacket,
            captured: 9,
            room: 8
        }
    );
    assert!(matches!(
        first_error(&with_block(3, &[9, 0, 0, 0, 1, 2, 3, 4], None)),
        ReadError::PacketTooLong {
            block: BlockKind::SimplePacket,
            captured: 9,
            room: 4,
            ..
        }
    ));
    // An option that overruns its block.
    let mut ob = epb_body(0, 4, &READ[..4]);
    ob.extend_from_slice(&[1, 0, 200, 0, b'x', 0, 0, 0]);
    assert_eq!(
        first_error(&with_block(6, &ob, None)),
        ReadError::BadOption {
            offset: base + 32,
            block: BlockKind::EnhancedPacket,
            code: 1,
            length: 200,
            room: 4
        }
    );
    // A block whose type is cut off.
    let mut cut = written(&[], &[rtu_iface()]);
    cut.extend_from_slice(&[6, 0]);
    assert!(matches!(
        first_error(&cut),
        ReadError::Truncated { block: BlockKind::Unreadable, offset, .. } if offset == base
    ));
}

#[test]
fn a_second_section_may_change_byte_order_and_interfaces() {
    let mut f = written(
        &[(
            PacketMeta {
                interface: 0,
                timestamp_us: 5,
                flags: 0,
                comment: None,
            },
            READ.to_vec(),
        )],
        &[rtu_iface()],
    );
    f.extend_from_slice(&pcapng_big_endian());
    let p: Vec<_> = Reader::new(&f).unwrap().collect::<Result<_, _>>().unwrap();
    assert_eq!(p.len(), 4);
    assert_eq!(p[0].timestamp_ns, Some(5_000));
    assert_eq!(p[1].timestamp_ns, Some(1_500));
}

#[test]
fn writer_errors() {
    let mut w = PcapngWriter::new(Vec::new(), APP).unwrap();
    let e = w
        .write_packet(&PacketMeta::default(), &READ)
        .expect_err("no interface yet");
    assert!(matches!(
        e,
        WriteError::NoInterface {
            interface: 0,
            described: 0
        }
    ));
    w.add_interface(&rtu_iface()).unwrap();
    let long = "x".repeat(70_000);
    let e = w
        .write_packet(
            &PacketMeta {
                comment: Some(long),
                ..PacketMeta::default()
            },
            &READ,
        )
        .expect_err("a comment over 65535 bytes");
    assert!(matches!(
        e,
        WriteError::TooLong {
            what: "an option",
            len: 70_000
        }
    ));
    // A failed packet leaves the file as it was: whole blocks only.
    let f = w.into_inner();
    assert_eq!(Reader::new(&f).unwrap().count(), 0);
    // A failing sink is an I/O error.
    struct Full;
    impl std::io::Write for Full {
        fn write(&mut self, _: &[u8]) -> std::io::Result<usize> {
            Err(std::io::Error::other("disk full"))
        }
        fn flush(&mut self) -> std::io::Result<()> {
            Ok(())
        }
    }
    assert!(matches!(
        PcapngWriter::new(Full, APP),
        Err(WriteError::Io(_))
    ));
}

#[test]
fn direction_flags() {
    assert_eq!(
        Direction::from_flags(FLAG_INBOUND | FLAG_CRC_ERROR),
        Some(Direction::Inbound)
    );
    assert_eq!(
        Direction::from_flags(FLAG_OUTBOUND),
        Some(Direction::Outbound)
    );
    assert_eq!(Direction::from_flags(0), None);
    assert_eq!(Direction::from_flags(0b11), None);
    assert_eq!(Direction::Outbound.flag(), 2);
    assert_eq!(link_type_of(crate::codec::Mode::Ascii), 148);
}

/// A stand-in for the fuzz target under plain `cargo test`: mutated captures (bytes
/// flipped, lengths set to extremes, cut, spliced) through the reader's oracle.
#[test]
fn mutated_captures_keep_every_law_of_the_oracle() {
    let frames: Vec<(PacketMeta, Vec<u8>)> = (0..6u8)
        .map(|i| {
            (
                PacketMeta {
                    interface: u32::from(i % 2),
                    timestamp_us: 1_000 * u64::from(i),
                    flags: if i % 2 == 0 {
                        FLAG_OUTBOUND
                    } else {
                        FLAG_INBOUND
                    },
                    comment: (i == 3).then(|| "damaged".to_string()),
                },
                READ[..usize::from(i) + 2].to_vec(),
            )
        })
        .collect();
    let seeds = [
        written(&frames, &[rtu_iface(), ascii_iface()]),
        pcapng_big_endian(),
        pcap(true, true, 147, &[(1, 2, &READ), (3, 4, &READ[..5])]),
        pcap(false, false, 147, &[(1, 2, &READ)]),
    ];
    let mut rng = crate::rng::Rng::new(0xCA9);
    for _ in 0..20_000 {
        let mut v = seeds[rng.below(seeds.len() as u64) as usize].clone();
        for _ in 0..=rng.below(4) {
            if v.is_empty() {
                break;
            }
            let at = rng.below(v.len() as u64) as usize;
            match rng.below(5) {
                0 => v[at] = rng.byte(),
                1 => v[at] ^= 1 << rng.below(8),
                // A length-sized field at an aligned offset set to an extreme.
                2 => {
                    let at = at & !3;
                    let x = [0u32, 1, 11, 12, 0x7FFF_FFFF, 0xFFFF_FFFF][rng.below(6) as usize];
                    let end = (at + 4).min(v.len());
                    v[at..end].copy_from_slice(&x.to_le_bytes()[..end - at]);
                }
                3 => v.truncate(at),
                _ => {
                    let tail = v[at..].to_vec();
                    v.extend_from_slice(&tail);
                }
            }
        }
        crate::oracle::capture_reader(&v);
    }
}

/// A capture's comments are anybody's text: the late mark is read back where this suite
/// wrote it, and nothing else (cut, doubled, huge or non-ASCII) panics or is misread.
#[test]
fn the_late_mark_is_read_from_what_the_suite_writes_and_from_nothing_else() {
    use std::time::Duration;
    let ours = format!(
        "check rtu.map.monitor.first: {LATE_ON_HOST}: 41250 us (the simulator on this host was due to begin it 10.0 ms after the request); as RTU: 01 03"
    );
    assert_eq!(
        late_on_host(Some(&ours)),
        Some(Duration::from_micros(41_250))
    );
    let huge = format!("{LATE_ON_HOST}: 18446744073709551615 us");
    assert_eq!(
        late_on_host(Some(&huge)),
        Some(Duration::from_micros(u64::MAX))
    );
    for other in [
        String::new(),
        LATE_ON_HOST.to_string(),
        format!("{LATE_ON_HOST}: us"),
        format!("{LATE_ON_HOST}: -5 us"),
        format!("{LATE_ON_HOST}: 18446744073709551616 us"),
        format!("{LATE_ON_HOST}: 12"),
        format!("{LATE_ON_HOST}:12 us"),
        format!("{LATE_ON_HOST}: 1é us"),
        "check rtu.bad-crc: sent with a wrong CRC on purpose".to_string(),
    ] {
        assert_eq!(late_on_host(Some(&other)), None, "{other:?}");
    }
    assert_eq!(late_on_host(None), None);
    // Every cut of ours, at a character boundary: no panic.
    for (i, _) in ours.char_indices() {
        let _ = late_on_host(Some(&ours[..i]));
    }
}

#[test]
fn a_read_errors_offset_is_read_and_moved_by_its_base() {
    let not = ReadError::NotACapture {
        found: "47494638".into(),
    };
    assert_eq!(not.offset(), 0);
    assert_eq!(not.clone().at_base(100), not);
    let cut = ReadError::Truncated {
        offset: 28,
        block: BlockKind::EnhancedPacket,
        needed: 32,
        available: 4,
    };
    assert_eq!(cut.offset(), 28);
    let moved = cut.at_base(1000);
    assert_eq!(moved.offset(), 1028);
    assert_eq!(moved.at_base(u64::MAX).offset(), u64::MAX);
}
