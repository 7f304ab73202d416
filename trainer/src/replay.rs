//! Algorithm 2's replayed samples: steps drawn from the domain-randomized trajectory batch,
//! re-rendered by replaying their actions, with advantages recomputed by the current value
//! function before every update (paper: "the advantages of the sampled trajectories are
//! re-estimated with the current critic").
//!
//! A replayed step's `old_log_prob` is the current policy's log-probability of the stored
//! action: the trajectory was produced by another policy (a secondary one, in another scene),
//! so there is no behaviour-policy probability to correct with. With the ratio starting at 1,
//! PPO's clip then bounds how far one update moves towards those actions, exactly as for
//! on-policy samples; without it the rare replayed actions would get unbounded ratios.

use crate::ppo::Ppo;
use crate::storage::{Batch, RolloutStorage};
use crate::trajectory::batch_file::TrajectoryBatch;
use rand::Rng;
use wheelleg_runtime::action::DIMS;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};

/// Draws whole trajectories uniformly from `batch` until `steps` samples are gathered (the
/// last one is cut), and scores them with the current policy and value function.
pub fn replay_samples(
    ppo: &Ppo,
    batch: &TrajectoryBatch,
    steps: usize,
    rng: &mut impl Rng,
) -> Result<Batch, String> {
    let mut out = Batch::default();
    if batch.is_empty() || steps == 0 {
        return Ok(out);
    }
    let env_config = batch.env_config();
    while out.len() < steps {
        let index = rng.random_range(0..batch.len());
        let trajectory = batch
            .trajectory(index)
            .ok_or_else(|| format!("trajectory batch has no trajectory {index}"))?;
        let replayed = trajectory
            .replay_observations(env_config)
            .map_err(|e| format!("replaying trajectory {index}: {e}"))?;
        let n = replayed.len();
        if n == 0 {
            continue;
        }
        let mut heights = Vec::with_capacity(n * HEIGHT_MAP_CELLS);
        let mut states = Vec::with_capacity(n * STATE_LEN);
        let mut actions = Vec::with_capacity(n * DIMS);
        for step in &replayed {
            heights.extend_from_slice(&step.observation.height_map);
            states.extend_from_slice(&step.observation.state);
            actions.extend(step.action.head_indices().map(|i| i as u8));
        }
        let scored = ppo.evaluate(&heights, &states, n)?;
        let log_probs: Vec<f32> = (0..n)
            .map(|i| scored.action_log_prob(i, &actions[i * DIMS..(i + 1) * DIMS]))
            .collect();
        // One trajectory is one environment's rollout: the same GAE as on-policy samples.
        let mut storage = RolloutStorage::new(1, n);
        for (i, step) in replayed.iter().enumerate() {
            storage.push_step(
                &heights[i * HEIGHT_MAP_CELLS..(i + 1) * HEIGHT_MAP_CELLS],
                &states[i * STATE_LEN..(i + 1) * STATE_LEN],
                &actions[i * DIMS..(i + 1) * DIMS],
                &log_probs[i..=i],
                &scored.values[i..=i],
                &[step.reward],
                &[step.done],
            );
        }
        // A stored trajectory ends in success, a terminal state: nothing to bootstrap.
        storage.compute_returns(&[0.0], ppo.config.gamma, ppo.config.gae_lambda);
        let take = (steps - out.len()).min(n);
        out.extend(&truncate(&storage.samples, take));
    }
    Ok(out)
}

/// The first `n` samples of `batch`.
fn truncate(batch: &Batch, n: usize) -> Batch {
    Batch {
        heights_m: batch.heights_m[..n * HEIGHT_MAP_CELLS].to_vec(),
        states: batch.states[..n * STATE_LEN].to_vec(),
        actions: batch.actions[..n * DIMS].to_vec(),
        old_log_probs: batch.old_log_probs[..n].to_vec(),
        advantages: batch.advantages[..n].to_vec(),
        returns: batch.returns[..n].to_vec(),
    }
}
