//! CRC-16/MODBUS by carry-less multiplication folding (PCLMULQDQ, x86-64).
//!
//! The one module of the crate with `unsafe` code: SIMD intrinsics, used only after
//! runtime detection of the CPU feature, and unaligned loads from slices whose length is
//! checked first.
//!
//! # How it works
//!
//! A CRC is the remainder of the message polynomial M(x)·x^16 modulo P(x) = x^16 + x^15 +
//! x^2 + 1. Folding replaces a 128-bit block B, which stands D bits before the end of the
//! data processed so far, with B·x^D mod P computed lazily: B = Bh·x^64 + Bl, and
//! Bh·(x^(D+64) mod P) + Bl·(x^D mod P) is congruent to B·x^D and only 80 bits wide, so it
//! can be XORed into the block D bits later. Four independent 128-bit accumulators fold by
//! 512 bits each step (hiding the multiplier's latency), are folded into one at the end,
//! and the last 16 bytes of state plus the tail are finished by the table-driven CRC.
//!
//! The data is "reflected" (least significant bit first), which is exactly how 16 bytes
//! read as a little-endian 128-bit lane represent the polynomial; a carry-less product of
//! two reflected 64-bit values is the reflected product shifted by one bit, hence the
//! constants x^(D+63) and x^(D-1) instead of x^(D+64) and x^D.
#![allow(unsafe_code)]

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
const FOLD_512: (u64, u64) = fold_constants(512);

/// Shortest input worth the SIMD path (four 16-byte lanes).
pub const MIN_LEN: usize = 64;

/// Whether this CPU can run [`crc16_update`]. `std` caches the detection.
#[inline]
pub fn available() -> bool {
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

/// Continues a CRC-16/MODBUS from register `crc` over `data` with PCLMULQDQ; `None` when
/// the CPU lacks the instructions or `data` is shorter than [`MIN_LEN`].
pub fn crc16_update(crc: u16, data: &[u8]) -> Option<u16> {
    #[cfg(target_arch = "x86_64")]
    {
        if data.len() >= MIN_LEN && available() {
            // SAFETY: the features `x86::crc16` is compiled for were detected just above,
            // and it requires at least MIN_LEN bytes, checked just above.
            return Some(unsafe { x86::crc16(crc, data) });
        }
    }
    let _ = (crc, data);
    None
}

#[cfg(target_arch = "x86_64")]
mod x86 {
    use std::arch::x86_64::*;

    use super::{FOLD_128, FOLD_512, MIN_LEN};
    use crate::codec::crc::crc16_update_table;

    #[inline(always)]
    unsafe fn constants(k: (u64, u64)) -> __m128i {
        _mm_set_epi64x(k.1 as i64, k.0 as i64)
    }

    /// One fold: `x`·x^D mod P (lazily), XORed into `next`.
    #[inline(always)]
    unsafe fn fold_into(x: __m128i, k: __m128i, next: __m128i) -> __m128i {
        let lo = _mm_clmulepi64_si128(x, k, 0x00);
        let hi = _mm_clmulepi64_si128(x, k, 0x11);
        _mm_xor_si128(_mm_xor_si128(lo, hi), next)
    }

    /// # Safety
    /// The CPU must support `pclmulqdq` and `sse4.1`, and `data.len() >= MIN_LEN`.
    #[target_feature(enable = "pclmulqdq,sse4.1")]
    pub(super) unsafe fn crc16(crc: u16, data: &[u8]) -> u16 {
        debug_assert!(data.len() >= MIN_LEN);
        let load = |at: usize| -> __m128i {
            // `at + 16 <= data.len()` at every call below.
            _mm_loadu_si128(data.as_ptr().add(at).cast())
        };
        let k512 = constants(FOLD_512);
        let k128 = constants(FOLD_128);
        // The initial register value enters as an XOR into the first two bytes.
        let mut x0 = _mm_xor_si128(load(0), _mm_cvtsi32_si128(i32::from(crc)));
        let mut x1 = load(16);
        let mut x2 = load(32);
        let mut x3 = load(48);
        let mut at = 64;
        while at + 64 <= data.len() {
            x0 = fold_into(x0, k512, load(at));
            x1 = fold_into(x1, k512, load(at + 16));
            x2 = fold_into(x2, k512, load(at + 32));
            x3 = fold_into(x3, k512, load(at + 48));
            at += 64;
        }
        let mut x = fold_into(x0, k128, x1);
        x = fold_into(x, k128, x2);
        x = fold_into(x, k128, x3);
        while at + 16 <= data.len() {
            x = fold_into(x, k128, load(at));
            at += 16;
        }
        let mut state = [0u8; 16];
        _mm_storeu_si128(state.as_mut_ptr().cast(), x);
        let crc = crc16_update_table(0, &state);
        crc16_update_table(crc, &data[at..])
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::codec::crc::crc16_reference;

    #[test]
    fn constants_are_powers_of_x() {
        assert_eq!(xpow_mod(0), 1);
        assert_eq!(xpow_mod(15), 0x8000);
        assert_eq!(xpow_mod(16), 0x8005);
    }

    #[test]
    fn equals_reference_on_every_length_and_init() {
        if !available() {
            eprintln!("pclmulqdq not available: SIMD CRC not tested on this CPU");
            return;
        }
        let mut state: u64 = 0x2545_F491_4F6C_DD1D;
        let mut next = || {
            state ^= state << 13;
            state ^= state >> 7;
            state ^= state << 17;
            state
        };
        for len in MIN_LEN..=2100 {
            let data: Vec<u8> = (0..len).map(|_| next() as u8).collect();
            let init = next() as u16;
            let want = crate::codec::crc::crc16_update_table(init, &data);
            assert_eq!(
                crc16_update(init, &data),
                Some(want),
                "len {len} init {init:04X}"
            );
            if init == 0xFFFF {
                assert_eq!(want, crc16_reference(&data));
            }
        }
        let data: Vec<u8> = (0..4096).map(|_| next() as u8).collect();
        assert_eq!(crc16_update(0xFFFF, &data), Some(crc16_reference(&data)));
    }
}
