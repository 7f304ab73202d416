//! Rollout storage: what `num_envs` environments saw and did over `steps_per_env` lock-step
//! steps, and the advantages and returns computed from it (GAE).
//!
//! Layout is step-major: sample `t * num_envs + e` is env `e` at step `t`. An update reads it
//! in [`Minibatch`]es.

use wheelleg_runtime::action::{CHOICES, DIMS};
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};

/// Training samples ready for a PPO update (on-policy or replayed alike).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Batch {
    /// `len * HEIGHT_MAP_CELLS` height maps, metres.
    pub heights_m: Vec<f32>,
    /// `len * STATE_LEN` robot states.
    pub states: Vec<f32>,
    /// `len * DIMS` chosen choice per action head.
    pub actions: Vec<u8>,
    /// `len` log-probabilities of the actions under the policy that sampled them.
    pub old_log_probs: Vec<f32>,
    /// `len` advantages.
    pub advantages: Vec<f32>,
    /// `len` return targets of the value function.
    pub returns: Vec<f32>,
    /// `len` weights of the imitation term (`-weight * log pi(a|s)`): zero for on-policy
    /// samples, `curriculum.replay_imitation_coef` for replayed ones (see `crate::replay`).
    pub imitation: Vec<f32>,
}

impl Batch {
    /// Number of samples.
    pub fn len(&self) -> usize {
        self.old_log_probs.len()
    }

    /// Whether there are no samples.
    pub fn is_empty(&self) -> bool {
        self.old_log_probs.is_empty()
    }

    /// Appends another batch (Algorithm 2 concatenates on-policy and replayed samples).
    pub fn extend(&mut self, other: &Batch) {
        self.heights_m.extend_from_slice(&other.heights_m);
        self.states.extend_from_slice(&other.states);
        self.actions.extend_from_slice(&other.actions);
        self.old_log_probs.extend_from_slice(&other.old_log_probs);
        self.advantages.extend_from_slice(&other.advantages);
        self.returns.extend_from_slice(&other.returns);
        self.imitation.extend_from_slice(&other.imitation);
    }
}

/// One iteration's rollout.
#[derive(Clone, Debug)]
pub struct RolloutStorage {
    /// Lock-step environments.
    pub num_envs: usize,
    /// Steps each environment takes.
    pub steps_per_env: usize,
    /// Samples stored so far.
    len: usize,
    /// Observations, actions and old log-probabilities, as in [`Batch`].
    pub samples: Batch,
    /// `len` rewards.
    pub rewards: Vec<f32>,
    /// `len` whether the episode ended with this step.
    pub dones: Vec<bool>,
    /// `len` value estimates of the observations.
    pub values: Vec<f32>,
}

impl RolloutStorage {
    /// Empty storage with room for `num_envs * steps_per_env` samples.
    pub fn new(num_envs: usize, steps_per_env: usize) -> Self {
        let n = num_envs * steps_per_env;
        RolloutStorage {
            num_envs,
            steps_per_env,
            len: 0,
            samples: Batch {
                heights_m: Vec::with_capacity(n * HEIGHT_MAP_CELLS),
                states: Vec::with_capacity(n * STATE_LEN),
                actions: Vec::with_capacity(n * DIMS),
                old_log_probs: Vec::with_capacity(n),
                advantages: Vec::with_capacity(n),
                returns: Vec::with_capacity(n),
                imitation: Vec::with_capacity(n),
            },
            rewards: Vec::with_capacity(n),
            dones: Vec::with_capacity(n),
            values: Vec::with_capacity(n),
        }
    }

    /// Forgets the samples, keeping the allocations.
    pub fn clear(&mut self) {
        self.len = 0;
        let s = &mut self.samples;
        for v in [
            &mut s.heights_m,
            &mut s.states,
            &mut s.old_log_probs,
            &mut s.advantages,
            &mut s.returns,
            &mut s.imitation,
        ] {
            v.clear();
        }
        s.actions.clear();
        self.rewards.clear();
        self.dones.clear();
        self.values.clear();
    }

    /// Whether every step slot is filled.
    pub fn is_full(&self) -> bool {
        self.len == self.num_envs * self.steps_per_env
    }

    /// Stores one lock-step of all environments: the observations they acted on, the actions,
    /// their log-probabilities and values, and the step's rewards and episode ends.
    #[allow(clippy::too_many_arguments)]
    pub fn push_step(
        &mut self,
        heights_m: &[f32],
        states: &[f32],
        actions: &[u8],
        log_probs: &[f32],
        values: &[f32],
        rewards: &[f32],
        dones: &[bool],
    ) {
        let s = &mut self.samples;
        s.heights_m.extend_from_slice(heights_m);
        s.states.extend_from_slice(states);
        s.actions.extend_from_slice(actions);
        s.old_log_probs.extend_from_slice(log_probs);
        s.imitation
            .extend(std::iter::repeat_n(0.0, log_probs.len()));
        self.values.extend_from_slice(values);
        self.rewards.extend_from_slice(rewards);
        self.dones.extend_from_slice(dones);
        self.len += self.num_envs;
    }

    /// Generalised advantage estimation, a backwards loop over the steps of each env:
    ///
    /// - `delta_t = r_t + gamma * V(s_{t+1}) * (1 - done_t) - V(s_t)` (one-step TD error;
    ///   `V(s_{t+1})` of the last step is `last_values`, the value of the observation the env
    ///   holds after the rollout);
    /// - `A_t = delta_t + gamma * lambda * (1 - done_t) * A_{t+1}`;
    /// - `R_t = A_t + V(s_t)`, the value target.
    ///
    /// With `lambda = 1` this is the paper's `A_t = R_t - V(s_t)` with `R_t` the discounted
    /// return (bootstrapped at the rollout's cut).
    pub fn compute_returns(&mut self, last_values: &[f32], gamma: f32, lambda: f32) {
        let n = self.num_envs;
        let steps = self.len / n;
        let mut advantages = vec![0.0f32; self.len];
        for (e, &last_value) in last_values.iter().enumerate().take(n) {
            let mut next_advantage = 0.0;
            let mut next_value = last_value;
            for t in (0..steps).rev() {
                let i = t * n + e;
                let not_done = if self.dones[i] { 0.0 } else { 1.0 };
                let delta = self.rewards[i] + gamma * next_value * not_done - self.values[i];
                next_advantage = delta + gamma * lambda * not_done * next_advantage;
                advantages[i] = next_advantage;
                next_value = self.values[i];
            }
        }
        self.samples.returns = advantages
            .iter()
            .zip(&self.values)
            .map(|(a, v)| a + v)
            .collect();
        self.samples.advantages = advantages;
    }
}

/// The samples of one minibatch, gathered from a rollout [`Batch`] for the loss.
pub struct Minibatch {
    /// Samples.
    pub len: usize,
    /// `[len, HEIGHT_MAP_CELLS]`: the height maps, metres.
    pub heights: Vec<f32>,
    /// `[len, STATE_LEN]`: the states.
    pub states: Vec<f32>,
    /// `[len, DIMS, CHOICES]`: each head's action taken, one-hot.
    pub one_hot: Vec<f32>,
    /// The rollout's log-probability of each action taken.
    pub old_log_probs: Vec<f32>,
    /// The advantages, normalised over the minibatch where asked.
    pub advantages: Vec<f32>,
    /// The value targets.
    pub returns: Vec<f32>,
    /// The clone term's weight of each sample (0 for on-policy samples).
    pub imitation: Vec<f32>,
}

impl Minibatch {
    /// The samples `idx` of `batch`, the advantages normalised over the minibatch when
    /// `normalize_advantages`.
    pub fn gather(batch: &Batch, idx: &[usize], normalize_advantages: bool) -> Minibatch {
        let b = idx.len();
        let mut rows = Minibatch {
            len: b,
            heights: Vec::with_capacity(b * HEIGHT_MAP_CELLS),
            states: Vec::with_capacity(b * STATE_LEN),
            one_hot: vec![0.0f32; b * DIMS * CHOICES],
            old_log_probs: Vec::with_capacity(b),
            advantages: Vec::with_capacity(b),
            returns: Vec::with_capacity(b),
            imitation: Vec::with_capacity(b),
        };
        for (k, &i) in idx.iter().enumerate() {
            rows.heights.extend_from_slice(
                &batch.heights_m[i * HEIGHT_MAP_CELLS..(i + 1) * HEIGHT_MAP_CELLS],
            );
            rows.states
                .extend_from_slice(&batch.states[i * STATE_LEN..(i + 1) * STATE_LEN]);
            for h in 0..DIMS {
                rows.one_hot[(k * DIMS + h) * CHOICES + batch.actions[i * DIMS + h] as usize] = 1.0;
            }
            rows.old_log_probs.push(batch.old_log_probs[i]);
            rows.advantages.push(batch.advantages[i]);
            rows.returns.push(batch.returns[i]);
            rows.imitation
                .push(batch.imitation.get(i).copied().unwrap_or(0.0));
        }
        if normalize_advantages {
            let adv = &mut rows.advantages;
            let mean = adv.iter().sum::<f32>() / b as f32;
            let var = adv.iter().map(|a| (a - mean) * (a - mean)).sum::<f32>() / (b as f32 - 1.0);
            let std = var.sqrt() + 1e-8;
            adv.iter_mut().for_each(|a| *a = (*a - mean) / std);
        }
        rows
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn storage_with(rewards: &[f32], dones: &[bool], values: &[f32]) -> RolloutStorage {
        let mut s = RolloutStorage::new(1, rewards.len());
        for i in 0..rewards.len() {
            s.push_step(
                &[0.0; HEIGHT_MAP_CELLS],
                &[0.0; STATE_LEN],
                &[1; DIMS],
                &[0.0],
                &values[i..=i],
                &rewards[i..=i],
                &dones[i..=i],
            );
        }
        s
    }

    #[test]
    fn lambda_one_gives_discounted_return_minus_value() {
        let mut s = storage_with(&[1.0, 2.0, 3.0], &[false, false, true], &[0.5, 0.25, 0.125]);
        s.compute_returns(&[100.0], 0.5, 1.0);
        // R_2 = 3, R_1 = 2 + 0.5*3 = 3.5, R_0 = 1 + 0.5*3.5 = 2.75 (episode ended: no bootstrap)
        assert_eq!(s.samples.returns, vec![2.75, 3.5, 3.0]);
        assert_eq!(s.samples.advantages, vec![2.25, 3.25, 2.875]);
    }

    #[test]
    fn unfinished_episodes_bootstrap_from_the_last_value() {
        let mut s = storage_with(&[1.0], &[false], &[0.0]);
        s.compute_returns(&[2.0], 0.5, 0.95);
        assert_eq!(s.samples.returns, vec![2.0]);
    }
}
