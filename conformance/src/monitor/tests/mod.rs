//! The monitor on byte streams with times chosen by the test: no port, no clock, so the
//! gaps are exact and nothing depends on how busy the machine is.
//!
//! By what they test: `findings.rs`, who is at fault and why; `values.rs`, values judged
//! after a write seen on the bus; `pairing.rs`, telling requests, replies, echoes and
//! resends apart; `memo_lines.rs`, the memo and the live lines, which change no verdict. The
//! helpers here build frames and traffic for them and for `tests_packet.rs` and
//! `tests_stream.rs`.

use std::time::Duration;

use super::*;
use crate::codec::pdu::{Pdu, Registers};
use crate::codec::timing::Parity;
use crate::model::{Access, Expectation};

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

pub(super) fn monitor(mode: Mode, nodes: &[u8]) -> Monitor {
    let data_bits = if mode == Mode::Rtu { 8 } else { 7 };
    Monitor::new(
        DriveModel::builtin("f510").unwrap(),
        MonitorConfig {
            gap_allowance: ms(5),
            ..MonitorConfig::new(
                mode,
                LineSettings::new(9600, data_bits, Parity::Even, 1),
                nodes.to_vec(),
            )
        },
    )
    .unwrap()
}

fn frame(mode: Mode, address: u8, pdu: Pdu<'_>) -> Vec<u8> {
    Message { address, pdu }.to_frame_vec(mode).unwrap()
}

pub(super) fn read(address: u8, start: u16, count: u16) -> Vec<u8> {
    frame(Mode::Rtu, address, Pdu::ReadRequest { start, count })
}

pub(super) fn values(address: u8, v: &[u16]) -> Vec<u8> {
    let bytes: Vec<u8> = v.iter().flat_map(|x| x.to_be_bytes()).collect();
    frame(
        Mode::Rtu,
        address,
        Pdu::ReadResponse {
            values: Registers::new(&bytes).unwrap(),
        },
    )
}

fn exception(address: u8, function: u8, code: u8) -> Vec<u8> {
    frame(Mode::Rtu, address, Pdu::Exception { function, code })
}

fn write(address: u8, register: u16, value: u16) -> Vec<u8> {
    frame(Mode::Rtu, address, Pdu::WriteSingle { register, value })
}

fn ascii_read(address: u8, start: u16, count: u16) -> Vec<u8> {
    frame(Mode::Ascii, address, Pdu::ReadRequest { start, count })
}

fn ascii_exception(address: u8, function: u8, code: u8) -> Vec<u8> {
    frame(Mode::Ascii, address, Pdu::Exception { function, code })
}

/// Feeds `frames` at their times (ms), then a long silence, then the end.
fn run(m: &mut Monitor, frames: &[(u64, &[u8])]) -> Vec<Line> {
    for (t, f) in frames {
        m.idle(ms(*t));
        m.feed(ms(*t), f);
    }
    let end = frames.last().map_or(0, |f| f.0) + 5000;
    m.idle(ms(end));
    m.finish();
    m.take_lines()
}

/// The (side.kind) of every finding on `node`.
pub(super) fn kinds(m: &Monitor, node: u8) -> Vec<String> {
    m.nodes()
        .get(&node)
        .map(|s| s.errors.keys().cloned().collect())
        .unwrap_or_default()
}

mod findings;
mod memo_lines;
mod pairing;
mod values;

/// A writable parameter the model takes `value` for with a normal reply.
fn writable_parameter(model: &DriveModel, value: u16) -> u16 {
    model
        .registers()
        .filter(|(r, a)| *a == Access::ReadWrite && model.named(*r).is_none())
        .find(|(r, _)| {
            matches!(
                model.judge(1, Mode::Rtu, &write(1, *r, value)).expect,
                Expectation::WriteSingle
            )
        })
        .expect("a writable parameter")
        .0
}

/// Every kind of traffic the monitor judges, `cycles` times over (the same exchanges
/// again, as a bus polls them; the values written change from cycle to cycle, so that the
/// reads after them are judged against other known values): normal polling, writes that
/// change later reads, right and wrong exceptions, wrong values, late replies, bad CRCs on
/// either side, garbage before a reply, gaps inside a reply, replies to broadcasts, from
/// the wrong node and for a node not on the bus, no reply (within the window and cut
/// short by the next request) and a retry, a request before the reply was due, no t3.5,
/// an unserved function, a reply with no request.
pub(super) fn varied_traffic(cycles: u64) -> Vec<(u64, Vec<u8>)> {
    let mut out = Vec::new();
    for c in 0..cycles {
        let t = c * 6000;
        let v = 100 + (c % 3) as u16;
        let mut bad_reply = values(1, &[7]);
        let n = bad_reply.len();
        bad_reply.swap(n - 1, n - 2);
        let mut bad_request = read(1, 0x2520, 1);
        bad_request[7] ^= 0xFF;
        let mut garbage = vec![0xFF, 0x00];
        garbage.extend(values(1, &[7]));
        let gappy = values(1, &[0x0102, 0x0304]);
        let steps: Vec<(u64, Vec<u8>)> = vec![
            (0, read(1, 0x2520, 1)),
            (15, values(1, &[0])),
            (100, write(1, 0x2502, v)),
            (112, write(1, 0x2502, v)),
            (200, read(1, 0x2502, 1)),
            // Right in one cycle of two, wrong in the other.
            (215, values(1, &[if c % 2 == 0 { v } else { v + 1 }])),
            (300, read(1, 0x2530, 1)),
            (315, exception(1, 3, if c % 2 == 0 { 2 } else { 3 })),
            (400, read(1, 0x2520, 1)),
            (700, values(1, &[0])),
            (1000, read(1, 0x2520, 1)),
            (1015, bad_reply),
            (1100, read(1, 0x2520, 1)),
            (1115, garbage),
            (1200, write(0, 0x2502, v)),
            (1212, write(0, 0x2502, v)),
            (1500, read(1, 0x2520, 1)),
            (1515, values(2, &[1])),
            (1700, read(3, 0x2520, 1)),
            (1715, values(3, &[1])),
            (1900, read(1, 0x2521, 1)),
            (2950, read(1, 0x2521, 1)),
            (2965, values(1, &[1])),
            (3500, read(1, 0x2520, 1)),
            (3502, write(1, 0x2502, v)),
            (3514, write(1, 0x2502, v)),
            (3600, read(1, 0x2520, 1)),
            (3615, values(1, &[0])),
            (3616, read(1, 0x2520, 1)),
            (3631, values(1, &[0])),
            (3800, bad_request),
            (4000, values(1, &[5])),
            (
                4200,
                frame(
                    Mode::Rtu,
                    1,
                    Pdu::Other {
                        function: 0x04,
                        data: &[0, 0, 0, 1],
                    },
                ),
            ),
            (4215, exception(1, 4, 1)),
            (4400, read(1, 0x2520, 2)),
            (4415, gappy[..3].to_vec()),
            (4423, gappy[3..].to_vec()),
            (4600, read(1, 0x251F, 2)),
            (4615, exception(1, 3, 2)),
            // No reply, and the next request after the reply was due but within the
            // window: how long the monitor listened differs from cycle to cycle.
            (5000, read(1, 0x2521, 1)),
            (5300 + 10 * (c % 2), read(1, 0x2520, 1)),
            (5315 + 10 * (c % 2), values(1, &[0])),
        ];
        out.extend(steps.into_iter().map(|(dt, f)| (t + dt, f)));
    }
    out
}

/// Everything a monitor reports, for comparing two: the live lines, every exchange as
/// counted (its findings with their texts, its citations, the exchange as an example
/// would keep it), the per-node statistics, the examples, the notices and the results.
pub(super) fn everything(m: &Monitor, lines: &[Line]) -> String {
    format!(
        "{lines:#?}\n{:#?}\n{:#?}\n{:#?}\n{:#?}\n{:#?}\n{}",
        m.trail,
        m.nodes(),
        m.examples(),
        m.notices(),
        m.results(),
        m.deviations()
    )
}
