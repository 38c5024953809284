//! What the monitor keeps of exchanges it has judged, to judge the same exchanges again
//! without redoing the work: a bus is polled, and the same requests and replies come back
//! again and again.
//!
//! Two memos, each keyed by everything its part of the verdict depends on:
//!
//! - a request's: the model's judgement of it and the master's findings that do not
//!   depend on timing, keyed by the node that judges it, the frame's status and its
//!   bytes (the t3.5 before it is judged for each request);
//! - an exchange's drive side without its timing ([`Judge::untimed_verdict_on`]), keyed by
//!   the node that judges it, the request's bytes, every byte that came back and where
//!   the reply begins in them, the values the traffic has set for the registers a read
//!   reads, and, where nothing came back, how long the monitor listened. Response times,
//!   early replies and gaps are judged for each exchange
//!   ([`Judge::timing_findings`]).
//!
//! Memory stays flat: each memo holds at most [`MEMO_ENTRIES`] entries of keys of at most
//! [`MEMO_KEY_MAX`] bytes, and is emptied when full (a bus polls far fewer kinds of
//! exchange than that; one that does not is judged as without a memo). Exchanges whose
//! key is longer are judged each time. The hash is seeded per monitor, so that no
//! capture can be made to collide on purpose.
//!
//! [`Judge::untimed_verdict_on`]: crate::judge::Judge::untimed_verdict_on
//! [`Judge::timing_findings`]: crate::judge::Judge::timing_findings

use std::collections::HashMap;
use std::hash::{BuildHasher, Hasher};

/// Entries a memo holds before it is emptied.
pub const MEMO_ENTRIES: usize = 1024;

/// The longest key a memo keeps (bytes); longer exchanges are judged each time.
pub const MEMO_KEY_MAX: usize = 768;

/// A fast hash of short byte keys (FxHash's multiply and rotate, from a seed).
#[derive(Clone, Copy)]
pub(crate) struct FastHasher {
    hash: u64,
}

const K: u64 = 0xf135_7aea_2e62_a9c5;

impl FastHasher {
    #[inline]
    fn add(&mut self, word: u64) {
        self.hash = (self.hash.rotate_left(26) ^ word).wrapping_mul(K);
    }
}

impl Hasher for FastHasher {
    #[inline]
    fn write(&mut self, bytes: &[u8]) {
        let mut chunks = bytes.chunks_exact(8);
        for c in &mut chunks {
            let mut w = [0u8; 8];
            w.copy_from_slice(c);
            self.add(u64::from_le_bytes(w));
        }
        let rest = chunks.remainder();
        if !rest.is_empty() {
            let mut w = [0u8; 8];
            w[..rest.len()].copy_from_slice(rest);
            self.add(u64::from_le_bytes(w) ^ ((rest.len() as u64) << 59));
        }
    }

    #[inline]
    fn write_u8(&mut self, i: u8) {
        self.add(u64::from(i));
    }

    #[inline]
    fn write_u16(&mut self, i: u16) {
        self.add(u64::from(i));
    }

    #[inline]
    fn write_u32(&mut self, i: u32) {
        self.add(u64::from(i));
    }

    #[inline]
    fn write_u64(&mut self, i: u64) {
        self.add(i);
    }

    #[inline]
    fn write_usize(&mut self, i: usize) {
        self.add(i as u64);
    }

    #[inline]
    fn finish(&self) -> u64 {
        self.hash
    }
}

/// Builds [`FastHasher`]s from one seed.
#[derive(Clone, Copy)]
pub(crate) struct FastHash {
    seed: u64,
}

impl FastHash {
    /// A seed of the process's random hash keys.
    pub(crate) fn random() -> Self {
        FastHash {
            seed: std::collections::hash_map::RandomState::new().hash_one(0x4d4f_4e49_544f_5255u64),
        }
    }
}

impl BuildHasher for FastHash {
    type Hasher = FastHasher;

    #[inline]
    fn build_hasher(&self) -> FastHasher {
        FastHasher { hash: self.seed }
    }
}

/// Values by byte key, bounded (see the module's documentation).
pub(super) struct Memo<V> {
    map: HashMap<Box<[u8]>, V, FastHash>,
}

impl<V> Memo<V> {
    pub(super) fn new() -> Self {
        Memo {
            map: HashMap::with_hasher(FastHash::random()),
        }
    }

    /// The value kept for `key`.
    #[inline]
    pub(super) fn get(&self, key: &[u8]) -> Option<&V> {
        self.map.get(key)
    }

    /// Keeps `value` for `key` (nothing for a key over [`MEMO_KEY_MAX`]), emptying the
    /// memo first when it is full.
    pub(super) fn insert(&mut self, key: &[u8], value: V) {
        if key.len() > MEMO_KEY_MAX {
            return;
        }
        if self.map.len() >= MEMO_ENTRIES {
            self.map.clear();
            self.map.shrink_to(MEMO_ENTRIES);
        }
        self.map.insert(key.into(), value);
    }

    /// Entries held (at most [`MEMO_ENTRIES`]).
    pub(super) fn len(&self) -> usize {
        self.map.len()
    }
}
