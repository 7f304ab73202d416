//! A specialised CPU kernel for the conv stack during training (issue 3): forward and backward
//! of the stride-2 3x3 convolutions (+ bias + ReLU) as im2col + GEMM.
//!
//! Why: the three convs are ~480k of the network's ~547k multiply-adds per sample, and burn's
//! generic conv2d (forward and autodiff backward) made the PPO update 0.6-0.7x as fast as the
//! JAX reference (docs/decisions.md). Only this hot part is hand-written, and only its data
//! movement (im2col, col2im, transposes, bias, ReLU masks): the products run on the `gemm`
//! crate's tuned, run-time-dispatched kernels ([`gemm`]). Everything after the conv features
//! (dense layers, log-softmax, the PPO loss and their gradients) stays in burn's autodiff: the
//! features enter the graph as a leaf tensor and its gradient comes back into [`backward`].
//! Tests hold every output and gradient to burn's own conv2d autodiff.
//!
//! Layouts: a layer's input and output activations are channel-major over a chunk of samples,
//! `[channels][sample][row][col]`, so a layer is one GEMM `out[C_out, n] = W[C_out, K] *
//! col[K, n]` with `K = C_in * k * k` (OIHW weight rows as stored in `network_f32`) and
//! `n = samples * out_rows * out_cols`; the first layer's input (one channel) is the height
//! maps as they are. Features are handed to burn as `[batch, C * rows * cols]` (CHW flatten,
//! the `network_f32` order).
//!
//! Determinism: the batch is cut into fixed chunks of [`CHUNK_SAMPLES`] samples whatever the
//! thread count; chunks run on rayon's pool (each with single-threaded GEMMs) and their
//! weight-gradient partials are summed in chunk order, so results do not depend on threads or
//! scheduling.

mod gemm;

use self::gemm::{matmul, MatRef};
use crate::network_f32::{Conv2dF32, ConvSpec};
use rayon::prelude::*;

/// Samples per chunk: the unit of parallel work and of the fixed gradient summation order.
/// 32 keeps the largest im2col matrix (conv 2: 144 x 2048 floats, 1.2 MB) near the 1 MB L2
/// of this machine's cores while the GEMMs stay large enough to run at full speed.
pub const CHUNK_SAMPLES: usize = 32;

/// Which implementation computes the conv stack in training.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConvKernel {
    /// This module's im2col + GEMM kernel (conv features enter burn as a leaf tensor).
    Native,
    /// burn's own conv2d inside the autodiff graph.
    Burn,
}

impl ConvKernel {
    /// Parses a name as used in configs (`ppo.conv_kernel`).
    pub fn from_name(name: &str) -> Result<ConvKernel, String> {
        match name {
            "native" => Ok(ConvKernel::Native),
            "burn" => Ok(ConvKernel::Burn),
            other => Err(format!(
                "unknown conv kernel {other:?} (expected \"native\" or \"burn\")"
            )),
        }
    }
}

/// Gradients of one conv layer's parameters, in `Conv2dF32`'s layouts.
#[derive(Clone, Debug, PartialEq)]
pub struct ConvGradients {
    /// `out * in * k * k`, OIHW.
    pub weights: Vec<f32>,
    /// `out`.
    pub bias: Vec<f32>,
}

/// One layer's sizes.
#[derive(Clone, Copy, Debug)]
struct Geometry {
    spec: ConvSpec,
    in_rows: usize,
    in_cols: usize,
    out_rows: usize,
    out_cols: usize,
}

impl Geometry {
    /// im2col rows: one per (input channel, kernel row, kernel column).
    fn patch_len(&self) -> usize {
        self.spec.in_channels * self.spec.kernel * self.spec.kernel
    }

    fn in_pixels(&self) -> usize {
        self.in_rows * self.in_cols
    }

    fn out_pixels(&self) -> usize {
        self.out_rows * self.out_cols
    }
}

/// What one chunk's forward pass keeps for the backward pass.
struct ChunkTape {
    samples: usize,
    /// Per layer: im2col matrix `[K][samples * out_pixels]`.
    cols: Vec<Vec<f32>>,
    /// Per layer: post-ReLU output `[C_out][samples][out_pixels]` (its sign is the ReLU mask).
    outs: Vec<Vec<f32>>,
}

/// Everything [`backward`] needs from a training [`forward`].
pub struct ConvTape {
    geometry: Vec<Geometry>,
    chunks: Vec<ChunkTape>,
    batch: usize,
}

impl ConvTape {
    /// Samples the tape was recorded for.
    pub fn batch(&self) -> usize {
        self.batch
    }
}

/// Checks the layers against each other and the map size; returns each layer's geometry.
fn geometry(convs: &[Conv2dF32], rows: usize, cols: usize) -> Result<Vec<Geometry>, String> {
    let (mut h, mut w, mut channels) = (rows, cols, 1);
    let mut out = Vec::with_capacity(convs.len());
    for (i, c) in convs.iter().enumerate() {
        let s = c.spec;
        if s.in_channels != channels {
            return Err(format!(
                "conv {i} reads {} channels but its input has {channels}",
                s.in_channels
            ));
        }
        if s.kernel == 0 || s.stride == 0 || h + 2 * s.padding < s.kernel {
            return Err(format!(
                "conv {i}: kernel {} stride {} padding {} does not fit a {h}x{w} input",
                s.kernel, s.stride, s.padding
            ));
        }
        if w + 2 * s.padding < s.kernel {
            return Err(format!("conv {i}: kernel {} wider than input", s.kernel));
        }
        let weights = s.out_channels * s.in_channels * s.kernel * s.kernel;
        if c.weights.len() != weights || c.bias.len() != s.out_channels {
            return Err(format!(
                "conv {i}: {} weights and {} biases, expected {weights} and {}",
                c.weights.len(),
                c.bias.len(),
                s.out_channels
            ));
        }
        let g = Geometry {
            spec: s,
            in_rows: h,
            in_cols: w,
            out_rows: s.output_side(h),
            out_cols: s.output_side(w),
        };
        (h, w, channels) = (g.out_rows, g.out_cols, s.out_channels);
        out.push(g);
    }
    Ok(out)
}

/// Length of one sample's features after `geometry` (the raw map without convs).
fn features_len(geometry: &[Geometry], rows: usize, cols: usize) -> usize {
    geometry
        .last()
        .map_or(rows * cols, |g| g.spec.out_channels * g.out_pixels())
}

/// Training forward pass of the conv stack over `batch` height maps of `rows x cols`
/// (`heights_m`: `batch * rows * cols`, row-major maps). Returns the features
/// (`batch * features_len`, CHW per sample) and the tape for [`backward`].
pub fn forward(
    convs: &[Conv2dF32],
    rows: usize,
    cols: usize,
    heights_m: &[f32],
    batch: usize,
) -> Result<(Vec<f32>, ConvTape), String> {
    let (features, chunks, geometry) = run_forward(convs, rows, cols, heights_m, batch, true)?;
    Ok((
        features,
        ConvTape {
            geometry,
            chunks,
            batch,
        },
    ))
}

/// Inference forward pass: the features only, nothing kept for a backward pass.
pub fn features(
    convs: &[Conv2dF32],
    rows: usize,
    cols: usize,
    heights_m: &[f32],
    batch: usize,
) -> Result<Vec<f32>, String> {
    run_forward(convs, rows, cols, heights_m, batch, false).map(|(f, _, _)| f)
}

type ForwardParts = (Vec<f32>, Vec<ChunkTape>, Vec<Geometry>);

fn run_forward(
    convs: &[Conv2dF32],
    rows: usize,
    cols: usize,
    heights_m: &[f32],
    batch: usize,
    keep: bool,
) -> Result<ForwardParts, String> {
    let geometry = geometry(convs, rows, cols)?;
    let map_len = rows * cols;
    if heights_m.len() != batch * map_len {
        return Err(format!(
            "conv forward: {} height values for {batch} maps of {rows}x{cols}",
            heights_m.len()
        ));
    }
    let chunk_len = CHUNK_SAMPLES * map_len;
    if batch == 0 || chunk_len == 0 {
        return Ok((Vec::new(), Vec::new(), geometry));
    }
    let parts: Vec<(Vec<f32>, ChunkTape)> = heights_m
        .par_chunks(chunk_len)
        .map(|maps| forward_chunk(convs, &geometry, maps, maps.len() / map_len, keep))
        .collect::<Result<_, String>>()?;
    let per_sample = features_len(&geometry, rows, cols);
    let mut features = Vec::with_capacity(batch * per_sample);
    let mut tapes = Vec::with_capacity(if keep { parts.len() } else { 0 });
    for (f, tape) in parts {
        features.extend_from_slice(&f);
        if keep {
            tapes.push(tape);
        }
    }
    Ok((features, tapes, geometry))
}

/// Forward pass of one chunk of `samples` maps; returns its features `[samples][F]`.
fn forward_chunk(
    convs: &[Conv2dF32],
    geometry: &[Geometry],
    maps: &[f32],
    samples: usize,
    keep: bool,
) -> Result<(Vec<f32>, ChunkTape), String> {
    let mut tape = ChunkTape {
        samples,
        cols: Vec::with_capacity(convs.len()),
        outs: Vec::with_capacity(convs.len()),
    };
    for (l, (conv, g)) in convs.iter().zip(geometry).enumerate() {
        let input: &[f32] = if l == 0 { maps } else { &tape.outs[l - 1] };
        let n = samples * g.out_pixels();
        let k = g.patch_len();
        let mut col = vec![0.0f32; k * n];
        im2col(input, g, samples, &mut col);
        let c_out = g.spec.out_channels;
        let mut out = vec![0.0f32; c_out * n];
        matmul(
            &mut out,
            MatRef::row_major(&conv.weights, c_out, k),
            MatRef::row_major(&col, k, n),
            false,
        )?;
        for (row, &b) in out.chunks_exact_mut(n).zip(&conv.bias) {
            row.iter_mut().for_each(|v| *v = (*v + b).max(0.0));
        }
        // Inference needs only the previous layer's output; drop what is behind it.
        if !keep && l > 0 {
            tape.outs[l - 1] = Vec::new();
        }
        if keep {
            tape.cols.push(col);
        }
        tape.outs.push(out);
    }
    let features = match (geometry.last(), tape.outs.last()) {
        (Some(g), Some(out)) => {
            let (c, p) = (g.spec.out_channels, g.out_pixels());
            let mut f = vec![0.0f32; samples * c * p];
            // [C][sample][P] -> [sample][C][P]
            for ch in 0..c {
                for s in 0..samples {
                    f[(s * c + ch) * p..][..p].copy_from_slice(&out[(ch * samples + s) * p..][..p]);
                }
            }
            f
        }
        _ => maps.to_vec(),
    };
    Ok((features, tape))
}

/// Gradients of every conv layer's weights and bias (layer order) from the loss gradient with
/// respect to the features (`d_features`: `batch * features_len`, as [`forward`] returned).
pub fn backward(
    convs: &[Conv2dF32],
    tape: &ConvTape,
    d_features: &[f32],
) -> Result<Vec<ConvGradients>, String> {
    if convs.len() != tape.geometry.len()
        || convs
            .iter()
            .zip(&tape.geometry)
            .any(|(c, g)| c.spec != g.spec)
    {
        return Err("conv backward: the layers differ from the recorded forward pass".into());
    }
    let Some(last) = tape.geometry.last() else {
        return Ok(Vec::new());
    };
    let per_sample = last.spec.out_channels * last.out_pixels();
    if d_features.len() != tape.batch * per_sample {
        return Err(format!(
            "conv backward: {} feature gradients for {} samples of {per_sample}",
            d_features.len(),
            tape.batch
        ));
    }
    let mut starts = Vec::with_capacity(tape.chunks.len());
    let mut start = 0;
    for chunk in &tape.chunks {
        starts.push(start);
        start += chunk.samples * per_sample;
    }
    let partials: Vec<Vec<ConvGradients>> = tape
        .chunks
        .par_iter()
        .zip(starts)
        .map(|(chunk, start)| {
            let d = &d_features[start..start + chunk.samples * per_sample];
            backward_chunk(convs, &tape.geometry, chunk, d)
        })
        .collect::<Result<_, String>>()?;
    // Fixed summation order (chunk order): the same bits for any thread count.
    let mut partials = partials.into_iter();
    let mut total = partials.next().unwrap_or_else(|| {
        convs
            .iter()
            .map(|c| ConvGradients {
                weights: vec![0.0; c.weights.len()],
                bias: vec![0.0; c.bias.len()],
            })
            .collect()
    });
    for part in partials {
        for (t, p) in total.iter_mut().zip(part) {
            t.weights
                .iter_mut()
                .zip(&p.weights)
                .for_each(|(a, b)| *a += b);
            t.bias.iter_mut().zip(&p.bias).for_each(|(a, b)| *a += b);
        }
    }
    Ok(total)
}

/// Backward pass of one chunk: its share of every layer's parameter gradients.
fn backward_chunk(
    convs: &[Conv2dF32],
    geometry: &[Geometry],
    chunk: &ChunkTape,
    d_features: &[f32],
) -> Result<Vec<ConvGradients>, String> {
    let samples = chunk.samples;
    let mut grads: Vec<Option<ConvGradients>> = vec![None; convs.len()];
    // Gradient with respect to the current layer's post-ReLU output, `[C][sample][P]`.
    let mut d_out = {
        let Some(g) = geometry.last() else {
            return Ok(Vec::new());
        };
        let (c, p) = (g.spec.out_channels, g.out_pixels());
        let mut d = vec![0.0f32; c * samples * p];
        for s in 0..samples {
            for ch in 0..c {
                d[(ch * samples + s) * p..][..p]
                    .copy_from_slice(&d_features[(s * c + ch) * p..][..p]);
            }
        }
        d
    };
    for l in (0..convs.len()).rev() {
        let (conv, g) = (&convs[l], &geometry[l]);
        let (out, col) = match (chunk.outs.get(l), chunk.cols.get(l)) {
            (Some(o), Some(c)) => (o, c),
            _ => return Err("conv backward: the tape was recorded without training".into()),
        };
        // Through the ReLU: the gradient passes where the pre-activation was positive, the
        // same rule as burn's relu backward (a zero output stops it).
        for (d, &o) in d_out.iter_mut().zip(out) {
            if o <= 0.0 {
                *d = 0.0;
            }
        }
        let c_out = g.spec.out_channels;
        let n = samples * g.out_pixels();
        let k = g.patch_len();
        let bias: Vec<f32> = d_out.chunks_exact(n).map(|row| row.iter().sum()).collect();
        let mut weights = vec![0.0f32; c_out * k];
        // dW[C_out, K] = dZ[C_out, n] * col^T[n, K]
        matmul(
            &mut weights,
            MatRef::row_major(&d_out, c_out, n),
            MatRef::transposed(col, n, k),
            false,
        )?;
        grads[l] = Some(ConvGradients { weights, bias });
        if l > 0 {
            // dcol[K, n] = W^T[K, C_out] * dZ[C_out, n], scattered back onto the input.
            let mut d_col = vec![0.0f32; k * n];
            matmul(
                &mut d_col,
                MatRef::transposed(&conv.weights, k, c_out),
                MatRef::row_major(&d_out, c_out, n),
                false,
            )?;
            let mut d_in = vec![0.0f32; g.spec.in_channels * samples * g.in_pixels()];
            col2im(&d_col, g, samples, &mut d_in);
            d_out = d_in;
        }
    }
    Ok(grads.into_iter().flatten().collect())
}

/// For each output pixel `p` of sample `s` and each (channel, kernel row, kernel column) `r`,
/// `col[r][s * P + p]` is the input value that kernel tap multiplies (0 in the padding).
/// `input` is `[C_in][samples][rows][cols]`. Hand-written because it is pure data movement
/// specific to this layout; the multiply-adds are in the GEMM.
fn im2col(input: &[f32], g: &Geometry, samples: usize, col: &mut [f32]) {
    let s = g.spec;
    let n = samples * g.out_pixels();
    let (h, w) = (g.in_rows, g.in_cols);
    let mut rows = col.chunks_exact_mut(n);
    for ci in 0..s.in_channels {
        for ky in 0..s.kernel {
            for kx in 0..s.kernel {
                let Some(row) = rows.next() else { return };
                for b in 0..samples {
                    let plane = &input[(ci * samples + b) * h * w..][..h * w];
                    for oy in 0..g.out_rows {
                        let dst = &mut row[(b * g.out_rows + oy) * g.out_cols..][..g.out_cols];
                        let Some(iy) = tap(oy, ky, s, h) else {
                            dst.fill(0.0);
                            continue;
                        };
                        let src = &plane[iy * w..][..w];
                        for (ox, d) in dst.iter_mut().enumerate() {
                            *d = tap(ox, kx, s, w).map_or(0.0, |ix| src[ix]);
                        }
                    }
                }
            }
        }
    }
}

/// The adjoint of [`im2col`]: adds each `col` entry onto the input value it was read from
/// (`d_input` must start zeroed; padding entries are dropped).
fn col2im(col: &[f32], g: &Geometry, samples: usize, d_input: &mut [f32]) {
    let s = g.spec;
    let n = samples * g.out_pixels();
    let (h, w) = (g.in_rows, g.in_cols);
    let mut rows = col.chunks_exact(n);
    for ci in 0..s.in_channels {
        for ky in 0..s.kernel {
            for kx in 0..s.kernel {
                let Some(row) = rows.next() else { return };
                for b in 0..samples {
                    let plane = &mut d_input[(ci * samples + b) * h * w..][..h * w];
                    for oy in 0..g.out_rows {
                        let Some(iy) = tap(oy, ky, s, h) else {
                            continue;
                        };
                        let src = &row[(b * g.out_rows + oy) * g.out_cols..][..g.out_cols];
                        let dst = &mut plane[iy * w..][..w];
                        for (ox, &v) in src.iter().enumerate() {
                            if let Some(ix) = tap(ox, kx, s, w) {
                                dst[ix] += v;
                            }
                        }
                    }
                }
            }
        }
    }
}

/// Input index read by output index `o` at kernel offset `k`, or `None` in the padding.
#[inline]
fn tap(o: usize, k: usize, s: ConvSpec, len: usize) -> Option<usize> {
    (o * s.stride + k)
        .checked_sub(s.padding)
        .filter(|&i| i < len)
}

#[cfg(test)]
mod tests;
