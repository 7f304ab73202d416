//! Reading and validating a weights file, once, before any inference.
//!
//! [`Model::parse`] checks the envelope (magic, version, checksum), decodes the layer records
//! borrowing every tensor from the input bytes, and checks every shape, length and parameter
//! range that inference relies on. After it succeeds, inference only needs the capacity check of
//! [`Requirements`] against its buffers; it never meets a length it did not expect.

use core::fmt;

use heapless::Vec;
use serde::Deserialize;

use super::crc32::crc32;
use super::format::{
    ActQuantRecord, ConvRecord, DenseRecord, InputQuantRecord, InputRecord, FORMAT_VERSION, MAGIC,
    OLDEST_FORMAT_VERSION,
};
use super::quant::{MAX_SHIFT, MIN_SHIFT};
use crate::action::{CHOICES, DIMS};

/// Most conv layers a model may have (sizes the layer table, not the activations).
pub const MAX_CONV_LAYERS: usize = 8;
/// Most hidden dense layers a model may have.
pub const MAX_DENSE_LAYERS: usize = 8;
/// Most state features a model may take.
pub const MAX_STATE_FEATURES: usize = 16;
/// Longest dot product (inputs per output) the format allows: with |x - zp| <= 255 and
/// |w| <= 128 the sum stays below 2^30, and with |bias| <= 2^30 the accumulator fits an i32.
/// A version 2 file's int16 state columns add at most 32,768 each (their sum divided by 256,
/// see `infer`), 128 more than an int8 column's `255 * 128`: with at most 16 of them the bound
/// still holds (`32,768 * 255 * 128 + 16 * 128 + 2^30 < 2^31`).
pub const MAX_DOT_LEN: usize = 32_768;
/// Largest bias magnitude the format allows (see [`MAX_DOT_LEN`]).
pub const MAX_BIAS_ABS: i32 = 1 << 30;
/// Outputs of the action head: one 3-way head per action dimension, in `Dim::ALL` order.
pub const ACTION_LOGITS: usize = DIMS * CHOICES;

/// A layer, for error messages.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LayerRef {
    /// The height-map / state input.
    Input,
    /// Conv layer number `n` (from 0).
    Conv(u8),
    /// Hidden dense layer number `n` (from 0).
    Dense(u8),
    /// The action head.
    ActionHead,
    /// The value head.
    ValueHead,
}

/// A compile-time capacity that a model can exceed.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Capacity {
    /// [`MAX_CONV_LAYERS`].
    ConvLayers,
    /// [`MAX_DENSE_LAYERS`].
    DenseLayers,
    /// [`MAX_STATE_FEATURES`].
    StateFeatures,
    /// [`MAX_DOT_LEN`], the format's own bound on inputs per output.
    DotLengthLimit,
    /// Elements of one activation buffer (the policy's `ACT` parameter).
    ActivationElements,
    /// Length of the widened input row (the policy's `ROW` parameter).
    RowElements,
}

/// Why a weights file was refused. Every check happens at load time; none of these can come out
/// of inference.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LoadError {
    /// The bytes end before the file does.
    Truncated,
    /// The first four bytes are not [`MAGIC`].
    BadMagic {
        /// What the file starts with (zero-padded if shorter).
        found: [u8; 4],
    },
    /// A format version this runtime does not read (it reads [`OLDEST_FORMAT_VERSION`] to
    /// [`FORMAT_VERSION`]).
    UnsupportedVersion {
        /// Version in the file.
        found: u16,
        /// Newest version this runtime reads.
        supported: u16,
    },
    /// The stored CRC-32 does not match the bytes.
    BadChecksum {
        /// CRC in the file.
        stored: u32,
        /// CRC of the bytes.
        computed: u32,
    },
    /// Bytes follow the checksum.
    TrailingBytes {
        /// How many.
        count: usize,
    },
    /// A part could not be decoded although the checksum matched (a writer bug).
    Corrupt {
        /// Which part.
        part: &'static str,
    },
    /// A tensor length or a layer size disagrees with the architecture.
    ShapeMismatch {
        /// The layer.
        layer: LayerRef,
        /// Which quantity.
        what: &'static str,
        /// The size the architecture implies.
        expected: usize,
        /// The size in the file.
        found: usize,
    },
    /// A parameter outside the range the arithmetic is defined for (zero stride, shift out of
    /// range, negative multiplier, bias too large, ...).
    InvalidParameter {
        /// The layer.
        layer: LayerRef,
        /// Which parameter.
        what: &'static str,
    },
    /// The model needs more than a compile-time capacity.
    ExceedsCapacity {
        /// Which capacity.
        what: Capacity,
        /// What the model needs.
        required: usize,
        /// What was compiled in.
        capacity: usize,
    },
}

impl fmt::Display for LoadError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LoadError::Truncated => write!(f, "weights file is truncated"),
            LoadError::BadMagic { found } => {
                write!(
                    f,
                    "not a weights file (magic {found:?}, expected {MAGIC:?})"
                )
            }
            LoadError::UnsupportedVersion { found, supported } => write!(
                f,
                "weights format version {found} is not supported (this runtime reads \
                 {OLDEST_FORMAT_VERSION} to {supported})"
            ),
            LoadError::BadChecksum { stored, computed } => write!(
                f,
                "checksum mismatch: stored {stored:#010x}, computed {computed:#010x}"
            ),
            LoadError::TrailingBytes { count } => {
                write!(f, "{count} unexpected bytes after the checksum")
            }
            LoadError::Corrupt { part } => write!(f, "cannot decode {part}"),
            LoadError::ShapeMismatch {
                layer,
                what,
                expected,
                found,
            } => write!(
                f,
                "{layer:?}: {what} is {found}, the architecture implies {expected}"
            ),
            LoadError::InvalidParameter { layer, what } => {
                write!(f, "{layer:?}: invalid {what}")
            }
            LoadError::ExceedsCapacity {
                what,
                required,
                capacity,
            } => write!(
                f,
                "model needs {required} {what:?} but the runtime was built for {capacity}"
            ),
        }
    }
}

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

/// A weights file, checked and decoded; tensors borrow from the file bytes.
#[derive(Clone, Debug)]
pub struct Model<'a> {
    /// Format version of the file (1: int8 state and action logits; 2: int16 state and
    /// logits, see [`Model::state_bits`] and [`Model::logit_bits`]).
    pub version: u16,
    /// Height-map shape and quantization.
    pub input: InputRecord,
    /// Per-state-feature quantization, in observation order.
    pub state: Vec<InputQuantRecord, MAX_STATE_FEATURES>,
    /// The conv stack.
    pub convs: Vec<ConvLayer<'a>, MAX_CONV_LAYERS>,
    /// The hidden dense stack.
    pub hidden: Vec<DenseLayer<'a>, MAX_DENSE_LAYERS>,
    /// The action head ([`ACTION_LOGITS`] int16 logits with zero point 0 and scale
    /// `action_head.record.output.scale`, whatever the version: see [`Model::parse`]).
    pub action_head: DenseLayer<'a>,
    /// The value head (1 output), if stored.
    pub value_head: Option<DenseLayer<'a>>,
    /// Channels of the last conv output (1 without convs).
    pub feature_channels: usize,
    /// Height of the last conv output.
    pub feature_rows: usize,
    /// Width of the last conv output.
    pub feature_cols: usize,
    /// Quantization shared by the flattened features and the quantized state.
    pub features_quant: ActQuantRecord,
    /// Buffer sizes this model needs.
    pub requirements: Requirements,
}

/// Decodes one postcard value from the front of `bytes`.
fn take<'a, T: Deserialize<'a>>(
    bytes: &'a [u8],
    truncated: LoadError,
    part: &'static str,
) -> Result<(T, &'a [u8]), LoadError> {
    postcard::take_from_bytes::<T>(bytes).map_err(|error| match error {
        postcard::Error::DeserializeUnexpectedEnd => truncated,
        _ => LoadError::Corrupt { part },
    })
}

/// Decodes a sequence length and checks it against a capacity before anything is stored.
fn take_len<'a>(
    bytes: &'a [u8],
    part: &'static str,
    what: Capacity,
    capacity: usize,
) -> Result<(usize, &'a [u8]), LoadError> {
    let (len, rest) = take::<u32>(bytes, LoadError::Corrupt { part }, part)?;
    let len = usize::try_from(len).map_err(|_| LoadError::Corrupt { part })?;
    if len > capacity {
        return Err(LoadError::ExceedsCapacity {
            what,
            required: len,
            capacity,
        });
    }
    Ok((len, rest))
}

/// Splits a file into its version and checked payload: magic, then version, then structure,
/// then checksum, so that each failure gets the most specific error.
pub fn open_envelope(bytes: &[u8]) -> Result<(u16, &[u8]), LoadError> {
    let mut found = [0u8; 4];
    for (slot, byte) in found.iter_mut().zip(bytes) {
        *slot = *byte;
    }
    if bytes.len() < MAGIC.len() {
        return if bytes == MAGIC.get(..bytes.len()).unwrap_or(&[]) {
            Err(LoadError::Truncated)
        } else {
            Err(LoadError::BadMagic { found })
        };
    }
    if found != MAGIC {
        return Err(LoadError::BadMagic { found });
    }
    let after_magic = bytes.get(MAGIC.len()..).ok_or(LoadError::Truncated)?;
    let (version, rest) = take::<u16>(after_magic, LoadError::Truncated, "version")?;
    if !(OLDEST_FORMAT_VERSION..=FORMAT_VERSION).contains(&version) {
        return Err(LoadError::UnsupportedVersion {
            found: version,
            supported: FORMAT_VERSION,
        });
    }
    let (payload, rest) = take::<&[u8]>(rest, LoadError::Truncated, "payload")?;
    let (stored, rest) = take::<[u8; 4]>(rest, LoadError::Truncated, "checksum")?;
    if !rest.is_empty() {
        return Err(LoadError::TrailingBytes { count: rest.len() });
    }
    // Everything but the last four bytes is covered by the checksum.
    let covered = bytes
        .get(..bytes.len().saturating_sub(4))
        .ok_or(LoadError::Truncated)?;
    let stored = u32::from_le_bytes(stored);
    let computed = crc32(covered);
    if stored != computed {
        return Err(LoadError::BadChecksum { stored, computed });
    }
    Ok((version, payload))
}

/// Little-endian i32 number `index` of a byte tensor (0 past the end: lengths were checked).
#[inline(always)]
pub fn i32_at(bytes: &[u8], index: usize) -> i32 {
    let start = index.saturating_mul(4);
    match bytes.get(start..start.saturating_add(4)) {
        Some(&[a, b, c, d]) => i32::from_le_bytes([a, b, c, d]),
        _ => 0,
    }
}

fn expect_len(
    layer: LayerRef,
    what: &'static str,
    expected: usize,
    found: usize,
) -> Result<(), LoadError> {
    if expected == found {
        Ok(())
    } else {
        Err(LoadError::ShapeMismatch {
            layer,
            what,
            expected,
            found,
        })
    }
}

fn check_input_quant(layer: LayerRef, quant: &InputQuantRecord) -> Result<(), LoadError> {
    if quant.multiplier < 0 {
        return Err(LoadError::InvalidParameter {
            layer,
            what: "input multiplier",
        });
    }
    if !(MIN_SHIFT..=MAX_SHIFT).contains(&quant.shift) {
        return Err(LoadError::InvalidParameter {
            layer,
            what: "input shift",
        });
    }
    Ok(())
}

/// Checks the tensors and requantization parameters shared by conv and dense layers.
#[allow(clippy::too_many_arguments)]
fn check_linear<'a>(
    layer: LayerRef,
    weights: &'a [u8],
    bias: &'a [u8],
    multipliers: &'a [u8],
    shifts: &'a [u8],
    rows: usize,
    row_len: usize,
    input_zero_point: i8,
    output: ActQuantRecord,
    relu: bool,
) -> Result<Linear<'a>, LoadError> {
    if rows == 0 || row_len == 0 {
        return Err(LoadError::InvalidParameter {
            layer,
            what: "empty layer",
        });
    }
    if row_len > MAX_DOT_LEN {
        return Err(LoadError::ExceedsCapacity {
            what: Capacity::DotLengthLimit,
            required: row_len,
            capacity: MAX_DOT_LEN,
        });
    }
    expect_len(
        layer,
        "weights bytes",
        rows.saturating_mul(row_len),
        weights.len(),
    )?;
    expect_len(layer, "bias bytes", rows.saturating_mul(4), bias.len())?;
    expect_len(
        layer,
        "multiplier bytes",
        rows.saturating_mul(4),
        multipliers.len(),
    )?;
    expect_len(layer, "shift bytes", rows, shifts.len())?;
    let (output_low, output_high) = Linear::int8_bounds(output.zero_point, relu);
    for row in 0..rows {
        let b = i32_at(bias, row);
        if b.unsigned_abs() > MAX_BIAS_ABS.unsigned_abs() {
            return Err(LoadError::InvalidParameter {
                layer,
                what: "bias magnitude",
            });
        }
        if i32_at(multipliers, row) < 0 {
            return Err(LoadError::InvalidParameter {
                layer,
                what: "multiplier",
            });
        }
    }
    if shifts
        .iter()
        .any(|&s| !(MIN_SHIFT..=MAX_SHIFT).contains(&(s as i8)))
    {
        return Err(LoadError::InvalidParameter {
            layer,
            what: "shift",
        });
    }
    Ok(Linear {
        weights,
        bias,
        multipliers,
        shifts,
        rows,
        row_len,
        input_zero_point,
        output_zero_point: output.zero_point,
        relu,
        output_low,
        output_high,
    })
}

fn dense_layer<'a>(
    layer: LayerRef,
    record: DenseRecord<'a>,
    in_features: usize,
    input_zero_point: i8,
) -> Result<DenseLayer<'a>, LoadError> {
    expect_len(
        layer,
        "input features",
        in_features,
        usize::from(record.in_features),
    )?;
    let linear = check_linear(
        layer,
        record.weights,
        record.bias,
        record.multipliers,
        record.shifts,
        usize::from(record.out_features),
        in_features,
        input_zero_point,
        record.output,
        record.relu,
    )?;
    Ok(DenseLayer { record, linear })
}

/// The action head's arithmetic as int16 logits with zero point 0, for either version.
///
/// Version 2 stores them so: the record's zero point must be 0 and ReLU off (a logit head has
/// no use for either, and refusing them keeps one meaning per file). A version 1 head is int8
/// `q = clamp(zp + r, low, 127)` read as real `scale * (q - zp)`; as the logit `q - zp` that is
/// `clamp(r, low - zp, 127 - zp)`, the same values and argmax, so version 1 files run through
/// the same int16 path with narrower bounds instead of a second code path.
fn logit_head<'a>(
    version: u16,
    linear: Linear<'a>,
    record: DenseRecord<'a>,
) -> Result<Linear<'a>, LoadError> {
    let zero_point = record.output.zero_point;
    if version >= 2 {
        if zero_point != 0 {
            return Err(LoadError::InvalidParameter {
                layer: LayerRef::ActionHead,
                what: "logit zero point (must be 0)",
            });
        }
        if record.relu {
            return Err(LoadError::InvalidParameter {
                layer: LayerRef::ActionHead,
                what: "ReLU on the logits",
            });
        }
        return Ok(Linear {
            output_low: i16::MIN,
            output_high: i16::MAX,
            ..linear
        });
    }
    let (low, high) = Linear::int8_bounds(zero_point, record.relu);
    Ok(Linear {
        output_zero_point: 0,
        output_low: low - i16::from(zero_point),
        output_high: high - i16::from(zero_point),
        ..linear
    })
}

fn layer_index(index: usize) -> u8 {
    u8::try_from(index).unwrap_or(u8::MAX)
}

impl<'a> Model<'a> {
    /// Checks and decodes a weights file. Never panics, never allocates, never copies tensors.
    pub fn parse(bytes: &'a [u8]) -> Result<Model<'a>, LoadError> {
        let (version, payload) = open_envelope(bytes)?;
        let corrupt = |part| LoadError::Corrupt { part };

        let (input, rest) = take::<InputRecord>(payload, corrupt("input"), "input")?;
        check_input_quant(LayerRef::Input, &input.height)?;
        let rows = usize::from(input.rows);
        let cols = usize::from(input.cols);
        if rows == 0 || cols == 0 {
            return Err(LoadError::InvalidParameter {
                layer: LayerRef::Input,
                what: "height map shape",
            });
        }

        let (count, mut rest) = take_len(
            rest,
            "state features",
            Capacity::StateFeatures,
            MAX_STATE_FEATURES,
        )?;
        let mut state = Vec::new();
        for _ in 0..count {
            let (quant, after) =
                take::<InputQuantRecord>(rest, corrupt("state feature"), "state feature")?;
            check_input_quant(LayerRef::Input, &quant)?;
            state.push(quant).map_err(|_| LoadError::ExceedsCapacity {
                what: Capacity::StateFeatures,
                required: count,
                capacity: MAX_STATE_FEATURES,
            })?;
            rest = after;
        }

        let mut activation_elements = rows.saturating_mul(cols);
        let mut row_elements = 0usize;

        let (count, mut rest) =
            take_len(rest, "conv layers", Capacity::ConvLayers, MAX_CONV_LAYERS)?;
        let mut convs: Vec<ConvLayer<'a>, MAX_CONV_LAYERS> = Vec::new();
        let (mut h, mut w, mut c) = (rows, cols, 1usize);
        let mut zero_point = input.height.zero_point;
        let mut features_quant = ActQuantRecord {
            scale: input.height.scale_m,
            zero_point,
        };
        for index in 0..count {
            let layer = LayerRef::Conv(layer_index(index));
            let (record, after) = take::<ConvRecord<'a>>(rest, corrupt("conv"), "conv")?;
            rest = after;
            expect_len(layer, "input channels", c, usize::from(record.in_channels))?;
            let kernel = usize::from(record.kernel);
            let stride = usize::from(record.stride);
            let padding = usize::from(record.padding);
            if kernel == 0 || stride == 0 || padding >= kernel {
                return Err(LoadError::InvalidParameter {
                    layer,
                    what: "kernel, stride or padding",
                });
            }
            let padded_h = h.saturating_add(2 * padding);
            let padded_w = w.saturating_add(2 * padding);
            if padded_h < kernel || padded_w < kernel {
                return Err(LoadError::InvalidParameter {
                    layer,
                    what: "kernel larger than its padded input",
                });
            }
            let out_rows = (padded_h - kernel) / stride + 1;
            let out_cols = (padded_w - kernel) / stride + 1;
            let out_channels = usize::from(record.out_channels);
            let linear = check_linear(
                layer,
                record.weights,
                record.bias,
                record.multipliers,
                record.shifts,
                out_channels,
                kernel.saturating_mul(kernel).saturating_mul(c),
                zero_point,
                record.output,
                record.relu,
            )?;
            activation_elements = activation_elements.max(
                out_rows
                    .saturating_mul(out_cols)
                    .saturating_mul(out_channels),
            );
            row_elements = row_elements.max(linear.row_len);
            let conv = ConvLayer {
                record,
                linear,
                in_rows: h,
                in_cols: w,
                in_channels: c,
                out_rows,
                out_cols,
            };
            convs.push(conv).map_err(|_| LoadError::ExceedsCapacity {
                what: Capacity::ConvLayers,
                required: count,
                capacity: MAX_CONV_LAYERS,
            })?;
            (h, w, c) = (out_rows, out_cols, out_channels);
            zero_point = record.output.zero_point;
            features_quant = record.output;
        }

        // Flattened features (CHW) followed by the quantized state, in the features'
        // quantization domain (the trainer folds each state feature's own scale and zero point
        // into the first dense layer's weights and bias).
        let mut width = h
            .saturating_mul(w)
            .saturating_mul(c)
            .saturating_add(state.len());
        activation_elements = activation_elements.max(width);

        let (count, mut rest) = take_len(
            rest,
            "dense layers",
            Capacity::DenseLayers,
            MAX_DENSE_LAYERS,
        )?;
        let mut hidden: Vec<DenseLayer<'a>, MAX_DENSE_LAYERS> = Vec::new();
        for index in 0..count {
            let layer = LayerRef::Dense(layer_index(index));
            let (record, after) = take::<DenseRecord<'a>>(rest, corrupt("dense"), "dense")?;
            rest = after;
            let dense = dense_layer(layer, record, width, zero_point)?;
            row_elements = row_elements.max(width);
            width = dense.linear.rows;
            activation_elements = activation_elements.max(width);
            zero_point = record.output.zero_point;
            hidden.push(dense).map_err(|_| LoadError::ExceedsCapacity {
                what: Capacity::DenseLayers,
                required: count,
                capacity: MAX_DENSE_LAYERS,
            })?;
        }
        row_elements = row_elements.max(width);

        let (record, rest) = take::<DenseRecord<'a>>(rest, corrupt("action head"), "action head")?;
        let mut action_head = dense_layer(LayerRef::ActionHead, record, width, zero_point)?;
        expect_len(
            LayerRef::ActionHead,
            "outputs",
            ACTION_LOGITS,
            action_head.linear.rows,
        )?;
        action_head.linear = logit_head(version, action_head.linear, record)?;
        let (record, rest) =
            take::<Option<DenseRecord<'a>>>(rest, corrupt("value head"), "value head")?;
        let value_head = match record {
            Some(record) => {
                let head = dense_layer(LayerRef::ValueHead, record, width, zero_point)?;
                expect_len(LayerRef::ValueHead, "outputs", 1, head.linear.rows)?;
                Some(head)
            }
            None => None,
        };
        if !rest.is_empty() {
            return Err(LoadError::Corrupt {
                part: "bytes after the value head",
            });
        }
        Ok(Model {
            version,
            input,
            state,
            convs,
            hidden,
            action_head,
            value_head,
            feature_channels: c,
            feature_rows: h,
            feature_cols: w,
            features_quant,
            requirements: Requirements {
                activation_elements,
                row_elements,
            },
        })
    }

    /// Bits of each quantized state feature: 8 in a version 1 file, 16 in version 2 (the int8
    /// grid refined by [`super::format::STATE_FRACTION_BITS`] bits).
    pub fn state_bits(&self) -> u32 {
        if self.version >= 2 {
            16
        } else {
            8
        }
    }

    /// Bits of the action logits as stored: 8 in a version 1 file, 16 in version 2 (the
    /// runtime reports both as int16, see [`Model::action_head`]).
    pub fn logit_bits(&self) -> u32 {
        if self.version >= 2 {
            16
        } else {
            8
        }
    }

    /// Number of weights and biases (int8 weights + int32 biases), the usual parameter count.
    pub fn parameter_count(&self) -> usize {
        self.linears()
            .map(|linear| linear.rows.saturating_mul(linear.row_len) + linear.rows)
            .sum()
    }

    /// Multiply-accumulates per decision (conv outputs x patch length, dense rows x inputs).
    pub fn macs(&self) -> usize {
        let conv: usize = self
            .convs
            .iter()
            .map(|conv| {
                (conv.out_rows * conv.out_cols)
                    .saturating_mul(conv.linear.rows)
                    .saturating_mul(conv.linear.row_len)
            })
            .sum();
        let dense: usize = self
            .hidden
            .iter()
            .chain(core::iter::once(&self.action_head))
            .chain(self.value_head.iter())
            .map(|dense| dense.linear.rows.saturating_mul(dense.linear.row_len))
            .sum();
        conv + dense
    }

    /// Bytes of tensor data (weights, biases, multipliers, shifts) borrowed from the file.
    pub fn tensor_bytes(&self) -> usize {
        self.linears()
            .map(|l| l.weights.len() + l.bias.len() + l.multipliers.len() + l.shifts.len())
            .sum()
    }

    /// Every layer's arithmetic, in execution order (heads last).
    pub fn linears(&self) -> impl Iterator<Item = &Linear<'a>> + '_ {
        self.convs
            .iter()
            .map(|conv| &conv.linear)
            .chain(self.hidden.iter().map(|dense| &dense.linear))
            .chain(core::iter::once(&self.action_head.linear))
            .chain(self.value_head.iter().map(|dense| &dense.linear))
    }
}
