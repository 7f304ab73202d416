//! The forward pass over a validated [`Model`]: integer only, into caller-sized buffers.
//!
//! Activations live in two int8 buffers used alternately (ping-pong), in HWC order (channels
//! innermost) so that a conv patch is `kernel^2` contiguous runs of `in_channels` bytes. One
//! int16 row buffer holds the current patch or dense input minus its zero point, which is what
//! the kernel multiplies. After the conv stack the features are re-laid out in CHW order
//! (channel-major, the order of a PyTorch `flatten`) and the quantized state is appended.

use core::mem;

use super::format::STATE_FRACTION_BITS;
use super::kernel::{
    le_i32, linear_batch, padded_row_len, prepare_row, quantize_inputs, Kernel, Output,
};
use super::load::{ConvLayer, Linear, Model, ACTION_LOGITS, MAX_STATE_FEATURES};
use super::quant::{quantize_mm, quantize_mm16};

/// Why a decision could not be computed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum InferError {
    /// The height map's size differs from the model's input.
    HeightMapShape {
        /// Cells the model expects (rows x cols).
        expected: usize,
        /// Cells given.
        found: usize,
    },
    /// The state vector's length differs from the model's.
    StateLength {
        /// Features the model expects.
        expected: usize,
        /// Features given.
        found: usize,
    },
    /// A buffer was too small. Cannot happen for a model accepted by `Policy::from_bytes` (which
    /// checks the capacities); reported instead of panicking.
    Internal,
    /// Caller-owned buffers ([`super::Policy::evaluate_in`]) are smaller than the model needs.
    Buffers {
        /// int8 elements each activation buffer needs.
        activation_elements: usize,
        /// int16 elements the row buffer needs.
        row_elements: usize,
    },
}

impl core::fmt::Display for InferError {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            InferError::HeightMapShape { expected, found } => {
                write!(
                    f,
                    "height map has {found} cells, the model takes {expected}"
                )
            }
            InferError::StateLength { expected, found } => {
                write!(f, "state has {found} features, the model takes {expected}")
            }
            InferError::Internal => write!(f, "inference buffer too small (runtime bug)"),
            InferError::Buffers {
                activation_elements,
                row_elements,
            } => write!(
                f,
                "buffers too small: the model needs {activation_elements} int8 per activation \
                 buffer and {row_elements} int16 in the row"
            ),
        }
    }
}

/// Working memory of one forward pass: two activation buffers of `ACT` int8 and one row of
/// `ROW` int16. Reusable across decisions; its size is the inference RAM besides the stack
/// frames.
#[derive(Clone, Debug)]
pub struct Scratch<const ACT: usize, const ROW: usize> {
    ping: [i8; ACT],
    pong: [i8; ACT],
    row: [i16; ROW],
}

impl<const ACT: usize, const ROW: usize> Scratch<ACT, ROW> {
    /// Zeroed buffers (a `const fn`, so a firmware can place one in a `static`).
    pub const fn new() -> Self {
        Scratch {
            ping: [0; ACT],
            pong: [0; ACT],
            row: [0; ROW],
        }
    }
}

impl<const ACT: usize, const ROW: usize> Default for Scratch<ACT, ROW> {
    fn default() -> Self {
        Self::new()
    }
}

/// Raw network outputs of one decision with their quantization.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outputs {
    /// Five 3-way logits, head order `Dim::ALL`, choice order `Step::ALL`: int16, zero point 0
    /// (real logit = `action_scale * q`), so that comparing them is comparing real logits.
    /// From a version 1 file they are the int8 logits minus their zero point.
    pub action_logits: [i16; ACTION_LOGITS],
    /// Real units per step of `action_logits`.
    pub action_scale: f32,
    /// The value estimate, if the model has a value head, with its scale and zero point.
    pub value: Option<(i8, f32, i8)>,
}

/// Widens `input` minus `zero_point` into `row` (which must be as long).
#[inline(always)]
fn widen(input: &[i8], zero_point: i8, row: &mut [i16]) {
    for (out, &q) in row.iter_mut().zip(input) {
        *out = i16::from(q) - i16::from(zero_point);
    }
}

/// A dense layer's output rows, and the input row buffer cut to what the kernel reads: the
/// padded row when the buffer has room, so that it reads the last, partial block directly
/// instead of copying it. The first `row_len` values are the caller's to fill.
#[inline(always)]
fn layer_buffers<'r, 'o, T>(
    linear_layer: &Linear<'_>,
    row: &'r mut [i16],
    output: &'o mut [T],
) -> Result<(&'o mut [T], &'r mut [i16]), InferError> {
    let output = output
        .get_mut(..linear_layer.rows)
        .ok_or(InferError::Internal)?;
    let padded = padded_row_len(linear_layer.row_len).min(row.len());
    let row = row.get_mut(..padded).ok_or(InferError::Internal)?;
    Ok((output, row))
}

fn layer<T: Output>(
    kernel: Kernel,
    linear_layer: &Linear<'_>,
    input: &[i8],
    row: &mut [i16],
    output: &mut [T],
) -> Result<(), InferError> {
    let row_len = linear_layer.row_len;
    let input = input.get(..row_len).ok_or(InferError::Internal)?;
    let (output, row) = layer_buffers(linear_layer, row, output)?;
    let values = row.get_mut(..row_len).ok_or(InferError::Internal)?;
    widen(input, linear_layer.input_zero_point, values);
    prepare_row(kernel, values);
    linear_batch(kernel, linear_layer, row, row_len, output);
    Ok(())
}

/// Output rows per kernel call of [`layer_with_state`]: its adjusted biases live in a stack
/// buffer of this many entries (512 bytes), whatever the layer's size. The default network's
/// 128 rows take one call (each call has a fixed set-up cost in the SIMD kernel).
const STATE_ROWS_PER_CALL: usize = 128;

/// `2^(STATE_FRACTION_BITS - 1)`: rounds the state columns' sum to nearest, halves up.
const STATE_HALF: i32 = 1 << (STATE_FRACTION_BITS - 1);

/// The layer that reads the flattened features and an int16 state (weights format version 2).
///
/// The state columns' int8 weights are folded exactly as in version 1, for inputs in int8
/// steps; the int16 state is that value times 256 (plus the fraction the int8 grid dropped).
/// So the columns' partial sum `sum_j w[o][j] * (u_j - 256 * zp_in)` is divided by 256,
/// rounded, and added to the bias of row `o`; the kernel itself sees 0 in the state columns.
/// That keeps the kernels (and their bit-exactness) untouched: the extra work is a few
/// multiply-adds per output row, the same code for every kernel. Nothing overflows:
/// `|u - 256 zp| <= 65,535`, `|w| <= 128`, at most 16 features, so the sum is below 2^27, and
/// after the division each column adds at most 32,768, which the loader's accumulator bound
/// allows for (see `load::MAX_DOT_LEN`).
fn layer_with_state<T: Output>(
    kernel: Kernel,
    linear_layer: &Linear<'_>,
    input: &[i8],
    state: &[i16],
    row: &mut [i16],
    output: &mut [T],
) -> Result<(), InferError> {
    let output = output
        .get_mut(..linear_layer.rows)
        .ok_or(InferError::Internal)?;
    let (row, wide) = state_input(kernel, linear_layer, input, state, row)?;
    let wide = wide.get(..state.len()).ok_or(InferError::Internal)?;
    let mut bias = [0u8; 4 * STATE_ROWS_PER_CALL];
    for (chunk, out) in output.chunks_mut(STATE_ROWS_PER_CALL).enumerate() {
        let rows = (chunk * STATE_ROWS_PER_CALL, out.len());
        let part = fold_state(linear_layer, wide, rows, &mut bias)?;
        linear_batch(kernel, &part, row, linear_layer.row_len, out);
    }
    Ok(())
}

/// [`layer_with_state`]'s input row (the features widened, 0 in the state columns, in the
/// kernel's order), cut as [`layer_buffers`] cuts it, and the state in the layer's input
/// domain, 256 times finer: `u - 256 * zp_in`. Apart from the output type, so that on a
/// controller one copy serves the layers of both types.
#[cfg_attr(target_arch = "arm", inline(never))]
fn state_input<'r>(
    kernel: Kernel,
    linear_layer: &Linear<'_>,
    input: &[i8],
    state: &[i16],
    row: &'r mut [i16],
) -> Result<(&'r mut [i16], [i32; MAX_STATE_FEATURES]), InferError> {
    let row_len = linear_layer.row_len;
    let features = row_len
        .checked_sub(state.len())
        .ok_or(InferError::Internal)?;
    let input = input.get(..features).ok_or(InferError::Internal)?;
    let padded = padded_row_len(row_len).min(row.len());
    let row = row.get_mut(..padded).ok_or(InferError::Internal)?;
    let values = row.get_mut(..row_len).ok_or(InferError::Internal)?;
    let (feature_values, state_values) = values
        .split_at_mut_checked(features)
        .ok_or(InferError::Internal)?;
    widen(input, linear_layer.input_zero_point, feature_values);
    state_values.fill(0);
    prepare_row(kernel, values);
    let zero_point = i32::from(linear_layer.input_zero_point) << STATE_FRACTION_BITS;
    let mut wide = [0i32; MAX_STATE_FEATURES];
    for (v, &u) in wide.iter_mut().zip(state) {
        *v = i32::from(u) - zero_point;
    }
    Ok((row, wide))
}

/// Rows `first..first + count` of `linear_layer` with the state columns' partial sums
/// (`wide`: [`state_input`]) folded into their biases, which it writes to `bias`.
#[cfg_attr(target_arch = "arm", inline(never))]
fn fold_state<'b>(
    linear_layer: &Linear<'b>,
    wide: &[i32],
    (first, count): (usize, usize),
    bias: &'b mut [u8; 4 * STATE_ROWS_PER_CALL],
) -> Result<Linear<'b>, InferError> {
    let row_len = linear_layer.row_len;
    let features = row_len
        .checked_sub(wide.len())
        .ok_or(InferError::Internal)?;
    let weights = linear_layer
        .weights
        .get(first * row_len..(first + count) * row_len)
        .ok_or(InferError::Internal)?;
    let biases = linear_layer
        .bias
        .get(4 * first..4 * (first + count))
        .ok_or(InferError::Internal)?;
    // Lock-step iterators over the rows: no index arithmetic or bounds checks per row.
    for ((slot, weights), stored) in bias
        .chunks_exact_mut(4)
        .zip(weights.chunks_exact(row_len))
        .zip(biases.chunks_exact(4))
    {
        let mut sum = 0i32;
        if let Some(columns) = weights.get(features..) {
            for (&w, &v) in columns.iter().zip(wide) {
                sum += i32::from(w as i8) * v;
            }
        }
        let adjusted = le_i32(stored) + ((sum + STATE_HALF) >> STATE_FRACTION_BITS);
        slot.copy_from_slice(&adjusted.to_le_bytes());
    }
    Ok(Linear {
        weights,
        bias: bias.get(..4 * count).ok_or(InferError::Internal)?,
        multipliers: linear_layer
            .multipliers
            .get(4 * first..4 * (first + count))
            .ok_or(InferError::Internal)?,
        shifts: linear_layer
            .shifts
            .get(first..first + count)
            .ok_or(InferError::Internal)?,
        rows: count,
        ..*linear_layer
    })
}

/// A layer that reads the flattened vector: with the int16 state of a version 2 file, or
/// ([`layer`]) with the int8 state slots already in the vector.
fn first_layer<T: Output>(
    kernel: Kernel,
    linear_layer: &Linear<'_>,
    input: &[i8],
    state: Option<&[i16]>,
    row: &mut [i16],
    output: &mut [T],
) -> Result<(), InferError> {
    match state {
        Some(state) => layer_with_state(kernel, linear_layer, input, state, row, output),
        None => layer(kernel, linear_layer, input, row, output),
    }
}

/// Gathers the patches of output pixels `first..` into `patches`, one every `stride` elements
/// (as many as fit), with the kernel's instruction set: the same code, compiled for AVX2 by
/// [`super::simd_x86::gather_avx2`], widens 16 inputs per instruction.
pub(super) fn gather_patches(
    kernel: Kernel,
    conv: &ConvLayer<'_>,
    src: &[i8],
    first: usize,
    patches: &mut [i16],
    stride: usize,
) {
    match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => super::simd_x86::gather_avx2(conv, src, first, patches, stride),
        _ => gather_pixels(conv, src, first, patches, stride),
    }
}

/// [`gather_patches`]'s portable body.
#[inline(always)]
pub(super) fn gather_pixels(
    conv: &ConvLayer<'_>,
    src: &[i8],
    first: usize,
    patches: &mut [i16],
    stride: usize,
) {
    let cols = conv.out_cols.max(1);
    for (offset, patch) in patches.chunks_exact_mut(stride.max(1)).enumerate() {
        let pixel = first + offset;
        gather(conv, src, pixel / cols, pixel % cols, patch);
    }
}

/// Gathers the patch of output pixel (`oy`, `ox`) into `patch` (at least `row_len` long):
/// `kernel` runs of `kernel x channels` inputs minus the zero point, one per kernel row, each a
/// contiguous run of the HWC input clipped to the map; padding cells stand for real 0, i.e. 0
/// after the subtraction.
#[inline(always)]
fn gather(conv: &ConvLayer<'_>, src: &[i8], oy: usize, ox: usize, patch: &mut [i16]) {
    let channels = conv.in_channels;
    let side = usize::from(conv.record.kernel);
    let stride = usize::from(conv.record.stride);
    let padding = usize::from(conv.record.padding);
    let zero_point = conv.linear.input_zero_point;
    let run = side * channels;
    let (y0, x0) = (oy * stride, ox * stride);
    if y0 >= padding
        && x0 >= padding
        && y0 + side <= conv.in_rows + padding
        && x0 + side <= conv.in_cols + padding
    {
        // Interior pixel (most of them): every run is whole, no clipping arithmetic.
        let pitch = conv.in_cols * channels;
        let base = ((y0 - padding) * conv.in_cols + (x0 - padding)) * channels;
        for (ky, segment) in patch.chunks_exact_mut(run).take(side).enumerate() {
            let start = base + ky * pitch;
            if let Some(pixels) = src.get(start..start + run) {
                // A first layer's 3-cell runs (one channel): straight-line code instead of a
                // vectorized loop whose set-up costs more than the 3 elements.
                match (
                    <&[i8; 3]>::try_from(pixels),
                    <&mut [i16; 3]>::try_from(&mut *segment),
                ) {
                    (Ok(pixels), Ok(segment)) => widen(pixels, zero_point, segment),
                    _ => widen(pixels, zero_point, segment),
                }
            }
        }
        return;
    }
    // Kernel columns inside the map: ix = ox * stride + kx - padding in [0, in_cols).
    let first = padding.saturating_sub(x0).min(side);
    let last = (conv.in_cols + padding)
        .saturating_sub(x0)
        .clamp(first, side);
    for (ky, segment) in patch.chunks_exact_mut(run).take(side).enumerate() {
        let iy = (y0 + ky).checked_sub(padding);
        let source = iy.filter(|&iy| iy < conv.in_rows).and_then(|iy| {
            // First input cell of the clipped run: ix = x0 + first - padding >= 0.
            let ix = (x0 + first).checked_sub(padding)?;
            let start = (iy * conv.in_cols + ix) * channels;
            src.get(start..start + (last - first) * channels)
        });
        let split = source.and_then(|pixels| {
            let (before, rest) = segment.split_at_mut_checked(first * channels)?;
            let (inside, after) = rest.split_at_mut_checked(pixels.len())?;
            Some((pixels, before, inside, after))
        });
        match split {
            Some((pixels, before, inside, after)) => {
                // Only border pixels have cells outside the map; a `fill` of nothing would
                // still cost a `memset` call per run.
                if !before.is_empty() {
                    before.fill(0);
                }
                widen(pixels, zero_point, inside);
                if !after.is_empty() {
                    after.fill(0);
                }
            }
            None => segment.fill(0),
        }
    }
}

/// Runs the network on a row-major height map in millimetres and a state in millimetres.
pub fn forward<const ACT: usize, const ROW: usize>(
    model: &Model<'_>,
    kernel: Kernel,
    scratch: &mut Scratch<ACT, ROW>,
    height_mm: &[i16],
    state_mm: &[i32],
) -> Result<Outputs, InferError> {
    let Scratch { ping, pong, row } = scratch;
    forward_in(model, kernel, ping, pong, row, height_mm, state_mm)
}

/// [`forward`] in any buffers: two activation buffers and a row, each at least as large as the
/// model's [`super::Requirements`] (checked: [`InferError::Buffers`]). For a controller that
/// lends the same RAM to something else between decisions.
pub fn forward_in(
    model: &Model<'_>,
    kernel: Kernel,
    ping: &mut [i8],
    pong: &mut [i8],
    row: &mut [i16],
    height_mm: &[i16],
    state_mm: &[i32],
) -> Result<Outputs, InferError> {
    let needs = model.requirements;
    if ping.len() < needs.activation_elements
        || pong.len() < needs.activation_elements
        || row.len() < needs.row_elements
    {
        return Err(InferError::Buffers {
            activation_elements: needs.activation_elements,
            row_elements: needs.row_elements,
        });
    }
    let rows = usize::from(model.input.rows);
    let cols = usize::from(model.input.cols);
    if height_mm.len() != rows * cols {
        return Err(InferError::HeightMapShape {
            expected: rows * cols,
            found: height_mm.len(),
        });
    }
    if state_mm.len() != model.state.len() {
        return Err(InferError::StateLength {
            expected: model.state.len(),
            found: state_mm.len(),
        });
    }
    let mut src: &mut [i8] = ping;
    let mut dst: &mut [i8] = pong;

    // Input: one channel, so HWC is plain row-major.
    let cells = src.get_mut(..rows * cols).ok_or(InferError::Internal)?;
    quantize_inputs(kernel, &model.input.height, height_mm, cells);

    for conv in &model.convs {
        #[cfg(target_arch = "x86_64")]
        if kernel == Kernel::Avx2 && super::simd_x86::conv3x3_one_channel_avx2(conv, src, dst, row)
        {
            mem::swap(&mut src, &mut dst);
            continue;
        }
        let out_channels = conv.linear.rows;
        let row_len = conv.linear.row_len;
        // Patches of several output pixels go to the kernel at once, each padded to a whole
        // number of SIMD blocks when the row buffer has room for it.
        let stride = if padded_row_len(row_len) <= row.len() {
            padded_row_len(row_len)
        } else {
            row_len
        };
        // An even count when possible: the SIMD kernel runs pixels in pairs, and an odd one
        // out per batch would take its slower single-pixel path.
        let fit = row.len() / stride;
        let batch = if fit >= 2 { fit & !1 } else { 1 };
        let pixels = conv.out_rows * conv.out_cols;
        let outputs = dst
            .get_mut(..pixels * out_channels)
            .ok_or(InferError::Internal)?;
        // The DSP kernel runs the layer's batches itself: its gather widens multi-channel
        // runs straight into its order, and the layer's requantization table is built once.
        // Pixels it does not take (none in the shipped network) go the portable way.
        #[cfg(all(target_arch = "arm", target_feature = "dsp"))]
        let mut first = if kernel == Kernel::Dsp {
            super::dsp_m4::conv_dsp(conv, &mut *src, &mut *outputs, row, stride, batch)
        } else {
            0
        };
        #[cfg(not(all(target_arch = "arm", target_feature = "dsp")))]
        let mut first = 0;
        let rest = outputs
            .get_mut(first * out_channels..)
            .ok_or(InferError::Internal)?;
        for out in rest.chunks_mut(batch * out_channels) {
            let count = out.len() / out_channels;
            let patches = row.get_mut(..count * stride).ok_or(InferError::Internal)?;
            gather_patches(kernel, conv, src, first, patches, stride);
            if kernel == Kernel::Dsp {
                for patch in patches.chunks_exact_mut(stride) {
                    prepare_row(kernel, patch.get_mut(..row_len).unwrap_or_default());
                }
            }
            linear_batch(kernel, &conv.linear, patches, stride, out);
            first += count;
        }
        mem::swap(&mut src, &mut dst);
    }

    // Flatten HWC -> CHW, then append the state (already in the features' domain once the
    // trainer's folding is accounted for; see `load::Model::parse`).
    let (h, w, c) = (
        model.feature_rows,
        model.feature_cols,
        model.feature_channels,
    );
    let features = h * w * c;
    let flat = dst
        .get_mut(..features + state_mm.len())
        .ok_or(InferError::Internal)?;
    let hwc = src.get(..features).ok_or(InferError::Internal)?;
    for (pixel, values) in hwc.chunks_exact(c).enumerate() {
        for (channel, &q) in values.iter().enumerate() {
            let slot = flat
                .get_mut(channel * h * w + pixel)
                .ok_or(InferError::Internal)?;
            *slot = q;
        }
    }
    // Version 1: int8 state slots after the features. Version 2: the int16 state goes to the
    // layer that reads the vector (its slots in `flat` stay unused).
    let mut state16 = [0i16; MAX_STATE_FEATURES];
    let wide_state = model.state_bits() == 16;
    let slots = flat.get_mut(features..).ok_or(InferError::Internal)?;
    for (((slot, wide), &mm), quant) in slots
        .iter_mut()
        .zip(state16.iter_mut())
        .zip(state_mm)
        .zip(&model.state)
    {
        if wide_state {
            *wide = quantize_mm16(mm, quant.multiplier, quant.shift, quant.zero_point);
        } else {
            *slot = quantize_mm(mm, quant.multiplier, quant.shift, quant.zero_point);
        }
    }
    let mut state = if wide_state {
        Some(state16.get(..state_mm.len()).ok_or(InferError::Internal)?)
    } else {
        None
    };
    mem::swap(&mut src, &mut dst);

    for dense in &model.hidden {
        first_layer(kernel, &dense.linear, src, state.take(), row, dst)?;
        mem::swap(&mut src, &mut dst);
    }

    // int16 logits (the loader set the head's bounds: see `load::Model::parse`). Without
    // hidden layers the heads read the flattened vector, so `state` is still there for them.
    let mut action_logits = [0i16; ACTION_LOGITS];
    first_layer(
        kernel,
        &model.action_head.linear,
        src,
        state,
        row,
        &mut action_logits,
    )?;
    let value = match &model.value_head {
        Some(head) => {
            let mut value = [0i8; 1];
            first_layer(kernel, &head.linear, src, state, row, &mut value)?;
            let [value] = value;
            Some((
                value,
                head.record.output.scale,
                head.record.output.zero_point,
            ))
        }
        None => None,
    };
    Ok(Outputs {
        action_logits,
        action_scale: model.action_head.record.output.scale,
        value,
    })
}
