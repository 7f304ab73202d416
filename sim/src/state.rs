//! The robot's state in the world, kept on the action lattice.
//!
//! Yaw, clearance and track change only by whole steps, so they are stored as integer step
//! counts: the state after any action sequence is exact, and two states compare equal exactly
//! when they are the same pose. Position moves along the robot's own axes and so leaves any
//! lattice; it is `f32`.

use nalgebra::{Isometry3, Point2, Translation3, UnitQuaternion, Vector2, Vector3};
use wheelleg_runtime::action::{Action, CLEARANCE_STEP_M, TRACK_STEP_M, YAW_STEP_DEG};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::BaseDisplacement;
use wheelleg_runtime::robot::{Robot, RobotGeometry};

/// Number of yaw steps in a full turn.
pub const YAW_STEPS_PER_TURN: i32 = (360.0 / YAW_STEP_DEG) as i32;

/// Pose and leg configuration of the robot.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RobotState {
    /// Body centre projected on the ground, world frame.
    pub position: Point2<f32>,
    /// Heading in yaw steps, in `0..YAW_STEPS_PER_TURN`.
    pub yaw_steps: i32,
    /// Clearance in steps from the default clearance.
    pub clearance_steps: i32,
    /// Track in steps from the default track.
    pub track_steps: i32,
}

impl RobotState {
    /// The robot at `position` with heading `yaw_steps`, legs in the default pose.
    pub fn new(position: Point2<f32>, yaw_steps: i32) -> Self {
        RobotState {
            position,
            yaw_steps: yaw_steps.rem_euclid(YAW_STEPS_PER_TURN),
            clearance_steps: 0,
            track_steps: 0,
        }
    }

    /// Heading in radians.
    pub fn yaw_rad(&self) -> f32 {
        (self.yaw_steps as f32 * YAW_STEP_DEG).to_radians()
    }

    /// Heading in degrees.
    pub fn yaw_deg(&self) -> f32 {
        self.yaw_steps as f32 * YAW_STEP_DEG
    }

    /// The legs' (clearance, track).
    pub fn leg_config(&self, geometry: &RobotGeometry) -> LegConfig {
        LegConfig {
            clearance_m: geometry.default_clearance_m
                + self.clearance_steps as f32 * CLEARANCE_STEP_M,
            track_m: geometry.default_track_m + self.track_steps as f32 * TRACK_STEP_M,
        }
    }

    /// The state an action leads to, before any check of whether it is allowed.
    ///
    /// The translation is along the robot's axes as they were when the decision was taken.
    pub fn after(&self, action: Action) -> RobotState {
        let (sin, cos) = self.yaw_rad().sin_cos();
        // The controller's definition of a step (runtime::motion), so both sides agree.
        let BaseDisplacement {
            dx_m: dx, dy_m: dy, ..
        } = BaseDisplacement::of_action(action, &Robot::WHEELLEG.actions);
        RobotState {
            position: self.position + Vector2::new(cos * dx - sin * dy, sin * dx + cos * dy),
            yaw_steps: (self.yaw_steps + action.yaw.sign() as i32).rem_euclid(YAW_STEPS_PER_TURN),
            clearance_steps: self.clearance_steps + action.clearance.sign() as i32,
            track_steps: self.track_steps + action.track.sign() as i32,
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
