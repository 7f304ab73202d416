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
//! The heuristic is pose-only and never overestimates (see [`Heuristic`]); the first goal
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
//! the shortest length. It also orders its queue by a leg-aware hint ([`LegHint`]: the leg
//! steps and the turn that straddling a slab or bar ahead calls for), which is not a lower bound
//! and is therefore used for nothing else.

use crate::collision::{place_parts, CLEARANCE_SLACK_M};
use crate::collision::{Part, RobotParts, PART_COUNT};
use crate::env::{proof_cap_m, Env, InvalidAction, Status, GRAZE_TOLERANCE_M};
use crate::generate::{passing_legs, Behaviour};
use crate::obstacle::ObstacleKind;
use crate::state::{RobotState, YAW_STEPS_PER_TURN};
use nalgebra::{Point2, Point3, Vector3};
use parry3d::bounding_volume::{Aabb, BoundingVolume};
use std::cmp::Ordering;
use std::collections::{BinaryHeap, HashMap};
use std::hash::{BuildHasherDefault, Hasher};
use wheelleg_runtime::action::{Action, Step, COUNT, MOVE_STEP_M};
use wheelleg_runtime::robot::RobotGeometry;

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
/// If the plan found does not replay to success in a copy of `env` (a bug in this module), or
/// if the robot's reachable leg lattice is larger than 16 clearance by 32 track steps.
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

// ---------------------------------------------------------------------------------------------
// Leg configuration sets.

/// Capacity of a [`LegSet`] in clearance steps (rows).
const LEG_ROWS: usize = 16;
/// Capacity of a [`LegSet`] in track steps (bits of a row).
const LEG_COLS: usize = 32;

/// A set of leg configurations: bit `t` of row `r` is (clearance row `r`, track column `t`) of
/// the [`LegLattice`]. One `u32` per clearance row makes the one-step dilation in either leg
/// dimension a row shift or a bit shift.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
struct LegSet([u32; LEG_ROWS]);

impl LegSet {
    fn contains(&self, row: usize, col: usize) -> bool {
        self.0[row] >> col & 1 == 1
    }

    fn insert(&mut self, row: usize, col: usize) {
        self.0[row] |= 1 << col;
    }

    fn is_empty(&self) -> bool {
        self.0.iter().all(|&w| w == 0)
    }

    fn is_subset_of(&self, other: &LegSet) -> bool {
        self.0.iter().zip(&other.0).all(|(a, b)| a & !b == 0)
    }

    fn union_with(&mut self, other: &LegSet) {
        for (a, b) in self.0.iter_mut().zip(&other.0) {
            *a |= b;
        }
    }

    fn intersection(mut self, other: &LegSet) -> LegSet {
        for (a, b) in self.0.iter_mut().zip(&other.0) {
            *a &= b;
        }
        self
    }

    /// The set moved by `dc` rows and `dt` columns (each -1, 0 or +1): contains `(r, t)` when
    /// `self` contains `(r - dc, t - dt)`. Bits pushed past the lattice are cut by the caller's
    /// intersection with the reachable set.
    fn shifted(&self, dc: i32, dt: i32) -> LegSet {
        let mut out = [0u32; LEG_ROWS];
        for (row, word) in out.iter_mut().enumerate() {
            let source = row as i32 - dc;
            if (0..LEG_ROWS as i32).contains(&source) {
                let w = self.0[source as usize];
                *word = match dt {
                    1 => w << 1,
                    -1 => w >> 1,
                    _ => w,
                };
            }
        }
        LegSet(out)
    }

    fn iter(&self) -> impl Iterator<Item = (usize, usize)> + '_ {
        self.0.iter().enumerate().flat_map(|(row, &word)| {
            let mut rest = word;
            std::iter::from_fn(move || {
                if rest == 0 {
                    return None;
                }
                let col = rest.trailing_zeros() as usize;
                rest &= rest - 1;
                Some((row, col))
            })
        })
    }
}

/// The leg configurations the IK can reach, as (clearance, track) step offsets from the
/// default pose, laid out on the rows and columns of a [`LegSet`].
struct LegLattice {
    /// Clearance steps of row 0.
    clearance0: i32,
    /// Track steps of column 0.
    track0: i32,
    reachable: LegSet,
}

impl LegLattice {
    fn new(geometry: &RobotGeometry) -> Self {
        // Far beyond any sensible robot: 64 steps of 0.02 m is 1.28 m.
        const SCAN: i32 = 64;
        let mut found = Vec::new();
        for clearance_steps in -SCAN..=SCAN {
            for track_steps in -SCAN..=SCAN {
                let state = RobotState {
                    clearance_steps,
                    track_steps,
                    ..RobotState::new(Point2::origin(), 0)
                };
                // Exactly the test the simulator applies (RobotParts::new runs this IK).
                if geometry.leg_ik(state.leg_config(geometry)).is_ok() {
                    found.push((clearance_steps, track_steps));
                }
            }
        }
        let clearance0 = found.iter().map(|f| f.0).min().unwrap_or(0);
        let track0 = found.iter().map(|f| f.1).min().unwrap_or(0);
        let mut reachable = LegSet::default();
        for (c, t) in found {
            let (row, col) = ((c - clearance0) as usize, (t - track0) as usize);
            assert!(
                row < LEG_ROWS && col < LEG_COLS,
                "reachable leg lattice exceeds the planner's {LEG_ROWS} x {LEG_COLS} steps"
            );
            reachable.insert(row, col);
        }
        LegLattice {
            clearance0,
            track0,
            reachable,
        }
    }

    /// Row and column of a state's leg configuration, if on the lattice.
    fn cell(&self, state: &RobotState) -> Option<(usize, usize)> {
        let row = usize::try_from(state.clearance_steps - self.clearance0).ok()?;
        let col = usize::try_from(state.track_steps - self.track0).ok()?;
        (row < LEG_ROWS && col < LEG_COLS && self.reachable.contains(row, col))
            .then_some((row, col))
    }

    fn state(&self, pose: &Pose, row: usize, col: usize) -> RobotState {
        RobotState {
            position: pose.position,
            yaw_steps: pose.yaw_steps,
            clearance_steps: self.clearance0 + row as i32,
            track_steps: self.track0 + col as i32,
        }
    }
}

// ---------------------------------------------------------------------------------------------
// Moves, poses, bounding boxes.

/// Base pose: where the body centre is and which way it faces.
#[derive(Clone, Copy, Debug)]
struct Pose {
    position: Point2<f32>,
    yaw_steps: i32,
}

type PoseKey = (i32, i32, i32);

impl Pose {
    fn key(&self) -> PoseKey {
        (
            (self.position.x * 1.0e4).round() as i32,
            (self.position.y * 1.0e4).round() as i32,
            self.yaw_steps,
        )
    }
}

fn step_of(sign: i32) -> Step {
    match sign {
        -1 => Step::Minus,
        1 => Step::Plus,
        _ => Step::Zero,
    }
}

/// One of the 27 base moves, with the leg steps the allowed-action mask permits alongside it.
struct BaseMove {
    /// The move with both leg dimensions at zero.
    action: Action,
    /// Allowed (clearance, track) steps with this move; never the idle action.
    leg_steps: Vec<(i32, i32)>,
}

impl BaseMove {
    fn all(allowed: &[bool; COUNT]) -> Vec<BaseMove> {
        let mut moves = Vec::with_capacity(27);
        for mx in -1..=1 {
            for my in -1..=1 {
                for yaw in -1..=1 {
                    let action = Action {
                        move_x: step_of(mx),
                        move_y: step_of(my),
                        yaw: step_of(yaw),
                        ..Action::IDLE
                    };
                    let leg_steps = (-1..=1)
                        .flat_map(|dc| (-1..=1).map(move |dt| (dc, dt)))
                        .filter(|&(dc, dt)| {
                            let full = Action {
                                clearance: step_of(dc),
                                track: step_of(dt),
                                ..action
                            };
                            full != Action::IDLE && allowed[full.index()]
                        })
                        .collect();
                    moves.push(BaseMove { action, leg_steps });
                }
            }
        }
        moves
    }

    fn with_legs(&self, dc: i32, dt: i32) -> Action {
        Action {
            clearance: step_of(dc),
            track: step_of(dt),
            ..self.action
        }
    }
}

/// Slack added to precomputed bounding boxes: they are computed at the origin and shifted, which
/// rounds differently from the simulator's boxes computed in place (by ~1e-7 m). Only ever makes
/// the fast path fall back to exact checks.
const AABB_SLACK_M: f32 = 1.0e-4;

/// One convex robot part, placed relative to the body centre's ground point.
#[derive(Clone, Copy, Debug)]
enum Convex {
    /// A box: centre, unit axes, half extents along them.
    Cuboid {
        centre: Vector3<f32>,
        axes: [Vector3<f32>; 3],
        half: [f32; 3],
    },
    /// A cylinder: centre, unit axle, half length, radius.
    Cylinder {
        centre: Vector3<f32>,
        axle: Vector3<f32>,
        half_length: f32,
        radius: f32,
    },
    /// A capsule: segment end points, radius.
    Capsule {
        a: Vector3<f32>,
        b: Vector3<f32>,
        radius: f32,
    },
}

impl Convex {
    fn from_part(part: &Part) -> Self {
        match part {
            Part::Body { pose, shape } => Convex::Cuboid {
                centre: pose.translation.vector,
                axes: [
                    pose.rotation * Vector3::x(),
                    pose.rotation * Vector3::y(),
                    pose.rotation * Vector3::z(),
                ],
                half: shape.half_extents.into(),
            },
            // parry's cylinders stand along their local y axis, here the axle.
            Part::Wheel { pose, shape } => Convex::Cylinder {
                centre: pose.translation.vector,
                axle: pose.rotation * Vector3::y(),
                half_length: shape.half_height,
                radius: shape.radius,
            },
            Part::Link(capsule) => Convex::Capsule {
                a: capsule.segment.a.coords,
                b: capsule.segment.b.coords,
                radius: capsule.radius,
            },
        }
    }

    /// Centre and half width of the part's projection on the unit vector `n`.
    fn projection(&self, n: &Vector3<f32>) -> (f32, f32) {
        match self {
            Convex::Cuboid { centre, axes, half } => (
                centre.dot(n),
                (0..3).map(|i| half[i] * axes[i].dot(n).abs()).sum(),
            ),
            Convex::Cylinder {
                centre,
                axle,
                half_length,
                radius,
            } => {
                let along = axle.dot(n);
                (
                    centre.dot(n),
                    half_length * along.abs() + radius * (1.0 - along * along).max(0.0).sqrt(),
                )
            }
            Convex::Capsule { a, b, radius } => {
                (0.5 * (a + b).dot(n), 0.5 * (b - a).dot(n).abs() + radius)
            }
        }
    }
}

/// An obstacle's box, for the separating-axis filter.
#[derive(Clone, Copy, Debug)]
struct ObstacleBox {
    /// As the simulator builds it, loosened by the slack.
    aabb: Aabb,
    centre: Vector3<f32>,
    half: Vector3<f32>,
}

impl ObstacleBox {
    /// The largest gap between the projections of `part`, shifted by `by`, and of this box
    /// over the axes tried (world x, y, z, the body's horizontal axes, a link's horizontal
    /// normal): positive means a separating axis, so they do not touch (both are convex).
    fn gap(&self, part: &Convex, by: &Vector3<f32>, body_axes: &[Vector3<f32>; 2]) -> f32 {
        let gap = |n: &Vector3<f32>| {
            let (centre, half) = part.projection(n);
            let own = self.half.x * n.x.abs() + self.half.y * n.y.abs() + self.half.z * n.z.abs();
            (centre + by.dot(n) - self.centre.dot(n)).abs() - half - own
        };
        let world = [Vector3::x(), Vector3::y(), Vector3::z()];
        let mut best = world
            .iter()
            .chain(body_axes)
            .map(gap)
            .fold(f32::NEG_INFINITY, f32::max);
        if let Convex::Capsule { a, b, .. } = part {
            let d = b - a;
            let normal = Vector3::new(-d.y, d.x, 0.0);
            if normal.norm() > 1.0e-6 {
                best = best.max(gap(&normal.normalize()));
            }
        }
        best
    }
}

/// The robot's parts at one pose relative to its body centre's ground point, with bounding
/// boxes: the whole robot's, and each part's.
#[derive(Clone, Copy, Debug)]
struct PartBoxes {
    whole: Aabb,
    boxes: [Aabb; PART_COUNT],
    parts: [Convex; PART_COUNT],
    /// The body's horizontal axes.
    body_axes: [Vector3<f32>; 2],
}

fn part_boxes(parts: &RobotParts) -> PartBoxes {
    let convex = parts.parts().map(|p| Convex::from_part(&p));
    let body_axes = match convex[0] {
        Convex::Cuboid { axes, .. } => [axes[0], axes[1]],
        _ => [Vector3::x(), Vector3::y()],
    };
    PartBoxes {
        whole: parts.aabb().loosened(AABB_SLACK_M),
        boxes: parts.parts().map(|p| p.aabb().loosened(AABB_SLACK_M)),
        parts: convex,
        body_axes,
    }
}

/// What the cheap geometric tests can tell about a pose, before the simulator's exact test.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
enum Contact {
    /// Surely touches no obstacle.
    Clear,
    /// Surely collides: the body box overlaps an obstacle box.
    Collides,
    /// Within a hair of touching: only the exact test can tell.
    Unknown,
}

/// Classifies the robot's parts, shifted to `position`, against the obstacles.
///
/// The simulator's exact test only looks at part/obstacle pairs whose boxes meet; for those,
/// a separating axis with room to spare proves the pair apart. The body is a box turned about
/// the vertical only, so against an axis-aligned obstacle box the five axes tried (world x, y,
/// z, body x, y) are all the separating-axis theorem needs: overlap on all five, with room to
/// spare, proves a collision. Only what is within the slack of touching is left to the exact
/// test.
fn classify(boxes: &PartBoxes, position: Point2<f32>, obstacles: &[ObstacleBox]) -> Contact {
    let by = Vector3::new(position.x, position.y, 0.0);
    let whole = shifted(&boxes.whole, position);
    let mut unknown = false;
    for o in obstacles.iter().filter(|o| o.aabb.intersects(&whole)) {
        for (index, (b, part)) in boxes.boxes.iter().zip(&boxes.parts).enumerate() {
            if !o.aabb.intersects(&shifted(b, position)) {
                continue;
            }
            match o.gap(part, &by, &boxes.body_axes) {
                gap if gap > AABB_SLACK_M => {}
                gap if index == 0 && gap < -AABB_SLACK_M => return Contact::Collides,
                _ => unknown = true,
            }
        }
    }
    if unknown {
        Contact::Unknown
    } else {
        Contact::Clear
    }
}

/// The robot's boxes at one yaw, per leg configuration (indexed `row * LEG_COLS + col`) and the
/// whole robot over all of them.
struct YawBoxes {
    all: Aabb,
    /// Reachable configurations only, in the order of `ordinal`.
    per_config: Vec<PartBoxes>,
    /// Index into `per_config` of cell `row * LEG_COLS + col`.
    ordinal: Vec<u16>,
}

impl YawBoxes {
    fn get(&self, row: usize, col: usize) -> &PartBoxes {
        &self.per_config[self.ordinal[row * LEG_COLS + col] as usize]
    }
}

impl YawBoxes {
    fn new(geometry: &RobotGeometry, lattice: &LegLattice, yaw_steps: i32) -> Self {
        let origin = Pose {
            position: Point2::origin(),
            yaw_steps,
        };
        let mut per_config = Vec::with_capacity(LEG_ROWS * LEG_COLS);
        let mut ordinal = vec![u16::MAX; LEG_ROWS * LEG_COLS];
        let mut all = Aabb::new_invalid();
        for (row, col) in lattice.reachable.iter() {
            let state = lattice.state(&origin, row, col);
            let parts = RobotParts::new(
                geometry,
                state.position,
                state.yaw_rad(),
                state.leg_config(geometry),
            )
            .expect("reachable by construction of the lattice");
            let boxes = part_boxes(&parts);
            all.merge(&boxes.whole);
            ordinal[row * LEG_COLS + col] = per_config.len() as u16;
            per_config.push(boxes);
        }
        YawBoxes {
            all,
            per_config,
            ordinal,
        }
    }
}

fn shifted(aabb: &Aabb, position: Point2<f32>) -> Aabb {
    let by = Vector3::new(position.x, position.y, 0.0);
    Aabb::new(aabb.mins + by, aabb.maxs + by)
}

/// Half of the most any point of the robot moves in one step, rounded up
/// ([`Env::motion_bound_m`]: a diagonal move 0.071 m, a 5 degree turn at 0.45 m reach 0.04 m,
/// a leg step a few centimetres). The planner looks for obstacles this far around a step's
/// ends; a larger bound is left to the simulator.
const SWEEP_GROW_M: f32 = 0.1;

/// Whether some part, grown by `grow_m` around the span of its boxes at the start (`start`
/// shifted to `from`) and at the end (`end` shifted to `to`), meets an obstacle box: the
/// simulator's `ObstacleSet::sweep_may_touch` on the planner's (slightly larger) boxes, so a
/// step this finds clear the simulator accepts without further tests.
fn sweep_meets(
    start: &PartBoxes,
    from: Point2<f32>,
    end: &PartBoxes,
    to: Point2<f32>,
    grow_m: f32,
    obstacles: &[ObstacleBox],
) -> bool {
    let whole = shifted(&start.whole, from)
        .merged(&shifted(&end.whole, to))
        .loosened(grow_m);
    obstacles
        .iter()
        .filter(|o| o.aabb.intersects(&whole))
        .any(|o| {
            start.boxes.iter().zip(&end.boxes).any(|(a, b)| {
                shifted(a, from)
                    .merged(&shifted(b, to))
                    .loosened(grow_m)
                    .intersects(&o.aabb)
            })
        })
}

/// How far [`state_clearance_m`] looks for a lattice state's clearance: more than the cap of
/// any step's proof ([`proof_cap_m`] of the largest motion bound, about 0.08 m).
const STATE_CAP_M: f32 = 0.25;

/// What [`state_clearance_m`] takes off for rounding: its bound comes from the same function
/// as the simulator's, with another cap (and possibly another position, a few ulps away), so
/// it may differ from the simulator's in the last bits; 5 um is far more than that (a few
/// ulps of the positions here are under 1 um) and far less than anything that matters.
const STATE_MARGIN_M: f32 = 5.0e-6;

/// Per lattice state (pose key, leg cell): the position its bound was computed at and
/// `ObstacleSet::clearance_lower_bound_m` up to [`STATE_CAP_M`] there.
type StateClearance = FastMap<(PoseKey, usize), (Point2<f32>, f32)>;

/// A lower bound on the clearance the simulator's proof of a step sees at the lattice state
/// `state` (pose key `key`, leg cell `cell`) at either end of a step whose proof caps its ends
/// at `cap_m` (never above [`STATE_CAP_M`]): the simulator's cheap bound there is
/// `clearance_lower_bound_m(parts, cap_m)`, which is `min(cap_m, B) - slack` for the parts'
/// box-gap bound `B`, and its exact value, when it asks parry, is no lower. Worked out once per
/// state, at the first position met with the key; a position `d` away from it (the same
/// lattice pose reached by another sequence of moves, rounding differently) has a clearance at
/// most `d` lower (every part moves by `d`).
fn state_clearance_m(
    env: &Env,
    cache: &mut StateClearance,
    state: &RobotState,
    key: PoseKey,
    cell: usize,
    cap_m: f32,
) -> f32 {
    let (at, bound_m) = *cache.entry((key, cell)).or_insert_with(|| {
        let geometry = env.geometry();
        let bound_m = place_parts(
            geometry,
            state.position,
            state.yaw_rad(),
            state.leg_config(geometry),
        )
        .map_or(f32::NEG_INFINITY, |parts| {
            env.obstacles()
                .parts_clearance_lower_bound_m(&parts, env.reach_m(), STATE_CAP_M, None)
        });
        (state.position, bound_m)
    });
    (cap_m - CLEARANCE_SLACK_M).min(bound_m) - (state.position - at).norm() - STATE_MARGIN_M
}

/// Stretches the planner's proof holds at once (one per halving level: a step's motion halves
/// below the graze tolerance in 11 levels); deeper, the simulator decides.
const WAY_PROOF_STACK: usize = 24;

/// Whether the simulator's proof of the way from `from` to `to` (`Env::check_transition`,
/// motion bound `bound_m`) surely succeeds, decided without parry: the end pose is already
/// known clear (the caller's test), and this replays the simulator's bisection with the cheap
/// bounds alone, each no higher than the value the simulator uses at the same pose.
///
/// The simulator splits a stretch only when its values at the ends do not cover the travel;
/// these values are lower, so this proof splits that stretch too, at the same fraction, with the
/// same caps. So every pose the simulator places is placed here (the same `Env::pose_between`:
/// a pose the legs cannot take ends this proof), every stretch the simulator ends with is one
/// this proof covered, and none is shorter than the graze tolerance. A pose whose cheap bound is
/// not above 0 ends this proof (the simulator might ask parry there and find it touching),
/// except the start, which the simulator counts as 0. The verdict is the simulator's: this only
/// ever says yes where it says yes, and the caller asks the simulator whenever this says no.
///
/// `from` and `to` come with their pose keys and leg cells, for [`state_clearance_m`].
fn way_proven(
    env: &Env,
    cache: &mut StateClearance,
    (from, from_key, from_cell): (&RobotState, PoseKey, usize),
    (to, to_key, to_cell): (&RobotState, PoseKey, usize),
    bound_m: f32,
) -> bool {
    let cap_m = proof_cap_m(bound_m);
    if cap_m > STATE_CAP_M {
        return false;
    }
    let end_m = state_clearance_m(env, cache, to, to_key, to_cell, cap_m);
    if end_m <= 0.0 {
        return false;
    }
    let start_m = state_clearance_m(env, cache, from, from_key, from_cell, cap_m).max(0.0);
    // Every pose on the way has its centre within the motion bound of the start, every part
    // within the reach of its centre, and only clearances up to the cap count.
    let near = env
        .obstacles()
        .near(from.position, env.reach_m() + bound_m + cap_m);
    // Stretches still to prove: (fraction, clearance bound) at each end.
    let mut open: heapless::Vec<((f32, f32), (f32, f32)), WAY_PROOF_STACK> = heapless::Vec::new();
    open.push(((0.0, start_m), (1.0, end_m)))
        .expect("room for one");
    while let Some(((a_t, a_m), (b_t, b_m))) = open.pop() {
        let travel_m = bound_m * (b_t - a_t);
        if a_m + b_m > travel_m {
            continue;
        }
        if travel_m < GRAZE_TOLERANCE_M {
            return false;
        }
        let t = 0.5 * (a_t + b_t);
        let Ok(parts) = env.parts_between(from, to, t) else {
            return false;
        };
        let mid_m = env.obstacles().parts_clearance_lower_bound_m(
            &parts,
            env.reach_m(),
            proof_cap_m(travel_m),
            Some(&near),
        ) - STATE_MARGIN_M;
        if mid_m <= 0.0 {
            return false;
        }
        if open.push(((t, mid_m), (b_t, b_m))).is_err()
            || open.push(((a_t, a_m), (t, mid_m))).is_err()
        {
            return false;
        }
    }
    true
}

// ---------------------------------------------------------------------------------------------
// Heuristic.

/// Length of the longest step (a diagonal move).
const DIAGONAL_STEP_M: f32 = MOVE_STEP_M * core::f32::consts::SQRT_2;

/// Lower bound on the steps from a pose to success: the larger of two bounds, both pose-only.
///
/// - Detour: the remaining travel through the places the body centre can be at all (a distance
///   field around the blocks, [`DistanceField`]) at the longest possible step.
/// - Heading: the straight-line progress towards the target. A step's progress along the unit
///   vector `u` towards the target is at most `0.05 sqrt(2) cos(delta)`, where `delta` is the
///   angle between `u` and the nearest of the robot's four diagonal move directions (an axis move
///   gives `0.05 cos(45 deg - delta)`, never more for `delta <= 45 deg`). Yaw turns 5 degrees per
///   step at most, and the step's move uses the yaw before the turn, so step `i` has
///   `delta_i >= delta_0 - 5 i` degrees. Reaching the success circle needs a total progress along
///   `u` of at least the distance minus the success radius.
struct Heuristic {
    field: DistanceField,
    target: Point2<f32>,
    success_radius_m: f32,
}

impl Heuristic {
    fn steps(&self, pose: &Pose) -> u32 {
        let d = self.target - pose.position;
        // 1e-4 m of slack keeps the bounds admissible under float rounding.
        let straight_m = d.norm() - self.success_radius_m - 1.0e-4;
        if straight_m <= 0.0 {
            return 0;
        }
        let field_m = self.field.lower_bound_m(pose.position) - 1.0e-4;
        let detour = (field_m / DIAGONAL_STEP_M).ceil().max(0.0);
        let heading = heading_steps(straight_m, d.y.atan2(d.x) - pose_yaw_rad(pose));
        if detour.is_infinite() {
            return u32::MAX / 4;
        }
        (detour as u32).max(heading)
    }
}

fn pose_yaw_rad(pose: &Pose) -> f32 {
    RobotState::new(pose.position, pose.yaw_steps).yaw_rad()
}

/// Fewest steps whose progress along a direction `alpha_rad` (relative to the robot's heading)
/// can add up to `need_m` (see [`Heuristic`]).
fn heading_steps(need_m: f32, alpha_rad: f32) -> u32 {
    use core::f32::consts::{FRAC_PI_2, FRAC_PI_4};
    let from_diagonal = (alpha_rad - FRAC_PI_4).rem_euclid(FRAC_PI_2);
    let mut delta = from_diagonal.min(FRAC_PI_2 - from_diagonal);
    let turn = wheelleg_runtime::action::YAW_STEP_DEG.to_radians();
    // Tiny relative slack: cos and the sum round; overestimating progress keeps this a bound.
    let best_step_m = DIAGONAL_STEP_M * (1.0 + 1.0e-5);
    let mut progress_m = 0.0;
    let mut steps = 0;
    while delta > 0.0 {
        if progress_m >= need_m {
            return steps;
        }
        progress_m += best_step_m * delta.cos();
        steps += 1;
        delta -= turn;
    }
    let rest_m = (need_m - progress_m).max(0.0);
    steps + (rest_m / best_step_m).ceil() as u32
}

/// Ordering hint for the weighted search only: the leg steps and the turn that a low obstacle
/// ahead calls for.
///
/// A low obstacle (a slab or a bar) on the way is passed by straddling it, lined up with its
/// length, in the pose the generator documents ([`passing_legs`]: spread and low for a slab,
/// lifted for a bar). A spread scene needs up to ten track steps before its fence, and the
/// pose-only [`Heuristic`] cannot see them: it leads the search to the fence early, legs still
/// narrow and turned to a diagonal heading, and the search then widens over every pose in front
/// of the fence at every step count (the weighted search ran out of 20,000 expansions on 3 of 4
/// spread scenes). This hint says that a robot whose straight way to the target enters such an
/// obstacle's reach needs, by the entry, the leg steps to the passing pose and the turn to within
/// [`LINED_UP_DEG`] of lined up, then the way on from the entry to the target. With it the
/// weighted search finds spread scenes in a few hundred expansions at most.
///
/// It is **not** a lower bound (the robot may go around, or pass in another pose), so it only
/// orders the weighted fallback search, whose plans are never claimed shortest. The step
/// limit's pruning keeps using the admissible [`Heuristic`], so a weighted search that exhausts
/// the space still proves a scene unsolvable.
struct LegHint {
    zones: Vec<StraddleZone>,
}

/// A low obstacle's footprint, grown by the robot's reach ahead of its centre, with the leg
/// steps from every lattice cell to its passing pose.
struct StraddleZone {
    min: Point2<f32>,
    max: Point2<f32>,
    /// Chebyshev distance in leg steps from cell `row * LEG_COLS + col` to the passing pose.
    leg_steps: Vec<u8>,
    /// Heading (yaw steps, modulo half a turn) along which the robot straddles the obstacle:
    /// along its length, the world axis its first size dimension lies on.
    along_yaw_steps: i32,
}

/// How far from lined up with an obstacle (degrees) the hint still counts the robot as lined up.
const LINED_UP_DEG: f32 = 10.0;

impl LegHint {
    fn new(env: &Env, lattice: &LegLattice) -> Self {
        let geometry = env.geometry();
        // The wheels reach this far ahead of the body centre: they meet the obstacle when the
        // centre is this close to it, so the legs must be ready by then.
        let reach_m = geometry.hip_x_m + geometry.wheel_radius_m;
        let zones = env
            .obstacles()
            .boxes()
            .iter()
            .filter_map(|b| {
                let (kind, behaviour) = [
                    (ObstacleKind::Slab, Behaviour::SpreadOver),
                    (ObstacleKind::Bar, Behaviour::LiftOver),
                ]
                .into_iter()
                .find(|(kind, _)| kind.size_m().2 == b.height_m)?;
                let (clearance, track) = passing_legs(behaviour);
                // The side nearer the kind's length: exact for the generator's boxes, and
                // still right for a perceived one, grown and cut to map cells
                // ([`crate::local_plan`]).
                let length_m = kind.size_m().0;
                let along_x = (b.max_x_m - b.min_x_m - length_m).abs()
                    <= (b.max_y_m - b.min_y_m - length_m).abs();
                let along_yaw_steps = if along_x { 0 } else { YAW_STEPS_PER_TURN / 4 };
                let (row, col) = (clearance - lattice.clearance0, track - lattice.track0);
                let leg_steps = (0..LEG_ROWS * LEG_COLS)
                    .map(|cell| {
                        let (r, c) = ((cell / LEG_COLS) as i32, (cell % LEG_COLS) as i32);
                        (r - row).abs().max((c - col).abs()).min(u8::MAX as i32) as u8
                    })
                    .collect();
                Some(StraddleZone {
                    min: Point2::new(b.min_x_m - reach_m, b.min_y_m - reach_m),
                    max: Point2::new(b.max_x_m + reach_m, b.max_y_m + reach_m),
                    leg_steps,
                    along_yaw_steps,
                })
            })
            .collect();
        LegHint { zones }
    }

    /// The hint's steps for a robot at `position` in any of the leg configurations `legs`: for
    /// every zone the straight way to the target enters, the legs must reach the passing pose
    /// by the entry (the larger of the leg steps and the way there), then the robot goes on
    /// from the entry to the target; the largest of these.
    fn steps(&self, pose: &Pose, target: Point2<f32>, legs: &LegSet) -> u32 {
        let position = pose.position;
        let whole_m = (target - position).norm();
        let half_turn = YAW_STEPS_PER_TURN / 2;
        let step_deg = wheelleg_runtime::action::YAW_STEP_DEG;
        self.zones
            .iter()
            .filter_map(|z| {
                let entry = segment_entry(position, target, z.min, z.max)?;
                let legs_steps = legs
                    .iter()
                    .map(|(row, col)| z.leg_steps[row * LEG_COLS + col])
                    .min()
                    .unwrap_or(0) as u32;
                let off = (pose.yaw_steps - z.along_yaw_steps).rem_euclid(half_turn);
                let off_deg = off.min(half_turn - off) as f32 * step_deg;
                let turn_steps = ((off_deg - LINED_UP_DEG).max(0.0) / step_deg).ceil() as u32;
                let to_entry = (entry * whole_m / DIAGONAL_STEP_M).ceil() as u32;
                let from_entry = ((1.0 - entry) * whole_m / DIAGONAL_STEP_M).ceil() as u32;
                Some(legs_steps.max(turn_steps).max(to_entry) + from_entry)
            })
            .max()
            .unwrap_or(0)
    }
}

/// Where the segment from `a` to `b` enters the axis-aligned rectangle `min`..`max`, as a
/// fraction of the way (0 when `a` is inside), if it meets it (Liang-Barsky clipping).
fn segment_entry(
    a: Point2<f32>,
    b: Point2<f32>,
    min: Point2<f32>,
    max: Point2<f32>,
) -> Option<f32> {
    let d = b - a;
    let (mut t0, mut t1) = (0.0f32, 1.0f32);
    for (p, q) in [
        (-d.x, a.x - min.x),
        (d.x, max.x - a.x),
        (-d.y, a.y - min.y),
        (d.y, max.y - a.y),
    ] {
        if p == 0.0 {
            if q < 0.0 {
                return None;
            }
        } else {
            let t = q / p;
            if p < 0.0 {
                t0 = t0.max(t);
            } else {
                t1 = t1.min(t);
            }
            if t0 > t1 {
                return None;
            }
        }
    }
    Some(t0)
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
        let min = Point2::new(
            start.x.min(target.x) - margin,
            start.y.min(target.y) - margin,
        );
        let cols = ((start.x.max(target.x) + margin - min.x) / FIELD_CELL_M).ceil() as usize + 1;
        let rows = ((start.y.max(target.y) + margin - min.y) / FIELD_CELL_M).ceil() as usize + 1;
        let half_width_m = 0.5 * env.geometry().body_width_m;
        let blocked_within_m = half_width_m - FIELD_CELL_M * core::f32::consts::FRAC_1_SQRT_2;
        let blocks: Vec<_> = env
            .obstacles()
            .boxes()
            .iter()
            .filter(|b| {
                b.height_m > env.geometry().clearance_range_m[1] + env.geometry().body_thickness_m
            })
            .copied()
            .collect();
        let centre = |c: usize, r: usize| {
            Point2::new(
                min.x + c as f32 * FIELD_CELL_M,
                min.y + r as f32 * FIELD_CELL_M,
            )
        };
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
        for (i, m) in metres.iter_mut().enumerate() {
            if (centre(i % cols, i / cols) - target).norm() <= goal_m {
                *m = 0.0;
                queue.push((std::cmp::Reverse(OrderedF32(0.0)), i));
            }
        }
        const MOVES: [(i32, i32); 16] = [
            (1, 0),
            (-1, 0),
            (0, 1),
            (0, -1),
            (1, 1),
            (1, -1),
            (-1, 1),
            (-1, -1),
            (2, 1),
            (2, -1),
            (-2, 1),
            (-2, -1),
            (1, 2),
            (1, -2),
            (-1, 2),
            (-1, -2),
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
        DistanceField {
            min,
            cols,
            rows,
            metres,
        }
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

#[derive(PartialEq)]
struct OrderedF32(f32);
impl Eq for OrderedF32 {}
impl Ord for OrderedF32 {
    fn cmp(&self, other: &Self) -> Ordering {
        self.0.total_cmp(&other.0)
    }
}
impl PartialOrd for OrderedF32 {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

// ---------------------------------------------------------------------------------------------
// The search.

/// FxHash-style hasher for the small integer keys of the search: the default SipHash costs more
/// than the rest of a fast-path successor.
#[derive(Default)]
struct FastHasher(u64);

impl Hasher for FastHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write(&mut self, bytes: &[u8]) {
        for &b in bytes {
            self.write_u64(b as u64);
        }
    }

    fn write_i32(&mut self, i: i32) {
        self.write_u64(i as u32 as u64);
    }

    fn write_u16(&mut self, i: u16) {
        self.write_u64(i as u64);
    }

    fn write_u64(&mut self, i: u64) {
        self.0 = (self.0.rotate_left(5) ^ i).wrapping_mul(0x51_7c_c1_b7_27_22_0a_95);
    }
}

type FastMap<K, V> = HashMap<K, V, BuildHasherDefault<FastHasher>>;

struct Node {
    pose: Pose,
    legs: LegSet,
    steps: u32,
    parent: u32,
    /// Index into the base moves of the move from the parent.
    base_move: u8,
    /// Dominated by a node found later: skipped when popped.
    dead: bool,
    /// Within the success radius (queued only to be accepted when it is the best in the queue).
    goal: bool,
}

#[derive(PartialEq)]
struct Open {
    f: f32,
    steps: u32,
    node: u32,
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

struct Search<'a> {
    env: &'a Env,
    config: &'a PlannerConfig,
    lattice: LegLattice,
    moves: Vec<BaseMove>,
    heuristic: Heuristic,
    /// Leg-aware ordering hint, for the weighted search only (`None` when exact).
    leg_hint: Option<LegHint>,
    /// Bounding boxes per yaw step, computed when the yaw is first met.
    boxes: Vec<Option<YawBoxes>>,
    /// Whether the robot at a pose with a leg configuration (row * LEG_COLS + col) is clear of
    /// every obstacle; the same end pose is reached from many parents.
    end_clear: FastMap<(PoseKey, u16), bool>,
    in_arena: FastMap<PoseKey, bool>,
    /// Lower bounds on the clearance of lattice states, for [`way_proven`]; see
    /// [`state_clearance_m`].
    state_clearance: StateClearance,
    /// Whether every step [`way_proven`] accepts is also put to `Env::check_transition`, which
    /// must accept it (tests of this module).
    cross_check: bool,
    /// Steps so checked.
    cross_checked: usize,
    /// The obstacles' boxes, as the simulator builds them, loosened by the slack.
    obstacle_boxes: Vec<ObstacleBox>,
    give_up_m: f32,
    max_steps: u32,
    nodes: Vec<Node>,
    /// Per pose, the live nodes that reached it (for dominance).
    seen: FastMap<PoseKey, Vec<u32>>,
    open: BinaryHeap<Open>,
}

impl<'a> Search<'a> {
    fn new(env: &'a Env, config: &'a PlannerConfig, max_steps: u32) -> Self {
        let start = *env.state();
        let lattice = LegLattice::new(env.geometry());
        let heuristic = Heuristic {
            field: DistanceField::new(env, start.position),
            target: env.target(),
            success_radius_m: env.config().success_radius_m,
        };
        let leg_hint = (config.heuristic_weight > 1.0).then(|| LegHint::new(env, &lattice));
        Search {
            env,
            config,
            moves: BaseMove::all(&config.allowed),
            heuristic,
            leg_hint,
            boxes: (0..YAW_STEPS_PER_TURN).map(|_| None).collect(),
            end_clear: FastMap::default(),
            in_arena: FastMap::default(),
            state_clearance: FastMap::default(),
            cross_check: false,
            cross_checked: 0,
            obstacle_boxes: env
                .obstacles()
                .boxes()
                .iter()
                .map(|b| ObstacleBox {
                    aabb: Aabb::new(
                        Point3::new(b.min_x_m, b.min_y_m, 0.0),
                        Point3::new(b.max_x_m, b.max_y_m, b.height_m),
                    )
                    .loosened(AABB_SLACK_M),
                    centre: b.centre(),
                    half: b.half_extents(),
                })
                .collect(),
            // The episode gives up beyond its start distance plus the margin; the planner starts
            // from the current state, which is the start for every caller that plans a scene.
            give_up_m: (env.target() - start.position).norm() + env.config().give_up_margin_m,
            max_steps: env
                .config()
                .max_steps
                .saturating_sub(env.steps())
                .min(max_steps),
            lattice,
            nodes: Vec::new(),
            seen: FastMap::default(),
            open: BinaryHeap::new(),
        }
    }

    fn run(&mut self) -> Plan {
        let start = *self.env.state();
        let Some((row, col)) = self.lattice.cell(&start) else {
            // The simulator never lets the robot stand in an unreachable leg pose.
            return Plan {
                outcome: PlanOutcome::Unsolvable,
                expansions: 0,
            };
        };
        let mut legs = LegSet::default();
        legs.insert(row, col);
        let pose = Pose {
            position: start.position,
            yaw_steps: start.yaw_steps,
        };
        self.nodes.push(Node {
            pose,
            legs,
            steps: 0,
            parent: 0,
            base_move: 0,
            dead: false,
            goal: false,
        });
        self.seen.insert(pose.key(), vec![0]);
        self.open.push(Open {
            f: 0.0,
            steps: 0,
            node: 0,
        });
        let mut expansions = 0;
        let shortest = self.config.heuristic_weight <= 1.0;
        while let Some(Open { f, node, .. }) = self.open.pop() {
            if self.nodes[node as usize].dead {
                continue;
            }
            if self.nodes[node as usize].goal {
                return self.solved(node, shortest, expansions);
            }
            if expansions >= self.config.max_expansions {
                return Plan {
                    outcome: PlanOutcome::BudgetExceeded,
                    expansions,
                };
            }
            expansions += 1;
            if self.nodes[node as usize].steps >= self.max_steps {
                continue;
            }
            if let Some(goal) = self.expand(node, f) {
                return self.solved(goal, shortest, expansions);
            }
        }
        Plan {
            outcome: PlanOutcome::Unsolvable,
            expansions,
        }
    }

    fn solved(&self, goal: u32, shortest: bool, expansions: usize) -> Plan {
        Plan {
            outcome: PlanOutcome::Solved {
                actions: self.actions_to(goal),
                shortest,
            },
            expansions,
        }
    }

    /// Queues the successors of `node` (popped with priority `f`); returns a goal node that can
    /// be accepted at once.
    fn expand(&mut self, node: u32, f: f32) -> Option<u32> {
        let (pose, legs, steps) = {
            let n = &self.nodes[node as usize];
            (n.pose, n.legs, n.steps)
        };
        let from = RobotState::new(pose.position, pose.yaw_steps);
        for m in 0..self.moves.len() {
            let next = from.after(self.moves[m].action);
            let next_pose = Pose {
                position: next.position,
                yaw_steps: next.yaw_steps,
            };
            let key = next_pose.key();
            let distance_m = (self.env.target() - next_pose.position).norm();
            if distance_m > self.give_up_m || !self.inside_arena(&next_pose, key) {
                continue;
            }
            let mut candidates = LegSet::default();
            for &(dc, dt) in &self.moves[m].leg_steps {
                candidates.union_with(&legs.shifted(dc, dt));
            }
            let candidates = candidates.intersection(&self.lattice.reachable);
            let next_steps = steps + 1;
            let goal = distance_m <= self.env.config().success_radius_m;
            let h = if goal {
                0
            } else {
                self.heuristic.steps(&next_pose)
            };
            if next_steps.saturating_add(h) > self.max_steps {
                // Even the most optimistic continuation runs past the step limit; dropping it
                // loses nothing and lets small step limits prove scenes unsolvable quickly.
                continue;
            }
            // The valid set is a subset of the candidates: if they are dominated, so is it, and
            // the collision checks can be skipped.
            if candidates.is_empty() || self.is_dominated(key, next_steps, &candidates) {
                continue;
            }
            let next_legs = self.valid_subset(&pose, &legs, m, &next_pose, key, &candidates);
            if next_legs.is_empty() || self.is_dominated(key, next_steps, &next_legs) {
                continue;
            }
            self.retire_dominated(key, next_steps, &next_legs);
            let index = self.nodes.len() as u32;
            self.nodes.push(Node {
                pose: next_pose,
                legs: next_legs,
                steps: next_steps,
                parent: node,
                base_move: m as u8,
                dead: false,
                goal,
            });
            self.seen.entry(key).or_default().push(index);
            if goal && (self.config.heuristic_weight > 1.0 || next_steps as f32 <= f) {
                // Every plan still queued costs at least the popped f (the heuristic never
                // overestimates), so a goal no deeper than f is shortest. A deeper goal waits in
                // the queue at f = its steps until nothing better is left.
                return Some(index);
            }
            // The weighted search orders by the leg hint too; the pruning above keeps to the
            // admissible `h`, so exhausting the space still proves the scene unsolvable.
            let order_h = match &self.leg_hint {
                Some(hint) if !goal => h.max(hint.steps(&next_pose, self.env.target(), &next_legs)),
                _ => h,
            };
            let f = next_steps as f32 + self.config.heuristic_weight * order_h as f32;
            self.open.push(Open {
                f,
                steps: next_steps,
                node: index,
            });
        }
        None
    }

    /// Whether `pose` is inside the arena. The simulator checks the arena before anything else,
    /// so a transition to an unreachable leg pose answers exactly that question, cheaply.
    fn inside_arena(&mut self, pose: &Pose, key: PoseKey) -> bool {
        let env = self.env;
        *self.in_arena.entry(key).or_insert_with(|| {
            let here = RobotState::new(pose.position, pose.yaw_steps);
            let probe = RobotState {
                track_steps: i32::MAX / 4,
                ..here
            };
            env.check_transition(&here, &probe) != Err(InvalidAction::OutOfBounds)
        })
    }

    /// The members of `candidates` the robot can take at `next` by move `m` from some member
    /// of `legs` at `pose`.
    ///
    /// Mirrors the simulator's `check_transition` with cheap sufficient tests first, and asks
    /// the simulator itself whenever they do not settle a case, so it never accepts a
    /// transition the simulator would refuse (the replay of every plan checks this):
    /// - the end pose: the simulator's exact test only looks at part/obstacle pairs whose
    ///   boxes meet, so an end pose whose boxes meet no obstacle's box is clear (first tested
    ///   for the box over all leg configurations at this yaw, then per candidate), and one
    ///   that the separating-axis tests of [`classify`] settle needs no exact test;
    /// - the way there: the simulator accepts it without a proof when no part's span of start
    ///   and end boxes, grown by half the step's motion bound, meets an obstacle box
    ///   ([`sweep_meets`]); otherwise the simulator decides.
    fn valid_subset(
        &mut self,
        pose: &Pose,
        legs: &LegSet,
        m: usize,
        next: &Pose,
        key: PoseKey,
        candidates: &LegSet,
    ) -> LegSet {
        let env = self.env;
        let geometry = env.geometry();
        let yaw = next.yaw_steps as usize;
        if self.boxes[yaw].is_none() {
            self.boxes[yaw] = Some(YawBoxes::new(geometry, &self.lattice, next.yaw_steps));
        }
        let all = shifted(
            &self.boxes[yaw].as_ref().expect("just filled").all,
            next.position,
        );
        let near: Vec<ObstacleBox> = self
            .obstacle_boxes
            .iter()
            .filter(|o| o.aabb.intersects(&all))
            .copied()
            .collect();
        let from_yaw = pose.yaw_steps as usize;
        if self.boxes[from_yaw].is_none() {
            self.boxes[from_yaw] = Some(YawBoxes::new(geometry, &self.lattice, pose.yaw_steps));
        }
        // Obstacles the way there could meet: near either end's boxes over every leg pose,
        // grown by the most any point moves in half a step.
        let span = shifted(
            &self.boxes[from_yaw].as_ref().expect("just filled").all,
            pose.position,
        )
        .merged(&all)
        .loosened(SWEEP_GROW_M);
        let near_way: Vec<ObstacleBox> = self
            .obstacle_boxes
            .iter()
            .filter(|o| o.aabb.intersects(&span))
            .copied()
            .collect();
        if near.is_empty() && near_way.is_empty() {
            return *candidates;
        }
        let mut valid = LegSet::default();
        for (row, col) in candidates.iter() {
            let cell = row * LEG_COLS + col;
            let end_boxes = self.boxes[yaw].as_ref().expect("just filled").get(row, col);
            let end_whole = shifted(&end_boxes.whole, next.position);
            let end_near = near.iter().any(|o| o.aabb.intersects(&end_whole));
            if !end_near && near_way.is_empty() {
                valid.insert(row, col);
                continue;
            }
            let to = self.lattice.state(next, row, col);
            let end_clear = match classify(end_boxes, next.position, &near) {
                _ if !end_near => true,
                Contact::Clear => true,
                Contact::Collides => false,
                Contact::Unknown => {
                    *self.end_clear.entry((key, cell as u16)).or_insert_with(|| {
                        RobotParts::new(
                            geometry,
                            to.position,
                            to.yaw_rad(),
                            to.leg_config(geometry),
                        )
                        .is_ok_and(|parts| !env.obstacles().collides(&parts))
                    })
                }
            };
            if !end_clear {
                continue;
            }
            // The planner's own tests first, for every predecessor; the simulator only for a
            // candidate none of them settles. Only whether some predecessor's step is valid
            // matters, not which.
            let mut unsettled: heapless::Vec<RobotState, 9> = heapless::Vec::new();
            let mut ok = false;
            for &(dc, dt) in &self.moves[m].leg_steps {
                let (r, c) = (row as i32 - dc, col as i32 - dt);
                if r < 0 || c < 0 || !legs.contains(r as usize, c as usize) {
                    continue;
                }
                let from = self.lattice.state(pose, r as usize, c as usize);
                // A leg pose the legs cannot take on the way is refused by the simulator.
                let Ok(bound_m) = env.motion_bound_m(&from, &to) else {
                    continue;
                };
                // Every point of a part stays within half the motion bound of where it is at
                // one end: when no part's span of start and end, grown by that, meets an
                // obstacle box, the simulator's own first sweep test accepts the step.
                let start_boxes = self.boxes[from_yaw]
                    .as_ref()
                    .expect("filled above")
                    .get(r as usize, c as usize);
                let sweep_clear = 0.5 * bound_m <= SWEEP_GROW_M
                    && !sweep_meets(
                        start_boxes,
                        pose.position,
                        end_boxes,
                        next.position,
                        0.5 * bound_m,
                        &near_way,
                    );
                if sweep_clear {
                    ok = true;
                    break;
                }
                if way_proven(
                    env,
                    &mut self.state_clearance,
                    (&from, pose.key(), r as usize * LEG_COLS + c as usize),
                    (&to, key, cell),
                    bound_m,
                ) {
                    if self.cross_check {
                        self.cross_checked += 1;
                        assert_eq!(
                            env.check_transition(&from, &to),
                            Ok(()),
                            "the planner's proof accepted {from:?} -> {to:?}"
                        );
                    }
                    ok = true;
                    break;
                }
                unsettled.push(from).expect("at most 9 leg steps");
            }
            if ok
                || unsettled
                    .iter()
                    .any(|from| env.check_transition(from, &to).is_ok())
            {
                valid.insert(row, col);
            }
        }
        valid
    }

    /// Whether a node already known at the pose has no more steps and a superset of the leg
    /// configurations: whatever a new node could do, that one does as well or sooner.
    fn is_dominated(&self, key: PoseKey, steps: u32, legs: &LegSet) -> bool {
        self.seen.get(&key).is_some_and(|known| {
            known.iter().any(|&k| {
                let n = &self.nodes[k as usize];
                n.steps <= steps && legs.is_subset_of(&n.legs)
            })
        })
    }

    /// Retires the known nodes at the pose that a new node with `steps` and `legs` dominates.
    fn retire_dominated(&mut self, key: PoseKey, steps: u32, legs: &LegSet) {
        let Some(known) = self.seen.get_mut(&key) else {
            return;
        };
        let nodes = &mut self.nodes;
        known.retain(|&k| {
            let n = &mut nodes[k as usize];
            let worse = steps <= n.steps && n.legs.is_subset_of(legs);
            n.dead |= worse;
            !worse
        });
    }

    /// The actions from the start to `goal`: walking back from any leg configuration of the
    /// goal, each step picks a configuration of the parent's set from which the simulator
    /// accepts the transition (one exists: that is how the configuration got into the set).
    fn actions_to(&self, goal: u32) -> Vec<Action> {
        let mut node = goal;
        let (mut row, mut col) = self.nodes[node as usize]
            .legs
            .iter()
            .next()
            .expect("nodes are never empty");
        let mut actions = Vec::with_capacity(self.nodes[node as usize].steps as usize);
        while node != 0 {
            let n = &self.nodes[node as usize];
            let parent = &self.nodes[n.parent as usize];
            let base = &self.moves[n.base_move as usize];
            let to = self.lattice.state(&n.pose, row, col);
            let (dc, dt) = base
                .leg_steps
                .iter()
                .copied()
                .find(|&(dc, dt)| {
                    let (r, c) = (row as i32 - dc, col as i32 - dt);
                    r >= 0
                        && c >= 0
                        && parent.legs.contains(r as usize, c as usize)
                        && self
                            .env
                            .check_transition(
                                &self.lattice.state(&parent.pose, r as usize, c as usize),
                                &to,
                            )
                            .is_ok()
                })
                .unwrap_or_else(|| {
                    panic!("planner bug: no valid predecessor for step {}", n.steps)
                });
            actions.push(base.with_legs(dc, dt));
            row = (row as i32 - dc) as usize;
            col = (col as i32 - dt) as usize;
            node = n.parent;
        }
        actions.reverse();
        actions
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::env::EnvConfig;
    use crate::generate::{generate_many, SceneKind};
    use rand::SeedableRng;

    /// Every step the planner's own proof of the way there accepts, the simulator accepts too:
    /// searches on generated scenes of every kind with obstacles, each such step put to
    /// `Env::check_transition` as well (the search asserts it).
    #[test]
    fn the_planners_proof_accepts_only_steps_the_simulator_accepts() {
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(17);
        let mut checked = 0;
        for kind in SceneKind::ALL {
            for scene in generate_many(kind, &mut rng, 2) {
                let env = Env::new(&scene, EnvConfig::default()).unwrap();
                for weight in [1.0, FALLBACK_WEIGHT] {
                    let config = PlannerConfig {
                        max_expansions: 40,
                        heuristic_weight: weight,
                        ..PlannerConfig::default()
                    };
                    let mut search = Search::new(&env, &config, u32::MAX);
                    search.cross_check = true;
                    search.run();
                    checked += search.cross_checked;
                }
            }
        }
        println!("{checked} steps the planner's proof accepted, all accepted by the simulator");
        assert!(checked > 10_000, "{checked}");
    }
}
