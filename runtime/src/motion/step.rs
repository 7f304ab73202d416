//! A step's motion: planned from the legs and an action, one setpoint per control tick.

use super::*;

/// The setpoint stream of one step; an iterator yielding exactly `ticks()` setpoints.
#[derive(Clone, Debug, PartialEq)]
pub struct StepMotion {
    pub(super) geometry: RobotGeometry,
    pub(super) start: LegConfig,
    pub(super) target: LegConfig,
    pub(super) displacement: BaseDisplacement,
    pub(super) ticks: u32,
    /// Ticks a stop in the middle of the step takes.
    pub(super) stop_ticks: u32,
    pub(super) tick_s: f32,
    pub(super) next_tick: u32,
    /// Joint angles at the end of the previous tick, for the velocity feed-forward.
    pub(super) previous_joints: JointAngles,
}

impl StepMotion {
    /// Plans the step `action` of `robot` (its geometry and action lattice) from leg
    /// configuration `start`, checking reachability along the way and the wheel and joint
    /// limits at every tick.
    pub fn plan(
        robot: &Robot,
        config: &MotionConfig,
        start: LegConfig,
        action: Action,
    ) -> Result<StepMotion, MotionError> {
        StepMotion::plan_between(
            &robot.geometry,
            config,
            start,
            target_config(start, action, &robot.actions),
            BaseDisplacement::of_action(action, &robot.actions),
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

    pub(super) fn legs_at(&self, s: f32) -> LegConfig {
        LegConfig {
            clearance_m: self.start.clearance_m
                + s * (self.target.clearance_m - self.start.clearance_m),
            track_m: self.start.track_m + s * (self.target.track_m - self.start.track_m),
        }
    }

    /// Progress at the end of tick `tick - 1`, i.e. after `tick` setpoints of the step.
    pub(super) fn progress_after(&self, ticks_sent: u32) -> f32 {
        progress(ticks_sent as f32 / self.ticks as f32)
    }

    pub(super) fn sample(&self, tick: u32, previous: JointAngles) -> Result<Setpoint, MotionError> {
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
    pub(super) fn sample_span(
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
