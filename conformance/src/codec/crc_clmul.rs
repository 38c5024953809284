//! CRC-16/MODBUS by carry-less multiplication folding (x86-64): PCLMULQDQ on 128-bit
//! lanes, VPCLMULQDQ on 256-bit registers (AVX2) and on 512-bit registers (AVX-512) for
//! long inputs; and the dispatcher that chooses among them and the table by CPU and length.
//!
//! The one module of the crate with `unsafe` code: each kernel is called only after
//! runtime detection of the CPU features it is compiled for, and every load reads from a
//! reference to an array of exactly the bytes it loads.
//!
//! # How it works
//!
//! A CRC is the remainder of the message polynomial M(x)·x^16 modulo P(x) = x^16 + x^15 +
//! x^2 + 1. Folding replaces a 128-bit block B, which stands D bits before the end of the
//! data processed so far, with B·x^D mod P computed lazily: B = Bh·x^64 + Bl, and
//! Bh·(x^(D+64) mod P) + Bl·(x^D mod P) is congruent to B·x^D and only 80 bits wide, so it
//! can be XORed into the block D bits later. Several independent accumulators fold the
//! input in parallel (hiding the multiplier's latency) and are folded into one at the end.
//!
//! The data is "reflected" (least significant bit first), which is exactly how 16 bytes
//! read as a little-endian 128-bit lane represent the polynomial; a carry-less product of
//! two reflected 64-bit values is the reflected product shifted by one bit, hence the
//! constants x^(D+63) and x^(D-1) instead of x^(D+64) and x^D.
//!
//! # The paths
//!
//! - **PCLMULQDQ** (`pclmulqdq`, `sse4.1`): four 128-bit accumulators fold 64 bytes a step.
//! - **AVX2** (`avx2`, `vpclmulqdq`): four 256-bit accumulators fold 128 bytes a step, each
//!   instruction folding two 128-bit lanes; then one accumulator folds 32 bytes a step,
//!   and its two lanes are folded into one 128-bit value, which the PCLMULQDQ code
//!   finishes. This is the widest path of the many CPUs that have VPCLMULQDQ without
//!   AVX-512 (AMD Zen 3, Intel client cores from Alder Lake on), where 128-bit lanes alone
//!   leave half of each multiplier idle.
//! - **AVX-512** (`avx512f`, `avx512vl`, `vpclmulqdq`): four 512-bit accumulators fold
//!   256 bytes a step, each instruction folding four 128-bit lanes; then one accumulator
//!   folds 64 bytes a step, and the four lanes are folded into one 128-bit value, which
//!   the PCLMULQDQ code finishes.
//!
//! All end the same way, without a loop over single bytes: the last 1..15 bytes are
//! taken with one 16-byte load that overlaps data already folded (the accumulator is
//! shifted by the same number of bytes, and its top part folded over them), and the
//! final 128-bit value is folded to 80 bits, whose remainder modulo P is one eight-byte
//! step of the table-driven CRC.
//!
//! # The dispatcher
//!
//! A CPU belongs to one *tier*, named by the widest path it can run: table only,
//! PCLMULQDQ, AVX2 with VPCLMULQDQ, or AVX-512 with VPCLMULQDQ. The tier is detected
//! once, at the first call, and each tier has its own size thresholds ([`Thresholds`]),
//! measured on a CPU of that tier (`benches/RESULTS.md`): where the setup of a wider path
//! costs more than its folding saves differs from CPU to CPU. [`PATH_ENV`]
//! (`CONFORMANCE_CRC_PATH=table|pclmul|avx2|avx512`) caps the tier, so that one machine
//! can run and measure the dispatcher of every tier up to its own.
//!
//! # Other architectures
//!
//! The constants, the thresholds and the dispatcher are portable; only the kernels (the
//! `x86` module) and the feature checks are not. An aarch64 path with PMULL (`pmull`,
//! `neon`) would add a `CrcPath` variant, its check with
//! `std::arch::is_aarch64_feature_detected!` beside [`pclmul_available`], a kernel module
//! `#[cfg(target_arch = "aarch64")]` using the same `fold_constants` (the algebra does not
//! depend on the instruction set) and a row in [`Thresholds::of`]. None is written: no
//! aarch64 machine or toolchain is at hand to build, test and measure one, and until then
//! such a CPU takes the table path, like any CPU without the x86 features.
#![allow(unsafe_code)]

use std::sync::atomic::{AtomicU8, Ordering};

/// One implementation of CRC-16/MODBUS, so tests, the fuzz target and benches can force
/// each path this CPU supports; [`crc16`](super::crc::crc16) chooses among them by itself. Ordered from the
/// narrowest to the widest, which is also the order of the dispatcher's tiers.
#[doc(hidden)]
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum CrcPath {
    /// Slice-by-8 tables, any CPU.
    Table,
    /// PCLMULQDQ folding, 128-bit lanes (x86-64).
    Pclmul,
    /// VPCLMULQDQ folding, 256-bit registers (x86-64 with AVX2, with or without AVX-512).
    Avx2,
    /// VPCLMULQDQ folding, 512-bit registers (x86-64 with AVX-512).
    Avx512,
}

impl CrcPath {
    /// Every path, supported here or not, narrowest first.
    pub const ALL: [CrcPath; 4] = [
        CrcPath::Table,
        CrcPath::Pclmul,
        CrcPath::Avx2,
        CrcPath::Avx512,
    ];

    /// Whether this CPU can run the path.
    pub fn available(self) -> bool {
        match self {
            CrcPath::Table => true,
            CrcPath::Pclmul => pclmul_available(),
            CrcPath::Avx2 => avx2_available(),
            CrcPath::Avx512 => avx512_available(),
        }
    }

    /// The paths this CPU can run.
    pub fn supported() -> impl Iterator<Item = CrcPath> {
        Self::ALL.into_iter().filter(|p| p.available())
    }

    /// A short name, for test messages, bench ids and `CONFORMANCE_CRC_PATH`.
    pub const fn name(self) -> &'static str {
        match self {
            CrcPath::Table => "table",
            CrcPath::Pclmul => "pclmul",
            CrcPath::Avx2 => "avx2",
            CrcPath::Avx512 => "avx512",
        }
    }

    /// The path of a [`name`](Self::name), `None` for any other text.
    pub fn from_name(name: &str) -> Option<CrcPath> {
        Self::ALL.into_iter().find(|p| p.name() == name)
    }

    /// The shortest input this path's own kernel folds: [`crc16_update_with`](super::crc::crc16_update_with) hands a
    /// shorter one to a narrower path (the width of one register; 0 for the table).
    pub const fn min_len(self) -> usize {
        match self {
            CrcPath::Table => 0,
            CrcPath::Pclmul => 16,
            CrcPath::Avx2 => 32,
            CrcPath::Avx512 => 64,
        }
    }
}

/// P(x) with its x^16 term.
const POLY: u32 = 0x1_8005;

/// x^n mod P, as a polynomial of degree < 16 (not reflected).
const fn xpow_mod(n: u32) -> u64 {
    let mut r: u32 = 1;
    let mut i = 0;
    while i < n {
        r <<= 1;
        if r & 0x1_0000 != 0 {
            r ^= POLY;
        }
        i += 1;
    }
    r as u64
}

/// Folding constants for a distance of `d` bits: (low lane, high lane), reflected.
const fn fold_constants(d: u32) -> (u64, u64) {
    (
        xpow_mod(d + 63).reverse_bits(),
        xpow_mod(d - 1).reverse_bits(),
    )
}

const FOLD_128: (u64, u64) = fold_constants(128);
const FOLD_256: (u64, u64) = fold_constants(256);
const FOLD_384: (u64, u64) = fold_constants(384);
const FOLD_512: (u64, u64) = fold_constants(512);
const FOLD_1024: (u64, u64) = fold_constants(1024);
const FOLD_2048: (u64, u64) = fold_constants(2048);
/// Multiplies the high 64 bits of a 128-bit value by x^80 mod P (the final fold to 80
/// bits; see `x86::finish`).
const FOLD_TO_80: u64 = xpow_mod(79).reverse_bits();

/// The environment variable that caps the dispatcher's tier: `table`, `pclmul`, `avx2` or
/// `avx512` ([`CrcPath::name`]). [`crc16_update`] then chooses as on a CPU whose widest
/// path is the one named (or the widest this CPU has below it), with that tier's
/// thresholds, so each tier can be measured and tested on one machine. Read once, with the
/// CPU's features; an unknown name is ignored (the benches refuse it).
pub const PATH_ENV: &str = "CONFORMANCE_CRC_PATH";

/// Where the dispatcher of one tier changes path: the table below `pclmul` bytes,
/// PCLMULQDQ from `pclmul`, and the tier's own wide path (AVX2 or AVX-512) from `wide`.
/// Each tier's values come from the forced-path benches run on a CPU of that tier
/// (`crc16-crossover` in `benches/benches/crc.rs`; the figures are in
/// `benches/RESULTS.md`).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Thresholds {
    /// Shortest input that PCLMULQDQ folds rather than the table.
    pub pclmul: usize,
    /// Shortest input that the tier's wide path folds rather than PCLMULQDQ
    /// (`usize::MAX`: the tier has no wide path).
    pub wide: usize,
}

impl Thresholds {
    /// The thresholds of the dispatcher of tier `tier` (a CPU whose widest path is
    /// `tier`).
    pub const fn of(tier: CrcPath) -> Thresholds {
        match tier {
            // No SIMD at all: every length is the table's.
            CrcPath::Table => Thresholds {
                pclmul: usize::MAX,
                wide: usize::MAX,
            },
            // Measured on the AMD EPYC (Zen 3) of issue 39 with the kernels forced
            // (`crc16-crossover`, 16..256 bytes): PCLMULQDQ beat the table at every size
            // from 16 bytes (one fold and one table step against two table steps at 16).
            // The same kernel runs on every tier; no PCLMULQDQ-only CPU was at hand.
            CrcPath::Pclmul => Thresholds {
                pclmul: 16,
                wide: usize::MAX,
            },
            // Measured on AMD EPYC (Zen 3: avx2 vpclmulqdq, no AVX-512), issue 39: the
            // table as above; the 256-bit kernel from 128 bytes, where its four
            // accumulators start (below, the two kernels were within the noise of a
            // loaded machine; from 160 bytes the 256-bit one was ahead at every size).
            CrcPath::Avx2 => Thresholds {
                pclmul: 16,
                wide: 128,
            },
            // Measured on AMD EPYC (Zen 4, AVX-512), issue 17; not remeasured since (no
            // such CPU at hand for issue 39), so unchanged.
            CrcPath::Avx512 => Thresholds {
                pclmul: 64,
                wide: 256,
            },
        }
    }
}

/// The path the dispatcher of tier `tier` takes for an input of `len` bytes.
pub const fn path_for(tier: CrcPath, len: usize) -> CrcPath {
    let t = Thresholds::of(tier);
    if len >= t.wide {
        tier
    } else if len >= t.pclmul {
        CrcPath::Pclmul
    } else {
        CrcPath::Table
    }
}

/// The shortest input that any tier hands to a SIMD path: below it, [`crc16_update`]
/// answers `None` after one comparison, without looking at the CPU.
pub const MIN_LEN: usize = {
    let mut min = usize::MAX;
    let mut i = 0;
    while i < CrcPath::ALL.len() {
        let t = Thresholds::of(CrcPath::ALL[i]).pclmul;
        if t < min {
            min = t;
        }
        i += 1;
    }
    min
};

/// The dispatcher's tier on this CPU, found once: 0 not yet known, else
/// [`tier_code`] of a tier whose path this CPU can run (`detect` stores no other).
static TIER: AtomicU8 = AtomicU8::new(0);

const fn tier_code(tier: CrcPath) -> u8 {
    match tier {
        CrcPath::Table => 1,
        CrcPath::Pclmul => 2,
        CrcPath::Avx2 => 3,
        CrcPath::Avx512 => 4,
    }
}

/// The dispatcher's tier on this CPU: the widest path it can run, capped by
/// [`PATH_ENV`].
#[inline]
pub fn tier() -> CrcPath {
    match TIER.load(Ordering::Relaxed) {
        1 => CrcPath::Table,
        2 => CrcPath::Pclmul,
        3 => CrcPath::Avx2,
        4 => CrcPath::Avx512,
        _ => detect(),
    }
}

#[cold]
fn detect() -> CrcPath {
    let requested = std::env::var(PATH_ENV).ok();
    let tier = resolve_tier(requested.as_deref(), CrcPath::available);
    TIER.store(tier_code(tier), Ordering::Relaxed);
    tier
}

/// The tier of a CPU that can run the paths for which `available` holds, capped by the
/// path named `requested` (the value of [`PATH_ENV`]; an unknown name caps nothing): the
/// widest available path not wider than the cap. The table when nothing else is
/// available, so a CPU (or a build for an architecture) without any of the features
/// takes the table path.
pub fn resolve_tier(requested: Option<&str>, available: impl Fn(CrcPath) -> bool) -> CrcPath {
    let cap = requested
        .and_then(CrcPath::from_name)
        .unwrap_or(CrcPath::Avx512);
    CrcPath::ALL
        .into_iter()
        .rev()
        .find(|&p| p <= cap && available(p))
        .unwrap_or(CrcPath::Table)
}

/// Whether this CPU can run the PCLMULQDQ path. `std` caches the detection.
pub fn pclmul_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("pclmulqdq")
            && std::arch::is_x86_feature_detected!("sse4.1")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether this CPU can run the AVX2 (256-bit VPCLMULQDQ) path, which also needs
/// PCLMULQDQ for its end.
pub fn avx2_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        pclmul_available()
            && std::arch::is_x86_feature_detected!("avx2")
            && std::arch::is_x86_feature_detected!("vpclmulqdq")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Whether this CPU can run the AVX-512 (VPCLMULQDQ) path, which also needs PCLMULQDQ
/// for its end.
pub fn avx512_available() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        pclmul_available()
            && std::arch::is_x86_feature_detected!("avx512f")
            && std::arch::is_x86_feature_detected!("avx512vl")
            && std::arch::is_x86_feature_detected!("vpclmulqdq")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

/// Continues a CRC-16/MODBUS from register `crc` over `data` with the path the dispatcher
/// chooses for this CPU's tier and this length ([`path_for`]); `None` where that is the
/// table (the caller's own code).
#[inline]
pub fn crc16_update(crc: u16, data: &[u8]) -> Option<u16> {
    if data.len() < MIN_LEN {
        return None;
    }
    match path_for(tier(), data.len()) {
        CrcPath::Table => None,
        #[cfg(target_arch = "x86_64")]
        CrcPath::Pclmul => {
            // SAFETY: `tier()` is a tier that `detect` found `CrcPath::available` on this
            // CPU, and every tier above the table has `pclmul_available` in its check:
            // `x86::crc16_pclmul` is compiled for `pclmulqdq` and `sse4.1`, which that
            // function detects. It takes any length.
            Some(unsafe { x86::crc16_pclmul(crc, data) })
        }
        #[cfg(target_arch = "x86_64")]
        CrcPath::Avx2 => {
            // SAFETY: `path_for` returns a wide path only for its own tier, so the tier is
            // AVX2, which `detect` stores only where `avx2_available` held: `avx2`,
            // `vpclmulqdq`, `pclmulqdq` and `sse4.1`, the features `x86::crc16_avx2` is
            // compiled for. It takes any length.
            Some(unsafe { x86::crc16_avx2(crc, data) })
        }
        #[cfg(target_arch = "x86_64")]
        CrcPath::Avx512 => {
            // SAFETY: as for AVX2, the tier is AVX-512, stored only where
            // `avx512_available` held: `avx512f`, `avx512vl`, `vpclmulqdq`, `pclmulqdq`
            // and `sse4.1`, the features `x86::crc16_avx512` is compiled for.
            Some(unsafe { x86::crc16_avx512(crc, data) })
        }
        #[cfg(not(target_arch = "x86_64"))]
        _ => None,
    }
}

/// The PCLMULQDQ path on any length (the table-driven CRC below 16 bytes); `None` when
/// the CPU lacks the instructions.
pub fn crc16_pclmul(crc: u16, data: &[u8]) -> Option<u16> {
    #[cfg(target_arch = "x86_64")]
    {
        if pclmul_available() {
            // SAFETY: `x86::crc16_pclmul` is compiled for `pclmulqdq` and `sse4.1`, which
            // `pclmul_available` has just detected on this CPU; it takes any length.
            return Some(unsafe { x86::crc16_pclmul(crc, data) });
        }
    }
    let _ = (crc, data);
    None
}

/// The AVX2 path on any length (shorter inputs end in the PCLMULQDQ code or the table);
/// `None` when the CPU lacks the instructions.
pub fn crc16_avx2(crc: u16, data: &[u8]) -> Option<u16> {
    #[cfg(target_arch = "x86_64")]
    {
        if avx2_available() {
            // SAFETY: `x86::crc16_avx2` is compiled for `avx2`, `vpclmulqdq`, `pclmulqdq`
            // and `sse4.1`, which `avx2_available` has just detected on this CPU; it
            // takes any length.
            return Some(unsafe { x86::crc16_avx2(crc, data) });
        }
    }
    let _ = (crc, data);
    None
}

/// The AVX-512 path on any length (shorter inputs end in the PCLMULQDQ code or the
/// table); `None` when the CPU lacks the instructions.
pub fn crc16_avx512(crc: u16, data: &[u8]) -> Option<u16> {
    #[cfg(target_arch = "x86_64")]
    {
        if avx512_available() {
            // SAFETY: `x86::crc16_avx512` is compiled for `avx512f`, `avx512vl`,
            // `vpclmulqdq`, `pclmulqdq` and `sse4.1`, which `avx512_available` has just
            // detected on this CPU; it takes any length.
            return Some(unsafe { x86::crc16_avx512(crc, data) });
        }
    }
    let _ = (crc, data);
    None
}

/// The kernels. They are safe functions with `#[target_feature]`: calling one needs
/// `unsafe` (and the features detected) only from code compiled without those features.
/// Every load reads from a reference to an array of exactly the bytes loaded, made by
/// `as_chunks`, `first_chunk` or `last_chunk`, so no offset arithmetic can leave the
/// slice and no length check can panic.
#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{FOLD_1024, FOLD_128, FOLD_2048, FOLD_256, FOLD_384, FOLD_512, FOLD_TO_80};
    use crate::codec::crc_table::{crc16_table_u64, crc16_update_table};

    /// Folding constants as a 128-bit lane: low lane's constant low.
    #[inline]
    #[target_feature(enable = "sse2")]
    fn constants(k: (u64, u64)) -> __m128i {
        _mm_set_epi64x(k.1 as i64, k.0 as i64)
    }

    /// One fold: `x`·x^D mod P (lazily), XORed into `next`.
    #[inline]
    #[target_feature(enable = "pclmulqdq,sse4.1")]
    fn fold_into(x: __m128i, k: __m128i, next: __m128i) -> __m128i {
        let lo = _mm_clmulepi64_si128(x, k, 0x00);
        let hi = _mm_clmulepi64_si128(x, k, 0x11);
        _mm_xor_si128(_mm_xor_si128(lo, hi), next)
    }

    /// Sixteen bytes as a register.
    #[inline]
    #[target_feature(enable = "sse2")]
    fn load128(bytes: &[u8; 16]) -> __m128i {
        // SAFETY: `bytes` refers to 16 readable bytes, exactly what the load reads; the
        // load is unaligned, so any address is valid.
        unsafe { _mm_loadu_si128(bytes.as_ptr().cast()) }
    }

    /// Lane `I` (16 bytes at 16·I) of a 64-byte block as a register.
    #[inline]
    #[target_feature(enable = "sse2")]
    fn lane128<const I: usize>(block: &[u8; 64]) -> __m128i {
        const { assert!(I < 4) };
        // SAFETY: I < 4 (checked at compile time), so the 16 bytes at 16·I lie inside
        // the 64 that `block` refers to; the load is unaligned.
        unsafe { _mm_loadu_si128(block.as_ptr().add(16 * I).cast()) }
    }

    /// Ends a computation: `x` is the folded state of the data before `rest`, at least 16
    /// bytes, and `last` the last 16 bytes of all the data (`rest` included). Returns the
    /// CRC register.
    #[inline]
    #[target_feature(enable = "pclmulqdq,sse4.1")]
    fn finish(mut x: __m128i, rest: &[u8], last: &[u8; 16]) -> u16 {
        let k128 = constants(FOLD_128);
        let (blocks, tail) = rest.as_chunks::<16>();
        for block in blocks {
            x = fold_into(x, k128, load128(block));
        }
        let t = tail.len();
        if t > 0 {
            // The last t bytes: the state's first t bytes are folded over the 16 bytes
            // made of the state's other 16 - t bytes and the t new ones, which are the
            // end of `last`. Shuffle masks from 0, 1, .., 15: byte i of `high` is state
            // byte i - (16 - t) (zero where that is negative: PSHUFB writes zero where the
            // mask byte's top bit is set), byte i of `low` is state byte i + t (zero past
            // the end).
            let t = t as i8;
            let iota = _mm_setr_epi8(0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12, 13, 14, 15);
            let to_high = _mm_add_epi8(iota, _mm_set1_epi8(t - 16));
            let down = _mm_add_epi8(iota, _mm_set1_epi8(t));
            let to_low = _mm_or_si128(down, _mm_cmpgt_epi8(down, _mm_set1_epi8(15)));
            let high = _mm_shuffle_epi8(x, to_high);
            let low = _mm_shuffle_epi8(x, to_low);
            // `to_high` has its top bit set exactly where `low` keeps state bytes.
            let block = _mm_blendv_epi8(load128(last), low, to_high);
            x = fold_into(high, k128, block);
        }
        // x = H·x^64 + L stands for x·x^16 mod P. H·(x^80 mod P) + L·x^16 is congruent and
        // 80 bits wide: its top 64 bits are an eight-byte message whose CRC (from zero) the
        // table gives in one step, and its low 16 bits add to that.
        let h = _mm_clmulepi64_si128(x, _mm_cvtsi64_si128(FOLD_TO_80 as i64), 0x00);
        let l = _mm_srli_si128(_mm_unpackhi_epi64(_mm_setzero_si128(), x), 2);
        let t80 = _mm_srli_si128(_mm_xor_si128(h, l), 6);
        let message = _mm_cvtsi128_si64(t80) as u64;
        let low16 = _mm_extract_epi16(t80, 4) as u16;
        crc16_table_u64(0, message) ^ low16
    }

    /// Folds 64-byte blocks with four 128-bit accumulators, then single 16-byte blocks;
    /// the table below 16 bytes.
    #[target_feature(enable = "pclmulqdq,sse4.1")]
    pub(super) fn crc16_pclmul(crc: u16, data: &[u8]) -> u16 {
        let (Some((first, after_first)), Some(last)) =
            (data.split_first_chunk::<16>(), data.last_chunk::<16>())
        else {
            return crc16_update_table(crc, data);
        };
        // The initial register value enters as an XOR into the first two bytes.
        let init = _mm_cvtsi32_si128(i32::from(crc));
        let (blocks, rest) = data.as_chunks::<64>();
        let Some((head, blocks)) = blocks.split_first() else {
            return finish(_mm_xor_si128(load128(first), init), after_first, last);
        };
        let k512 = constants(FOLD_512);
        let mut x0 = _mm_xor_si128(lane128::<0>(head), init);
        let mut x1 = lane128::<1>(head);
        let mut x2 = lane128::<2>(head);
        let mut x3 = lane128::<3>(head);
        for block in blocks {
            x0 = fold_into(x0, k512, lane128::<0>(block));
            x1 = fold_into(x1, k512, lane128::<1>(block));
            x2 = fold_into(x2, k512, lane128::<2>(block));
            x3 = fold_into(x3, k512, lane128::<3>(block));
        }
        // A tree, so two multiplications stand in the dependency chain, not three.
        let k128 = constants(FOLD_128);
        let y0 = fold_into(x0, k128, x1);
        let y1 = fold_into(x2, k128, x3);
        finish(fold_into(y0, constants(FOLD_256), y1), rest, last)
    }

    /// A 128-bit lane's constants in both lanes of a 256-bit register.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn broadcast256(k: (u64, u64)) -> __m256i {
        _mm256_broadcastsi128_si256(constants(k))
    }

    /// One fold of two lanes at once.
    #[inline]
    #[target_feature(enable = "avx2,vpclmulqdq")]
    fn fold256(x: __m256i, k: __m256i, next: __m256i) -> __m256i {
        let lo = _mm256_clmulepi64_epi128(x, k, 0x00);
        let hi = _mm256_clmulepi64_epi128(x, k, 0x11);
        _mm256_xor_si256(_mm256_xor_si256(lo, hi), next)
    }

    /// Thirty-two bytes as a register.
    #[inline]
    #[target_feature(enable = "avx")]
    fn load256(bytes: &[u8; 32]) -> __m256i {
        // SAFETY: `bytes` refers to 32 readable bytes, exactly what the load reads; the
        // load is unaligned, so any address is valid.
        unsafe { _mm256_loadu_si256(bytes.as_ptr().cast()) }
    }

    /// Register `I` (32 bytes at 32·I) of a 128-byte block.
    #[inline]
    #[target_feature(enable = "avx")]
    fn lane256<const I: usize>(block: &[u8; 128]) -> __m256i {
        const { assert!(I < 4) };
        // SAFETY: I < 4 (checked at compile time), so the 32 bytes at 32·I lie inside
        // the 128 that `block` refers to; the load is unaligned.
        unsafe { _mm256_loadu_si256(block.as_ptr().add(32 * I).cast()) }
    }

    /// Folds 128-byte blocks with four 256-bit accumulators, then 32-byte blocks with one,
    /// then folds its two lanes into one and lets [`finish`] end; the PCLMULQDQ kernel
    /// below 32 bytes.
    #[target_feature(enable = "avx2,vpclmulqdq,pclmulqdq,sse4.1")]
    pub(super) fn crc16_avx2(crc: u16, data: &[u8]) -> u16 {
        let (Some((first, after_first)), Some(last)) =
            (data.split_first_chunk::<32>(), data.last_chunk::<16>())
        else {
            return crc16_pclmul(crc, data);
        };
        let init = _mm256_zextsi128_si256(_mm_cvtsi32_si128(i32::from(crc)));
        let k256 = broadcast256(FOLD_256);
        let (big, after_big) = data.as_chunks::<128>();
        let (mut x, rest) = match big.split_first() {
            None => (_mm256_xor_si256(load256(first), init), after_first),
            Some((head, blocks)) => {
                // Four independent chains: each fold waits for the multiplier's latency,
                // four keep it busy.
                let k1024 = broadcast256(FOLD_1024);
                let mut x0 = _mm256_xor_si256(lane256::<0>(head), init);
                let mut x1 = lane256::<1>(head);
                let mut x2 = lane256::<2>(head);
                let mut x3 = lane256::<3>(head);
                for block in blocks {
                    x0 = fold256(x0, k1024, lane256::<0>(block));
                    x1 = fold256(x1, k1024, lane256::<1>(block));
                    x2 = fold256(x2, k1024, lane256::<2>(block));
                    x3 = fold256(x3, k1024, lane256::<3>(block));
                }
                // A tree, as in the PCLMULQDQ kernel: x0 and x1 stand 64 bytes before x2
                // and x3, and the two sums 32 bytes apart.
                let k512 = broadcast256(FOLD_512);
                let y0 = fold256(x0, k512, x2);
                let y1 = fold256(x1, k512, x3);
                (fold256(y0, k256, y1), after_big)
            }
        };
        let (blocks, rest) = rest.as_chunks::<32>();
        for block in blocks {
            x = fold256(x, k256, load256(block));
        }
        // The low lane stands 16 bytes before the high one.
        let low = _mm256_castsi256_si128(x);
        let high = _mm256_extracti128_si256::<1>(x);
        finish(fold_into(low, constants(FOLD_128), high), rest, last)
    }

    /// A 128-bit lane's constants in all four lanes of a 512-bit register.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn broadcast(k: (u64, u64)) -> __m512i {
        _mm512_broadcast_i32x4(constants(k))
    }

    /// One fold of four lanes at once, with a three-way XOR in one instruction.
    #[inline]
    #[target_feature(enable = "avx512f,vpclmulqdq")]
    fn fold512(x: __m512i, k: __m512i, next: __m512i) -> __m512i {
        let lo = _mm512_clmulepi64_epi128(x, k, 0x00);
        let hi = _mm512_clmulepi64_epi128(x, k, 0x11);
        _mm512_ternarylogic_epi64(lo, hi, next, 0x96)
    }

    /// Sixty-four bytes as a register.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn load512(bytes: &[u8; 64]) -> __m512i {
        // SAFETY: `bytes` refers to 64 readable bytes, exactly what the load reads; the
        // load is unaligned, so any address is valid.
        unsafe { _mm512_loadu_si512(bytes.as_ptr().cast()) }
    }

    /// Register `I` (64 bytes at 64·I) of a 256-byte block.
    #[inline]
    #[target_feature(enable = "avx512f")]
    fn lane512<const I: usize>(block: &[u8; 256]) -> __m512i {
        const { assert!(I < 4) };
        // SAFETY: I < 4 (checked at compile time), so the 64 bytes at 64·I lie inside
        // the 256 that `block` refers to; the load is unaligned.
        unsafe { _mm512_loadu_si512(block.as_ptr().add(64 * I).cast()) }
    }

    /// Folds 256-byte blocks with four 512-bit accumulators, then 64-byte blocks with one,
    /// then folds its four lanes into one and lets [`finish`] end; the PCLMULQDQ kernel
    /// below 64 bytes.
    #[target_feature(enable = "avx512f,avx512vl,vpclmulqdq,pclmulqdq,sse4.1")]
    pub(super) fn crc16_avx512(crc: u16, data: &[u8]) -> u16 {
        let (Some((first, after_first)), Some(last)) =
            (data.split_first_chunk::<64>(), data.last_chunk::<16>())
        else {
            return crc16_pclmul(crc, data);
        };
        let init = _mm512_castsi128_si512(_mm_cvtsi32_si128(i32::from(crc)));
        let k512 = broadcast(FOLD_512);
        let (big, after_big) = data.as_chunks::<256>();
        let (mut x, rest) = match big.split_first() {
            None => (_mm512_xor_si512(load512(first), init), after_first),
            Some((head, blocks)) => {
                let k2048 = broadcast(FOLD_2048);
                let mut x0 = _mm512_xor_si512(lane512::<0>(head), init);
                let mut x1 = lane512::<1>(head);
                let mut x2 = lane512::<2>(head);
                let mut x3 = lane512::<3>(head);
                for block in blocks {
                    x0 = fold512(x0, k2048, lane512::<0>(block));
                    x1 = fold512(x1, k2048, lane512::<1>(block));
                    x2 = fold512(x2, k2048, lane512::<2>(block));
                    x3 = fold512(x3, k2048, lane512::<3>(block));
                }
                let y0 = fold512(x0, k512, x1);
                let y1 = fold512(x2, k512, x3);
                (fold512(y0, broadcast(FOLD_1024), y1), after_big)
            }
        };
        let (blocks, rest) = rest.as_chunks::<64>();
        for block in blocks {
            x = fold512(x, k512, load512(block));
        }
        // Lanes 0, 1, 2 stand 48, 32 and 16 bytes before lane 3: fold each by its distance
        // in one pair of multiplications (lane 3's constants are zero), then add them up.
        let k = _mm512_set_epi64(
            0,
            0,
            FOLD_128.1 as i64,
            FOLD_128.0 as i64,
            FOLD_256.1 as i64,
            FOLD_256.0 as i64,
            FOLD_384.1 as i64,
            FOLD_384.0 as i64,
        );
        let folded = _mm512_xor_si512(
            _mm512_clmulepi64_epi128(x, k, 0x00),
            _mm512_clmulepi64_epi128(x, k, 0x11),
        );
        let lanes01 = _mm_xor_si128(
            _mm512_castsi512_si128(folded),
            _mm512_extracti32x4_epi32(folded, 1),
        );
        let lanes23 = _mm_xor_si128(
            _mm512_extracti32x4_epi32(folded, 2),
            _mm512_extracti32x4_epi32(x, 3),
        );
        finish(_mm_xor_si128(lanes01, lanes23), rest, last)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::crc::crc16_reference;
    use crate::codec::crc_table::crc16_update_table;

    #[test]
    fn constants_are_powers_of_x() {
        assert_eq!(xpow_mod(0), 1);
        assert_eq!(xpow_mod(15), 0x8000);
        assert_eq!(xpow_mod(16), 0x8005);
    }

    fn xorshift(mut state: u64) -> impl FnMut() -> u64 {
        move || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        }
    }

    /// Longest input of the every-length sweeps.
    const SWEEP: usize = 4096;

    /// A buffer aligned to 64 bytes, so that `data[a..]` starts at alignment `a` for every
    /// `a` in 0..64 (the widest register is 64 bytes).
    #[repr(align(64))]
    struct Aligned([u8; SWEEP + 64]);

    fn check_path(name: &str, available: bool, f: fn(u16, &[u8]) -> Option<u16>) {
        if !available {
            eprintln!("{name} not available: that SIMD CRC is not tested on this CPU");
            assert_eq!(f(0xFFFF, &[0; 300]), None);
            return;
        }
        // Every length, from a random register value and from FFFFH against the manuals'
        // bit loop.
        let mut next = xorshift(0x2545_F491_4F6C_DD1D);
        for len in 0..=SWEEP {
            let data: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            let init = next() as u16;
            let want = crc16_update_table(init, &data);
            assert_eq!(
                f(init, &data),
                Some(want),
                "{name}: len {len} init {init:04X}"
            );
            assert_eq!(
                f(0xFFFF, &data),
                Some(crc16_reference(&data)),
                "{name}: len {len}"
            );
        }
        // Every length at every alignment: the reference for `data[a..a + len]` is
        // carried forward a byte at a time, so each length costs only the path's own run.
        let mut buf = Aligned([0; SWEEP + 64]);
        buf.0.iter_mut().for_each(|b| *b = next() as u8);
        for a in 0..64 {
            let data = &buf.0[a..a + SWEEP];
            assert_eq!(data.as_ptr() as usize % 64, a);
            let mut want = 0xFFFF;
            for len in 0..=SWEEP {
                assert_eq!(
                    f(0xFFFF, &data[..len]),
                    Some(want),
                    "{name}: alignment {a} len {len}"
                );
                if let Some(&b) = data.get(len) {
                    want = crc16_update_table(want, &[b]);
                }
            }
        }
        let data: Vec<u8> = (0..70_000).map(|_| next() as u8).collect();
        assert_eq!(f(0xFFFF, &data), Some(crc16_reference(&data)));
    }

    #[test]
    fn pclmul_equals_reference_on_every_length_init_and_alignment() {
        check_path("pclmulqdq", pclmul_available(), crc16_pclmul);
    }

    #[test]
    fn avx2_equals_reference_on_every_length_init_and_alignment() {
        check_path("avx2+vpclmulqdq", avx2_available(), crc16_avx2);
    }

    #[test]
    fn avx512_equals_reference_on_every_length_init_and_alignment() {
        check_path("avx512+vpclmulqdq", avx512_available(), crc16_avx512);
    }

    #[test]
    fn automatic_choice_equals_reference() {
        let mut next = xorshift(0x9E37_79B9_7F4A_7C15);
        for len in [
            0, 1, 63, 64, 65, 127, 128, 129, 255, 256, 257, 1024, 4096, 4097,
        ] {
            let data: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            let want = crc16_update_table(0x1234, &data);
            assert_eq!(crc16_update(0x1234, &data).unwrap_or(want), want);
        }
    }

    #[test]
    fn each_tier_chooses_by_its_thresholds() {
        for tier in CrcPath::ALL {
            let t = Thresholds::of(tier);
            assert!(t.pclmul <= t.wide, "{tier:?}: {t:?}");
            // A path's kernel must really fold from where the dispatcher hands it over.
            assert!(t.pclmul >= CrcPath::Pclmul.min_len(), "{tier:?}");
            assert!(t.wide == usize::MAX || t.wide >= tier.min_len(), "{tier:?}");
            assert!(MIN_LEN <= t.pclmul);
            for len in 0..=SWEEP {
                let path = path_for(tier, len);
                assert!(path <= tier, "{tier:?} at {len}: {path:?}");
                let want = if len >= t.wide {
                    tier
                } else if len >= t.pclmul {
                    CrcPath::Pclmul
                } else {
                    CrcPath::Table
                };
                assert_eq!(path, want, "{tier:?} at {len}");
                if len < MIN_LEN {
                    assert_eq!(path, CrcPath::Table, "{tier:?} at {len}");
                }
            }
        }
        // The tiers without a wide path never leave PCLMULQDQ, whatever the length.
        assert_eq!(path_for(CrcPath::Table, usize::MAX - 1), CrcPath::Table);
        assert_eq!(path_for(CrcPath::Pclmul, usize::MAX - 1), CrcPath::Pclmul);
    }

    #[test]
    fn a_cpu_without_the_features_takes_the_table() {
        assert_eq!(resolve_tier(None, |p| p == CrcPath::Table), CrcPath::Table);
        // Even when asked for a wider path: it cannot run here.
        for name in ["pclmul", "avx2", "avx512"] {
            assert_eq!(
                resolve_tier(Some(name), |p| p == CrcPath::Table),
                CrcPath::Table
            );
        }
        // And never a SIMD path at any length.
        for len in [0, 64, 128, 256, 4096, 1 << 20] {
            assert_eq!(path_for(CrcPath::Table, len), CrcPath::Table);
        }
    }

    #[test]
    fn the_tier_is_the_widest_path_available_under_the_cap() {
        let all = |_: CrcPath| true;
        let no_avx512 = |p: CrcPath| p != CrcPath::Avx512;
        let pclmul_only = |p: CrcPath| p <= CrcPath::Pclmul;
        assert_eq!(resolve_tier(None, all), CrcPath::Avx512);
        assert_eq!(resolve_tier(None, no_avx512), CrcPath::Avx2);
        assert_eq!(resolve_tier(None, pclmul_only), CrcPath::Pclmul);
        assert_eq!(resolve_tier(Some("avx2"), all), CrcPath::Avx2);
        assert_eq!(resolve_tier(Some("pclmul"), all), CrcPath::Pclmul);
        assert_eq!(resolve_tier(Some("table"), all), CrcPath::Table);
        // A cap above what the CPU has: the CPU's own tier.
        assert_eq!(resolve_tier(Some("avx512"), no_avx512), CrcPath::Avx2);
        assert_eq!(resolve_tier(Some("avx2"), pclmul_only), CrcPath::Pclmul);
        // An unknown name caps nothing.
        assert_eq!(resolve_tier(Some("AVX2"), no_avx512), CrcPath::Avx2);
        assert_eq!(resolve_tier(Some(""), pclmul_only), CrcPath::Pclmul);
    }

    #[test]
    fn this_cpus_tier_can_run_its_paths() {
        let tier = tier();
        assert!(tier.available(), "{tier:?}");
        // The tier is the widest path here unless `CONFORMANCE_CRC_PATH` caps it.
        if std::env::var_os(PATH_ENV).is_none() {
            assert_eq!(Some(tier), CrcPath::supported().last());
        }
        for len in [0, 16, 64, 128, 256, 4096] {
            assert!(path_for(tier, len).available());
        }
    }
}
