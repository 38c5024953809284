//! Sixteen hex characters at a time with SSE2 (every x86-64 CPU has it), for the ASCII
//! decode's common case: validate, convert and sum a frame's hex in a few vector steps.
//!
//! One `unsafe` block, in [`decode`]: the vector is built from two 64-bit words read
//! from the slice by safe code, the intrinsics take no pointers, and the only
//! precondition of the call is that the CPU has SSE2, which every x86-64 CPU has and the
//! compile-time assertion below checks (Rust treats the call as unsafe only because the
//! callee names the feature and the caller does not). The SWAR path in
//! [`ascii`](super::ascii) stays for other targets, and both are tested against the
//! byte-by-byte decode.
#![allow(unsafe_code)]

// SSE2 is part of the x86-64 baseline: the SAFETY argument of `decode` rests on this.
const _: () = assert!(cfg!(target_feature = "sse2"));

use std::arch::x86_64::{
    __m128i, _mm_add_epi8, _mm_and_si128, _mm_andnot_si128, _mm_cmpgt_epi8, _mm_cmplt_epi8,
    _mm_cvtsi128_si64, _mm_movemask_epi8, _mm_or_si128, _mm_packus_epi16, _mm_sad_epu8,
    _mm_set1_epi8, _mm_set_epi64x, _mm_set_epi8, _mm_setzero_si128, _mm_slli_epi16, _mm_srli_epi16,
    _mm_sub_epi8,
};

/// Lane numbers 0..16, for masks by position.
#[inline]
#[target_feature(enable = "sse2")]
fn iota() -> __m128i {
    _mm_set_epi8(15, 14, 13, 12, 11, 10, 9, 8, 7, 6, 5, 4, 3, 2, 1, 0)
}

/// Decodes the 16 characters `chars` (read little-endian: `lo` holds the first eight) as
/// eight bytes, the first pair in the low byte. Characters at positions `valid..16` are
/// taken as '0' (they lie beyond the hex: a delimiter, or pairs decoded already), and the
/// sum covers only bytes `sum_from..8`. `None` if a character below `valid` is not a hex
/// digit (upper or lower case).
#[inline]
#[target_feature(enable = "sse2")]
fn hex16(lo: u64, hi: u64, valid: i8, sum_from: i8) -> Option<(u64, u32)> {
    let v = _mm_set_epi64x(hi as i64, lo as i64);
    let lanes = iota();
    // Lanes past the hex become '0', which decodes to zero.
    let inside = _mm_cmplt_epi8(lanes, _mm_set1_epi8(valid));
    let v = _mm_or_si128(
        _mm_and_si128(inside, v),
        _mm_andnot_si128(inside, _mm_set1_epi8(b'0' as i8)),
    );
    // c - '0' below 10 (unsigned) is a digit; (c | 20H) - 'a' below 6 is a letter. The
    // unsigned compare is a signed one after flipping the top bit.
    let flip = _mm_set1_epi8(i8::MIN);
    let d = _mm_sub_epi8(v, _mm_set1_epi8(b'0' as i8));
    let is_digit = _mm_cmplt_epi8(_mm_add_epi8(d, flip), _mm_set1_epi8((10u8 ^ 0x80) as i8));
    let l = _mm_sub_epi8(
        _mm_or_si128(v, _mm_set1_epi8(0x20)),
        _mm_set1_epi8(b'a' as i8),
    );
    let is_letter = _mm_cmplt_epi8(_mm_add_epi8(l, flip), _mm_set1_epi8((6u8 ^ 0x80) as i8));
    if _mm_movemask_epi8(_mm_or_si128(is_digit, is_letter)) != 0xFFFF {
        return None;
    }
    let nibbles = _mm_or_si128(
        _mm_and_si128(is_digit, d),
        _mm_and_si128(is_letter, _mm_add_epi8(l, _mm_set1_epi8(10))),
    );
    // Each 16-bit lane holds a pair, high nibble in its low byte: byte = lo << 4 | hi.
    let high = _mm_and_si128(_mm_slli_epi16::<4>(nibbles), high_nibbles());
    let bytes16 = _mm_or_si128(high, _mm_srli_epi16::<8>(nibbles));
    let packed = _mm_packus_epi16(bytes16, _mm_setzero_si128());
    // The sum of bytes sum_from..8 (the upper eight lanes are zero after the pack).
    let counted = _mm_cmpgt_epi8(lanes, _mm_set1_epi8(sum_from - 1));
    let sum = _mm_cvtsi128_si64(_mm_sad_epu8(
        _mm_and_si128(packed, counted),
        _mm_setzero_si128(),
    )) as u32;
    Some((_mm_cvtsi128_si64(packed) as u64, sum))
}

/// 00F0H in every 16-bit lane.
#[inline]
#[target_feature(enable = "sse2")]
fn high_nibbles() -> __m128i {
    std::arch::x86_64::_mm_set1_epi16(0x00F0)
}

/// Decodes `hex` (an even number of characters, 2..=510) into `scratch`, returning the
/// bytes decoded and their 8-bit sum, or `None` on a character that is not hex.
#[inline(always)]
pub(super) fn decode(hex: &[u8], scratch: &mut [u8]) -> Option<(usize, u8)> {
    // SAFETY: `decode_sse2` needs SSE2 and nothing else; every x86-64 CPU has it (checked
    // at compile time above).
    unsafe { decode_sse2(hex, scratch) }
}

#[inline]
#[target_feature(enable = "sse2")]
fn decode_sse2(hex: &[u8], scratch: &mut [u8]) -> Option<(usize, u8)> {
    let n = hex.len();
    let word = |s: &[u8], at: usize| -> Option<u64> {
        let c: &[u8; 8] = s.get(at..at + 8)?.try_into().ok()?;
        Some(u64::from_le_bytes(*c))
    };
    if n < 16 {
        // Fewer than 16 characters: read them with what follows in the frame (at least
        // the CR LF), or from a padded copy when the frame is shorter than that.
        // Fewer than 16 characters: read in registers, with no copy through memory (a
        // copy read back as wider words stalls store forwarding); positions past the hex
        // are zero here and '0' after the mask in `hex16`.
        let (lo, hi) = if n >= 8 {
            let last = word(hex, n - 8)?;
            (
                word(hex, 0)?,
                last.checked_shr(8 * (16 - n as u32)).unwrap_or(0),
            )
        } else if n >= 4 {
            let w4 = |at: usize| -> Option<u64> {
                let c: &[u8; 4] = hex.get(at..at + 4)?.try_into().ok()?;
                Some(u64::from(u32::from_le_bytes(*c)))
            };
            (w4(0)? | w4(n - 4)? << (8 * (n - 4)), 0)
        } else {
            let c: &[u8; 2] = hex.get(..2)?.try_into().ok()?;
            (u64::from(u16::from_le_bytes(*c)), 0)
        };
        let (bytes, sum) = hex16(lo, hi, n as i8, 0)?;
        scratch.get_mut(..8)?.copy_from_slice(&bytes.to_le_bytes());
        return Some((n / 2, sum as u8));
    }
    let mut sum = 0u32;
    let mut at = 0;
    while at + 16 <= n {
        let (bytes, s) = hex16(word(hex, at)?, word(hex, at + 8)?, 16, 0)?;
        scratch
            .get_mut(at / 2..at / 2 + 8)?
            .copy_from_slice(&bytes.to_le_bytes());
        sum += s;
        at += 16;
    }
    if at < n {
        // The last 2..14 characters: the last sixteen, overlapping pairs already decoded
        // (written again with the same values, left out of the sum).
        let start = n - 16;
        let again = ((at - start) / 2) as i8;
        let (bytes, s) = hex16(word(hex, start)?, word(hex, start + 8)?, 16, again)?;
        scratch
            .get_mut(start / 2..start / 2 + 8)?
            .copy_from_slice(&bytes.to_le_bytes());
        sum += s;
    }
    Some((n / 2, sum as u8))
}
