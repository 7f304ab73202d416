//! How the behaviour scenes' fences fit a robot: which leg pose passes each fence, and which
//! behaviours the obstacle set asks of this robot at all.
//!
//! The fences are built from the paper's three obstacles (a 0.15 m bar, a 0.05 m slab 0.45 m
//! wide, 0.40 m blocks a cell apart), whose sizes every scenario file and the controller's height
//! map share. What changes with the robot is the pose that passes: the lattice pose nearest the
//! default (fewest clearance and track steps) that drives lined up through the fence keeping
//! [`FENCE_MARGIN_M`] from every obstacle at every point of the way. A fence is left out when no
//! pose passes it (the robot lacks the behaviour) or when the default pose already drives
//! through (the fence would not ask for the behaviour), with the reason in figures. The shipped
//! robot keeps the poses its fences were designed with ([`SHIPPED_PASSING`]).

use super::fence::{fence_cells, fence_rows};
use super::Behaviour;
use crate::collision::{ObstacleSet, RobotParts};
use crate::obstacle::{cell_centre_m, Obstacle, ObstacleYaw, GRID_CELL_M};
use crate::robot::SimulatedRobot;
use crate::state::RobotState;
use nalgebra::Point2;
use wheelleg_runtime::robot::RobotGeometry;

/// Free space a passing pose keeps from every obstacle of its fence, all the way through: what
/// a policy that steers a step off the centre line, or a real robot that sways, still has.
pub const FENCE_MARGIN_M: f32 = 0.01;

/// The shipped robot's passing poses (lift, spread, squeeze), chosen by hand when its fences were
/// designed: spread 0.56 m wide at 0.08 m clearance, squeeze 0.20 m narrow, lift 0.18 m
/// clearance. They are kept so that its scenes, start stages and plans stay those its figures
/// were measured on; each drives through its fence (tests), though not all keep
/// [`FENCE_MARGIN_M`] (the lift pose's wheels pass the neighbouring bars a few mm closer).
const SHIPPED_PASSING: [(i32, i32); 3] = [(3, 0), (-2, 10), (0, -8)];

/// Spacing of the poses checked along the way through a fence.
const DRIVE_SAMPLE_M: f32 = 0.01;

/// How far from the default pose the passing poses are searched, each way in clearance and in
/// track (15 steps of 0.02 m).
const SEARCH_M: f32 = 0.30;

/// What the scene generators build for one robot.
#[derive(Clone, Debug, PartialEq)]
pub struct SceneRobot {
    robot: SimulatedRobot,
    /// Lift, spread, squeeze: the passing pose in (clearance, track) steps, or why the fence is
    /// left out.
    fences: [Result<(i32, i32), String>; 3],
    /// How far beside an around block's centre the way past it runs, on the start lattice.
    around_offset_m: f32,
    /// How far ahead of the start the first fence row's centre stands at least.
    fence_lead_m: f32,
}

impl SceneRobot {
    /// The fit of the fences to `robot`.
    pub fn new(robot: &SimulatedRobot) -> SceneRobot {
        let fences = if *robot == SimulatedRobot::SHIPPED {
            SHIPPED_PASSING.map(Ok)
        } else {
            [
                Behaviour::LiftOver,
                Behaviour::SpreadOver,
                Behaviour::Squeeze,
            ]
            .map(|b| passing_pose(robot, b))
        };
        SceneRobot {
            robot: *robot,
            fences,
            around_offset_m: around_offset_m(robot),
            fence_lead_m: fence_lead_m(robot.geometry()),
        }
    }

    /// The shipped robot's fit, worked out once.
    pub fn shipped() -> &'static SceneRobot {
        SceneRobot::of(&SimulatedRobot::SHIPPED)
    }

    /// The fit for `robot`, worked out on first use and kept for the program's life (the
    /// planner asks for it on every search, the trainer on every episode).
    pub fn of(robot: &SimulatedRobot) -> &'static SceneRobot {
        static FITS: crate::PerRobot<SceneRobot> = crate::PerRobot::new();
        FITS.get(robot, SceneRobot::new)
    }

    /// The robot the scenes are built for.
    pub fn robot(&self) -> &SimulatedRobot {
        &self.robot
    }

    /// The robot's geometry.
    pub fn geometry(&self) -> &RobotGeometry {
        self.robot.geometry()
    }

    /// The `index`-th point of the start lattice, on either axis: whole move steps placed so
    /// that every obstacle cell's centre (0.125 + 0.25 k) lies on it, 0.025 + 0.05 k for the
    /// shipped robot. A passage centred on a cell can then be entered exactly on its centre.
    pub fn on_start_lattice(&self, index: i32) -> f32 {
        let step_m = self.robot.lattice().move_step_m as f64;
        // Built as a whole number of 0.1 mm so that the value prints and parses back to the
        // same f32.
        let tenths_of_mm = ((index as f64 + self.start_lattice_offset()) * step_m * 1.0e4).round();
        (tenths_of_mm / 1.0e4) as f32
    }

    /// Index of the start lattice point nearest `value_m`.
    pub(super) fn start_lattice_index(&self, value_m: f32) -> i32 {
        let step_m = self.robot.lattice().move_step_m as f64;
        (value_m as f64 / step_m - self.start_lattice_offset()).round() as i32
    }

    /// Where the start lattice stands, in move steps: half a step when a cell's half width is
    /// an odd number of half steps (0.125 m of 0.05 m steps), none when even.
    fn start_lattice_offset(&self) -> f64 {
        let steps_per_cell = (GRID_CELL_M / self.robot.lattice().move_step_m).round() as i32;
        if steps_per_cell % 2 == 1 {
            0.5
        } else {
            0.0
        }
    }

    /// Whether the generators can build `behaviour`'s scenes for this robot; the error says
    /// why not, in figures.
    pub fn has(&self, behaviour: Behaviour) -> Result<(), String> {
        self.fence(behaviour).map(|_| ())
    }

    /// Whether the generators can build scenes of `kind` for this robot: a behaviour's when
    /// the robot has it, composed ones when it has at least one fence, complex ones always.
    pub fn has_kind(&self, kind: super::SceneKind) -> Result<(), String> {
        match kind {
            super::SceneKind::Behaviour(b) => self.has(b),
            super::SceneKind::Composed if !self.has_a_fence() => {
                Err("it has none of the lift, spread and squeeze fences".into())
            }
            super::SceneKind::Composed | super::SceneKind::Complex => Ok(()),
        }
    }

    /// Whether any of the lift, spread and squeeze fences is built for this robot.
    pub(super) fn has_a_fence(&self) -> bool {
        self.fences.iter().any(Result::is_ok)
    }

    /// The leg pose (clearance steps, track steps from the default) in which the robot, lined
    /// up with `behaviour`'s fence and centred on its opening, drives straight through it;
    /// the default pose for straight and around, and for a behaviour the robot lacks.
    pub fn passing_legs(&self, behaviour: Behaviour) -> (i32, i32) {
        self.fence(behaviour).unwrap_or((0, 0))
    }

    /// How far beside an around block's centre the way past it runs.
    pub(super) fn around_offset_m(&self) -> f32 {
        self.around_offset_m
    }

    /// How far ahead of the start the first fence row's (or the around block's) centre stands
    /// at least, so that the robot in its default pose turns on the spot at the start.
    pub(super) fn fence_lead_m(&self) -> f32 {
        self.fence_lead_m
    }

    fn fence(&self, behaviour: Behaviour) -> Result<(i32, i32), String> {
        match behaviour {
            Behaviour::Straight | Behaviour::Around => Ok((0, 0)),
            Behaviour::LiftOver => self.fences[0].clone(),
            Behaviour::SpreadOver => self.fences[1].clone(),
            Behaviour::Squeeze => self.fences[2].clone(),
        }
    }
}

/// The fence of `behaviour` with its opening on cell 0 and its first row on cell 0.
fn canonical_fence(behaviour: Behaviour) -> Vec<Obstacle> {
    (0..fence_rows(behaviour))
        .flat_map(|row| {
            fence_cells(behaviour).into_iter().map(move |(m, kind)| {
                Obstacle::new(
                    kind,
                    cell_centre_m(row),
                    cell_centre_m(m),
                    ObstacleYaw::Deg0,
                )
            })
        })
        .collect()
}

/// Whether the robot in `legs` (steps from the default), facing along x on the opening's centre
/// line, drives from well before the fence to well past it keeping `margin_m` from every
/// obstacle (touching counts as a collision at margin 0).
fn drives_through(
    robot: &SimulatedRobot,
    obstacles: &ObstacleSet,
    rows: i32,
    legs: (i32, i32),
    margin_m: f32,
) -> bool {
    let geometry = robot.geometry();
    let state = RobotState {
        clearance_steps: legs.0,
        track_steps: legs.1,
        ..RobotState::new(Point2::origin(), 0, robot.lattice())
    };
    let config = state.leg_config(geometry);
    let reach_m = geometry.body_length_m.max(geometry.track_range_m[1]);
    let from_m = cell_centre_m(0) - 0.5 * GRID_CELL_M - reach_m;
    let to_m = cell_centre_m(rows - 1) + 0.5 * GRID_CELL_M + reach_m;
    let samples = ((to_m - from_m) / DRIVE_SAMPLE_M).ceil() as i32;
    (0..=samples).all(|i| {
        let at = Point2::new(from_m + i as f32 * DRIVE_SAMPLE_M, cell_centre_m(0));
        match RobotParts::new(geometry, at, 0.0, config) {
            Ok(parts) if margin_m > 0.0 => !obstacles.within_margin(&parts, margin_m),
            Ok(parts) => !obstacles.collides(&parts),
            Err(_) => false,
        }
    })
}

/// The passing pose of `behaviour`'s fence for `robot`, or why there is none.
fn passing_pose(robot: &SimulatedRobot, behaviour: Behaviour) -> Result<(i32, i32), String> {
    let obstacles = ObstacleSet::new(&canonical_fence(behaviour));
    let rows = fence_rows(behaviour);
    let name = behaviour.name();
    if drives_through(robot, &obstacles, rows, (0, 0), 0.0) {
        return Err(format!(
            "the default pose drives through the {name} fence: its obstacles do not ask this \
             robot for the behaviour"
        ));
    }
    // Nearest the default first; among equals, the one that changes one dimension only, then
    // clearance before track, each way down before up.
    let lattice = robot.lattice();
    let clearance_steps = (SEARCH_M / lattice.clearance_step_m).round() as i32;
    let track_steps = (SEARCH_M / lattice.track_step_m).round() as i32;
    let mut candidates: Vec<(i32, i32)> = (-clearance_steps..=clearance_steps)
        .flat_map(|c| (-track_steps..=track_steps).map(move |t| (c, t)))
        .filter(|&p| p != (0, 0))
        .collect();
    candidates.sort_by_key(|&(c, t)| (c.abs() + t.abs(), c.abs().min(t.abs()), c.abs(), c, t));
    candidates
        .into_iter()
        .find(|&legs| drives_through(robot, &obstacles, rows, legs, FENCE_MARGIN_M))
        .ok_or_else(|| {
            format!(
                "no pose within {SEARCH_M} m of clearance and of track from the default drives \
                 through the {name} fence keeping {:.0} mm from it",
                FENCE_MARGIN_M * 1000.0
            )
        })
}

/// Beside an around block: the block's half width, the default pose's half width and 0.10 m
/// of free space, rounded up to the start lattice (0.40 m for the shipped robot).
/// The fence lead: the default pose's horizontal reach, half a block and [`FENCE_MARGIN_M`];
/// never under 0.45 m, the lead the shipped robot's scenes were built with (its own is 0.44 m).
fn fence_lead_m(geometry: &RobotGeometry) -> f32 {
    let reach_m = crate::env::horizontal_reach_at_track_m(geometry, geometry.default_track_m);
    let block_half_m = 0.5 * crate::obstacle::ObstacleKind::Block.size_m().0;
    (reach_m + block_half_m + FENCE_MARGIN_M).max(0.45)
}

fn around_offset_m(robot: &SimulatedRobot) -> f32 {
    let geometry = robot.geometry();
    let half_width_m = RobotParts::new(
        geometry,
        Point2::origin(),
        0.0,
        RobotState::new(Point2::origin(), 0, robot.lattice()).leg_config(geometry),
    )
    .map(|parts| parts.aabb().maxs.y.max(-parts.aabb().mins.y))
    .unwrap_or(0.5 * geometry.default_track_m);
    let block_half_m = 0.5 * crate::obstacle::ObstacleKind::Block.size_m().1;
    let step = robot.lattice().move_step_m as f64;
    let wanted = (block_half_m + half_width_m + 0.10) as f64;
    ((wanted / step - 1e-3).ceil() * step) as f32
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;

    #[test]
    fn the_shipped_robot_passes_each_fence_in_its_pose_and_not_in_the_default() {
        let fit = SceneRobot::shipped();
        for (i, b) in [
            Behaviour::LiftOver,
            Behaviour::SpreadOver,
            Behaviour::Squeeze,
        ]
        .into_iter()
        .enumerate()
        {
            let obstacles = ObstacleSet::new(&canonical_fence(b));
            let rows = fence_rows(b);
            assert_eq!(fit.passing_legs(b), SHIPPED_PASSING[i]);
            assert!(
                drives_through(
                    &SimulatedRobot::SHIPPED,
                    &obstacles,
                    rows,
                    SHIPPED_PASSING[i],
                    0.0
                ),
                "{b:?}"
            );
            assert!(
                !drives_through(&SimulatedRobot::SHIPPED, &obstacles, rows, (0, 0), 0.0),
                "{b:?}"
            );
            // The search finds a pose of its own for the same robot, with the margin.
            let found = passing_pose(&SimulatedRobot::SHIPPED, b).unwrap();
            assert!(drives_through(
                &SimulatedRobot::SHIPPED,
                &obstacles,
                rows,
                found,
                FENCE_MARGIN_M
            ));
        }
        assert_eq!(fit.around_offset_m(), 0.40);
    }

    #[test]
    fn a_robot_too_tall_for_the_bar_has_no_lift_fence() {
        // Lifted high enough by default to clear the 0.15 m bar: the fence asks nothing of it.
        let tall = RobotGeometry {
            default_clearance_m: 0.20,
            ..wheelleg_runtime::robot::WHEELLEG
        };
        let tall = SimulatedRobot::new(tall, wheelleg_runtime::action::ActionLattice::PAPER);
        let fit = SceneRobot::new(&tall.unwrap());
        let why = fit.has(Behaviour::LiftOver).unwrap_err();
        assert!(
            why.contains("default pose drives through the lift fence"),
            "{why}"
        );
        assert_eq!(fit.passing_legs(Behaviour::LiftOver), (0, 0));
        assert!(fit.has(Behaviour::Straight).is_ok());
    }
}
