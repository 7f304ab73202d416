//! The data movement around the GEMM: the layer input laid out as one row per output pixel
//! (im2col) and its adjoint (col2im).

use super::Geometry;
use crate::network_f32::ConvSpec;

/// Row `s * P + p` of `col` holds, for output pixel `p` of sample `s`, the input values each
/// (kernel row, kernel column, channel) tap multiplies (0 in the padding). `input` is
/// `[samples][rows][cols][C_in]`. Hand-written because it is pure data movement specific to
/// this layout; the multiply-adds are in the GEMM.
#[inline(always)]
pub(super) fn im2col(input: &[f32], g: &Geometry, samples: usize, col: &mut [f32]) {
    let s = g.spec;
    let (w, c_in, k) = (g.in_cols, s.in_channels, s.kernel);
    let (row_taps, col_taps) = (taps(g.out_rows, s, g.in_rows), taps(g.out_cols, s, w));
    let runs = runs(&col_taps, k);
    let mut rows = col.chunks_exact_mut(g.patch_len());
    for image in input.chunks_exact(g.in_len()).take(samples) {
        for ys in row_taps.chunks_exact(k) {
            for (xs, &run) in col_taps.chunks_exact(k).zip(&runs) {
                let Some(row) = rows.next() else { return };
                for (&iy, taps) in ys.iter().zip(row.chunks_exact_mut(k * c_in)) {
                    let Some(iy) = iy else {
                        taps.fill(0.0);
                        continue;
                    };
                    let line = &image[iy * w * c_in..(iy + 1) * w * c_in];
                    if let Some(x0) = run {
                        copy(taps, &line[x0 * c_in..][..k * c_in]);
                        continue;
                    }
                    for (&ix, dst) in xs.iter().zip(taps.chunks_exact_mut(c_in)) {
                        match ix {
                            Some(ix) => dst.copy_from_slice(&line[ix * c_in..][..c_in]),
                            None => dst.fill(0.0),
                        }
                    }
                }
            }
        }
    }
}

/// The adjoint of [`im2col`]: adds each `col` entry onto the input value it was read from
/// (`d_input` must start zeroed; padding entries are dropped). (Gathering each input value's
/// sum instead, written once with no zeroing pass, measured no faster: its reads of `col`
/// scatter.)
#[inline(always)]
pub(super) fn col2im(col: &[f32], g: &Geometry, samples: usize, d_input: &mut [f32]) {
    let s = g.spec;
    let (w, c_in, k) = (g.in_cols, s.in_channels, s.kernel);
    let (row_taps, col_taps) = (taps(g.out_rows, s, g.in_rows), taps(g.out_cols, s, w));
    let runs = runs(&col_taps, k);
    let mut rows = col.chunks_exact(g.patch_len());
    for image in d_input.chunks_exact_mut(g.in_len()).take(samples) {
        for ys in row_taps.chunks_exact(k) {
            for (xs, &run) in col_taps.chunks_exact(k).zip(&runs) {
                let Some(row) = rows.next() else { return };
                for (&iy, taps) in ys.iter().zip(row.chunks_exact(k * c_in)) {
                    let Some(iy) = iy else { continue };
                    let line = &mut image[iy * w * c_in..(iy + 1) * w * c_in];
                    if let Some(x0) = run {
                        let dst = &mut line[x0 * c_in..][..k * c_in];
                        dst.iter_mut().zip(taps).for_each(|(d, v)| *d += v);
                        continue;
                    }
                    for (&ix, src) in xs.iter().zip(taps.chunks_exact(c_in)) {
                        if let Some(ix) = ix {
                            let dst = &mut line[ix * c_in..][..c_in];
                            dst.iter_mut().zip(src).for_each(|(d, v)| *d += v);
                        }
                    }
                }
            }
        }
    }
}

/// Per output index, the first input index of its `k` taps when all of them lie inside the
/// input: they are then consecutive, and a kernel row's taps are one contiguous run of
/// `k * C_in` values (every output pixel but those on the padded border).
fn runs(taps: &[Option<usize>], k: usize) -> Vec<Option<usize>> {
    taps.chunks_exact(k)
        .map(|xs| match (xs.first(), xs.last()) {
            (Some(&Some(first)), Some(&Some(_))) => Some(first),
            _ => None,
        })
        .collect()
}

/// `dst = src` (same lengths), in blocks of 16 values where it can: a copy of a length known
/// at compile time is a few vector moves, where a run's length known only at run time would
/// be a `memcpy` call per run.
#[inline(always)]
fn copy(dst: &mut [f32], src: &[f32]) {
    let mut blocks = dst.chunks_exact_mut(16);
    let mut from = src.chunks_exact(16);
    for (d, s) in blocks.by_ref().zip(from.by_ref()) {
        d.copy_from_slice(s);
    }
    for (d, s) in blocks.into_remainder().iter_mut().zip(from.remainder()) {
        *d = *s;
    }
}

/// For each output index and kernel offset (`[out][k]`), the input index it reads, or `None`
/// in the padding: looked up by im2col/col2im instead of recomputed per element.
pub(super) fn taps(out_len: usize, s: ConvSpec, len: usize) -> Vec<Option<usize>> {
    (0..out_len)
        .flat_map(|o| (0..s.kernel).map(move |k| tap(o, k, s, len)))
        .collect()
}

/// Input index read by output index `o` at kernel offset `k`, or `None` in the padding.
#[inline]
fn tap(o: usize, k: usize, s: ConvSpec, len: usize) -> Option<usize> {
    (o * s.stride + k)
        .checked_sub(s.padding)
        .filter(|&i| i < len)
}
