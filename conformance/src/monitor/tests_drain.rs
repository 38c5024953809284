//! Listening stopped by `--duration` on a bus polled back to back ([`run_from`]): the line
//! is never quiet for long, so wherever the clock stops it, a frame may be arriving. The
//! monitor listens on until the frame under way has ended, and a frame that the limit
//! cuts anyway is not judged: no stop, at any moment, makes a drive that answered in full
//! look like one that cut its reply short.

use std::sync::atomic::AtomicBool;
use std::time::{Duration, Instant};

use super::tap::{run_from, Ended, Tap};
use super::tests::{kinds, read, values};
use super::*;
use crate::codec::timing::Parity;
use crate::transport::TransportError;

/// A line as a UART hears it: a master reading 252FH of node 1 over and over, t3.5 and a
/// little between frames, each byte there to read once its last bit is in (a character
/// time after the one before), counted from when the line was made.
struct PolledLine {
    origin: Instant,
    cycle: Vec<(Duration, u8)>,
    cycle_len: Duration,
    /// Bytes read so far.
    read: u64,
}

impl PolledLine {
    fn new(line: LineSettings) -> Self {
        let char_us = line.char_time_us();
        let (request, reply) = (read(1, 0x252F, 1), values(1, &[0x0510]));
        let mut cycle = Vec::new();
        let mut t = 0;
        // The drive answers 6 ms after the request; the master asks again 3 ms after the
        // reply (t3.5 is 2.0 ms at 19200 baud).
        for (frame, gap_after_us) in [(&request, 6_000), (&reply, 3_000)] {
            for &b in frame {
                t += char_us;
                cycle.push((Duration::from_micros(t), b));
            }
            t += gap_after_us;
        }
        PolledLine {
            origin: Instant::now(),
            cycle,
            cycle_len: Duration::from_micros(t),
            read: 0,
        }
    }

    /// When byte `i` of the stream is in, and what it is.
    fn byte(&self, i: u64) -> (Duration, u8) {
        let n = self.cycle.len() as u64;
        let (at, b) = self.cycle[(i % n) as usize];
        (self.cycle_len * (i / n) as u32 + at, b)
    }
}

impl Tap for PolledLine {
    fn listen(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        let asked = self.origin.elapsed();
        let (next, _) = self.byte(self.read);
        if next > asked {
            std::thread::sleep((next - asked).min(timeout));
        }
        let now = self.origin.elapsed();
        let mut n = 0;
        while n < buf.len() && self.byte(self.read).0 <= now {
            buf[n] = self.byte(self.read).1;
            self.read += 1;
            n += 1;
        }
        Ok(n)
    }

    fn describe(&self) -> String {
        "a line polled back to back".into()
    }
}

#[test]
fn listening_stopped_at_any_moment_of_a_busy_line_judges_no_reply_cut() {
    let line = LineSettings::new(19200, 8, Parity::Odd, 1);
    let stop = AtomicBool::new(false);
    let mut cut = 0;
    // Stops a little over a millisecond apart, across more than one 17.5 ms cycle.
    for k in 0..16u64 {
        let mut m = Monitor::new(
            crate::model::DriveModel::builtin("f510").unwrap(),
            MonitorConfig::new(Mode::Rtu, line, vec![1]),
        )
        .unwrap();
        let mut tap = PolledLine::new(line);
        let origin = tap.origin;
        let duration = Duration::from_micros(150_000 + 1_100 * k);
        let ended = run_from(
            &mut tap,
            &mut m,
            &stop,
            Some(duration),
            origin,
            Vec::new(),
            |_| {},
        )
        .unwrap();
        assert_eq!(ended, Ended::Duration);
        let t = m.tally();
        cut += t.cut;
        let node = &m.nodes()[&1];
        assert_eq!(
            (node.deviations, kinds(&m, 1)),
            (0, Vec::<String>::new()),
            "stopped at {duration:?}: {t:?} {:?}",
            m.notices()
        );
        assert!(node.exchanges >= 4, "{t:?} {:?}", m.notices());
        assert_eq!(
            m.frames_heard(),
            t.requests + t.replies + t.damaged + t.unpaired + t.cut,
            "{t:?}"
        );
        assert_eq!(t.requests, t.answered + t.unanswered + t.unjudged, "{t:?}");
    }
    // How many stops cut a frame depends on how the host ran the listener; none was
    // judged (above).
    eprintln!("frames cut by the end of listening, of 16 stops: {cut}");
}
