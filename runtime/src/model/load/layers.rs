//! The validated layers inference reads: tensors borrowed from the file, shapes checked.

use crate::model::format::{ConvRecord, DenseRecord};

/// The arithmetic shared by conv and dense layers once the input row is laid out: `rows` dot
/// products of length `row_len`, plus bias, requantized per row to
/// `clamp(output_zero_point + rescale(acc), output_low, output_high)`.
///
/// The bounds are stored rather than derived from `relu` so that one kernel serves int8
/// activations (`[-128 or the zero point under ReLU, 127]`) and the action head's int16 logits
/// (`[-32768, 32767]`, zero point 0): only the store differs between the two.
#[derive(Clone, Copy, Debug)]
pub struct Linear<'a> {
    /// `rows * row_len` int8 weights (stored as bytes), row-major.
    pub weights: &'a [u8],
    /// `rows` little-endian i32.
    pub bias: &'a [u8],
    /// `rows` little-endian i32.
    pub multipliers: &'a [u8],
    /// `rows` i8 (stored as bytes).
    pub shifts: &'a [u8],
    /// Outputs.
    pub rows: usize,
    /// Inputs per output.
    pub row_len: usize,
    /// Zero point subtracted from every input.
    pub input_zero_point: i8,
    /// Zero point of the outputs.
    pub output_zero_point: i8,
    /// Whether ReLU is fused (already part of `output_low`; kept for descriptions).
    pub relu: bool,
    /// Smallest output value.
    pub output_low: i16,
    /// Largest output value.
    pub output_high: i16,
}

impl Linear<'_> {
    /// The int8 output bounds of a layer: `[zero_point, 127]` under ReLU (real values below 0
    /// become 0), else `[-128, 127]`.
    pub const fn int8_bounds(zero_point: i8, relu: bool) -> (i16, i16) {
        (if relu { zero_point as i16 } else { -128 }, 127)
    }
}

/// A validated conv layer with its input and output geometry.
#[derive(Clone, Copy, Debug)]
pub struct ConvLayer<'a> {
    /// The record as stored.
    pub record: ConvRecord<'a>,
    /// The arithmetic (rows = output channels, row length = kernel^2 * input channels).
    pub linear: Linear<'a>,
    /// Input height.
    pub in_rows: usize,
    /// Input width.
    pub in_cols: usize,
    /// Input channels.
    pub in_channels: usize,
    /// Output height.
    pub out_rows: usize,
    /// Output width.
    pub out_cols: usize,
}

/// A validated dense layer.
#[derive(Clone, Copy, Debug)]
pub struct DenseLayer<'a> {
    /// The record as stored.
    pub record: DenseRecord<'a>,
    /// The arithmetic.
    pub linear: Linear<'a>,
}

/// What a model needs from the inference buffers.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Requirements {
    /// Largest activation tensor (elements, int8): the input map, any conv output, the
    /// flattened-and-concatenated vector, any hidden layer output.
    pub activation_elements: usize,
    /// Longest widened input row (i16 elements): any conv patch or dense input.
    pub row_elements: usize,
}
