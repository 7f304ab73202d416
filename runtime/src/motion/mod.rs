//! One discrete decision as a smooth stream of motor setpoints.
//!
//! The policy decides once per step; the motors want a setpoint every control tick. A
//! [`StepMotion`] bridges the two: planned from the current leg configuration and an
//! [`Action`], it yields one [`Setpoint`] per tick (default 100 Hz) for the step's duration, and
//! nothing more. It is an iterator over fixed-size values: no buffer, no allocation.
//!
//! **The ideal step** ([`ideal_step`]): the body translates by the lattice's move step along the start
//! pose's own x and/or y axis on a straight line, and rotates by its yaw step about its centre,
//! both at once, while the legs go from the start to the target (clearance, track). The end pose
//! is `start * Isometry2::new((dx, dy), dyaw)`.
//!
//! **The profile**: every quantity follows the same progress curve
//! `s(u) = u - sin(2πu) / 2π` over normalised time `u ∈ [0, 1]`. Its velocity `1 - cos(2πu)`
//! and acceleration `2π sin(2πu)` are zero at both ends, so consecutive steps join without a
//! jerk in velocity, and the peak velocity is twice the mean.
//!
//! **Exactness**: the wheel command for a tick is the *mean* body velocity over that tick (the
//! progress increment divided by the tick length), expressed in the body frame at the tick's
//! mid-heading. Integrated by [`crate::base::Odometry`] (which uses the same mid-heading rule),
//! the commands land on the ideal end pose up to floating-point rounding, not up to a
//! discretisation error.
//!
//! **Legs**: the (clearance, track) pair is interpolated on a straight line in that space and
//! every intermediate point is solved by the leg IK, so the legs never leave the reachable set
//! without [`StepMotion::plan`] refusing the step first.
//!
//! **Stopping** ([`StepMotion::stop_after`], [`StopMotion`]): base pose and legs are one
//! function of progress, so a stop that only slows progress down keeps the robot on the step's
//! path. The controller's safe stop does that: the progress rate ramps down to zero over
//! [`MotionConfig::stop_s`] for every axis at once, and the robot rests at a pose the step
//! passes through anyway (one the world validated with the step, see docs/robustness.md),
//! instead of wheels coasting while the legs freeze, which leaves the path.

use crate::action::{Action, ActionLattice};
use crate::base::{BaseError, BaseVelocity, MecanumBase, WheelSpeeds};
use crate::leg::{IkError, JointAngles, LegConfig};
use crate::robot::{Robot, RobotGeometry};
use core::f32::consts::PI;
use nalgebra::Isometry2;

mod step;
mod stop;
#[cfg(test)]
mod tests;

pub use step::StepMotion;
pub use stop::StopMotion;

/// Longest step the planner accepts, in ticks: keeps a typo in the rate or duration from
/// turning validation into a long loop.
pub const MAX_TICKS_PER_STEP: u32 = 100_000;

/// Timing and limits of the setpoint stream.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MotionConfig {
    /// Setpoints per second.
    pub control_rate_hz: f32,
    /// Duration of one decision step.
    pub step_duration_s: f32,
    /// Wheel speed limit (wheel axle, not motor).
    pub max_wheel_radps: f32,
    /// Joint speed limit for hip, knee and wheel mount (joint output, not motor).
    pub max_joint_radps: f32,
    /// How long a stop in the middle of a step takes ([`StepMotion::stop_after`]): the
    /// progress rate falls linearly from its last value to zero over this time.
    pub stop_s: f32,
}

impl Default for MotionConfig {
    /// 100 Hz, half a second per step. The limits leave margin over what a lattice step needs
    /// at that duration (peak wheel speed about 11 rad/s for a combined move and turn at full
    /// track, peak joint speed well under 1 rad/s). A stop takes 0.1 s: from the step's peak
    /// progress rate (4 /s) that is a deceleration of 40 /s², 1.6 times the step profile's own
    /// peak (2π / 0.25 s²), far inside the motors' acceleration limits, and it adds at most a
    /// fifth of a step (1 cm, 1°) to the motion.
    fn default() -> Self {
        MotionConfig {
            control_rate_hz: 100.0,
            step_duration_s: 0.5,
            max_wheel_radps: 20.0,
            max_joint_radps: 3.0,
            stop_s: 0.1,
        }
    }
}

/// Why a step cannot be executed.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum MotionError {
    /// Control rate, step duration or stop time not finite and positive, or more than
    /// [`MAX_TICKS_PER_STEP`] ticks.
    BadTiming,
    /// A limit is not finite and positive.
    BadLimit,
    /// The start or target configuration, or a point between them, has no leg solution.
    Unreachable(IkError),
    /// The base kinematics refused a value (non-finite input).
    Base(BaseError),
    /// The step needs a wheel faster than the limit; the value is the peak it would need.
    WheelSpeedLimit {
        /// Peak wheel speed the step would need.
        peak_radps: f32,
    },
    /// The step needs a joint faster than the limit; the value is the peak it would need.
    JointSpeedLimit {
        /// Peak joint speed the step would need.
        peak_radps: f32,
    },
}

impl From<IkError> for MotionError {
    fn from(e: IkError) -> Self {
        MotionError::Unreachable(e)
    }
}

impl From<BaseError> for MotionError {
    fn from(e: BaseError) -> Self {
        MotionError::Base(e)
    }
}

/// Rigid motion of the base over one step, in the frame of the pose the step starts from.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BaseDisplacement {
    /// Translation along the start pose's x.
    pub dx_m: f32,
    /// Translation along the start pose's y.
    pub dy_m: f32,
    /// Rotation, counter-clockwise.
    pub dyaw_rad: f32,
}

impl BaseDisplacement {
    /// No motion.
    pub const ZERO: BaseDisplacement = BaseDisplacement {
        dx_m: 0.0,
        dy_m: 0.0,
        dyaw_rad: 0.0,
    };

    /// The base part of a lattice action on `lattice`.
    pub fn of_action(action: Action, lattice: &ActionLattice) -> BaseDisplacement {
        BaseDisplacement {
            dx_m: f32::from(action.move_x.sign()) * lattice.move_step_m,
            dy_m: f32::from(action.move_y.sign()) * lattice.move_step_m,
            dyaw_rad: f32::from(action.yaw.sign()) * lattice.yaw_step_deg.to_radians(),
        }
    }

    /// The pose change as an isometry: `end = start * displacement.isometry()`.
    pub fn isometry(&self) -> Isometry2<f32> {
        crate::trig::isometry(self.dx_m, self.dy_m, self.dyaw_rad)
    }

    /// The pose change after `progress` (0 to 1) of the step: the step's straight line and
    /// steady turn, stopped part-way ([`progress`] maps time to this).
    pub fn isometry_at(&self, progress: f32) -> Isometry2<f32> {
        crate::trig::isometry(
            self.dx_m * progress,
            self.dy_m * progress,
            self.dyaw_rad * progress,
        )
    }

    fn is_finite(&self) -> bool {
        self.dx_m.is_finite() && self.dy_m.is_finite() && self.dyaw_rad.is_finite()
    }
}

/// The leg configuration an action on `lattice` asks for from `start` (not checked for
/// reachability).
pub fn target_config(start: LegConfig, action: Action, lattice: &ActionLattice) -> LegConfig {
    LegConfig {
        clearance_m: start.clearance_m
            + f32::from(action.clearance.sign()) * lattice.clearance_step_m,
        track_m: start.track_m + f32::from(action.track.sign()) * lattice.track_step_m,
    }
}

/// The ideal outcome of one step: end pose (relative to the start pose) and end legs.
pub fn ideal_step(
    start: LegConfig,
    action: Action,
    lattice: &ActionLattice,
) -> (Isometry2<f32>, LegConfig) {
    (
        BaseDisplacement::of_action(action, lattice).isometry(),
        target_config(start, action, lattice),
    )
}

/// Joint speeds of one leg (left-leg convention, like [`JointAngles`]).
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct JointRates {
    /// Hip joint speed.
    pub hip_radps: f32,
    /// Knee joint speed.
    pub knee_radps: f32,
    /// Wheel mount joint speed.
    pub wheel_mount_radps: f32,
}

impl JointRates {
    fn between(from: JointAngles, to: JointAngles, dt_s: f32) -> JointRates {
        JointRates {
            hip_radps: (to.hip_rad - from.hip_rad) / dt_s,
            knee_radps: (to.knee_rad - from.knee_rad) / dt_s,
            wheel_mount_radps: (to.wheel_mount_rad - from.wheel_mount_rad) / dt_s,
        }
    }

    /// Largest absolute joint speed.
    pub fn max_abs_radps(&self) -> f32 {
        self.hip_radps
            .abs()
            .max(self.knee_radps.abs())
            .max(self.wheel_mount_radps.abs())
    }
}

/// What the motors should do during one control tick.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Setpoint {
    /// Index of the tick within its step, from 0.
    pub tick: u32,
    /// When the tick starts, relative to the step's start.
    pub start_s: f32,
    /// Leg configuration to reach by the end of the tick.
    pub legs: LegConfig,
    /// Joint angles of `legs` (all four legs share them, mirrored).
    pub joints: JointAngles,
    /// Joint speeds over the tick, as velocity feed-forward.
    pub joint_rates: JointRates,
    /// Mean body velocity over the tick, in the body frame.
    pub base: BaseVelocity,
    /// Wheel speeds realising `base` at the tick's mean track.
    pub wheels: WheelSpeeds,
    /// Ideal pose at the end of the tick, relative to the step's start pose.
    pub ideal_pose: Isometry2<f32>,
}

impl Setpoint {
    /// Standing still with the legs at `legs`: what to send between steps or to hold safely.
    pub fn hold(geometry: &RobotGeometry, legs: LegConfig) -> Result<Setpoint, MotionError> {
        let joints = geometry.leg_ik(legs)?;
        Ok(Setpoint {
            tick: 0,
            start_s: 0.0,
            legs,
            joints,
            joint_rates: JointRates::default(),
            base: BaseVelocity::ZERO,
            wheels: WheelSpeeds::ZERO,
            ideal_pose: Isometry2::identity(),
        })
    }
}

/// Progress along the step at normalised time `u` (clamped to [0, 1]).
pub fn progress(u: f32) -> f32 {
    let u = u.clamp(0.0, 1.0);
    u - crate::trig::sin(2.0 * PI * u) / (2.0 * PI)
}
