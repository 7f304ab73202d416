//! From a float network and its calibration to int8 tensors (their file bytes: `file_bytes.rs`).

use std::fmt;

use wheelleg_robot::RobotDescription;
use wheelleg_runtime::model::format::{FORMAT_VERSION, OLDEST_FORMAT_VERSION, STATE_FRACTION_BITS};
use wheelleg_runtime::model::load::MAX_BIAS_ABS;

use super::calibrate::{ActionRange, Calibration, RangeMethod, RangeObserver};
use super::params::{quantize_multiplier, quantize_rows, ActQuant};
use crate::network_f32::{Architecture, ConvSpec, DenseF32, NetworkF32};

/// Why a network could not be quantized.
#[derive(Clone, Debug, PartialEq)]
pub enum QuantizeError {
    /// A requantization multiplier is out of the runtime's range (a scale ratio above 2^30).
    Multiplier {
        /// Which layer.
        layer: String,
        /// The real multiplier.
        value: f64,
    },
    /// A bias does not fit the runtime's bound once divided by its scale.
    Bias {
        /// Which layer.
        layer: String,
        /// The quantized value that was too large.
        value: f64,
    },
    /// A size does not fit the file's fields.
    TooLarge {
        /// What.
        what: String,
    },
    /// Serialization failed.
    Encode(String),
    /// A format version this trainer cannot write.
    Version(u16),
}

impl fmt::Display for QuantizeError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            QuantizeError::Multiplier { layer, value } => {
                write!(f, "{layer}: multiplier {value:e} is not representable")
            }
            QuantizeError::Bias { layer, value } => {
                write!(f, "{layer}: quantized bias {value:e} exceeds 2^30")
            }
            QuantizeError::TooLarge { what } => write!(f, "{what} does not fit the format"),
            QuantizeError::Encode(error) => write!(f, "encoding failed: {error}"),
            QuantizeError::Version(version) => write!(
                f,
                "cannot write weights format version {version} (versions \
                 {OLDEST_FORMAT_VERSION} to {FORMAT_VERSION})"
            ),
        }
    }
}

impl std::error::Error for QuantizeError {}

/// How a raw input in millimetres becomes int8 (or, for a version 2 state feature, int16).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct InputQuant {
    /// Scale (metres per int8 step) and zero point: the int8 grid, which the weight folding
    /// uses in both versions.
    pub act: ActQuant,
    /// Fixed-point multiplier of `1 mm / scale`, times 256 for a version 2 state feature
    /// (int16 steps, [`STATE_FRACTION_BITS`]).
    pub multiplier: i32,
    /// Its shift.
    pub shift: i8,
    /// Bits the integer refines the int8 grid by: 0, or [`STATE_FRACTION_BITS`].
    pub fraction_bits: u32,
}

/// One layer's integer tensors (conv or dense), rows = output channels.
#[derive(Clone, Debug, PartialEq)]
pub struct QuantizedLayer {
    /// Int8 weights: conv OHWI, dense `[out][in]`.
    pub weights: Vec<i8>,
    /// Per-row weight scales (real per step).
    pub weight_scales: Vec<f32>,
    /// Int32 bias per row, in units of input scale x weight scale.
    pub bias: Vec<i32>,
    /// Requantization multiplier per row.
    pub multipliers: Vec<i32>,
    /// Requantization shift per row.
    pub shifts: Vec<i8>,
    /// Input activation quantization.
    pub input: ActQuant,
    /// Output activation quantization.
    pub output: ActQuant,
    /// ReLU fused.
    pub relu: bool,
}

/// A quantized conv layer.
#[derive(Clone, Debug, PartialEq)]
pub struct QuantizedConv {
    /// Shape.
    pub spec: ConvSpec,
    /// Tensors.
    pub layer: QuantizedLayer,
}

/// A quantized dense layer.
#[derive(Clone, Debug, PartialEq)]
pub struct QuantizedDense {
    /// Inputs.
    pub in_features: usize,
    /// Outputs.
    pub out_features: usize,
    /// Tensors.
    pub layer: QuantizedLayer,
}

/// The whole network in int8, ready to be written.
#[derive(Clone, Debug, PartialEq)]
pub struct QuantizedNetwork {
    /// Weights format version this network is quantized for and written as: 3 (the robot
    /// record after the tensors), 2 (int16 action logits, `action_head.layer.output`
    /// symmetric with zero point 0) or 1 (int8 logits).
    pub version: u16,
    /// Shape.
    pub arch: Architecture,
    /// Height map (millimetres, i16) to int8.
    pub height: InputQuant,
    /// Each state feature (millimetres, i32) to int8 (version 1) or int16 (version 2).
    pub state: Vec<InputQuant>,
    /// Quantization of the flattened features, which the state shares after folding.
    pub features: ActQuant,
    /// Conv stack.
    pub convs: Vec<QuantizedConv>,
    /// Hidden dense stack.
    pub hidden: Vec<QuantizedDense>,
    /// Action head (its `output` is the int16 logit quantization in version 2).
    pub action_head: QuantizedDense,
    /// Value head.
    pub value_head: Option<QuantizedDense>,
    /// The robot the network was trained for, written as the file's robot record (version 3
    /// on; its wheel offset from version 4 on).
    pub robot: RobotDescription,
}

fn act_quant(observer: &RangeObserver, method: RangeMethod) -> ActQuant {
    let (low, high) = observer.range(method);
    ActQuant::from_range(low, high)
}

/// An input's int8 grid from its calibrated range, and the millimetre multiplier of that grid
/// refined by `fraction_bits` (0 for int8; [`STATE_FRACTION_BITS`] for a version 2 state
/// feature, whose int16 steps are 256 times finer: the grid, zero point and weight folding
/// stay those of int8, only the multiplier grows).
fn input_quant(
    observer: &RangeObserver,
    method: RangeMethod,
    what: &str,
    fraction_bits: u32,
) -> Result<InputQuant, QuantizeError> {
    let act = act_quant(observer, method);
    let real = 0.001 * f64::from(1u32 << fraction_bits) / f64::from(act.scale);
    let (multiplier, shift) =
        quantize_multiplier(real).map_err(|error| QuantizeError::Multiplier {
            layer: what.to_owned(),
            value: error.0,
        })?;
    Ok(InputQuant {
        act,
        multiplier,
        shift,
        fraction_bits,
    })
}

/// Quantizes float rows (`row_len` inputs each) with bias, between two activation
/// quantizations.
fn quantize_layer(
    name: &str,
    weights: &[f32],
    bias: &[f32],
    row_len: usize,
    input: ActQuant,
    output: ActQuant,
    relu: bool,
) -> Result<QuantizedLayer, QuantizeError> {
    let (quantized, weight_scales) = quantize_rows(weights, row_len);
    let mut bias_q = Vec::with_capacity(bias.len());
    let mut multipliers = Vec::with_capacity(bias.len());
    let mut shifts = Vec::with_capacity(bias.len());
    for (&b, &weight_scale) in bias.iter().zip(&weight_scales) {
        // The accumulator's unit: one input step times one weight step.
        let acc_scale = f64::from(input.scale) * f64::from(weight_scale);
        let value = (f64::from(b) / acc_scale).round();
        if value.abs() > f64::from(MAX_BIAS_ABS) {
            return Err(QuantizeError::Bias {
                layer: name.to_owned(),
                value,
            });
        }
        bias_q.push(value as i32);
        let (multiplier, shift) = quantize_multiplier(acc_scale / f64::from(output.scale))
            .map_err(|error| QuantizeError::Multiplier {
                layer: name.to_owned(),
                value: error.0,
            })?;
        multipliers.push(multiplier);
        shifts.push(shift);
    }
    Ok(QuantizedLayer {
        weights: quantized,
        weight_scales,
        bias: bias_q,
        multipliers,
        shifts,
        input,
        output,
        relu,
    })
}

/// Folds the state features' own quantization into a layer that reads the concatenated
/// (features ++ state) vector, so the runtime can treat the whole vector as one int8 tensor
/// quantized like the features.
///
/// State slot j holds `q_j = zp_j + x_j / t_j`, but the layer reads it as `s_x (q_j - zp_x)`.
/// With column j scaled by `t_j / s_x` and `sum_j W_j t_j (zp_x - zp_j)` added to the bias, the
/// layer computes exactly `W x + b` in real arithmetic. The same folding serves version 2's
/// int16 state: the runtime divides those columns' sum by 256, i.e. reads `u_j / 256`, the
/// same `q_j` in int8 steps without its rounding.
fn fold_state(
    layer: &DenseF32,
    features_len: usize,
    features: ActQuant,
    state: &[InputQuant],
) -> (Vec<f32>, Vec<f32>) {
    let mut weights = layer.weights.clone();
    let mut bias = layer.bias.clone();
    for (row, b) in weights.chunks_exact_mut(layer.in_features).zip(&mut bias) {
        for (w, quant) in row[features_len..].iter_mut().zip(state) {
            let t = quant.act.scale;
            *b += *w * t * (f32::from(features.zero_point) - f32::from(quant.act.zero_point));
            *w *= t / features.scale;
        }
    }
    (weights, bias)
}

fn dense(
    name: &str,
    layer: &DenseF32,
    weights_bias: Option<(Vec<f32>, Vec<f32>)>,
    input: ActQuant,
    output: ActQuant,
    relu: bool,
) -> Result<QuantizedDense, QuantizeError> {
    let (weights, bias) =
        weights_bias.unwrap_or_else(|| (layer.weights.clone(), layer.bias.clone()));
    Ok(QuantizedDense {
        in_features: layer.in_features,
        out_features: layer.out_features,
        layer: quantize_layer(
            name,
            &weights,
            &bias,
            layer.in_features,
            input,
            output,
            relu,
        )?,
    })
}

/// Post-training quantization of `network` with the activation ranges of `calibration`, for the
/// current weights format ([`FORMAT_VERSION`]: int16 action logits).
pub fn quantize(
    network: &NetworkF32,
    calibration: &Calibration,
    method: RangeMethod,
) -> Result<QuantizedNetwork, QuantizeError> {
    quantize_for_version(network, calibration, method, FORMAT_VERSION)
}

/// [`quantize`] for a given format version: 2 gives the action head int16 logits
/// ([`ActQuant::logits16`]), 1 the int8 logits of older runtimes (kept to write files for
/// them and to measure what the int16 head gains).
pub fn quantize_for_version(
    network: &NetworkF32,
    calibration: &Calibration,
    method: RangeMethod,
    version: u16,
) -> Result<QuantizedNetwork, QuantizeError> {
    if !(OLDEST_FORMAT_VERSION..=FORMAT_VERSION).contains(&version) {
        return Err(QuantizeError::Version(version));
    }
    let height = input_quant(&calibration.height, method, "height map", 0)?;
    let state_bits = if version >= 2 { STATE_FRACTION_BITS } else { 0 };
    let state = calibration
        .state
        .iter()
        .map(|observer| input_quant(observer, method, "state", state_bits))
        .collect::<Result<Vec<_>, _>>()?;

    let mut input = height.act;
    let mut convs = Vec::with_capacity(network.convs.len());
    for (index, (conv, observer)) in network.convs.iter().zip(&calibration.convs).enumerate() {
        let spec = conv.spec;
        let patch = spec.in_channels * spec.kernel * spec.kernel;
        // OIHW -> OHWI: the runtime's patches are channel-innermost.
        let mut ohwi = Vec::with_capacity(conv.weights.len());
        for o in 0..spec.out_channels {
            for ky in 0..spec.kernel {
                for kx in 0..spec.kernel {
                    for i in 0..spec.in_channels {
                        ohwi.push(
                            conv.weights[((o * spec.in_channels + i) * spec.kernel + ky)
                                * spec.kernel
                                + kx],
                        );
                    }
                }
            }
        }
        let output = act_quant(observer, method);
        let layer = quantize_layer(
            &format!("conv {index}"),
            &ohwi,
            &conv.bias,
            patch,
            input,
            output,
            true,
        )?;
        convs.push(QuantizedConv { spec, layer });
        input = output;
    }
    let features = input;
    let features_len = network.arch.features_len();
    let fold = |layer: &DenseF32| Some(fold_state(layer, features_len, features, &state));

    let mut hidden = Vec::with_capacity(network.hidden.len());
    for (index, (layer, observer)) in network.hidden.iter().zip(&calibration.hidden).enumerate() {
        let output = act_quant(observer, method);
        let folded = if index == 0 { fold(layer) } else { None };
        hidden.push(dense(
            &format!("dense {index}"),
            layer,
            folded,
            input,
            output,
            true,
        )?);
        input = output;
    }
    // Without hidden layers the heads read the concatenated vector themselves.
    let heads_fold = |layer: &DenseF32| {
        if network.hidden.is_empty() {
            fold(layer)
        } else {
            None
        }
    };
    let action_observer = match calibration.action_range {
        ActionRange::AllLogits => &calibration.action,
        ActionRange::Contenders => &calibration.action_contenders,
    };
    let action_output = if version >= 2 {
        let (low, high) = action_observer.range(method);
        ActQuant::logits16(low, high)
    } else {
        act_quant(action_observer, method)
    };
    let action_head = dense(
        "action head",
        &network.action_head,
        heads_fold(&network.action_head),
        input,
        action_output,
        false,
    )?;
    let value_head = match &network.value_head {
        Some(head) => Some(dense(
            "value head",
            head,
            heads_fold(head),
            input,
            act_quant(&calibration.value, method),
            false,
        )?),
        None => None,
    };
    Ok(QuantizedNetwork {
        version,
        arch: network.arch.clone(),
        height,
        state,
        features,
        convs,
        hidden,
        action_head,
        value_head,
        robot: RobotDescription::shipped(),
    })
}
