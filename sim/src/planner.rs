//! Exact shortest-path search over the robot's discrete action set (A*).
//!
//! Nodes are robot states; edges are the 242 non-idle actions whose transitions the simulator
//! accepts (an undone action never helps a shortest path, so invalid transitions are not
//! edges). Every edge costs one step. The heuristic, the number of steps the straight-line
//! distance to the success circle needs at the longest possible step (a diagonal move of
//! 0.05 * sqrt(2) m), never overestimates, so the first goal popped is a shortest plan.
//!
//! Positions are compared at 0.1 mm: the same pose reached by moves in a different order differs
//! only by float rounding, and merging those keeps the search finite without merging poses
//! the simulator would treat differently at the scale of any obstacle.
//!
//! The search is bounded by a number of expansions. When exact search runs out, a weighted
//! search (heuristic inflated) can still prove a scene solvable, without the shortest length.

use crate::env::{Env, Status};
use crate::state::RobotState;
use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap};
use wheelleg_runtime::action::{Action, COUNT, MOVE_STEP_M};

/// Search settings.
#[derive(Clone, Copy, Debug)]
pub struct PlannerConfig {
    /// Give up after expanding this many states.
    pub max_expansions: usize,
    /// Heuristic weight: 1.0 for shortest plans; above 1 finds plans faster, not shortest.
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
    /// States expanded.
    pub expansions: usize,
}

type Key = (i32, i32, i32, i32, i32);

fn key(state: &RobotState) -> Key {
    (
        (state.position.x * 1.0e4).round() as i32,
        (state.position.y * 1.0e4).round() as i32,
        state.yaw_steps,
        state.clearance_steps,
        state.track_steps,
    )
}

struct Node {
    state: RobotState,
    parent: usize,
    action: Action,
    steps: u32,
}

#[derive(PartialEq)]
struct Open {
    f: f32,
    steps: u32,
    node: usize,
}

impl Eq for Open {}

impl Ord for Open {
    fn cmp(&self, other: &Self) -> Ordering {
        // Smallest f first; among equals, deepest first (closest to a goal).
        other
            .f
            .total_cmp(&self.f)
            .then(self.steps.cmp(&other.steps))
            .then(other.node.cmp(&self.node))
    }
}

impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Lower bound on the steps from `state` to success.
fn steps_to_go(env: &Env, state: &RobotState) -> f32 {
    let distance_m = (env.target() - state.position).norm() - env.config().success_radius_m;
    // 1e-4 m of slack keeps the bound admissible under float rounding.
    ((distance_m - 1.0e-4) / (MOVE_STEP_M * core::f32::consts::SQRT_2)).ceil().max(0.0)
}

/// Searches from the episode's current state for a plan to the target within its rules (step
/// limit, give-up distance, arena).
pub fn plan(env: &Env, config: &PlannerConfig) -> Plan {
    let actions: Vec<Action> = (0..COUNT)
        .filter(|&i| config.allowed[i])
        .filter_map(Action::from_index)
        .filter(|a| *a != Action::IDLE)
        .collect();
    let start = *env.state();
    let give_up_m = (env.target() - start.position).norm() + env.config().give_up_margin_m;
    let max_steps = env.config().max_steps.saturating_sub(env.steps());
    let mut nodes = vec![Node { state: start, parent: 0, action: Action::IDLE, steps: 0 }];
    let mut best: HashMap<Key, u32> = HashMap::from([(key(&start), 0)]);
    let mut open = BinaryHeap::from([Open { f: 0.0, steps: 0, node: 0 }]);
    let mut expansions = 0;
    if env.status() == Status::Success {
        return Plan { outcome: PlanOutcome::Solved { actions: Vec::new(), shortest: true }, expansions };
    }
    while let Some(Open { node, steps, .. }) = open.pop() {
        let state = nodes[node].state;
        if best.get(&key(&state)).is_some_and(|&g| g < steps) {
            continue; // a shorter way here was found after this entry was queued
        }
        if expansions >= config.max_expansions {
            return Plan { outcome: PlanOutcome::BudgetExceeded, expansions };
        }
        expansions += 1;
        if steps >= max_steps {
            continue;
        }
        for &action in &actions {
            let next = state.after(action);
            let distance_m = (env.target() - next.position).norm();
            if distance_m > give_up_m || env.check_transition(&state, &next).is_err() {
                continue;
            }
            let next_steps = steps + 1;
            let k = key(&next);
            if best.get(&k).is_some_and(|&g| g <= next_steps) {
                continue;
            }
            best.insert(k, next_steps);
            nodes.push(Node { state: next, parent: node, action, steps: next_steps });
            let index = nodes.len() - 1;
            if distance_m <= env.config().success_radius_m {
                // Goal test on generation is exact here: all edges cost the same, and the
                // heuristic is consistent, so no shorter plan can still be in the queue.
                let shortest = config.heuristic_weight <= 1.0;
                return Plan { outcome: PlanOutcome::Solved { actions: unwind(&nodes, index), shortest }, expansions };
            }
            let f = next_steps as f32 + config.heuristic_weight * steps_to_go(env, &next);
            open.push(Open { f, steps: next_steps, node: index });
        }
    }
    Plan { outcome: PlanOutcome::Unsolvable, expansions }
}

fn unwind(nodes: &[Node], mut index: usize) -> Vec<Action> {
    let mut actions = Vec::with_capacity(nodes[index].steps as usize);
    while index != 0 {
        actions.push(nodes[index].action);
        index = nodes[index].parent;
    }
    actions.reverse();
    actions
}
