//! A specialised CPU kernel for the conv stack: forward and backward of the
//! convolutions (+ bias + ReLU; any `ConvSpec`, the policy's are stride-2 3x3) as im2col + GEMM.
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
//! Layouts: activations are channels-last over a chunk of samples, `[sample][row][col][ch]`
//! (the first layer's input, one channel, is the height maps as they are), so each im2col row
//! (one output pixel) is `k * k` contiguous copies of `C_in` channels, and a layer is one GEMM
//! `out[n, C_out] = col[n, K] * W'^T` with `n = samples * out_rows * out_cols` and
//! `K = k * k * C_in` in (kernel row, kernel column, channel) order. `W'` is the OIHW weight
//! (`network_f32`) permuted to that order once per call (a few thousand floats), and its
//! gradient is permuted back. Why channels-last rather than channel-major
//! (`[ch][sample][row][col]`, the first version): its GEMMs measured 1.2-1.6x faster (conv 2,
//! per 32-sample chunk: forward 215 vs 328 us, weight gradient 280 vs 450 us) and im2col copies
//! runs of C_in floats instead of rows of 4 to 16 with per-row bounds logic. Features are
//! handed to burn as `[batch, C * rows * cols]` (CHW flatten, the `network_f32` order).
//!
//! The first layer (one input channel, a multiple of 16 output channels, 3 x 3: the policy's)
//! skips im2col: `direct` computes it and its weight gradient straight from the maps. The
//! data movement and the direct layer are compiled for each SIMD level and picked at run time
//! (`ForwardPass`). Figures: docs/decisions.md.
//!
//! Determinism: the batch is cut into fixed chunks of [`CHUNK_SAMPLES`] samples whatever the
//! thread count; chunks run on rayon's pool (each with single-threaded GEMMs) and their
//! weight-gradient partials are summed in chunk order, so results do not depend on threads or
//! scheduling.

mod direct;
mod gemm;
mod im2col;

use self::gemm::{matmul, MatRef};
use self::im2col::{col2im, im2col};
use crate::error::TrainError;
use crate::network_f32::{Conv2dF32, ConvSpec};
use rayon::prelude::*;

/// Samples per chunk: the unit of parallel work and of the fixed gradient summation order.
/// 16 keeps the largest im2col matrix (conv 2: 1024 x 144 floats, 0.6 MB) well inside a core's
/// L2 while the GEMMs stay large enough to run at full speed; 32 measured 17-19% slower in the
/// batch-64 forward (two chunks for two threads, each past L2) and the same in the update.
pub const CHUNK_SAMPLES: usize = 16;

/// Which implementation computes the conv stack, in updates and in `Ppo::evaluate`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ConvKernel {
    /// This module's im2col + GEMM kernel (conv features enter burn as a leaf tensor).
    Native,
    /// burn's own conv2d inside the autodiff graph.
    Burn,
}

impl ConvKernel {
    /// Parses a name as used in configs (`ppo.conv_kernel`).
    pub fn from_name(name: &str) -> Result<ConvKernel, TrainError> {
        match name {
            "native" => Ok(ConvKernel::Native),
            "burn" => Ok(ConvKernel::Burn),
            other => Err(TrainError::setting(
                "ppo.conv_kernel",
                format!("unknown conv kernel {other:?} (expected \"native\" or \"burn\")"),
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
    /// im2col columns: one per (kernel row, kernel column, input channel).
    fn patch_len(&self) -> usize {
        self.spec.in_channels * self.spec.kernel * self.spec.kernel
    }

    fn in_len(&self) -> usize {
        self.in_rows * self.in_cols * self.spec.in_channels
    }

    fn out_pixels(&self) -> usize {
        self.out_rows * self.out_cols
    }
}

/// What one chunk's forward pass keeps for the backward pass, and the chunk's scratch
/// buffers. Kept across calls (see [`ConvTape`]) so that a training step reuses its ~3 MB per
/// chunk instead of fresh allocations, whose page faults cost ~20% of the kernel's time.
#[derive(Default)]
struct ChunkTape {
    samples: usize,
    /// Per layer: im2col matrix `[samples * out_pixels][K]`; for a layer on the direct path
    /// (`direct`), the maps it read.
    cols: Vec<Vec<f32>>,
    /// Per layer: post-ReLU output `[samples * out_pixels][C_out]` (its sign is the ReLU mask).
    outs: Vec<Vec<f32>>,
    /// Backward scratch: gradient of the current layer's output, of its im2col matrix, and of
    /// its input.
    d_out: Vec<f32>,
    d_col: Vec<f32>,
    d_in: Vec<f32>,
}

/// Everything [`backward`] needs from a training [`forward`]. Reusing one tape for every
/// step ([`forward_into`]) keeps its buffers allocated.
#[derive(Default)]
pub struct ConvTape {
    geometry: Vec<Geometry>,
    /// Per layer: the weights in `[C_out][ky][kx][C_in]` order, as the forward pass used them.
    weights_hwc: Vec<Vec<f32>>,
    chunks: Vec<ChunkTape>,
    batch: usize,
}

impl ConvTape {
    /// Samples the tape was recorded for.
    pub fn batch(&self) -> usize {
        self.batch
    }
}

/// One chunk's forward pass ([`forward_chunk`]), run through `pulp` so that it is
/// compiled for the widest SIMD this CPU has (AVX-512, AVX2 with FMA, or the portable
/// baseline), chosen at run time. The data movement and elementwise loops here are plain Rust
/// the compiler vectorizes; outside such a pass they are built for baseline x86-64 (SSE2) only.
/// Only code inlined into `with_simd` gets the wider instructions: the pass bodies and every
/// helper they call are `#[inline(always)]`, and a pass is a struct because a closure handed to
/// `pulp` is not inlined. Elementwise results are the same bits on every path.
struct ForwardPass<'a> {
    convs: &'a [Conv2dF32],
    geometry: &'a [Geometry],
    weights_hwc: &'a [Vec<f32>],
    maps: &'a [f32],
    samples: usize,
    chunk: &'a mut ChunkTape,
    features: &'a mut [f32],
}

impl pulp::WithSimd for ForwardPass<'_> {
    type Output = Result<(), TrainError>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        forward_chunk(self)
    }
}

/// One chunk's backward pass ([`backward_chunk`]), dispatched as [`ForwardPass`].
struct BackwardPass<'a> {
    geometry: &'a [Geometry],
    weights_hwc: &'a [Vec<f32>],
    chunk: &'a mut ChunkTape,
    d_features: &'a [f32],
}

impl pulp::WithSimd for BackwardPass<'_> {
    type Output = Result<Vec<ConvGradients>, TrainError>;

    #[inline(always)]
    fn with_simd<S: pulp::Simd>(self, _: S) -> Self::Output {
        backward_chunk(self)
    }
}

/// Sets `v` to `len` values without clearing them: every caller overwrites all of them.
fn set_len(v: &mut Vec<f32>, len: usize) -> &mut [f32] {
    v.resize(len, 0.0);
    v
}

/// Checks the layers against each other and the map size; returns each layer's geometry.
fn geometry(convs: &[Conv2dF32], rows: usize, cols: usize) -> Result<Vec<Geometry>, TrainError> {
    let (mut h, mut w, mut channels) = (rows, cols, 1);
    let mut out = Vec::with_capacity(convs.len());
    for (i, c) in convs.iter().enumerate() {
        let s = c.spec;
        if s.in_channels != channels {
            return Err(TrainError::Shape(format!(
                "conv {i} reads {} channels but its input has {channels}",
                s.in_channels
            )));
        }
        if s.kernel == 0
            || s.stride == 0
            || h + 2 * s.padding < s.kernel
            || w + 2 * s.padding < s.kernel
        {
            return Err(TrainError::Shape(format!(
                "conv {i}: kernel {} stride {} padding {} does not fit a {h}x{w} input",
                s.kernel, s.stride, s.padding
            )));
        }
        let weights = s.out_channels * s.in_channels * s.kernel * s.kernel;
        if c.weights.len() != weights || c.bias.len() != s.out_channels {
            return Err(TrainError::Shape(format!(
                "conv {i}: {} weights and {} biases, expected {weights} and {}",
                c.weights.len(),
                c.bias.len(),
                s.out_channels
            )));
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

/// OIHW -> `[O][ky][kx][I]` (the im2col column order).
fn to_hwc(weights: &[f32], s: ConvSpec) -> Vec<f32> {
    let (i_n, k) = (s.in_channels, s.kernel);
    let mut out = vec![0.0f32; weights.len()];
    for o in 0..s.out_channels {
        for i in 0..i_n {
            for t in 0..k * k {
                out[(o * k * k + t) * i_n + i] = weights[(o * i_n + i) * k * k + t];
            }
        }
    }
    out
}

/// `[O][ky][kx][I]` -> OIHW (inverse of [`to_hwc`]).
fn from_hwc(weights: &[f32], s: ConvSpec) -> Vec<f32> {
    let (i_n, k) = (s.in_channels, s.kernel);
    let mut out = vec![0.0f32; weights.len()];
    for o in 0..s.out_channels {
        for i in 0..i_n {
            for t in 0..k * k {
                out[(o * i_n + i) * k * k + t] = weights[(o * k * k + t) * i_n + i];
            }
        }
    }
    out
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
) -> Result<(Vec<f32>, ConvTape), TrainError> {
    let mut tape = ConvTape::default();
    let features = forward_into(convs, rows, cols, heights_m, batch, &mut tape)?;
    Ok((features, tape))
}

/// Inference forward pass: the features only.
pub fn features(
    convs: &[Conv2dF32],
    rows: usize,
    cols: usize,
    heights_m: &[f32],
    batch: usize,
) -> Result<Vec<f32>, TrainError> {
    forward(convs, rows, cols, heights_m, batch).map(|(f, _)| f)
}

/// [`forward`] recording into `tape`, reusing its buffers (whatever it held is replaced).
pub fn forward_into(
    convs: &[Conv2dF32],
    rows: usize,
    cols: usize,
    heights_m: &[f32],
    batch: usize,
    tape: &mut ConvTape,
) -> Result<Vec<f32>, TrainError> {
    tape.batch = 0;
    tape.geometry = geometry(convs, rows, cols)?;
    let map_len = rows * cols;
    if heights_m.len() != batch * map_len {
        return Err(TrainError::Shape(format!(
            "conv forward: {} height values for {batch} maps of {rows}x{cols}",
            heights_m.len()
        )));
    }
    tape.weights_hwc = convs.iter().map(|c| to_hwc(&c.weights, c.spec)).collect();
    let per_sample = features_len(&tape.geometry, rows, cols);
    let mut features = vec![0.0f32; batch * per_sample];
    if batch == 0 || map_len == 0 || per_sample == 0 {
        return Ok(features);
    }
    let chunks = batch.div_ceil(CHUNK_SAMPLES);
    tape.chunks.resize_with(chunks, ChunkTape::default);
    let (geometry, weights) = (&tape.geometry, &tape.weights_hwc);
    features
        .par_chunks_mut(CHUNK_SAMPLES * per_sample)
        .zip(heights_m.par_chunks(CHUNK_SAMPLES * map_len))
        .zip(tape.chunks.par_iter_mut())
        .try_for_each(|((features, maps), chunk)| {
            pulp::Arch::new().dispatch(ForwardPass {
                convs,
                geometry,
                weights_hwc: weights,
                maps,
                samples: maps.len() / map_len,
                chunk,
                features,
            })
        })?;
    tape.batch = batch;
    Ok(features)
}

/// Forward pass of one chunk of `samples` maps, writing its features `[samples][F]`;
/// inlined into each SIMD level's build ([`ForwardPass`]).
#[inline(always)]
fn forward_chunk(pass: ForwardPass<'_>) -> Result<(), TrainError> {
    let ForwardPass {
        convs,
        geometry,
        weights_hwc,
        maps,
        samples,
        chunk,
        features,
    } = pass;
    chunk.samples = samples;
    chunk.cols.resize_with(convs.len(), Vec::new);
    chunk.outs.resize_with(convs.len(), Vec::new);
    for (l, ((conv, g), w)) in convs.iter().zip(geometry).zip(weights_hwc).enumerate() {
        let n = samples * g.out_pixels();
        let k = g.patch_len();
        let c_out = g.spec.out_channels;
        let (done, rest) = chunk.outs.split_at_mut(l);
        let out = set_len(&mut rest[0], n * c_out);
        if direct::applies(l, g) {
            // The maps stand in for the im2col matrix: the backward pass reads them.
            let kept = set_len(&mut chunk.cols[l], maps.len());
            kept.copy_from_slice(maps);
            direct::forward(maps, g, samples, &direct::tap_major(w, g), &conv.bias, out);
            continue;
        }
        let input: &[f32] = if l == 0 { maps } else { &done[l - 1] };
        let col = set_len(&mut chunk.cols[l], n * k);
        im2col(input, g, samples, col);
        matmul(
            out,
            MatRef::row_major(col, n, k),
            MatRef::transposed(w, k, c_out),
            false,
        )?;
        for pixel in out.chunks_exact_mut(c_out) {
            for (v, b) in pixel.iter_mut().zip(&conv.bias) {
                *v = (*v + b).max(0.0);
            }
        }
    }
    match (geometry.last(), chunk.outs.last()) {
        (Some(g), Some(out)) => {
            let (c, p) = (g.spec.out_channels, g.out_pixels());
            // [sample][P][C] -> [sample][C][P]
            for (f, out) in features
                .chunks_exact_mut(c * p)
                .zip(out.chunks_exact(c * p))
            {
                for (px, pixel) in out.chunks_exact(c).enumerate() {
                    for (ch, &v) in pixel.iter().enumerate() {
                        f[ch * p + px] = v;
                    }
                }
            }
        }
        _ => features.copy_from_slice(maps),
    }
    Ok(())
}

/// Gradients of every conv layer's weights and bias (layer order) from the loss gradient with
/// respect to the features (`d_features`: `batch * features_len`, as [`forward`] returned).
pub fn backward(
    convs: &[Conv2dF32],
    tape: &mut ConvTape,
    d_features: &[f32],
) -> Result<Vec<ConvGradients>, TrainError> {
    if convs.len() != tape.geometry.len()
        || convs
            .iter()
            .zip(&tape.geometry)
            .zip(&tape.weights_hwc)
            .any(|((c, g), w)| {
                c.spec != g.spec
                    || c.weights.len() != w.len()
                    || c.bias.len() != c.spec.out_channels
            })
    {
        return Err(TrainError::Shape(
            "conv backward: the layers differ from the recorded forward pass".into(),
        ));
    }
    let Some(last) = tape.geometry.last() else {
        return Ok(Vec::new());
    };
    let per_sample = last.spec.out_channels * last.out_pixels();
    if d_features.len() != tape.batch * per_sample {
        return Err(TrainError::Shape(format!(
            "conv backward: {} feature gradients for {} samples of {per_sample}",
            d_features.len(),
            tape.batch
        )));
    }
    if tape.chunks.iter().map(|c| c.samples).sum::<usize>() != tape.batch {
        return Err(TrainError::Shape(
            "conv backward: the tape holds no complete forward pass".into(),
        ));
    }
    let mut starts = Vec::with_capacity(tape.chunks.len());
    let mut start = 0;
    for chunk in &tape.chunks {
        starts.push(start);
        start += chunk.samples * per_sample;
    }
    let (geometry, weights) = (&tape.geometry, &tape.weights_hwc);
    let partials: Vec<Vec<ConvGradients>> = tape
        .chunks
        .par_iter_mut()
        .zip(starts)
        .map(|(chunk, start)| {
            let d_features = &d_features[start..start + chunk.samples * per_sample];
            pulp::Arch::new().dispatch(BackwardPass {
                geometry,
                weights_hwc: weights,
                chunk,
                d_features,
            })
        })
        .collect::<Result<_, TrainError>>()?;
    // Fixed summation order (chunk order): the same bits for any thread count.
    let mut total: Vec<ConvGradients> = convs
        .iter()
        .map(|c| ConvGradients {
            weights: vec![0.0; c.weights.len()],
            bias: vec![0.0; c.bias.len()],
        })
        .collect();
    for part in partials {
        for (t, p) in total.iter_mut().zip(part) {
            t.weights
                .iter_mut()
                .zip(&p.weights)
                .for_each(|(a, b)| *a += b);
            t.bias.iter_mut().zip(&p.bias).for_each(|(a, b)| *a += b);
        }
    }
    for (t, g) in total.iter_mut().zip(&tape.geometry) {
        t.weights = from_hwc(&t.weights, g.spec);
    }
    Ok(total)
}

/// Backward pass of one chunk: its share of every layer's parameter gradients (weights still
/// in `[O][ky][kx][I]` order); inlined into each SIMD level's build ([`BackwardPass`]).
#[inline(always)]
fn backward_chunk(pass: BackwardPass<'_>) -> Result<Vec<ConvGradients>, TrainError> {
    let BackwardPass {
        geometry,
        weights_hwc,
        chunk,
        d_features,
    } = pass;
    let samples = chunk.samples;
    let layers = geometry.len();
    let mut grads: Vec<Option<ConvGradients>> = vec![None; layers];
    let Some(g) = geometry.last() else {
        return Ok(Vec::new());
    };
    // Gradient with respect to the current layer's post-ReLU output, `[sample][P][C]`.
    let (c, p) = (g.spec.out_channels, g.out_pixels());
    let d_out = set_len(&mut chunk.d_out, samples * p * c);
    for (d, src) in d_out
        .chunks_exact_mut(c * p)
        .zip(d_features.chunks_exact(c * p))
    {
        for (px, pixel) in d.chunks_exact_mut(c).enumerate() {
            for (ch, v) in pixel.iter_mut().enumerate() {
                *v = src[ch * p + px];
            }
        }
    }
    for l in (0..layers).rev() {
        let (g, w) = (&geometry[l], &weights_hwc[l]);
        let (out, col) = match (chunk.outs.get(l), chunk.cols.get(l)) {
            (Some(o), Some(c)) => (o, c),
            _ => {
                return Err(TrainError::Shape(
                    "conv backward: the tape holds no complete forward pass".into(),
                ))
            }
        };
        let d_out = &mut chunk.d_out;
        // Through the ReLU: the gradient passes where the pre-activation was positive, the
        // same rule as burn's relu backward (a zero output stops it).
        // (A select, not a branch: it vectorizes; the branch cost 10% of the kernel.)
        for (d, &o) in d_out.iter_mut().zip(out) {
            *d = if o > 0.0 { *d } else { 0.0 };
        }
        let c_out = g.spec.out_channels;
        let n = samples * g.out_pixels();
        let k = g.patch_len();
        let mut bias = vec![0.0f32; c_out];
        for pixel in d_out.chunks_exact(c_out) {
            bias.iter_mut().zip(pixel).for_each(|(b, d)| *b += d);
        }
        let mut weights = vec![0.0f32; c_out * k];
        if direct::applies(l, g) {
            direct::weight_gradient(col, g, samples, d_out, &mut weights);
        } else {
            // dW'[C_out, K] = dZ^T[C_out, n] * col[n, K]
            matmul(
                &mut weights,
                MatRef::transposed(d_out, c_out, n),
                MatRef::row_major(col, n, k),
                false,
            )?;
        }
        grads[l] = Some(ConvGradients { weights, bias });
        if l > 0 {
            // dcol[n, K] = dZ[n, C_out] * W'[C_out, K], scattered back onto the input.
            let d_col = set_len(&mut chunk.d_col, n * k);
            matmul(
                d_col,
                MatRef::row_major(d_out, n, c_out),
                MatRef::row_major(w, c_out, k),
                false,
            )?;
            let d_in = set_len(&mut chunk.d_in, samples * g.in_len());
            d_in.fill(0.0);
            col2im(d_col, g, samples, d_in);
            std::mem::swap(&mut chunk.d_out, &mut chunk.d_in);
        }
    }
    Ok(grads.into_iter().flatten().collect())
}

#[cfg(test)]
mod tests;
