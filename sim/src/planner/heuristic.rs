//! Heuristics: the admissible pose-only bound ([`Heuristic`], with its [`DistanceField`]) and the
//! weighted search's leg-aware ordering hint ([`LegHint`]).

use super::legs::LegSet;
use super::legs::LEG_COLS;
use super::legs::{LegLattice, LEG_ROWS};
use super::moves::Pose;
use crate::env::Env;
use crate::generate::Behaviour;
use crate::generate::SceneRobot;
use crate::obstacle::ObstacleKind;
use crate::state::RobotState;
use nalgebra::Point2;
use std::cmp::Ordering;
use std::collections::BinaryHeap;
use wheelleg_runtime::action::ActionLattice;

/// Length of the longest step on `lattice` (a diagonal move).
pub(super) fn diagonal_step_m(lattice: &ActionLattice) -> f32 {
    lattice.move_step_m * core::f32::consts::SQRT_2
}

/// Lower bound on the steps from a pose to success: the larger of two bounds, both pose-only.
///
/// - Detour: the remaining travel through the places the body centre can be at all (a distance
///   field around the blocks, [`DistanceField`]) at the longest possible step.
/// - Heading: the straight-line progress towards the target. A step's progress along the unit
///   vector `u` towards the target is at most `s sqrt(2) cos(delta)` for a move step `s`, where
///   `delta` is the angle between `u` and the nearest of the robot's four diagonal move
///   directions (an axis move gives `s cos(45 deg - delta)`, never more for `delta <= 45 deg`).
///   Yaw turns one yaw step `y` per step at most, and the step's move uses the yaw before the
///   turn, so step `i` has `delta_i >= delta_0 - y i`. Reaching the success circle needs a total progress along
///   `u` of at least the distance minus the success radius.
pub(super) struct Heuristic {
    pub(super) field: DistanceField,
    pub(super) target: Point2<f32>,
    pub(super) success_radius_m: f32,
    pub(super) lattice: ActionLattice,
}

impl Heuristic {
    pub(super) fn steps(&self, pose: &Pose) -> u32 {
        let d = self.target - pose.position;
        // 1e-4 m of slack keeps the bounds admissible under float rounding.
        let straight_m = d.norm() - self.success_radius_m - 1.0e-4;
        if straight_m <= 0.0 {
            return 0;
        }
        let field_m = self.field.lower_bound_m(pose.position) - 1.0e-4;
        let detour = (field_m / diagonal_step_m(&self.lattice)).ceil().max(0.0);
        let alpha_rad = d.y.atan2(d.x) - pose_yaw_rad(pose, &self.lattice);
        let heading = heading_steps(straight_m, alpha_rad, &self.lattice);
        if detour.is_infinite() {
            return u32::MAX / 4;
        }
        (detour as u32).max(heading)
    }
}

pub(super) fn pose_yaw_rad(pose: &Pose, lattice: &ActionLattice) -> f32 {
    RobotState::new(pose.position, pose.yaw_steps, lattice).yaw_rad()
}

/// Fewest steps whose progress along a direction `alpha_rad` (relative to the robot's heading)
/// can add up to `need_m` (see [`Heuristic`]).
pub(super) fn heading_steps(need_m: f32, alpha_rad: f32, lattice: &ActionLattice) -> u32 {
    use core::f32::consts::{FRAC_PI_2, FRAC_PI_4};
    let from_diagonal = (alpha_rad - FRAC_PI_4).rem_euclid(FRAC_PI_2);
    let mut delta = from_diagonal.min(FRAC_PI_2 - from_diagonal);
    let turn = lattice.yaw_step_deg.to_radians();
    // Tiny relative slack: cos and the sum round; overestimating progress keeps this a bound.
    let best_step_m = diagonal_step_m(lattice) * (1.0 + 1.0e-5);
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
/// length, in the robot's passing pose ([`SceneRobot::passing_legs`]: spread and low for a
/// slab, lifted for a bar). A spread scene needs up to ten track steps before its fence, and the
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
pub(super) struct LegHint {
    pub(super) zones: Vec<StraddleZone>,
    lattice: ActionLattice,
    /// Yaw steps in half a turn.
    half_turn: i32,
}

/// A low obstacle's footprint, grown by the robot's reach ahead of its centre, with the leg
/// steps from every lattice cell to its passing pose.
pub(super) struct StraddleZone {
    pub(super) min: Point2<f32>,
    pub(super) max: Point2<f32>,
    /// Chebyshev distance in leg steps from cell `row * LEG_COLS + col` to the passing pose.
    pub(super) leg_steps: Vec<u8>,
    /// Heading (yaw steps, modulo half a turn) along which the robot straddles the obstacle:
    /// along its length, the world axis its first size dimension lies on.
    pub(super) along_yaw_steps: i32,
}

/// How far from lined up with an obstacle (degrees) the hint still counts the robot as lined up.
pub(super) const LINED_UP_DEG: f32 = 10.0;

impl LegHint {
    pub(super) fn new(env: &Env, lattice: &LegLattice) -> Self {
        let geometry = env.geometry();
        // The wheels reach this far ahead of the body centre: they meet the obstacle when the
        // centre is this close to it, so the legs must be ready by then.
        let reach_m = geometry.hip_x_m + geometry.wheel_radius_m;
        let fit = SceneRobot::of(env.robot());
        let quarter_turn = env.robot().yaw_steps_per_turn() / 4;
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
                let (clearance, track) = fit.passing_legs(behaviour);
                // The side nearer the kind's length: exact for the generator's boxes, and
                // still right for a perceived one, grown and cut to map cells
                // ([`crate::local_plan`]).
                let length_m = kind.size_m().0;
                let along_x = (b.max_x_m - b.min_x_m - length_m).abs()
                    <= (b.max_y_m - b.min_y_m - length_m).abs();
                let along_yaw_steps = if along_x { 0 } else { quarter_turn };
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
        LegHint {
            zones,
            lattice: *env.lattice(),
            half_turn: env.robot().yaw_steps_per_turn() / 2,
        }
    }

    /// The hint's steps for a robot at `position` in any of the leg configurations `legs`: for
    /// every zone the straight way to the target enters, the legs must reach the passing pose
    /// by the entry (the larger of the leg steps and the way there), then the robot goes on
    /// from the entry to the target; the largest of these.
    pub(super) fn steps(&self, pose: &Pose, target: Point2<f32>, legs: &LegSet) -> u32 {
        self.entered(pose, target)
            .map(|(z, other, from_entry)| z.fewest_leg_steps(legs).max(other) + from_entry)
            .max()
            .unwrap_or(0)
    }

    /// The leg configurations of `legs` to prove first when a node's priority may rise once
    /// its valid set is known: the fewest that hold some zone's term at or below the level
    /// the priority stands at (`floor`, the pose-only bound, or the hint, whichever is larger)
    /// and none of which is `proven` valid already. Refuting them all lifts that zone's term,
    /// so the hint, above the level. `None` when no zone can rise: then the level holds
    /// whatever the rest proves. The order of proofs changes no verdict, only how soon a rise
    /// is seen.
    pub(super) fn holding(
        &self,
        pose: &Pose,
        target: Point2<f32>,
        legs: &LegSet,
        proven: &LegSet,
        floor: u32,
    ) -> Option<LegSet> {
        let level = floor.max(self.steps(pose, target, legs));
        let mut best: Option<LegSet> = None;
        for (z, other, from_entry) in self.entered(pose, target) {
            let Some(threshold) = level.checked_sub(from_entry).filter(|&t| other <= t) else {
                continue;
            };
            let mut holding = LegSet::default();
            for (row, col) in legs.iter() {
                if z.leg_steps[row * LEG_COLS + col] as u32 <= threshold {
                    holding.insert(row, col);
                }
            }
            if holding.is_empty() || !holding.intersection(proven).is_empty() {
                continue;
            }
            if best.is_none_or(|b| holding.len() < b.len()) {
                best = Some(holding);
            }
        }
        best
    }

    /// Per zone the straight way from `pose` to the target enters: the zone, its steps other
    /// than the legs' (the turn to line up, the way to the entry), and the steps from the
    /// entry to the target.
    fn entered<'z>(
        &'z self,
        pose: &'z Pose,
        target: Point2<f32>,
    ) -> impl Iterator<Item = (&'z StraddleZone, u32, u32)> + 'z {
        let position = pose.position;
        let whole_m = (target - position).norm();
        let half_turn = self.half_turn;
        let step_deg = self.lattice.yaw_step_deg;
        let diagonal_m = diagonal_step_m(&self.lattice);
        self.zones.iter().filter_map(move |z| {
            let entry = segment_entry(position, target, z.min, z.max)?;
            let off = (pose.yaw_steps - z.along_yaw_steps).rem_euclid(half_turn);
            let off_deg = off.min(half_turn - off) as f32 * step_deg;
            let turn_steps = ((off_deg - LINED_UP_DEG).max(0.0) / step_deg).ceil() as u32;
            let to_entry = (entry * whole_m / diagonal_m).ceil() as u32;
            let from_entry = ((1.0 - entry) * whole_m / diagonal_m).ceil() as u32;
            Some((z, turn_steps.max(to_entry), from_entry))
        })
    }
}

impl StraddleZone {
    /// The fewest leg steps from a member of `legs` to the passing pose (0 for none).
    fn fewest_leg_steps(&self, legs: &LegSet) -> u32 {
        legs.iter()
            .map(|(row, col)| self.leg_steps[row * LEG_COLS + col])
            .min()
            .unwrap_or(0) as u32
    }
}

/// Where the segment from `a` to `b` enters the axis-aligned rectangle `min`..`max`, as a
/// fraction of the way (0 when `a` is inside), if it meets it (Liang-Barsky clipping).
pub(super) fn segment_entry(
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
pub(super) struct DistanceField {
    pub(super) min: Point2<f32>,
    pub(super) cols: usize,
    pub(super) rows: usize,
    pub(super) metres: Vec<f32>,
}

pub(super) const FIELD_CELL_M: f32 = 0.025;
/// Grid paths with 16 neighbours are at most 1/cos(13.3 deg) longer than straight ones.
pub(super) const FIELD_DISCOUNT: f32 = 0.97;

impl DistanceField {
    pub(super) fn new(env: &Env, start: Point2<f32>) -> Self {
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
    pub(super) fn lower_bound_m(&self, p: Point2<f32>) -> f32 {
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
pub(super) struct OrderedF32(pub(super) f32);
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
