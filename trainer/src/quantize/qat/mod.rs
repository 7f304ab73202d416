//! Quantization-aware fine-tuning (QAT) by distillation: a student copy of the float network
//! learns, through the int8 arithmetic the exporter will give it, to take the float teacher's
//! greedy actions.
//!
//! The student's forward pass is the float graph with every rounding of the exported file put
//! in (fake quantization), each through the straight-through estimator `x + (q(x) - x).detach()`
//! (the rounding is used forward, ignored backward):
//!
//! - weights and biases: the student is quantized with [`quantize`] itself, the exporter's own
//!   function, at every step, and its dequantized tensors are what the forward pass multiplies
//!   with ([`dequantize`]): symmetric per-output-channel int8 weights (the first dense layer's
//!   rows after the state columns are folded in, as the file stores them), int32 biases;
//! - inputs: height map in millimetres to its int8 grid, state features to their int16 grid
//!   (format version 2; int8 in version 1), with the runtime's own integer functions;
//! - every conv and hidden output to its calibrated int8 grid (scale and zero point, clamped to
//!   the range), the action logits to their int16 grid (version 2).
//!
//! Activation ranges come from the calibration observations run through the student's float
//! network (what the exporter will calibrate on), taken again every
//! [`QatOptions::recalibrate_every`] steps because the student's ranges drift as it trains.
//!
//! Loss: per action dimension, the KL divergence from the teacher's distribution to the
//! student's (both at [`QatOptions::temperature`]), summed over the five dimensions, with the
//! dimensions where the teacher's top two logits are close weighted up
//! ([`QatOptions::near_tie_weight`]): those are the decisions rounding flips.

use burn::tensor::activation::{log_softmax, relu};
use burn::tensor::module::conv2d;
use burn::tensor::ops::ConvOptions;
use burn::tensor::{Device, Gradients, Tensor, TensorData};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use wheelleg_runtime::action::{CHOICES, DIMS};
use wheelleg_runtime::model::quant::{quantize_mm, quantize_mm16};

use super::build::{quantize_for_version, QuantizedLayer, QuantizedNetwork};
use super::calibrate::{ActionRange, Calibration, RangeMethod};
use super::params::ActQuant;
use crate::batch_policy::FloatPolicy;
use crate::error::TrainError;
use crate::evaluate::RecordedObservation;
use crate::network::{self, to_vec};
use crate::network_f32::{DenseF32, NetworkF32, Trace};
use crate::ppo::{clip_global_norm, Adam};
use wheelleg_stack::policy::BatchPolicy;

mod ranges;
mod student;

use ranges::*;
pub use student::dequantize;
use student::*;

/// Fine-tuning steps `wheelleg export` takes by default: on the final baseline checkpoint 300
/// steps took the worst action dimension's agreement from 98.81% (plain PTQ) to 99.26%, and
/// 1,000 steps measured worse (docs/results.md, "Quantization").
pub const RECOMMENDED_STEPS: usize = 300;

/// Settings of the fine-tuning. The default takes no step (plain post-training quantization)
/// so that library callers opt in; the command line's default is [`RECOMMENDED_STEPS`].
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct QatOptions {
    /// Gradient steps (0: no fine-tuning, plain post-training quantization).
    pub steps: usize,
    /// Adam's learning rate at the first step; it decays to 0 by a half cosine over the steps
    /// so the last steps only settle the weights.
    pub learning_rate: f64,
    /// Observations per gradient step.
    pub batch: usize,
    /// Softmax temperature of both distributions in the KL (1: the policy's own).
    pub temperature: f32,
    /// Extra weight of an action dimension whose teacher margin (largest minus second-largest
    /// logit) is small: weight `1 + near_tie_weight * exp(-margin / near_tie_margin)`.
    pub near_tie_weight: f32,
    /// Margin scale of that weight, in logits (> 0).
    pub near_tie_margin: f32,
    /// Steps between two recalibrations of the activation ranges on the student.
    pub recalibrate_every: usize,
    /// Observations the student is trained on (stochastic teacher rollouts).
    pub observations: usize,
    /// Seed of the training rollouts' scenes and of the minibatch order.
    pub seed: u64,
    /// Global gradient norm limit (0: none).
    pub max_grad_norm: f32,
}

impl Default for QatOptions {
    fn default() -> Self {
        QatOptions {
            steps: 0,
            learning_rate: 1e-4,
            batch: 256,
            temperature: 1.0,
            near_tie_weight: 0.0,
            near_tie_margin: 0.1,
            recalibrate_every: 200,
            observations: 20_000,
            seed: wheelleg_sim::seeds::CALIBRATION + 2,
            max_grad_norm: 1.0,
        }
    }
}

impl QatOptions {
    /// Checks every setting, naming the bad one (and its `wheelleg export` flag).
    pub fn validate(&self) -> Result<(), TrainError> {
        let bad = |key, problem: String| Err(TrainError::setting(key, problem));
        if !(self.learning_rate.is_finite() && self.learning_rate > 0.0) {
            return bad(
                "QAT learning rate (--qat-lr)",
                format!("{} must be a positive finite number", self.learning_rate),
            );
        }
        if self.steps > 0 && self.batch == 0 {
            return bad("QAT batch (--qat-batch)", "must be at least 1".into());
        }
        if self.steps > 0 && self.observations == 0 {
            return bad(
                "QAT observations (--qat-observations)",
                "must be at least 1".into(),
            );
        }
        if !(self.temperature.is_finite() && self.temperature > 0.0) {
            return bad(
                "QAT temperature (--qat-temperature)",
                format!("{} must be positive", self.temperature),
            );
        }
        if !(self.near_tie_weight.is_finite() && self.near_tie_weight >= 0.0) {
            return bad(
                "QAT near-tie weight (--qat-near-tie-weight)",
                format!("{} must be at least 0", self.near_tie_weight),
            );
        }
        if !(self.near_tie_margin.is_finite() && self.near_tie_margin > 0.0) {
            return bad(
                "QAT near-tie margin (--qat-near-tie-margin)",
                format!("{} must be positive", self.near_tie_margin),
            );
        }
        if self.recalibrate_every == 0 {
            return bad(
                "QAT recalibration interval (--qat-recalibrate-every)",
                "must be at least 1 step".into(),
            );
        }
        if !(self.max_grad_norm.is_finite() && self.max_grad_norm >= 0.0) {
            return bad(
                "QAT gradient norm limit",
                format!("{} must be at least 0", self.max_grad_norm),
            );
        }
        Ok(())
    }
}

/// What the fine-tuning did.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct QatReport {
    /// Mean distillation loss of the first and of the last tenth of the steps.
    pub loss_first: f32,
    /// See `loss_first`.
    pub loss_last: f32,
    /// Gradient steps taken.
    pub steps: usize,
}

/// How the student will be quantized after fine-tuning (the export's settings), so that the
/// fine-tuning mirrors it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct QatSettings {
    /// Range method of every tensor.
    pub range: RangeMethod,
    /// Which logits set the action head's range.
    pub action_range: ActionRange,
    /// Weights format version (2: int16 state features and action logits).
    pub version: u16,
}

/// Fine-tunes a copy of `teacher` so that its int8 version (quantized as `settings` say, with
/// ranges from `calibration_set`) takes the teacher's greedy actions on `training_set`.
/// Deterministic given `options.seed` and the inputs.
pub fn fine_tune(
    teacher: &NetworkF32,
    device: &Device,
    calibration_set: &[RecordedObservation],
    training_set: &[RecordedObservation],
    settings: &QatSettings,
    options: &QatOptions,
) -> Result<(NetworkF32, QatReport), TrainError> {
    let (method, action_range, version) = (settings.range, settings.action_range, settings.version);
    options.validate()?;
    network::check_policy_shape(teacher)?;
    if options.steps == 0 {
        return Ok((
            teacher.clone(),
            QatReport {
                loss_first: 0.0,
                loss_last: 0.0,
                steps: 0,
            },
        ));
    }
    if calibration_set.is_empty() || training_set.is_empty() {
        return Err(TrainError::Nothing {
            what: "calibration or training observations for QAT (it needs both)",
        });
    }
    let arch = &teacher.arch;
    let cells = arch.height_rows * arch.height_cols;
    if let Some((h, s)) = training_set
        .iter()
        .chain(calibration_set)
        .find(|(h, s)| h.len() != cells || s.len() != arch.state_len)
    {
        return Err(TrainError::Shape(format!(
            "QAT observation of {} cells and {} state values; the network reads {cells} and {}",
            h.len(),
            s.len(),
            arch.state_len
        )));
    }

    // Teacher targets: log-probabilities per dimension at the distillation temperature, and
    // each dimension's weight from its margin.
    let teacher_policy = FloatPolicy::new(teacher, device)?;
    let n = training_set.len();
    let mut targets = Vec::with_capacity(n * DIMS * CHOICES);
    let mut weights = Vec::with_capacity(n * DIMS);
    for chunk in training_set.chunks(CHUNK) {
        let (heights, states) = flatten(chunk);
        let out = teacher_policy
            .log_probs(&heights, &states, chunk.len())
            .map_err(TrainError::Stack)?;
        for head in out.chunks_exact(CHOICES) {
            // Log-probabilities differ from logits by a constant per head: same margins.
            let mut sorted = head.to_vec();
            sorted.sort_by(|a, b| b.total_cmp(a));
            let margin = sorted[0] - sorted[1];
            weights.push(1.0 + options.near_tie_weight * (-margin / options.near_tie_margin).exp());
            let tempered: Vec<f32> = head.iter().map(|l| l / options.temperature).collect();
            let max = tempered.iter().copied().fold(f32::NEG_INFINITY, f32::max);
            let log_sum = tempered.iter().map(|l| (l - max).exp()).sum::<f32>().ln() + max;
            targets.extend(tempered.iter().map(|l| l - log_sum));
        }
    }
    let mut student = teacher.clone();
    let mut adam = Adam::new(&student);
    let mut calibration = calibrate_batched(&student, device, calibration_set, action_range)?;
    let (_, first) = fake_quant_params(&student, &calibration, method, version)?;
    // Input grids depend on the observations alone, not on the weights: quantize once.
    let mut heights = Vec::with_capacity(n * cells);
    let mut states = Vec::with_capacity(n * arch.state_len);
    for (h, s) in training_set {
        quantized_inputs(&first, h, s, &mut heights, &mut states);
    }

    let autodiff = device.clone().autodiff();
    let mut rng = ChaCha8Rng::seed_from_u64(options.seed);
    rng.set_stream(2);
    let batch = options.batch.min(n);
    let mut losses = Vec::with_capacity(options.steps);
    for step in 0..options.steps {
        if step > 0 && step % options.recalibrate_every == 0 {
            calibration = calibrate_batched(&student, device, calibration_set, action_range)?;
        }
        let (fq, _) = fake_quant_params(&student, &calibration, method, version)?;
        let mut batch_heights = Vec::with_capacity(batch * cells);
        let mut batch_states = Vec::with_capacity(batch * arch.state_len);
        let mut batch_targets = Vec::with_capacity(batch * DIMS * CHOICES);
        let mut batch_weights = Vec::with_capacity(batch * DIMS);
        for _ in 0..batch {
            let i = rng.random_range(0..n);
            batch_heights.extend_from_slice(&heights[i * cells..(i + 1) * cells]);
            batch_states.extend_from_slice(&states[i * arch.state_len..(i + 1) * arch.state_len]);
            batch_targets.extend_from_slice(&targets[i * DIMS * CHOICES..(i + 1) * DIMS * CHOICES]);
            batch_weights.extend_from_slice(&weights[i * DIMS..(i + 1) * DIMS]);
        }
        let graph = student_logits(&student, &fq, batch_heights, batch_states, batch, &autodiff);
        let log_q = log_softmax(
            graph
                .logits
                .clone()
                .div_scalar(options.temperature)
                .reshape([batch, DIMS, CHOICES]),
            2,
        );
        let log_p: Tensor<3> = Tensor::from_data(
            TensorData::new(batch_targets, [batch, DIMS, CHOICES]),
            &autodiff,
        );
        let weight: Tensor<2> =
            Tensor::from_data(TensorData::new(batch_weights, [batch, DIMS]), &autodiff);
        // KL(p || q) = sum p (log p - log q) per dimension; weighted, summed over the
        // dimensions, averaged over the batch. T^2 keeps the gradient's size independent of
        // the temperature (Hinton et al.).
        let kl: Tensor<2> = (log_p.clone().exp() * (log_p - log_q))
            .sum_dim(2)
            .reshape([batch, DIMS]);
        let loss = (kl * weight)
            .sum_dim(1)
            .mean()
            .mul_scalar(options.temperature * options.temperature);
        let loss_value = to_vec(loss.clone().detach())
            .first()
            .copied()
            .unwrap_or(f32::NAN);
        if !loss_value.is_finite() {
            return Err(TrainError::QatDiverged { step });
        }
        losses.push(loss_value);
        let grads = loss.backward();
        let mut g = gradients(&student, &graph, &grads);
        clip_global_norm(&mut g, options.max_grad_norm);
        let progress = step as f64 / options.steps as f64;
        let lr = options.learning_rate * 0.5 * (1.0 + (std::f64::consts::PI * progress).cos());
        adam.apply(&mut student, &g, lr, 1e-8);
    }
    let tenth = (losses.len() / 10).max(1);
    let mean = |v: &[f32]| v.iter().sum::<f32>() / v.len().max(1) as f32;
    Ok((
        student,
        QatReport {
            loss_first: mean(&losses[..tenth]),
            loss_last: mean(&losses[losses.len() - tenth..]),
            steps: losses.len(),
        },
    ))
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, clippy::indexing_slicing)]

    use super::*;
    use crate::network::BackendKind;
    use crate::network_f32::Architecture;
    use crate::quantize::{quantize, Int8Policy};
    use wheelleg_runtime::model::format::FORMAT_VERSION;

    fn observation(rng: &mut ChaCha8Rng) -> RecordedObservation {
        crate::quantize::synthetic::synthetic_observation(rng, 3.0)
    }

    fn argmax(head: &[f32]) -> usize {
        let mut best = 0;
        for (i, &v) in head.iter().enumerate() {
            if v > head[best] {
                best = i;
            }
        }
        best
    }

    /// The fake-quantized forward pass is the int8 runtime's arithmetic: its logits are far
    /// closer to the runtime's than the float network's are, and its greedy choices are the
    /// runtime's.
    #[test]
    fn fake_quantized_forward_tracks_the_int8_runtime() {
        let mut rng = ChaCha8Rng::seed_from_u64(11);
        let network = NetworkF32::random(&Architecture::default_policy(), &mut rng);
        let calibration_set: Vec<_> = (0..300).map(|_| observation(&mut rng)).collect();
        let test_set: Vec<_> = (0..300).map(|_| observation(&mut rng)).collect();
        let calibration = Calibration::from_observations(
            &network,
            calibration_set
                .iter()
                .map(|(h, s)| (h.as_slice(), s.as_slice())),
        );
        let quantized = quantize(&network, &calibration, RangeMethod::MinMax).unwrap();
        let bytes = quantized.to_bytes().unwrap();
        let int8 = Int8Policy::from_bytes(&bytes).unwrap();
        let (fq, _) =
            fake_quant_params(&network, &calibration, RangeMethod::MinMax, FORMAT_VERSION).unwrap();
        let (mut heights, mut states) = (Vec::new(), Vec::new());
        for (h, s) in &test_set {
            quantized_inputs(&quantized, h, s, &mut heights, &mut states);
        }
        let device = BackendKind::Flex.device().unwrap().autodiff();
        let graph = student_logits(&network, &fq, heights, states, test_set.len(), &device);
        let fake = to_vec(graph.logits.detach());
        let (mut fake_error, mut float_error, mut same, mut heads) = (0.0f64, 0.0f64, 0, 0);
        for (i, (h, s)) in test_set.iter().enumerate() {
            let int8_logits = int8.evaluate_m(h, s).unwrap().action_logits_f32();
            let (float_logits, _) = network.forward(h, s);
            let fake_logits = &fake[i * DIMS * CHOICES..(i + 1) * DIMS * CHOICES];
            for k in 0..DIMS * CHOICES {
                fake_error += f64::from((fake_logits[k] - int8_logits[k]).abs());
                float_error += f64::from((float_logits[k] - int8_logits[k]).abs());
            }
            for (a, b) in fake_logits
                .chunks_exact(CHOICES)
                .zip(int8_logits.chunks_exact(CHOICES))
            {
                same += usize::from(argmax(a) == argmax(b));
                heads += 1;
            }
        }
        println!(
            "mean |logit - int8 logit|: fake-quantized {:.5}, float {:.5}; greedy {same} of {heads}",
            fake_error / (test_set.len() * DIMS * CHOICES) as f64,
            float_error / (test_set.len() * DIMS * CHOICES) as f64
        );
        assert!(
            fake_error < 0.1 * float_error,
            "fake-quantized vs int8 {fake_error}, float vs int8 {float_error}"
        );
        assert!(
            same as f64 >= 0.995 * heads as f64,
            "{same} of {heads} greedy choices"
        );
    }

    #[test]
    fn bad_settings_are_refused_by_name() {
        assert!(QatOptions::default().validate().is_ok());
        let bad = |options: QatOptions, word: &str| {
            let error = options.validate().unwrap_err();
            assert!(matches!(error, TrainError::Setting { .. }), "{error}");
            assert!(error.to_string().contains(word), "{error}");
        };
        let base = QatOptions {
            steps: 10,
            ..QatOptions::default()
        };
        for lr in [0.0, -1.0, f64::NAN, f64::INFINITY] {
            bad(
                QatOptions {
                    learning_rate: lr,
                    ..base.clone()
                },
                "learning rate",
            );
        }
        bad(
            QatOptions {
                batch: 0,
                ..base.clone()
            },
            "batch",
        );
        bad(
            QatOptions {
                temperature: 0.0,
                ..base.clone()
            },
            "temperature",
        );
        bad(
            QatOptions {
                near_tie_weight: -1.0,
                ..base.clone()
            },
            "near-tie weight",
        );
        bad(
            QatOptions {
                near_tie_margin: 0.0,
                ..base.clone()
            },
            "near-tie margin",
        );
        bad(
            QatOptions {
                recalibrate_every: 0,
                ..base.clone()
            },
            "recalibration",
        );
    }
}
