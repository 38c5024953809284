//! Laws of the codec, under proptest: checksums, round trips, ASCII/RTU equivalence,
//! streaming deframing and totality.

use conformance::codec::crc::{crc16_update_table, crc16_update_with, CrcBytes, CrcPath};
use conformance::codec::timing::{LineSettings, Parity};
use conformance::codec::{
    ascii_to_rtu, crc16, crc16_reference, decode_ascii, decode_ascii_unchecked, decode_rtu,
    decode_rtu_unchecked, lrc, rtu_to_ascii, AsciiDeframer, Direction, Event, FrameError,
    RtuDeframer, RtuFraming, MAX_ASCII_FRAME, MAX_RTU_FRAME,
};
use conformance::oracle::{self, OwnedMessage, OwnedPdu};
use proptest::collection::vec;
use proptest::prelude::*;

fn other_fc(direction: Direction) -> impl Strategy<Value = u8> {
    any::<u8>().prop_filter("modelled function", move |f| {
        ![0x03, 0x06, 0x08, 0x10].contains(f) && (direction == Direction::Request || *f < 0x80)
    })
}

fn arb_pdu(direction: Direction) -> BoxedStrategy<OwnedPdu> {
    let common = prop_oneof![
        (any::<u16>(), any::<u16>()).prop_map(|(r, v)| OwnedPdu::WriteSingle(r, v)),
        (any::<u16>(), vec(any::<u8>(), 0..=250)).prop_map(|(t, d)| OwnedPdu::LoopBack(t, d)),
        (other_fc(direction), vec(any::<u8>(), 0..=252)).prop_map(|(f, d)| OwnedPdu::Other(f, d)),
    ];
    match direction {
        Direction::Request => prop_oneof![
            (any::<u16>(), any::<u16>()).prop_map(|(s, c)| OwnedPdu::ReadRequest(s, c)),
            (any::<u16>(), vec(any::<u16>(), 0..=123))
                .prop_map(|(s, v)| OwnedPdu::WriteMultipleRequest(s, v)),
            common,
        ]
        .boxed(),
        Direction::Response => prop_oneof![
            vec(any::<u16>(), 0..=125).prop_map(OwnedPdu::ReadResponse),
            (any::<u16>(), any::<u16>()).prop_map(|(s, c)| OwnedPdu::WriteMultipleResponse(s, c)),
            (0u8..0x80, any::<u8>()).prop_map(|(f, c)| OwnedPdu::Exception(f, c)),
            common,
        ]
        .boxed(),
    }
}

fn arb_direction() -> impl Strategy<Value = Direction> {
    prop_oneof![Just(Direction::Request), Just(Direction::Response)]
}

fn arb_built() -> impl Strategy<Value = (Direction, OwnedMessage)> {
    arb_direction().prop_flat_map(|d| {
        (Just(d), any::<u8>(), arb_pdu(d)).prop_map(|(d, a, p)| {
            (
                d,
                OwnedMessage::new(a, p, d).expect("generated for its direction"),
            )
        })
    })
}

/// Response frames whose length the RTU deframer can infer (for streaming laws).
fn arb_framable_response() -> impl Strategy<Value = Vec<u8>> {
    (
        any::<u8>(),
        prop_oneof![
            vec(any::<u16>(), 0..=125).prop_map(OwnedPdu::ReadResponse),
            (any::<u16>(), any::<u16>()).prop_map(|(s, c)| OwnedPdu::WriteMultipleResponse(s, c)),
            (0u8..0x80, any::<u8>()).prop_map(|(f, c)| OwnedPdu::Exception(f, c)),
            (any::<u16>(), any::<u16>()).prop_map(|(r, v)| OwnedPdu::WriteSingle(r, v)),
            (any::<u16>(), vec(any::<u8>(), 2..=2)).prop_map(|(t, d)| OwnedPdu::LoopBack(t, d)),
        ],
    )
        .prop_map(|(a, p)| {
            OwnedMessage::new(a, p, Direction::Response)
                .unwrap()
                .message()
                .to_rtu_vec()
                .unwrap()
        })
}

fn collect_frames(events: &mut Vec<(u8, Vec<u8>)>) -> impl FnMut(Event<'_>) + '_ {
    move |e| {
        let tag = match e {
            Event::Frame(_) => 0,
            Event::Corrupt(_) => 1,
            Event::Incomplete(_) => 2,
            Event::Garbage(_) => 3,
        };
        // Adjacent garbage events are merged: how garbage is split is not a promise.
        if let (3, Some((3, prev))) = (tag, events.last_mut()) {
            prev.extend_from_slice(e.bytes());
            return;
        }
        events.push((tag, e.bytes().to_vec()));
    }
}

/// Cuts `data` at the given fractions into chunks.
fn chunked(data: &[u8], cuts: &[usize]) -> Vec<Vec<u8>> {
    let mut points: Vec<usize> = cuts.iter().map(|c| c % (data.len() + 1)).collect();
    points.push(0);
    points.push(data.len());
    points.sort_unstable();
    points.dedup();
    points
        .windows(2)
        .map(|w| data[w[0]..w[1]].to_vec())
        .collect()
}

proptest! {
    // 1024 cases a law by default (the whole file runs in about a second); more with
    // PROPTEST_CASES=N.
    #![proptest_config(ProptestConfig::with_cases(
        std::env::var("PROPTEST_CASES").ok().and_then(|s| s.parse().ok()).unwrap_or(1024)
    ))]

    // 1. CRC.
    #[test]
    fn fast_crc_equals_reference(data in vec(any::<u8>(), 0..600)) {
        prop_assert_eq!(crc16(&data), crc16_reference(&data));
    }

    /// Every path this CPU can run, forced, from any register value, whole and in two
    /// pieces, up to 2100 bytes (past every threshold and loop of the SIMD paths).
    #[test]
    fn every_crc_path_equals_reference(
        data in vec(any::<u8>(), 0..=2100),
        init in any::<u16>(),
        cut in any::<usize>(),
    ) {
        let want = crc16_update_table(init, &data);
        if init == 0xFFFF {
            prop_assert_eq!(want, crc16_reference(&data));
        }
        let (a, b) = data.split_at(cut % (data.len() + 1));
        for path in CrcPath::supported() {
            prop_assert_eq!(crc16_update_with(path, init, &data), Some(want), "{}", path.name());
            let pieces = crc16_update_with(path, init, a)
                .and_then(|c| crc16_update_with(path, c, b));
            prop_assert_eq!(pieces, Some(want), "{} in pieces", path.name());
        }
        for path in CrcPath::ALL.into_iter().filter(|p| !p.available()) {
            prop_assert_eq!(crc16_update_with(path, init, &data), None);
        }
    }

    #[test]
    fn crc_residue_and_error_detection(
        (_, b) in arb_built(),
        bit in any::<prop::sample::Index>(),
        burst_len in 1usize..=16,
        pattern in any::<u16>(),
    ) {
        let frame = b.message().to_rtu_vec().unwrap();
        prop_assert_eq!(crc16(&frame), 0, "residue of a frame with its CRC appended is zero");
        let bits = frame.len() * 8;
        // Single-bit flip.
        let i = bit.index(bits);
        let mut flipped = frame.clone();
        flipped[i / 8] ^= 1 << (i % 8);
        prop_assert_ne!(crc16(&flipped), 0);
        prop_assert!(decode_rtu(&flipped, Direction::Request).is_err() && decode_rtu(&flipped, Direction::Response).is_err());
        // Burst of up to 16 bits: first and last bit of the burst set.
        let len = burst_len.min(bits);
        let start = bit.index(bits - len + 1);
        let mut mask = u32::from(pattern) & ((1u32 << len) - 1);
        mask |= 1 | (1 << (len - 1));
        let mut burst = frame.clone();
        for k in 0..len {
            if mask >> k & 1 == 1 {
                let p = start + k;
                burst[p / 8] ^= 1 << (p % 8);
            }
        }
        prop_assert_ne!(crc16(&burst), 0, "burst of {} bits at bit {}", len, start);
    }

    // 2. LRC.
    #[test]
    fn lrc_makes_sum_zero(data in vec(any::<u8>(), 0..300)) {
        let sum = data.iter().fold(lrc(&data), |s, &b| s.wrapping_add(b));
        prop_assert_eq!(sum, 0);
    }

    #[test]
    fn lrc_detects_any_single_byte_change((dir, b) in arb_built(), at in any::<prop::sample::Index>(), new in any::<u8>()) {
        let frame = b.message().to_ascii_vec().unwrap();
        let i = at.index(frame.len());
        prop_assume!(frame[i] != new);
        let mut changed = frame.clone();
        changed[i] = new;
        let mut s = [0u8; MAX_RTU_FRAME];
        match decode_ascii(&changed, dir, &mut s) {
            Err(_) => {}
            Ok(m) => {
                // Only a change of letter case keeps a valid frame, and the same message.
                prop_assert!(frame[i].eq_ignore_ascii_case(&new), "byte {} changed {:02X} -> {:02X} undetected", i, frame[i], new);
                prop_assert_eq!(m, b.message());
            }
        }
    }

    // 3. Round trips.
    #[test]
    fn round_trip_rtu((dir, b) in arb_built()) {
        let m = b.message();
        let frame = m.to_rtu_vec().unwrap();
        prop_assert_eq!(frame.len(), m.rtu_len());
        prop_assert_eq!(decode_rtu(&frame, dir).unwrap(), m);
    }

    #[test]
    fn round_trip_ascii((dir, b) in arb_built()) {
        let m = b.message();
        let frame = m.to_ascii_vec().unwrap();
        prop_assert_eq!(frame.len(), m.ascii_len());
        prop_assert!(frame.len() <= MAX_ASCII_FRAME);
        let mut s = [0u8; MAX_RTU_FRAME];
        prop_assert_eq!(decode_ascii(&frame, dir, &mut s).unwrap(), m);
    }

    #[test]
    fn round_trip_oracle((dir, b) in arb_built()) {
        oracle::roundtrip(&b, dir);
    }

    // 4. ASCII/RTU equivalence.
    #[test]
    fn ascii_and_rtu_are_equivalent((dir, b) in arb_built()) {
        let m = b.message();
        let rtu = m.to_rtu_vec().unwrap();
        let ascii = m.to_ascii_vec().unwrap();
        let mut s = [0u8; MAX_RTU_FRAME];
        prop_assert_eq!(decode_ascii(&ascii, dir, &mut s).unwrap(), decode_rtu(&rtu, dir).unwrap());
        let mut a = [0u8; MAX_ASCII_FRAME];
        let n = rtu_to_ascii(&rtu, &mut a).unwrap();
        prop_assert_eq!(&a[..n], &ascii[..]);
        let mut r = [0u8; MAX_RTU_FRAME];
        let k = ascii_to_rtu(&a[..n], &mut r).unwrap();
        prop_assert_eq!(&r[..k], &rtu[..]);
        let k = ascii_to_rtu(&ascii, &mut r).unwrap();
        let n = rtu_to_ascii(&r[..k], &mut a).unwrap();
        prop_assert_eq!(&a[..n], &ascii[..]);
    }

    // 5. Streaming.
    #[test]
    fn rtu_stream_recovers_every_frame(
        parts in vec((vec(any::<u8>(), 0..12), arb_framable_response()), 1..8),
        cuts in vec(any::<usize>(), 0..20),
    ) {
        let mut stream = Vec::new();
        let mut want = Vec::new();
        for (garbage, frame) in &parts {
            stream.extend_from_slice(garbage);
            stream.extend_from_slice(frame);
            want.push(frame.clone());
        }
        let mut whole = Vec::new();
        {
            let mut d = RtuDeframer::new(Direction::Response, RtuFraming::ByLength);
            d.push(&stream, collect_frames(&mut whole));
            d.flush(collect_frames(&mut whole));
        }
        let mut pieces = Vec::new();
        {
            let mut d = RtuDeframer::new(Direction::Response, RtuFraming::ByLength);
            for c in chunked(&stream, &cuts) {
                d.push(&c, collect_frames(&mut pieces));
            }
            d.flush(collect_frames(&mut pieces));
        }
        prop_assert_eq!(&whole, &pieces, "chunking changed the events");
        let total: usize = whole.iter().map(|(_, b)| b.len()).sum();
        prop_assert_eq!(total, stream.len(), "every byte is reported once");
        // Where each frame was found. Random garbage can hold a CRC-valid frame by chance
        // (about 1 in 131072 positions for a 5-byte exception frame): that is a real frame
        // to any deframer; such cases are discarded, after checking its checksum.
        let mut at = 0;
        let mut found = Vec::new();
        for (tag, bytes) in &whole {
            if *tag == 0 {
                prop_assert!(decode_rtu_unchecked(bytes, Direction::Response).unwrap().checksum.is_valid());
                found.push((at, bytes.clone()));
            }
            at += bytes.len();
        }
        let mut at = 0;
        let mut placed = Vec::new();
        for (garbage, frame) in &parts {
            at += garbage.len();
            placed.push((at, frame.clone()));
            at += frame.len();
        }
        prop_assume!(found.iter().all(|f| placed.contains(f)), "garbage held a valid frame");
        prop_assert_eq!(found, placed);
        prop_assert_eq!(total, stream.len(), "every byte is reported once");
    }

    #[test]
    fn rtu_stream_by_silence(frames in vec(arb_framable_response(), 1..6), gaps in vec(5_100u64..50_000, 6)) {
        let line = LineSettings::new(9600, 8, Parity::Even, 1);
        let mut d = RtuDeframer::new(Direction::Response, RtuFraming::BySilence(line));
        let mut ev = Vec::new();
        let mut now = 0;
        for (f, gap) in frames.iter().zip(&gaps) {
            // Gaps are measured from the previous frame's last burst (1 ms after its first):
            // at least 4.1 ms of silence, over t3.5 (4011 us).
            now += gap;
            // Each frame arrives in two bursts 1 ms apart: within t1.5 at 9600 8E1.
            let mid = f.len() / 2;
            d.push_at(now, &f[..mid], collect_frames(&mut ev));
            d.push_at(now + 1_000, &f[mid..], collect_frames(&mut ev));
        }
        d.flush(collect_frames(&mut ev));
        let got: Vec<Vec<u8>> = ev.iter().map(|(t, b)| { assert_eq!(*t, 0); b.clone() }).collect();
        prop_assert_eq!(got, frames);
    }

    #[test]
    fn ascii_stream_recovers_every_frame(
        parts in vec((vec(any::<u8>(), 0..12), arb_built()), 1..6),
        cuts in vec(any::<usize>(), 0..20),
    ) {
        let mut stream = Vec::new();
        let mut want = Vec::new();
        for (garbage, (_, b)) in &parts {
            stream.extend_from_slice(garbage);
            let f = b.message().to_ascii_vec().unwrap();
            stream.extend_from_slice(&f);
            want.push(f);
        }
        let mut whole = Vec::new();
        {
            let mut d = AsciiDeframer::default();
            d.push(&stream, collect_frames(&mut whole));
            d.flush(collect_frames(&mut whole));
        }
        let mut pieces = Vec::new();
        {
            let mut d = AsciiDeframer::default();
            for c in chunked(&stream, &cuts) {
                d.push(&c, collect_frames(&mut pieces));
            }
            d.flush(collect_frames(&mut pieces));
        }
        prop_assert_eq!(&whole, &pieces);
        let frames: Vec<Vec<u8>> = whole.iter().filter(|(t, _)| *t == 0).map(|(_, b)| b.clone()).collect();
        for f in &frames {
            let mut s = [0u8; MAX_RTU_FRAME];
            prop_assert!(decode_ascii_unchecked(f, Direction::Request, &mut s).map(|u| u.checksum.is_valid()).unwrap_or(true));
        }
        prop_assert_eq!(frames, want);
    }

    // 6. Totality.
    #[test]
    fn parsers_are_total(data in vec(any::<u8>(), 0..600), dir in arb_direction()) {
        let _ = decode_rtu(&data, dir);
        let _ = decode_rtu_unchecked(&data, dir);
        let mut s = [0u8; MAX_RTU_FRAME];
        let _ = decode_ascii(&data, dir, &mut s);
        let mut s = [0u8; MAX_RTU_FRAME];
        let _ = decode_ascii_unchecked(&data, dir, &mut s);
        let mut a = [0u8; MAX_ASCII_FRAME];
        let _ = rtu_to_ascii(&data, &mut a);
        let mut r = [0u8; MAX_RTU_FRAME];
        let _ = ascii_to_rtu(&data, &mut r);
        let mut d = RtuDeframer::new(dir, RtuFraming::ByLength);
        d.push(&data, |_| {});
        d.flush(|_| {});
        let mut a = AsciiDeframer::default();
        a.push(&data, |_| {});
        a.flush(|_| {});
    }

    #[test]
    fn ascii_frames_of_random_hex_are_total(body in vec(any::<u8>(), 0..260), dir in arb_direction(), lower in any::<bool>()) {
        // Well-delimited frames with random content reach deeper than random bytes.
        let mut f = vec![b':'];
        for b in &body {
            let s = format!("{b:02X}");
            f.extend_from_slice(if lower { s.to_lowercase() } else { s }.as_bytes());
        }
        f.extend_from_slice(b"\r\n");
        let mut s = [0u8; MAX_RTU_FRAME];
        let _ = decode_ascii_unchecked(&f, dir, &mut s);
    }

    #[test]
    fn rtu_frames_with_valid_crc_are_total(body in vec(any::<u8>(), 0..256), dir in arb_direction()) {
        let mut f = body.clone();
        f.extend_from_slice(&CrcBytes::of(&body).wire());
        match decode_rtu(&f, dir) {
            Ok(m) => prop_assert_eq!(m.to_rtu_vec().unwrap(), f),
            Err(e) => {
                let crc_error = matches!(e, FrameError::CrcMismatch { .. });
                prop_assert!(!crc_error, "valid CRC reported as mismatch: {}", e);
            }
        }
    }
}
