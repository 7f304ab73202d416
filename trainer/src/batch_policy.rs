//! A policy run on a batch of observations, whatever it is made of: the float network (burn, as
//! trained) or the int8 network (the robot's `wheelleg_runtime`, as shipped). Evaluation and
//! calibration rollouts take either, so what is measured for a weights file is what the robot
//! runs.

use crate::network::{to_vec, Net};
use crate::network_f32::NetworkF32;
use crate::ppo::PolicyOutput;
use crate::quantize::EvalPolicy;
use burn::tensor::Device;
use wheelleg_runtime::action::{CHOICES, DIMS};

/// A policy that maps a batch of observations to per-head log-probabilities.
pub trait BatchPolicy {
    /// `n` observations (`heights_m`: `n` row-major height maps in metres; `states`: `n` state
    /// vectors) to a [`PolicyOutput`] with `n * DIMS * CHOICES` log-probabilities (no values).
    fn log_probs(
        &self,
        heights_m: &[f32],
        states: &[f32],
        n: usize,
    ) -> Result<PolicyOutput, String>;

    /// A short name for reports: `float` or `int8`.
    fn kind(&self) -> &'static str;
}

/// The float network as trained, batched through burn.
pub struct FloatPolicy {
    net: Net,
}

impl FloatPolicy {
    /// Copies `network` to `device` for inference.
    pub fn new(network: &NetworkF32, device: &Device) -> Result<FloatPolicy, String> {
        Ok(FloatPolicy {
            net: Net::new(network, device, false)?,
        })
    }
}

impl BatchPolicy for FloatPolicy {
    fn log_probs(
        &self,
        heights_m: &[f32],
        states: &[f32],
        n: usize,
    ) -> Result<PolicyOutput, String> {
        let forward = self.net.forward(heights_m.to_vec(), states.to_vec(), n);
        Ok(PolicyOutput {
            log_probs: to_vec(forward.log_probs),
            values: vec![],
        })
    }

    fn kind(&self) -> &'static str {
        "float"
    }
}

impl BatchPolicy for EvalPolicy<'_> {
    fn log_probs(
        &self,
        heights_m: &[f32],
        states: &[f32],
        n: usize,
    ) -> Result<PolicyOutput, String> {
        let cells = heights_m.len() / n.max(1);
        let state_len = states.len() / n.max(1);
        let mut log_probs = Vec::with_capacity(n * DIMS * CHOICES);
        for i in 0..n {
            let outputs = self
                .evaluate_m(
                    &heights_m[i * cells..(i + 1) * cells],
                    &states[i * state_len..(i + 1) * state_len],
                )
                .map_err(|e| format!("int8 policy: {e:?}"))?;
            // The robot acts on the argmax of the integer logits; sampling (stochastic evaluation)
            // needs probabilities, so the dequantized logits go through a log-softmax per head,
            // which keeps the argmax.
            for head in outputs.action_logits_f32().chunks_exact(CHOICES) {
                let max = head.iter().copied().fold(f32::NEG_INFINITY, f32::max);
                let log_sum = head.iter().map(|&l| (l - max).exp()).sum::<f32>().ln() + max;
                log_probs.extend(head.iter().map(|&l| l - log_sum));
            }
        }
        Ok(PolicyOutput {
            log_probs,
            values: vec![],
        })
    }

    fn kind(&self) -> &'static str {
        "int8"
    }
}

/// Wants to drive forward above all, then sideways to the left; keeps everything else. A
/// policy whose every choice a test can name.
#[cfg(test)]
pub(crate) struct Fixated;

#[cfg(test)]
impl BatchPolicy for Fixated {
    fn log_probs(&self, _: &[f32], _: &[f32], n: usize) -> Result<PolicyOutput, String> {
        let mut one = Vec::new();
        one.extend([-9.0, -6.0, -0.01f32]); // move x: forward
        one.extend([-9.0, -0.1, -3.0]); // move y: keep, else left
        for _ in 2..DIMS {
            one.extend([-9.0, -0.01, -9.0]); // keep
        }
        Ok(PolicyOutput {
            log_probs: one.repeat(n),
            values: vec![],
        })
    }

    fn kind(&self) -> &'static str {
        "fixed"
    }
}
