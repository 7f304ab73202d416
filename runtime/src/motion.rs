//! One discrete decision as a smooth stream of motor setpoints.
//!
//! The policy decides once per step; the motors want a setpoint every control tick. A
//! [`StepMotion`] bridges the two: planned from the current leg configuration and an
//! [`Action`], it yields one [`Setpoint`] per tick (default 100 Hz) for the step's duration, and
//! nothing more. It is an iterator over fixed-size values: no buffer, no allocation.
//!
//! **The ideal step** ([`ideal_step`]): the body translates by `MOVE_STEP_M` along the start
//! pose's own x and/or y axis on a straight line, and rotates by `YAW_STEP_DEG` about its centre,
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

use crate::action::{Action, CLEARANCE_STEP_M, MOVE_STEP_M, TRACK_STEP_M, YAW_STEP_DEG};
use crate::base::{BaseError, BaseVelocity, MecanumBase, WheelSpeeds};
use crate::leg::{IkError, JointAngles, LegConfig};
use crate::robot::RobotGeometry;
use core::f32::consts::PI;
use nalgebra::Isometry2;

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

    /// The base part of a lattice action.
    pub fn of_action(action: Action) -> BaseDisplacement {
        BaseDisplacement {
            dx_m: f32::from(action.move_x.sign()) * MOVE_STEP_M,
            dy_m: f32::from(action.move_y.sign()) * MOVE_STEP_M,
            dyaw_rad: f32::from(action.yaw.sign()) * YAW_STEP_DEG.to_radians(),
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

/// The leg configuration an action asks for from `start` (not checked for reachability).
pub fn target_config(start: LegConfig, action: Action) -> LegConfig {
    LegConfig {
        clearance_m: start.clearance_m + f32::from(action.clearance.sign()) * CLEARANCE_STEP_M,
        track_m: start.track_m + f32::from(action.track.sign()) * TRACK_STEP_M,
    }
}

/// The ideal outcome of one step: end pose (relative to the start pose) and end legs.
pub fn ideal_step(start: LegConfig, action: Action) -> (Isometry2<f32>, LegConfig) {
    (
        BaseDisplacement::of_action(action).isometry(),
        target_config(start, action),
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

/// The setpoint stream of one step; an iterator yielding exactly `ticks()` setpoints.
#[derive(Clone, Debug, PartialEq)]
pub struct StepMotion {
    geometry: RobotGeometry,
    start: LegConfig,
    target: LegConfig,
    displacement: BaseDisplacement,
    ticks: u32,
    /// Ticks a stop in the middle of the step takes.
    stop_ticks: u32,
    tick_s: f32,
    next_tick: u32,
    /// Joint angles at the end of the previous tick, for the velocity feed-forward.
    previous_joints: JointAngles,
}

impl StepMotion {
    /// Plans the step `action` from leg configuration `start`, checking reachability along the
    /// way and the wheel and joint limits at every tick.
    pub fn plan(
        geometry: &RobotGeometry,
        config: &MotionConfig,
        start: LegConfig,
        action: Action,
    ) -> Result<StepMotion, MotionError> {
        StepMotion::plan_between(
            geometry,
            config,
            start,
            target_config(start, action),
            BaseDisplacement::of_action(action),
        )
    }

    /// Plans a step between arbitrary leg configurations with an arbitrary base displacement
    /// (for recovery moves and tests; lattice steps use [`StepMotion::plan`]).
    pub fn plan_between(
        geometry: &RobotGeometry,
        config: &MotionConfig,
        start: LegConfig,
        target: LegConfig,
        displacement: BaseDisplacement,
    ) -> Result<StepMotion, MotionError> {
        let ticks_f = config.control_rate_hz * config.step_duration_s;
        if !(config.control_rate_hz.is_finite()
            && config.step_duration_s.is_finite()
            && config.control_rate_hz > 0.0
            && config.step_duration_s > 0.0
            && ticks_f <= MAX_TICKS_PER_STEP as f32
            && config.stop_s.is_finite()
            && config.stop_s > 0.0
            && config.stop_s * config.control_rate_hz <= MAX_TICKS_PER_STEP as f32)
        {
            return Err(MotionError::BadTiming);
        }
        let limits_ok = |x: f32| x.is_finite() && x > 0.0;
        if !limits_ok(config.max_wheel_radps) || !limits_ok(config.max_joint_radps) {
            return Err(MotionError::BadLimit);
        }
        if !displacement.is_finite() {
            return Err(MotionError::Base(BaseError::NotFinite));
        }
        // At least one tick, so a very short step still ends exactly at its target.
        let ticks = (libm::roundf(ticks_f) as u32).max(1);
        let stop_ticks = (libm::roundf(config.stop_s * config.control_rate_hz) as u32).max(1);
        let motion = StepMotion {
            geometry: *geometry,
            start,
            target,
            displacement,
            ticks,
            stop_ticks,
            tick_s: config.step_duration_s / ticks as f32,
            next_tick: 0,
            previous_joints: geometry.leg_ik(start)?,
        };
        geometry.leg_ik(target)?;
        // Validation pass: the same computation the iterator does, so whatever it yields has
        // been checked against IK and the limits.
        let (mut peak_wheel_radps, mut peak_joint_radps) = (0.0f32, 0.0f32);
        let mut previous = motion.previous_joints;
        for tick in 0..ticks {
            let sample = motion.sample(tick, previous)?;
            peak_wheel_radps = peak_wheel_radps.max(sample.wheels.max_abs_radps());
            peak_joint_radps = peak_joint_radps.max(sample.joint_rates.max_abs_radps());
            previous = sample.joints;
        }
        if peak_wheel_radps > config.max_wheel_radps {
            return Err(MotionError::WheelSpeedLimit {
                peak_radps: peak_wheel_radps,
            });
        }
        if peak_joint_radps > config.max_joint_radps {
            return Err(MotionError::JointSpeedLimit {
                peak_radps: peak_joint_radps,
            });
        }
        Ok(motion)
    }

    /// Number of setpoints in the step.
    pub fn ticks(&self) -> u32 {
        self.ticks
    }

    /// Length of one tick.
    pub fn tick_s(&self) -> f32 {
        self.tick_s
    }

    /// Leg configuration at the start of the step.
    pub fn start(&self) -> LegConfig {
        self.start
    }

    /// Leg configuration at the end of the step.
    pub fn target(&self) -> LegConfig {
        self.target
    }

    /// Base motion over the whole step.
    pub fn displacement(&self) -> BaseDisplacement {
        self.displacement
    }

    fn legs_at(&self, s: f32) -> LegConfig {
        LegConfig {
            clearance_m: self.start.clearance_m
                + s * (self.target.clearance_m - self.start.clearance_m),
            track_m: self.start.track_m + s * (self.target.track_m - self.start.track_m),
        }
    }

    /// Progress at the end of tick `tick - 1`, i.e. after `tick` setpoints of the step.
    fn progress_after(&self, ticks_sent: u32) -> f32 {
        progress(ticks_sent as f32 / self.ticks as f32)
    }

    fn sample(&self, tick: u32, previous: JointAngles) -> Result<Setpoint, MotionError> {
        self.sample_span(
            tick,
            self.progress_after(tick),
            self.progress_after(tick + 1),
            previous,
        )
    }

    /// The setpoint of one tick that moves the step's progress from `s0` to `s1`: every
    /// quantity (base pose, legs) is the same function of progress as in the step itself, so
    /// any progress sequence stays on the step's path.
    fn sample_span(
        &self,
        tick: u32,
        s0: f32,
        s1: f32,
        previous: JointAngles,
    ) -> Result<Setpoint, MotionError> {
        let ds = s1 - s0;
        let d = self.displacement;
        let legs = self.legs_at(s1);
        let joints = self.geometry.leg_ik(legs)?;
        // Straight line in the start frame, seen from the body at the tick's mid-heading.
        let heading_rad = d.dyaw_rad * 0.5 * (s0 + s1);
        let (sin, cos) = (crate::trig::sin(heading_rad), crate::trig::cos(heading_rad));
        let (ux, uy) = (d.dx_m * ds / self.tick_s, d.dy_m * ds / self.tick_s);
        let base = BaseVelocity {
            vx_mps: cos * ux + sin * uy,
            vy_mps: -sin * ux + cos * uy,
            yaw_rate_radps: d.dyaw_rad * ds / self.tick_s,
        };
        let mean_legs = self.legs_at(0.5 * (s0 + s1));
        let wheels = MecanumBase::at(&self.geometry, mean_legs)?.wheel_speeds(base)?;
        let ideal_pose = d.isometry_at(s1);
        Ok(Setpoint {
            tick,
            start_s: tick as f32 * self.tick_s,
            legs,
            joints,
            joint_rates: JointRates::between(previous, joints, self.tick_s),
            base,
            wheels,
            ideal_pose,
        })
    }
}

impl StepMotion {
    /// The controlled stop of this step after `ticks_sent` of its setpoints have been sent:
    /// the robot decelerates *along the step's own path* (base pose and legs stay the same
    /// function of progress as in the step), so wherever it comes to rest is a pose the step
    /// itself passes through. The progress rate falls linearly from that of the last tick sent
    /// to zero over the configured stop time ([`MotionConfig::stop_s`]), never faster than the
    /// step itself would go, so the stop ends no later than the step would have and never
    /// beyond its target. Fails only if the legs at the current progress have no IK solution
    /// (impossible for a planned step; the caller then falls back to holding the measured
    /// joints).
    pub fn stop_after(&self, ticks_sent: u32) -> Result<StopMotion, MotionError> {
        let sent = ticks_sent.min(self.ticks);
        let progress_now = self.progress_after(sent);
        let rate_per_s = match sent.checked_sub(1) {
            Some(last) => (progress_now - self.progress_after(last)) / self.tick_s,
            None => 0.0,
        };
        let legs = self.legs_at(progress_now);
        Ok(StopMotion {
            step: self.clone(),
            from_tick: sent,
            progress: progress_now,
            rate0_per_s: rate_per_s.max(0.0),
            next: 0,
            joints: self.geometry.leg_ik(legs)?,
            legs,
        })
    }
}

/// A controlled stop in the middle of a step ([`StepMotion::stop_after`]): yields the
/// decelerating setpoints, then [`StopMotion::rest`] is the pose to hold.
#[derive(Clone, Debug, PartialEq)]
pub struct StopMotion {
    step: StepMotion,
    /// Setpoints of the step sent before the stop began.
    from_tick: u32,
    /// Progress along the step reached by the setpoints yielded so far.
    progress: f32,
    /// Progress rate of the last step setpoint sent, per second.
    rate0_per_s: f32,
    /// Stop ticks yielded so far.
    next: u32,
    /// Legs and joint angles at `progress`.
    legs: LegConfig,
    joints: JointAngles,
}

impl StopMotion {
    /// Progress along the step the robot is commanded to so far; once the stop has been
    /// yielded whole, where it rests.
    pub fn progress(&self) -> f32 {
        self.progress
    }

    /// Where the robot rests once the stop is over (or now, if it is cut short): the legs at
    /// the progress reached, wheels stopped. Needs no IK: the joints are those of the last
    /// setpoint.
    pub fn rest(&self) -> Setpoint {
        Setpoint {
            tick: self.from_tick + self.next,
            start_s: (self.from_tick + self.next) as f32 * self.step.tick_s,
            legs: self.legs,
            joints: self.joints,
            joint_rates: JointRates::default(),
            base: BaseVelocity::ZERO,
            wheels: WheelSpeeds::ZERO,
            ideal_pose: self.step.displacement.isometry_at(self.progress),
        }
    }

    /// The pose change from the step's start to where the stop rests (so far).
    pub fn rest_pose(&self) -> Isometry2<f32> {
        self.step.displacement.isometry_at(self.progress)
    }

    /// The stop's next setpoint, or `None` once it is over.
    fn advance(&mut self) -> Result<Option<Setpoint>, MotionError> {
        let m = self.step.stop_ticks;
        if self.next >= m {
            return Ok(None);
        }
        let j = self.next + 1;
        let tick = self.from_tick + self.next;
        // What the step itself would do in this tick (zero past its end) ...
        let planned_ds = self.step.progress_after(tick + 1) - self.step.progress_after(tick);
        // ... capped by the linear ramp of the rate, taken at the tick's middle.
        let ramp = 1.0 - (j as f32 - 0.5) / m as f32;
        let ramp_ds = self.rate0_per_s * self.step.tick_s * ramp;
        let ds = planned_ds.min(ramp_ds).max(0.0);
        let s1 = (self.progress + ds).min(1.0);
        let sample = self
            .step
            .sample_span(tick, self.progress, s1, self.joints)?;
        self.next = j;
        self.progress = s1;
        self.legs = sample.legs;
        self.joints = sample.joints;
        Ok(Some(sample))
    }
}

impl Iterator for StopMotion {
    type Item = Setpoint;

    fn next(&mut self) -> Option<Setpoint> {
        // Between two points of a planned step the legs are reachable; if IK somehow failed,
        // ending the stop here is the safe reaction: `rest` holds the last pose sent.
        match self.advance() {
            Ok(sample) => sample,
            Err(_) => {
                self.next = self.step.stop_ticks;
                None
            }
        }
    }
}

impl Iterator for StepMotion {
    type Item = Setpoint;

    fn next(&mut self) -> Option<Setpoint> {
        if self.next_tick >= self.ticks {
            return None;
        }
        // `plan` ran this exact computation for every tick, so it cannot fail here; if it
        // somehow did, ending the stream early is the safe reaction (the caller then holds).
        let sample = self.sample(self.next_tick, self.previous_joints).ok()?;
        self.next_tick += 1;
        self.previous_joints = sample.joints;
        Some(sample)
    }

    fn size_hint(&self) -> (usize, Option<usize>) {
        let left = self.ticks.saturating_sub(self.next_tick) as usize;
        (left, Some(left))
    }
}

impl ExactSizeIterator for StepMotion {}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::action::Step;
    use crate::base::{Odometry, WheelSpeeds};
    use crate::robot::WHEELLEG;

    fn default_legs() -> LegConfig {
        LegConfig {
            clearance_m: WHEELLEG.default_clearance_m,
            track_m: WHEELLEG.default_track_m,
        }
    }

    fn busy_action() -> Action {
        Action {
            move_x: Step::Plus,
            move_y: Step::Minus,
            yaw: Step::Plus,
            clearance: Step::Plus,
            track: Step::Minus,
        }
    }

    #[test]
    fn default_stream_has_one_setpoint_per_tick_at_100_hz() {
        let m = StepMotion::plan(
            &WHEELLEG,
            &MotionConfig::default(),
            default_legs(),
            busy_action(),
        )
        .unwrap();
        assert_eq!(m.len(), 50);
        let all: heapless::Vec<Setpoint, 64> = m.collect();
        assert_eq!(all.len(), 50);
        assert!((all[1].start_s - 0.01).abs() < 1e-6);
    }

    #[test]
    fn integrated_commands_land_on_the_ideal_step() {
        let start = default_legs();
        for index in 0..crate::action::COUNT {
            let action = Action::from_index(index).unwrap();
            let Ok(m) = StepMotion::plan(&WHEELLEG, &MotionConfig::default(), start, action) else {
                continue;
            };
            let tick_s = m.tick_s();
            let mut odo = Odometry::default();
            let mut last: Option<Setpoint> = None;
            for sp in m {
                // The wheels were solved at the tick's mean track; legs move linearly in
                // progress, so that is the mean of the tick's end points.
                let previous_track_m = last.map_or(start.track_m, |p| p.legs.track_m);
                let mean_track_m = 0.5 * (previous_track_m + sp.legs.track_m);
                let base = MecanumBase::new(&WHEELLEG, mean_track_m).unwrap();
                // Odometry from the wheel commands, the way the robot would measure them.
                let v = base.body_velocity(sp.wheels).unwrap();
                odo.integrate(v, tick_s).unwrap();
                last = Some(sp);
            }
            let last = last.unwrap();
            let (pose, legs) = ideal_step(start, action);
            let err = odo.pose.inverse() * pose;
            assert!(err.translation.vector.norm() < 1e-5, "{action:?}: {odo:?}");
            assert!(err.rotation.angle().abs() < 1e-5);
            assert_eq!(last.legs, legs);
            assert_eq!(last.ideal_pose.rotation.angle(), pose.rotation.angle());
        }
    }

    #[test]
    fn velocities_start_and_end_at_rest_and_stay_within_limits() {
        let config = MotionConfig::default();
        let m = StepMotion::plan(&WHEELLEG, &config, default_legs(), busy_action()).unwrap();
        let all: heapless::Vec<Setpoint, 64> = m.collect();
        let first = all.first().unwrap();
        let last = all.last().unwrap();
        let peak = all
            .iter()
            .map(|s| s.base.yaw_rate_radps)
            .fold(0.0f32, f32::max);
        // The raised-cosine profile: the end ticks move far less than the middle ones.
        assert!(first.base.yaw_rate_radps < 0.02 * peak);
        assert!(last.base.yaw_rate_radps < 0.02 * peak);
        // Peak is twice the mean (5 degrees over 0.5 s) within discretisation.
        let mean_radps = 5.0f32.to_radians() / 0.5;
        assert!(
            (peak - 2.0 * mean_radps).abs() < 0.01 * mean_radps,
            "{peak}"
        );
        for s in &all {
            assert!(s.wheels.max_abs_radps() <= config.max_wheel_radps);
            assert!(s.joint_rates.max_abs_radps() <= config.max_joint_radps);
        }
    }

    #[test]
    fn legs_follow_ik_at_every_tick() {
        let m = StepMotion::plan(
            &WHEELLEG,
            &MotionConfig::default(),
            default_legs(),
            busy_action(),
        )
        .unwrap();
        let mut previous = default_legs();
        for sp in m {
            let back = WHEELLEG.config_from_joints(sp.joints);
            assert!((back.track_m - sp.legs.track_m).abs() < 1e-5);
            assert!((back.clearance_m - sp.legs.clearance_m).abs() < 1e-5);
            // Monotone interpolation: clearance only rises, track only narrows.
            assert!(sp.legs.clearance_m >= previous.clearance_m - 1e-7);
            assert!(sp.legs.track_m <= previous.track_m + 1e-7);
            previous = sp.legs;
        }
    }

    #[test]
    fn impossible_or_too_fast_steps_are_refused() {
        let top = LegConfig {
            clearance_m: 0.24,
            track_m: 0.36,
        };
        let up = Action {
            clearance: Step::Plus,
            ..Action::IDLE
        };
        assert!(matches!(
            StepMotion::plan(&WHEELLEG, &MotionConfig::default(), top, up),
            Err(MotionError::Unreachable(_))
        ));
        let hasty = MotionConfig {
            step_duration_s: 0.02,
            ..MotionConfig::default()
        };
        let forward = Action {
            move_x: Step::Plus,
            ..Action::IDLE
        };
        assert!(matches!(
            StepMotion::plan(&WHEELLEG, &hasty, default_legs(), forward),
            Err(MotionError::WheelSpeedLimit { .. })
        ));
        let slow_joints = MotionConfig {
            max_joint_radps: 0.01,
            ..MotionConfig::default()
        };
        assert!(matches!(
            StepMotion::plan(&WHEELLEG, &slow_joints, default_legs(), up),
            Err(MotionError::JointSpeedLimit { .. })
        ));
        let no_rate = MotionConfig {
            control_rate_hz: f32::NAN,
            ..MotionConfig::default()
        };
        assert_eq!(
            StepMotion::plan(&WHEELLEG, &no_rate, default_legs(), forward),
            Err(MotionError::BadTiming)
        );
    }

    #[test]
    fn a_stop_decelerates_along_the_steps_own_path() {
        let config = MotionConfig::default();
        let start = default_legs();
        let step = StepMotion::plan(&WHEELLEG, &config, start, busy_action()).unwrap();
        let tick_s = step.tick_s();
        for sent in [0, 1, 10, 25, 40, 49, 50] {
            let stop = step.stop_after(sent).unwrap();
            let s0 = stop.progress();
            let r0 = if sent == 0 {
                0.0
            } else {
                (progress(sent as f32 / 50.0) - progress((sent - 1) as f32 / 50.0)) / tick_s
            };
            let mut odo = Odometry {
                pose: step.displacement().isometry_at(s0),
            };
            let mut previous_s = s0;
            let mut count = 0;
            let mut stop_iter = stop.clone();
            for sp in stop_iter.by_ref() {
                count += 1;
                // On the path: legs and pose are the step's at some progress, never going back.
                let s = (sp.legs.clearance_m - start.clearance_m) / CLEARANCE_STEP_M;
                assert!(s >= previous_s - 1e-5 && s <= 1.0 + 1e-5, "{sent}: {s}");
                let ideal = step.displacement().isometry_at(s);
                assert!(
                    (ideal.translation.vector - sp.ideal_pose.translation.vector).norm() < 1e-5
                );
                assert!(sp.wheels.max_abs_radps() <= config.max_wheel_radps);
                let previous_track_m = start.track_m - previous_s * TRACK_STEP_M;
                let base = MecanumBase::new(&WHEELLEG, 0.5 * (previous_track_m + sp.legs.track_m))
                    .unwrap();
                odo.integrate(base.body_velocity(sp.wheels).unwrap(), tick_s)
                    .unwrap();
                previous_s = s;
            }
            assert!(count <= 10, "a stop takes at most stop_s");
            let rest = stop_iter.rest();
            assert_eq!(rest.wheels, WheelSpeeds::ZERO);
            // Never beyond the step's end, never more than the ramp allows.
            assert!(stop_iter.progress() <= 1.0);
            assert!(stop_iter.progress() <= s0 + 0.5 * r0 * config.stop_s + 1e-5);
            // The wheel commands integrate to the rest pose: the base stops on the path too.
            let err = odo.pose.inverse() * stop_iter.rest_pose();
            assert!(err.translation.vector.norm() < 1e-5, "{sent}: {err:?}");
            assert!(err.rotation.angle().abs() < 1e-5);
        }
        // Nothing sent yet: the robot rests where the step starts.
        let stop = step.stop_after(0).unwrap();
        assert_eq!(stop.rest().legs, start);
    }

    #[test]
    fn control_rate_is_configurable() {
        let config = MotionConfig {
            control_rate_hz: 250.0,
            step_duration_s: 0.8,
            ..MotionConfig::default()
        };
        let m = StepMotion::plan(&WHEELLEG, &config, default_legs(), busy_action()).unwrap();
        assert_eq!(m.ticks(), 200);
        assert!((m.tick_s() - 0.004).abs() < 1e-7);
    }
}
