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
//!   Planner demonstrations ([`crate::trajectory::demonstrations`]) count as one more
//!   behaviour.

use crate::ppo::Ppo;
use crate::storage::{Batch, RolloutStorage};
use crate::trajectory::batch_file::TrajectoryBatch;
use crate::trajectory::Origin;
use rand::Rng;
use serde::{Deserialize, Serialize};
use wheelleg_runtime::action::DIMS;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};

/// How replayed trajectories are drawn from the batch.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum ReplayBalance {
    /// Uniformly over all stored trajectories (the paper).
    #[default]
    Trajectory,
    /// A behaviour (the planner's demonstrations are one) uniformly, then one of its
    /// trajectories uniformly.
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
    /// Share of the drawn trajectories taken from the planner's demonstrations, when the
    /// batch holds any (0: they are drawn like every other origin).
    pub planner_share: f32,
}

/// Draws whole trajectories from `batch` until `options.steps` samples are gathered (the last
/// one is cut), and scores them with the current policy and value function.
pub fn replay_samples(
    ppo: &Ppo,
    batch: &TrajectoryBatch,
    options: &ReplayOptions,
    rng: &mut impl Rng,
) -> Result<Batch, String> {
    let steps = options.steps;
    let mut out = Batch::default();
    if batch.is_empty() || steps == 0 {
        return Ok(out);
    }
    let env_config = batch.env_config();
    let draw = TrajectoryDraw::new(scene_ranges_by_origin(batch), batch.len(), options);
    while out.len() < steps {
        let index = draw.next(rng);
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

/// Which stored trajectory to replay next, by [`ReplayOptions::balance`] and
/// [`ReplayOptions::planner_share`].
struct TrajectoryDraw {
    /// The share and scene ranges of the planner's demonstrations, when a share is set and
    /// the batch holds some.
    planner: Option<(f32, Vec<(usize, usize)>)>,
    /// Scene ranges of every other origin (all origins without a planner share).
    groups: Vec<Vec<(usize, usize)>>,
    /// `groups` flattened into one.
    others: Vec<(usize, usize)>,
    balance: ReplayBalance,
    len: usize,
}

impl TrajectoryDraw {
    fn new(
        by_origin: Vec<(Origin, Vec<(usize, usize)>)>,
        len: usize,
        options: &ReplayOptions,
    ) -> Self {
        let share = options.planner_share;
        let mut planner = None;
        let mut groups = Vec::new();
        for (origin, ranges) in by_origin {
            if share > 0.0 && origin == Origin::Planner {
                planner = Some((share, ranges));
            } else {
                groups.push(ranges);
            }
        }
        TrajectoryDraw {
            planner,
            others: groups.concat(),
            groups,
            balance: options.balance,
            len,
        }
    }

    fn next(&self, rng: &mut impl Rng) -> usize {
        if let Some((share, ranges)) = &self.planner {
            // Drawn only with a share, so runs without one replay exactly as before.
            if self.others.is_empty() || rng.random::<f32>() < *share {
                return draw_balanced(std::slice::from_ref(ranges), rng);
            }
        }
        match self.balance {
            ReplayBalance::Behaviour => draw_balanced(&self.groups, rng),
            ReplayBalance::Trajectory if self.planner.is_none() => rng.random_range(0..self.len),
            ReplayBalance::Trajectory => draw_balanced(std::slice::from_ref(&self.others), rng),
        }
    }
}

/// Per origin present in `batch`: its sources' scene ranges (first scene, count).
fn scene_ranges_by_origin(batch: &TrajectoryBatch) -> Vec<(Origin, Vec<(usize, usize)>)> {
    let mut groups: Vec<(Origin, Vec<(usize, usize)>)> = Vec::new();
    for source in batch.sources().iter().filter(|s| s.scenes > 0) {
        let range = (source.first_scene as usize, source.scenes as usize);
        match groups.iter_mut().find(|(o, _)| *o == source.origin) {
            Some((_, ranges)) => ranges.push(range),
            None => groups.push((source.origin, vec![range])),
        }
    }
    groups
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
    use wheelleg_sim::generate::Behaviour;

    #[test]
    fn a_planner_share_draws_that_share_from_the_demonstrations() {
        // Scenes 0..900 from two behaviours, 900..1000 from the planner.
        let by_origin = vec![
            (Origin::Secondary(Behaviour::Straight), vec![(0, 600)]),
            (Origin::Secondary(Behaviour::LiftOver), vec![(600, 300)]),
            (Origin::Planner, vec![(900, 100)]),
        ];
        let mut rng = ChaCha8Rng::seed_from_u64(4);
        for (share, balance, expected) in [
            (0.5, ReplayBalance::Behaviour, 0.5),
            (0.5, ReplayBalance::Trajectory, 0.5),
            // Without a share the planner is one more group, or one more trajectory source.
            (0.0, ReplayBalance::Behaviour, 1.0 / 3.0),
            (0.0, ReplayBalance::Trajectory, 0.1),
        ] {
            let options = ReplayOptions {
                steps: 1,
                imitation_coef: 0.0,
                balance,
                planner_share: share,
            };
            let draw = TrajectoryDraw::new(by_origin.clone(), 1000, &options);
            let draws = 20_000;
            let planned = (0..draws).filter(|_| draw.next(&mut rng) >= 900).count();
            let got = planned as f32 / draws as f32;
            assert!((got - expected).abs() < 0.02, "{share} {balance:?}: {got}");
        }
        // A share with no demonstrations in the batch draws as if none were asked for.
        let options = ReplayOptions {
            planner_share: 0.9,
            ..ReplayOptions::default()
        };
        let draw = TrajectoryDraw::new(by_origin[..2].to_vec(), 900, &options);
        assert!((0..1000).all(|_| draw.next(&mut rng) < 900));
    }

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
