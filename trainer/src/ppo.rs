//! Proximal policy optimisation, the paper's "Preliminaries" and Eq. 2:
//!
//! `L(theta) = E[ lambda_1 * eta_PPO(theta) + lambda_2 * L_v(theta) ] (+ entropy bonus)`, with
//! `eta_PPO = E[min(Z(psi) A, psi A)]` (Eq. 1, `psi` the probability ratio, `Z` the clip to
//! `[1 - eps, 1 + eps]`) maximised and `L_v = (V(s) - R)^2` minimised.
//!
//! The verbs follow the paper: [`Ppo::act`] (sample with the current policy), [`Ppo::evaluate`]
//! (log-probabilities and values of given samples: Algorithm 2 recomputes replayed samples'
//! advantages with it), [`Ppo::update`] (minibatch epochs of Adam on the loss). Rollout and
//! advantage computation live in `storage`/`runner`, so a caller can feed any [`Batch`].

use crate::config::PpoConfig;
use crate::conv_kernel::{self, ConvKernel, ConvTape};
use crate::error::TrainError;
use crate::network::{self, Net};
use crate::network_f32::NetworkF32;
use crate::storage::{Batch, Minibatch};
use burn::tensor::{Device, Tensor, TensorData};
use rand::seq::SliceRandom;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::mem::take;
use std::sync::{Mutex, PoisonError};
use wheelleg_runtime::action::{CHOICES, DIMS};
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_stack::policy::{greedy_heads, sample_heads, LOG_PROBS};

/// Adam (Kingma & Ba) over the flat parameter tensors, PyTorch semantics (bias-corrected
/// moments, epsilon added to the root). Kept here rather than burn's optimizer so that the
/// state is plain vectors (exact checkpoints) and clipping is over the global norm.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct Adam {
    /// Steps taken.
    pub step: u64,
    /// First moments, one vector per parameter tensor.
    pub m: Vec<Vec<f32>>,
    /// Second moments.
    pub v: Vec<Vec<f32>>,
}

impl Adam {
    /// Zero state for `net`'s parameters.
    pub fn new(net: &NetworkF32) -> Adam {
        let zeros: Vec<Vec<f32>> = network::parameters(net)
            .iter()
            .map(|p| vec![0.0; p.len()])
            .collect();
        Adam {
            step: 0,
            m: zeros.clone(),
            v: zeros,
        }
    }

    /// Whether the state fits `net`'s parameter shapes.
    pub fn fits(&self, net: &NetworkF32) -> bool {
        let params = network::parameters(net);
        params.len() == self.m.len()
            && params.len() == self.v.len()
            && params
                .iter()
                .zip(&self.m)
                .zip(&self.v)
                .all(|((p, m), v)| p.len() == m.len() && p.len() == v.len())
    }

    /// One Adam step on `net` with `grads` (already clipped).
    pub fn apply(&mut self, net: &mut NetworkF32, grads: &[Vec<f32>], lr: f64, epsilon: f64) {
        const BETA1: f64 = 0.9;
        const BETA2: f64 = 0.999;
        self.step += 1;
        let bias1 = 1.0 - BETA1.powi(self.step as i32);
        let bias2 = 1.0 - BETA2.powi(self.step as i32);
        let step_size = (lr / bias1) as f32;
        let bias2_sqrt = bias2.sqrt() as f32;
        let eps = epsilon as f32;
        for (((p, g), m), v) in network::parameters_mut(net)
            .into_iter()
            .zip(grads)
            .zip(&mut self.m)
            .zip(&mut self.v)
        {
            for i in 0..p.len() {
                m[i] = BETA1 as f32 * m[i] + (1.0 - BETA1 as f32) * g[i];
                v[i] = BETA2 as f32 * v[i] + (1.0 - BETA2 as f32) * g[i] * g[i];
                p[i] -= step_size * m[i] / (v[i].sqrt() / bias2_sqrt + eps);
            }
        }
    }
}

/// What one update did (means over the minibatches actually taken).
#[derive(Clone, Copy, Debug, Default, PartialEq, Serialize, Deserialize)]
pub struct UpdateStats {
    /// Clipped surrogate loss (negated Eq. 1).
    pub policy_loss: f32,
    /// Value loss.
    pub value_loss: f32,
    /// Mean entropy of the five heads' distributions (sum over heads).
    pub entropy: f32,
    /// Approximate KL(old || new) of the last minibatch.
    pub approx_kl: f32,
    /// Fraction of samples whose ratio was clipped.
    pub clip_fraction: f32,
    /// Minibatch gradient steps taken.
    pub gradient_steps: usize,
    /// Whether the KL limit stopped the epochs early.
    pub kl_stopped: bool,
}

/// Policy and value outputs for a batch of observations.
#[derive(Clone, Debug, PartialEq)]
pub struct PolicyOutput {
    /// `batch * DIMS * CHOICES` log-probabilities.
    pub log_probs: Vec<f32>,
    /// `batch` values.
    pub values: Vec<f32>,
}

impl PolicyOutput {
    /// Log-probability of `actions` (`DIMS` choices) for sample `i`.
    pub fn action_log_prob(&self, i: usize, actions: &[u8]) -> f32 {
        (0..DIMS)
            .map(|h| self.log_probs[(i * DIMS + h) * CHOICES + actions[h] as usize])
            .sum()
    }

    /// Samples one choice per head for sample `i` (inverse CDF on one uniform draw per head).
    pub fn sample(&self, i: usize, rng: &mut impl Rng) -> [u8; DIMS] {
        sample_heads(&self.log_probs[i * LOG_PROBS..(i + 1) * LOG_PROBS], rng)
    }

    /// The most probable choice per head for sample `i` (greedy evaluation).
    pub fn greedy(&self, i: usize) -> [u8; DIMS] {
        greedy_heads(&self.log_probs[i * LOG_PROBS..(i + 1) * LOG_PROBS])
    }
}

/// Actions sampled for a batch of observations.
#[derive(Clone, Debug, PartialEq)]
pub struct Acted {
    /// `n * DIMS` chosen choice per head.
    pub choices: Vec<u8>,
    /// `n` log-probabilities of the chosen actions.
    pub log_probs: Vec<f32>,
    /// `n` state values.
    pub values: Vec<f32>,
}

/// The PPO learner: the policy's parameters, their Adam state and the hyperparameters.
pub struct Ppo {
    /// Hyperparameters.
    pub config: PpoConfig,
    /// The policy and value function (shared trunk).
    pub net: NetworkF32,
    /// Optimizer state.
    pub adam: Adam,
    device: Device,
    /// The native conv kernel's buffers, reused by every minibatch step.
    conv_tape: ConvTape,
    /// The same for inference (`evaluate` takes `&self`): fresh buffers on every call were
    /// measured 2-3x slower once training had run (allocator page faults).
    eval_tape: Mutex<ConvTape>,
}

/// Observations are evaluated in chunks of this many samples (bounds memory of inference).
const EVAL_CHUNK: usize = 1024;

impl Ppo {
    /// A learner for `net` on `device` (a plain device; autodiff is added for updates).
    pub fn new(net: NetworkF32, config: PpoConfig, device: Device) -> Result<Ppo, TrainError> {
        network::check_policy_shape(&net)?;
        ConvKernel::from_name(&config.conv_kernel)?;
        let adam = Adam::new(&net);
        Ok(Ppo {
            config,
            net,
            adam,
            device,
            conv_tape: ConvTape::default(),
            eval_tape: Mutex::new(ConvTape::default()),
        })
    }

    /// The device.
    pub fn device(&self) -> &Device {
        &self.device
    }

    /// Log-probabilities and values of `n` observations under the current parameters.
    pub fn evaluate(
        &self,
        heights_m: &[f32],
        states: &[f32],
        n: usize,
    ) -> Result<PolicyOutput, TrainError> {
        let kernel = ConvKernel::from_name(&self.config.conv_kernel)?;
        let net = Net::new(&self.net, &self.device, false)?;
        let mut out = PolicyOutput {
            log_probs: Vec::with_capacity(n * DIMS * CHOICES),
            values: Vec::with_capacity(n),
        };
        let mut start = 0;
        while start < n {
            let end = (start + EVAL_CHUNK).min(n);
            let heights = &heights_m[start * HEIGHT_MAP_CELLS..end * HEIGHT_MAP_CELLS];
            let states = states[start * STATE_LEN..end * STATE_LEN].to_vec();
            let f = match kernel {
                ConvKernel::Burn => net.forward(heights.to_vec(), states, end - start),
                ConvKernel::Native => {
                    let arch = &self.net.arch;
                    // A poisoned lock only means another call panicked mid-way; the tape is
                    // overwritten anyway.
                    let mut tape = self
                        .eval_tape
                        .lock()
                        .unwrap_or_else(PoisonError::into_inner);
                    let features = conv_kernel::forward_into(
                        &self.net.convs,
                        arch.height_rows,
                        arch.height_cols,
                        heights,
                        end - start,
                        &mut tape,
                    )?;
                    let features = Tensor::<2>::from_data(
                        TensorData::new(features, [end - start, arch.features_len()]),
                        &self.device,
                    );
                    net.forward_from_features(features, states, end - start)
                }
            };
            out.log_probs.extend(network::to_vec(f.log_probs));
            out.values.extend(network::to_vec(f.values));
            start = end;
        }
        Ok(out)
    }

    /// Samples actions for `n` observations with the current policy.
    pub fn act(
        &self,
        heights_m: &[f32],
        states: &[f32],
        n: usize,
        rng: &mut impl Rng,
    ) -> Result<Acted, TrainError> {
        let out = self.evaluate(heights_m, states, n)?;
        let mut acted = Acted {
            choices: Vec::with_capacity(n * DIMS),
            log_probs: Vec::with_capacity(n),
            values: out.values.clone(),
        };
        for i in 0..n {
            let a = out.sample(i, rng);
            acted.log_probs.push(out.action_log_prob(i, &a));
            acted.choices.extend_from_slice(&a);
        }
        Ok(acted)
    }

    /// `config.epochs` passes over `batch` in shuffled minibatches; stops early when the
    /// approximate KL exceeds `config.target_kl`.
    pub fn update(&mut self, batch: &Batch, rng: &mut impl Rng) -> Result<UpdateStats, TrainError> {
        let n = batch.len();
        let mb = self.config.minibatch_size.min(n);
        if mb < 2 {
            return Err(TrainError::BatchTooSmall { samples: n });
        }
        let mut order: Vec<usize> = (0..n).collect();
        let mut sums = UpdateStats::default();
        let mut last_kl = 0.0;
        let mut kl_stopped = false;
        'epochs: for _ in 0..self.config.epochs {
            order.shuffle(rng);
            // Drop the ragged tail: every minibatch has the same size and weight.
            for chunk in order.chunks_exact(mb) {
                let s = self.minibatch_step(batch, chunk)?;
                sums.policy_loss += s.policy_loss;
                sums.value_loss += s.value_loss;
                sums.entropy += s.entropy;
                sums.clip_fraction += s.clip_fraction;
                sums.gradient_steps += 1;
                last_kl = s.approx_kl;
                if self.config.target_kl > 0.0 && s.approx_kl > self.config.target_kl {
                    kl_stopped = true;
                    break 'epochs;
                }
            }
        }
        let k = sums.gradient_steps.max(1) as f32;
        Ok(UpdateStats {
            policy_loss: sums.policy_loss / k,
            value_loss: sums.value_loss / k,
            entropy: sums.entropy / k,
            approx_kl: last_kl,
            clip_fraction: sums.clip_fraction / k,
            gradient_steps: sums.gradient_steps,
            kl_stopped,
        })
    }

    /// Forward, loss, backward, global-norm clip and Adam on the samples `idx` of `batch`.
    pub fn minibatch_step(
        &mut self,
        batch: &Batch,
        idx: &[usize],
    ) -> Result<UpdateStats, TrainError> {
        let mut rows = Minibatch::gather(batch, idx, self.config.normalize_advantages);
        let device = self.device.clone().autodiff();
        let tracked = self.forward_tracked(&mut rows, &device)?;
        let loss = ppo_loss(tracked.forward, rows.loss_inputs(&device), &self.config);
        let mut grads = self.gradients(&tracked.net, tracked.features_leaf, &loss.total)?;
        let stats = loss.stats(self.config.clip_epsilon);
        if !stats.policy_loss.is_finite() || !stats.value_loss.is_finite() {
            return Err(TrainError::Diverged {
                policy_loss: stats.policy_loss,
                value_loss: stats.value_loss,
            });
        }
        let c = &self.config;
        clip_global_norm(&mut grads, c.max_grad_norm);
        self.adam
            .apply(&mut self.net, &grads, c.learning_rate, c.adam_epsilon);
        Ok(stats)
    }

    /// The minibatch's forward pass in a graph burn can differentiate. With the native kernel
    /// the conv features enter the graph as a leaf whose gradient [`Ppo::gradients`] feeds to
    /// the kernel's backward; burn differentiates everything after them.
    fn forward_tracked(
        &mut self,
        rows: &mut Minibatch,
        device: &Device,
    ) -> Result<TrackedForward, TrainError> {
        let b = rows.len;
        match ConvKernel::from_name(&self.config.conv_kernel)? {
            ConvKernel::Burn => {
                let net = Net::new(&self.net, device, true)?;
                let forward = net.forward(take(&mut rows.heights), take(&mut rows.states), b);
                Ok(TrackedForward {
                    net,
                    forward,
                    features_leaf: None,
                })
            }
            ConvKernel::Native => {
                let arch = &self.net.arch;
                let features = conv_kernel::forward_into(
                    &self.net.convs,
                    arch.height_rows,
                    arch.height_cols,
                    &rows.heights,
                    b,
                    &mut self.conv_tape,
                )?;
                let leaf = Tensor::<2>::from_data(
                    TensorData::new(features, [b, arch.features_len()]),
                    device,
                )
                .require_grad();
                let net = Net::with_tracking(&self.net, device, false, true)?;
                let forward = net.forward_from_features(leaf.clone(), take(&mut rows.states), b);
                Ok(TrackedForward {
                    net,
                    forward,
                    features_leaf: Some(leaf),
                })
            }
        }
    }

    /// Every parameter's gradient of `total`, in `network::parameters` order: burn's for the
    /// layers in its graph, the native kernel's for the convs when `features_leaf` stands in
    /// for them.
    fn gradients(
        &mut self,
        net: &Net,
        features_leaf: Option<Tensor<2>>,
        total: &Tensor<1>,
    ) -> Result<Vec<Vec<f32>>, TrainError> {
        let grads = total.backward();
        let mut g = net.gradients(&grads);
        if let Some(leaf) = features_leaf {
            let d_features = network::grad_vec(&leaf, &grads)
                .ok_or_else(|| TrainError::Shape("no gradient reached the conv features".into()))?;
            let conv_grads =
                conv_kernel::backward(&self.net.convs, &mut self.conv_tape, &d_features)?;
            // `parameters` order starts with each conv's weights then bias.
            for (l, cg) in conv_grads.into_iter().enumerate() {
                g[2 * l] = cg.weights;
                g[2 * l + 1] = cg.bias;
            }
        }
        Ok(g)
    }
}

/// A minibatch's forward pass with the graph its gradients come from.
struct TrackedForward {
    /// The layers burn differentiates.
    net: Net,
    /// Their outputs.
    forward: network::Forward,
    /// The conv features as a graph leaf, when the native kernel computed them.
    features_leaf: Option<Tensor<2>>,
}

impl Minibatch {
    /// The loss's per-sample inputs as tensors on `device` (the height maps and states have
    /// gone to the forward pass).
    fn loss_inputs(self, device: &Device) -> LossInputs {
        let b = self.len;
        let data1 = |v: Vec<f32>| Tensor::<1>::from_data(TensorData::new(v, [b]), device);
        let imitates = self.imitation.iter().any(|&w| w != 0.0);
        LossInputs {
            one_hot: Tensor::<3>::from_data(
                TensorData::new(self.one_hot, [b, DIMS, CHOICES]),
                device,
            ),
            old_log_probs: data1(self.old_log_probs),
            advantages: data1(self.advantages),
            returns: data1(self.returns),
            imitation: imitates.then(|| data1(self.imitation)),
        }
    }
}

/// The loss of one minibatch and its terms, on the autodiff device.
struct Loss {
    /// What Adam minimises.
    total: Tensor<1>,
    /// `-eta_PPO`: the clipped surrogate, negated.
    policy: Tensor<1>,
    /// `L_v`.
    value: Tensor<1>,
    /// The policy's entropy (its bonus is subtracted from the total).
    entropy: Tensor<1>,
    /// `log psi` of each sample, for the diagnostics.
    log_ratio: Tensor<1>,
}

/// What the loss reads besides the forward pass, one entry per sample.
struct LossInputs {
    /// `[b, DIMS, CHOICES]`: each head's action taken, one-hot.
    one_hot: Tensor<3>,
    /// `log pi_old(a|s)` from the rollout.
    old_log_probs: Tensor<1>,
    /// `A`, the advantages.
    advantages: Tensor<1>,
    /// The value targets.
    returns: Tensor<1>,
    /// Behaviour cloning weights of replayed and labelled samples; `None` when all are 0.
    imitation: Option<Tensor<1>>,
}

/// The paper's loss (the module's Eq. 1 and 2) on the forward pass `fwd` of a minibatch:
/// `lambda_1 * -eta_PPO + lambda_2 * L_v - c_H * H`, and where `imitation` weights replayed
/// samples, their behaviour cloning `-mean(w * log pi(a|s))`.
fn ppo_loss(fwd: network::Forward, inputs: LossInputs, c: &PpoConfig) -> Loss {
    let LossInputs {
        one_hot,
        old_log_probs,
        advantages,
        returns,
        imitation,
    } = inputs;
    let b = advantages.dims()[0];
    // psi = pi(a|s) / pi_old(a|s), from the sum of the five heads' log-probabilities.
    let new_lp: Tensor<1> = (fwd.log_probs.clone() * one_hot)
        .sum_dim(2)
        .sum_dim(1)
        .reshape([b]);
    let log_ratio = new_lp.clone() - old_log_probs;
    let ratio = log_ratio.clone().exp();
    // Eq. 1: min(Z(psi) A, psi A); negated because Adam minimises.
    let unclipped = ratio.clone() * advantages.clone();
    let clipped = ratio.clamp(1.0 - c.clip_epsilon, 1.0 + c.clip_epsilon) * advantages;
    let policy = unclipped.min_pair(clipped).mean().neg();
    // L_v: squared error of the value against the return target.
    let value = (fwd.values - returns).square().mean();
    // Entropy of the factorised distribution: the sum of the heads' entropies.
    let entropy = (fwd.log_probs.clone().exp() * fwd.log_probs)
        .sum_dim(2)
        .sum_dim(1)
        .mean()
        .neg();
    let mut total = policy.clone().mul_scalar(c.policy_coef)
        + value.clone().mul_scalar(c.value_coef)
        - entropy.clone().mul_scalar(c.entropy_coef);
    if let Some(weights) = imitation {
        // Behaviour cloning of replayed successes (`crate::replay`): unlike the clipped
        // surrogate, it does not fade once the critic has learnt their returns.
        total = total - (new_lp * weights).mean();
    }
    Loss {
        total,
        policy,
        value,
        entropy,
        log_ratio,
    }
}

impl Loss {
    /// The minibatch's diagnostics: the loss terms' values and the ratio's KL and clip fraction.
    fn stats(&self, clip_epsilon: f32) -> UpdateStats {
        let (approx_kl, clip_fraction) = ratio_diagnostics(
            &network::to_vec(self.log_ratio.clone().detach()),
            clip_epsilon,
        );
        let scalar = |t: &Tensor<1>| {
            network::to_vec(t.clone().detach())
                .first()
                .copied()
                .unwrap_or(f32::NAN)
        };
        UpdateStats {
            policy_loss: scalar(&self.policy),
            value_loss: scalar(&self.value),
            entropy: scalar(&self.entropy),
            approx_kl,
            clip_fraction,
            gradient_steps: 1,
            kl_stopped: false,
        }
    }
}

/// Approximate KL divergence (Schulman's k3 estimator) and the fraction of samples whose ratio
/// the clip bounds, from their `log_ratio`: diagnostics, without gradients.
fn ratio_diagnostics(log_ratio: &[f32], clip_epsilon: f32) -> (f32, f32) {
    let n = log_ratio.len() as f32;
    let approx_kl = log_ratio.iter().map(|lr| lr.exp() - 1.0 - lr).sum::<f32>() / n;
    let clip_fraction = log_ratio
        .iter()
        .filter(|lr| (lr.exp() - 1.0).abs() > clip_epsilon)
        .count() as f32
        / n;
    (approx_kl, clip_fraction)
}

/// Scales all gradients together so their joint L2 norm is at most `max_norm` (0: no clip).
/// Returns the norm before clipping.
pub fn clip_global_norm(grads: &mut [Vec<f32>], max_norm: f32) -> f32 {
    let norm = grads.iter().flatten().map(|g| g * g).sum::<f32>().sqrt();
    if max_norm > 0.0 && norm > max_norm {
        let scale = max_norm / (norm + 1e-6);
        grads.iter_mut().flatten().for_each(|g| *g *= scale);
    }
    norm
}

#[cfg(test)]
mod tests;
