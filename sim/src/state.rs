//! The robot's state in the world, kept on its action lattice.
//!
//! Yaw, clearance and track change only by whole steps, so they are stored as integer step
//! counts: the state after any action sequence is exact, and two states compare equal exactly
//! when they are the same pose. Position moves along the robot's own axes and so leaves any
//! lattice; it is `f32`. The state carries the lattice its steps count on, so that it reads
//! the same wherever it goes.

use crate::robot::yaw_steps_per_turn;
use nalgebra::{Isometry3, Point2, Translation3, UnitQuaternion, Vector2, Vector3};
use wheelleg_runtime::action::{Action, ActionLattice};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::BaseDisplacement;
use wheelleg_runtime::robot::RobotGeometry;

/// Pose and leg configuration of the robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotState {
    /// Body centre projected on the ground, world frame.
    pub position: Point2<f32>,
    /// Heading in yaw steps, in `0..`[`RobotState::yaw_steps_per_turn`].
    pub yaw_steps: i32,
    /// Clearance in steps from the default clearance.
    pub clearance_steps: i32,
    /// Track in steps from the default track.
    pub track_steps: i32,
    /// The lattice the steps count on (a [`crate::robot::SimulatedRobot`]'s).
    pub lattice: ActionLattice,
}

impl RobotState {
    /// The robot at `position` with heading `yaw_steps` on `lattice`, legs in the default pose.
    pub fn new(position: Point2<f32>, yaw_steps: i32, lattice: &ActionLattice) -> Self {
        RobotState {
            position,
            yaw_steps: yaw_steps.rem_euclid(yaw_steps_per_turn(lattice)),
            clearance_steps: 0,
            track_steps: 0,
            lattice: *lattice,
        }
    }

    /// Whole yaw steps in a full turn on the state's lattice.
    pub fn yaw_steps_per_turn(&self) -> i32 {
        yaw_steps_per_turn(&self.lattice)
    }

    /// Heading in radians.
    pub fn yaw_rad(&self) -> f32 {
        (self.yaw_steps as f32 * self.lattice.yaw_step_deg).to_radians()
    }

    /// Heading in degrees.
    pub fn yaw_deg(&self) -> f32 {
        self.yaw_steps as f32 * self.lattice.yaw_step_deg
    }

    /// The signed turn from `self` to `to`, in yaw steps, for neighbours on the lattice (at most
    /// one step apart): -1, 0 or +1 across the wrap at a full turn.
    pub fn yaw_steps_to(&self, to: &RobotState) -> i32 {
        let steps = to.yaw_steps - self.yaw_steps;
        // Only a turn across the wrap needs the turn's length (a division).
        if (-1..=1).contains(&steps) {
            steps
        } else {
            (steps + 1).rem_euclid(self.yaw_steps_per_turn()) - 1
        }
    }

    /// The signed turn from `self` to a neighbour `to`, radians ([`RobotState::yaw_steps_to`]).
    pub fn yaw_turn_rad_to(&self, to: &RobotState) -> f32 {
        (self.yaw_steps_to(to) as f32 * self.lattice.yaw_step_deg).to_radians()
    }

    /// The legs' (clearance, track).
    pub fn leg_config(&self, geometry: &RobotGeometry) -> LegConfig {
        LegConfig {
            clearance_m: geometry.default_clearance_m
                + self.clearance_steps as f32 * self.lattice.clearance_step_m,
            track_m: geometry.default_track_m + self.track_steps as f32 * self.lattice.track_step_m,
        }
    }

    /// `yaw_steps` brought into `0..`[`RobotState::yaw_steps_per_turn`]; kept out of a step's
    /// way, since a step crosses the wrap once in tens.
    #[cold]
    fn wrapped(&self, yaw_steps: i32) -> i32 {
        yaw_steps.rem_euclid(self.yaw_steps_per_turn())
    }

    /// The state an action leads to, before any check of whether it is allowed.
    ///
    /// The translation is along the robot's axes as they were when the decision was taken.
    #[inline]
    pub fn after(&self, action: Action) -> RobotState {
        let (sin, cos) = self.yaw_rad().sin_cos();
        // The controller's definition of a step (runtime::motion), so both sides agree.
        let BaseDisplacement {
            dx_m: dx, dy_m: dy, ..
        } = BaseDisplacement::of_action(action, &self.lattice);
        // Wrapped only past either end of the turn, so that a step multiplies where the wrap
        // would divide (every yaw step is at least 1.5 degrees: the last one is below 359).
        let yaw_steps = self.yaw_steps + action.yaw.sign() as i32;
        let yaw_steps = if yaw_steps >= 0 && (yaw_steps as f32) * self.lattice.yaw_step_deg < 359.0
        {
            yaw_steps
        } else {
            self.wrapped(yaw_steps)
        };
        RobotState {
            position: self.position + Vector2::new(cos * dx - sin * dy, sin * dx + cos * dy),
            yaw_steps,
            clearance_steps: self.clearance_steps + action.clearance.sign() as i32,
            track_steps: self.track_steps + action.track.sign() as i32,
            lattice: self.lattice,
        }
    }

    /// World pose of the body frame (origin at the body centre).
    pub fn body_pose(&self, geometry: &RobotGeometry) -> Isometry3<f32> {
        let height_m = geometry.body_centre_height_m(self.leg_config(geometry).clearance_m);
        body_pose_at(self.position, self.yaw_rad(), height_m)
    }

    /// A point in the robot frame (x ahead, y left) expressed in the world frame.
    pub fn robot_to_world(&self, local: Vector2<f32>) -> Point2<f32> {
        let (sin, cos) = self.yaw_rad().sin_cos();
        self.position + Vector2::new(cos * local.x - sin * local.y, sin * local.x + cos * local.y)
    }

    /// A world point expressed in the robot frame.
    pub fn world_to_robot(&self, world: Point2<f32>) -> Vector2<f32> {
        let (sin, cos) = self.yaw_rad().sin_cos();
        let d = world - self.position;
        Vector2::new(cos * d.x + sin * d.y, -sin * d.x + cos * d.y)
    }
}

/// World pose of a body frame at ground position `position`, heading `yaw_rad`, centre height
/// `height_m`.
pub fn body_pose_at(position: Point2<f32>, yaw_rad: f32, height_m: f32) -> Isometry3<f32> {
    Isometry3::from_parts(
        Translation3::new(position.x, position.y, height_m),
        UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw_rad),
    )
}
