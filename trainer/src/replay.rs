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
//!
//! Two options go beyond the paper (both off by default, `[curriculum]` in the config):
//! - `replay_imitation_coef`: a behaviour-cloning term on the replayed steps. The surrogate
//!   only pushes a replayed action while its advantage is positive, and the critic learns the
//!   replayed returns within a few updates; after that the rare behaviours (lift, spread,
//!   squeeze), which complex scenes seldom demand, fade from the primary policy (curriculum-s0:
//!   lift 89% as a secondary, 28% in the primary). Cloning keeps them: every replayed action
//!   is collision-free and part of a success (undone actions are never stored).
//! - `replay_balance = "behaviour"`: draw a behaviour uniformly, then one of its
//!   trajectories, so each behaviour gets an equal share however many successes it stored.

use crate::error::TrainError;
use crate::ppo::Ppo;
use crate::storage::{Batch, RolloutStorage};
use crate::trajectory::batch_file::TrajectoryBatch;
use rand::Rng;
use serde::{Deserialize, Serialize};
use wheelleg_runtime::action::DIMS;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_sim::generate::Behaviour;

/// How replayed trajectories are drawn from the batch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReplayBalance {
    /// Uniformly over all stored trajectories (the paper).
    #[default]
    Trajectory,
    /// A behaviour uniformly, then one of its trajectories uniformly.
    Behaviour,
}

/// How Algorithm 2 draws and weighs its replayed samples.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct ReplayOptions {
    /// Replayed samples per iteration.
    pub steps: usize,
    /// Weight of the behaviour-cloning term on replayed samples (0: the paper).
    pub imitation_coef: f32,
    /// How trajectories are drawn.
    pub balance: ReplayBalance,
}

/// Draws whole trajectories from `batch` until `options.steps` samples are gathered (the last
/// one is cut), and scores them with the current policy and value function.
pub fn replay_samples(
    ppo: &Ppo,
    batch: &TrajectoryBatch,
    options: &ReplayOptions,
    rng: &mut impl Rng,
) -> Result<Batch, TrainError> {
    let steps = options.steps;
    let mut out = Batch::default();
    if batch.is_empty() || steps == 0 {
        return Ok(out);
    }
    let env_config = batch.env_config()?;
    let groups = scene_ranges_by_behaviour(batch);
    while out.len() < steps {
        let index = match options.balance {
            ReplayBalance::Trajectory => rng.random_range(0..batch.len()),
            ReplayBalance::Behaviour => draw_balanced(&groups, rng),
        };
        let trajectory = batch
            .trajectory(index)
            .ok_or(TrainError::NoTrajectory { index })?;
        let replayed = trajectory
            .replay_observations(env_config)
            .map_err(|e| TrainError::stage(format!("replaying trajectory {index}"), e))?;
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
        storage.samples.imitation.fill(options.imitation_coef);
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
        imitation: batch.imitation[..n].to_vec(),
    }
}

/// Per behaviour present in `batch`, in order of first appearance: its sources' scene ranges
/// (first scene, count).
fn scene_ranges_by_behaviour(batch: &TrajectoryBatch) -> Vec<Vec<(usize, usize)>> {
    let mut groups: Vec<(Behaviour, Vec<(usize, usize)>)> = Vec::new();
    for source in batch.sources().iter().filter(|s| s.scenes > 0) {
        let range = (source.first_scene as usize, source.scenes as usize);
        match groups.iter_mut().find(|(b, _)| *b == source.behaviour) {
            Some((_, ranges)) => ranges.push(range),
            None => groups.push((source.behaviour, vec![range])),
        }
    }
    groups.into_iter().map(|(_, ranges)| ranges).collect()
}

/// A behaviour uniformly, then a scene uniformly among that behaviour's scenes.
fn draw_balanced(groups: &[Vec<(usize, usize)>], rng: &mut impl Rng) -> usize {
    let ranges = &groups[rng.random_range(0..groups.len())];
    let total: usize = ranges.iter().map(|&(_, count)| count).sum();
    let mut k = rng.random_range(0..total);
    for &(first, count) in ranges {
        if k < count {
            return first + k;
        }
        k -= count;
    }
    // Unreachable: k < total.
    ranges[0].0
}

#[cfg(test)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn balanced_draws_give_each_behaviour_an_equal_share() {
        // Behaviour A: 900 scenes in two sources; behaviour B: 100 scenes.
        let groups = vec![vec![(0, 500), (600, 400)], vec![(500, 100)]];
        let mut rng = ChaCha8Rng::seed_from_u64(9);
        let draws = 20_000;
        let mut from_b = 0;
        for _ in 0..draws {
            let index = draw_balanced(&groups, &mut rng);
            assert!(index < 1000, "drew scene {index} past the batch");
            if (500..600).contains(&index) {
                from_b += 1;
            }
        }
        let share = from_b as f32 / draws as f32;
        assert!((share - 0.5).abs() < 0.02, "behaviour B drew {share}");
    }
}
