//! Exact shortest-path search over the robot's discrete action set.
//!
//! The robot's full state is its base pose (position, yaw) and its leg configuration
//! (clearance, track). Leg changes ride along with every move for free, so a search over full
//! states sees every pose in up to ~200 leg variants that all look equally promising, and
//! explodes. This search collapses the leg dimensions instead:
//!
//! - A node is a base pose with the *set* of leg configurations in which the robot can stand
//!   there after exactly `g` steps (a bitset over the reachable (clearance, track) lattice).
//! - An edge is one of the 27 base moves (9 translations x 3 yaw steps, "stay" included). From
//!   `(pose, L)` the move leads to `(pose', L')` where `L'` holds every configuration one leg step
//!   (-1/0/+1 per leg dimension) from some member of `L` for which the simulator accepts the
//!   transition, restricted to the allowed actions. Every edge costs one step.
//! - Dominance: a node is dropped when the same pose is already known with no more steps and a
//!   superset of leg configurations; whatever the dropped node could do, that one does as well or
//!   sooner. Nothing else is pruned, so the search stays exact.
//!
//! The heuristic is pose-only and never overestimates (see [`heuristic::Heuristic`]); the first goal
//! accepted is therefore a shortest plan. At the goal, a concrete action sequence is rebuilt by
//! walking back through the parents, choosing for each step a leg configuration of the parent
//! set from which the transition is valid, and the plan is replayed in a copy of the episode;
//! a plan that does not replay is a bug in this module, and panics rather than being reported.
//!
//! Positions are compared at 0.1 mm: the same pose reached by moves in a different order
//! differs only by float rounding, and merging those keeps the search finite without merging
//! poses the simulator would treat differently at the scale of any obstacle.
//!
//! The search is bounded by a number of expansions. When exact search runs out, a weighted
//! search (heuristic inflated, [`plan_with_fallback`]) can still prove a scene solvable, without
//! the shortest length. It also orders its queue by a leg-aware hint ([`heuristic::LegHint`]: the leg
//! steps and the turn that straddling a slab or bar ahead calls for), which is not a lower bound
//! and is therefore used for nothing else.
//!
//! The module's files, by concept: [`legs`] (the leg lattice and leg sets), [`moves`] (base poses
//! and moves), [`broad_phase`] (precomputed boxes and the cheap tests), [`way`] (the planner's
//! proof of the way there), [`heuristic`] (the admissible bound and the leg hint) and [`search`]
//! (the search). This file is the API.

mod broad_phase;
mod heuristic;
mod lazy;
mod legs;
pub(crate) use legs::{LEG_COLS, LEG_ROWS};
mod moves;
mod search;
mod valid;
mod way;

use crate::env::{Env, Status};
use search::Search;
use wheelleg_runtime::action::{Action, COUNT};

/// Search settings.
#[derive(Clone, Copy, Debug)]
pub struct PlannerConfig {
    /// Give up after expanding this many nodes.
    pub max_expansions: usize,
    /// Heuristic weight: 1.0 for shortest plans; above 1 finds plans faster, not shortest, and
    /// also orders the search by the leg hint (see [`plan_with_fallback`]).
    pub heuristic_weight: f32,
    /// Which of the 243 actions may be used (to prove that a behaviour is necessary, freeze
    /// a dimension).
    pub allowed: [bool; COUNT],
}

impl Default for PlannerConfig {
    fn default() -> Self {
        PlannerConfig {
            max_expansions: 200_000,
            heuristic_weight: 1.0,
            allowed: [true; COUNT],
        }
    }
}

impl PlannerConfig {
    /// Allows only actions for which `keep` holds.
    pub fn restricted(mut self, keep: impl Fn(&Action) -> bool) -> Self {
        for (index, allowed) in self.allowed.iter_mut().enumerate() {
            *allowed = Action::from_index(index).is_some_and(|a| keep(&a));
        }
        self
    }
}

/// What the search found.
#[derive(Clone, Debug, PartialEq)]
pub enum PlanOutcome {
    /// A plan that reaches the target; shortest when the search was exact.
    Solved {
        /// The actions, in order.
        actions: Vec<Action>,
        /// Whether the plan is proven shortest (exact search).
        shortest: bool,
    },
    /// Every reachable state was expanded: no plan exists within the episode rules.
    Unsolvable,
    /// The expansion budget ran out first.
    BudgetExceeded,
}

/// The outcome and the effort it took.
#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    /// What was found.
    pub outcome: PlanOutcome,
    /// Nodes (base pose with a set of leg configurations) expanded.
    pub expansions: usize,
}

/// Heuristic weight of the fallback search in [`plan_with_fallback`]: large enough to dive
/// through the behaviour scenes in a few thousand expansions, small enough that plans stay
/// reasonably short.
pub const FALLBACK_WEIGHT: f32 = 3.0;

/// Result of [`plan_with_fallback`]: the exact search, and the weighted one when the exact one
/// ran out of budget.
#[derive(Clone, Debug, PartialEq)]
pub struct FallbackPlan {
    /// The exact (or, if so configured, weighted) search.
    pub exact: Plan,
    /// The weighted search, run only when `exact` exceeded its budget.
    pub fallback: Option<Plan>,
}

impl FallbackPlan {
    /// The final answer: the fallback's when it ran, else the exact search's.
    pub fn outcome(&self) -> &PlanOutcome {
        self.fallback
            .as_ref()
            .map_or(&self.exact.outcome, |p| &p.outcome)
    }

    /// Nodes expanded by both searches together.
    pub fn expansions(&self) -> usize {
        self.exact.expansions + self.fallback.as_ref().map_or(0, |p| p.expansions)
    }
}

/// Exact search within the budget; if that runs out, a weighted search
/// ([`FALLBACK_WEIGHT`], ordered by the leg hint too) with the same budget, which can still prove
/// the scene solvable (plan not shortest) or unsolvable (it explores everything when it fails).
///
/// A search configured with `heuristic_weight > 1` is that weighted search from the start.
pub fn plan_with_fallback(env: &Env, config: &PlannerConfig) -> FallbackPlan {
    let exact = plan(env, config);
    if exact.outcome != PlanOutcome::BudgetExceeded || config.heuristic_weight >= FALLBACK_WEIGHT {
        return FallbackPlan {
            exact,
            fallback: None,
        };
    }
    let weighted = PlannerConfig {
        heuristic_weight: FALLBACK_WEIGHT,
        ..*config
    };
    FallbackPlan {
        exact,
        fallback: Some(plan(env, &weighted)),
    }
}

/// Searches from the episode's current state for a plan to the target within its rules (step
/// limit, give-up distance, arena).
///
/// # Panics
///
/// If the plan found does not replay to success in a copy of `env` (a bug in this module). The
/// planner's leg sets hold 16 clearance by 32 track steps, which every
/// [`crate::robot::SimulatedRobot`] fits.
pub fn plan(env: &Env, config: &PlannerConfig) -> Plan {
    plan_within(env, config, u32::MAX)
}

/// [`plan`] for a plan of at most `max_steps` steps: [`PlanOutcome::Unsolvable`] then says
/// that none is that short. A tight limit prunes every node whose most optimistic way is
/// longer, so proving that a known way is shortest is quick where the heuristic is close.
///
/// # Panics
///
/// As [`plan`].
pub fn plan_within(env: &Env, config: &PlannerConfig, max_steps: u32) -> Plan {
    match env.status() {
        Status::Success => {
            return Plan {
                outcome: PlanOutcome::Solved {
                    actions: Vec::new(),
                    shortest: true,
                },
                expansions: 0,
            }
        }
        Status::TooFar | Status::StepLimit => {
            return Plan {
                outcome: PlanOutcome::Unsolvable,
                expansions: 0,
            }
        }
        Status::Running => {}
    }
    let mut search = Search::new(env, config, max_steps);
    let plan = search.run();
    if let PlanOutcome::Solved { actions, .. } = &plan.outcome {
        if let Err(why) = replay(env, actions) {
            panic!(
                "planner bug: the plan found ({} steps) does not replay: {why}",
                actions.len()
            );
        }
    }
    plan
}

/// Replays `actions` in a copy of `env`: every action valid, success exactly at the end.
fn replay(env: &Env, actions: &[Action]) -> Result<(), String> {
    let mut env = env.clone();
    for (i, &action) in actions.iter().enumerate() {
        let outcome = env
            .step(action)
            .map_err(|_| format!("episode over before step {i}"))?;
        if let Some(invalid) = outcome.invalid {
            return Err(format!("step {i} ({action:?}) is invalid: {invalid:?}"));
        }
        if outcome.status.is_done() && i + 1 < actions.len() {
            return Err(format!("episode ends ({:?}) at step {i}", outcome.status));
        }
    }
    match env.status() {
        Status::Success => Ok(()),
        status => Err(format!("ends with {status:?}")),
    }
}
