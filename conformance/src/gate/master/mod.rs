//! The master gate: `conformance gate --master CMD` runs a Modbus master (a library
//! behind an adapter, `adapters/PROTOCOL.md`, role "master") against the simulated drive
//! on a pseudo-terminal pair, under a schedule of faults, and judges every request it
//! puts on the line and every value it reports.
//!
//! - [`protocol`]: the gate's side of the master adapter protocol.
//! - [`drive`]: the drive's end of the line, which answers as the model says and
//!   misbehaves as each case says; its read replies carry tags, values no other frame of
//!   the run carries.
//! - [`cases`]: the schedule: each operation (read, write-single, write-multiple,
//!   loop-back, broadcast) paired with each behaviour of the drive, followed by a normal
//!   read (the recovery).
//! - [`verdict`]: the judgement of each operation; requests through the monitor's judge
//!   of a master's request, so that a request gets one verdict whoever heard it.
//! - [`summary`]: what the report says besides the results (the master's line and
//!   settings, its findings by kind).
//! - [`reference`]: this suite's own master, the test double (`conformance adapter
//!   --master [--master-quirk Q]`), used in tests only.

pub mod cases;
pub mod drive;
pub mod fuzzing;
pub mod protocol;
pub mod reference;
pub mod summary;
pub mod verdict;

use std::collections::BTreeMap;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::time::{Duration, Instant};

/// How the summary of a case begins that the gate did not judge because its own drive
/// was not scheduled during it (an overloaded host): a caller may run the gate again.
pub const UNSCHEDULED: &str = "not judged: the gate's drive was not scheduled";

pub use cases::{MasterCase, Plan};
pub use protocol::{MasterAdapter, MasterSettings, Operation, Reported};
pub use summary::{summary, KindSummary, MasterSummary};
pub use verdict::MasterFinding;

use crate::codec::hex::Hex;
use crate::codec::timing::LineSettings;
use crate::codec::Mode;
use crate::gate::adapter::CallError;
use crate::judge::{Finding, Severity};
use crate::model::DriveModel;
use crate::monitor::{Monitor, MonitorConfig};
use crate::runner::{CheckResult, ExchangeRecord, Status};
use drive::{Behaviour, DriveSide, Sent};
use verdict::{OpRecord, Role};

/// Options of a master gate run.
#[derive(Debug, Clone)]
pub struct MasterOptions {
    /// The drive's model.
    pub model: DriveModel,
    /// The drive's node address.
    pub node: u8,
    /// The modes to run.
    pub modes: Vec<Mode>,
    /// Only cases whose id matches one of these.
    pub only: Vec<String>,
    /// The master's own timeout and retries (asked for in `open`).
    pub settings: MasterSettings,
    /// The line settings given to the master (their timing judges t3.5).
    pub line: LineSettings,
    /// The command line that reproduces a case, without `--only` (e.g. `conformance
    /// gate --master 'python3 a.py'`).
    pub repro: String,
    /// The line the gate serves: a pty, or RTU/ASCII frames over TCP.
    pub line_kind: drive::LineKind,
    /// Exception codes to answer with besides the model's (`--exception-code`): codes
    /// other devices on the bus use (05H, 07H, 0AH, 0BH), to see a master handle them.
    pub extra_exceptions: Vec<u8>,
    /// Give the master a new line (a new pseudo-terminal pair or TCP port) and open it
    /// again before each case after the first (`--reopen-each-case`), so that what a fault
    /// left behind (a reply one request late, bytes queued in the kernel or stuck in the
    /// library's buffer) is not blamed on the next case. Off, a run shows what a master
    /// that never reopens does: a state a fault leaves is carried on (found as
    /// `no-recovery` in the case that left it, and in the cases after it).
    pub reopen: bool,
}

/// Told about each case as it runs.
pub trait MasterProgress {
    /// A case is about to run.
    fn started(&mut self, case: &MasterCase);
    /// A case ended.
    fn finished(&mut self, result: &CheckResult);
}

/// Why a master gate run could not start.
#[derive(Debug, thiserror::Error)]
pub enum MasterGateError {
    /// The pseudo-terminal pair could not be opened.
    #[error("cannot open a pseudo-terminal pair for the master: {0}")]
    Line(#[from] crate::transport::TransportError),
    /// The settings make no sense (a node address out of range).
    #[error("{0}")]
    Config(String),
}

/// The outcome of a run.
#[derive(Debug, Default)]
pub struct MasterRun {
    /// One result per case, in order.
    pub results: Vec<CheckResult>,
    /// Per kind of finding: the cases, in order, and the first one's text.
    pub by_kind: BTreeMap<String, KindSummary>,
    /// Per mode: the settings the master ran with (as it reported them in `open`).
    pub settings: BTreeMap<String, MasterSettings>,
}

fn mode_key(m: Mode) -> &'static str {
    match m {
        Mode::Rtu => "rtu",
        Mode::Ascii => "ascii",
    }
}

/// The cases of a run, selected by `only`.
pub fn cases(opts: &MasterOptions) -> Vec<MasterCase> {
    let mut plan = Plan::of(&opts.model, opts.node);
    plan.exception_codes.extend(&opts.extra_exceptions);
    plan.exception_codes.sort_unstable();
    plan.exception_codes.dedup();
    let mut all = cases::cases(&plan, &opts.settings, &opts.line, &opts.modes);
    all.retain(|c| crate::runner::selected(&c.id, &opts.only));
    all
}

/// The reproducer of a case.
pub fn repro(opts: &MasterOptions, id: &str) -> String {
    format!("{} --only {id}", opts.repro)
}

/// The result of a case that was not judged (`status` SKIP or ERROR, `why`), with no
/// finding.
fn unjudged(
    case: &MasterCase,
    status: Status,
    why: String,
    t0: Instant,
) -> (CheckResult, Vec<MasterFinding>) {
    (
        result(case, status, why, vec![], vec![], t0.elapsed()),
        vec![],
    )
}

fn result(
    case: &MasterCase,
    status: Status,
    summary: String,
    findings: Vec<Finding>,
    exchanges: Vec<ExchangeRecord>,
    took: Duration,
) -> CheckResult {
    CheckResult {
        id: case.id.clone(),
        title: case.title.clone(),
        mode: Some(case.mode),
        source: case.fault.source.to_string(),
        status,
        summary,
        findings,
        exchanges,
        duration: took,
        node: None,
    }
}

/// Gives every case of `cases` the same `status` and summary `why` (a mode the master
/// does not speak, a line it cannot open, a line that could not be opened).
fn settle_all(
    cases: &[&MasterCase],
    status: Status,
    why: &str,
    progress: &mut dyn MasterProgress,
    out: &mut MasterRun,
) {
    for case in cases {
        progress.started(case);
        let r = result(
            case,
            status,
            why.to_string(),
            vec![],
            vec![],
            Duration::ZERO,
        );
        progress.finished(&r);
        out.results.push(r);
    }
}

/// Runs `cases` through the master; stops before the next case once `stop` is set.
pub fn run(
    adapter: &mut MasterAdapter,
    opts: &MasterOptions,
    cases: &[MasterCase],
    stop: &AtomicBool,
    progress: &mut dyn MasterProgress,
) -> Result<MasterRun, MasterGateError> {
    let mut out = MasterRun::default();
    let model = Arc::new(opts.model.clone());
    for &mode in &opts.modes {
        let mine: Vec<&MasterCase> = cases.iter().filter(|c| c.mode == mode).collect();
        if mine.is_empty() {
            continue;
        }
        if opts.line_kind == drive::LineKind::Mbap && mode == Mode::Ascii {
            let why = "there is no ASCII over Modbus TCP (MBAP carries the RTU-equivalent PDU)"
                .to_string();
            settle_all(&mine, Status::Skip, &why, progress, &mut out);
            continue;
        }
        if !adapter.speaks(mode) {
            let why = format!(
                "the master does not speak {} (its hello's modes: {:?})",
                mode_key(mode),
                adapter.hello.modes
            );
            settle_all(&mine, Status::Skip, &why, progress, &mut out);
            continue;
        }
        if !adapter.opens(opts.line_kind.key()) {
            let why = format!(
                "the master cannot open a {} line (its hello's lines: {:?})",
                opts.line_kind.key(),
                adapter.hello.lines
            );
            settle_all(&mine, Status::Skip, &why, progress, &mut out);
            continue;
        }
        let mut drive =
            DriveSide::start_on(model.clone(), opts.node, mode, opts.line, opts.line_kind)?;
        let opened = adapter.open(drive.endpoint(), mode, opts.line, opts.settings);
        let settings = match opened {
            Ok(s) => s,
            Err(e) => {
                let why = open_failed("could not open the line", &e.to_string(), opts);
                settle_all(&mine, Status::Error, &why, progress, &mut out);
                continue;
            }
        };
        out.settings.insert(mode_key(mode).to_string(), settings);
        let mut monitor_cfg = MonitorConfig {
            mode,
            line: opts.line,
            nodes: vec![opts.node],
            window: settings.timeout,
            response_allowance: Duration::from_millis(5),
            gap_allowance: Duration::from_millis(5),
        };
        if monitor_cfg.window.is_zero() {
            monitor_cfg.window = Duration::from_millis(1);
        }
        let monitor = match Monitor::new(opts.model.clone(), monitor_cfg) {
            Ok(m) => m,
            Err(e) => return Err(MasterGateError::Config(e.to_string())),
        };
        let mut last_called = drive.now();
        let mut first = true;
        for case in mine {
            if stop.load(Ordering::Relaxed) {
                break;
            }
            progress.started(case);
            if opts.reopen && !std::mem::take(&mut first) {
                // The master's line closed, and a new line (a new pseudo-terminal pair, or
                // a new TCP port) opened: nothing a fault left queued on the old one, in
                // the kernel or in the library, reaches this case.
                adapter.close();
                drive =
                    DriveSide::start_on(model.clone(), opts.node, mode, opts.line, opts.line_kind)?;
                if let Err(e) = adapter.open(drive.endpoint(), mode, opts.line, opts.settings) {
                    let r = result(
                        case,
                        Status::Error,
                        open_failed(
                            "could not open the line again (--reopen-each-case)",
                            &e.to_string(),
                            opts,
                        ),
                        vec![],
                        vec![],
                        Duration::ZERO,
                    );
                    progress.finished(&r);
                    out.results.push(r);
                    continue;
                }
                last_called = drive.now();
            }
            // A case during which the gate's own drive was not scheduled is not judged
            // (bytes waited unread, replies went late): it runs again, at most twice.
            let mut r;
            let mut attempt = 0;
            loop {
                let from = drive.now();
                r = run_case(
                    adapter,
                    opts,
                    &drive,
                    &monitor,
                    &settings,
                    case,
                    &mut last_called,
                );
                let stalled = drive.stalled_since(from);
                if stalled <= stall_limit(case, &opts.line, &settings) || r.0.status == Status::Skip
                {
                    break;
                }
                attempt += 1;
                if attempt > 2 {
                    r.0.status = Status::Error;
                    r.0.summary = format!(
                        "{UNSCHEDULED} for {} ms during the case, three times (an overloaded host); run it again",
                        stalled.as_millis()
                    );
                    r.1.clear();
                    r.0.findings.clear();
                    break;
                }
            }
            for f in &r.1 {
                let e = out
                    .by_kind
                    .entry(f.kind.clone())
                    .or_insert_with(|| KindSummary {
                        severity: f.severity,
                        cases: Vec::new(),
                        example: format!("{}: {}", case.id, f.text),
                        repro: repro(opts, &case.id),
                    });
                e.severity = e.severity.max(f.severity);
                if e.cases.last() != Some(&case.id) {
                    e.cases.push(case.id.clone());
                }
            }
            progress.finished(&r.0);
            out.results.push(r.0);
        }
        adapter.close();
    }
    Ok(out)
}

/// The longest the gate's drive may go unscheduled during `case` before the case is run
/// again: where the line is busy, what would let a master that does not wait for t3.5
/// see a silence of t3.5 less one character (the tolerance of the judge); elsewhere a
/// third of the master's timeout (requests read that late could be taken for the next
/// operation's).
fn stall_limit(case: &MasterCase, line: &LineSettings, settings: &MasterSettings) -> Duration {
    if case.fault.busy {
        let t35 = Duration::from_micros(line.t3_5_us());
        let char_time = Duration::from_micros(line.char_time_us());
        t35.saturating_sub(char_time)
            .saturating_sub(Duration::from_millis(5))
            .max(drive::STALL)
    } else {
        (settings.timeout / 3).max(drive::STALL)
    }
}

/// Runs one case: the operation under the fault, then the recovery read.
fn run_case(
    adapter: &mut MasterAdapter,
    opts: &MasterOptions,
    drive: &DriveSide,
    monitor: &Monitor,
    settings: &MasterSettings,
    case: &MasterCase,
    last_called: &mut Duration,
) -> (CheckResult, Vec<MasterFinding>) {
    let t0 = Instant::now();
    let quiet = drive::apart(&drive.line);
    let timed = opts.line_kind == drive::LineKind::Pty;
    // Through a Modbus TCP gateway only whole frames with a right CRC cross, as PDUs: a
    // fault made of a serial line's bytes does not exist there.
    if opts.line_kind == drive::LineKind::Mbap
        && matches!(
            case.fault.behaviour,
            Behaviour::Truncated
                | Behaviour::BadChecksum
                | Behaviour::GarbageBefore(_)
                | Behaviour::GarbageAfter(_)
                | Behaviour::ExceptionNoChecksum(_)
                | Behaviour::Split(_)
        )
    {
        return unjudged(case, Status::Skip, "a Modbus TCP gateway passes whole frames with a right CRC only, as PDUs: this fault is a serial line's (run it on a pty)".to_string(), t0);
    }
    if !timed && (case.fault.busy || matches!(case.fault.behaviour, Behaviour::Split(_))) {
        return unjudged(
            case,
            Status::Skip,
            format!(
                "a {} line carries no line timing (t1.5, t3.5): run it on a pty",
                opts.line_kind.key()
            ),
            t0,
        );
    }
    if !adapter.supports(case.op.name()) {
        return unjudged(
            case,
            Status::Skip,
            format!("the master does not offer {}", case.op.name()),
            t0,
        );
    }
    drive.drop_held();
    drive.arm(Behaviour::Normal);
    drive.settle(quiet);
    if case.fault.busy {
        let n = (cases::BUSY_FOR.as_micros() / cases::BUSY_PACE.as_micros().max(1)) as usize;
        let bytes = match drive.mode {
            Mode::Rtu => vec![0xFF; n],
            // ASCII: one long frame, ':' first and CR LF last, a character at a time.
            Mode::Ascii => {
                let mut b = vec![b'0'; n.max(3)];
                b[0] = b':';
                let k = b.len();
                b[k - 2] = b'\r';
                b[k - 1] = b'\n';
                b
            }
        };
        drive.busy(&bytes, cases::BUSY_PACE);
        // The operation is asked while the drive is well into sending.
        std::thread::sleep(cases::BUSY_FOR / 5);
    }
    let recent = *last_called;
    let mark = drive.now();
    drive.arm(case.fault.behaviour.clone());
    let call = Instant::now();
    let first = adapter.operate(&case.op);
    let took = call.elapsed();
    let ended = drive.now();
    *last_called = mark;
    if case.fault.behaviour == Behaviour::AfterTimeout {
        // The master gave up: the reply comes now, stale, before its next request.
        drive.release_held();
    }
    drive.arm(Behaviour::Normal);
    drive.settle(quiet);
    let reported = match first {
        Ok(Some(r)) => r,
        // The adapter died while the call was in the library: the call crashed
        // (adapters/PROTOCOL.md, "Timeouts and crashes"); the gate restarted it.
        Err(CallError::Crashed(why)) => Reported::Raised {
            kind: "crash".into(),
            message: format!("the adapter exited during the call ({why})"),
        },
        Ok(None) => {
            return unjudged(
                case,
                Status::Skip,
                format!("the adapter answered unsupported for {}", case.op.name()),
                t0,
            )
        }
        Err(e) => return unjudged(case, Status::Error, adapter_error(&e), t0),
    };
    let mark2 = drive.now();
    let call2 = Instant::now();
    let second = adapter.operate(&case.recovery);
    let took2 = call2.elapsed();
    let ended2 = drive.now();
    *last_called = mark2;
    drive.settle(quiet);
    let (log, requests, _) = drive.since(mark.saturating_sub(Duration::from_secs(2)));
    let sent = drive.all_sent();
    let in_first: Vec<_> = requests
        .iter()
        .filter(|r| r.start >= mark && r.start < mark2)
        .cloned()
        .collect();
    let in_second: Vec<_> = requests
        .iter()
        .filter(|r| r.start >= mark2)
        .cloned()
        .collect();
    let rec = OpRecord {
        op: &case.op,
        behaviour: &case.fault.behaviour,
        role: Role::Fault,
        reported: &reported,
        took,
        requests: &in_first,
        sent: &sent,
        log: &log,
        called: mark,
        ended,
        recent,
        timed,
    };
    let mut found = verdict::judge_requests(&rec, monitor, settings);
    found.extend(verdict::judge_report(&rec, settings));
    let mut exchanges = records(&in_first, &sent, &case.fault.title, &reported);
    let mut notes = Vec::new();
    match second {
        Ok(Some(reported2)) => {
            let rec2 = OpRecord {
                op: &case.recovery,
                behaviour: &Behaviour::Normal,
                role: Role::Recovery,
                reported: &reported2,
                took: took2,
                requests: &in_second,
                sent: &sent,
                log: &log,
                called: mark2,
                ended: ended2,
                recent: mark,
                timed,
            };
            let mut more = verdict::judge_requests(&rec2, monitor, settings);
            more.extend(verdict::judge_report(&rec2, settings));
            for f in &mut more {
                f.text = format!("in the read after the fault: {}", f.text);
            }
            found.extend(more);
            exchanges.extend(records(
                &in_second,
                &sent,
                "a normal reply (the read after the fault)",
                &reported2,
            ));
        }
        Ok(None) => notes.push("the recovery read is unsupported".to_string()),
        Err(e) => notes.push(format!("the recovery read: {}", adapter_error(&e))),
    }
    // After a broadcast the master waits the turnaround delay before its next request
    // (the drives are still acting on it): the monitor's rule, an observation (the TECO
    // manuals give no delay).
    if let (true, Some(b), Some(n)) = (
        case.op.broadcast(),
        in_first.iter().rev().find(|r| r.valid),
        in_second.first(),
    ) {
        let gap = n.start.saturating_sub(b.end);
        if gap < crate::monitor::BROADCAST_TURNAROUND {
            found.push(MasterFinding {
                kind: "broadcast-turnaround".into(),
                severity: Severity::Observation,
                text: format!(
                    "its next request began {:.1} ms after the broadcast, under the turnaround delay of {} ms; Modbus over Serial Line V1.02, 2.4.1 (typically 100 to 200 ms; the TECO manuals give none)",
                    gap.as_secs_f64() * 1000.0,
                    crate::monitor::BROADCAST_TURNAROUND.as_millis()
                ),
            });
        }
    }
    if let Some(e) = drive.error() {
        notes.push(format!("the drive's line: {e}"));
    }
    // One finding of a kind per case is enough (a retry storm is one storm).
    let mut seen = std::collections::BTreeSet::new();
    found.retain(|f| seen.insert((f.kind.clone(), f.text.clone())));
    let mut findings: Vec<Finding> = found
        .iter()
        .map(|f| Finding {
            severity: f.severity,
            text: format!("{}: {}", f.kind, f.text),
        })
        .collect();
    findings.sort_by_key(|f| std::cmp::Reverse(f.severity));
    if let Some(first) = findings.first_mut() {
        first
            .text
            .push_str(&format!("; reproduce: {}", repro(opts, &case.id)));
    }
    let status = match findings.iter().map(|f| f.severity).max() {
        Some(Severity::Deviation) => Status::Deviation,
        Some(Severity::Observation) => Status::Observation,
        None if !notes.is_empty() => Status::Error,
        None => Status::Pass,
    };
    let summary = match findings.first() {
        Some(f) => f.text.clone(),
        None if !notes.is_empty() => notes.join("; "),
        None => format!("the master reported {reported}, as the drive sent"),
    };
    (
        result(case, status, summary, findings, exchanges, t0.elapsed()),
        found,
    )
}

/// Why a case could not run because the master's `open` failed, with the cause where the
/// gate knows it. A Linux pseudo-terminal has no parity bit: its driver clears PARENB on
/// every tcsetattr (and says nothing), and glibc's tcsetattr reads the settings back and
/// fails with EINVAL when none of the call took and PARENB is not as asked. pyserial
/// applies all its settings in one call, and again whenever one changes: its first call
/// on the gate's fresh pty also changes the baud rate and succeeds, but pymodbus sets a
/// timeout right after opening, and that second call changes nothing but PARENB.
/// The gate could give such a master no parity in `open` and keep the parity's timing
/// for itself, but the master would then keep the silences of another character length
/// (t3.5 of 10 bits, not 11) and be judged for them: the error says what to run instead.
fn open_failed(what: &str, error: &str, opts: &MasterOptions) -> String {
    let mut why = format!("the adapter {what}: {error}");
    let einval = error.contains("Invalid argument") || error.contains("EINVAL");
    if opts.line_kind == drive::LineKind::Pty
        && opts.line.parity != crate::codec::timing::Parity::None
        && einval
    {
        why.push_str(&format!(
            " (a pseudo-terminal has no parity bit: Linux clears PARENB on every tcsetattr, \
             and glibc then fails the call with EINVAL where nothing else of it took, as \
             when pyserial applies its settings again after opening, which pymodbus does: \
             a Python master cannot open the gate's pty with parity {}; run the gate with \
             -P none, and -s 2 to keep the 11 bits a character of {})",
            opts.line.parity.name(),
            opts.line
        ));
    }
    why
}

fn adapter_error(e: &CallError) -> String {
    format!("the adapter failed: {e}")
}

/// The exchanges of one operation, for the report.
fn records(
    requests: &[drive::Request],
    sent: &[Sent],
    behaviour: &str,
    reported: &Reported,
) -> Vec<ExchangeRecord> {
    requests
        .iter()
        .map(|r| {
            let mine: Vec<&Sent> = sent.iter().filter(|s| s.for_seq == r.seq).collect();
            let received: Vec<u8> = mine.iter().flat_map(|s| s.bytes.clone()).collect();
            let reply = mine
                .iter()
                .find(|s| s.class.valid())
                .map(|s| s.bytes.clone());
            // The time to the reply where one went out (garbage sent before it is not
            // the reply: the findings time the valid reply too); else to the first bytes.
            let sent_at = |valid: bool| {
                mine.iter()
                    .filter(|s| !valid || s.class.valid())
                    .filter_map(|s| s.at)
                    .min()
            };
            let latency = sent_at(true)
                .or_else(|| sent_at(false))
                .map(|t| t.saturating_sub(r.end));
            ExchangeRecord {
                request: r.bytes.clone(),
                expected: None,
                received,
                reply,
                predicted: format!("the drive: {behaviour}"),
                actual: format!(
                    "the master reported {reported}{}",
                    if r.valid {
                        String::new()
                    } else {
                        format!(" (its request {} is not a valid frame)", Hex(&r.bytes))
                    }
                ),
                latency,
            }
        })
        .collect()
}
#[cfg(test)]
mod tests {
    use super::*;

    /// A lone 00H 0.2 ms after the request, the reply 11 ms after it: the exchange's
    /// latency is the reply's, as the finding's text says (not the garbage's); with no
    /// valid reply it is the first bytes'.
    #[test]
    fn an_exchange_is_timed_to_its_reply_not_to_garbage_before_it() {
        let ms = |n: f64| Duration::from_secs_f64(n / 1000.0);
        let request = drive::Request {
            seq: 1,
            start: ms(1000.0),
            end: ms(1008.0),
            bytes: vec![0x01, 0x03, 0x00, 0x00, 0x00, 0x02, 0xC4, 0x0B],
            valid: true,
            address: 1,
        };
        let sent = |class, bytes: Vec<u8>, at| Sent {
            for_seq: 1,
            bytes,
            class,
            values: None,
            exception: None,
            at: Some(ms(at)),
        };
        let reply = vec![0x01, 0x03, 0x04, 0x80, 0x90, 0x80, 0x91, 0x73, 0xB2];
        let both = [
            sent(drive::SentClass::Garbage, vec![0x00], 1008.2),
            sent(drive::SentClass::Reply, reply.clone(), 1019.0),
        ];
        let timeout = Reported::Error {
            kind: protocol::ErrorKind::Timeout,
            message: "no response".into(),
        };
        let r = records(
            std::slice::from_ref(&request),
            &both,
            "a lone 00H",
            &timeout,
        );
        assert_eq!(r[0].reply.as_deref(), Some(&reply[..]));
        assert_eq!(r[0].latency, Some(ms(11.0)));
        let r = records(
            std::slice::from_ref(&request),
            &both[..1],
            "a lone 00H",
            &timeout,
        );
        assert_eq!(r[0].reply, None);
        assert_eq!(r[0].latency, Some(ms(1008.2) - ms(1008.0)));
    }

    fn options(parity: crate::codec::timing::Parity, line_kind: drive::LineKind) -> MasterOptions {
        MasterOptions {
            model: DriveModel::builtin("f510").unwrap(),
            node: 1,
            modes: vec![Mode::Rtu],
            only: vec![],
            settings: MasterSettings {
                timeout: Duration::from_millis(300),
                retries: 0,
            },
            line: LineSettings::new(9600, 8, parity, 1),
            repro: String::new(),
            line_kind,
            extra_exceptions: vec![],
            reopen: false,
        }
    }

    #[test]
    fn a_parity_a_pty_refused_is_named_with_what_to_run_instead() {
        use crate::codec::timing::Parity;
        let einval =
            "the adapter failed: pymodbus could not open /dev/pts/3: (22, 'Invalid argument')";
        let why = open_failed(
            "could not open the line",
            einval,
            &options(Parity::Even, drive::LineKind::Pty),
        );
        assert!(why.starts_with(&format!("the adapter could not open the line: {einval} (")));
        for part in [
            "no parity bit",
            "PARENB",
            "EINVAL",
            "parity even",
            "-P none",
            "-s 2",
            "9600 8E1",
        ] {
            assert!(why.contains(part), "{part:?} missing: {why}");
        }
        // No parity, another line or another cause: the error as the adapter gave it.
        for (parity, kind, error) in [
            (Parity::None, drive::LineKind::Pty, einval),
            (Parity::Even, drive::LineKind::TcpRtu, einval),
            (
                Parity::Even,
                drive::LineKind::Pty,
                "the adapter failed: no such file",
            ),
        ] {
            assert_eq!(
                open_failed("could not open the line", error, &options(parity, kind)),
                format!("the adapter could not open the line: {error}")
            );
        }
    }
}
