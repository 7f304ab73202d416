//! The AVX2 matrix product of dense and conv layers: 2 input rows x 4 output rows per step,
//! and the short-row path of a first conv layer.

#![allow(unsafe_code)]

use core::arch::x86_64::*;

use super::requant::{chunk_constants, requant4, store16, store4, Requant4};
use crate::model::kernel::{finish, Output};
use crate::model::load::{i32_at, Linear};

/// Sums each of four 8-lane accumulators: `[sum(a), sum(b), sum(c), sum(d)]`.
#[target_feature(enable = "avx2")]
#[inline]
pub(super) fn hsum4(a: __m256i, b: __m256i, c: __m256i, d: __m256i) -> __m128i {
    // Within each 128-bit half: pairwise sums of a,b then c,d, then of those.
    let ab = _mm256_hadd_epi32(a, b);
    let cd = _mm256_hadd_epi32(c, d);
    let abcd = _mm256_hadd_epi32(ab, cd);
    _mm_add_epi32(
        _mm256_castsi256_si128(abcd),
        _mm256_extracti128_si256::<1>(abcd),
    )
}

/// 16 weights of a row's last, partial block. Lanes past the row's end multiply zero inputs,
/// so whatever they hold (the next row's weights, or zeros past the tensor) adds nothing.
///
/// # Safety
/// AVX2 must be available.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn load_tail_weights(weights: &[u8], start: usize) -> __m256i {
    if start.saturating_add(16) <= weights.len() {
        // SAFETY: the 16 bytes at `start` are inside `weights` (checked just above).
        _mm256_cvtepi8_epi16(unsafe { _mm_loadu_si128(weights.as_ptr().add(start).cast()) })
    } else {
        let mut padded = [0u8; 16];
        for (slot, byte) in padded.iter_mut().zip(weights.get(start..).unwrap_or(&[])) {
            *slot = *byte;
        }
        // SAFETY: `padded` is 16 bytes.
        _mm256_cvtepi8_epi16(unsafe { _mm_loadu_si128(padded.as_ptr().cast()) })
    }
}

/// The last `tail` (< 16) inputs of a row starting at `start`, zero in the other lanes. Reads
/// the 16 lanes directly and masks them when they are inside `inputs` (always, in the padded
/// layout `infer` uses), and copies otherwise.
#[target_feature(enable = "avx2")]
pub(super) fn tail_inputs(inputs: &[i16], start: usize, tail: usize, mask: __m256i) -> __m256i {
    if tail == 0 {
        return _mm256_setzero_si256();
    }
    match inputs.get(start..start.saturating_add(16)) {
        // SAFETY: `block` is 16 i16 (32 bytes); loadu has no alignment requirement.
        Some(block) => _mm256_and_si256(unsafe { _mm256_loadu_si256(block.as_ptr().cast()) }, mask),
        None => {
            let mut padded = [0i16; 16];
            let values = inputs.get(start..).unwrap_or(&[]).iter().take(tail);
            for (slot, value) in padded.iter_mut().zip(values) {
                *slot = *value;
            }
            // SAFETY: `padded` is 16 i16.
            unsafe { _mm256_loadu_si256(padded.as_ptr().cast()) }
        }
    }
}

/// `P` input rows (pixels) against all output rows of a layer.
///
/// # Safety
/// AVX2 must be available; every `starts[p] + row_len <= inputs.len()`, every
/// `outs[p] + rows <= outputs.len()`, and the tensor lengths checked by [`linear_batch_avx2`].
#[target_feature(enable = "avx2")]
pub(super) unsafe fn pixels<T: Output, const P: usize, const TAIL: bool>(
    linear: &Linear<'_>,
    inputs: &[i16],
    starts: [usize; P],
    outs: [usize; P],
    tail_mask: __m256i,
    outputs: &mut [T],
) {
    let row_len = linear.row_len;
    let rows = linear.rows;
    let tail = row_len % 16;
    let body = row_len - tail;
    let w = linear.weights.as_ptr();
    let x = starts.map(|start| inputs.as_ptr().wrapping_add(start));
    let x_tail = starts.map(|start| tail_inputs(inputs, start + body, tail, tail_mask));
    // `TAIL` is `tail != 0`, as a constant: conv rows of 16-channel multiples have no partial
    // block, and without the branch the compiler keeps the accumulators in registers.

    let mut row = 0;
    while row + 4 <= rows {
        let mut acc = [[_mm256_setzero_si256(); 4]; P];
        let mut i = 0;
        while i < body {
            // SAFETY: i + 16 <= body <= row_len and starts[p] + row_len <= inputs.len(), so
            // 16 i16 (32 bytes) are in bounds; loadu has no alignment requirement.
            let xs = x.map(|x| unsafe { _mm256_loadu_si256(x.add(i).cast::<__m256i>()) });
            for r in 0..4 {
                // SAFETY: (row + r) < rows and i + 16 <= row_len, so the 16 bytes at
                // (row + r) * row_len + i are inside `weights` (rows * row_len bytes).
                let ws = _mm256_cvtepi8_epi16(unsafe {
                    _mm_loadu_si128(w.add((row + r) * row_len + i).cast())
                });
                for (acc, xs) in acc.iter_mut().zip(xs) {
                    if let Some(acc) = acc.get_mut(r) {
                        *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(xs, ws));
                    }
                }
            }
            i += 16;
        }
        if TAIL {
            for r in 0..4 {
                // SAFETY: AVX2 is available.
                let ws = unsafe { load_tail_weights(linear.weights, (row + r) * row_len + body) };
                for (acc, xs) in acc.iter_mut().zip(x_tail) {
                    if let Some(acc) = acc.get_mut(r) {
                        *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(xs, ws));
                    }
                }
            }
        }
        // SAFETY: row + 4 <= rows, so the 16 bias bytes at 4 * row are inside `bias`.
        let bias = unsafe { _mm_loadu_si128(linear.bias.as_ptr().add(4 * row).cast()) };
        // SAFETY: row + 4 <= rows; tensor lengths per this function's contract.
        let constants = unsafe { Requant4::for_rows(linear, row) };
        for ([a, b, c, d], &out) in acc.into_iter().zip(&outs) {
            let sums = _mm_add_epi32(hsum4(a, b, c, d), bias);
            store4(requant4(sums, &constants), outputs, out + row);
        }
        row += 4;
    }
    while row < rows {
        let mut acc = [_mm256_setzero_si256(); P];
        let mut i = 0;
        while i < body {
            // SAFETY: as in the 4-row loop, for the single row `row < rows`.
            let ws =
                _mm256_cvtepi8_epi16(unsafe { _mm_loadu_si128(w.add(row * row_len + i).cast()) });
            for (acc, x) in acc.iter_mut().zip(x) {
                // SAFETY: as in the 4-row loop.
                let xs = unsafe { _mm256_loadu_si256(x.add(i).cast::<__m256i>()) };
                *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(xs, ws));
            }
            i += 16;
        }
        if TAIL {
            // SAFETY: AVX2 is available.
            let ws = unsafe { load_tail_weights(linear.weights, row * row_len + body) };
            for (acc, xs) in acc.iter_mut().zip(x_tail) {
                *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(xs, ws));
            }
        }
        let zero = _mm256_setzero_si256();
        let bias = i32_at(linear.bias, row);
        for (acc, &out) in acc.into_iter().zip(&outs) {
            let sum = _mm_cvtsi128_si32(hsum4(acc, zero, zero, zero)) + bias;
            if let Some(slot) = outputs.get_mut(out + row) {
                *slot = finish(linear, row, sum);
            }
        }
        row += 1;
    }
}

/// Longest row (in input pairs) of the short-row path: a first conv layer on a one-channel map
/// with a 3 x 3 kernel has 9 inputs per output, 5 pairs.
pub(super) const SHORT_PAIRS: usize = 5;

/// Short rows (at most `2 * SHORT_PAIRS` inputs, a first conv layer): the dot-product layout
/// would fill 9 of 16 lanes and spend more on horizontal sums and per-row requantization than
/// on multiplying. Instead the outputs are the lanes: the weights of 16 rows are packed once
/// per call as `[pair][row][2]` (10 registers), and each pixel broadcasts an input pair to all
/// lanes, so 10 `vpmaddwd` give 16 outputs that are requantized and stored together (HWC is
/// row-contiguous per pixel).
///
/// # Safety
/// AVX2 must be available, the lengths checked by [`linear_batch_avx2`] must hold,
/// `row_len <= 2 * SHORT_PAIRS` and `stride >= 2 * SHORT_PAIRS`.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn short_rows<T: Output>(
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    count: usize,
    outputs: &mut [T],
) {
    let rows = linear.rows;
    let row_len = linear.row_len;
    let mut first_row = 0;
    while first_row < rows {
        let chunk = (rows - first_row).min(16);
        // Packed weights, and bias and requantization constants, of rows first_row..+chunk;
        // rows past the layer's end get zero weights and are not stored.
        let mut packed = [[0i16; 32]; 2 * SHORT_PAIRS];
        for r in 0..chunk {
            let row = first_row + r;
            let weights = linear
                .weights
                .get(row * row_len..(row + 1) * row_len)
                .unwrap_or(&[]);
            for (k, &w) in weights.iter().enumerate() {
                // pair k / 2, register r / 8, lane pair r % 8, position k % 2.
                if let Some(slot) = packed
                    .get_mut(2 * (k / 2) + r / 8)
                    .and_then(|v| v.get_mut(2 * (r % 8) + k % 2))
                {
                    *slot = i16::from(w as i8);
                }
            }
        }
        // SAFETY: each packed vector is 32 i16 (2 x 256 bits); the first 16 are loaded.
        let w = packed.map(|v| unsafe { _mm256_loadu_si256(v.as_ptr().cast()) });
        let (bias_lo, bias_hi, constants) = chunk_constants(linear, first_row, chunk);
        for pixel in 0..count {
            let x = inputs.as_ptr().wrapping_add(pixel * stride).cast::<i32>();
            let mut lo = bias_lo;
            let mut hi = bias_hi;
            for pair in 0..SHORT_PAIRS {
                // SAFETY: AVX2 is available; `x` is the row's start, as `pair_at` requires
                // (it reads inside `inputs` only).
                let xs = unsafe { pair_at(inputs, x, pixel * stride, pair) };
                if let (Some(&w_lo), Some(&w_hi)) = (w.get(2 * pair), w.get(2 * pair + 1)) {
                    lo = _mm256_add_epi32(lo, _mm256_madd_epi16(xs, w_lo));
                    hi = _mm256_add_epi32(hi, _mm256_madd_epi16(xs, w_hi));
                }
            }
            store16(lo, hi, &constants, outputs, pixel * rows + first_row, chunk);
        }
        first_row += chunk;
    }
}

/// Inputs `2 * pair` and `2 * pair + 1` of the row at `start`, broadcast to every 32-bit lane;
/// an input past the slice reads as 0 (its weight is 0 anyway).
///
/// # Safety
/// AVX2 must be available; `x` is `inputs.as_ptr() + start` (as `i32` pointer).
#[target_feature(enable = "avx2")]
#[inline]
pub(super) unsafe fn pair_at(inputs: &[i16], x: *const i32, start: usize, pair: usize) -> __m256i {
    let at = start + 2 * pair;
    if at + 2 <= inputs.len() {
        // SAFETY: the two i16 at `at` are inside `inputs`; read_unaligned has no alignment need.
        _mm256_set1_epi32(unsafe { x.add(pair).read_unaligned() })
    } else {
        let lo = inputs.get(at).copied().unwrap_or(0);
        let hi = inputs.get(at + 1).copied().unwrap_or(0);
        _mm256_set1_epi32(i32::from(lo as u16) | (i32::from(hi) << 16))
    }
}

/// # Safety
/// AVX2 must be available and the lengths checked by [`linear_batch_avx2`] must hold.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn linear_batch_unchecked<T: Output>(
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    count: usize,
    outputs: &mut [T],
) {
    let rows = linear.rows;
    if linear.row_len <= 2 * SHORT_PAIRS && stride >= 2 * SHORT_PAIRS {
        // SAFETY: forwarded contract, plus `stride >= 2 * SHORT_PAIRS` (checked just above).
        unsafe { short_rows(linear, inputs, stride, count, outputs) };
        return;
    }
    let tail = linear.row_len % 16;
    let mut lanes = [0i16; 16];
    for (lane, slot) in lanes.iter_mut().enumerate() {
        *slot = if lane < tail { -1 } else { 0 };
    }
    // SAFETY: `lanes` is 16 i16.
    let tail_mask = unsafe { _mm256_loadu_si256(lanes.as_ptr().cast()) };
    let mut pixel = 0;
    while pixel + 2 <= count {
        let starts = [pixel * stride, (pixel + 1) * stride];
        let outs = [pixel * rows, (pixel + 1) * rows];
        // SAFETY: pixel + 1 < count, so both rows are inside `inputs` and `outputs` (checked
        // by the caller for the last row `count - 1`).
        unsafe {
            if tail == 0 {
                pixels::<T, 2, false>(linear, inputs, starts, outs, tail_mask, outputs);
            } else {
                pixels::<T, 2, true>(linear, inputs, starts, outs, tail_mask, outputs);
            }
        }
        pixel += 2;
    }
    if pixel < count {
        let (starts, outs) = ([pixel * stride], [pixel * rows]);
        // SAFETY: as above for the single row `pixel < count`.
        unsafe {
            if tail == 0 {
                pixels::<T, 1, false>(linear, inputs, starts, outs, tail_mask, outputs);
            } else {
                pixels::<T, 1, true>(linear, inputs, starts, outs, tail_mask, outputs);
            }
        }
    }
}
