//! The drive's loop: frames what the master sends, answers as the model says, and
//! misbehaves as the case's behaviour says.

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::codec::ascii::Scratch;
use crate::codec::deframe::{AsciiDeframer, Event, RtuDeframer, RtuFraming};
use crate::codec::hex;
use crate::codec::pdu::{Direction, Message, Pdu, Registers};
use crate::codec::timing::later;
use crate::codec::timing::LineSettings;
use crate::codec::{self, Mode};
use crate::model::{DriveModel, Expectation};

use super::link::Link;
use super::{apart, lock, tags, Behaviour, Chunk, Dir, Request, Sent, SentClass, State, STALL};

pub(super) struct Server {
    pub(super) link: Link,
    pub(super) model: Arc<DriveModel>,
    pub(super) node: u8,
    pub(super) mode: Mode,
    pub(super) line: LineSettings,
    pub(super) state: Arc<Mutex<State>>,
    pub(super) origin: Instant,
}

enum Framer {
    // Boxed: the RTU deframer holds a frame's buffer, the ASCII one far more.
    Rtu(Box<RtuDeframer>),
    Ascii(Box<AsciiDeframer>),
}

impl Server {
    pub(super) fn run(&mut self, stop: &AtomicBool) {
        let mut framer = match self.mode {
            Mode::Rtu => Framer::Rtu(Box::new(RtuDeframer::new(
                Direction::Request,
                RtuFraming::ByLength,
            ))),
            Mode::Ascii => Framer::Ascii(Box::default()),
        };
        let mut buf = [0u8; 1024];
        // Bytes of a request under way: when its first byte came.
        let mut started: Option<Duration> = None;
        let mut last_rx: Option<Instant> = None;
        let mut turn = self.origin.elapsed();
        while !stop.load(Ordering::Relaxed) {
            let now = self.origin.elapsed();
            if now.saturating_sub(turn) > STALL {
                lock(&self.state).stalls.push((turn, now));
            }
            turn = now;
            self.send_due();
            let wait = {
                let s = lock(&self.state);
                let next = s.queue.iter().map(|(t, _)| *t).min();
                next.map_or(Duration::from_millis(5), |t| {
                    t.saturating_duration_since(Instant::now())
                        .min(Duration::from_millis(5))
                })
            };
            let n = match self.link.recv(&mut buf, wait) {
                Ok(n) => n,
                Err(e) => {
                    lock(&self.state).error = Some(e.to_string());
                    std::thread::sleep(Duration::from_millis(5));
                    0
                }
            };
            if n == 0 {
                // A partial request abandoned for long: what it held is no frame.
                if last_rx.is_some_and(|t| t.elapsed() > Duration::from_millis(100)) {
                    let mut events = Vec::new();
                    match &mut framer {
                        Framer::Rtu(d) => d.flush(|e| events.push(owned(e))),
                        Framer::Ascii(d) => d.flush(|e| events.push(owned(e))),
                    }
                    let at = self.origin.elapsed();
                    for (bytes, valid) in events {
                        self.on_frame(started.unwrap_or(at), at, bytes, valid);
                    }
                    started = None;
                    last_rx = None;
                }
                continue;
            }
            let at = self.origin.elapsed();
            last_rx = Some(Instant::now());
            started.get_or_insert(at);
            lock(&self.state).log.push(Chunk {
                at,
                done: at,
                dir: Dir::FromMaster,
                bytes: buf[..n].to_vec(),
            });
            let mut events = Vec::new();
            match &mut framer {
                Framer::Rtu(d) => d.push(&buf[..n], |e| events.push(owned(e))),
                Framer::Ascii(d) => d.push(&buf[..n], |e| events.push(owned(e))),
            }
            let pending = match &framer {
                Framer::Rtu(d) => d.pending(),
                Framer::Ascii(d) => d.pending(),
            };
            for (bytes, valid) in events {
                self.on_frame(started.unwrap_or(at), at, bytes, valid);
            }
            started = (pending > 0).then_some(at);
            if pending == 0 {
                last_rx = None;
            }
        }
    }

    fn send_due(&mut self) {
        loop {
            let (k, next) = {
                let mut s = lock(&self.state);
                let now = Instant::now();
                let Some(k) = (0..s.queue.len())
                    .filter(|k| s.queue[*k].0 <= now)
                    .min_by_key(|k| s.queue[*k].0)
                else {
                    return;
                };
                let (_, i) = s.queue.remove(k);
                let at = self.origin.elapsed();
                s.sent[i].at = Some(at);
                let bytes = s.sent[i].bytes.clone();
                let for_seq = s.sent[i].for_seq;
                s.log.push(Chunk {
                    at,
                    done: at,
                    dir: Dir::ToMaster,
                    bytes: bytes.clone(),
                });
                (s.log.len() - 1, (bytes, for_seq))
            };
            let sent = self.link.send(&next.0, next.1);
            let done = self.origin.elapsed();
            let mut s = lock(&self.state);
            if let Some(c) = s.log.get_mut(k) {
                c.done = done;
            }
            if let Err(e) = sent {
                s.error = Some(e.to_string());
            }
        }
    }

    fn on_frame(&mut self, start: Duration, end: Duration, bytes: Vec<u8>, valid: bool) {
        let address = crate::judge::body_of(self.mode, &bytes).map_or(0, |b| b[0]);
        let mut s = lock(&self.state);
        s.seq += 1;
        let seq = s.seq;
        s.requests.push(Request {
            seq,
            start,
            end,
            bytes: bytes.clone(),
            valid,
            address,
        });
        if !valid {
            return;
        }
        let behaviour = s.behaviour.clone().unwrap_or(Behaviour::Normal);
        let broadcast = address == self.model.broadcast;
        if address != self.node && !broadcast {
            return;
        }
        // A reply held for the next request goes out now, and this request's own reply
        // a silence after it.
        let flight = std::mem::take(&mut s.in_flight);
        let base = if flight.is_empty() {
            Duration::ZERO
        } else {
            apart(&self.line)
        };
        // A drive still sending (the busy line) finishes that first, then answers.
        let busy_for = s
            .queue
            .iter()
            .map(|(t, _)| t.saturating_duration_since(Instant::now()))
            .max()
            .map_or(Duration::ZERO, |d| {
                d.saturating_add(Duration::from_millis(1))
            });
        let base = base.max(busy_for);
        {
            let now = Instant::now();
            for i in flight {
                s.sent[i].class = SentClass::Stale;
                s.queue.push((now, i));
            }
        }
        let as_addressed = if broadcast {
            if behaviour != Behaviour::ReplyToBroadcast {
                // The drive acts on a broadcast write and says nothing.
                return;
            }
            match codec::readdressed(self.mode, &bytes, self.node) {
                Ok(f) => f,
                Err(_) => return,
            }
        } else {
            bytes.clone()
        };
        let judgement = self.model.judge(self.node, self.mode, &as_addressed);
        let mut scratch: Scratch = [0; codec::MAX_RTU_FRAME];
        let Ok(request) = codec::decode(self.mode, &as_addressed, Direction::Request, &mut scratch)
        else {
            return;
        };
        let function = request.pdu.function_code();
        s.frames += 1;
        let frame_no = s.frames;
        let mut values = None;
        let mut exception = None;
        let mut value_bytes = Vec::new();
        let reply: Option<Message<'_>> = match (&judgement.expect, &behaviour) {
            (Expectation::Silence(_), _) => None,
            // The case's exception first, else the model's.
            (_, Behaviour::Exception(code) | Behaviour::ExceptionNoChecksum(code))
            | (Expectation::Exception { code, .. }, _) => {
                exception = Some(*code);
                Some(Message {
                    address: self.node,
                    pdu: Pdu::Exception {
                        function,
                        code: *code,
                    },
                })
            }
            (Expectation::Read(plan), _) => {
                let v = tags(frame_no, plan.registers.len());
                for x in &v {
                    value_bytes.extend_from_slice(&x.to_be_bytes());
                }
                values = Some(v);
                Registers::new(&value_bytes).ok().map(|r| Message {
                    address: self.node,
                    pdu: Pdu::ReadResponse { values: r },
                })
            }
            (Expectation::WriteMultiple, _) => match request.pdu {
                Pdu::WriteMultipleRequest { start, values } => Some(Message {
                    address: self.node,
                    pdu: Pdu::WriteMultipleResponse {
                        start,
                        count: values.len() as u16,
                    },
                }),
                _ => None,
            },
            // 06H and 08H: the echo.
            (Expectation::WriteSingle | Expectation::LoopBack, _) => Some(Message {
                address: self.node,
                pdu: request.pdu,
            }),
        };
        let Some(reply) = reply else {
            return;
        };
        let Ok(frame) = reply.to_frame_vec(self.mode) else {
            return;
        };
        let now = Instant::now();
        let gap = apart(&self.line);
        let class = if broadcast {
            SentClass::BroadcastReply
        } else {
            SentClass::Reply
        };
        let push = |s: &mut State, after: Duration, bytes: Vec<u8>, class: SentClass| {
            let i = s.sent.len();
            let carries = matches!(
                class,
                SentClass::Reply
                    | SentClass::Stale
                    | SentClass::OtherNode
                    | SentClass::BadChecksum
                    | SentClass::Duplicate
                    | SentClass::BroadcastReply
            );
            s.sent.push(Sent {
                for_seq: seq,
                bytes,
                class,
                values: if carries { values.clone() } else { None },
                exception: if carries || class == SentClass::NoChecksum {
                    exception
                } else {
                    None
                },
                at: None,
            });
            s.queue.push((later(now, base.saturating_add(after)), i));
            i
        };
        match behaviour {
            Behaviour::Normal | Behaviour::Exception(_) | Behaviour::ReplyToBroadcast => {
                push(&mut s, Duration::ZERO, frame, class);
            }
            Behaviour::Late(d) => {
                push(&mut s, d, frame, class);
            }
            Behaviour::AfterTimeout => {
                let i = push(&mut s, Duration::ZERO, frame, class);
                s.queue.retain(|(_, k)| *k != i);
                s.held.push(i);
            }
            // An exception in flight is no test: it carries nothing that tells it from
            // the next request's (no count, no values); it goes out at once.
            Behaviour::InFlight if exception.is_some() => {
                push(&mut s, Duration::ZERO, frame, class);
            }
            Behaviour::InFlight => {
                let i = push(&mut s, Duration::ZERO, frame, class);
                s.queue.retain(|(_, k)| *k != i);
                s.in_flight.push(i);
            }
            Behaviour::WrongFunction => {
                // The echo of a write of the first tag to the first register read.
                let (register, value) = match request.pdu {
                    Pdu::ReadRequest { start, .. } => (start, tags(frame_no, 1)[0]),
                    _ => (0, 0),
                };
                let echo = Message {
                    address: self.node,
                    pdu: Pdu::WriteSingle { register, value },
                };
                if let Ok(f) = echo.to_frame_vec(self.mode) {
                    push(&mut s, Duration::ZERO, f, SentClass::WrongFunction);
                }
            }
            Behaviour::NoReply => {}
            Behaviour::Truncated => {
                let cut = match self.mode {
                    Mode::Rtu => frame.len().saturating_sub(3),
                    Mode::Ascii => frame.len().saturating_sub(4),
                };
                push(
                    &mut s,
                    Duration::ZERO,
                    frame[..cut].to_vec(),
                    SentClass::Truncated,
                );
            }
            Behaviour::BadChecksum => {
                push(
                    &mut s,
                    Duration::ZERO,
                    bad_checksum(self.mode, &frame),
                    SentClass::BadChecksum,
                );
            }
            Behaviour::GarbageBefore(g) => {
                push(&mut s, Duration::ZERO, g, SentClass::Garbage);
                push(&mut s, gap, frame, class);
            }
            Behaviour::GarbageAfter(g) => {
                push(&mut s, Duration::ZERO, frame, class);
                push(&mut s, gap, g, SentClass::Garbage);
            }
            Behaviour::ExceptionNoChecksum(_) => {
                let body = [self.node, function | 0x80, exception.unwrap_or(0)];
                let bytes = match self.mode {
                    Mode::Rtu => body.to_vec(),
                    Mode::Ascii => {
                        let mut b = vec![b':'];
                        b.extend(body.iter().flat_map(|&x| hex::encode_byte(x)));
                        b.extend_from_slice(b"\r\n");
                        b
                    }
                };
                push(&mut s, Duration::ZERO, bytes, SentClass::NoChecksum);
            }
            Behaviour::OtherNode(n) => {
                if let Ok(f) = codec::readdressed(self.mode, &frame, n) {
                    push(&mut s, Duration::ZERO, f, SentClass::OtherNode);
                }
            }
            Behaviour::Split(d) => {
                let half = frame.len() / 2;
                // The first part carries the values (a master that takes them took the
                // whole frame); the second is the rest.
                push(&mut s, Duration::ZERO, frame[..half].to_vec(), class);
                push(&mut s, d, frame[half..].to_vec(), SentClass::Garbage);
            }
            Behaviour::Twice => {
                push(&mut s, Duration::ZERO, frame.clone(), class);
                push(&mut s, gap, frame, SentClass::Duplicate);
            }
        }
    }
}

/// The frame with its checksum made wrong (RTU: the last byte flipped; ASCII: the LRC's
/// characters of another value).
fn bad_checksum(mode: Mode, frame: &[u8]) -> Vec<u8> {
    let mut f = frame.to_vec();
    match mode {
        Mode::Rtu => {
            if let Some(b) = f.last_mut() {
                *b ^= 0xFF;
            }
        }
        Mode::Ascii => {
            // ':' body LRC CR LF: the LRC is the two characters before CR LF.
            let n = f.len();
            if n >= 5 {
                let hi = f[n - 4];
                f[n - 4] = if hi == b'0' { b'1' } else { b'0' };
            }
        }
    }
    f
}

/// An event's bytes, and whether they are a valid frame.
fn owned(e: Event<'_>) -> (Vec<u8>, bool) {
    (e.bytes().to_vec(), matches!(e, Event::Frame(_)))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_bad_checksum_is_bad() {
        let f = [0x01, 0x03, 0x02, 0x00, 0x01, 0x79, 0x84];
        let mut scratch: Scratch = [0; codec::MAX_RTU_FRAME];
        assert!(codec::decode(Mode::Rtu, &f, Direction::Response, &mut scratch).is_ok());
        let b = bad_checksum(Mode::Rtu, &f);
        assert!(codec::decode(Mode::Rtu, &b, Direction::Response, &mut scratch).is_err());
    }
}
