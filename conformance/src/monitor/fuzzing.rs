//! The listener's laws on arbitrary traffic, for the cargo-fuzz targets `monitor_stream`,
//! `tap_framer` and `line_search` (issue 37), and for the unit tests below, which run the
//! same laws on stable.
//!
//! A stream is read from the fuzzer's bytes by [`Stream::read`]: a control byte (the mode:
//! RTU, ASCII or auto; the baud rate; whether the bus names its nodes; where to cut), then
//! pieces, each a gap byte (the silence before it: `(g & 0x7F)² × 16` µs, and with bit 7
//! an idle report at its time first) and a length byte and that many bytes.
//! [`encode_stream`] writes one, for the seed corpora.
//!
//! The laws:
//! - [`monitor_stream`]: no panic; the bytes counted are the bytes fed; every frame is
//!   accounted for once (paired, unpaired or damaged) and every request closed once; what
//!   the monitor holds stays under [`Held::within_bounds`](super::Held::within_bounds)
//!   after every piece; and the same stream fed with its pieces cut in two (both halves
//!   read at the piece's time, which no gap separates) gives the same verdicts, every
//!   one: reads at one moment are one read (see [`super::frames`]).
//! - [`tap_framer`]: the framer gives back every byte once, in order; a valid RTU frame
//!   has its CRC right and, ended by its length, the length the codec's rule gives; a
//!   valid ASCII frame is one the codec takes; a frame ended by t3.5 ends where the
//!   codec's deframer by silence ends a block; it holds a bounded number of bytes; cut
//!   pieces give the same frames, to their times and status.
//! - [`line_search`]: the search ends within its budget (it reads at most
//!   [`SETTING_BYTES`] and one read more at a setting before it moves on, and never sets
//!   a setting without reading), and never reports a setting without two valid frames of
//!   the mode it reports in what it heard there.

use std::sync::atomic::AtomicBool;
use std::sync::OnceLock;
use std::time::{Duration, Instant};

use super::frames::{EndedBy, FrameStatus, TapFrame, TapFramer};
use super::guess::{guess, Guess};
use super::line_search::{listen_for_line, Tunable, SETTING_BYTES};
use super::tap::Tap;
use super::{Monitor, MonitorConfig, NodeStats};
use crate::codec::deframe::{bus_rtu_frame_len, Event, RtuDeframer, RtuFraming};
use crate::codec::pdu::{Direction, Message, Pdu, Registers};
use crate::codec::timing::{LineSettings, Parity};
use crate::codec::{Mode, MAX_RTU_FRAME};
use crate::model::DriveModel;
use crate::transport::TransportError;

/// Baud rates a control byte chooses from.
const BAUDS: [u32; 4] = [9600, 19200, 38400, 115_200];

/// The mode a stream asks for.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum StreamMode {
    /// RTU.
    Rtu,
    /// ASCII.
    Ascii,
    /// Whichever the bytes show (RTU where they show neither).
    Auto,
}

/// One piece of a stream: the silence before it, whether the listener reported the
/// silence (an empty read) before it, and its bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Piece {
    /// The silence before it.
    pub gap: Duration,
    /// Whether an idle report at its time comes first.
    pub idle_first: bool,
    /// The bytes.
    pub bytes: Vec<u8>,
}

/// A stream of bytes with their arrival gaps, read from a fuzzer's input.
#[derive(Debug, Clone)]
pub struct Stream {
    /// RTU, ASCII or auto.
    pub mode: StreamMode,
    /// The line's baud rate.
    pub baud: u32,
    /// Whether the monitor is told the bus's nodes (1 and 2) or takes every address.
    pub named_nodes: bool,
    /// Where to cut pieces for the cut law.
    pub cut_seed: u8,
    /// The pieces, in order.
    pub pieces: Vec<Piece>,
}

impl Stream {
    /// Reads a stream from `data` (see the module notes); any input is a stream.
    pub fn read(data: &[u8]) -> Stream {
        let (control, mut rest) = data.split_first().map_or((0, data), |(c, r)| (*c, r));
        let mode = match control % 3 {
            0 => StreamMode::Rtu,
            1 => StreamMode::Ascii,
            _ => StreamMode::Auto,
        };
        let mut pieces = Vec::new();
        while let [g, n, tail @ ..] = rest {
            let take = usize::from(*n).min(tail.len());
            let code = u64::from(g & 0x7F);
            pieces.push(Piece {
                gap: Duration::from_micros(code * code * 16),
                idle_first: g & 0x80 != 0,
                bytes: tail[..take].to_vec(),
            });
            rest = &tail[take..];
        }
        Stream {
            mode,
            baud: BAUDS[usize::from(control >> 2) % 4],
            named_nodes: control & 0x10 != 0,
            cut_seed: control >> 5,
            pieces,
        }
    }

    /// Every byte of the stream, in order.
    pub fn bytes(&self) -> Vec<u8> {
        self.pieces.iter().flat_map(|p| p.bytes.clone()).collect()
    }

    /// The mode the stream is judged in: auto takes what the bytes show.
    pub fn resolved_mode(&self) -> Mode {
        match self.mode {
            StreamMode::Rtu => Mode::Rtu,
            StreamMode::Ascii => Mode::Ascii,
            StreamMode::Auto => match guess(&self.bytes()) {
                Guess::Mode(m, _) => m,
                _ => Mode::Rtu,
            },
        }
    }

    /// The line: 8E1 in RTU, 7E1 in ASCII.
    pub fn line(&self, mode: Mode) -> LineSettings {
        let data_bits = if mode == Mode::Ascii { 7 } else { 8 };
        LineSettings::new(self.baud, data_bits, Parity::Even, 1)
    }

    /// The same stream with every piece of two bytes or more cut in two, both halves at
    /// the piece's time (the second with no gap and no idle report before it).
    pub fn cut(&self) -> Stream {
        let mut pieces = Vec::new();
        for (i, p) in self.pieces.iter().enumerate() {
            if p.bytes.len() < 2 {
                pieces.push(p.clone());
                continue;
            }
            let k = 1 + (usize::from(self.cut_seed) + i) % (p.bytes.len() - 1);
            pieces.push(Piece {
                bytes: p.bytes[..k].to_vec(),
                ..p.clone()
            });
            pieces.push(Piece {
                gap: Duration::ZERO,
                idle_first: false,
                bytes: p.bytes[k..].to_vec(),
            });
        }
        Stream {
            pieces,
            ..self.clone()
        }
    }
}

/// The fuzzer's input for `control` and `pieces` of (gap byte, bytes; see the module
/// notes; a piece over 255 bytes is cut into pieces of 255 with no gap between them).
pub fn encode_stream(control: u8, pieces: &[(u8, &[u8])]) -> Vec<u8> {
    let mut out = vec![control];
    for (gap, bytes) in pieces {
        let mut g = *gap;
        for chunk in bytes.chunks(255) {
            out.push(g);
            out.push(chunk.len() as u8);
            out.extend_from_slice(chunk);
            g = 0;
        }
    }
    out
}

fn f510() -> &'static DriveModel {
    static MODEL: OnceLock<DriveModel> = OnceLock::new();
    MODEL.get_or_init(|| DriveModel::builtin("f510").expect("the built-in F510 model loads"))
}

/// What a monitor made of a stream: its counts, and per node its requests, exchanges,
/// replies, timeouts, CRC errors, retries and the count of each kind of finding.
#[derive(Debug, PartialEq, Eq)]
struct Judged {
    frames: u64,
    bytes: u64,
    tally: super::FrameTally,
    nodes: Vec<NodeVerdict>,
}

/// A node's verdicts: its address, its counts, its findings by kind.
type NodeVerdict = (u8, [u64; 6], Vec<(String, u64)>);

fn verdicts(address: u8, n: &NodeStats) -> NodeVerdict {
    let mut errors: Vec<(String, u64)> = n.errors.iter().map(|(k, v)| (k.clone(), *v)).collect();
    errors.sort();
    let counts = [
        n.requests,
        n.exchanges,
        n.replies,
        n.timeouts,
        n.crc_errors,
        n.retries,
    ];
    (address, counts, errors)
}

/// Feeds `stream` to a monitor in `mode`, checking after each piece that what it holds is
/// bounded; its verdicts.
fn judge_stream(stream: &Stream, mode: Mode) -> Judged {
    let nodes = if stream.named_nodes {
        vec![1, 2]
    } else {
        Vec::new()
    };
    let cfg = MonitorConfig::new(mode, stream.line(mode), nodes.clone());
    let mut m = Monitor::new(f510().clone(), cfg).expect("nodes 1 and 2 are valid");
    // Writes teach at most every register of the address space per node.
    let map = 1 << 16;
    let mut at = Duration::ZERO;
    let mut fed = 0u64;
    let check = |m: &Monitor, when: &str| {
        if let Err(e) = m.held().within_bounds(map, nodes.len()) {
            panic!("{when}: the monitor holds too much: {e} ({:?})", m.held());
        }
    };
    for p in &stream.pieces {
        at += p.gap;
        if p.idle_first {
            m.idle(at);
        }
        m.feed(at, &p.bytes);
        fed += p.bytes.len() as u64;
        // The caller takes the live lines as it goes; they are not the monitor's to keep.
        m.take_lines();
        check(&m, "after a piece");
    }
    m.idle(at + Duration::from_secs(2));
    m.finish();
    check(&m, "at the end");
    assert_eq!(
        m.bytes_heard(),
        fed,
        "the bytes counted are not the bytes fed"
    );
    let t = tally_laws(&m);
    Judged {
        frames: m.frames_heard(),
        bytes: m.bytes_heard(),
        tally: t,
        nodes: m.nodes().iter().map(|(a, s)| verdicts(*a, s)).collect(),
    }
}

/// Panics where a monitor's count of what became of its frames does not add up: every
/// frame accounted for once, every request closed once, every reply its request's, the
/// nodes' requests the requests. Its tally.
fn tally_laws(m: &Monitor) -> super::FrameTally {
    let t = m.tally();
    assert_eq!(
        m.frames_heard(),
        t.requests + t.replies + t.damaged + t.unpaired + t.cut,
        "a frame not accounted for once: {t:?}"
    );
    assert_eq!(
        t.requests,
        t.answered + t.unanswered + t.unjudged,
        "a request not closed once: {t:?}"
    );
    assert_eq!(t.replies, t.answered, "a reply without its request: {t:?}");
    let per_node: u64 = m.nodes().values().map(|n| n.requests).sum();
    assert_eq!(
        per_node, t.requests,
        "the nodes' requests are not the requests"
    );
    t
}

/// `monitor --capture-in` on any bytes, in RTU and in ASCII (the `capture_reader` fuzz
/// target calls it after its own laws): no panic, the monitor's count of frames adds up
/// ([`tally_laws`]), and it was given no more bytes than the capture's packets hold
/// (those of a first packet its writer marked as read mid-traffic are not judged).
pub fn capture_replay(data: &[u8]) {
    for mode in [Mode::Rtu, Mode::Ascii] {
        let cfg = MonitorConfig::new(mode, LineSettings::new(9600, 8, Parity::Even, 1), vec![1]);
        let mut m = Monitor::new(f510().clone(), cfg).expect("node 1 is valid");
        // A file that is no capture, or a link type no Modbus reader takes: a typed error.
        let Ok(r) = super::replay::replay(data, &mut m, |_| {}) else {
            continue;
        };
        tally_laws(&m);
        assert!(
            m.bytes_heard() <= r.bytes,
            "the monitor heard {} bytes of a capture of {}",
            m.bytes_heard(),
            r.bytes
        );
    }
}

/// The monitor on the stream `data` describes; panics where a law does not hold (see the
/// module notes). For the fuzz target `monitor_stream`; any input is fine.
pub fn monitor_stream(data: &[u8]) {
    let stream = Stream::read(data);
    let mode = stream.resolved_mode();
    let whole = judge_stream(&stream, mode);
    let cut = judge_stream(&stream.cut(), mode);
    assert_eq!(
        whole, cut,
        "the same stream cut in pieces is judged otherwise"
    );
}

/// Frames a stream with a tap framer; every frame, with the end offset of each.
fn frame_stream(stream: &Stream, mode: Mode) -> Vec<(usize, TapFrame)> {
    let mut f = TapFramer::new(mode, stream.line(mode));
    let mut out = Vec::new();
    let mut at = Duration::ZERO;
    let mut emitted = Vec::new();
    let mut offset = 0;
    let mut take = |out: &mut Vec<TapFrame>, emitted: &mut Vec<(usize, TapFrame)>| {
        for fr in out.drain(..) {
            offset += fr.bytes.len();
            emitted.push((offset, fr));
        }
    };
    for p in &stream.pieces {
        at += p.gap;
        if p.idle_first {
            f.idle(at, &mut out);
        }
        f.push(at, &p.bytes, &mut out);
        take(&mut out, &mut emitted);
        assert!(
            f.held_bytes() <= 4 * crate::codec::MAX_ASCII_FRAME,
            "the framer holds {} bytes",
            f.held_bytes()
        );
        assert!(
            f.held_pieces() <= 8 * MAX_RTU_FRAME,
            "the framer keeps the times of {} pieces",
            f.held_pieces()
        );
    }
    f.idle(at + Duration::from_secs(2), &mut out);
    f.finish(&mut out);
    take(&mut out, &mut emitted);
    emitted
}

/// Where the codec's RTU deframer by silence ends blocks of the same stream (byte
/// offsets).
fn silence_block_ends(stream: &Stream, line: LineSettings) -> Vec<usize> {
    let mut d = RtuDeframer::new(Direction::Request, RtuFraming::BySilence(line));
    let mut ends = Vec::new();
    let mut offset = 0;
    let mut at = Duration::ZERO;
    let add = |e: Event<'_>, ends: &mut Vec<usize>, offset: &mut usize| {
        *offset += e.bytes().len();
        ends.push(*offset);
    };
    for p in &stream.pieces {
        at += p.gap;
        let now = u64::try_from(at.as_micros()).unwrap_or(u64::MAX);
        if p.idle_first {
            d.idle(now, |e| add(e, &mut ends, &mut offset));
        }
        d.push_at(now, &p.bytes, |e| add(e, &mut ends, &mut offset));
    }
    d.flush(|e| add(e, &mut ends, &mut offset));
    ends
}

/// The tap framer on the stream `data` describes; panics where a law does not hold (see
/// the module notes). For the fuzz target `tap_framer`; any input is fine.
pub fn tap_framer(data: &[u8]) {
    let stream = Stream::read(data);
    let mode = stream.resolved_mode();
    let frames = frame_stream(&stream, mode);
    let all: Vec<u8> = frames.iter().flat_map(|(_, f)| f.bytes.clone()).collect();
    assert_eq!(
        all,
        stream.bytes(),
        "the frames are not the bytes fed, once each, in order"
    );
    let silence_ends = (mode == Mode::Rtu).then(|| silence_block_ends(&stream, stream.line(mode)));
    for (i, (end, f)) in frames.iter().enumerate() {
        if f.status != FrameStatus::Valid {
            continue;
        }
        match mode {
            Mode::Rtu => {
                assert!(
                    (4..=MAX_RTU_FRAME).contains(&f.bytes.len())
                        && crate::codec::crc::crc16_frame_ok(&f.bytes),
                    "a valid RTU frame without its CRC: {}",
                    crate::codec::hex::Hex(&f.bytes)
                );
                if f.ended_by == EndedBy::Length {
                    let by_rule = [Direction::Request, Direction::Response]
                        .into_iter()
                        .any(|d| bus_rtu_frame_len(d, &f.bytes) == Some(f.bytes.len()));
                    // Or the bytes before a frame the length rule found, whose CRC holds
                    // (a function the rule does not know, 04H or 41H, answered at once):
                    // the valid frame after it ends it.
                    let before_a_frame = frames
                        .get(i + 1)
                        .is_some_and(|(_, next)| next.status == FrameStatus::Valid);
                    assert!(
                        by_rule || before_a_frame,
                        "a frame ended by its length that no length rule gives, and no valid frame after it: {}",
                        crate::codec::hex::Hex(&f.bytes)
                    );
                }
                if f.ended_by == EndedBy::Silence {
                    let ends = silence_ends.as_deref().unwrap_or(&[]);
                    assert!(
                        ends.contains(end),
                        "a frame ended by t3.5 at byte {end}, where the codec's deframer ends no block ({ends:?}): {}",
                        crate::codec::hex::Hex(&f.bytes)
                    );
                }
            }
            Mode::Ascii => assert!(
                crate::codec::ascii::is_valid_frame(&f.bytes),
                "a valid ASCII frame the codec refuses: {:?}",
                String::from_utf8_lossy(&f.bytes)
            ),
        }
    }
    // Reads at one moment are one read (see `frames`): the halves of a piece cut in two,
    // both read at its time, are framed as the piece is, to the last time and status.
    let cut = frame_stream(&stream.cut(), mode);
    assert!(
        frames == cut,
        "the same stream cut in pieces is framed otherwise:\n whole: {frames:?}\n cut: {cut:?}"
    );
}

/// A port that hears a script of reads whatever its setting, and records what it gave at
/// each setting; the end of the script ends the input.
struct ScriptTap {
    reads: Vec<Vec<u8>>,
    next: usize,
    /// Per setting set, in order: the bytes read at it.
    visits: Vec<(LineSettings, Vec<u8>)>,
}

impl Tap for ScriptTap {
    fn listen(&mut self, buf: &mut [u8], _timeout: Duration) -> Result<usize, TransportError> {
        let Some(read) = self.reads.get(self.next) else {
            return Err(TransportError::Closed {
                link: "the fuzzer's script".into(),
            });
        };
        self.next += 1;
        let n = read.len().min(buf.len());
        buf[..n].copy_from_slice(&read[..n]);
        if let Some((_, got)) = self.visits.last_mut() {
            got.extend_from_slice(&read[..n]);
        }
        Ok(n)
    }

    fn describe(&self) -> String {
        "the fuzzer's script".into()
    }
}

impl Tunable for ScriptTap {
    fn set_line(&mut self, line: LineSettings) -> Result<(), TransportError> {
        self.visits.push((line, Vec::new()));
        Ok(())
    }
}

/// Valid frames of `mode` in `bytes`, counted by the codec's own rules (RTU: a length the
/// header gives, as a request or a reply, and a CRC that checks; ASCII: ':' to LF that the
/// codec takes), each starting after the one before.
pub fn valid_frames(mode: Mode, bytes: &[u8]) -> usize {
    let mut n = 0;
    let mut i = 0;
    while i < bytes.len() {
        let rest = &bytes[i..];
        let len = match mode {
            Mode::Rtu => [Direction::Request, Direction::Response]
                .into_iter()
                .filter_map(|d| bus_rtu_frame_len(d, rest))
                .find(|&l| l <= rest.len() && crate::codec::crc::crc16_frame_ok(&rest[..l])),
            Mode::Ascii => (rest[0] == b':')
                .then(|| rest.iter().position(|&b| b == b'\n'))
                .flatten()
                .filter(|&e| crate::codec::ascii::is_valid_frame(&rest[..=e]))
                .map(|e| e + 1),
        };
        match len {
            Some(l) => {
                n += 1;
                i += l;
            }
            None => i += 1,
        }
    }
    n
}

/// The line search on the script `data` describes: a control byte (the mode asked for:
/// any, RTU or ASCII; how many settings, 1 to 4), then reads, each a length byte and that
/// many bytes (0: a read that came back empty). Panics where a law does not hold (see the
/// module notes). For the fuzz target `line_search`; any input is fine.
pub fn line_search(data: &[u8]) {
    let (control, mut rest) = data.split_first().map_or((0, data), |(c, r)| (*c, r));
    let asked = match control % 3 {
        0 => None,
        1 => Some(Mode::Rtu),
        _ => Some(Mode::Ascii),
    };
    let settings: Vec<LineSettings> = super::line_search::candidates(&[], &[], None, 1, asked)
        .into_iter()
        .take(1 + usize::from(control >> 2) % 4)
        .collect();
    let mut reads = Vec::new();
    while let [n, tail @ ..] = rest {
        let take = usize::from(*n).min(tail.len());
        reads.push(tail[..take].to_vec());
        rest = &tail[take..];
    }
    let script_len = reads.len();
    let mut tap = ScriptTap {
        reads,
        next: 0,
        visits: Vec::new(),
    };
    let stop = AtomicBool::new(false);
    let result = listen_for_line(
        &mut tap,
        &settings,
        asked,
        &stop,
        None,
        Instant::now(),
        |_| {},
    )
    .expect("a script tap never fails to set a line");
    assert!(tap.next <= script_len, "read past the end of its input");
    assert!(
        tap.visits.len() <= tap.next + settings.len(),
        "{} settings set for {} reads: a setting left unheard",
        tap.visits.len(),
        tap.next
    );
    for (line, got) in &tap.visits {
        assert!(
            got.len() < SETTING_BYTES + 512,
            "{} bytes read at {line} before moving on (budget {SETTING_BYTES} and one read)",
            got.len()
        );
    }
    if let Ok(found) = result {
        let (line, got) = tap.visits.last().expect("a setting was set");
        assert_eq!(
            *line, found.line,
            "found a setting other than the last one set"
        );
        let heard: Vec<u8> = found.heard.iter().flat_map(|(_, b)| b.clone()).collect();
        assert_eq!(
            &heard, got,
            "what the search heard is not what the port read"
        );
        assert!(
            asked.is_none_or(|m| m == found.mode),
            "found {} where {asked:?} was asked for",
            found.mode
        );
        let n = valid_frames(found.mode, &heard);
        assert!(
            n >= 2,
            "{} {} reported with {n} valid frame(s) in what it heard: {}",
            found.line,
            found.mode,
            crate::codec::hex::Hex(&heard)
        );
    }
}

/// A read of two registers at `node` and its reply, as frames of `mode`.
fn poll(mode: Mode, node: u8) -> (Vec<u8>, Vec<u8>) {
    let req = Message {
        address: node,
        pdu: Pdu::ReadRequest {
            start: 0x2520,
            count: 2,
        },
    };
    let rep = Message {
        address: node,
        pdu: Pdu::ReadResponse {
            values: Registers::new(&[0x00, 0x03, 0x11, 0x94]).unwrap(),
        },
    };
    (
        req.to_frame_vec(mode).unwrap(),
        rep.to_frame_vec(mode).unwrap(),
    )
}

/// Streams like a bus's: polls with their replies, a silence between, in RTU, ASCII
/// and auto, with a damaged reply, a reply never asked for and noise.
pub fn bus_streams() -> Vec<Vec<u8>> {
    let mut out = Vec::new();
    for control in [0u8, 1, 2, 0x0C, 0x1D, 0xE2, 0x50] {
        let mode = if control % 3 == 1 {
            Mode::Ascii
        } else {
            Mode::Rtu
        };
        let (q1, r1) = poll(mode, 1);
        let (q2, r2) = poll(mode, 2);
        let mut damaged = r2.clone();
        damaged[3] ^= 0x40;
        let noise = [0xFFu8, 0x00, 0x3A, 0x0D, 0x0A, 0x01];
        out.push(encode_stream(
            control,
            &[
                (0, &q1),
                (20, &r1),
                (0xC0, &q2),
                (20, &damaged),
                (60, &r2),
                (0x90, &noise),
                (0x90, &r1),
                (40, &q1[..3]),
                (10, &q1[3..]),
            ],
        ));
    }
    out
}

/// Scripts for [`line_search`] of `frames` (each frame a read, an empty read after each
/// pair), once for each mode asked for.
pub fn search_scripts(frames: &[Vec<u8>]) -> Vec<Vec<u8>> {
    (0u8..3)
        .map(|control| {
            let mut data = vec![control | 0x04];
            for (i, f) in frames.iter().enumerate() {
                for chunk in f.chunks(255) {
                    data.push(chunk.len() as u8);
                    data.extend_from_slice(chunk);
                }
                if i % 2 == 1 {
                    data.push(0);
                }
            }
            data
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Pseudo-random inputs: a fixed xorshift, so that a failure replays.
    fn noise(count: usize, longest: u32) -> Vec<Vec<u8>> {
        let mut x = 0x9E37_79B9u32;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 17;
            x ^= x << 5;
            x
        };
        (0..count)
            .map(|_| {
                let n = next() % longest;
                (0..n).map(|_| next() as u8).collect()
            })
            .collect()
    }

    #[test]
    fn a_bus_stream_is_judged_by_every_law() {
        for s in bus_streams() {
            monitor_stream(&s);
            tap_framer(&s);
        }
    }

    #[test]
    fn the_tally_counts_each_frame_once() {
        let (q, r) = poll(Mode::Rtu, 1);
        // A poll answered, a poll answered and its reply again, a poll never answered.
        let s = encode_stream(
            0,
            &[
                (0, &q),
                (20, &r),
                (0xC0, &q),
                (20, &r),
                (0xC0, &r),
                (0xC0, &q),
            ],
        );
        let stream = Stream::read(&s);
        let j = judge_stream(&stream, Mode::Rtu);
        assert_eq!(j.frames, 6);
        assert_eq!(j.tally.requests, 3, "{:?}", j.tally);
        assert_eq!(j.tally.replies, 2, "{:?}", j.tally);
        assert_eq!(j.tally.unpaired, 1, "{:?}", j.tally);
        assert_eq!(j.tally.unanswered, 1, "{:?}", j.tally);
        assert_eq!(j.bytes, (3 * q.len() + 3 * r.len()) as u64);
    }

    #[test]
    fn edges_and_noise_keep_every_law() {
        for data in [&[][..], &[0xFF; 300], &[0x01; 600], &[0x3A; 2000]] {
            monitor_stream(data);
            tap_framer(data);
            line_search(data);
        }
        for data in noise(400, 700) {
            monitor_stream(&data);
            tap_framer(&data);
            line_search(&data);
        }
    }

    #[test]
    fn a_long_block_without_silence_is_held_in_bounded_memory() {
        for control in [0u8, 1] {
            let junk: Vec<u8> = (0..4000u32).map(|i| (i * 7 + 1) as u8).collect();
            let s = encode_stream(control, &[(0, &junk)]);
            monitor_stream(&s);
            tap_framer(&s);
        }
    }

    #[test]
    fn the_line_search_finds_polls_and_reports_them_with_two_frames() {
        for (control, mode) in [(1u8, Mode::Rtu), (2, Mode::Ascii), (0, Mode::Rtu)] {
            let (q, r) = poll(mode, 1);
            let mut data = vec![control];
            for _ in 0..3 {
                for f in [&q, &r] {
                    data.push(f.len() as u8);
                    data.extend_from_slice(f);
                }
                data.push(0);
            }
            line_search(&data);
            assert!(valid_frames(mode, &[q.clone(), r.clone()].concat()) == 2);
        }
        // One frame and noise: never enough.
        let (q, _) = poll(Mode::Rtu, 1);
        assert_eq!(valid_frames(Mode::Rtu, &q[..q.len() - 1]), 0);
    }
}
