//! Requantization on AVX2: exact 64-bit products, the rounding shift, saturation and stores.

#![allow(unsafe_code)]

use core::arch::asm;
use core::arch::x86_64::*;

use crate::model::kernel::{Output, OutputSlice};
use crate::model::load::{i32_at, Linear};
use crate::model::quant::{MAX_SHIFT, MIN_SHIFT};

/// Requantization constants of 4 output rows, one per 64-bit lane.
#[derive(Clone, Copy)]
pub(super) struct Requant4 {
    /// The 4 multipliers as i32 (sign-extended where used: see [`requant4`]).
    multiplier: __m128i,
    /// The right shift `31 - shift`, in `1..=62`.
    right: __m256i,
    /// `2^(right - 1)`: rounds halves towards +infinity.
    half: __m256i,
    /// `2^63 >> right`: undoes the 2^63 offset of the logical shift.
    offset: __m256i,
    /// Output zero point.
    zero_point: __m256i,
    /// Lowest output (int8: the zero point under ReLU, else -128; int16 logits: -32768).
    low: __m256i,
    /// Highest output (int8: 127; int16 logits: 32767).
    high: __m256i,
}

impl Requant4 {
    /// Constants from 4 multipliers and 4 shifts (shifts clamped as the scalar code does) and
    /// the output bounds.
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) fn new(
        multipliers: __m128i,
        shifts: __m128i,
        zero_point: i8,
        low: i16,
        high: i16,
    ) -> Requant4 {
        let shifts = _mm_min_epi8(
            _mm_max_epi8(shifts, _mm_set1_epi8(MIN_SHIFT)),
            _mm_set1_epi8(MAX_SHIFT),
        );
        let right = _mm256_sub_epi64(_mm256_set1_epi64x(31), _mm256_cvtepi8_epi64(shifts));
        let one = _mm256_set1_epi64x(1);
        Requant4 {
            multiplier: multipliers,
            right,
            half: _mm256_sllv_epi64(one, _mm256_sub_epi64(right, one)),
            offset: _mm256_srlv_epi64(_mm256_set1_epi64x(i64::MIN), right),
            zero_point: _mm256_set1_epi64x(i64::from(zero_point)),
            low: _mm256_set1_epi64x(i64::from(low)),
            high: _mm256_set1_epi64x(i64::from(high)),
        }
    }

    /// The constants of rows `row..row + 4` of a layer.
    ///
    /// # Safety
    /// AVX2 must be available and `row + 4 <= linear.rows`, with the tensor lengths checked by
    /// [`linear_batch_avx2`].
    #[target_feature(enable = "avx2")]
    #[inline]
    pub(super) unsafe fn for_rows(linear: &Linear<'_>, row: usize) -> Requant4 {
        // SAFETY: rows `row..row + 4` exist, so 16 multiplier bytes at 4 * row are in bounds.
        let multipliers =
            unsafe { _mm_loadu_si128(linear.multipliers.as_ptr().add(4 * row).cast()) };
        let shifts = match linear.shifts.get(row..row + 4) {
            Some(&[a, b, c, d]) => i32::from_le_bytes([a, b, c, d]),
            _ => 0,
        };
        Requant4::new(
            multipliers,
            _mm_cvtsi32_si128(shifts),
            linear.output_zero_point,
            linear.output_low,
            linear.output_high,
        )
    }
}

/// `requantize_clamped` of 4 accumulators at once: `clamp(zp + floor((acc * M + 2^(r-1)) /
/// 2^r), low, high)` (min with `high`, then max with `low`, as the scalar code) with the exact 64-bit product, as 4 i32 lanes. The arithmetic right shift is a logical
/// one of `t + 2^63` (xor of the sign bit) minus `2^63 >> r`, exact because `2^r` divides
/// `2^63`; `|t| < 2^62 + 2^61` so nothing wraps.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn requant4(acc: __m128i, c: &Requant4) -> __m128i {
    let product = vpmuldq(
        _mm256_cvtepi32_epi64(acc),
        _mm256_cvtepi32_epi64(c.multiplier),
    );
    let biased = _mm256_xor_si256(
        _mm256_add_epi64(product, c.half),
        _mm256_set1_epi64x(i64::MIN),
    );
    let scaled = _mm256_sub_epi64(vpsrlvq(biased, c.right), c.offset);
    let q = _mm256_add_epi64(scaled, c.zero_point);
    let q = _mm256_blendv_epi8(q, c.high, _mm256_cmpgt_epi64(q, c.high));
    let q = _mm256_blendv_epi8(q, c.low, _mm256_cmpgt_epi64(c.low, q));
    // Low 32 bits of each 64-bit lane (the values fit the output type by now).
    let low_halves = _mm256_permutevar8x32_epi32(q, _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6));
    _mm256_castsi256_si128(low_halves)
}

/// `vpmuldq` (`_mm256_mul_epi32`) as exactly that instruction. LLVM rewrites the intrinsic
/// as a generic 64-bit multiply and, when the constants come back from the stack and it can no
/// longer prove them sign-extended, lowers that to three `vpmuludq` and shifts.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn vpmuldq(a: __m256i, b: __m256i) -> __m256i {
    let out: __m256i;
    // SAFETY: a register-only AVX2 instruction (AVX2 is enabled for this function).
    unsafe {
        asm!("vpmuldq {o}, {a}, {b}", a = in(ymm_reg) a, b = in(ymm_reg) b,
             o = lateout(ymm_reg) out, options(pure, nomem, nostack, preserves_flags));
    }
    out
}

/// `vpsrlvq` (`_mm256_srlv_epi64`) as exactly that instruction: LLVM otherwise adds a
/// compare-and-mask for shift counts above 63 that it cannot rule out (ours are in 1..=62).
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn vpsrlvq(a: __m256i, count: __m256i) -> __m256i {
    let out: __m256i;
    // SAFETY: a register-only AVX2 instruction (AVX2 is enabled for this function).
    unsafe {
        asm!("vpsrlvq {o}, {a}, {c}", a = in(ymm_reg) a, c = in(ymm_reg) count,
             o = lateout(ymm_reg) out, options(pure, nomem, nostack, preserves_flags));
    }
    out
}

/// Writes 4 requantized lanes (each within the output type's range) to `out[at..at + 4]`.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn store4<T: Output>(values: __m128i, out: &mut [T], at: usize) {
    // Saturating packs: exact, since the lanes are already within the output bounds.
    let words = _mm_packs_epi32(values, values);
    match T::slice(out) {
        OutputSlice::Int8(out) => {
            let bytes = _mm_packs_epi16(words, _mm_setzero_si128());
            let word = _mm_cvtsi128_si32(bytes).to_le_bytes().map(|b| b as i8);
            if let Some(slot) = out.get_mut(at..at + 4) {
                slot.copy_from_slice(&word);
            }
        }
        OutputSlice::Int16(out) => {
            let bytes = _mm_cvtsi128_si64(words).to_le_bytes();
            if let Some(slot) = out.get_mut(at..at + 4) {
                for (o, pair) in slot.iter_mut().zip(bytes.chunks_exact(2)) {
                    if let &[lo, hi] = pair {
                        *o = i16::from_le_bytes([lo, hi]);
                    }
                }
            }
        }
    }
}

/// Bias (2 x 8 lanes) and requantization constants (4 x 4 rows) of the rows
/// `first_row..first_row + chunk` (at most 16) of a layer; missing rows get zeros.
#[target_feature(enable = "avx2")]
pub(super) fn chunk_constants(
    linear: &Linear<'_>,
    first_row: usize,
    chunk: usize,
) -> (__m256i, __m256i, [Requant4; 4]) {
    let mut bias = [0i32; 16];
    let mut multipliers = [0i32; 16];
    let mut shifts = [0u8; 16];
    for r in 0..chunk.min(16) {
        let row = first_row + r;
        if let (Some(b), Some(m), Some(s), Some(&shift)) = (
            bias.get_mut(r),
            multipliers.get_mut(r),
            shifts.get_mut(r),
            linear.shifts.get(row),
        ) {
            *b = i32_at(linear.bias, row);
            *m = i32_at(linear.multipliers, row);
            *s = shift;
        }
    }
    // SAFETY (loads): each array holds 16 elements, at least what is read.
    let bias_lo = unsafe { _mm256_loadu_si256(bias.as_ptr().cast()) };
    let bias_hi = unsafe { _mm256_loadu_si256(bias.as_ptr().add(8).cast()) };
    let mut constants = [Requant4::new(_mm_setzero_si128(), _mm_setzero_si128(), 0, -128, 127); 4];
    for (quarter, c) in constants.iter_mut().enumerate() {
        let m = unsafe { _mm_loadu_si128(multipliers.as_ptr().add(4 * quarter).cast()) };
        let s = match shifts.get(4 * quarter..4 * quarter + 4) {
            Some(&[a, b, c, d]) => i32::from_le_bytes([a, b, c, d]),
            _ => 0,
        };
        *c = Requant4::new(
            m,
            _mm_cvtsi32_si128(s),
            linear.output_zero_point,
            linear.output_low,
            linear.output_high,
        );
    }
    (bias_lo, bias_hi, constants)
}

/// Requantizes 16 accumulators (rows `0..16` of a chunk, as two 8-lane vectors) and writes
/// the first `chunk` of them to `out[at..]`.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn store16<T: Output>(
    lo: __m256i,
    hi: __m256i,
    c: &[Requant4; 4],
    out: &mut [T],
    at: usize,
    chunk: usize,
) {
    let [c0, c1, c2, c3] = c;
    let a = requant4(_mm256_castsi256_si128(lo), c0);
    let b = requant4(_mm256_extracti128_si256::<1>(lo), c1);
    let c = requant4(_mm256_castsi256_si128(hi), c2);
    let d = requant4(_mm256_extracti128_si256::<1>(hi), c3);
    // Saturating packs: exact, since the lanes are already within the output bounds.
    let (ab, cd) = (_mm_packs_epi32(a, b), _mm_packs_epi32(c, d));
    match T::slice(out) {
        OutputSlice::Int8(out) => {
            let mut sixteen = [0i8; 16];
            // SAFETY: `sixteen` is 16 bytes.
            unsafe { _mm_storeu_si128(sixteen.as_mut_ptr().cast(), _mm_packs_epi16(ab, cd)) };
            store_chunk(out, at, chunk, sixteen);
        }
        OutputSlice::Int16(out) => {
            let mut sixteen = [0i16; 16];
            // SAFETY: `sixteen` is 32 bytes: two 16-byte stores.
            unsafe {
                _mm_storeu_si128(sixteen.as_mut_ptr().cast(), ab);
                _mm_storeu_si128(sixteen.as_mut_ptr().add(8).cast(), cd);
            }
            store_chunk(out, at, chunk, sixteen);
        }
    }
}

/// Copies the first `chunk` of `sixteen` values to `out[at..]` (nothing if out of bounds).
#[inline(always)]
pub(super) fn store_chunk<V: Copy>(out: &mut [V], at: usize, chunk: usize, sixteen: [V; 16]) {
    if let Some(slot) = out.get_mut(at..at + chunk) {
        // A whole chunk is one fixed-size copy (a store, not a `memcpy` call).
        match <&mut [V; 16]>::try_from(&mut *slot) {
            Ok(slot) => *slot = sixteen,
            Err(_) => {
                for (o, v) in slot.iter_mut().zip(sixteen) {
                    *o = v;
                }
            }
        }
    }
}
