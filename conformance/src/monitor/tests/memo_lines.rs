//! The memo and the live lines change no verdict, and the memo stays bounded.

use super::*;

/// Without live lines (`--quiet` and no `--log`) the verdicts and statistics are the
/// same; only the lines are not made.
#[test]
fn without_live_lines_the_verdicts_are_the_same() {
    let steps: Vec<(u64, Vec<u8>)> = vec![
        (0, read(1, 0x2520, 1)),
        (15, values(1, &[1])),
        (100, read(1, 0x2530, 1)),
        (115, exception(1, 3, 3)),
        (300, write(1, 0x2502, 100)),
    ];
    let heard = |live: bool| {
        let mut m = monitor(Mode::Rtu, &[1]);
        m.set_live(live);
        let frames: Vec<(u64, &[u8])> = steps.iter().map(|(t, f)| (*t, &f[..])).collect();
        let lines = run(&mut m, &frames);
        (
            kinds(&m, 1),
            m.nodes()[&1].exchanges,
            m.deviations(),
            lines.len(),
        )
    };
    let (k, n, d, lines) = heard(true);
    assert_eq!(lines, 3);
    assert!(
        d > 0 && k.contains(&"drive.wrong-exception".to_string()),
        "{k:?}"
    );
    assert_eq!(heard(false), (k, n, d, 0));
}

/// The memo changes no verdict: the same traffic judged with it and without gives the
/// same lines, statistics, findings, citations, examples and results.
#[test]
fn the_memo_changes_no_verdict() {
    let steps = varied_traffic(6);
    let frames: Vec<(u64, &[u8])> = steps.iter().map(|(t, f)| (*t, &f[..])).collect();
    for live in [true, false] {
        let judged = |memo: bool| {
            let mut m = monitor(Mode::Rtu, &[1]);
            m.set_live(live);
            m.set_memo(memo);
            let lines = run(&mut m, &frames);
            let held = (m.requests_memo.len(), m.verdicts_memo.len());
            (
                everything(&m, &lines),
                kinds(&m, 1),
                held,
                m.nodes()[&1].exchanges,
            )
        };
        let (with, k, held, exchanges) = judged(true);
        let (without, _, none, _) = judged(false);
        assert_eq!(none, (0, 0));
        // The memo was used: far fewer kinds of exchange than exchanges.
        assert!(held.0 > 0 && held.1 > 0, "{held:?}");
        assert!((held.1 as u64) < exchanges / 2, "{held:?} {exchanges}");
        // The traffic is as varied as it says.
        for want in [
            "drive.wrong-value",
            "drive.wrong-exception",
            "drive.wrong-address",
            "drive.late-reply",
            "drive.bad-checksum",
            "drive.extra-bytes",
            "drive.no-reply",
            "drive.unexpected-reply",
            "drive.decision",
            "master.no-t3.5",
            "master.retry",
            "master.request-before-reply",
            "master.bad-checksum",
            "master.function-not-served",
        ] {
            assert!(k.contains(&want.to_string()), "{want} not in {k:?}");
        }
        assert!(with == without, "live {live}:\n{with}\n---\n{without}");
    }
    // ASCII too.
    let req = ascii_read(1, 0x2530, 1);
    let ok = ascii_exception(1, 3, 2);
    let wrong = ascii_exception(1, 3, 3);
    let mut bad = ok.clone();
    let n = bad.len();
    bad.swap(n - 3, n - 4);
    let ascii: Vec<(u64, &[u8])> = (0..5u64)
        .flat_map(|c| {
            [
                (c * 1000, &req[..]),
                (c * 1000 + 40, &ok[..]),
                (c * 1000 + 200, &req[..]),
                (c * 1000 + 240, &wrong[..]),
                (c * 1000 + 400, &req[..]),
                (c * 1000 + 440, &bad[..]),
            ]
        })
        .collect();
    let judged = |memo: bool| {
        let mut m = monitor(Mode::Ascii, &[1]);
        m.set_memo(memo);
        let lines = run(&mut m, &ascii);
        everything(&m, &lines)
    };
    assert!(judged(true) == judged(false));
}

/// The memos stay bounded however many kinds of exchange the bus carries.
#[test]
fn the_memo_stays_bounded() {
    let mut m = monitor(Mode::Rtu, &[1]);
    let r = read(1, 0x2520, 1);
    let n = memo::MEMO_ENTRIES as u64 + 500;
    for i in 0..n {
        m.feed(ms(i * 50), &r);
        // A different value each time: a different exchange.
        m.feed(ms(i * 50 + 15), &values(1, &[i as u16]));
        assert!(m.verdicts_memo.len() <= memo::MEMO_ENTRIES);
    }
    m.finish();
    assert_eq!(m.nodes()[&1].exchanges, n);
    assert!(m.verdicts_memo.len() <= memo::MEMO_ENTRIES);
    assert_eq!(m.requests_memo.len(), 1);
}
