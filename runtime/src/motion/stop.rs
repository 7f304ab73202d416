//! A step slowed to rest along its own path: the safe stop's motion.

use super::*;

/// A controlled stop in the middle of a step ([`StepMotion::stop_after`]): yields the
/// decelerating setpoints, then [`StopMotion::rest`] is the pose to hold.
#[derive(Clone, Debug, PartialEq)]
pub struct StopMotion {
    pub(super) step: StepMotion,
    /// Setpoints of the step sent before the stop began.
    pub(super) from_tick: u32,
    /// Progress along the step reached by the setpoints yielded so far.
    pub(super) progress: f32,
    /// Progress rate of the last step setpoint sent, per second.
    pub(super) rate0_per_s: f32,
    /// Stop ticks yielded so far.
    pub(super) next: u32,
    /// Legs and joint angles at `progress`.
    pub(super) legs: LegConfig,
    pub(super) joints: JointAngles,
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
