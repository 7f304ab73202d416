//! A policy run on a batch of observations, whatever it is made of: the int8 network (the
//! robot's `wheelleg_runtime`, as shipped) here, the float network as trained in the trainer.
//! Evaluation takes either, so what is measured for a weights file is what the robot runs.

use rand::Rng;
use wheelleg_runtime::action::{CHOICES, DIMS};
use wheelleg_runtime::model::{Policy, Scratch};

/// Log-probabilities of one observation: `DIMS` heads of `CHOICES` each.
pub const LOG_PROBS: usize = DIMS * CHOICES;

/// A policy that maps a batch of observations to per-head log-probabilities.
pub trait BatchPolicy: Sync {
    /// `n` observations (`heights_m`: `n` row-major height maps in metres; `states`: `n` state
    /// vectors) to `n * LOG_PROBS` log-probabilities, head by head.
    fn log_probs(&self, heights_m: &[f32], states: &[f32], n: usize) -> Result<Vec<f32>, String>;

    /// A short name for reports: `float` or `int8`.
    fn kind(&self) -> &'static str;
}

/// The runtime's int8 policy with buffers large enough for any architecture the trainer is
/// likely to try (64 KiB activations, 8 Ki-element rows): evaluation on the host, not the
/// robot.
pub type Int8Policy<'a> = Policy<'a, 65_536, 8_192>;

impl BatchPolicy for Int8Policy<'_> {
    fn log_probs(&self, heights_m: &[f32], states: &[f32], n: usize) -> Result<Vec<f32>, String> {
        let cells = heights_m.len() / n.max(1);
        let state_len = states.len() / n.max(1);
        let mut log_probs = Vec::with_capacity(n * LOG_PROBS);
        // One set of buffers for the batch: zeroing them per observation (over 250 KiB) took
        // about 6 % of the look-ahead's rollouts (docs/model.md).
        let mut scratch = Box::new(Scratch::new());
        let mut heights_mm = vec![0i16; cells];
        for i in 0..n {
            let outputs = self
                .evaluate_m_with(
                    &mut scratch,
                    &mut heights_mm,
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
        Ok(log_probs)
    }

    fn kind(&self) -> &'static str {
        "int8"
    }
}

/// One choice per head drawn from one observation's `log_probs` (inverse CDF on one uniform
/// draw per head): the training rule.
pub fn sample_heads(log_probs: &[f32], rng: &mut impl Rng) -> [u8; DIMS] {
    let mut out = [0u8; DIMS];
    for (slot, head) in out.iter_mut().zip(log_probs.chunks_exact(CHOICES)) {
        let u: f32 = rng.random();
        let mut acc = 0.0;
        let mut choice = CHOICES - 1;
        for (c, &log_p) in head.iter().enumerate() {
            acc += log_p.exp();
            if u < acc {
                choice = c;
                break;
            }
        }
        *slot = choice as u8;
    }
    out
}

/// Each head's most probable choice in one observation's `log_probs` (the first of equals).
pub fn greedy_heads(log_probs: &[f32]) -> [u8; DIMS] {
    let mut out = [0u8; DIMS];
    for (slot, head) in out.iter_mut().zip(log_probs.chunks_exact(CHOICES)) {
        let mut best = 0;
        for c in 1..head.len() {
            if head[c] > head[best] {
                best = c;
            }
        }
        *slot = best as u8;
    }
    out
}

/// Wants to drive forward above all, then sideways to the left; keeps everything else. A
/// policy whose every choice a test can name.
#[derive(Clone, Copy, Debug, Default)]
pub struct Fixated;

impl BatchPolicy for Fixated {
    fn log_probs(&self, _: &[f32], _: &[f32], n: usize) -> Result<Vec<f32>, String> {
        let mut one = Vec::with_capacity(LOG_PROBS);
        one.extend([-9.0, -6.0, -0.01f32]); // move x: forward
        one.extend([-9.0, -0.1, -3.0]); // move y: keep, else left
        for _ in 2..DIMS {
            one.extend([-9.0, -0.01, -9.0]); // keep
        }
        Ok(one.repeat(n))
    }

    fn kind(&self) -> &'static str {
        "fixed"
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;

    #[test]
    fn greedy_takes_each_heads_most_probable_and_sampling_follows_the_odds() {
        let log_probs = Fixated.log_probs(&[], &[], 1).unwrap();
        assert_eq!(greedy_heads(&log_probs), [2, 1, 1, 1, 1]);
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(0);
        let forward = (0..1_000)
            .filter(|_| sample_heads(&log_probs, &mut rng)[0] == 2)
            .count();
        // exp(-0.01) = 99.0 % of the draws.
        assert!((970..=1_000).contains(&forward), "{forward}");
    }
}
