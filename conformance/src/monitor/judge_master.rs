//! The master's side: each request against the manual (the function is served, the
//! registers are in the map, counts within the model's limits, broadcasts are writes, a
//! valid checksum, t3.5 of silence before it). Where the manual does not settle a point,
//! the finding is an observation, as in `check`.

use std::time::Duration;

use super::{is_write, FrameStatus, Issue, Monitor, Side, TapFrame};
use crate::codec::{self, Mode};
use crate::judge::{self, Severity};
use crate::model::{Expectation, Fault, Judgement, SilenceReason};

/// The kind a master's request gets for a fault the drive would answer.
fn fault_kind(fault: Fault) -> &'static str {
    match fault {
        Fault::IllegalFunction => "function-not-served",
        Fault::IllegalRegister => "register-not-in-map",
        Fault::IllegalCount => "count-over-limit",
        Fault::DataOutOfRange => "value-out-of-range",
        Fault::ReadOnly => "write-to-read-only",
        Fault::ReservedWrite => "write-to-reserved",
        Fault::CrossesGroup => "crosses-group",
        Fault::NoAccess => "no-access-register",
        Fault::Malformed => "malformed-request",
    }
}

/// The findings on the master's request `f`; `judgement` is the model's on it as the
/// drive the monitor judges it by.
pub(super) fn judge_request(m: &Monitor, f: &TapFrame, judgement: &Judgement) -> Vec<Issue> {
    let mut out = Vec::new();
    if f.status == FrameStatus::Valid {
        out.extend(t35_before(m, f));
    }
    out.extend(request_issues(m, &f.bytes, f.status, judgement));
    out
}

/// The master's finding on the silence before the valid request `f`: t3.5 (RTU).
pub(super) fn t35_before(m: &Monitor, f: &TapFrame) -> Option<Issue> {
    if m.cfg.mode != Mode::Rtu {
        return None;
    }
    let s = f.silence_before?;
    let line = m.cfg.line;
    let t35 = Duration::from_micros(line.t3_5_us());
    // One character of tolerance: the tap's clock reads the pieces a little late.
    let tolerance = Duration::from_micros(line.char_time_us());
    // The silence before a first request is unbounded (`Duration::MAX`): saturate.
    (s.saturating_add(tolerance) < t35).then(|| Issue {
        side: Side::Master,
        kind: "no-t3.5",
        severity: Severity::Deviation,
        text: format!(
            "the request began {} us after the previous frame, sooner than t3.5 ({} us, less one character of tolerance); Modbus over Serial Line V1.02, 2.5.1.1",
            s.as_micros(),
            t35.as_micros()
        ),
    })
}

/// The master's findings on a request of `bytes` with `status` that do not depend on
/// its timing: after [`t35_before`] (for a valid frame), in [`judge_request`]'s order.
pub(super) fn request_issues(
    m: &Monitor,
    bytes: &[u8],
    status: FrameStatus,
    judgement: &Judgement,
) -> Vec<Issue> {
    let mode = m.cfg.mode;
    let check = if mode == Mode::Rtu { "CRC" } else { "LRC" };
    let mut out = Vec::new();
    let master = |kind, severity, text: String| Issue {
        side: Side::Master,
        kind,
        severity,
        text,
    };
    if status != FrameStatus::Valid {
        let (kind, what) = match status {
            FrameStatus::Incomplete => (
                "incomplete-request",
                "a frame with a silence over t1.5 inside it (or abandoned)".to_string(),
            ),
            _ => (
                if judge::body_of(mode, bytes).is_some() {
                    "bad-checksum"
                } else {
                    "malformed"
                },
                judge::explain_invalid(mode, bytes),
            ),
        };
        out.push(master(
            kind,
            Severity::Deviation,
            format!(
                "the master sent {}: {what}; Modbus over Serial Line V1.02, 2.5.1.2 ({check})",
                judge::show(mode, bytes)
            ),
        ));
        return out;
    }
    let Some(body) = judge::body_of(mode, bytes) else {
        return out;
    };
    let (address, fc) = (body[0], body[1]);
    if address == 0 && !is_write(fc) {
        out.push(master(
            "broadcast-read",
            Severity::Deviation,
            format!(
                "a broadcast (node 00) with function {fc:02X}H: broadcast requests are writes only; Modbus over Serial Line V1.02, 2.1 (no reply can come back)"
            ),
        ));
    }
    // What a drive of the bus answers to this request addressed to itself: a broadcast or
    // a request to another node is judged as if it were addressed to one.
    let node = m.judged_as(address);
    let other;
    let as_addressed = if address == node {
        judgement
    } else {
        let mut b = body.clone();
        b[0] = node;
        match codec::frame_of_body(mode, &b) {
            Ok(frame) => {
                other = m.model.judge(node, mode, &frame);
                &other
            }
            Err(_) => return out,
        }
    };
    match &as_addressed.expect {
        Expectation::Exception { fault, code } => out.push(master(
            fault_kind(*fault),
            Severity::of(as_addressed.basis()),
            format!(
                "a drive answers it with exception {code:02X}H ({fault}): {}; {}",
                as_addressed.detail,
                as_addressed.citations().join("; ")
            ),
        )),
        Expectation::Silence(SilenceReason::FrameTooLong) => out.push(master(
            "frame-too-long",
            Severity::of(as_addressed.basis()),
            format!(
                "{}; {}",
                as_addressed.detail,
                as_addressed.citations().join("; ")
            ),
        )),
        _ => {}
    }
    out
}
