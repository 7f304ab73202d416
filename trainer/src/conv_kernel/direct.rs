//! The first layer (one input channel: the height maps) computed directly, without im2col.
//!
//! Why: its im2col matrix is `k * k` floats per output pixel for `k * k * C_out` multiply-adds
//! per pixel, and writing it, reading it back and running a GEMM with an inner dimension of 9
//! cost more than the products. Here each output pixel's `C_out` values are accumulated in
//! blocks of [`LANES`] (one AVX-512 register, two AVX2 ones) straight from the map, and the
//! weight gradient is accumulated the same way, from the maps the tape keeps in place of the
//! im2col matrix.

use super::im2col::taps;
use super::Geometry;

/// Output channels per block: the direct path needs `C_out` to be a multiple of it.
pub(super) const LANES: usize = 16;

/// The kernel side the direct path is built for (the policy's 3 x 3): with the taps known at
/// compile time, a pixel's inputs and a block's per-tap sums live in registers.
const KERNEL: usize = 3;

/// Taps per output pixel.
const TAPS: usize = KERNEL * KERNEL;

type Block = [f32; LANES];

/// Whether layer `l` of `g` takes the direct path.
pub(super) fn applies(l: usize, g: &Geometry) -> bool {
    l == 0
        && g.spec.in_channels == 1
        && g.spec.kernel == KERNEL
        && g.spec.out_channels > 0
        && g.spec.out_channels.is_multiple_of(LANES)
}

/// `[O][ky][kx]` (the layer's weights with one input channel) -> `[ky][kx][O]`: one row of
/// output channels per tap.
pub(super) fn tap_major(weights_hwc: &[f32], g: &Geometry) -> Vec<f32> {
    let c_out = g.spec.out_channels;
    let mut out = vec![0.0; weights_hwc.len()];
    for o in 0..c_out {
        for t in 0..TAPS {
            out[t * c_out + o] = weights_hwc[o * TAPS + t];
        }
    }
    out
}

/// For each output pixel of a map, the offsets in the map of its nine taps in `(ky, kx)`
/// order (`None` in the padding).
fn tap_offsets(g: &Geometry) -> Vec<[Option<usize>; TAPS]> {
    let row_taps = taps(g.out_rows, g.spec, g.in_rows);
    let col_taps = taps(g.out_cols, g.spec, g.in_cols);
    let mut out = Vec::with_capacity(g.out_pixels());
    for ys in row_taps.chunks_exact(KERNEL) {
        for xs in col_taps.chunks_exact(KERNEL) {
            let mut offsets = [None; TAPS];
            for (ky, iy) in ys.iter().enumerate() {
                for (kx, ix) in xs.iter().enumerate() {
                    if let (Some(iy), Some(ix)) = (iy, ix) {
                        offsets[ky * KERNEL + kx] = Some(iy * g.in_cols + ix);
                    }
                }
            }
            out.push(offsets);
        }
    }
    out
}

/// A pixel's nine input values, 0 in the padding: a zero adds nothing to a sum, so the border
/// needs no branch in the products.
#[inline(always)]
fn gather(map: &[f32], offsets: &[Option<usize>; TAPS]) -> [f32; TAPS] {
    let mut v = [0.0; TAPS];
    for (v, o) in v.iter_mut().zip(offsets) {
        if let Some(o) = *o {
            *v = map[o];
        }
    }
    v
}

/// Forward of the layer with bias and ReLU: `out` is `[samples * P][C_out]`, `maps`
/// `[samples][rows][cols]`, `weights` tap-major ([`tap_major`]).
#[inline(always)]
pub(super) fn forward(
    maps: &[f32],
    g: &Geometry,
    samples: usize,
    weights: &[f32],
    bias: &[f32],
    out: &mut [f32],
) {
    let (c_out, pixels) = (g.spec.out_channels, g.out_pixels());
    let offsets = tap_offsets(g);
    let maps = maps.chunks_exact(g.in_len()).take(samples);
    for (map, out) in maps.zip(out.chunks_exact_mut(pixels * c_out)) {
        for (offsets, pixel) in offsets.iter().zip(out.chunks_exact_mut(c_out)) {
            let v = gather(map, offsets);
            for (b, (dst, bias)) in pixel
                .chunks_exact_mut(LANES)
                .zip(bias.chunks_exact(LANES))
                .enumerate()
            {
                let mut acc = block(bias);
                for (t, &v) in v.iter().enumerate() {
                    let row = block(&weights[t * c_out + b * LANES..]);
                    for (a, w) in acc.iter_mut().zip(row) {
                        *a += v * w;
                    }
                }
                for (d, a) in dst.iter_mut().zip(acc) {
                    *d = a.max(0.0);
                }
            }
        }
    }
}

/// The layer's weight gradient `[O][ky][kx]` from `d_out` (`[samples * P][C_out]`, already
/// through the ReLU) and the `maps` the forward pass read; overwrites `d_weights`.
#[inline(always)]
pub(super) fn weight_gradient(
    maps: &[f32],
    g: &Geometry,
    samples: usize,
    d_out: &[f32],
    d_weights: &mut [f32],
) {
    let (c_out, pixels) = (g.spec.out_channels, g.out_pixels());
    let offsets = tap_offsets(g);
    for b in 0..c_out / LANES {
        // One block of output channels at a time, its nine per-tap sums over the chunk's
        // pixels in order.
        let mut acc = [[0.0f32; LANES]; TAPS];
        let maps = maps.chunks_exact(g.in_len()).take(samples);
        for (map, d_out) in maps.zip(d_out.chunks_exact(pixels * c_out)) {
            for (offsets, pixel) in offsets.iter().zip(d_out.chunks_exact(c_out)) {
                let v = gather(map, offsets);
                let d = block(&pixel[b * LANES..]);
                for (sum, &v) in acc.iter_mut().zip(&v) {
                    for (a, d) in sum.iter_mut().zip(d) {
                        *a += v * d;
                    }
                }
            }
        }
        for (t, sum) in acc.iter().enumerate() {
            for (lane, &v) in sum.iter().enumerate() {
                d_weights[(b * LANES + lane) * TAPS + t] = v;
            }
        }
    }
}

/// The first [`LANES`] values of `v` as a fixed-size block (`v` holds at least that many).
#[inline(always)]
fn block(v: &[f32]) -> Block {
    let mut out = [0.0; LANES];
    out.copy_from_slice(&v[..LANES]);
    out
}
