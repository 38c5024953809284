//! An in-memory link: two ends joined by channels, for tests of the simulator and runner
//! without any operating-system device.

use std::collections::VecDeque;
use std::sync::mpsc::{channel, Receiver, RecvTimeoutError, Sender};
use std::time::Duration;

use super::{LinkKind, Transport, TransportError};
use crate::codec::timing::LineSettings;

/// One end of an in-memory link.
pub struct MemoryEnd {
    name: String,
    tx: Sender<Vec<u8>>,
    rx: Receiver<Vec<u8>>,
    pending: VecDeque<u8>,
}

/// Two connected ends: what one sends, the other receives.
pub fn pair() -> (MemoryEnd, MemoryEnd) {
    let (tx_a, rx_b) = channel();
    let (tx_b, rx_a) = channel();
    (
        MemoryEnd {
            name: "memory a".into(),
            tx: tx_a,
            rx: rx_a,
            pending: VecDeque::new(),
        },
        MemoryEnd {
            name: "memory b".into(),
            tx: tx_b,
            rx: rx_b,
            pending: VecDeque::new(),
        },
    )
}

impl Transport for MemoryEnd {
    fn send(&mut self, bytes: &[u8]) -> Result<(), TransportError> {
        self.tx
            .send(bytes.to_vec())
            .map_err(|_| TransportError::Closed {
                link: self.name.clone(),
            })
    }

    fn recv(&mut self, buf: &mut [u8], timeout: Duration) -> Result<usize, TransportError> {
        if self.pending.is_empty() && !buf.is_empty() {
            match self.rx.recv_timeout(timeout) {
                Ok(chunk) => self.pending.extend(chunk),
                Err(RecvTimeoutError::Timeout) => return Ok(0),
                Err(RecvTimeoutError::Disconnected) => {
                    return Err(TransportError::Closed {
                        link: self.name.clone(),
                    })
                }
            }
        }
        let n = buf.len().min(self.pending.len());
        for (slot, b) in buf.iter_mut().zip(self.pending.drain(..n)) {
            *slot = b;
        }
        Ok(n)
    }

    fn discard_input(&mut self) -> Result<(), TransportError> {
        self.pending.clear();
        while self.rx.try_recv().is_ok() {}
        Ok(())
    }

    fn describe(&self) -> String {
        self.name.clone()
    }

    fn kind(&self) -> LinkKind {
        LinkKind::Memory
    }

    fn line_timing(&self) -> Option<LineSettings> {
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_cross_and_a_closed_end_is_reported() {
        let (mut a, mut b) = pair();
        a.send(&[1, 2, 3]).unwrap();
        let mut buf = [0u8; 2];
        assert_eq!(b.recv(&mut buf, Duration::from_millis(100)).unwrap(), 2);
        assert_eq!(buf, [1, 2]);
        assert_eq!(b.recv(&mut buf, Duration::from_millis(100)).unwrap(), 1);
        assert_eq!(b.recv(&mut buf, Duration::from_millis(10)).unwrap(), 0);
        drop(a);
        assert!(matches!(
            b.recv(&mut buf, Duration::from_millis(10)),
            Err(TransportError::Closed { .. })
        ));
    }
}
