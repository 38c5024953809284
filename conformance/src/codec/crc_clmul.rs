//! CRC-16/MODBUS by carry-less multiplication folding (x86-64): PCLMULQDQ on 128-bit
//! lanes, and VPCLMULQDQ on 512-bit registers (AVX-512) for long inputs.
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
//! - **AVX-512** (`avx512f`, `avx512vl`, `vpclmulqdq`): four 512-bit accumulators fold
//!   256 bytes a step, each instruction folding four 128-bit lanes; then one accumulator
//!   folds 64 bytes a step, and the four lanes are folded into one 128-bit value, which
//!   the PCLMULQDQ code finishes.
//!
//! Both end the same way, without a loop over single bytes: the last 1..15 bytes are
//! taken with one 16-byte load that overlaps data already folded (the accumulator is
//! shifted by the same number of bytes, and its top part folded over them), and the
//! final 128-bit value is folded to 80 bits, whose remainder modulo P is one eight-byte
//! step of the table-driven CRC.
#![allow(unsafe_code)]

use std::sync::atomic::{AtomicU8, Ordering};

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

/// Shortest input for which [`crc16_update`] takes a SIMD path (below it, the table
/// wins): four 16-byte lanes.
pub const MIN_LEN: usize = 64;

/// Shortest input for which [`crc16_update`] takes the AVX-512 path rather than
/// PCLMULQDQ, where the CPU has both.
pub const AVX512_MIN_LEN: usize = 256;

/// The best SIMD level of this CPU, detected once: 0 not yet known, then one of the
/// `LEVEL_*` values.
static LEVEL: AtomicU8 = AtomicU8::new(0);
const LEVEL_NONE: u8 = 1;
const LEVEL_PCLMUL: u8 = 2;
const LEVEL_AVX512: u8 = 3;

#[inline]
fn level() -> u8 {
    match LEVEL.load(Ordering::Relaxed) {
        0 => detect(),
        l => l,
    }
}

#[cold]
fn detect() -> u8 {
    let l = if avx512_available() {
        LEVEL_AVX512
    } else if pclmul_available() {
        LEVEL_PCLMUL
    } else {
        LEVEL_NONE
    };
    LEVEL.store(l, Ordering::Relaxed);
    l
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

/// Continues a CRC-16/MODBUS from register `crc` over `data` with the fastest SIMD path
/// for this CPU and length; `None` when the CPU has none or `data` is shorter than
/// [`MIN_LEN`], where the table-driven CRC is the faster.
#[inline]
pub fn crc16_update(crc: u16, data: &[u8]) -> Option<u16> {
    if data.len() < MIN_LEN {
        return None;
    }
    match level() {
        LEVEL_AVX512 if data.len() >= AVX512_MIN_LEN => crc16_avx512(crc, data),
        LEVEL_AVX512 | LEVEL_PCLMUL => crc16_pclmul(crc, data),
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
    use crate::codec::crc::{crc16_table_u64, crc16_update_table};

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
    use crate::codec::crc::{crc16_reference, crc16_update_table};

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

    fn check_path(name: &str, available: bool, f: fn(u16, &[u8]) -> Option<u16>) {
        if !available {
            eprintln!("{name} not available: that SIMD CRC is not tested on this CPU");
            assert_eq!(f(0xFFFF, &[0; 300]), None);
            return;
        }
        let mut next = xorshift(0x2545_F491_4F6C_DD1D);
        for len in 0..=2100 {
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
        let data: Vec<u8> = (0..70_000).map(|_| next() as u8).collect();
        assert_eq!(f(0xFFFF, &data), Some(crc16_reference(&data)));
    }

    #[test]
    fn pclmul_equals_reference_on_every_length_and_init() {
        check_path("pclmulqdq", pclmul_available(), crc16_pclmul);
    }

    #[test]
    fn avx512_equals_reference_on_every_length_and_init() {
        check_path("avx512+vpclmulqdq", avx512_available(), crc16_avx512);
    }

    #[test]
    fn automatic_choice_equals_reference() {
        let mut next = xorshift(0x9E37_79B9_7F4A_7C15);
        for len in [0, 1, 63, 64, 65, 255, 256, 257, 1024, 4096, 4097] {
            let data: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            let want = crc16_update_table(0x1234, &data);
            assert_eq!(crc16_update(0x1234, &data).unwrap_or(want), want);
        }
    }
}
