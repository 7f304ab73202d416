//! One candidate's rollout: the perceived episode after the candidate, run in lock-step with
//! the others under the robot's rule, and what its outcome costs.

use crate::policy::{BatchPolicy, LOG_PROBS};
use crate::rule::{mark_taken, RobotRule};
use wheelleg_runtime::action::{Action, ActionLattice};
use wheelleg_runtime::arrival::Arrival;
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_runtime::observation::STATE_LEN;
use wheelleg_sim::env::{Env, Observation, Status};

/// The policy's inputs for a batch of episodes, with each observation's key.
struct PolicyInputs {
    heights: Vec<f32>,
    states: Vec<f32>,
    keys: Vec<ObservationKey>,
}

impl PolicyInputs {
    fn of<'a>(envs: impl Iterator<Item = &'a Env>) -> PolicyInputs {
        let mut obs = Observation::default();
        let mut inputs = PolicyInputs {
            heights: Vec::new(),
            states: Vec::new(),
            keys: Vec::new(),
        };
        for env in envs {
            env.observe(&mut obs);
            inputs
                .keys
                .push(ObservationKey::of_metres(&obs.height_map, &obs.state));
            inputs.heights.extend_from_slice(&obs.height_map);
            inputs.states.extend_from_slice(&obs.state);
        }
        inputs
    }

    fn state(&self, k: usize) -> &[f32] {
        &self.states[k * STATE_LEN..(k + 1) * STATE_LEN]
    }

    fn logits<'a>(&self, log_probs: &'a [f32], k: usize) -> Result<&'a [f32; LOG_PROBS], String> {
        log_probs
            .get(k * LOG_PROBS..(k + 1) * LOG_PROBS)
            .and_then(|l| l.try_into().ok())
            .ok_or_else(|| "the policy returned too few log-probabilities".to_string())
    }
}

/// The robot's rule without its guard (the perceived scene refuses what the guard would):
/// the untried rule, with the arrival rule at `success_radius_m` where `arrival` is on.
fn rule_action(
    decider: &mut Decider,
    key: ObservationKey,
    logits: &[f32; LOG_PROBS],
    state: &[f32],
    arrival: bool,
    success_radius_m: f32,
    lattice: &ActionLattice,
) -> Action {
    RobotRule {
        guard: None,
        arrival: arrival.then(|| Arrival::from_state_m(state, success_radius_m, lattice)),
    }
    .choose(decider, key, logits)
}

/// One candidate's rollout: the perceived episode after the candidate, and the decider that
/// goes on from the robot's.
#[derive(Clone, Debug)]
pub struct Rollout {
    /// The perceived episode, already stepped by the candidate.
    pub env: Env,
    /// The decision rule's memory, as the robot's would be after the candidate.
    pub decider: Decider,
    /// The episode's step count at the decision weighed.
    pub decision_step: u32,
    /// Steps since the decision that the perceived scene refused (not counted).
    pub refused_steps: u32,
    /// The actions taken since the decision that the perceived scene did not refuse (the
    /// candidate always).
    pub actions: Vec<Action>,
}

impl Rollout {
    /// A rollout of `env` from the decision at hand, with the rule's memory `decider`.
    pub fn new(env: Env, decider: Decider) -> Rollout {
        Rollout {
            decision_step: env.steps(),
            env,
            decider,
            refused_steps: 0,
            actions: Vec::new(),
        }
    }

    /// Takes the candidate `action` at the observation `key`: stepped and marked taken as if
    /// the rule had chosen it. Counted even where the perceived scene refuses it: the guard
    /// passed it, so the robot takes it.
    pub(super) fn take_candidate(
        &mut self,
        key: ObservationKey,
        action: Action,
    ) -> Result<(), String> {
        self.env
            .step(action)
            .map_err(|_| "stepped a finished episode".to_string())?;
        self.actions.push(action);
        mark_taken(&mut self.decider, key, action);
        Ok(())
    }
}

/// The cost of a rollout that ended (or was cut at the horizon) after `steps` steps that the
/// world did not refuse: those steps when it arrived; otherwise more than any arrival within
/// the horizon, plus the straight steps from the nearest point it reached (`nearest_m` from
/// the target), so that of two rollouts that do not arrive the one that came nearer is
/// preferred. The nearest point, not the last: a rollout that drives past the target ends as
/// far away as one that never came near. Straight steps are `move_step_m` long.
pub fn rollout_cost(
    status: Status,
    steps: u32,
    horizon_steps: u32,
    nearest_m: f32,
    move_step_m: f32,
) -> f32 {
    if status == Status::Success {
        steps as f32
    } else {
        let to_go = if nearest_m.is_finite() {
            nearest_m / move_step_m
        } else {
            f32::MAX / 4.0
        };
        2.0 * horizon_steps as f32 + to_go
    }
}

/// Whether a [`rollout_cost`] is that of a rollout that arrived.
pub fn arrives(cost: f32, horizon_steps: u32) -> bool {
    cost <= horizon_steps as f32
}

/// Runs `rollouts` in lock-step with `policy` under the robot's rule without a guard, with
/// the arrival rule at `success_radius_m` when `arrival`, until each
/// ends or has taken `horizon_steps` steps counting the candidate. Returns each one's
/// [`rollout_cost`].
///
/// A step the perceived scene refuses (it would collide there) is stepped, so the rule moves
/// on to its next choice, but not counted: the robot runs the guard, which refuses such an
/// action before it is sent and takes the next choice in the same decision.
///
/// `groups[i]` names the decision rollout `i` weighs. A rollout that can no longer arrive as
/// soon as one of its group already has (its steps so far plus the fewest it still needs at
/// the longest step, [`steps_still_needed`]) is stopped there, and costs that bound: it can
/// no longer be chosen ([`best_candidate`] takes the least cost, ties to the first), and the
/// group has a rollout that arrives, so what is chosen is the same as had it run on. Most of
/// the steps of the rollouts that do not arrive are spared that way. Likewise where
/// `to_beat[g]` holds a cost that group `g`'s rollouts matter only under (a kept way's, which
/// stands against any rollout no shorter): a rollout whose bound reaches it is stopped there.
pub fn rollout_costs(
    policy: &dyn BatchPolicy,
    rollouts: &mut [Rollout],
    groups: &[usize],
    to_beat: &[Option<u32>],
    horizon_steps: u32,
    arrival: bool,
    success_radius_m: f32,
) -> Result<Vec<f32>, String> {
    if groups.len() != rollouts.len() {
        return Err("a rollout without its decision".to_string());
    }
    let taken = |r: &Rollout| r.env.steps() - r.decision_step;
    // The steps a rollout's cost counts: all since the decision but those refused.
    let counted = |r: &Rollout| taken(r) - r.refused_steps;
    let mut nearest_m: Vec<f32> = rollouts
        .iter()
        .map(|r| r.env.distance_to_target_m())
        .collect();
    let group_count = groups.iter().max().map_or(0, |&g| g + 1);
    // By group, the fewest steps a rollout of it arrived in so far.
    let mut best_arrived: Vec<Option<u32>> = vec![None; group_count];
    // By group, the least bound that stops a rollout: one more than an arrival (a tie may
    // still be chosen, by preference), or the cost to beat (a tie loses to the kept way).
    let bar = |best_arrived: &[Option<u32>], g: usize| {
        let arrived = best_arrived[g].map(|best| best + 1);
        match (arrived, to_beat.get(g).copied().flatten()) {
            (Some(a), Some(b)) => Some(a.min(b)),
            (a, b) => a.or(b),
        }
    };
    // By rollout, the bound it was stopped at.
    let mut stopped: Vec<Option<u32>> = vec![None; rollouts.len()];
    loop {
        for (i, r) in rollouts.iter().enumerate() {
            if r.env.status() == Status::Success {
                let steps = counted(r);
                let best = &mut best_arrived[groups[i]];
                *best = Some(best.map_or(steps, |b| b.min(steps)));
            }
        }
        for (i, r) in rollouts.iter().enumerate() {
            if stopped[i].is_some() || r.env.status().is_done() {
                continue;
            }
            let at_least = counted(r) + steps_still_needed(&r.env);
            if bar(&best_arrived, groups[i]).is_some_and(|bar| at_least >= bar) {
                stopped[i] = Some(at_least);
            }
        }
        let running: Vec<usize> = (0..rollouts.len())
            .filter(|&i| {
                stopped[i].is_none()
                    && !rollouts[i].env.status().is_done()
                    && taken(&rollouts[i]) < horizon_steps
            })
            .collect();
        if running.is_empty() {
            break;
        }
        let inputs = PolicyInputs::of(running.iter().map(|&i| &rollouts[i].env));
        let log_probs = policy.log_probs(&inputs.heights, &inputs.states, running.len())?;
        for (k, &i) in running.iter().enumerate() {
            let logits = inputs.logits(&log_probs, k)?;
            let rollout = &mut rollouts[i];
            let action = rule_action(
                &mut rollout.decider,
                inputs.keys[k],
                logits,
                inputs.state(k),
                arrival,
                success_radius_m,
                rollout.env.lattice(),
            );
            let outcome = rollout
                .env
                .step(action)
                .map_err(|_| "stepped a finished rollout".to_string())?;
            if outcome.invalid.is_some() {
                rollout.refused_steps += 1;
            } else {
                rollout.actions.push(action);
            }
            nearest_m[i] = nearest_m[i].min(rollout.env.distance_to_target_m());
        }
    }
    let costs = rollouts
        .iter()
        .zip(&nearest_m)
        .zip(&stopped)
        .map(|((r, &nearest_m), &stopped)| match stopped {
            Some(at_least) => at_least as f32,
            None => rollout_cost(
                r.env.status(),
                counted(r),
                horizon_steps,
                nearest_m,
                r.env.lattice().move_step_m,
            ),
        })
        .collect();
    Ok(costs)
}

/// The fewest further counted steps in which a running episode `env` can arrive: at least one,
/// and at least its distance beyond the success radius at the longest step (a diagonal move;
/// no step moves the body centre further, and a refused one does not move it).
pub fn steps_still_needed(env: &Env) -> u32 {
    // The slack keeps this a bound where the distance and the division round.
    let longest_step_m = env.lattice().move_step_m * core::f32::consts::SQRT_2 * (1.0 + 1.0e-3);
    let beyond_m = env.distance_to_target_m() - env.config().success_radius_m;
    let steps = (beyond_m / longest_step_m).floor();
    if steps.is_finite() && steps > 1.0 {
        steps.min(u32::MAX as f32 / 4.0) as u32
    } else {
        1
    }
}

/// The candidate to take: the first (the policy's preference) of those with the least cost.
/// `None` for no candidates.
pub fn best_candidate(costs: &[f32]) -> Option<usize> {
    let mut best: Option<(usize, f32)> = None;
    for (i, &cost) in costs.iter().enumerate() {
        if best.is_none_or(|(_, c)| cost < c) {
            best = Some((i, cost));
        }
    }
    best.map(|(i, _)| i)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_arriving_rollout_costs_its_steps_and_beats_any_that_does_not() {
        let arrived = rollout_cost(Status::Success, 39, 40, 0.0, 0.05);
        let near = rollout_cost(Status::Running, 40, 40, 0.06, 0.05);
        let far = rollout_cost(Status::StepLimit, 12, 40, 0.8, 0.05);
        assert_eq!(arrived, 39.0);
        assert!(arrived < near && near < far, "{arrived} {near} {far}");
        assert!(rollout_cost(Status::TooFar, 3, 40, f32::NAN, 0.05).is_finite());
        assert!(arrives(arrived, 40) && !arrives(near, 40) && !arrives(far, 40));
    }

    /// Rollouts of the rule's first 6 candidates far from the target on open ground, with a
    /// policy that drives forward: their costs, and the steps they took in all.
    fn far_rollouts(to_beat: Option<u32>) -> (Vec<f32>, u32) {
        use crate::policy::Fixated;
        use crate::rule::candidates;
        use nalgebra::Point2;
        use wheelleg_sim::env::EnvConfig;
        use wheelleg_sim::scenario::Scenario;
        use wheelleg_sim::state::RobotState;
        let scenario = Scenario {
            name: "far-ahead".into(),
            start: RobotState::new(Point2::new(0.0, 0.125), 0, &ActionLattice::PAPER),
            target: Point2::new(0.9, 0.125),
            obstacles: vec![],
        };
        let env = Env::new(&scenario, EnvConfig::default()).unwrap();
        let inputs = PolicyInputs::of(std::iter::once(&env));
        let log_probs = Fixated
            .log_probs(&inputs.heights, &inputs.states, 1)
            .unwrap();
        let logits = inputs.logits(&log_probs, 0).unwrap();
        let decider = Decider::new();
        let found = candidates(&decider, 6, |d| {
            rule_action(
                d,
                inputs.keys[0],
                logits,
                inputs.state(0),
                false,
                0.0,
                &ActionLattice::PAPER,
            )
        });
        let mut rollouts: Vec<Rollout> = found
            .iter()
            .map(|&action| {
                let mut rollout = Rollout::new(env.clone(), decider.clone());
                rollout.take_candidate(inputs.keys[0], action).unwrap();
                rollout
            })
            .collect();
        let groups = vec![0; rollouts.len()];
        let radius_m = EnvConfig::default().success_radius_m;
        let costs = rollout_costs(
            &Fixated,
            &mut rollouts,
            &groups,
            &[to_beat],
            40,
            false,
            radius_m,
        )
        .unwrap();
        (costs, rollouts.iter().map(|r| r.env.steps()).sum())
    }

    #[test]
    fn rollouts_stop_once_they_cannot_come_in_under_the_cost_to_beat() {
        let (free, free_steps) = far_rollouts(None);
        let least = free.iter().copied().fold(f32::INFINITY, f32::min);
        assert!(arrives(least, 40), "{free:?}");
        // A kept way one step longer than the best rollout: that rollout is still found, at
        // its cost, and so is every other under the bar; the rest stop at the bar or beyond.
        for bar in [least as u32 + 1, least as u32 + 3] {
            let (beaten, steps) = far_rollouts(Some(bar));
            for (&free, &beaten) in free.iter().zip(&beaten) {
                if free < bar as f32 {
                    assert_eq!(free, beaten, "{bar}");
                } else {
                    assert!(beaten >= bar as f32, "{bar}: {beaten} for {free}");
                }
            }
            assert_eq!(best_candidate(&free), best_candidate(&beaten));
            assert!(steps <= free_steps, "{steps} > {free_steps}");
        }
        // A kept way as short as the best rollout stops every one of them early.
        let (beaten, steps) = far_rollouts(Some(least as u32));
        assert!(beaten.iter().all(|&c| c >= least), "{beaten:?}");
        assert!(steps < free_steps, "{steps} vs {free_steps}");
    }

    #[test]
    fn ties_go_to_the_policys_preference() {
        assert_eq!(best_candidate(&[12.0, 11.0, 11.0, 15.0]), Some(1));
        assert_eq!(best_candidate(&[12.0, 12.0]), Some(0));
        assert_eq!(best_candidate(&[]), None);
    }
}
