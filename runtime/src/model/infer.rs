//! The forward pass over a validated [`Model`]: integer only, into caller-sized buffers.
//!
//! Activations live in two int8 buffers used alternately (ping-pong), in HWC order (channels
//! innermost) so that a conv patch is `kernel^2` contiguous runs of `in_channels` bytes. One
//! int16 row buffer holds the current patch or dense input minus its zero point, which is what
//! the kernel multiplies. After the conv stack the features are re-laid out in CHW order
//! (channel-major, the order of a PyTorch `flatten`) and the quantized state is appended.

use core::mem;

use super::kernel::{linear, Kernel};
use super::load::{Linear, Model, ACTION_LOGITS};
use super::quant::quantize_mm;

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

/// Raw network outputs of one decision, int8 with their quantization.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Outputs {
    /// Five 3-way logits, head order `Dim::ALL`, choice order `Step::ALL`.
    pub action_logits: [i8; ACTION_LOGITS],
    /// Real units per step of `action_logits`.
    pub action_scale: f32,
    /// Zero point of `action_logits`.
    pub action_zero_point: i8,
    /// The value estimate, if the model has a value head, with its scale and zero point.
    pub value: Option<(i8, f32, i8)>,
}

/// Widens `input` minus `zero_point` into `row` (which must be as long).
fn widen(input: &[i8], zero_point: i8, row: &mut [i16]) {
    for (out, &q) in row.iter_mut().zip(input) {
        *out = i16::from(q) - i16::from(zero_point);
    }
}

fn layer(
    kernel: Kernel,
    linear_layer: &Linear<'_>,
    input: &[i8],
    row: &mut [i16],
    output: &mut [i8],
) -> Result<(), InferError> {
    let input = input
        .get(..linear_layer.row_len)
        .ok_or(InferError::Internal)?;
    let row = row
        .get_mut(..linear_layer.row_len)
        .ok_or(InferError::Internal)?;
    let output = output
        .get_mut(..linear_layer.rows)
        .ok_or(InferError::Internal)?;
    widen(input, linear_layer.input_zero_point, row);
    linear(kernel, linear_layer, row, output);
    Ok(())
}

/// Runs the network on a row-major height map in millimetres and a state in millimetres.
pub fn forward<const ACT: usize, const ROW: usize>(
    model: &Model<'_>,
    kernel: Kernel,
    scratch: &mut Scratch<ACT, ROW>,
    height_mm: &[i16],
    state_mm: &[i32],
) -> Result<Outputs, InferError> {
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
    let Scratch { ping, pong, row } = scratch;
    let mut src: &mut [i8] = ping;
    let mut dst: &mut [i8] = pong;

    // Input: one channel, so HWC is plain row-major.
    let height = &model.input.height;
    for (q, &mm) in src.iter_mut().zip(height_mm) {
        *q = quantize_mm(
            i32::from(mm),
            height.multiplier,
            height.shift,
            height.zero_point,
        );
    }

    for conv in &model.convs {
        let channels = conv.in_channels;
        let kernel_side = usize::from(conv.record.kernel);
        let stride = usize::from(conv.record.stride);
        let padding = usize::from(conv.record.padding);
        let zero_point = i16::from(conv.linear.input_zero_point);
        let out_channels = conv.linear.rows;
        let patch = row
            .get_mut(..conv.linear.row_len)
            .ok_or(InferError::Internal)?;
        let mut outputs = dst
            .get_mut(..conv.out_rows * conv.out_cols * out_channels)
            .ok_or(InferError::Internal)?
            .chunks_exact_mut(out_channels);
        for oy in 0..conv.out_rows {
            for ox in 0..conv.out_cols {
                // Gather the patch: kernel rows x kernel cols x channels, minus the zero
                // point; padding cells stand for real 0, i.e. 0 after the subtraction.
                let mut cells = patch.chunks_exact_mut(channels);
                for ky in 0..kernel_side {
                    for kx in 0..kernel_side {
                        let cell = cells.next().ok_or(InferError::Internal)?;
                        let iy = (oy * stride + ky).checked_sub(padding);
                        let ix = (ox * stride + kx).checked_sub(padding);
                        match (iy, ix) {
                            (Some(iy), Some(ix)) if iy < conv.in_rows && ix < conv.in_cols => {
                                let start = (iy * conv.in_cols + ix) * channels;
                                let pixel = src
                                    .get(start..start + channels)
                                    .ok_or(InferError::Internal)?;
                                for (out, &q) in cell.iter_mut().zip(pixel) {
                                    *out = i16::from(q) - zero_point;
                                }
                            }
                            _ => cell.fill(0),
                        }
                    }
                }
                let out = outputs.next().ok_or(InferError::Internal)?;
                linear(kernel, &conv.linear, patch, out);
            }
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
    for ((slot, &mm), quant) in flat
        .get_mut(features..)
        .ok_or(InferError::Internal)?
        .iter_mut()
        .zip(state_mm)
        .zip(&model.state)
    {
        *slot = quantize_mm(mm, quant.multiplier, quant.shift, quant.zero_point);
    }
    mem::swap(&mut src, &mut dst);

    for dense in &model.hidden {
        layer(kernel, &dense.linear, src, row, dst)?;
        mem::swap(&mut src, &mut dst);
    }

    let mut action_logits = [0i8; ACTION_LOGITS];
    layer(
        kernel,
        &model.action_head.linear,
        src,
        row,
        &mut action_logits,
    )?;
    let value = match &model.value_head {
        Some(head) => {
            let mut value = [0i8; 1];
            layer(kernel, &head.linear, src, row, &mut value)?;
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
        action_zero_point: model.action_head.record.output.zero_point,
        value,
    })
}
