//! Decision-time rollouts of the policy on the robot's own map: the rollout algorithm of
//! approximate dynamic programming (Bertsekas), with the trained policy as its base policy.
//!
//! At each decision the robot's usual rule (untried, guard, arrival) names its action; the next
//! few actions it would fall back to are the other candidates. Each candidate is tried in the
//! scene as the robot's map shows it ([`PerceivedScene`]): the candidate first, then the policy
//! with its usual rule until the target or a horizon. The candidate whose rollout reaches the
//! target in the fewest steps is taken; ties go to the policy's preference, so the rule's own
//! action keeps its place unless another does strictly better.
//!
//! Why it shortens paths: the policy's own choice is among the candidates, so in a model that
//! matched the world the rollout rule would never take more steps than the policy alone (the
//! cost-improvement property of rollout), and it takes fewer wherever the policy's second or
//! third choice leads somewhere sooner, typically a diagonal step where the policy slid
//! sideways, or the turn that avoids a detour. The model is the perceived scene, not the
//! world, so the property holds only as far as the map is true; the guard still checks the
//! action taken.
//!
//! Rollouts of all episodes and candidates run in lock-step, one batched policy call per step.

use crate::batch_policy::BatchPolicy;
use wheelleg_runtime::action::{Action, CHOICES, DIMS, MOVE_STEP_M};
use wheelleg_runtime::arrival::Arrival;
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_sim::env::{Env, Observation, Status};
use wheelleg_sim::height_map::MapGrid;
use wheelleg_sim::local_plan::{PerceivedScene, LOCAL_MAP};

/// Settings of the look-ahead.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LookaheadConfig {
    /// Actions tried at each decision: the rule's own and the next ones it would fall back to.
    pub candidates: usize,
    /// Actions tried in all when none of the first `candidates` arrives within the horizon
    /// (the policy is lost there); at or below `candidates`, no more are tried.
    pub stuck_candidates: usize,
    /// Steps a rollout may take (the candidate included) before it counts as not arriving.
    pub horizon_steps: u32,
    /// The map the perceived scene is made of.
    pub grid: MapGrid,
    /// Growth of every perceived box on each side.
    pub margin_m: f32,
}

impl Default for LookaheadConfig {
    /// 8 candidates, none more where none arrives, 40-step rollouts, on the search's 2.56 m,
    /// 1 cm map with boxes not grown. Measured on the held-out scenes (docs/results.md,
    /// "Rollouts on the robot's map"): 16 candidates gave the same paths at 2.6 times the
    /// cost, 24 where none of 8 arrives rescued one scene in 300 at 3.3 times; boxes grown by
    /// 5 mm change the policy's input in edge cells and gave longer paths. An episode's
    /// typical way is 10 to 20 steps, so 40 leaves room for a detour.
    fn default() -> Self {
        LookaheadConfig {
            candidates: 8,
            stuck_candidates: 8,
            horizon_steps: 40,
            grid: LOCAL_MAP,
            margin_m: 0.0,
        }
    }
}

/// What the look-ahead chose at one decision.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Weighed {
    /// The caller's number for the decision, as given to [`Lookahead::push`].
    pub slot: usize,
    /// The action to take.
    pub action: Action,
    /// Whether it is another than the rule's own (the first candidate).
    pub overridden: bool,
    /// Whether its rollout arrived within the horizon.
    pub arrives: bool,
}

/// One decision waiting for its rollouts.
#[derive(Clone, Debug)]
struct Pending {
    slot: usize,
    candidates: Vec<Action>,
    seen: Env,
    decider: Decider,
    key: ObservationKey,
}

/// The look-ahead over a batch of episodes: decisions are pushed one by one, then weighed
/// together so that all their rollouts share each batched policy call.
#[derive(Clone, Debug)]
pub struct Lookahead {
    config: LookaheadConfig,
    perceived: PerceivedScene,
    pending: Vec<Pending>,
}

impl Lookahead {
    /// A look-ahead with `config`.
    pub fn new(config: LookaheadConfig) -> Lookahead {
        Lookahead {
            config,
            perceived: PerceivedScene::new(config.grid, config.margin_m),
            pending: Vec::new(),
        }
    }

    /// Its settings.
    pub fn config(&self) -> &LookaheadConfig {
        &self.config
    }

    /// How many of the rule's candidates ([`candidates`]) a decision needs: enough for the
    /// wider look where none of the first arrives.
    pub fn candidates_wanted(&self) -> usize {
        self.config.candidates.max(self.config.stuck_candidates)
    }

    /// Queues a decision: `env` as it stands (the look-ahead sees it only through its
    /// robot's map), the robot's `decider` before deciding, the observation's `key`, and the
    /// rule's `candidates` in order ([`candidates`], at least `stuck_candidates` of them where
    /// the rule has that many).
    pub fn push(
        &mut self,
        slot: usize,
        env: &Env,
        decider: &Decider,
        key: ObservationKey,
        candidates: Vec<Action>,
    ) {
        let (seen, _) = self.perceived.of(env);
        self.pending.push(Pending {
            slot,
            candidates,
            seen,
            decider: decider.clone(),
            key,
        });
    }

    /// Weighs every queued decision by rollouts of `policy` (see [`rollout_costs`]): the
    /// first `candidates` of each, then the rest up to `stuck_candidates` of those where none
    /// arrived. Returns the choices in the order pushed and empties the queue.
    pub fn weigh(
        &mut self,
        policy: &dyn BatchPolicy,
        arrival: bool,
        success_radius_m: f32,
    ) -> Result<Vec<Weighed>, String> {
        let pending = std::mem::take(&mut self.pending);
        let horizon = self.config.horizon_steps;
        let first = self.config.candidates.max(1);
        let mut costs = self.costs_of(policy, &pending, 0..first, arrival, success_radius_m)?;
        let lost: Vec<usize> = (0..pending.len())
            .filter(|&p| !costs[p].iter().any(|&c| arrives(c, horizon)))
            .collect();
        let wider = first..self.config.stuck_candidates.max(first);
        if !lost.is_empty() && !wider.is_empty() {
            let lost_pending: Vec<Pending> = lost.iter().map(|&p| pending[p].clone()).collect();
            let more = self.costs_of(policy, &lost_pending, wider, arrival, success_radius_m)?;
            for (&p, more) in lost.iter().zip(more) {
                costs[p].extend(more);
            }
        }
        Ok(pending
            .iter()
            .zip(&costs)
            .map(|(p, costs)| {
                let best = best_candidate(costs).unwrap_or(0);
                Weighed {
                    slot: p.slot,
                    action: p.candidates.get(best).copied().unwrap_or_default(),
                    overridden: best != 0,
                    arrives: costs.get(best).is_some_and(|&c| arrives(c, horizon)),
                }
            })
            .collect())
    }

    /// Rollout costs of candidates `range` (those there are) of each decision.
    fn costs_of(
        &self,
        policy: &dyn BatchPolicy,
        pending: &[Pending],
        range: std::ops::Range<usize>,
        arrival: bool,
        success_radius_m: f32,
    ) -> Result<Vec<Vec<f32>>, String> {
        let mut rollouts = Vec::new();
        let mut counts = Vec::with_capacity(pending.len());
        for p in pending {
            let these = p.candidates.get(range.clone()).unwrap_or_default();
            counts.push(these.len());
            for &candidate in these {
                let mut env = p.seen.clone();
                env.step(candidate)
                    .map_err(|_| "stepped a finished episode".to_string())?;
                let mut decider = p.decider.clone();
                mark_taken(&mut decider, p.key, candidate);
                rollouts.push(Rollout { env, decider });
            }
        }
        let costs = rollout_costs(
            policy,
            rollouts,
            self.config.horizon_steps,
            arrival,
            success_radius_m,
        )?;
        let mut rest = costs.as_slice();
        Ok(counts
            .into_iter()
            .map(|n| {
                let (these, after) = rest.split_at(n.min(rest.len()));
                rest = after;
                these.to_vec()
            })
            .collect())
    }
}

/// One candidate's rollout: the perceived episode after the candidate, and the decider that
/// goes on from the robot's.
#[derive(Clone, Debug)]
pub struct Rollout {
    /// The perceived episode, already stepped by the candidate.
    pub env: Env,
    /// The decision rule's memory, as the robot's would be after the candidate.
    pub decider: Decider,
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
pub fn rollout_costs(
    policy: &dyn BatchPolicy,
    mut rollouts: Vec<Rollout>,
    horizon_steps: u32,
    arrival: bool,
    success_radius_m: f32,
) -> Result<Vec<f32>, String> {
    let start_steps: Vec<u32> = rollouts
        .iter()
        .map(|r| r.env.steps().saturating_sub(1))
        .collect();
    let taken = |r: &Rollout, start: u32| r.env.steps() - start;
    let mut obs = Observation::default();
    let mut refused = vec![0u32; rollouts.len()];
    let mut nearest_m: Vec<f32> = rollouts
        .iter()
        .map(|r| r.env.distance_to_target_m())
        .collect();
    loop {
        let running: Vec<usize> = (0..rollouts.len())
            .filter(|&i| {
                !rollouts[i].env.status().is_done()
                    && taken(&rollouts[i], start_steps[i]) < horizon_steps
            })
            .collect();
        if running.is_empty() {
            break;
        }
        let mut heights = Vec::with_capacity(running.len() * HEIGHT_MAP_CELLS);
        let mut states = Vec::with_capacity(running.len() * STATE_LEN);
        let mut keys = Vec::with_capacity(running.len());
        for &i in &running {
            rollouts[i].env.observe(&mut obs);
            keys.push(ObservationKey::of_metres(&obs.height_map, &obs.state));
            heights.extend_from_slice(&obs.height_map);
            states.extend_from_slice(&obs.state);
        }
        let out = policy.log_probs(&heights, &states, running.len())?;
        for (k, &i) in running.iter().enumerate() {
            let logits: &[f32; DIMS * CHOICES] = out
                .log_probs
                .get(k * DIMS * CHOICES..(k + 1) * DIMS * CHOICES)
                .and_then(|l| l.try_into().ok())
                .ok_or("the policy returned too few log-probabilities")?;
            let rollout = &mut rollouts[i];
            let action = if arrival {
                let state = &states[k * STATE_LEN..(k + 1) * STATE_LEN];
                Arrival::from_state_m(state, success_radius_m)
                    .choose(&mut rollout.decider, keys[k], logits)
                    .action
            } else {
                rollout.decider.choose(keys[k], logits)
            };
            let outcome = rollout
                .env
                .step(action)
                .map_err(|_| "stepped a finished rollout".to_string())?;
            if outcome.invalid.is_some() {
                refused[i] += 1;
            }
            nearest_m[i] = nearest_m[i].min(rollout.env.distance_to_target_m());
        }
    }
    let costs = rollouts
        .iter()
        .zip(&start_steps)
        .zip(&refused)
        .zip(&nearest_m)
        .map(|(((r, &start), &refused), &nearest_m)| {
            rollout_cost(
                r.env.status(),
                taken(r, start) - refused,
                horizon_steps,
                nearest_m,
            )
        })
        .collect();
    Ok(costs)
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

/// The candidate actions at one decision, in the rule's order of preference: `decide` is the
/// robot's rule applied to a decider; called on a copy of `decider` again and again, it names
/// the rule's own action and then what it would fall back to, each marked taken in the copy.
/// At most `count`, all distinct.
pub fn candidates(
    decider: &Decider,
    count: usize,
    mut decide: impl FnMut(&mut Decider) -> Action,
) -> Vec<Action> {
    let mut copy = decider.clone();
    let mut found: Vec<Action> = Vec::with_capacity(count);
    // The rule may repeat itself once every action was taken at an observation (its memory
    // starts over); a bounded number of calls keeps that from looping.
    for _ in 0..count.saturating_mul(2) {
        if found.len() >= count {
            break;
        }
        let action = decide(&mut copy);
        if !found.contains(&action) {
            found.push(action);
        }
    }
    found
}

/// The rule's own action when there is nothing to weigh: fewer than two candidates, or the
/// first (the rule's own) already reaches the target under `arrival`. `None`: weigh them.
pub fn settled(found: &[Action], arrival: Option<&Arrival>) -> Option<Action> {
    let first = found.first().copied().unwrap_or_default();
    let arrives = arrival.is_some_and(|a| a.reached_by(first));
    (found.len() < 2 || arrives).then_some(first)
}

/// Marks `action` taken at `key` in `decider`, as if its rule had chosen it.
pub fn mark_taken(decider: &mut Decider, key: ObservationKey, action: Action) {
    if decider.was_taken(key, action) {
        return;
    }
    let logits = [0.0f32; DIMS * CHOICES];
    decider.choose_checked(key, &logits, 1, |_, a| a == action);
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
    fn one_candidate_or_an_arriving_first_needs_no_weighing() {
        let ahead = Action {
            move_x: wheelleg_runtime::action::Step::Plus,
            ..Action::IDLE
        };
        let near = Arrival::new(nalgebra::Vector2::new(0.05, 0.0), 0.05);
        let far = Arrival::new(nalgebra::Vector2::new(0.5, 0.0), 0.05);
        assert_eq!(settled(&[ahead], None), Some(ahead));
        assert_eq!(settled(&[ahead, Action::IDLE], Some(&near)), Some(ahead));
        assert_eq!(settled(&[ahead, Action::IDLE], Some(&far)), None);
        assert_eq!(settled(&[ahead, Action::IDLE], None), None);
    }

    #[test]
    fn ties_go_to_the_policys_preference() {
        assert_eq!(best_candidate(&[12.0, 11.0, 11.0, 15.0]), Some(1));
        assert_eq!(best_candidate(&[12.0, 12.0]), Some(0));
        assert_eq!(best_candidate(&[]), None);
    }

    #[test]
    fn candidates_are_the_rules_choices_in_order_and_distinct() {
        let mut logits = [0.0f32; DIMS * CHOICES];
        // Head move x prefers Plus, then Zero; everything else Zero.
        for dim in 0..DIMS {
            logits[dim * CHOICES + 1] = 1.0;
        }
        logits[2] = 2.0;
        let key = ObservationKey(7);
        let decider: Decider = Decider::new();
        let found = candidates(&decider, 3, |d| d.choose(key, &logits));
        assert_eq!(found.len(), 3);
        assert_eq!(found[0].move_x, wheelleg_runtime::action::Step::Plus);
        assert_eq!(found[1].move_x, wheelleg_runtime::action::Step::Zero);
        assert_ne!(found[1], found[2]);
        // The robot's own decider is untouched.
        assert_eq!(decider.taken_count(key), 0);
        let mut decider = decider;
        mark_taken(&mut decider, key, found[2]);
        assert!(decider.was_taken(key, found[2]));
        assert_eq!(decider.taken_count(key), 1);
    }
}
