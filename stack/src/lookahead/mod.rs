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
//!
//! A search for a shorter way (optional, [`LookaheadConfig::search_expansions`]): where the
//! best rollout arrives in `n` steps, the planner's exact search runs in the same perceived
//! scene for a way of at most `n - 1` steps, within a small budget of expansions, and its way
//! is taken where the robot's guard allows its first step. The policy's ways are about a tenth
//! longer than the shortest even on open ground, because the shortest way turns the robot so
//! that its longest step (a diagonal move, 0.071 m) carries it, and the policy mostly drives
//! along its axes; no rollout of the policy finds that, and an exact search does so in a few
//! hundred expansions where the way is open. Where the way is hard (clutter, a bar or slab at
//! the target) the budget runs out and the rollouts decide, as without the search.
//!
//! With the search on, the way taken (searched or rolled out) is kept, and at the next
//! decision it is replayed in the newly perceived scene: where it still arrives with every
//! step clear and its next step allowed by the guard, it is followed unless a rollout now
//! arrives strictly sooner (the fortified rollout algorithm), and no search is run. That
//! keeps the cost of the search to the decisions where the way changed, and keeps the robot
//! from switching between ways of equal length as its map shifts.

mod rollout;

pub use rollout::{
    arrives, best_candidate, rollout_cost, rollout_costs, steps_still_needed, Rollout,
};

use crate::policy::BatchPolicy;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_sim::env::{Env, Status};
use wheelleg_sim::height_map::MapGrid;
use wheelleg_sim::local_plan::{PerceivedScene, LOCAL_MAP};
use wheelleg_sim::planner::{plan_within, PlanOutcome, PlannerConfig};
use wheelleg_sim::state::RobotState;

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
    /// Expansions of the exact search for a way shorter than the best rollout's (0: no
    /// search; see [`Lookahead::weigh`]). With the search on, the way taken is kept and
    /// followed while it still holds.
    pub search_expansions: usize,
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
            search_expansions: 0,
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
    incumbent: Option<KeptPlan>,
}

impl Pending {
    /// Whether a searched or kept way's first step `action` may be taken as the rule would
    /// take it: passed by the guard (`allows`), and not already tried at this observation (a
    /// step the world refused leaves the robot where it was, and the same search would offer
    /// it again forever).
    fn takes(&self, action: Action, allows: &mut dyn FnMut(usize, Action) -> bool) -> bool {
        !self.decider.was_taken(self.key, action) && allows(self.slot, action)
    }
}

/// The way the last decision of an episode expected to arrive by: the actions after the one
/// taken, and the robot's state that action was to lead to.
#[derive(Clone, Debug)]
struct KeptPlan {
    expected: RobotState,
    actions: Vec<Action>,
}

/// What one candidate's best rollout found: its cost and the actions it took that the
/// perceived scene did not refuse, the candidate first.
#[derive(Clone, Debug)]
struct Found {
    cost: f32,
    actions: Vec<Action>,
}

/// The look-ahead over a batch of episodes: decisions are pushed one by one, then weighed
/// together so that all their rollouts share each batched policy call.
#[derive(Clone, Debug)]
pub struct Lookahead {
    config: LookaheadConfig,
    perceived: PerceivedScene,
    pending: Vec<Pending>,
    /// By slot, the way the last decision expected to arrive by (see `keep_plans`).
    plans: Vec<Option<KeptPlan>>,
}

impl Lookahead {
    /// A look-ahead with `config`.
    pub fn new(config: LookaheadConfig) -> Lookahead {
        Lookahead {
            config,
            perceived: PerceivedScene::new(config.grid, config.margin_m),
            pending: Vec::new(),
            plans: Vec::new(),
        }
    }

    /// Its settings.
    pub fn config(&self) -> &LookaheadConfig {
        &self.config
    }

    /// How many of the rule's candidates ([`crate::rule::candidates`]) a decision needs: enough for the
    /// wider look where none of the first arrives.
    pub fn candidates_wanted(&self) -> usize {
        self.config.candidates.max(self.config.stuck_candidates)
    }

    /// Queues a decision of episode `slot` (a number that stays with the episode, so that the
    /// way kept for it is offered again): `env` as it stands (the look-ahead sees it only
    /// through its robot's map), the robot's `decider` before deciding, the observation's
    /// `key`, and the rule's `candidates` in order ([`crate::rule::candidates`], at least
    /// `stuck_candidates` of them where the rule has that many).
    pub fn push(
        &mut self,
        slot: usize,
        env: &Env,
        decider: &Decider,
        key: ObservationKey,
        candidates: Vec<Action>,
    ) {
        let (seen, _) = self.perceived.of(env);
        // The way kept from the last decision holds only where the robot stands where it was
        // to lead (the action taken was the one weighed, and the world moved it as the map
        // said it would).
        let incumbent = self
            .plans
            .get_mut(slot)
            .and_then(Option::take)
            .filter(|plan| plan.expected == *env.state());
        self.pending.push(Pending {
            slot,
            candidates,
            seen,
            decider: decider.clone(),
            key,
            incumbent,
        });
    }

    /// Weighs every queued decision by rollouts of `policy` (see [`rollout_costs`]): the
    /// first `candidates` of each, then the rest up to `stuck_candidates` of those where none
    /// arrived (nor a kept way). With the search on, a shorter searched way or the kept way
    /// may stand instead (see the module's notes), where its first step passes the robot's
    /// guard: `allows(slot, action)` says whether the guard of the decision pushed as `slot`
    /// lets `action` be sent now. It is asked only of those first steps, at most two per
    /// decision, because checking all 243 actions at every decision cost more than the
    /// rollouts and searches together. Returns the choices in the order pushed and empties the
    /// queue.
    pub fn weigh(
        &mut self,
        policy: &dyn BatchPolicy,
        arrival: bool,
        success_radius_m: f32,
        allows: &mut dyn FnMut(usize, Action) -> bool,
    ) -> Result<Vec<Weighed>, String> {
        let pending = std::mem::take(&mut self.pending);
        let horizon = self.config.horizon_steps;
        let first = self.config.candidates.max(1);
        let incumbents: Vec<Option<Found>> = pending
            .iter()
            .map(|p| replay_incumbent(p, &mut *allows))
            .collect();
        // A kept way stands against any rollout no shorter, so rollouts stop once they cannot
        // come in under it.
        let to_beat: Vec<Option<u32>> = incumbents
            .iter()
            .map(|i| i.as_ref().map(|i| i.cost as u32))
            .collect();
        let mut found = self.costs_of(
            policy,
            &pending,
            &to_beat,
            0..first,
            arrival,
            success_radius_m,
        )?;
        let lost: Vec<usize> = (0..pending.len())
            .filter(|&p| {
                incumbents[p].is_none() && !found[p].iter().any(|f| arrives(f.cost, horizon))
            })
            .collect();
        let wider = first..self.config.stuck_candidates.max(first);
        if !lost.is_empty() && !wider.is_empty() {
            let lost_pending: Vec<Pending> = lost.iter().map(|&p| pending[p].clone()).collect();
            // Lost decisions have no kept way.
            let none = vec![None; lost_pending.len()];
            let more = self.costs_of(
                policy,
                &lost_pending,
                &none,
                wider,
                arrival,
                success_radius_m,
            )?;
            for (&p, more) in lost.iter().zip(more) {
                found[p].extend(more);
            }
        }
        let mut weighed = Vec::with_capacity(pending.len());
        for ((p, found), incumbent) in pending.iter().zip(found).zip(incumbents) {
            let costs: Vec<f32> = found.iter().map(|f| f.cost).collect();
            let best = best_candidate(&costs).unwrap_or(0);
            let mut chosen = found.into_iter().nth(best);
            // A kept way that still holds was the shortest the search found, or no longer
            // than any rollout since: searching again would mostly repeat it.
            let searching = incumbent.is_none();
            if let Some(best) = chosen
                .as_ref()
                .filter(|c| searching && arrives(c.cost, horizon))
            {
                if let Some(searched) = self.shorter_way(p, best.cost as u32, &mut *allows) {
                    chosen = Some(searched);
                }
            }
            // The kept way stands unless a rollout now arrives strictly sooner.
            if let Some(incumbent) = incumbent {
                if chosen.as_ref().is_none_or(|c| incumbent.cost <= c.cost) {
                    chosen = Some(incumbent);
                }
            }
            let action = chosen
                .as_ref()
                .and_then(|c| c.actions.first().copied())
                .unwrap_or_else(|| p.candidates.first().copied().unwrap_or_default());
            let arrived = chosen.as_ref().is_some_and(|c| arrives(c.cost, horizon));
            if self.config.search_expansions > 0 {
                if self.plans.len() <= p.slot {
                    self.plans.resize(p.slot + 1, None);
                }
                // The state the action leads to in the perceived scene, as its rollout or the
                // search stepped it there.
                let mut after = p.seen.clone();
                let expected = after.step(action).ok().map(|_| *after.state());
                self.plans[p.slot] =
                    chosen
                        .filter(|_| arrived)
                        .zip(expected)
                        .map(|(c, expected)| KeptPlan {
                            expected,
                            actions: c.actions.get(1..).unwrap_or_default().to_vec(),
                        });
            }
            weighed.push(Weighed {
                slot: p.slot,
                action,
                overridden: Some(&action) != p.candidates.first(),
                arrives: arrived,
            });
        }
        Ok(weighed)
    }

    /// A way strictly shorter than `steps` in the perceived scene, by an exact search within
    /// the configured expansions, whose first action the robot's rule would take.
    fn shorter_way(
        &self,
        p: &Pending,
        steps: u32,
        allows: &mut dyn FnMut(usize, Action) -> bool,
    ) -> Option<Found> {
        if self.config.search_expansions == 0 || steps < 2 {
            return None;
        }
        let config = PlannerConfig {
            max_expansions: self.config.search_expansions,
            ..PlannerConfig::default()
        };
        let PlanOutcome::Solved { actions, .. } = plan_within(&p.seen, &config, steps - 1).outcome
        else {
            return None;
        };
        let first = *actions.first()?;
        if !p.takes(first, allows) {
            return None;
        }
        Some(Found {
            cost: actions.len() as f32,
            actions,
        })
    }

    /// What the best rollout of each of candidates `range` (those there are) of each decision
    /// found.
    fn costs_of(
        &self,
        policy: &dyn BatchPolicy,
        pending: &[Pending],
        to_beat: &[Option<u32>],
        range: std::ops::Range<usize>,
        arrival: bool,
        success_radius_m: f32,
    ) -> Result<Vec<Vec<Found>>, String> {
        let mut rollouts = Vec::new();
        let mut groups = Vec::new();
        let mut counts = Vec::with_capacity(pending.len());
        for (group, p) in pending.iter().enumerate() {
            let these = p.candidates.get(range.clone()).unwrap_or_default();
            counts.push(these.len());
            for &candidate in these {
                let mut rollout = Rollout::new(p.seen.clone(), p.decider.clone());
                rollout.take_candidate(p.key, candidate)?;
                rollouts.push(rollout);
                groups.push(group);
            }
        }
        let costs = rollout_costs(
            policy,
            &mut rollouts,
            &groups,
            to_beat,
            self.config.horizon_steps,
            arrival,
            success_radius_m,
        )?;
        let mut found = rollouts
            .into_iter()
            .zip(costs)
            .map(|(rollout, cost)| Found {
                cost,
                actions: rollout.actions,
            });
        Ok(counts
            .into_iter()
            .map(|n| found.by_ref().take(n).collect())
            .collect())
    }
}

/// The kept way of decision `p`, replayed in the scene as now perceived: its cost and
/// actions where the robot's guard still allows its first action and it still arrives with
/// no step refused; `None` otherwise.
fn replay_incumbent(p: &Pending, allows: &mut dyn FnMut(usize, Action) -> bool) -> Option<Found> {
    let plan = p.incumbent.as_ref()?;
    let first = *plan.actions.first()?;
    if !p.takes(first, allows) {
        return None;
    }
    let mut env = p.seen.clone();
    for (taken, &action) in plan.actions.iter().enumerate() {
        let outcome = env.step(action).ok()?;
        if outcome.invalid.is_some() {
            return None;
        }
        if env.status() == Status::Success {
            return Some(Found {
                cost: (taken + 1) as f32,
                actions: plan.actions[..=taken].to_vec(),
            });
        }
        if env.status().is_done() {
            return None;
        }
    }
    None
}
