//! A look-ahead check on the height map: refuse an action the robot can already see would hit
//! something, or that its legs cannot take.
//!
//! The policy is trained to avoid collisions, but it errs, and an action the world refuses costs a
//! whole decision and, in a real robot, a bump. Everything needed to foresee most of those
//! refusals is on board: the robot's geometry, the height map it just measured and the motion
//! each action commands ([`crate::motion`]). The guard replays that motion against the map; the
//! [`crate::decision::Decider`] then skips the actions it refuses.
//!
//! The model, and why it is only an estimate:
//! - each map cell with a height `h > 0` is a column: the cell's square (side
//!   [`HEIGHT_MAP_CELL_M`] on the policy's map, aligned with the map) from the ground up to `h`.
//!   The map samples each cell at its centre, so an obstacle's true edge lies up to half a cell
//!   beyond or short of the square's edge. The guard's `margin_m` grows (or, negative, shrinks)
//!   every square by that much on each side: half a cell covers everything the map may have
//!   missed, minus half a cell leaves only the sample points, where an obstacle certainly is.
//!   The guard can read a finer map than the policy's ([`GridMap`]): a robot's elevation
//!   mapping keeps one anyway, and at 1 cm cells the default margin covers all the sampling can
//!   hide while the straddles still fit (docs/results.md, "A finer map for the guard");
//! - the robot is the simulator's 13 parts: the body box, per leg a thigh and a shank capsule
//!   in the leg plane and a wheel (a cylinder with its axle along body y);
//! - the step is the path [`crate::motion::StepMotion`] drives: a straight line and a steady
//!   turn, legs moving in a straight line in (clearance, track). It is checked at
//!   [`POSE_FRACTIONS`] of the way. A step moves no point of the robot farther than 94 mm (a
//!   diagonal move, 71 mm, plus a 5-degree turn at the body's corners, 23 mm), so every pose on
//!   the way is within 12 mm of a checked one (or of the start, which the world accepted);
//!   the simulator proves the whole way clear, the guard only samples it.
//! - the cell squares are not turned with the robot: over one step the robot turns at most 5
//!   degrees, which moves a square's corner by under 3 mm.
//!
//! Cost: for each pose, the occupied cells within a step's reach; those within the robot's
//! extent are tested against the body and each leg's box, and against the 3 parts of the legs
//! whose box they meet (most cells near the robot meet one leg's at most); a few
//! multiplications each; no allocation.

mod geometry;
mod map;
#[cfg(test)]
mod tests;

use geometry::{intersect, Column, Parts, OVERLAP_TOLERANCE_M};
pub use map::{FineWindow, GridMap, GridMapError, HeightMapRef, WindowBounds, MAX_WINDOW_ROWS};

use crate::action::{Action, ActionLattice, CHOICES, DIMS};
use crate::arrival::Arrival;
use crate::decision::{Checked, Decider, ObservationKey};
use crate::leg::LegConfig;
use crate::motion::{target_config, BaseDisplacement};
use crate::observation::HEIGHT_MAP_CELL_M;
use crate::robot::{Robot, RobotGeometry};
use nalgebra::{Isometry2, Point2};

/// The robot's half-extent along its own x and y, for any leg configuration: the body, the
/// wheels at the widest track, and the links (all in the hip's leg plane): the knee, and the
/// shank's end at the wheel mount, the wheel offset inboard of the wheel's centre.
fn half_extent_m(g: &RobotGeometry) -> (f32, f32) {
    let half_x_m = (0.5 * g.body_length_m).max(g.hip_x_m + g.wheel_radius_m.max(g.link_radius_m));
    let half_y_m = (0.5 * g.body_width_m)
        .max(0.5 * g.track_range_m[1] + 0.5 * g.wheel_width_m)
        .max(g.hip_y_m + g.thigh_m + g.link_radius_m)
        .max(0.5 * g.track_range_m[1] - g.wheel_offset_m + g.link_radius_m);
    (half_x_m, half_y_m)
}

/// How far past [`half_extent_m`] a column must be to be skipped: the legs take a track up to
/// 1e-5 m past its range (the IK's tolerance), and the parts' positions round; this is well
/// above both.
const EXTENT_SLACK_M: f32 = 1.0e-4;

/// Where along the step (0 = start, 1 = end) the robot's pose is checked.
pub const POSE_FRACTIONS: [f32; 4] = [0.25, 0.5, 0.75, 1.0];

/// The growth of every column the guard uses by default: 5 mm. The robot straddles the widest
/// slab (0.45 m) at full track (0.56 m) with 35 mm between each wheel and the slab's edge, and
/// the map may show that edge up to half a cell (25 mm) farther out than it is; a margin past
/// 10 mm would refuse the straddle outright in the worst alignment, so the default stays well
/// under it. docs/results.md measures the margins from -25 mm to 25 mm.
pub const DEFAULT_MARGIN_M: f32 = 0.005;

/// Why the guard refuses an action.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// The legs cannot take the configuration the action asks for (or one on the way).
    Unreachable,
    /// A part of the robot would meet a column of the height map (grown by the margin) at one
    /// of the checked poses.
    Collision,
}

/// The height of a cell nobody measured (NaN in a map in metres): the tallest obstacle a map
/// in millimetres holds, so that the guard never takes an unknown cell for free ground.
pub const UNKNOWN_HEIGHT_MM: i16 = i16::MAX;

/// [`UNKNOWN_HEIGHT_MM`] in metres.
pub const UNKNOWN_HEIGHT_M: f32 = UNKNOWN_HEIGHT_MM as f32 * 1.0e-3;

/// A cell's height as the guard takes it: unknown (NaN) is [`UNKNOWN_HEIGHT_M`].
#[inline]
pub(crate) fn known_or_tallest_m(height_m: f32) -> f32 {
    if height_m.is_nan() {
        UNKNOWN_HEIGHT_M
    } else {
        height_m
    }
}

/// A height in metres as a map in millimetres carries it (the fine window, the observation
/// link): rounded to the millimetre and saturated, and an unknown height (NaN) as
/// [`UNKNOWN_HEIGHT_MM`], the tallest obstacle.
pub fn height_mm(height_m: f32) -> i16 {
    if height_m.is_nan() {
        UNKNOWN_HEIGHT_MM
    } else {
        // `as` saturates at the i16 range.
        libm::roundf(height_m * 1000.0) as i16
    }
}

/// Checks actions against the height map before they are sent.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CollisionGuard {
    geometry: RobotGeometry,
    lattice: ActionLattice,
    margin_m: f32,
    /// Cells farther than this from the robot's centre (along x or y) cannot touch it anywhere
    /// along a step.
    reach_m: f32,
    /// Half the robot's extent along its own x and y for any leg configuration: a column whose
    /// square lies beyond at a checked pose touches nothing (two comparisons, where most
    /// columns within `reach_m` are). Per leg configuration it would be tighter across, but
    /// its code did not fit the controller's flash.
    half_extent_m: (f32, f32),
}

impl CollisionGuard {
    /// A guard for `robot` (its geometry and the steps of its action lattice) that grows every
    /// column's square by `margin_m` on each side (a square shrinks at most to its bare sample
    /// point; non-finite counts as 0). Heights are not padded: they are measured to the
    /// millimetre, not sampled.
    pub fn new(robot: &Robot, margin_m: f32) -> CollisionGuard {
        let geometry = robot.geometry;
        let lattice = robot.actions;
        // At least minus half the policy's cell: the bound of every earlier version. A finer
        // map's squares are floored at their sample point where they are used.
        let margin_m = if margin_m.is_finite() {
            margin_m.max(-0.5 * HEIGHT_MAP_CELL_M)
        } else {
            0.0
        };
        let (half_length_m, half_width_m) = half_extent_m(&geometry);
        // The farthest any part gets from the centre, plus one step of travel and the growth.
        let reach_m = crate::trig::hypot(half_length_m, half_width_m)
            + lattice.move_step_m * core::f32::consts::SQRT_2
            + margin_m.max(0.0);
        CollisionGuard {
            geometry,
            lattice,
            margin_m,
            reach_m,
            half_extent_m: half_extent_m(&geometry),
        }
    }

    /// The window of a robot-centred `side` x `side` map of `cell_m` cells outside which no
    /// column can meet the robot on any step ([`FineWindow`]).
    ///
    /// Tighter than the square of [`Self::check`]'s reach (which bounds the robot's distance
    /// from its centre in any direction): along each map axis, the robot's extent along that
    /// axis in its own frame, turned by at most one yaw step (the farthest corner of a
    /// rectangle turned by an angle below its diagonal's is at that angle), plus one move step
    /// and the margin; then one cell more, as in [`Self::check`], for the column's own
    /// half-side.
    pub fn fine_window(&self, side: usize, cell_m: f32) -> WindowBounds {
        let (half_x_m, half_y_m) = self.half_extent_m;
        let turn_rad = self.lattice.yaw_step_deg.to_radians();
        let (sin, cos) = (crate::trig::sin(turn_rad), crate::trig::cos(turn_rad));
        let travel_m = self.lattice.move_step_m + self.margin_m.max(0.0);
        let reach_x_m = half_x_m * cos + half_y_m * sin + travel_m;
        let reach_y_m = half_y_m * cos + half_x_m * sin + travel_m;
        let span = |reach_m: f32| {
            let half = 0.5 * (side as f32 - 1.0);
            let cells = if cell_m > 0.0 {
                reach_m / cell_m + 1.0
            } else {
                0.0
            };
            let first = crate::trig::ceil(half - cells).max(0.0) as usize;
            let last = (crate::trig::floor(half + cells)
                .min(side as f32 - 1.0)
                .max(0.0) as usize)
                .max(first);
            (first, (last + 1).min(side) - first.min(side))
        };
        let (first_row, rows) = span(reach_x_m);
        let (first_col, cols) = span(reach_y_m);
        WindowBounds {
            side,
            cell_m,
            first_row,
            rows,
            first_col,
            cols,
        }
    }

    /// Check levels for [`crate::decision::Decider::choose_checked`]: [`Self::allows`] at
    /// level 0 is [`Self::check`], at level 1 [`Self::check_no_deeper`].
    pub const LEVELS: usize = 2;

    /// The check of `level` (see [`Self::LEVELS`]): whether `action` passes it. Levels past
    /// the last refuse everything.
    pub fn allows(
        &self,
        level: usize,
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        action: Action,
    ) -> bool {
        match level {
            0 => self.check(heights, legs, action).is_ok(),
            1 => self.check_no_deeper(heights, legs, action).is_ok(),
            _ => false,
        }
    }

    /// The decider's choice for observation `key` among the actions this guard passes
    /// ([`crate::decision::Decider::choose_checked`] over [`Self::LEVELS`]): what a robot
    /// running the guard does each decision. With an `arrival`, an action that reaches the
    /// target and passes the strict check comes first, where [`Arrival::applies`]. The
    /// returned level is the guard's ([`Self::allows`]), whether or not the action arrives.
    pub fn choose<const STATES: usize, L: Copy + Into<f32>>(
        &self,
        decider: &mut Decider<STATES>,
        key: ObservationKey,
        logits: &[L; DIMS * CHOICES],
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        arrival: Option<&Arrival>,
    ) -> Checked {
        let decided = self.choose_in_time(decider, key, logits, heights, legs, arrival, || true);
        // Never out of time: the fallback only keeps the types honest.
        decided.unwrap_or(Checked {
            action: Action::IDLE,
            level: None,
            checks: 0,
        })
    }

    /// [`Self::choose`] with a deadline: `in_time` is asked before each candidate's check,
    /// and once it says no the decision is abandoned (`None`, nothing remembered). A check
    /// costs at most one pass over the window, so the decision's time past the deadline is
    /// bounded by one check ([`crate::decision::Decider::choose_checked_in_time`]).
    #[allow(clippy::too_many_arguments)]
    pub fn choose_in_time<const STATES: usize, L: Copy + Into<f32>>(
        &self,
        decider: &mut Decider<STATES>,
        key: ObservationKey,
        logits: &[L; DIMS * CHOICES],
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        arrival: Option<&Arrival>,
        mut in_time: impl FnMut() -> bool,
    ) -> Option<Checked> {
        let arrival = arrival.filter(|a| a.applies(decider, key));
        let first = usize::from(arrival.is_some());
        // Levels numbered as if arrival were always asked: 0 arrival, 1 strict, 2 lenient.
        let skipped = 1 - first;
        let mut checked = decider.choose_checked_in_time(
            key,
            logits,
            first + Self::LEVELS,
            |level, action| {
                if !in_time() {
                    return None;
                }
                Some(match level + skipped {
                    0 => {
                        arrival.is_some_and(|a| a.reached_by(action))
                            && self.check(heights, legs, action).is_ok()
                    }
                    1 => self.check(heights, legs, action).is_ok(),
                    2 => self.check_no_deeper(heights, legs, action).is_ok(),
                    _ => false,
                })
            },
        )?;
        checked.level = checked.level.map(|level| level.saturating_sub(first));
        Some(checked)
    }

    /// How much every column's square is grown on each side (negative: shrunk).
    pub fn margin_m(&self) -> f32 {
        self.margin_m
    }

    /// Whether `action`, taken from leg configuration `legs`, stays clear of the height map
    /// `heights` (seen from the robot's current pose) at every checked pose of its step.
    pub fn check(
        &self,
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        action: Action,
    ) -> Result<(), Refusal> {
        self.check_from(heights, &Isometry2::identity(), legs, action)
    }

    /// [`Self::check`] of `action` taken from the pose `from` (in the frame of the robot that
    /// measured `heights`) with leg configuration `legs`: a step of a plan ahead, judged on the
    /// map measured now. Parts beyond the map's edge meet nothing: the caller keeps plans
    /// within the map.
    pub fn check_from(
        &self,
        heights: HeightMapRef<'_>,
        from: &Isometry2<f32>,
        legs: LegConfig,
        action: Action,
    ) -> Result<(), Refusal> {
        match self.deepest_overlap_m(heights, legs, action, Some(0.0), None, from)? {
            overlap_m if overlap_m >= 0.0 => Err(Refusal::Collision),
            _ => Ok(()),
        }
    }

    /// The lenient check, for when [`CollisionGuard::check`] refuses everything: the robot
    /// already overlaps a column where it stands (the grown columns claim more than is there),
    /// so an action passes if its step goes no deeper into any column than the current pose
    /// is, column by column: a column the robot does not overlap now must stay clear. (A
    /// check of the deepest overlap alone let a step into a new column pass as long as it went
    /// no deeper than the old one: on the 1 cm map, where a robot within 10 mm of an obstacle
    /// overlaps its grown columns, that was a collision.)
    pub fn check_no_deeper(
        &self,
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        action: Action,
    ) -> Result<(), Refusal> {
        let here = Parts::place(&self.geometry, legs).ok_or(Refusal::Unreachable)?;
        match self.deepest_overlap_m(
            heights,
            legs,
            action,
            Some(OVERLAP_TOLERANCE_M),
            Some(&here),
            &Isometry2::identity(),
        )? {
            excess_m if excess_m >= OVERLAP_TOLERANCE_M => Err(Refusal::Collision),
            _ => Ok(()),
        }
    }

    /// The deepest overlap of any part with any column over the step's checked poses (0:
    /// touching; negative: no overlap, and then not exact, as columns that cannot reach the
    /// robot are skipped), stopping early once it reaches `stop_m`. Given the robot's parts
    /// `here` at its current pose, each column's overlap counts only past that pose's overlap
    /// with the same column (when positive).
    fn deepest_overlap_m(
        &self,
        heights: HeightMapRef<'_>,
        legs: LegConfig,
        action: Action,
        stop_m: Option<f32>,
        here: Option<&Parts>,
        from: &Isometry2<f32>,
    ) -> Result<f32, Refusal> {
        let target = target_config(legs, action, &self.lattice);
        if !self.geometry.is_reachable(target) {
            return Err(Refusal::Unreachable);
        }
        let base = BaseDisplacement::of_action(action, &self.lattice);
        let mut deepest_m = f32::NEG_INFINITY;
        for t in POSE_FRACTIONS {
            let legs_t = LegConfig {
                clearance_m: legs.clearance_m + t * (target.clearance_m - legs.clearance_m),
                track_m: legs.track_m + t * (target.track_m - legs.track_m),
            };
            let parts = Parts::place(&self.geometry, legs_t).ok_or(Refusal::Unreachable)?;
            let inverse = (from * base.isometry_at(t)).inverse();
            let (x0_m, y0_m) = (from.translation.x, from.translation.y);
            let (held_rows, held_cols) = heights.held();
            let rows = intersect(self.cells_within_reach(&heights, x0_m), held_rows);
            let cols = intersect(self.cells_within_reach(&heights, y0_m), held_cols);
            for row in rows {
                for col in intersect(cols.clone(), heights.occupied(row)) {
                    let (x_m, y_m) = heights.cell_centre_m(row, col);
                    // Unknown heights arrive as the tallest obstacle (`height_at_m`).
                    let height_m = heights.height_at_m(row, col);
                    if height_m <= 0.0 {
                        continue;
                    }
                    let centre = inverse * Point2::new(x_m, y_m);
                    let column = Column {
                        x_m: centre.x,
                        y_m: centre.y,
                        half_m: (0.5 * heights.cell_m() + self.margin_m).max(0.0),
                        height_m,
                    };
                    if !self.may_touch(&column) {
                        continue;
                    }
                    let mut overlap_m = parts.overlap_m(&column);
                    if let Some(here) = here {
                        let now = Column { x_m, y_m, ..column };
                        overlap_m -= here.overlap_m(&now).max(0.0);
                    }
                    deepest_m = deepest_m.max(overlap_m);
                    if stop_m.is_some_and(|stop_m| deepest_m >= stop_m) {
                        return Ok(deepest_m);
                    }
                }
            }
        }
        Ok(deepest_m)
    }

    /// Whether `column` (in the robot's frame) is within its extent at all: if not, it
    /// overlaps nothing.
    fn may_touch(&self, column: &Column) -> bool {
        column.x_m.abs() - column.half_m <= self.half_extent_m.0 + EXTENT_SLACK_M
            && column.y_m.abs() - column.half_m <= self.half_extent_m.1 + EXTENT_SLACK_M
    }

    /// The rows (or columns: the map is square and centred) whose cells lie within the
    /// robot's reach of `centre_m` along that axis (x for rows, y for columns; 0 for the
    /// robot that measured the map).
    fn cells_within_reach(
        &self,
        heights: &HeightMapRef<'_>,
        centre_m: f32,
    ) -> core::ops::Range<usize> {
        let side = heights.side() as f32;
        // Rows count down from +x, columns from +y: the centre's index.
        let half = 0.5 * (side - 1.0) - centre_m / heights.cell_m();
        // One cell more: a column's square reaches half a cell past its centre.
        let cells = self.reach_m / heights.cell_m() + 1.0;
        // Saturating casts: a huge reach covers the whole map, never more.
        let first = crate::trig::ceil(half - cells).max(0.0) as usize;
        let last = crate::trig::floor(half + cells).min(side - 1.0) as usize;
        first..last + 1
    }
}
