//! The runner on a busy host: a request the host could not send whole, a paced simulator
//! on a loaded machine, answers a busy host delays past the timeout on a pty, a preflight
//! answered late, a restore write that gets no reply, a check the host stalled under: each
//! is sent again or marked an ERROR, never a deviation. (The runner's verdicts and reports:
//! tests/runner.rs.)

mod common;
mod sessions;
use common::{line, Scratch};

use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread;
use std::time::{Duration, Instant};

use conformance::codec::timing::LineSettings;
use conformance::codec::Mode;
use conformance::model::DriveModel;
use conformance::runner::{MasterTiming, Status};

use sessions::*;

/// A link on which this host stalls while pacing some requests (issue 24): a request it
/// breaks never reaches the simulator whole (here: not at all, as a receiver that frames
/// by silence drops it) and the link says so. `breaks(len, nth_send_of_it)` decides.
struct Stalling<F: Fn(usize, u32) -> bool + Send> {
    inner: conformance::transport::memory::MemoryEnd,
    breaks: F,
    last: Vec<u8>,
    nth: u32,
    broken: bool,
}

impl<F: Fn(usize, u32) -> bool + Send> conformance::transport::Transport for Stalling<F> {
    fn send(&mut self, bytes: &[u8]) -> Result<(), conformance::transport::TransportError> {
        self.nth = if self.last == bytes { self.nth + 1 } else { 1 };
        self.last = bytes.to_vec();
        self.broken = (self.breaks)(bytes.len(), self.nth);
        if self.broken {
            return Ok(());
        }
        self.inner.send(bytes)
    }
    fn recv(
        &mut self,
        buf: &mut [u8],
        timeout: Duration,
    ) -> Result<usize, conformance::transport::TransportError> {
        self.inner.recv(buf, timeout)
    }
    fn discard_input(&mut self) -> Result<(), conformance::transport::TransportError> {
        self.inner.discard_input()
    }
    fn describe(&self) -> String {
        "a link whose host stalls".into()
    }
    fn kind(&self) -> conformance::transport::LinkKind {
        conformance::transport::LinkKind::Memory
    }
    fn send_was_broken(&self) -> bool {
        self.broken
    }
    fn line_timing(&self) -> Option<LineSettings> {
        None
    }
}

/// Runs F510's RTU checks against the simulator over a [`Stalling`] link.
fn run_stalling(
    breaks: impl Fn(usize, u32) -> bool + Send + 'static,
) -> Vec<conformance::runner::CheckResult> {
    use conformance::runner::{run_mode, CheckResult, Progress};
    use conformance::sim::{serve, Drive, TrafficLog};
    struct Quiet;
    impl Progress for Quiet {
        fn started(&mut self, _: &conformance::runner::Check) {}
        fn finished(&mut self, _: &CheckResult) {}
    }
    let model = Arc::new(DriveModel::builtin("f510").unwrap());
    let (a, mut b) = conformance::transport::memory::pair();
    let stop = Arc::new(AtomicBool::new(false));
    let s = stop.clone();
    let m = model.clone();
    let sim = thread::spawn(move || {
        let mut drive = Drive::new(m, 1, Duration::from_millis(1));
        let _ = serve(&mut b, &mut drive, Mode::Rtu, &mut TrafficLog::new(), &s);
    });
    let link = Stalling {
        inner: a,
        breaks,
        last: Vec::new(),
        nth: 0,
        broken: false,
    };
    let mut opts = options(&[]);
    // The simulator answers within a millisecond or two over memory: short windows keep
    // the three runs quick (a broken send is listened to for a silence window).
    opts.timing.silence = Duration::from_millis(30);
    let run = run_mode(
        &model,
        None,
        Mode::Rtu,
        Box::new(link),
        &opts,
        &AtomicBool::new(false),
        &mut Quiet,
    );
    stop.store(true, Ordering::Relaxed);
    sim.join().unwrap();
    assert!(run.stopped.is_none(), "{:?}", run.stopped);
    run.results
}

/// Issue 24: a request this host could not put on the line whole is never the device's
/// silence. Deterministic: the link breaks sends on purpose, no load needed.
#[test]
fn a_request_the_host_could_not_send_whole_is_an_error_never_a_deviation() {
    let clean = run_stalling(|_, _| false);
    assert!(clean.iter().all(|c| c.status != Status::Deviation));
    // Every long request (10H with many registers) broken every time it is sent.
    let stalled = run_stalling(|len, _| len >= 40);
    let errors: Vec<&conformance::runner::CheckResult> = stalled
        .iter()
        .filter(|c| c.status == Status::Error)
        .collect();
    assert!(
        errors.iter().any(|c| c.id == "rtu.write-count.limit"),
        "{:?}",
        errors.iter().map(|c| &c.id).collect::<Vec<_>>()
    );
    for c in &stalled {
        assert_ne!(c.status, Status::Deviation, "{}: {}", c.id, c.summary);
        if c.status == Status::Error {
            assert!(
                c.summary.contains("could not send the request")
                    && c.summary.contains("whole: the host stalled 8 times"),
                "{}: {}",
                c.id,
                c.summary
            );
        }
    }
    // The checks whose requests went out are judged as on a clean link (not the
    // response times over the mode: those are this host's timing on a memory link, and a
    // busy machine may make one run observe a slow reply that the other does not).
    for (s, c) in stalled.iter().zip(&clean) {
        assert_eq!(s.id, c.id);
        if s.status != Status::Error && !s.id.ends_with(".response-time") {
            assert_eq!(s.status, c.status, "{}: {}", s.id, s.summary);
        }
    }
    // Every request broken twice before it goes out whole: the same verdicts as on a
    // clean link, no error.
    let resent = run_stalling(|_, nth| nth <= 2);
    let statuses = |r: &[conformance::runner::CheckResult]| -> Vec<(String, Status)> {
        r.iter().map(|c| (c.id.clone(), c.status)).collect()
    };
    let judged = |r: &[conformance::runner::CheckResult]| -> Vec<(String, Status)> {
        statuses(r)
            .into_iter()
            .filter(|(id, _)| !id.ends_with(".response-time"))
            .collect()
    };
    assert_eq!(judged(&resent), judged(&clean));
}

/// Busy threads on every core (two per core) until dropped: a loaded machine.
struct Hog {
    stop: Arc<AtomicBool>,
    threads: Vec<thread::JoinHandle<()>>,
}

impl Hog {
    fn start() -> Hog {
        let stop = Arc::new(AtomicBool::new(false));
        let cores = thread::available_parallelism().map_or(2, |n| n.get());
        let threads = (0..2 * cores)
            .map(|_| {
                let s = stop.clone();
                thread::spawn(move || {
                    let mut x = 0u64;
                    while !s.load(Ordering::Relaxed) {
                        x = std::hint::black_box(
                            x.wrapping_mul(6364136223846793005).wrapping_add(1),
                        );
                    }
                })
            })
            .collect();
        Hog { stop, threads }
    }
}

impl Drop for Hog {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

/// Issue 24: `check --sim f510 --mode rtu` reported a DEVIATION ("no reply within
/// 50 ms") on the clean simulator while a build ran alongside. With every core kept busy
/// the paced simulator still has no deviation; an ERROR is allowed only where this host
/// could not put a request on the line whole.
#[test]
fn a_clean_paced_simulator_on_a_loaded_machine_has_no_deviations() {
    let mut opts = options(&[]);
    // The command line's timing: 1 s timeout, silence window derived from the replies.
    opts.timing = MasterTiming {
        timeout: Duration::from_millis(1000),
        silence: Duration::from_millis(1000),
        derive_silence: true,
        quiet: Duration::from_millis(30),
        gap: Duration::from_millis(5),
        retries: 0,
    };
    opts.response_allowance = Duration::from_millis(20);
    let c = config("f510", &[Mode::Rtu], &[], true, opts);
    let r = {
        let _hog = Hog::start();
        run(&c)
    };
    assert!(r.complete, "{:?}", r.stopped);
    assert_eq!(deviations(&r), Vec::<String>::new());
    for c in &r.results {
        if c.status == Status::Error {
            assert!(
                c.summary.contains("could not send the request"),
                "{}: {}",
                c.id,
                c.summary
            );
        }
    }
    assert!(r.unrestored().is_empty(), "{:?}", r.unrestored());
    assert_valid(&r);
}

/// A memory link that calls itself a pseudo-terminal (the other end is a program on this
/// host).
struct OnAPty(conformance::transport::memory::MemoryEnd);

impl conformance::transport::Transport for OnAPty {
    fn send(&mut self, b: &[u8]) -> Result<(), conformance::transport::TransportError> {
        self.0.send(b)
    }
    fn recv(
        &mut self,
        b: &mut [u8],
        t: Duration,
    ) -> Result<usize, conformance::transport::TransportError> {
        self.0.recv(b, t)
    }
    fn discard_input(&mut self) -> Result<(), conformance::transport::TransportError> {
        self.0.discard_input()
    }
    fn describe(&self) -> String {
        "pty (a test)".into()
    }
    fn kind(&self) -> conformance::transport::LinkKind {
        conformance::transport::LinkKind::Pty
    }
    fn line_timing(&self) -> Option<LineSettings> {
        None
    }
}

/// A drive on a memory link, seen as a pseudo-terminal, that answers each request with
/// a read reply of 0004H: `answer(request)` gives the address the reply comes from and
/// how long after the request it is sent, or `None` not to answer. It stops after 20 s or
/// when its link closes.
fn answering_0004(
    mut answer: impl FnMut(&[u8]) -> Option<(u8, Duration)> + Send + 'static,
) -> (OnAPty, thread::JoinHandle<()>) {
    use conformance::transport::Transport;
    let (a, mut b) = conformance::transport::memory::pair();
    let h = thread::spawn(move || {
        let mut buf = [0u8; 64];
        let t0 = Instant::now();
        while t0.elapsed() < Duration::from_secs(20) {
            let n = match b.recv(&mut buf, Duration::from_millis(20)) {
                Ok(n) => n,
                Err(_) => return,
            };
            if n == 0 {
                continue;
            }
            let Some((address, after)) = answer(&buf[..n]) else {
                continue;
            };
            let mut reply = vec![address, 3, 2, 0, 4];
            let c = conformance::codec::crc::crc16(&reply);
            reply.extend_from_slice(&c.to_le_bytes());
            thread::sleep(after);
            if b.send(&reply).is_err() {
                return;
            }
        }
    });
    (OnAPty(a), h)
}

/// Issue 24: with every core busy the simulator's answer came after the 500 ms timeout
/// and was judged "no reply within 500 ms" (a DEVIATION) once the liveness probe that
/// followed was answered. On a pseudo-terminal an answer that turns up late, every time,
/// is an ERROR of this host; one that is on time when sent again is judged as usual.
#[test]
fn an_answer_a_busy_host_delays_past_the_timeout_on_a_pty_is_never_a_deviation() {
    use conformance::codec::pdu::{Message, Pdu};
    use conformance::runner::Ctx;
    let read = |start| {
        Message {
            address: 1,
            pdu: Pdu::ReadRequest { start, count: 1 },
        }
        .to_rtu_vec()
        .unwrap()
    };
    // A peer that answers the liveness probe (2520H) at once and 0400H `late` times
    // after the timeout, then at once.
    let peer = |late: u32| {
        let mut late = late;
        answering_0004(move |req| {
            let slow = req[2..4] == [0x04, 0x00] && late > 0;
            late -= u32::from(slow);
            Some((1, Duration::from_millis(if slow { 250 } else { 0 })))
        })
    };
    let model = DriveModel::builtin("f510").unwrap();
    let mut opts = options(&[]);
    opts.timing.timeout = Duration::from_millis(150);
    opts.timing.silence = Duration::from_millis(100);
    // Late twice, then on time: the answer is judged as any other.
    let (link, h) = peer(2);
    let mut ctx = Ctx::new(&model, None, Mode::Rtu, &opts, Box::new(link));
    let p = ctx.probe(read(0x0400), None).unwrap();
    assert!(p.exchange.reply.is_some(), "{:?}", p.exchange);
    assert!(p.comparison.findings.is_empty(), "{:?}", p.comparison);
    drop(ctx);
    h.join().unwrap();
    // Late every time: an ERROR of this host, naming the request.
    let (link, h) = peer(u32::MAX);
    let mut ctx = Ctx::new(&model, None, Mode::Rtu, &opts, Box::new(link));
    let e = match ctx.probe(read(0x0400), None) {
        Err(e @ conformance::runner::RunError::HostStalled(_)) => e,
        Err(e) => panic!("not a host stall: {e}"),
        Ok(p) => panic!("judged: {:?}", p.comparison),
    };
    assert!(
        e.to_string().contains(
            "the answer to 01 03 04 00 00 01 85 3A came only after the 150 ms timeout, 3 times"
        ),
        "{e}"
    );
    assert!(ctx.lost.is_none());
    drop(ctx);
    h.join().unwrap();
}

/// Issue 24: `identify --sim e510` stopped with "no answer to the preflight" with every
/// core busy: the in-process simulator's answer came after the timeout. On a
/// pseudo-terminal the preflight is sent again (the other end is a program this host
/// delays); a peer that never answers is still no device, and the advice says how many
/// times the read was sent.
#[test]
fn a_preflight_answered_late_on_a_pty_is_sent_again_not_a_dead_device() {
    use conformance::runner::Ctx;
    // A peer that answers every read with 0004H, the first `late` ones after 250 ms
    // (over the 150 ms timeout); `None`: never answers.
    let peer = |late: Option<u32>| {
        let mut late = late;
        answering_0004(move |_| {
            let l = late.as_mut()?;
            let slow = *l > 0;
            *l -= u32::from(slow);
            Some((1, Duration::from_millis(if slow { 250 } else { 0 })))
        })
    };
    let model = DriveModel::builtin("f510").unwrap();
    let mut opts = options(&[]);
    opts.timing.timeout = Duration::from_millis(150);
    opts.timing.silence = Duration::from_millis(100);
    // Late twice, then on time: alive, and the late answers are not left on the line.
    let (link, h) = peer(Some(2));
    let mut ctx = Ctx::new(&model, None, Mode::Rtu, &opts, Box::new(link));
    let v = ctx.preflight().unwrap();
    assert!(v.error.is_none(), "{:?}", v.error);
    assert!(ctx.lost.is_none(), "{:?}", ctx.lost);
    let p = ctx
        .probe(
            conformance::codec::pdu::Message {
                address: 1,
                pdu: conformance::codec::pdu::Pdu::ReadRequest {
                    start: 0x2520,
                    count: 1,
                },
            }
            .to_rtu_vec()
            .unwrap(),
            None,
        )
        .unwrap();
    assert!(
        p.exchange.leading.is_empty() && p.exchange.trailing.is_empty(),
        "{:?}",
        p.exchange
    );
    drop(ctx);
    h.join().unwrap();
    // Never answers: no device, after three sends.
    let (link, h) = peer(None);
    let mut ctx = Ctx::new(&model, None, Mode::Rtu, &opts, Box::new(link));
    let v = ctx.preflight().unwrap();
    let e = v.error.expect("a silent peer passed the preflight");
    assert!(e.contains("3 time(s)"), "{e}");
    assert!(ctx.lost.is_some());
    drop(ctx);
    h.join().unwrap();
}

/// Issue 24: with every core busy the answer-every-address quirk went unseen: the
/// simulator's answer to another address came after the silence window, so the
/// silence was judged (a PASS) and the answer found later. On a pseudo-terminal an answer
/// found waiting before the liveness probe makes the request go once more, listened to
/// for the whole timeout: the answer is judged.
#[test]
fn an_answer_to_another_address_a_busy_host_delays_is_still_judged_on_a_pty() {
    use conformance::codec::pdu::{Message, Pdu};
    use conformance::runner::Ctx;
    // A peer that answers every read with its address and 0004H: those to address 1 at
    // once, the others 180 ms later (over the 100 ms silence window, under the 400 ms
    // timeout).
    let (a, h) = answering_0004(|req| {
        let late = if req[0] == 1 { 0 } else { 180 };
        Some((req[0], Duration::from_millis(late)))
    });
    let model = DriveModel::builtin("f510").unwrap();
    let mut opts = options(&[]);
    opts.timing.timeout = Duration::from_millis(400);
    opts.timing.silence = Duration::from_millis(100);
    let mut ctx = Ctx::new(&model, None, Mode::Rtu, &opts, Box::new(a));
    let frame = Message {
        address: 0x7F,
        pdu: Pdu::ReadRequest {
            start: 0x2520,
            count: 1,
        },
    }
    .to_rtu_vec()
    .unwrap();
    let p = ctx.probe(frame, None).unwrap();
    assert!(p.exchange.reply.is_some(), "{:?}", p.exchange);
    assert!(
        p.comparison
            .findings
            .iter()
            .any(|f| f.text.contains("manual: no reply")),
        "{:?}",
        p.comparison
    );
    drop(ctx);
    h.join().unwrap();
}

/// CI failed once with a register left unrestored on a loaded machine: one step of the
/// restore got no answer and the register was given up at once. A step that gets no
/// reply is tried again (up to three times in all); a device that never answers the
/// restore's write is still reported unrestored, with what to write back by hand.
#[test]
fn a_restore_write_that_gets_no_reply_is_tried_again() {
    use conformance::codec::crc::crc16;
    use conformance::runner::{Ctx, RESTORE_ATTEMPTS};
    use conformance::transport::Transport;
    // A peer holding register 0500H (7 at first; every other register reads 0) that
    // drops its answer to the first `drop` writes of 7 (the restore's value).
    let peer = |drop: u32| {
        let (a, mut b) = conformance::transport::memory::pair();
        let h = thread::spawn(move || {
            let mut buf = [0u8; 64];
            let mut held: u16 = 7;
            let mut drop = drop;
            let t0 = Instant::now();
            while t0.elapsed() < Duration::from_secs(20) {
                let n = match b.recv(&mut buf, Duration::from_millis(20)) {
                    Ok(n) => n,
                    Err(_) => return,
                };
                if n < 8 {
                    continue;
                }
                let register = u16::from_be_bytes([buf[2], buf[3]]);
                let value = u16::from_be_bytes([buf[4], buf[5]]);
                let mut reply = match buf[1] {
                    0x03 => {
                        let v = if register == 0x0500 { held } else { 0 };
                        let [hi, lo] = v.to_be_bytes();
                        vec![1, 3, 2, hi, lo]
                    }
                    0x06 => {
                        if register == 0x0500 {
                            if value == 7 && drop > 0 {
                                drop -= 1;
                                continue;
                            }
                            held = value;
                        }
                        buf[..6].to_vec()
                    }
                    _ => continue,
                };
                let c = crc16(&reply);
                reply.extend_from_slice(&c.to_le_bytes());
                if b.send(&reply).is_err() {
                    return;
                }
            }
        });
        (OnAPty(a), h)
    };
    let model = DriveModel::builtin("f510").unwrap();
    let mut opts = options(&[]);
    opts.timing.timeout = Duration::from_millis(150);
    opts.timing.silence = Duration::from_millis(100);
    let restore_after = |lost: u32| {
        let (link, h) = peer(lost);
        let mut ctx = Ctx::new(&model, None, Mode::Rtu, &opts, Box::new(link));
        assert_eq!(ctx.remember(0x0500).unwrap(), Ok(7));
        assert_eq!(ctx.write(0x0500, 9).unwrap(), Ok(()));
        let records = ctx.restore();
        drop(ctx);
        h.join().unwrap();
        assert_eq!(records.len(), 1, "{records:?}");
        records.into_iter().next().unwrap()
    };
    // The first write back is lost: the second attempt restores it, and says so.
    let r = restore_after(1);
    assert!(r.restored && r.changed, "{r:?}");
    assert!(r.detail.contains("attempt 2 of 3"), "{}", r.detail);
    // Every write back is lost: unrestored, after every attempt, with the value to write.
    let r = restore_after(RESTORE_ATTEMPTS);
    assert!(!r.restored, "{r:?}");
    assert!(
        r.detail.contains("3 attempts; write 0007H back by hand"),
        "{}",
        r.detail
    );
}

/// The status of check `id` in a report, with its summary.
fn check_in<'a>(v: &'a serde_json::Value, id: &str) -> (&'a str, &'a str) {
    let c = common::check_of(v, id);
    (
        c["status"].as_str().unwrap(),
        c["summary"].as_str().unwrap(),
    )
}

/// A check under which this host stalled (issue 33: `rtu.write-count.limit` on a busy
/// 2-core host made `check --sim f510` exit 2) runs again, as the master gate's cases
/// do, and the report counts the runs again; three stalls in a row are an ERROR that
/// says so. The stalls are planted (`--inject-host-stall`, hidden, for tests), so that
/// no test needs a busy host; a real stall on top can only add runs (the check's request
/// is 8 bytes, which a host seldom breaks).
#[test]
fn a_check_the_host_stalled_under_runs_again_and_is_counted() {
    let id = "rtu.map.command.first";
    let dir = Scratch::new("runner-stall");
    let run = |n: u32| {
        let inject = format!("{id}:{n}");
        common::check_device(
            &dir,
            &line(&[
                "--sim f510 --mode rtu --only",
                id,
                "--inject-host-stall",
                &inject,
            ]),
            Duration::from_secs(120),
        )
    };
    let reruns = |v: &serde_json::Value| v["budget"]["rtu"]["host_reruns"].as_u64().unwrap_or(0);
    // One stall: the second run judges the device.
    let (code, v) = run(1);
    let (status, summary) = check_in(&v, id);
    assert_eq!(status, "pass", "{summary}");
    assert_eq!(code, Some(0), "{summary}");
    assert!(reruns(&v) >= 1, "{:#}", v["budget"]);
    // Stalls every time: an ERROR after three runs, which says why.
    let (code, v) = run(3);
    let (status, summary) = check_in(&v, id);
    assert_eq!(status, "error", "{summary}");
    assert_eq!(code, Some(2));
    assert!(summary.contains("the check ran 3 times"), "{summary}");
    assert_eq!(reruns(&v), 2, "{:#}", v["budget"]);
}
