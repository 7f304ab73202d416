//! What stops an episode through the loop early: a step off tolerance, the controller's safe
//! stop, a disagreement over what the legs can reach, and the loop's own errors.

use super::{DriverError, Tolerance};
use std::fmt;
use wheelleg_firmware_sim::rig::{RigError, StepReport, StopReason};
use wheelleg_runtime::action::Action;
use wheelleg_runtime::can::host::AxisSet;
use wheelleg_runtime::can::node_map::{Axis, NodeMap};
use wheelleg_runtime::motion::MotionError;
use wheelleg_sim::env::EpisodeOver;
use wheelleg_sim::scenario::ScenarioError;

/// Errors of one achieved step against its ideal.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct StepError {
    /// Position error.
    pub position_m: f32,
    /// Heading error.
    pub yaw_rad: f32,
    /// Largest clearance or track error.
    pub legs_m: f32,
}

impl StepError {
    /// Errors of a rig report.
    pub fn of(report: &StepReport) -> StepError {
        StepError {
            position_m: report.position_error_m(),
            yaw_rad: report.yaw_error_rad(),
            legs_m: (report.achieved_legs.clearance_m - report.ideal_legs.clearance_m)
                .abs()
                .max((report.achieved_legs.track_m - report.ideal_legs.track_m).abs()),
        }
    }

    /// Whether every error is within `tolerance`.
    pub fn within(&self, tolerance: &Tolerance) -> bool {
        self.position_m <= tolerance.position_m
            && self.yaw_rad <= tolerance.yaw_rad
            && self.legs_m <= tolerance.legs_m
    }

    pub(super) fn max(self, other: StepError) -> StepError {
        StepError {
            position_m: self.position_m.max(other.position_m),
            yaw_rad: self.yaw_rad.max(other.yaw_rad),
            legs_m: self.legs_m.max(other.legs_m),
        }
    }
}

/// Why the loop stopped the robot before the episode ended.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Fault {
    /// The controller put the robot in safe stop (wheels stopped, legs held).
    SafeStop {
        /// Decision index (0-based) during which it happened.
        step: u32,
        /// What the controller saw.
        reason: StopReason,
    },
    /// A step (or the move backing out of one) ended too far from its ideal.
    OffTolerance {
        /// Decision index (0-based).
        step: u32,
        /// The errors measured.
        error: StepError,
    },
    /// The controller firmware stopped the robot (wheels stopped, legs held) and said why
    /// (`wheelleg demo --controller qemu`).
    Controller {
        /// Decision index (0-based) during or after which it happened.
        step: u32,
        /// What the firmware reported.
        reason: crate::hil::ControllerStop,
    },
    /// The runtime could not reach an action's legs that the simulator accepts.
    KinematicsDisagree {
        /// Decision index (0-based).
        step: u32,
        /// The action.
        action: Action,
    },
}

fn describe_axes(set: AxisSet) -> String {
    set.iter()
        .map(|axis: Axis| format!("node {} ({axis:?})", NodeMap::NOMINAL.node_id(axis).get()))
        .collect::<Vec<_>>()
        .join(", ")
}

impl fmt::Display for Fault {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Fault::SafeStop {
                step,
                reason: StopReason::Silent(set),
            } => write!(
                f,
                "safe stop during step {}: {} silent (no frames for the health timeout); \
                 wheels stopped, legs held",
                step + 1,
                describe_axes(*set)
            ),
            Fault::SafeStop {
                step,
                reason: StopReason::AxisError(set),
            } => write!(
                f,
                "safe stop during step {}: {} reported errors; wheels stopped, legs held",
                step + 1,
                describe_axes(*set)
            ),
            Fault::SafeStop { step, reason } => {
                let why = match reason {
                    StopReason::CanLink => "the CAN link was lost",
                    StopReason::ObservationStalled => "no observation within its timeout",
                    StopReason::ObservationCorrupt => "only corrupt observation frames",
                    StopReason::StartupFailed => "not every axis reached closed loop",
                    StopReason::Control => "a frame could not be queued or sent",
                    StopReason::Estop => "an emergency stop was sent to every axis",
                    StopReason::Silent(_) | StopReason::AxisError(_) => "axes failed",
                };
                write!(
                    f,
                    "safe stop during step {}: {why}; wheels stopped, legs held",
                    step + 1
                )
            }
            Fault::Controller { step, reason } => write!(
                f,
                "the controller stopped the robot at step {}: {reason}; wheels stopped, legs \
                 held",
                step + 1
            ),
            Fault::OffTolerance { step, error } => write!(
                f,
                "step {} ended off its ideal by {:.2} mm, {:.3}°, legs {:.2} mm (beyond \
                 tolerance); robot held",
                step + 1,
                1e3 * error.position_m,
                error.yaw_rad.to_degrees(),
                1e3 * error.legs_m
            ),
            Fault::KinematicsDisagree { step, action } => write!(
                f,
                "step {}: the runtime cannot reach the legs of {action:?} but the simulator \
                 accepts them; robot held",
                step + 1
            ),
        }
    }
}

/// Why the loop could not go on at all (as opposed to a [`Fault`], which is the robot stopping
/// safely and is part of the episode's report).
#[derive(Debug)]
pub enum LoopError {
    /// The scenario is invalid.
    Scenario(ScenarioError),
    /// The rig failed (bus, log, start-up, an impossible motion setting).
    Rig(RigError),
    /// The driver could not decide.
    Driver(DriverError),
    /// A step was asked for after the episode ended or after a fault.
    Finished,
}

impl fmt::Display for LoopError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            LoopError::Scenario(e) => write!(f, "{e}"),
            LoopError::Rig(RigError::StartupFailed(health)) => write!(
                f,
                "the motor controllers did not all reach closed loop at start-up \
                 (silent: {}; errored: {})",
                or_none(describe_axes(health.silent)),
                or_none(describe_axes(health.errored))
            ),
            // Already a sentence naming the node, the axis and the reason.
            LoopError::Rig(e @ RigError::StartupRefused(_)) => write!(f, "{e}"),
            LoopError::Rig(e) => write!(f, "rig: {e}"),
            LoopError::Driver(e) => write!(f, "driver: {e}"),
            LoopError::Finished => f.write_str("the episode is over"),
        }
    }
}

fn or_none(s: String) -> String {
    if s.is_empty() {
        "none".to_owned()
    } else {
        s
    }
}

impl std::error::Error for LoopError {}

impl From<ScenarioError> for LoopError {
    fn from(e: ScenarioError) -> Self {
        LoopError::Scenario(e)
    }
}

impl From<RigError> for LoopError {
    fn from(e: RigError) -> Self {
        LoopError::Rig(e)
    }
}

impl From<MotionError> for LoopError {
    fn from(e: MotionError) -> Self {
        LoopError::Rig(RigError::Motion(e))
    }
}

impl From<DriverError> for LoopError {
    fn from(e: DriverError) -> Self {
        LoopError::Driver(e)
    }
}

impl From<EpisodeOver> for LoopError {
    fn from(_: EpisodeOver) -> Self {
        LoopError::Finished
    }
}
