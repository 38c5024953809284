//! The master gate's verdicts from arbitrary input, for the cargo-fuzz target
//! `master_gate_verdict` (issue 33: `--retries 1` made the gate add a character time to
//! `Duration::MAX`, an "unbounded" silence, and panic).
//!
//! [`judge_any`] reads, from the fuzzer's bytes, everything a verdict takes: the mode,
//! any baud rate, any timeout (up to `Duration::MAX`), any retries, the drive's behaviour,
//! what the master reported, the requests the drive received, the line log, the frames the
//! drive sent, and every time of the operation. It judges the operation as the gate does
//! ([`super::verdict::judge_requests`], [`super::verdict::judge_report`]), and checks two
//! laws: nothing panics (no sum of times or counts overflows), and the same operation
//! judged twice gives the same findings (a verdict depends on its record only). The
//! property test `verdict::tests::arithmetic` covers the same ground with proptest's
//! strategies in every `cargo test`.

use std::sync::OnceLock;
use std::time::Duration;

use super::drive::{Behaviour, Chunk, Dir, Request, Sent, SentClass};
use super::protocol::{MasterSettings, Operation, Reported};
use super::verdict::{judge_report, judge_requests, OpRecord, Role};
use crate::codec::timing::{LineSettings, Parity};
use crate::codec::Mode;
use crate::model::DriveModel;
use crate::monitor::{Monitor, MonitorConfig};

/// The fuzzer's bytes, read as values; zeros once they run out.
struct Input<'a>(&'a [u8]);

impl Input<'_> {
    fn u8(&mut self) -> u8 {
        match self.0.split_first() {
            Some((b, rest)) => {
                self.0 = rest;
                *b
            }
            None => 0,
        }
    }

    fn u16(&mut self) -> u16 {
        u16::from_le_bytes([self.u8(), self.u8()])
    }

    fn u32(&mut self) -> u32 {
        u32::from_le_bytes([self.u8(), self.u8(), self.u8(), self.u8()])
    }

    fn u64(&mut self) -> u64 {
        u64::from(self.u32()) | (u64::from(self.u32()) << 32)
    }

    fn bool(&mut self) -> bool {
        self.u8() & 1 == 1
    }

    /// Any duration, with the edges (zero, the largest) and the usual milliseconds
    /// likely.
    fn duration(&mut self) -> Duration {
        match self.u8() % 5 {
            0 => Duration::from_millis(u64::from(self.u16())),
            1 => Duration::from_micros(self.u64()),
            2 => Duration::from_millis(self.u64()),
            3 => Duration::ZERO,
            _ => Duration::MAX,
        }
    }

    fn bytes(&mut self, most: usize) -> Vec<u8> {
        let n = usize::from(self.u8()) % (most + 1);
        (0..n).map(|_| self.u8()).collect()
    }

    fn behaviour(&mut self) -> Behaviour {
        match self.u8() % 15 {
            0 => Behaviour::Normal,
            1 => Behaviour::Exception(self.u8()),
            2 => Behaviour::Late(self.duration()),
            3 => Behaviour::AfterTimeout,
            4 => Behaviour::InFlight,
            5 => Behaviour::WrongFunction,
            6 => Behaviour::NoReply,
            7 => Behaviour::Truncated,
            8 => Behaviour::BadChecksum,
            9 => Behaviour::GarbageBefore(self.bytes(4)),
            10 => Behaviour::GarbageAfter(self.bytes(4)),
            11 => Behaviour::ExceptionNoChecksum(self.u8()),
            12 => Behaviour::OtherNode(self.u8()),
            13 => Behaviour::Split(self.duration()),
            _ => Behaviour::Twice,
        }
    }

    fn reported(&mut self) -> Reported {
        match self.u8() % 4 {
            0 => Reported::Values((0..self.u8() % 4).map(|_| self.u16()).collect()),
            1 => Reported::Done,
            2 => Reported::Exception(self.u8()),
            _ => Reported::Raised {
                kind: "timeout".into(),
                message: "no reply".into(),
            },
        }
    }

    fn operation(&mut self) -> Operation {
        match self.u8() % 2 {
            0 => Operation::Read {
                unit: self.u8(),
                start: self.u16(),
                count: self.u16(),
            },
            _ => Operation::WriteSingle {
                unit: self.u8(),
                register: self.u16(),
                value: self.u16(),
            },
        }
    }
}

fn f510() -> &'static DriveModel {
    static MODEL: OnceLock<DriveModel> = OnceLock::new();
    MODEL.get_or_init(|| DriveModel::builtin("f510").expect("the built-in F510 model loads"))
}

/// Judges the operation `data` describes, twice; panics where a law does not hold (see
/// the module notes). For the fuzz target; any input is fine.
pub fn judge_any(data: &[u8]) {
    let mut d = Input(data);
    let mode = if d.bool() { Mode::Ascii } else { Mode::Rtu };
    let line = LineSettings::new(
        d.u32(),
        if mode == Mode::Ascii { 7 } else { 8 },
        Parity::Even,
        1,
    );
    let settings = MasterSettings {
        timeout: d.duration(),
        retries: d.u32(),
    };
    let cfg = MonitorConfig {
        mode,
        line,
        nodes: vec![1],
        window: settings.timeout.max(Duration::from_millis(1)),
        response_allowance: d.duration(),
        gap_allowance: d.duration(),
    };
    let Ok(monitor) = Monitor::new(f510().clone(), cfg) else {
        return;
    };
    let op = d.operation();
    let behaviour = d.behaviour();
    let reported = d.reported();
    let role = if d.bool() {
        Role::Fault
    } else {
        Role::Recovery
    };
    let requests: Vec<Request> = (0..d.u8() % 5)
        .map(|i| Request {
            seq: u32::from(i),
            start: d.duration(),
            end: d.duration(),
            bytes: d.bytes(12),
            valid: d.bool(),
            address: d.u8(),
        })
        .collect();
    let log: Vec<Chunk> = (0..d.u8() % 7)
        .map(|_| Chunk {
            at: d.duration(),
            done: d.duration(),
            dir: if d.bool() {
                Dir::ToMaster
            } else {
                Dir::FromMaster
            },
            bytes: d.bytes(8),
        })
        .collect();
    let sent: Vec<Sent> = (0..d.u8() % 4)
        .map(|i| Sent {
            for_seq: u32::from(i),
            bytes: d.bytes(8),
            class: if d.bool() {
                SentClass::Reply
            } else {
                SentClass::Stale
            },
            values: d.bool().then(|| vec![d.u16(), d.u16()]),
            exception: d.bool().then(|| d.u8()),
            at: d.bool().then(|| d.duration()),
        })
        .collect();
    let rec = OpRecord {
        op: &op,
        behaviour: &behaviour,
        role,
        reported: &reported,
        took: d.duration(),
        requests: &requests,
        sent: &sent,
        log: &log,
        called: d.duration(),
        ended: d.duration(),
        recent: d.duration(),
        timed: d.bool(),
    };
    let first = (
        judge_requests(&rec, &monitor, &settings),
        judge_report(&rec, &settings),
    );
    let again = (
        judge_requests(&rec, &monitor, &settings),
        judge_report(&rec, &settings),
    );
    assert_eq!(first, again, "the same operation judged twice: {rec:?}");
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The shape of the panic the issue found: RTU, retries 1, a first request with no
    /// silence before it; and inputs cut anywhere, all zeros, all ones.
    #[test]
    fn edges_are_judged_without_a_panic() {
        judge_any(&[]);
        judge_any(&[0xFF; 300]);
        // RTU at 9600 baud, timeout 200 ms, retries 1, allowances zero; a read of 2
        // registers that got no reply and a timeout reported; one request read at 10..18 ms
        // after a chunk of the drive at 5..6 ms, the call begun at 0 (so the line was
        // silent "as long as it likes" before that chunk: Duration::MAX), on a timed line.
        let mut retries_one = vec![0u8];
        retries_one.extend(9600u32.to_le_bytes());
        retries_one.extend([0, 200, 0]);
        retries_one.extend(1u32.to_le_bytes());
        retries_one.extend([3, 3]);
        retries_one.extend([0, 1, 0, 0, 2, 0, 6, 3, 1]);
        retries_one.extend([1, 0, 10, 0, 0, 18, 0, 8, 1, 3, 0, 0, 0, 2, 0xC4, 0x0B, 1, 1]);
        retries_one.extend([1, 0, 5, 0, 0, 6, 0, 1, 0]);
        retries_one.extend([0, 3, 3, 3, 3, 1]);
        judge_any(&retries_one);
        for cut in 0..retries_one.len() {
            judge_any(&retries_one[..cut]);
        }
        let mut x = 0x1234_5678u32;
        for _ in 0..2_000 {
            let data: Vec<u8> = (0..x % 200)
                .map(|_| {
                    x ^= x << 13;
                    x ^= x >> 17;
                    x ^= x << 5;
                    x as u8
                })
                .collect();
            judge_any(&data);
        }
    }
}
