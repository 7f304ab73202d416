//! Ground truth and injected faults (in-process bus only): what fault tests see and do that
//! the controller cannot.

use super::{Rig, TimedFault};
use nalgebra::Isometry2;
use wheelleg_runtime::base::WheelSpeeds;
use wheelleg_runtime::leg::LegConfig;

/// Where the robot really was at one instant (in-process bus only): what a fault test checks
/// for collisions at every control tick, not only after each step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrueSample {
    /// Simulated time.
    pub at_us: u64,
    /// [`Rig::true_pose`] then.
    pub pose: Isometry2<f32>,
    /// [`Rig::true_legs`] then.
    pub legs: LegConfig,
}

impl Rig {
    /// Injects `fault` at the first physics step at or after `at_us` (in-process bus only: a
    /// remote rig has no physics steps, and its motors are out of reach).
    pub fn schedule(&mut self, at_us: u64, fault: TimedFault) {
        self.scheduled.push((at_us, fault));
    }

    /// Where the robot really is relative to where it started: odometry of the simulated
    /// wheels' true speeds at every physics step, with the true leg track. Unlike
    /// [`Rig::pose`], a silent or lying node cannot corrupt it. Identity for a remote rig.
    pub fn true_pose(&self) -> Isometry2<f32> {
        self.true_odometry.pose
    }

    /// The legs as the simulated joints really are (forward kinematics of their true
    /// positions, averaged over the four legs); `None` for a remote rig.
    pub fn true_legs(&self) -> Option<LegConfig> {
        self.firmware
            .true_legs(&self.robot.can, &self.robot.geometry)
    }

    pub(super) fn true_wheel_speeds(&self) -> Option<WheelSpeeds> {
        self.firmware.true_wheel_speeds(&self.robot.can)
    }

    /// Starts (or stops) recording the ground truth at the end of every control tick; what was
    /// recorded so far is kept until [`Rig::take_truth`].
    pub fn record_truth(&mut self, on: bool) {
        match (on, &self.truth) {
            (true, None) => self.truth = Some(Vec::new()),
            (false, Some(_)) => self.truth = None,
            _ => {}
        }
    }

    /// The ground truth recorded since the last call (empty when not recording).
    pub fn take_truth(&mut self) -> Vec<TrueSample> {
        self.truth.as_mut().map(std::mem::take).unwrap_or_default()
    }

    /// Applies the scheduled faults that are due at `now_us`.
    pub(super) fn inject_due_faults(&mut self) {
        let now_us = self.now_us;
        let (due, later): (Vec<_>, Vec<_>) = self
            .scheduled
            .drain(..)
            .partition(|(at_us, _)| *at_us <= now_us);
        self.scheduled = later;
        for (_, fault) in due {
            match fault {
                TimedFault::Silence(axis) => {
                    if let Some(motor) = self.firmware.axis_mut(axis) {
                        motor.set_silent(true);
                    }
                }
                TimedFault::Disconnect(axis) => {
                    if let Some(motor) = self.firmware.axis_mut(axis) {
                        motor.set_silent(true);
                        motor.set_deaf(true);
                    }
                }
                TimedFault::HangCommands => self.commands_paused = true,
            }
        }
    }

    /// Simulates a controller whose transmit path hangs: it keeps listening but sends nothing.
    pub fn pause_commands(&mut self, paused: bool) {
        self.commands_paused = paused;
    }
}
