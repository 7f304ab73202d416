//! Shared by the runtime agreement tests: random architectures of the supported family, random
//! observations, quantized networks, and an independent, plainly written integer reference.
// The reference indexes plainly on purpose: it should read like the arithmetic it checks.
#![allow(
    dead_code,
    clippy::needless_range_loop,
    clippy::unwrap_used,
    clippy::indexing_slicing,
    clippy::expect_used
)]

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::model::format::FORMAT_VERSION;
use wheelleg_trainer::network_f32::{Architecture, ConvSpec, NetworkF32};
use wheelleg_trainer::quantize::{
    quantize_for_version, Calibration, QuantizedLayer, QuantizedNetwork, RangeMethod,
};

#[path = "../../../runtime/tests/common/inputs.rs"]
mod inputs;
pub use inputs::raw_inputs_mm;

/// A random architecture of the family: 0-3 convs of random channels, kernel, stride and
/// padding on a random non-square map, 0-5 state features, 0-2 hidden layers, value head or not.
pub fn random_architecture(rng: &mut ChaCha8Rng) -> Architecture {
    let height_rows = rng.random_range(3..=20);
    let height_cols = rng.random_range(3..=20);
    let (mut h, mut w, mut c) = (height_rows, height_cols, 1);
    let mut convs = Vec::new();
    for _ in 0..rng.random_range(0..=3) {
        let padding_max = 2;
        let mut kernel = rng.random_range(1..=4);
        let padding = rng.random_range(0..kernel.min(padding_max + 1));
        while h + 2 * padding < kernel || w + 2 * padding < kernel {
            kernel -= 1;
        }
        let padding = padding.min(kernel - 1);
        let spec = ConvSpec {
            in_channels: c,
            out_channels: rng.random_range(1..=12),
            kernel,
            stride: rng.random_range(1..=3),
            padding,
        };
        h = spec.output_side(h);
        w = spec.output_side(w);
        c = spec.out_channels;
        convs.push(spec);
    }
    Architecture {
        height_rows,
        height_cols,
        state_len: rng.random_range(0..=5),
        convs,
        hidden: (0..rng.random_range(0..=2))
            .map(|_| rng.random_range(1..=40))
            .collect(),
        value_head: rng.random_bool(0.5),
    }
}

/// A height map of a few boxes on flat ground (metres) and a state (clearance, track, target x,
/// target y, then extra features if the architecture has more).
pub fn random_observation(rng: &mut ChaCha8Rng, arch: &Architecture) -> (Vec<f32>, Vec<f32>) {
    let (rows, cols) = (arch.height_rows, arch.height_cols);
    let mut height = vec![0.0f32; rows * cols];
    for _ in 0..rng.random_range(0..6) {
        let (r0, c0) = (rng.random_range(0..rows), rng.random_range(0..cols));
        let (r1, c1) = (
            (r0 + rng.random_range(1..=rows / 2 + 1)).min(rows),
            (c0 + rng.random_range(1..=cols / 2 + 1)).min(cols),
        );
        let top = rng.random_range(0.02..0.45);
        for r in r0..r1 {
            for c in c0..c1 {
                height[r * cols + c] = top;
            }
        }
    }
    let state = (0..arch.state_len)
        .map(|i| match i {
            0 => rng.random_range(0.1..0.35),
            1 => rng.random_range(0.3..0.5),
            _ => rng.random_range(-5.0..5.0),
        })
        .collect();
    (height, state)
}

/// A random network of `arch`, calibrated on random observations and quantized for the current
/// format version.
pub fn random_quantized(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    method: RangeMethod,
) -> (NetworkF32, QuantizedNetwork) {
    random_quantized_version(rng, arch, method, FORMAT_VERSION)
}

/// [`random_quantized`] for a given weights format version (1: int8 logits, 2: int16).
pub fn random_quantized_version(
    rng: &mut ChaCha8Rng,
    arch: &Architecture,
    method: RangeMethod,
    version: u16,
) -> (NetworkF32, QuantizedNetwork) {
    let network = NetworkF32::random(arch, rng);
    let observations: Vec<_> = (0..24).map(|_| random_observation(rng, arch)).collect();
    let calibration = Calibration::from_observations(
        &network,
        observations
            .iter()
            .map(|(h, s)| (h.as_slice(), s.as_slice())),
    );
    let quantized = quantize_for_version(&network, &calibration, method, version).unwrap();
    (network, quantized)
}

/// The default network, randomly initialised from `seed`, quantized.
pub fn default_quantized(seed: u64) -> (NetworkF32, QuantizedNetwork) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    random_quantized(
        &mut rng,
        &Architecture::default_policy(),
        RangeMethod::MinMax,
    )
}

/// Raw integer inputs for `arch` ([`raw_inputs_mm`]).
pub fn random_inputs_mm(rng: &mut ChaCha8Rng, arch: &Architecture) -> (Vec<i16>, Vec<i32>) {
    raw_inputs_mm(rng, arch.height_rows * arch.height_cols, arch.state_len)
}

// ---------------------------------------------------------------------------------------------
// The reference: the same integer arithmetic written as plainly as possible, independently of
// the runtime (CHW layout, i128 products, floor division instead of shifts, direct indexing).

/// round(value * multiplier / 2^(31 - shift)), halves up.
fn reference_rescale(value: i64, multiplier: i32, shift: i8) -> i64 {
    let numerator = i128::from(value) * i128::from(multiplier);
    let denominator = 1i128 << (31 - i32::from(shift));
    (numerator + denominator / 2).div_euclid(denominator) as i64
}

fn reference_int8(value: i64, zero_point: i8, relu: bool) -> i8 {
    let low = if relu { i64::from(zero_point) } else { -128 };
    let v = value + i64::from(zero_point);
    v.max(low).min(127) as i8
}

/// Each output's accumulator (bias plus products), rescaled: before zero point and clamping.
/// `state16` (version 2, only for the layer reading the flattened vector) are int16 state
/// features after the int8 `input`: their columns' sum of `w * (u - 256 zp)` joins the
/// accumulator divided by 256, rounded half up.
fn reference_rescaled(layer: &QuantizedLayer, input: &[i8], state16: &[i16]) -> Vec<i64> {
    let in_len = input.len();
    let row_len = in_len + state16.len();
    let zero_point = i64::from(layer.input.zero_point);
    (0..layer.bias.len())
        .map(|o| {
            let mut acc = i64::from(layer.bias[o]);
            for i in 0..in_len {
                acc +=
                    (i64::from(input[i]) - zero_point) * i64::from(layer.weights[o * row_len + i]);
            }
            let mut state_sum = 0i64;
            for j in 0..state16.len() {
                state_sum += (i64::from(state16[j]) - 256 * zero_point)
                    * i64::from(layer.weights[o * row_len + in_len + j]);
            }
            acc += (state_sum + 128).div_euclid(256);
            reference_rescale(acc, layer.multipliers[o], layer.shifts[o])
        })
        .collect()
}

fn reference_dense(layer: &QuantizedLayer, input: &[i8], state16: &[i16]) -> Vec<i8> {
    reference_rescaled(layer, input, state16)
        .into_iter()
        .map(|v| reference_int8(v, layer.output.zero_point, layer.relu))
        .collect()
}

/// The action head's logits as the runtime reports them (zero point 0): in format version 2
/// the rescaled value clamped to int16; in version 1 the int8 output minus its zero point.
fn reference_logits(
    layer: &QuantizedLayer,
    input: &[i8],
    state16: &[i16],
    version: u16,
) -> Vec<i16> {
    if version >= 2 {
        assert_eq!(layer.output.zero_point, 0, "version 2 logits are symmetric");
        reference_rescaled(layer, input, state16)
            .into_iter()
            .map(|v| v.clamp(-32768, 32767) as i16)
            .collect()
    } else {
        reference_dense(layer, input, state16)
            .into_iter()
            .map(|q| i16::from(q) - i16::from(layer.output.zero_point))
            .collect()
    }
}

/// Action logits and value of the integer network, computed the plain way.
pub fn reference_forward(
    q: &QuantizedNetwork,
    height_mm: &[i16],
    state_mm: &[i32],
) -> (Vec<i16>, Option<i8>) {
    let (mut h, mut w, mut c) = (q.arch.height_rows, q.arch.height_cols, 1usize);
    // CHW activations.
    let mut x: Vec<i8> = height_mm
        .iter()
        .map(|&mm| {
            reference_int8(
                reference_rescale(i64::from(mm), q.height.multiplier, q.height.shift),
                q.height.act.zero_point,
                false,
            )
        })
        .collect();
    for conv in &q.convs {
        let s = conv.spec;
        let (oh, ow) = (s.output_side(h), s.output_side(w));
        let l = &conv.layer;
        let mut out = vec![0i8; s.out_channels * oh * ow];
        for oc in 0..s.out_channels {
            for oy in 0..oh {
                for ox in 0..ow {
                    let mut acc = i64::from(l.bias[oc]);
                    for ky in 0..s.kernel {
                        for kx in 0..s.kernel {
                            let iy = (oy * s.stride + ky) as i64 - s.padding as i64;
                            let ix = (ox * s.stride + kx) as i64 - s.padding as i64;
                            for ic in 0..c {
                                let value = if iy < 0 || ix < 0 || iy >= h as i64 || ix >= w as i64
                                {
                                    l.input.zero_point
                                } else {
                                    x[(ic * h + iy as usize) * w + ix as usize]
                                };
                                let weight =
                                    l.weights[((oc * s.kernel + ky) * s.kernel + kx) * c + ic];
                                acc += (i64::from(value) - i64::from(l.input.zero_point))
                                    * i64::from(weight);
                            }
                        }
                    }
                    out[(oc * oh + oy) * ow + ox] = reference_int8(
                        reference_rescale(acc, l.multipliers[oc], l.shifts[oc]),
                        l.output.zero_point,
                        l.relu,
                    );
                }
            }
        }
        (h, w, c) = (oh, ow, s.out_channels);
        x = out;
    }
    // Version 1: int8 state appended to the features. Version 2: int16 state, kept apart for
    // the layer that reads the flattened vector.
    let mut state16: Vec<i16> = Vec::new();
    for (quant, &mm) in q.state.iter().zip(state_mm) {
        let rescaled = reference_rescale(i64::from(mm), quant.multiplier, quant.shift);
        if q.version >= 2 {
            let u = rescaled + 256 * i64::from(quant.act.zero_point);
            state16.push(u.clamp(-32768, 32767) as i16);
        } else {
            x.push(reference_int8(rescaled, quant.act.zero_point, false));
        }
    }
    for dense in &q.hidden {
        x = reference_dense(&dense.layer, &x, &state16);
        state16.clear();
    }
    let logits = reference_logits(&q.action_head.layer, &x, &state16, q.version);
    let value = q
        .value_head
        .as_ref()
        .map(|head| reference_dense(&head.layer, &x, &state16)[0]);
    (logits, value)
}
