//! The generator: a master's poll cycle over simulated drives, on a clock of the line's
//! character times, each frame written as one packet the moment it is made.

use std::collections::HashMap;
use std::io::Write;
use std::sync::Arc;
use std::time::{Duration, Instant};

use super::{DayConfig, DayError, Fault, FaultKind, NodeTruth, Truth};
use crate::capture::{self, Interface, PacketMeta, PcapngWriter};
use crate::codec::crc::crc16_frame_ok;
use crate::codec::deframe::bus_rtu_frame_len;
use crate::codec::hex::Hex;
use crate::codec::pdu::{function, Direction};
use crate::codec::{frame_of_body, Mode};
use crate::model::DriveModel;
use crate::rng::Rng;
use crate::sim::{Drive, SendKind};

/// How long the master waits for a reply before it asks again or moves on.
const MASTER_TIMEOUT_US: u64 = 100_000;
/// Planted faults an hour, by kind; at least one of each kind in any span.
const NOISE_PER_HOUR: f64 = 4.0;
const COLLISIONS_PER_HOUR: f64 = 3.0;
const SILENCES_PER_HOUR: f64 = 0.5;
const RESTARTS_PER_HOUR: f64 = 0.25;
/// The longest a drive stays silent.
const SILENCE_US: u64 = 60_000_000;
/// Every frame's first byte when a noise burst begins: a line left idle (mark) that a
/// spike pulls low reads as a byte of mostly ones, and none of these is a node's address
/// (1..=247), so no listener waits for the rest of a frame after it.
const NOISE_FIRST: [u8; 4] = [0xF8, 0xFC, 0xFE, 0xFF];

/// Writes the capture of a day of a bus to `sink` (pcapng, one interface: a tap on the
/// line, RTU) and returns its truth. `sink` is written block by block: the memory held
/// does not grow with the span.
pub fn generate<W: Write>(
    cfg: &DayConfig,
    model: DriveModel,
    sink: W,
) -> Result<(Truth, W), DayError> {
    if !(1..=32).contains(&cfg.drives) {
        return Err(DayError::Config(format!(
            "drives: 1..32 on one line, not {}",
            cfg.drives
        )));
    }
    if cfg.span < Duration::from_secs(60) {
        return Err(DayError::Config(format!(
            "span: at least 60 s (room for one fault of each kind), not {:?}",
            cfg.span
        )));
    }
    let line_name = format!(
        "{} {}{}{}",
        cfg.line.baud,
        cfg.line.data_bits,
        cfg.line
            .parity
            .name()
            .chars()
            .next()
            .unwrap_or('N')
            .to_ascii_uppercase(),
        cfg.line.stop_bits
    );
    let mut writer = PcapngWriter::new(sink, "conformance capture synth")?;
    writer.add_interface(&Interface {
        link_type: capture::LINKTYPE_USER0,
        name: "synthetic tap".to_string(),
        description: format!(
            "rtu {line_name}, a day of a bus: {} drives ({}), seed {}",
            cfg.drives, model.id, cfg.seed
        ),
    })?;
    let model = Arc::new(model);
    let mut g = Gen {
        char_us: cfg.line.char_time_us(),
        span_us: u64::try_from(cfg.span.as_micros()).unwrap_or(u64::MAX),
        start_unix_us: cfg.start_unix_us,
        drives: (1..=cfg.drives)
            .map(|n| Drive::new(model.clone(), n, Duration::ZERO).with_line(cfg.line, true))
            .collect(),
        base: Instant::now(),
        writer,
        rng: Rng::new(cfg.seed),
        t: 0,
        counts: HashMap::new(),
        last: HashMap::new(),
        faults: Vec::new(),
        plan: Vec::new(),
        silent: None,
        collide_next: false,
        packets: 0,
        bytes: 0,
        end: 0,
        setpoints: vec![(0u16, 0u16); usize::from(cfg.drives)],
        exceptions_at: 0x0039,
        error: None,
    };
    g.plan = plan(&mut g.rng, g.span_us, cfg.drives);
    g.run(cfg.drives)?;
    let mut truth = Truth {
        span_s: cfg.span.as_secs_f64(),
        line: line_name,
        drives: cfg.drives,
        seed: cfg.seed,
        model: model.id.to_string(),
        packets: g.packets,
        bytes: g.bytes,
        heard_s: secs(g.end),
        nodes: Default::default(),
        faults: std::mem::take(&mut g.faults),
    };
    for (a, c) in g.counts {
        truth.nodes.insert(format!("{a:02X}"), c);
    }
    Ok((truth, g.writer.into_inner()))
}

fn secs(us: u64) -> f64 {
    us as f64 / 1e6
}

/// One planned fault: its kind, the earliest it happens, and for a silence its length.
#[derive(Debug, Clone, Copy)]
struct Planned {
    kind: FaultKind,
    at: u64,
    length: u64,
    node: u8,
}

/// The faults of a span, each in a slot of its own (so that none overlaps another), the
/// kinds shuffled over the slots.
fn plan(rng: &mut Rng, span_us: u64, drives: u8) -> Vec<Planned> {
    let hours = span_us as f64 / 3.6e9;
    let n = |rate: f64| ((hours * rate).round() as usize).max(1);
    let mut kinds = Vec::new();
    kinds.extend(std::iter::repeat_n(FaultKind::Noise, n(NOISE_PER_HOUR)));
    kinds.extend(std::iter::repeat_n(
        FaultKind::Collision,
        n(COLLISIONS_PER_HOUR),
    ));
    kinds.extend(std::iter::repeat_n(
        FaultKind::SilentDrive,
        n(SILENCES_PER_HOUR),
    ));
    kinds.extend(std::iter::repeat_n(
        FaultKind::MasterRestart,
        n(RESTARTS_PER_HOUR),
    ));
    // Fisher-Yates, from the seed.
    for i in (1..kinds.len()).rev() {
        let j = rng.below(i as u64 + 1) as usize;
        kinds.swap(i, j);
    }
    // The first and last 5 s are plain traffic: the monitor has heard the bus before the
    // first fault, and every fault is over before the end.
    let margin = 5_000_000u64.min(span_us / 10);
    let usable = span_us - 2 * margin;
    let slot = usable / kinds.len() as u64;
    kinds
        .into_iter()
        .enumerate()
        .map(|(i, kind)| {
            let length = if kind == FaultKind::SilentDrive {
                SILENCE_US.min(slot * 6 / 10)
            } else {
                0
            };
            let room = slot - length;
            Planned {
                kind,
                at: margin + i as u64 * slot + rng.below(room / 2),
                length,
                node: 1 + rng.below(u64::from(drives)) as u8,
            }
        })
        .collect()
}

/// The generator's state.
struct Gen<W: Write> {
    char_us: u64,
    span_us: u64,
    start_unix_us: u64,
    drives: Vec<Drive>,
    /// The instant the drives' clock starts at (they measure only durations from it).
    base: Instant,
    writer: PcapngWriter<W>,
    rng: Rng,
    /// When the line is next free, microseconds from the first packet.
    t: u64,
    counts: HashMap<u8, NodeTruth>,
    /// Per address, the last request's bytes and whether it was answered (the monitor's
    /// rule for a retry).
    last: HashMap<u8, (Vec<u8>, bool)>,
    faults: Vec<Fault>,
    plan: Vec<Planned>,
    /// The silent node, until when, and the index of its fault.
    silent: Option<(u8, u64, usize)>,
    /// The next reply collides.
    collide_next: bool,
    packets: u64,
    bytes: u64,
    /// The end of the last packet.
    end: u64,
    /// Per drive: the frequency command and the operation word the master last wrote.
    setpoints: Vec<(u16, u16)>,
    /// The register the odd exception is provoked with (not in the F510's group 0).
    exceptions_at: u16,
    /// The first write that failed: the run stops at its next cycle and returns it.
    error: Option<capture::WriteError>,
}

/// What became of one request.
enum Answer {
    /// A valid reply.
    Reply,
    /// No reply due (a broadcast).
    NoneDue,
    /// Nothing, or a garbled reply: the master waited its timeout.
    Failed,
}

impl<W: Write> Gen<W> {
    fn run(&mut self, drives: u8) -> Result<(), DayError> {
        let mut cycle = 0u64;
        let mut restarted = true;
        while self.t < self.span_us {
            if let Some(e) = self.error.take() {
                return Err(e.into());
            }
            if restarted {
                // After power-up or a restart, the master writes each drive's setpoints.
                restarted = false;
                for n in 1..=drives {
                    let (f, op) = self.setpoints[usize::from(n - 1)];
                    self.poll(n, &write_single(n, 0x2502, f))?;
                    self.poll(n, &write_single(n, 0x2501, op))?;
                }
            }
            for n in 1..=drives {
                if self.fault_due(n)? {
                    restarted = true;
                    break;
                }
                self.poll(n, &read(n, 0x2520, 5))?;
                if cycle % 4 == u64::from(n) % 4 {
                    self.poll(n, &read(n, 0x2526, 8))?;
                }
                self.occasional(n)?;
            }
            if restarted {
                cycle = 0;
                continue;
            }
            if self.rng.below(2000) == 0 {
                let v = self.rng.below(1001) as u16;
                self.poll(0, &write_single(0, 0x2505, v))?;
            }
            cycle += 1;
            self.t += self.cycle_pause();
        }
        // The last exchange is answered, so that the monitor judges every request it heard.
        let n = (1..=drives).find(|&n| !self.is_silent(n)).unwrap_or(1);
        self.silent = None;
        self.poll(n, &read(n, 0x2520, 5))?;
        self.error.take().map_or(Ok(()), |e| Err(e.into()))
    }

    /// The rare requests of a cycle to node `n`.
    fn occasional(&mut self, n: u8) -> Result<(), DayError> {
        let i = usize::from(n - 1);
        if self.rng.below(40) == 0 {
            let f = 50 * self.rng.below(121) as u16;
            self.setpoints[i].0 = f;
            self.poll(n, &write_single(n, 0x2502, f))?;
        }
        if self.rng.below(150) == 0 {
            let op = self.setpoints[i].1 ^ 1;
            self.setpoints[i].1 = op;
            self.poll(n, &write_single(n, 0x2501, op))?;
        }
        if self.rng.below(400) == 0 {
            let f = 50 * self.rng.below(121) as u16;
            self.setpoints[i] = (f, 1);
            self.poll(n, &write_multiple(n, 0x2501, &[1, f]))?;
        }
        if self.rng.below(300) == 0 {
            let start = self.rng.below(0x30) as u16;
            self.poll(n, &read(n, start, 8))?;
        }
        if self.rng.below(800) == 0 {
            self.poll(n, &read(n, self.exceptions_at, 1))?;
        }
        Ok(())
    }

    /// The master's pause between two cycles: short by day, longer at night (its clock
    /// from the capture's start time), and now and then a long one (an HMI page change).
    fn cycle_pause(&mut self) -> u64 {
        let hour = ((self.start_unix_us + self.t) / 3_600_000_000) % 24;
        let night = !(6..22).contains(&hour);
        let base = if night {
            20_000 + self.rng.below(40_000)
        } else {
            self.rng.below(5_000)
        };
        if self.rng.below(500) == 0 {
            base + 200_000 + self.rng.below(800_000)
        } else {
            base
        }
    }

    /// The master's silence before a request: at least t3.5 and some.
    fn master_gap(&mut self) -> u64 {
        2_000 + self.rng.below(3_000)
    }

    /// Node `n`'s delay from the end of a request to its reply: its own, with jitter, now
    /// and then slower; always under the manual's 10 ms.
    fn reply_delay(&mut self, n: u8) -> u64 {
        let slow = if self.rng.below(500) == 0 { 2_500 } else { 0 };
        2_000 + 400 * u64::from(n.min(8)) + self.rng.below(1_500) + slow
    }

    fn is_silent(&self, n: u8) -> bool {
        self.silent
            .is_some_and(|(s, until, _)| s == n && self.t < until)
    }

    /// Plants the faults whose time has come, before node `n`'s turn; whether the master
    /// restarted.
    fn fault_due(&mut self, n: u8) -> Result<bool, DayError> {
        if let Some((_, until, _)) = self.silent {
            if self.t >= until {
                self.silent = None;
            }
        }
        let Some(p) = self.plan.first().copied() else {
            return Ok(false);
        };
        if self.t < p.at {
            return Ok(false);
        }
        self.plan.remove(0);
        match p.kind {
            FaultKind::Noise => {
                self.t += 3_000 + self.rng.below(5_000);
                let noise = self.noise();
                let at = self.t;
                self.frame(&noise);
                self.count_request(noise[0], &noise, true);
                self.settle(noise[0], Answer::NoneDue);
                self.faults.push(Fault {
                    kind: FaultKind::Noise,
                    at_s: secs(at),
                    node: noise[0],
                    bytes: Hex(&noise).to_string(),
                    until_s: None,
                    unanswered: 0,
                });
                self.t += 3_000 + self.rng.below(5_000);
            }
            FaultKind::Collision => self.collide_next = true,
            FaultKind::SilentDrive => {
                self.silent = Some((p.node, self.t + p.length, self.faults.len()));
                self.faults.push(Fault {
                    kind: FaultKind::SilentDrive,
                    at_s: secs(self.t),
                    node: p.node,
                    bytes: String::new(),
                    until_s: Some(secs(self.t + p.length)),
                    unanswered: 0,
                });
            }
            FaultKind::MasterRestart => {
                // The master dies while it sends node n's next request.
                let req = read(n, 0x2520, 5);
                let cut = 4 + self.rng.below(req.len() as u64 - 4) as usize;
                let part = &req[..cut];
                self.t += self.master_gap();
                let at = self.t;
                self.frame(part);
                self.count_request(n, part, true);
                self.settle(n, Answer::NoneDue);
                let down = 3_000_000 + self.rng.below(12_000_000);
                self.t += down;
                self.faults.push(Fault {
                    kind: FaultKind::MasterRestart,
                    at_s: secs(at),
                    node: n,
                    bytes: Hex(part).to_string(),
                    until_s: None,
                    unanswered: 0,
                });
                return Ok(true);
            }
        }
        Ok(false)
    }

    /// A noise burst: 4..16 bytes, neither a frame with a valid CRC nor one the length
    /// rule would cut, and whose second byte is none of the master's functions (so that
    /// nothing takes the master's next request for its reply).
    fn noise(&mut self) -> Vec<u8> {
        loop {
            let len = 4 + self.rng.below(13) as usize;
            let mut b: Vec<u8> = (0..len).map(|_| self.rng.byte()).collect();
            b[0] = NOISE_FIRST[self.rng.below(NOISE_FIRST.len() as u64) as usize];
            let fc = b[1] & !function::EXCEPTION_BIT;
            let cut = [Direction::Request, Direction::Response]
                .iter()
                .any(|&d| bus_rtu_frame_len(d, &b).is_some_and(|l| l < b.len()));
            if !crc16_frame_ok(&b) && !cut && ![0x03, 0x06, 0x08, 0x10].contains(&fc) {
                return b;
            }
        }
    }

    /// One request to node `n` (0: broadcast) as the master makes it: asked once more
    /// after a timeout or a garbled reply.
    fn poll(&mut self, n: u8, req: &[u8]) -> Result<(), DayError> {
        for _attempt in 0..2 {
            match self.exchange(n, req)? {
                Answer::Reply | Answer::NoneDue => return Ok(()),
                Answer::Failed => {}
            }
        }
        Ok(())
    }

    fn exchange(&mut self, n: u8, req: &[u8]) -> Result<Answer, DayError> {
        // The first packet is at 0: the times of the truth are a listener's, from it.
        if self.packets > 0 {
            self.t += self.master_gap();
        }
        let req_start = self.t;
        self.frame(req);
        self.count_request(n, req, false);
        let req_end = self.t;
        let now = self.base + Duration::from_micros(req_end);
        if n == 0 {
            for d in &mut self.drives {
                d.handle(Mode::Rtu, req, now);
            }
            self.settle(0, Answer::NoneDue);
            // The turnaround delay after a broadcast.
            self.t += 110_000 + self.rng.below(90_000);
            return Ok(Answer::NoneDue);
        }
        if self.is_silent(n) {
            if let Some((_, _, i)) = self.silent {
                self.faults[i].unanswered += 1;
            }
            return Ok(self.fail(n, req_end, true));
        }
        let outcome = self.drives[usize::from(n - 1)].handle(Mode::Rtu, req, now);
        let reply = outcome
            .sends
            .into_iter()
            .find(|s| s.kind == SendKind::Reply)
            .map(|s| s.bytes);
        let Some(reply) = reply else {
            // The model says no reply is due (none of the master's requests is such).
            let due = outcome.judgement.expect.replies();
            if due {
                return Ok(self.fail(n, req_end, true));
            }
            self.settle(n, Answer::NoneDue);
            return Ok(Answer::NoneDue);
        };
        self.t = req_end + self.reply_delay(n);
        if self.collide_next {
            self.collide_next = false;
            let garbled = self.garble(&reply);
            self.frame(&garbled);
            self.counts.entry(n).or_default().crc_errors += 1;
            self.faults.push(Fault {
                kind: FaultKind::Collision,
                at_s: secs(req_start),
                node: n,
                bytes: Hex(&garbled).to_string(),
                until_s: None,
                unanswered: 0,
            });
            return Ok(self.fail(n, req_end, false));
        }
        self.frame(&reply);
        let c = self.counts.entry(n).or_default();
        c.replies += 1;
        if reply
            .get(1)
            .is_some_and(|f| f & function::EXCEPTION_BIT != 0)
        {
            c.exceptions += 1;
        }
        self.settle(n, Answer::Reply);
        Ok(Answer::Reply)
    }

    /// The master heard no valid reply: it waits its timeout from the request's end.
    fn fail(&mut self, n: u8, req_end: u64, nothing: bool) -> Answer {
        if nothing {
            self.counts.entry(n).or_default().timeouts += 1;
        }
        self.settle(n, Answer::Failed);
        self.t = self.t.max(req_end + MASTER_TIMEOUT_US);
        Answer::Failed
    }

    /// `reply` as heard while another transmitter sent at the same time: the line carries
    /// the AND of both (a driven 0 wins), and the CRC no longer holds.
    fn garble(&mut self, reply: &[u8]) -> Vec<u8> {
        loop {
            let g: Vec<u8> = reply.iter().map(|&b| b & self.rng.byte()).collect();
            if !crc16_frame_ok(&g) {
                return g;
            }
        }
    }

    /// Counts a frame that begins an exchange at `address`: a request, and a retry where
    /// it repeats the node's last request, which got no reply.
    fn count_request(&mut self, address: u8, bytes: &[u8], corrupt: bool) {
        let c = self.counts.entry(address).or_default();
        c.requests += 1;
        c.exchanges += 1;
        let unmapped = bytes.len() == 8
            && bytes[1] == function::READ_HOLDING_REGISTERS
            && u16::from_be_bytes([bytes[2], bytes[3]]) == self.exceptions_at;
        if corrupt {
            c.crc_errors += 1;
        } else if unmapped {
            c.unmapped_reads += 1;
        } else if bytes.get(1).is_some_and(|&f| {
            f == function::WRITE_SINGLE_REGISTER || f == function::WRITE_MULTIPLE_REGISTERS
        }) {
            c.writes += 1;
        }
        let e = self
            .last
            .entry(address)
            .or_insert_with(|| (Vec::new(), true));
        if e.0 == bytes && !e.1 {
            c.retries += 1;
        }
        e.0.clear();
        e.0.extend_from_slice(bytes);
        e.1 = false;
    }

    /// Whether the last request to `address` counts as answered (a valid reply, or none
    /// was due).
    fn settle(&mut self, address: u8, a: Answer) {
        if let Some(e) = self.last.get_mut(&address) {
            e.1 = !matches!(a, Answer::Failed);
        }
    }

    /// Writes `bytes` as one packet beginning at `self.t`; the line is busy until its last
    /// character is through.
    fn frame(&mut self, bytes: &[u8]) {
        let meta = PacketMeta {
            interface: 0,
            timestamp_us: self.start_unix_us + self.t,
            flags: 0,
            comment: None,
        };
        // Written now or never: an error is kept and returned by `run` at its next check.
        if let Err(e) = self.writer.write_packet(&meta, bytes) {
            self.error = Some(e);
        }
        self.packets += 1;
        self.bytes += bytes.len() as u64;
        self.t += self.char_us * bytes.len() as u64;
        self.end = self.t;
    }
}

/// A read (03H) of `count` registers from `start`.
fn read(n: u8, start: u16, count: u16) -> Vec<u8> {
    let s = start.to_be_bytes();
    let c = count.to_be_bytes();
    rtu(&[n, function::READ_HOLDING_REGISTERS, s[0], s[1], c[0], c[1]])
}

/// A write (06H) of `value` to `register`.
fn write_single(n: u8, register: u16, value: u16) -> Vec<u8> {
    let r = register.to_be_bytes();
    let v = value.to_be_bytes();
    rtu(&[n, function::WRITE_SINGLE_REGISTER, r[0], r[1], v[0], v[1]])
}

/// A write (10H) of `values` from `start`.
fn write_multiple(n: u8, start: u16, values: &[u16]) -> Vec<u8> {
    let s = start.to_be_bytes();
    let count = values.len() as u16;
    let mut body = vec![
        n,
        function::WRITE_MULTIPLE_REGISTERS,
        s[0],
        s[1],
        (count >> 8) as u8,
        count as u8,
        (2 * values.len()) as u8,
    ];
    for v in values {
        body.extend_from_slice(&v.to_be_bytes());
    }
    rtu(&body)
}

fn rtu(body: &[u8]) -> Vec<u8> {
    // The bodies above are at most 11 bytes: framing cannot fail.
    frame_of_body(Mode::Rtu, body).unwrap_or_default()
}
