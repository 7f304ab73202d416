//! One candidate's rollout: the perceived episode after the candidate, run in lock-step with
//! the others under the robot's rule, and what its outcome costs.

use crate::policy::{BatchPolicy, LOG_PROBS};
use crate::rule::{mark_taken, RobotRule};
use wheelleg_runtime::action::{Action, MOVE_STEP_M};
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
) -> Action {
    RobotRule {
        guard: None,
        arrival: arrival.then(|| Arrival::from_state_m(state, success_radius_m)),
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
/// far away as one that never came near.
pub fn rollout_cost(status: Status, steps: u32, horizon_steps: u32, nearest_m: f32) -> f32 {
    if status == Status::Success {
        steps as f32
    } else {
        let to_go = if nearest_m.is_finite() {
            nearest_m / MOVE_STEP_M
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
/// the steps of the rollouts that do not arrive are spared that way.
pub fn rollout_costs(
    policy: &dyn BatchPolicy,
    rollouts: &mut [Rollout],
    groups: &[usize],
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
            if best_arrived[groups[i]].is_some_and(|best| at_least > best) {
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
            None => rollout_cost(r.env.status(), counted(r), horizon_steps, nearest_m),
        })
        .collect();
    Ok(costs)
}

/// The fewest further counted steps in which a running episode `env` can arrive: at least one,
/// and at least its distance beyond the success radius at the longest step (a diagonal move;
/// no step moves the body centre further, and a refused one does not move it).
pub fn steps_still_needed(env: &Env) -> u32 {
    // The slack keeps this a bound where the distance and the division round.
    let longest_step_m = MOVE_STEP_M * core::f32::consts::SQRT_2 * (1.0 + 1.0e-3);
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
        let arrived = rollout_cost(Status::Success, 39, 40, 0.0);
        let near = rollout_cost(Status::Running, 40, 40, 0.06);
        let far = rollout_cost(Status::StepLimit, 12, 40, 0.8);
        assert_eq!(arrived, 39.0);
        assert!(arrived < near && near < far, "{arrived} {near} {far}");
        assert!(rollout_cost(Status::TooFar, 3, 40, f32::NAN).is_finite());
        assert!(arrives(arrived, 40) && !arrives(near, 40) && !arrives(far, 40));
    }

    #[test]
    fn ties_go_to_the_policys_preference() {
        assert_eq!(best_candidate(&[12.0, 11.0, 11.0, 15.0]), Some(1));
        assert_eq!(best_candidate(&[12.0, 12.0]), Some(0));
        assert_eq!(best_candidate(&[]), None);
    }
}
