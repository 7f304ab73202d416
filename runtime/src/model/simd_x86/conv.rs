//! The first conv layer on a one-channel map (3 x 3 kernel), 16 channels per vector pair.

#![allow(unsafe_code)]

use core::arch::x86_64::*;

use super::avx2_supported;
use super::requant::{chunk_constants, store16};
use crate::model::load::ConvLayer;

/// A conv layer on a one-channel map with a 3 x 3 kernel (the first layer), straight from the
/// int8 map: no patch gather at all. For each output row the three input rows it reads are
/// widened once (minus the zero point, zero-padded) into `scratch`; then kernel cells
/// (ky, 0..2) and (ky, 2..4) of a pixel are adjacent i16 pairs of such a row, read as one i32
/// and broadcast, against weights packed per call as `[ky][pair][row][2]` (the (ky, 3) weight
/// is 0). 16 output channels per vector pair, requantized and stored together. Returns
/// `false`, having done nothing, when the layer is not of that shape, the CPU has no AVX2 or
/// `scratch` is too short (the caller then takes the general path).
pub fn conv3x3_one_channel_avx2(
    conv: &ConvLayer<'_>,
    src: &[i8],
    out: &mut [i8],
    scratch: &mut [i16],
) -> bool {
    let linear = &conv.linear;
    let rows = linear.rows;
    let padding = usize::from(conv.record.padding);
    let stride = usize::from(conv.record.stride);
    // One padded row, plus one slack element for the last pixel's (ky, 3) read.
    let width = conv.in_cols + 2 * padding + 1;
    let applicable = conv.in_channels == 1
        && conv.record.kernel == 3
        && rows > 0
        && conv.out_cols > 0
        && linear.row_len == 9
        && linear.weights.len() == rows.saturating_mul(9)
        && linear.bias.len() == rows.saturating_mul(4)
        && linear.multipliers.len() == rows.saturating_mul(4)
        && linear.shifts.len() == rows
        && src.len() >= conv.in_rows.saturating_mul(conv.in_cols)
        && out.len() >= conv.out_rows.saturating_mul(conv.out_cols).saturating_mul(rows)
        && scratch.len() >= 3 * width
        // Reads of pixel ox reach padded column ox * stride + 3.
        && (conv.out_cols - 1) * stride + 4 <= width
        && avx2_supported();
    if applicable {
        // SAFETY: AVX2 is supported and the bounds above hold.
        unsafe { conv3x3_one_channel_unchecked(conv, src, out, scratch, width) };
    }
    applicable
}

/// # Safety
/// AVX2 must be available and the conditions checked by [`conv3x3_one_channel_avx2`] hold.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn conv3x3_one_channel_unchecked(
    conv: &ConvLayer<'_>,
    src: &[i8],
    out: &mut [i8],
    scratch: &mut [i16],
    width: usize,
) {
    let linear = &conv.linear;
    let rows = linear.rows;
    let padding = usize::from(conv.record.padding);
    let stride = usize::from(conv.record.stride);
    let zero_point = i16::from(linear.input_zero_point);
    let mut first_row = 0;
    while first_row < rows {
        let chunk = (rows - first_row).min(16);
        // Weights: vector 2 * (2 * ky + pair) + r / 8, lanes 2 * (r % 8) + (kx % 2).
        let mut packed = [[0i16; 32]; 12];
        for r in 0..chunk {
            let row = first_row + r;
            let weights = linear.weights.get(row * 9..row * 9 + 9).unwrap_or(&[]);
            for (k, &w) in weights.iter().enumerate() {
                let (ky, kx) = (k / 3, k % 3);
                if let Some(slot) = packed
                    .get_mut(2 * (2 * ky + kx / 2) + r / 8)
                    .and_then(|v| v.get_mut(2 * (r % 8) + kx % 2))
                {
                    *slot = i16::from(w as i8);
                }
            }
        }
        // SAFETY: each packed vector is 32 i16 (2 x 256 bits); the first 16 are loaded.
        let w = packed.map(|v| unsafe { _mm256_loadu_si256(v.as_ptr().cast()) });
        let (bias_lo, bias_hi, constants) = chunk_constants(linear, first_row, chunk);
        for oy in 0..conv.out_rows {
            // The three input rows of this output row, widened and zero-padded.
            for (ky, line) in scratch.chunks_exact_mut(width).take(3).enumerate() {
                let iy = (oy * stride + ky).checked_sub(padding);
                let cells = iy
                    .filter(|&iy| iy < conv.in_rows)
                    .and_then(|iy| src.get(iy * conv.in_cols..(iy + 1) * conv.in_cols));
                line.fill(0);
                if let (Some(cells), Some(inside)) =
                    (cells, line.get_mut(padding..padding + conv.in_cols))
                {
                    for (x, &q) in inside.iter_mut().zip(cells) {
                        *x = i16::from(q) - zero_point;
                    }
                }
            }
            let base = scratch.as_ptr();
            for ox in 0..conv.out_cols {
                let mut lo = bias_lo;
                let mut hi = bias_hi;
                for ky in 0..3 {
                    for pair in 0..2 {
                        // SAFETY: ky * width + ox * stride + 2 * pair + 1 < 3 * width <=
                        // scratch.len() (checked by the caller: (out_cols - 1) * stride + 4
                        // <= width); read_unaligned has no alignment requirement.
                        let xs = _mm256_set1_epi32(unsafe {
                            base.add(ky * width + ox * stride + 2 * pair)
                                .cast::<i32>()
                                .read_unaligned()
                        });
                        let v = 2 * (2 * ky + pair);
                        if let (Some(&w_lo), Some(&w_hi)) = (w.get(v), w.get(v + 1)) {
                            lo = _mm256_add_epi32(lo, _mm256_madd_epi16(xs, w_lo));
                            hi = _mm256_add_epi32(hi, _mm256_madd_epi16(xs, w_hi));
                        }
                    }
                }
                let at = (oy * conv.out_cols + ox) * rows + first_row;
                store16(lo, hi, &constants, out, at, chunk);
            }
        }
        first_row += chunk;
    }
}
