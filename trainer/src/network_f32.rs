//! The policy network in plain f32: its architecture, its tensors and a straightforward forward
//! pass. This is the float reference: quantization calibrates on it and int8 results are
//! compared with it.
//!
//! Layout conventions (the same as PyTorch, so trained weights drop in): activations CHW, conv
//! weights `[out][in][ky][kx]` (OIHW), dense weights `[out][in]`. The conv features are
//! flattened channel-major (CHW) and the state is appended after them.

use rand::Rng;
use wheelleg_runtime::action::{CHOICES, DIMS};
use wheelleg_runtime::observation::{HEIGHT_MAP_SIDE, STATE_LEN};

/// Outputs of the action head: five 3-way heads in `Dim::ALL` order.
pub const ACTION_LOGITS: usize = DIMS * CHOICES;

/// One conv layer's shape (square kernel, ReLU after it).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ConvSpec {
    /// Input channels.
    pub in_channels: usize,
    /// Output channels.
    pub out_channels: usize,
    /// Kernel side.
    pub kernel: usize,
    /// Stride, both axes.
    pub stride: usize,
    /// Zero padding on every side.
    pub padding: usize,
}

impl ConvSpec {
    /// Output side for an input side.
    pub fn output_side(&self, input: usize) -> usize {
        (input + 2 * self.padding - self.kernel) / self.stride + 1
    }
}

/// The whole network's shape: conv stack (ReLU) -> flatten CHW ++ state -> dense stack (ReLU) ->
/// action head (15 logits) and optional value head (1).
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Architecture {
    /// Height-map rows.
    pub height_rows: usize,
    /// Height-map columns.
    pub height_cols: usize,
    /// State features appended after the conv features.
    pub state_len: usize,
    /// Conv layers, first first.
    pub convs: Vec<ConvSpec>,
    /// Widths of the hidden dense layers.
    pub hidden: Vec<usize>,
    /// Whether the network has a value head.
    pub value_head: bool,
}

impl Architecture {
    /// The shipped policy: three stride-2 3x3 convs (1->16->32->32 channels, 32x32 -> 4x4),
    /// flatten (512) ++ state (4), dense 516->128, action head 128->15, value head 128->1.
    pub fn default_policy() -> Architecture {
        let conv = |in_channels, out_channels| ConvSpec {
            in_channels,
            out_channels,
            kernel: 3,
            stride: 2,
            padding: 1,
        };
        Architecture {
            height_rows: HEIGHT_MAP_SIDE,
            height_cols: HEIGHT_MAP_SIDE,
            state_len: STATE_LEN,
            convs: vec![conv(1, 16), conv(16, 32), conv(32, 32)],
            hidden: vec![128],
            value_head: true,
        }
    }

    /// (channels, rows, cols) after each conv layer.
    pub fn conv_shapes(&self) -> Vec<(usize, usize, usize)> {
        let (mut h, mut w) = (self.height_rows, self.height_cols);
        self.convs
            .iter()
            .map(|conv| {
                h = conv.output_side(h);
                w = conv.output_side(w);
                (conv.out_channels, h, w)
            })
            .collect()
    }

    /// Length of the flattened conv features (the raw map without convs).
    pub fn features_len(&self) -> usize {
        self.conv_shapes()
            .last()
            .map_or(self.height_rows * self.height_cols, |&(c, h, w)| c * h * w)
    }

    /// Input width of the dense stack: features then state.
    pub fn concat_len(&self) -> usize {
        self.features_len() + self.state_len
    }

    /// Width of the layer feeding the heads.
    pub fn trunk_width(&self) -> usize {
        self.hidden
            .last()
            .copied()
            .unwrap_or_else(|| self.concat_len())
    }
}

/// A conv layer's tensors.
#[derive(Clone, Debug, PartialEq)]
pub struct Conv2dF32 {
    /// Shape.
    pub spec: ConvSpec,
    /// `out * in * k * k`, OIHW.
    pub weights: Vec<f32>,
    /// `out`.
    pub bias: Vec<f32>,
}

/// A dense layer's tensors.
#[derive(Clone, Debug, PartialEq)]
pub struct DenseF32 {
    /// Inputs.
    pub in_features: usize,
    /// Outputs.
    pub out_features: usize,
    /// `out * in`, row-major.
    pub weights: Vec<f32>,
    /// `out`.
    pub bias: Vec<f32>,
}

impl DenseF32 {
    /// `W x + b`, optionally through a ReLU.
    pub fn forward(&self, input: &[f32], relu: bool) -> Vec<f32> {
        self.weights
            .chunks_exact(self.in_features)
            .zip(&self.bias)
            .map(|(row, &b)| {
                let sum = b + row.iter().zip(input).map(|(w, x)| w * x).sum::<f32>();
                if relu {
                    sum.max(0.0)
                } else {
                    sum
                }
            })
            .collect()
    }
}

/// The float policy network.
#[derive(Clone, Debug, PartialEq)]
pub struct NetworkF32 {
    /// Shape of everything.
    pub arch: Architecture,
    /// Conv stack.
    pub convs: Vec<Conv2dF32>,
    /// Hidden dense stack.
    pub hidden: Vec<DenseF32>,
    /// Action head, [`ACTION_LOGITS`] outputs.
    pub action_head: DenseF32,
    /// Value head, 1 output.
    pub value_head: Option<DenseF32>,
}

/// Every intermediate tensor of one forward pass (what calibration observes).
#[derive(Clone, Debug, PartialEq)]
pub struct Trace {
    /// The height map, metres, row-major.
    pub height_m: Vec<f32>,
    /// The state.
    pub state: Vec<f32>,
    /// Each conv layer's output after ReLU, CHW.
    pub convs: Vec<Vec<f32>>,
    /// Each hidden dense layer's output after ReLU.
    pub hidden: Vec<Vec<f32>>,
    /// Action logits.
    pub action_logits: Vec<f32>,
    /// Value estimate.
    pub value: Option<f32>,
}

fn dense_random(rng: &mut impl Rng, in_features: usize, out_features: usize) -> DenseF32 {
    // He (Kaiming) uniform: keeps activation variance roughly constant through ReLU layers.
    let bound = (6.0 / in_features as f32).sqrt();
    DenseF32 {
        in_features,
        out_features,
        weights: (0..in_features * out_features)
            .map(|_| rng.random_range(-bound..bound))
            .collect(),
        bias: (0..out_features)
            .map(|_| rng.random_range(-0.1..0.1))
            .collect(),
    }
}

impl NetworkF32 {
    /// A randomly initialised network (He uniform weights, small random biases).
    pub fn random(arch: &Architecture, rng: &mut impl Rng) -> NetworkF32 {
        let convs = arch
            .convs
            .iter()
            .map(|&spec| {
                let fan_in = spec.in_channels * spec.kernel * spec.kernel;
                let bound = (6.0 / fan_in as f32).sqrt();
                Conv2dF32 {
                    spec,
                    weights: (0..spec.out_channels * fan_in)
                        .map(|_| rng.random_range(-bound..bound))
                        .collect(),
                    bias: (0..spec.out_channels)
                        .map(|_| rng.random_range(-0.1..0.1))
                        .collect(),
                }
            })
            .collect();
        let mut width = arch.concat_len();
        let hidden = arch
            .hidden
            .iter()
            .map(|&out| {
                let layer = dense_random(rng, width, out);
                width = out;
                layer
            })
            .collect();
        NetworkF32 {
            arch: arch.clone(),
            convs,
            hidden,
            action_head: dense_random(rng, width, ACTION_LOGITS),
            value_head: arch.value_head.then(|| dense_random(rng, width, 1)),
        }
    }

    /// Weights and biases.
    pub fn parameter_count(&self) -> usize {
        let conv: usize = self
            .convs
            .iter()
            .map(|c| c.weights.len() + c.bias.len())
            .sum();
        let dense: usize = self
            .dense_layers()
            .map(|d| d.weights.len() + d.bias.len())
            .sum();
        conv + dense
    }

    /// Hidden layers then heads.
    pub fn dense_layers(&self) -> impl Iterator<Item = &DenseF32> {
        self.hidden
            .iter()
            .chain(std::iter::once(&self.action_head))
            .chain(self.value_head.iter())
    }

    /// Action logits and value for a row-major height map in metres and a state vector.
    pub fn forward(&self, height_m: &[f32], state: &[f32]) -> (Vec<f32>, Option<f32>) {
        let trace = self.trace(height_m, state);
        (trace.action_logits, trace.value)
    }

    /// The forward pass keeping every intermediate tensor.
    pub fn trace(&self, height_m: &[f32], state: &[f32]) -> Trace {
        let (mut h, mut w) = (self.arch.height_rows, self.arch.height_cols);
        let mut x = height_m.to_vec();
        let mut convs = Vec::with_capacity(self.convs.len());
        for conv in &self.convs {
            let out = conv2d_relu(conv, &x, h, w);
            h = conv.spec.output_side(h);
            w = conv.spec.output_side(w);
            convs.push(out.clone());
            x = out;
        }
        x.extend_from_slice(state);
        let mut hidden = Vec::with_capacity(self.hidden.len());
        for layer in &self.hidden {
            x = layer.forward(&x, true);
            hidden.push(x.clone());
        }
        let action_logits = self.action_head.forward(&x, false);
        let value = self
            .value_head
            .as_ref()
            .and_then(|head| head.forward(&x, false).first().copied());
        Trace {
            height_m: height_m.to_vec(),
            state: state.to_vec(),
            convs,
            hidden,
            action_logits,
            value,
        }
    }
}

/// Direct convolution + ReLU on a CHW input of `h x w`.
fn conv2d_relu(conv: &Conv2dF32, input: &[f32], h: usize, w: usize) -> Vec<f32> {
    let ConvSpec {
        in_channels,
        out_channels,
        kernel,
        stride,
        padding,
    } = conv.spec;
    let (oh, ow) = (conv.spec.output_side(h), conv.spec.output_side(w));
    let mut out = vec![0.0; out_channels * oh * ow];
    for oc in 0..out_channels {
        for oy in 0..oh {
            for ox in 0..ow {
                let mut sum = conv.bias[oc];
                for ic in 0..in_channels {
                    for ky in 0..kernel {
                        for kx in 0..kernel {
                            let iy = (oy * stride + ky) as isize - padding as isize;
                            let ix = (ox * stride + kx) as isize - padding as isize;
                            if iy < 0 || ix < 0 || iy >= h as isize || ix >= w as isize {
                                continue;
                            }
                            let (iy, ix) = (iy as usize, ix as usize);
                            let weight =
                                conv.weights[((oc * in_channels + ic) * kernel + ky) * kernel + kx];
                            sum += weight * input[(ic * h + iy) * w + ix];
                        }
                    }
                }
                out[(oc * oh + oy) * ow + ox] = sum.max(0.0);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn default_architecture_has_the_documented_shapes() {
        let arch = Architecture::default_policy();
        assert_eq!(
            arch.conv_shapes(),
            vec![(16, 16, 16), (32, 8, 8), (32, 4, 4)]
        );
        assert_eq!(arch.features_len(), 512);
        assert_eq!(arch.concat_len(), 516);
        let net = NetworkF32::random(&arch, &mut ChaCha8Rng::seed_from_u64(1));
        // 160 + 4640 + 9248 + 66176 + 1935 + 129
        assert_eq!(net.parameter_count(), 82_288);
    }

    #[test]
    fn conv_matches_a_hand_computed_example() {
        // 1 channel 3x3 input, 2x2 kernel of ones, stride 1, no padding: sums of 2x2 windows.
        let conv = Conv2dF32 {
            spec: ConvSpec {
                in_channels: 1,
                out_channels: 1,
                kernel: 2,
                stride: 1,
                padding: 0,
            },
            weights: vec![1.0; 4],
            bias: vec![-10.0],
        };
        let input = [1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0];
        // windows: 12, 16, 24, 28; minus 10; ReLU.
        assert_eq!(conv2d_relu(&conv, &input, 3, 3), vec![2.0, 6.0, 14.0, 18.0]);
    }
}
