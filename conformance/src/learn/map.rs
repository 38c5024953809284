//! The register map: which registers of 0000H..FFFFH the device serves to 03H, found with
//! a bounded number of multi-register reads.
//!
//! A device may refuse any read that spans one register it does not serve (pymodbus,
//! libmodbus, TECO's drives), so a refused read of many registers says only "not all of
//! these". The search therefore:
//! 1. samples one register every `stride` registers (a single read), where nothing is
//!    known yet: the only cost of empty space;
//! 2. at a sample that answers, finds the block's first register by reading from
//!    candidates below it up to the sample (a binary search: a read answers exactly when
//!    it starts inside the block);
//! 3. grows the block with reads of the largest count (the read limit, 125 until a
//!    smaller one shows), each starting at the last register known, so that a read that
//!    answers proves its registers are one block with it;
//! 4. where such a read is refused, finds the last register it answers up to (a binary
//!    search), then reads the next register alone: refused, the block ends; answered,
//!    either the device's read limit was hit (the same count shifted by one answers) or
//!    a new block starts there that the device will not read together with this one (a
//!    "same group" rule, as TECO's drives have).
//!
//! Cost: one read a stride of empty space, and for each block about its length over the
//! read limit plus two binary searches. A block shorter than the stride that lies between
//! two sample points is not found; `stride` 1 finds everything at one read a register.

use std::collections::{BTreeMap, BTreeSet};

use super::ask::{registers, Answer, Asker, Evidence};
use super::LearnError;

/// The largest 03H count the Modbus application protocol allows (V1.1b3, 6.3).
pub const SPEC_READ_LIMIT: u16 = 125;

/// What to search.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct MapConfig {
    /// First register of the range.
    pub first: u16,
    /// Last register of the range.
    pub last: u16,
    /// Registers between two sample points.
    pub stride: u16,
}

impl Default for MapConfig {
    fn default() -> Self {
        MapConfig {
            first: 0,
            last: 0xFFFF,
            stride: 16,
        }
    }
}

/// A run of registers that one read may cover.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Block {
    /// First register.
    pub first: u16,
    /// Last register.
    pub last: u16,
    /// The read that answered up to `last`.
    pub shown_by: Evidence,
    /// Whether the register before `first` was shown not to be read with it (else the
    /// block was cut by the range searched).
    pub start_shown: bool,
    /// Whether the register after `last` was shown not to be read with it (else the
    /// search stopped there: the range's end, the request cap, Ctrl-C).
    pub end_shown: bool,
}

/// What the map search found, filled in as it goes (an interrupted search leaves what it
/// had).
#[derive(Debug, Clone, Default)]
pub struct MapFound {
    /// Blocks, in order.
    pub blocks: Vec<Block>,
    /// The last register the search has classified, if any.
    pub searched_to: Option<u16>,
    /// Whether the whole range was searched.
    pub complete: bool,
    /// The device's read limit where it showed: a count it answers, and the read of one
    /// more that it refused although every register of it is served.
    pub limit: Option<(u16, Evidence)>,
    /// The largest read answered, and that read.
    pub largest: Option<(u16, Evidence)>,
    /// The first single-register read refused: its register, answer and exchange.
    pub miss: Option<(u16, Answer, Evidence)>,
    /// A read across two served blocks that was refused: the first register of the
    /// second block, the answer, and the read.
    pub split: Option<(u16, Answer, Evidence)>,
    /// Every value read (the first time it was read).
    pub values: BTreeMap<u16, u16>,
    /// Registers read twice with different values.
    pub changed: BTreeSet<u16>,
    /// Requests the search made.
    pub requests: u64,
}

struct Search<'s, 'a> {
    ask: &'s mut Asker<'a>,
    cfg: MapConfig,
    found: &'s mut MapFound,
    /// The read limit in use.
    window: u16,
    /// Whether `window` is the device's (shown) rather than the protocol's.
    window_shown: bool,
}

/// Searches `cfg`'s range, filling `found` as it goes.
pub fn search(ask: &mut Asker<'_>, cfg: MapConfig, found: &mut MapFound) -> Result<(), LearnError> {
    let before = ask.requests();
    let mut s = Search {
        ask,
        cfg: MapConfig {
            stride: cfg.stride.max(1),
            ..cfg
        },
        found,
        window: SPEC_READ_LIMIT,
        window_shown: false,
    };
    let r = s.run();
    s.found.requests = s.ask.requests() - before;
    r
}

impl Search<'_, '_> {
    /// Reads `count` registers from `start`: their values, or None where refused.
    fn read(
        &mut self,
        start: u16,
        count: u16,
    ) -> Result<(Option<Vec<u16>>, Answer, Evidence), LearnError> {
        let node = self.ask.node();
        let [sh, sl] = start.to_be_bytes();
        let [ch, cl] = count.to_be_bytes();
        let (answer, ev) = self.ask.ask(&[node, 0x03, sh, sl, ch, cl], true)?;
        let values = match &answer {
            Answer::Data(d) => registers(d, count),
            _ => None,
        };
        match &values {
            Some(v) => {
                for (i, &x) in v.iter().enumerate() {
                    let r = start.wrapping_add(i as u16);
                    match self.found.values.get(&r) {
                        Some(&old) if old != x => {
                            self.found.changed.insert(r);
                        }
                        Some(_) => {}
                        None => {
                            self.found.values.insert(r, x);
                        }
                    }
                }
                if self.found.largest.as_ref().is_none_or(|(n, _)| count > *n) {
                    self.found.largest = Some((count, ev.clone()));
                }
                if count >= SPEC_READ_LIMIT && !self.window_shown {
                    self.window_shown = true;
                }
            }
            None if count == 1 && self.found.miss.is_none() => {
                self.found.miss = Some((start, answer.clone(), ev.clone()));
            }
            None => {}
        }
        Ok((values, answer, ev))
    }

    fn classified(&mut self, r: u16) {
        if self.found.searched_to.is_none_or(|s| r > s) {
            self.found.searched_to = Some(r);
        }
    }

    fn samples_left(&self, from: u32) -> u64 {
        let last = u32::from(self.cfg.last);
        if from > last {
            0
        } else {
            u64::from((last - from) / u32::from(self.cfg.stride) + 1)
        }
    }

    /// The first sample point at or after `r`.
    fn next_sample(&self, r: u32) -> u32 {
        let first = u32::from(self.cfg.first);
        let s = u32::from(self.cfg.stride);
        first + (r.saturating_sub(first)).div_ceil(s) * s
    }

    fn run(&mut self) -> Result<(), LearnError> {
        let last = u32::from(self.cfg.last);
        // Registers below `floor` are classified: unserved, or in a block found.
        let mut floor = u32::from(self.cfg.first);
        let mut p = floor;
        // A register known to be served and to start a block (after a split).
        let mut known_start: Option<u16> = None;
        while p <= last {
            self.ask.left = self.samples_left(p) + 8;
            let (start, start_shown) = match known_start.take() {
                Some(s) => (s, true),
                None => {
                    self.ask.doing = format!("map: sampling {p:04X}H");
                    let r = p as u16;
                    let (v, ..) = self.read(r, 1)?;
                    self.classified(r);
                    if v.is_none() {
                        floor = p + 1;
                        p += u32::from(self.cfg.stride);
                        continue;
                    }
                    self.ask.doing = format!("map: the start of the block at {p:04X}H");
                    self.find_start(floor as u16, r)?
                }
            };
            let (end, next) = self.grow(start, start_shown)?;
            match next {
                Some(n) => {
                    known_start = Some(n);
                    p = u32::from(n);
                }
                None => {
                    floor = u32::from(end) + 2;
                    p = self.next_sample(floor);
                }
            }
        }
        self.found.complete = true;
        Ok(())
    }

    /// The first register of the block around `p` (served), not below `floor`; and
    /// whether the one below it was shown apart.
    fn find_start(&mut self, floor: u16, p: u16) -> Result<(u16, bool), LearnError> {
        // Registers s..=p are one block; each read below reaches up to s (at most the
        // read limit), so that an answer proves its registers are one block with s.
        let mut s = p;
        loop {
            if s == floor {
                // Below the floor lies a register shown not served, except at the range's
                // first register.
                return Ok((s, s != self.cfg.first));
            }
            let lo = floor.max(s.saturating_sub(self.window - 1));
            if self.read(lo, s - lo + 1)?.0.is_some() {
                s = lo;
                continue;
            }
            // The smallest m in (lo, s] whose read up to s answers.
            let (mut bad, mut good) = (lo, s);
            while good - bad > 1 {
                let mid = bad + (good - bad) / 2;
                if self.read(mid, s - mid + 1)?.0.is_some() {
                    good = mid;
                } else {
                    bad = mid;
                }
            }
            return Ok((good, true));
        }
    }

    /// Grows the block from `start` (served): its last register, and the first of a next
    /// block that starts right after it, if one does.
    fn grow(&mut self, start: u16, start_shown: bool) -> Result<(u16, Option<u16>), LearnError> {
        self.found.blocks.push(Block {
            first: start,
            last: start,
            shown_by: Evidence::default(),
            start_shown,
            end_shown: false,
        });
        let mut e = start;
        self.classified(e);
        loop {
            self.ask.doing = format!("map: the block from {start:04X}H, at {e:04X}H");
            self.ask.left = self.samples_left(u32::from(e) + 1) + 8;
            if e == self.cfg.last {
                return Ok((e, None));
            }
            let n =
                (u32::from(self.cfg.last) - u32::from(e) + 1).min(u32::from(self.window)) as u16;
            let (v, a, ev) = self.read(e, n)?;
            if v.is_some() {
                e += n - 1;
                self.extend(e, ev);
                continue;
            }
            // The last register a read from `e` answers up to: read(e, k) answers for
            // k <= good and is refused from `bad` on.
            let (mut good, mut bad) = (1u16, n);
            let mut refused = ev;
            let mut refused_answer = a;
            while bad - good > 1 {
                let mid = good + (bad - good) / 2;
                let (v, a, ev) = self.read(e, mid)?;
                if v.is_some() {
                    good = mid;
                    self.extend(e + mid - 1, ev);
                } else {
                    bad = mid;
                    refused = ev;
                    refused_answer = a;
                }
            }
            let end = e + good - 1;
            if good == n || end == self.cfg.last {
                return Ok((end, None));
            }
            let (next, ..) = self.read(end + 1, 1)?;
            self.classified(end + 1);
            if next.is_none() {
                self.close();
                return Ok((end, None));
            }
            // end + 1 is served. The read limit, or a block of its own?
            if !self.window_shown && good >= 2 {
                let (v, _, ev) = self.read(e + 1, good)?;
                if v.is_some() {
                    self.window = good;
                    self.window_shown = true;
                    self.found.limit = Some((good, refused));
                    e = end + 1;
                    self.extend(e, ev);
                    continue;
                }
            }
            if self.found.split.is_none() {
                self.found.split = Some((end + 1, refused_answer, refused));
            }
            self.close();
            return Ok((end, Some(end + 1)));
        }
    }

    fn extend(&mut self, last: u16, ev: Evidence) {
        if let Some(b) = self.found.blocks.last_mut() {
            if last >= b.last {
                b.last = last;
                b.shown_by = ev;
            }
        }
        self.classified(last);
    }

    fn close(&mut self) {
        if let Some(b) = self.found.blocks.last_mut() {
            b.end_shown = true;
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;
    use crate::codec::{frame_of_body, frame_parts, Mode};
    use crate::learn::ask::{Device, Heard};
    use crate::transport::TransportError;
    use std::sync::atomic::AtomicBool;

    /// A device with holding-register blocks, a read limit and, like TECO's drives, no
    /// read across two blocks when `same_group`: exception 02H for a register it does
    /// not serve or a read across blocks, 03H for a count over its limit.
    pub(crate) struct Fake {
        pub blocks: Vec<(u16, u16)>,
        pub limit: u16,
        pub same_group: bool,
        pub node: u8,
        pub asked: u64,
        /// Answers requests to every node (the broadcast too) with exception 04H, at
        /// once, as pymodbus's serial server does for a node it does not have.
        pub answers_everyone: Option<std::time::Duration>,
    }

    impl Fake {
        pub(crate) fn new(blocks: &[(u16, u16)], limit: u16, same_group: bool) -> Fake {
            Fake {
                blocks: blocks.to_vec(),
                limit,
                same_group,
                node: 1,
                asked: 0,
                answers_everyone: None,
            }
        }

        fn block_of(&self, r: u32) -> Option<usize> {
            self.blocks
                .iter()
                .position(|&(a, b)| u32::from(a) <= r && r <= u32::from(b))
        }

        fn answer(&self, body: &[u8]) -> Option<Vec<u8>> {
            let (&node, rest) = body.split_first()?;
            if node != self.node {
                return self
                    .answers_everyone
                    .and_then(|_| Some(vec![node, rest.first()? | 0x80, 0x04]));
            }
            match rest {
                [0x03, sh, sl, ch, cl] => {
                    let start = u32::from(u16::from_be_bytes([*sh, *sl]));
                    let count = u32::from(u16::from_be_bytes([*ch, *cl]));
                    if count == 0 || count > u32::from(self.limit) {
                        return Some(vec![node, 0x83, 0x03]);
                    }
                    let first = self.block_of(start);
                    for r in start..start + count {
                        let b = self.block_of(r);
                        if b.is_none() || (self.same_group && b != first) {
                            return Some(vec![node, 0x83, 0x02]);
                        }
                    }
                    let mut out = vec![node, 0x03, (2 * count) as u8];
                    for r in start..start + count {
                        out.extend_from_slice(&((r as u16) ^ 0x5A5A).to_be_bytes());
                    }
                    Some(out)
                }
                [0x08, data @ ..] => Some([&[node, 0x08][..], data].concat()),
                [f, ..] => Some(vec![node, f | 0x80, 0x01]),
                [] => None,
            }
        }
    }

    impl Device for Fake {
        fn mode(&self) -> Mode {
            Mode::Rtu
        }

        fn exchange(&mut self, frame: &[u8], _expect: bool) -> Result<Heard, TransportError> {
            self.asked += 1;
            let body = frame_parts(Mode::Rtu, frame)
                .ok()
                .filter(|p| p.checksum.is_valid())
                .map(|p| p.body);
            let to_other = body.as_ref().is_some_and(|b| b[0] != self.node);
            let reply = body
                .and_then(|b| self.answer(&b))
                .map(|b| frame_of_body(Mode::Rtu, &b).unwrap());
            let latency = match self.answers_everyone {
                Some(t) if to_other => t,
                _ => std::time::Duration::from_millis(3),
            };
            Ok(Heard {
                request: frame.to_vec(),
                reply,
                stray: 0,
                latency: Some(latency),
            })
        }
    }

    pub(crate) fn run(
        fake: &mut Fake,
        cfg: MapConfig,
        max: u64,
    ) -> (MapFound, Result<(), LearnError>) {
        let stop = AtomicBool::new(false);
        let mut progress = |_: crate::learn::ask::Progress<'_>| {};
        let mut ask = Asker::new(fake, 1, &stop, max, &mut progress);
        let mut found = MapFound::default();
        let r = search(&mut ask, cfg, &mut found);
        (found, r)
    }

    fn spans(f: &MapFound) -> Vec<(u16, u16)> {
        f.blocks.iter().map(|b| (b.first, b.last)).collect()
    }

    #[test]
    fn blocks_longer_than_the_stride_are_found_with_their_edges() {
        let blocks = [(0x0000, 0x0FFF), (0x2500, 0x252F)];
        let mut fake = Fake::new(&blocks, 125, false);
        let (f, r) = run(&mut fake, MapConfig::default(), 100_000);
        r.unwrap();
        assert!(f.complete);
        assert_eq!(spans(&f), blocks);
        assert!(f.blocks.iter().all(|b| b.end_shown));
        assert_eq!(f.largest.as_ref().unwrap().0, 125);
        // One read a stride of empty space, and few for the blocks: far from one a register.
        assert!(f.requests < 65536 / 16 + 120, "{} requests", f.requests);
        assert_eq!(f.miss.as_ref().unwrap().1, Answer::Exception(2));
        assert!(f.split.is_none());
    }

    #[test]
    fn a_read_limit_and_same_group_blocks_as_teco_drives_have() {
        // The F510's first parameter group, a group that starts off the sample grid, and
        // its command and monitor blocks, which it never reads together.
        let blocks = [
            (0x0000, 0x0038),
            (0x0103, 0x0126),
            (0x2500, 0x251F),
            (0x2520, 0x252F),
        ];
        let mut fake = Fake::new(&blocks, 37, true);
        let (f, r) = run(
            &mut fake,
            MapConfig {
                first: 0,
                last: 0x2FFF,
                stride: 16,
            },
            100_000,
        );
        r.unwrap();
        assert_eq!(spans(&f), blocks);
        assert_eq!(f.limit.as_ref().unwrap().0, 37);
        assert_eq!(f.largest.as_ref().unwrap().0, 37);
        let (at, answer, _) = f.split.clone().unwrap();
        assert_eq!((at, answer), (0x2520, Answer::Exception(2)));
        assert!(f.blocks[3].start_shown);
    }

    #[test]
    fn a_block_between_sample_points_is_missed_unless_the_stride_is_small() {
        let blocks = [(0x0221, 0x0222)];
        let mut fake = Fake::new(&blocks, 125, false);
        let cfg = MapConfig {
            first: 0x0200,
            last: 0x02FF,
            stride: 16,
        };
        let (f, _) = run(&mut fake, cfg, 10_000);
        assert!(f.blocks.is_empty());
        let (f, _) = run(&mut fake, MapConfig { stride: 1, ..cfg }, 10_000);
        assert_eq!(spans(&f), blocks);
    }

    #[test]
    fn a_device_serving_everything_costs_one_read_a_window() {
        let mut fake = Fake::new(&[(0x0000, 0xFFFF)], 125, false);
        let (f, r) = run(&mut fake, MapConfig::default(), 100_000);
        r.unwrap();
        assert_eq!(spans(&f), [(0x0000, 0xFFFF)]);
        assert!(f.requests <= 65536 / 124 + 2, "{} requests", f.requests);
        assert!(!f.blocks[0].end_shown);
    }

    #[test]
    fn the_cap_stops_the_search_and_keeps_what_was_found() {
        let blocks = [(0x0000, 0x0FFF), (0x2500, 0x252F)];
        let mut fake = Fake::new(&blocks, 125, false);
        let (f, r) = run(&mut fake, MapConfig::default(), 40);
        assert!(matches!(r, Err(LearnError::Budget(40))), "{r:?}");
        assert!(!f.complete);
        assert_eq!(f.blocks.len(), 1);
        assert_eq!(f.blocks[0].first, 0);
        assert!(f.blocks[0].last >= 0x0F00);
        assert_eq!(fake.asked, 40);
    }
}
