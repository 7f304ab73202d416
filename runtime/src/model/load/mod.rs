//! Reading and validating a weights file, once, before any inference.
//!
//! [`Model::parse`] checks the envelope (magic, version, checksum), decodes the layer records
//! borrowing every tensor from the input bytes, and checks every shape, length and parameter
//! range that inference relies on. After it succeeds, inference only needs the capacity check of
//! [`Requirements`] against its buffers; it never meets a length it did not expect.
//!
//! Pieces: the model and its parse here; the record decoding and checks in `checks.rs`; the
//! validated layers in `layers.rs`; the errors in `error.rs`.

use heapless::Vec;

use super::format::{
    ActQuantRecord, ConvRecord, DenseRecord, InputQuantRecord, InputRecord, RobotRecord,
    ROBOT_RECORD_VERSION, WHEEL_OFFSET_VERSION,
};
use crate::action::{CHOICES, DIMS};

mod checks;
mod error;
mod layers;
mod robot;

use checks::{
    check_input_quant, check_linear, dense_layer, expect_len, layer_index, logit_head, take,
    take_len,
};
pub use checks::{i32_at, open_envelope};
pub use error::{Capacity, LayerRef, LoadError};
pub use layers::{ConvLayer, DenseLayer, Linear, Requirements};
pub use robot::{trained_for, TrainedFor};

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
    /// The robot the policy was trained for: the file's robot record (version 3 on), the
    /// shipped robot for older files.
    pub trained_for: TrainedFor<'a>,
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
        let (trained_for, rest) = if version >= ROBOT_RECORD_VERSION {
            let (record, rest) =
                take::<RobotRecord<'a>>(rest, corrupt("robot record"), "robot record")?;
            let (wheel_offset_m, rest) = if version >= WHEEL_OFFSET_VERSION {
                take::<f32>(rest, corrupt("wheel offset"), "wheel offset")?
            } else {
                (0.0, rest)
            };
            (trained_for(record, wheel_offset_m)?, rest)
        } else {
            (TrainedFor::SHIPPED, rest)
        };
        if !rest.is_empty() {
            return Err(LoadError::Corrupt {
                part: "bytes after the last record",
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
            trained_for,
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
