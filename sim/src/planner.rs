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
use nalgebra::Point2;
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
        // Smallest f first; among equals, deepest first, then newest first: with a tight
        // heuristic this dives straight along one shortest plan instead of widening over the
        // many equally short ones.
        other
            .f
            .total_cmp(&self.f)
            .then(self.steps.cmp(&other.steps))
            .then(self.node.cmp(&other.node))
    }
}

impl PartialOrd for Open {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Lower bound on the distance the body centre must still travel, through the places it can
/// be at all.
///
/// A body centre closer than the body's half-width to a block is impossible at any yaw, leg
/// pose or clearance (no clearance clears a block, and the body contains a disc of that radius
/// around its centre). So the shortest way to the target avoids blocks grown by that radius:
/// a Dijkstra distance field over a fine grid around those grown blocks, discounted for grid
/// paths being longer than straight ones, so that it never overestimates.
struct DistanceField {
    min: Point2<f32>,
    cols: usize,
    rows: usize,
    metres: Vec<f32>,
}

const FIELD_CELL_M: f32 = 0.025;
/// Grid paths with 16 neighbours are at most 1/cos(13.3 deg) longer than straight ones.
const FIELD_DISCOUNT: f32 = 0.97;

impl DistanceField {
    fn new(env: &Env, start: Point2<f32>) -> Self {
        let margin = env.config().arena_margin_m + 0.1;
        let target = env.target();
        let min = Point2::new(start.x.min(target.x) - margin, start.y.min(target.y) - margin);
        let cols = ((start.x.max(target.x) + margin - min.x) / FIELD_CELL_M).ceil() as usize + 1;
        let rows = ((start.y.max(target.y) + margin - min.y) / FIELD_CELL_M).ceil() as usize + 1;
        let half_width_m = 0.5 * env.geometry().body_width_m;
        let blocked_within_m = half_width_m - FIELD_CELL_M * core::f32::consts::FRAC_1_SQRT_2;
        let blocks: Vec<_> = env
            .obstacles()
            .boxes()
            .iter()
            .filter(|b| b.height_m > env.geometry().clearance_range_m[1] + env.geometry().body_thickness_m)
            .copied()
            .collect();
        let centre = |c: usize, r: usize| Point2::new(min.x + c as f32 * FIELD_CELL_M, min.y + r as f32 * FIELD_CELL_M);
        let blocked: Vec<bool> = (0..rows * cols)
            .map(|i| {
                let p = centre(i % cols, i / cols);
                blocks.iter().any(|b| {
                    let dx = (b.min_x_m - p.x).max(p.x - b.max_x_m).max(0.0);
                    let dy = (b.min_y_m - p.y).max(p.y - b.max_y_m).max(0.0);
                    dx * dx + dy * dy < blocked_within_m * blocked_within_m
                })
            })
            .collect();
        let mut metres = vec![f32::INFINITY; rows * cols];
        let mut queue = BinaryHeap::new();
        let goal_m = env.config().success_radius_m + FIELD_CELL_M;
        for i in 0..rows * cols {
            if (centre(i % cols, i / cols) - target).norm() <= goal_m {
                metres[i] = 0.0;
                queue.push((std::cmp::Reverse(OrderedF32(0.0)), i));
            }
        }
        const MOVES: [(i32, i32); 16] = [
            (1, 0), (-1, 0), (0, 1), (0, -1), (1, 1), (1, -1), (-1, 1), (-1, -1),
            (2, 1), (2, -1), (-2, 1), (-2, -1), (1, 2), (1, -2), (-1, 2), (-1, -2),
        ];
        while let Some((std::cmp::Reverse(OrderedF32(d)), i)) = queue.pop() {
            if d > metres[i] {
                continue;
            }
            let (c, r) = ((i % cols) as i32, (i / cols) as i32);
            for (dc, dr) in MOVES {
                let (nc, nr) = (c + dc, r + dr);
                if nc < 0 || nr < 0 || nc >= cols as i32 || nr >= rows as i32 {
                    continue;
                }
                let j = nr as usize * cols + nc as usize;
                if blocked[j] {
                    continue;
                }
                let nd = d + FIELD_CELL_M * ((dc * dc + dr * dr) as f32).sqrt();
                if nd < metres[j] {
                    metres[j] = nd;
                    queue.push((std::cmp::Reverse(OrderedF32(nd)), j));
                }
            }
        }
        DistanceField { min, cols, rows, metres }
    }

    /// Lower bound on the remaining travel of the body centre from `p`.
    fn lower_bound_m(&self, p: Point2<f32>) -> f32 {
        let c = ((p.x - self.min.x) / FIELD_CELL_M).round();
        let r = ((p.y - self.min.y) / FIELD_CELL_M).round();
        if c < 0.0 || r < 0.0 || c as usize >= self.cols || r as usize >= self.rows {
            return 0.0;
        }
        let d = self.metres[r as usize * self.cols + c as usize];
        if d.is_finite() {
            // Snapping p to its cell moves it by up to half a cell diagonal; the goal cells
            // reach one cell past the success circle.
            (FIELD_DISCOUNT * d - 2.0 * FIELD_CELL_M).max(0.0)
        } else {
            d
        }
    }
}

#[derive(PartialEq, PartialOrd)]
struct OrderedF32(f32);
impl Eq for OrderedF32 {}
impl Ord for OrderedF32 {
    fn cmp(&self, other: &Self) -> Ordering {
        self.0.total_cmp(&other.0)
    }
}

/// Lower bound on the steps from `state` to success: the remaining travel at the longest
/// possible step (a diagonal move of 0.05 * sqrt(2) m).
fn steps_to_go(env: &Env, field: &DistanceField, state: &RobotState) -> f32 {
    let straight_m = (env.target() - state.position).norm() - env.config().success_radius_m;
    let travel_m = straight_m.max(field.lower_bound_m(state.position));
    // 1e-4 m of slack keeps the bound admissible under float rounding.
    ((travel_m - 1.0e-4) / (MOVE_STEP_M * core::f32::consts::SQRT_2)).ceil().max(0.0)
}

/// Searches from the episode's current state for a plan to the target within its rules (step
/// limit, give-up distance, arena).
pub fn plan(env: &Env, config: &PlannerConfig) -> Plan {
    let mut actions: Vec<Action> = (0..COUNT)
        .filter(|&i| config.allowed[i])
        .filter_map(Action::from_index)
        .filter(|a| *a != Action::IDLE)
        .collect();
    // Successors are queued in this order and popped newest first: plain moves last, so that
    // leg changes are tried only when moving alone does not do.
    actions.sort_by_key(|a| core::cmp::Reverse(a.clearance.sign().abs() + a.track.sign().abs()));
    let start = *env.state();
    let field = DistanceField::new(env, start.position);
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
            let f = next_steps as f32 + config.heuristic_weight * steps_to_go(env, &field, &next);
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
