//! The actor-critic network (paper, "Network Architecture") as a differentiable burn graph.
//!
//! The parameters themselves live in a [`NetworkF32`]: it is the one source of truth that the
//! optimizer updates, checkpoints store and export/quantization read. [`Net`] copies them into
//! burn tensors (with gradient tracking for training, without for inference), runs the forward
//! pass and hands the gradients back in the same layout. Copying ~82k floats per minibatch is
//! negligible next to the convolutions, and it keeps checkpoints, Adam state and conversions
//! plain `Vec<f32>`s (docs/decisions.md).
//!
//! Shapes: conv stack (ReLU) over the 1 x 32 x 32 height map, flatten CHW, append the 4 state
//! features, dense stack (ReLU), then the action head (5 heads x 3 logits) and the value head.

use crate::error::TrainError;
use crate::network_f32::{Architecture, Conv2dF32, DenseF32, NetworkF32, ACTION_LOGITS};
use burn::tensor::activation::{log_softmax, relu};
use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{Device, Gradients, Tensor, TensorData};
use rand::Rng;
use wheelleg_runtime::action::{CHOICES, DIMS};

/// Scale of the action head's initial weights: near-uniform initial action distributions, so
/// early exploration is not biased by random logits (the usual PPO 0.01 init).
pub const ACTION_HEAD_INIT_SCALE: f32 = 0.01;

/// Which CPU/GPU path burn runs on. All are selected at run time; those not compiled in
/// report an error.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum BackendKind {
    /// burn's pure-Rust CPU backend (default).
    Flex,
    /// CUDA GPU 0 (feature `cuda`).
    Cuda,
}

impl BackendKind {
    /// Parses a name as used in configs (`run.backend`).
    pub fn from_name(name: &str) -> Result<BackendKind, TrainError> {
        match name {
            "flex" => Ok(BackendKind::Flex),
            "cuda" => Ok(BackendKind::Cuda),
            other => Err(TrainError::setting(
                "run.backend",
                format!("unknown backend {other:?} (expected flex or cuda)"),
            )),
        }
    }

    /// The burn device, or an error naming the cargo feature to enable.
    #[allow(unreachable_code)]
    pub fn device(self) -> Result<Device, TrainError> {
        match self {
            BackendKind::Flex => {
                #[cfg(feature = "flex")]
                return Ok(Device::flex());
                Err(TrainError::BackendNotBuilt { backend: "flex" })
            }
            BackendKind::Cuda => {
                #[cfg(feature = "cuda")]
                return Ok(Device::cuda(0));
                Err(TrainError::BackendNotBuilt { backend: "cuda" })
            }
        }
    }
}

/// A fresh policy: He-uniform weights (from `network_f32`), action head scaled down by
/// [`ACTION_HEAD_INIT_SCALE`], zero head biases. The first dense layer's columns that read the
/// state (clearance, track, target) are drawn with the state's own fan-in: with the conv
/// features' fan-in (516) their weights would be ~0.1 and the target, the one input every
/// behaviour needs, would start drowned by 512 conv features (measured: straight-line
/// learning stalled at a few % success). Every number comes from `rng`.
pub fn init_policy(arch: &Architecture, rng: &mut impl Rng) -> NetworkF32 {
    let mut net = NetworkF32::random(arch, rng);
    if let Some(first) = net.hidden.first_mut() {
        let features = arch.features_len();
        let bound = (6.0 / arch.state_len.max(1) as f32).sqrt();
        for row in first.weights.chunks_exact_mut(first.in_features) {
            for w in &mut row[features..] {
                *w = rng.random_range(-bound..bound);
            }
        }
    }
    net.action_head
        .weights
        .iter_mut()
        .for_each(|w| *w *= ACTION_HEAD_INIT_SCALE);
    net.action_head.bias.iter_mut().for_each(|b| *b = 0.0);
    if let Some(head) = &mut net.value_head {
        head.bias.iter_mut().for_each(|b| *b = 0.0);
    }
    net
}

/// The parameter tensors of `net` in a fixed order (conv w, b ..., hidden w, b ..., action
/// w, b, value w, b): the order of gradients, Adam moments and checkpoints.
pub fn parameters(net: &NetworkF32) -> Vec<&[f32]> {
    let mut out: Vec<&[f32]> = Vec::new();
    for c in &net.convs {
        out.push(&c.weights);
        out.push(&c.bias);
    }
    for d in net.dense_layers() {
        out.push(&d.weights);
        out.push(&d.bias);
    }
    out
}

/// Mutable parameter tensors, same order as [`parameters`].
pub fn parameters_mut(net: &mut NetworkF32) -> Vec<&mut [f32]> {
    let mut out: Vec<&mut [f32]> = Vec::new();
    for c in &mut net.convs {
        out.push(&mut c.weights);
        out.push(&mut c.bias);
    }
    for d in net
        .hidden
        .iter_mut()
        .chain(std::iter::once(&mut net.action_head))
        .chain(net.value_head.iter_mut())
    {
        out.push(&mut d.weights);
        out.push(&mut d.bias);
    }
    out
}

struct ConvT {
    weight: Tensor<4>,
    bias: Tensor<1>,
    options: ConvOptions<2>,
}

struct DenseT {
    /// `[out, in]` as in `network_f32`; transposed in the graph so gradients keep that layout.
    weight: Tensor<2>,
    bias: Tensor<1>,
}

/// The network's parameters as burn tensors on one device.
pub struct Net {
    arch: Architecture,
    convs: Vec<ConvT>,
    hidden: Vec<DenseT>,
    action_head: DenseT,
    value_head: DenseT,
    device: Device,
}

/// Outputs of one batched forward pass.
pub struct Forward {
    /// `[batch, DIMS, CHOICES]` log-probabilities of each head's choices.
    pub log_probs: Tensor<3>,
    /// `[batch]` state values.
    pub values: Tensor<1>,
}

impl Net {
    /// Copies `net` to `device`. With `track_grad`, every parameter records gradients (the
    /// device must then be an autodiff device: `device.autodiff()`).
    pub fn new(net: &NetworkF32, device: &Device, track_grad: bool) -> Result<Net, TrainError> {
        Net::with_tracking(net, device, track_grad, track_grad)
    }

    /// Like [`Net::new`], choosing separately whether the conv parameters and the dense ones
    /// record gradients. Training with the native conv kernel (`crate::conv_kernel`) tracks
    /// only the dense ones and feeds [`Net::forward_from_features`]; [`Net::gradients`] then
    /// reports zeros for the convs, to be replaced by the kernel's.
    pub fn with_tracking(
        net: &NetworkF32,
        device: &Device,
        track_convs: bool,
        track_dense: bool,
    ) -> Result<Net, TrainError> {
        let Some(value_head) = &net.value_head else {
            return Err(TrainError::Shape(
                "the actor-critic network needs a value head".into(),
            ));
        };
        let conv = |c: &Conv2dF32| {
            let s = c.spec;
            ConvT {
                weight: leaf(
                    TensorData::new(
                        c.weights.clone(),
                        [s.out_channels, s.in_channels, s.kernel, s.kernel],
                    ),
                    device,
                    track_convs,
                ),
                bias: leaf(
                    TensorData::new(c.bias.clone(), [s.out_channels]),
                    device,
                    track_convs,
                ),
                options: ConvOptions::new([s.stride, s.stride], [s.padding, s.padding], [1, 1], 1),
            }
        };
        let dense = |d: &DenseF32| DenseT {
            weight: leaf(
                TensorData::new(d.weights.clone(), [d.out_features, d.in_features]),
                device,
                track_dense,
            ),
            bias: leaf(
                TensorData::new(d.bias.clone(), [d.out_features]),
                device,
                track_dense,
            ),
        };
        Ok(Net {
            arch: net.arch.clone(),
            convs: net.convs.iter().map(conv).collect(),
            hidden: net.hidden.iter().map(dense).collect(),
            action_head: dense(&net.action_head),
            value_head: dense(value_head),
            device: device.clone(),
        })
    }

    /// The device the tensors live on.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Batched forward pass. `height_m` is `batch * rows * cols` (row-major maps), `state` is
    /// `batch * state_len`.
    pub fn forward(&self, height_m: Vec<f32>, state: Vec<f32>, batch: usize) -> Forward {
        let a = &self.arch;
        let mut x: Tensor<4> = Tensor::from_data(
            TensorData::new(height_m, [batch, 1, a.height_rows, a.height_cols]),
            &self.device,
        );
        for c in &self.convs {
            x = relu(conv2d(
                x,
                c.weight.clone(),
                Some(c.bias.clone()),
                c.options.clone(),
            ));
        }
        let features: Tensor<2> = x.reshape([batch, a.features_len()]);
        self.forward_from_features(features, state, batch)
    }

    /// The network from the conv features on: `features` is `[batch, features_len]` (CHW
    /// flatten per sample, as `crate::conv_kernel` returns them), `state` is
    /// `batch * state_len`.
    pub fn forward_from_features(
        &self,
        features: Tensor<2>,
        state: Vec<f32>,
        batch: usize,
    ) -> Forward {
        let a = &self.arch;
        let state: Tensor<2> =
            Tensor::from_data(TensorData::new(state, [batch, a.state_len]), &self.device);
        let mut h = Tensor::cat(vec![features, state], 1);
        for d in &self.hidden {
            h = relu(dense_forward(d, h));
        }
        let logits = dense_forward(&self.action_head, h.clone());
        let log_probs = log_softmax(logits.reshape([batch, DIMS, CHOICES]), 2);
        let values = dense_forward(&self.value_head, h).reshape([batch]);
        Forward { log_probs, values }
    }

    /// Gradients of every parameter in [`parameters`] order (zeros where none flowed).
    pub fn gradients(&self, grads: &Gradients) -> Vec<Vec<f32>> {
        let mut out = Vec::new();
        let mut push =
            |g: Option<Vec<f32>>, len: usize| out.push(g.unwrap_or_else(|| vec![0.0; len]));
        for c in &self.convs {
            push(grad_vec(&c.weight, grads), c.weight.shape().num_elements());
            push(grad_vec(&c.bias, grads), c.bias.shape().num_elements());
        }
        for d in self
            .hidden
            .iter()
            .chain([&self.action_head, &self.value_head])
        {
            push(grad_vec(&d.weight, grads), d.weight.shape().num_elements());
            push(grad_vec(&d.bias, grads), d.bias.shape().num_elements());
        }
        out
    }
}

fn leaf<const D: usize>(data: TensorData, device: &Device, track_grad: bool) -> Tensor<D> {
    let t = Tensor::from_data(data, device);
    if track_grad {
        t.require_grad()
    } else {
        t
    }
}

fn dense_forward(d: &DenseT, x: Tensor<2>) -> Tensor<2> {
    x.matmul(d.weight.clone().transpose()) + d.bias.clone().unsqueeze::<2>()
}

pub(crate) fn grad_vec<const D: usize>(t: &Tensor<D>, grads: &Gradients) -> Option<Vec<f32>> {
    let g = t.grad(grads)?;
    let data = g.into_data();
    data.as_slice::<f32>().ok().map(<[f32]>::to_vec)
}

/// Reads a `[batch, ...]` tensor back as a flat `Vec<f32>`.
pub fn to_vec<const D: usize>(t: Tensor<D>) -> Vec<f32> {
    let data = t.into_data();
    match data.as_slice::<f32>() {
        Ok(s) => s.to_vec(),
        Err(_) => data
            .convert::<f32>()
            .as_slice::<f32>()
            .map(<[f32]>::to_vec)
            .unwrap_or_default(),
    }
}

/// Checks that the policy has the layout the trainer assumes (15 action logits, value head).
pub fn check_policy_shape(net: &NetworkF32) -> Result<(), TrainError> {
    if net.action_head.out_features != ACTION_LOGITS {
        return Err(TrainError::Shape(format!(
            "action head has {} outputs, expected {ACTION_LOGITS}",
            net.action_head.out_features
        )));
    }
    if net.value_head.is_none() {
        return Err(TrainError::Shape("network has no value head".into()));
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    fn device() -> Device {
        BackendKind::Flex.device().unwrap()
    }

    #[test]
    fn burn_forward_matches_the_f32_reference() {
        let arch = Architecture::default_policy();
        let mut rng = ChaCha8Rng::seed_from_u64(3);
        let net = NetworkF32::random(&arch, &mut rng);
        let batch = 3;
        let maps: Vec<f32> = (0..batch * 1024)
            .map(|_| rng.random_range(0.0..0.3))
            .collect();
        let states: Vec<f32> = (0..batch * 4)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect();
        let burn_net = Net::new(&net, &device(), false).unwrap();
        let out = burn_net.forward(maps.clone(), states.clone(), batch);
        let log_probs = to_vec(out.log_probs);
        let values = to_vec(out.values);
        for b in 0..batch {
            let (logits, value) =
                net.forward(&maps[b * 1024..(b + 1) * 1024], &states[b * 4..(b + 1) * 4]);
            assert!(
                (values[b] - value.unwrap()).abs() < 1e-3,
                "{} vs {:?}",
                values[b],
                value
            );
            for head in 0..DIMS {
                let l = &logits[head * 3..head * 3 + 3];
                let max = l.iter().cloned().fold(f32::MIN, f32::max);
                let lse = max + l.iter().map(|v| (v - max).exp()).sum::<f32>().ln();
                for c in 0..3 {
                    let got = log_probs[(b * DIMS + head) * 3 + c];
                    assert!((got - (l[c] - lse)).abs() < 1e-3);
                }
            }
        }
    }

    #[test]
    fn gradients_come_back_in_parameter_order_and_shape() {
        let arch = Architecture::default_policy();
        let net = init_policy(&arch, &mut ChaCha8Rng::seed_from_u64(4));
        let dev = device().autodiff();
        let burn_net = Net::new(&net, &dev, true).unwrap();
        let out = burn_net.forward(vec![0.1; 2 * 1024], vec![0.2; 8], 2);
        let loss = out.values.sum() + out.log_probs.sum();
        let grads = loss.backward();
        let g = burn_net.gradients(&grads);
        let p = parameters(&net);
        assert_eq!(g.len(), p.len());
        for (g, p) in g.iter().zip(&p) {
            assert_eq!(g.len(), p.len());
        }
        // The value head's bias gradient of sum(values) over a batch of 2 is exactly 2.
        assert!((g.last().unwrap()[0] - 2.0).abs() < 1e-5);
    }
}
