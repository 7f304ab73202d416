//! Why the loop holds the robot in safe stop, and why an activity ends in error.

use wheelleg_runtime::can::host::{AxisSet, CanError, RollCallRefusal};
use wheelleg_runtime::motion::MotionError;

/// Why the control loop holds the robot in safe stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopReason {
    /// Axes not heard from within [`HEALTH_TIMEOUT_US`](crate::HEALTH_TIMEOUT_US).
    Silent(AxisSet),
    /// Axes whose heartbeat reported errors.
    AxisError(AxisSet),
    /// The CAN link is lost ([`Board::link_lost`](crate::Board::link_lost)).
    CanLink,
    /// No observation within the observation timeout (the board's program decides).
    ObservationStalled,
    /// Only corrupt observation frames within the observation timeout.
    ObservationCorrupt,
    /// Not every axis reached closed loop at start-up.
    StartupFailed,
    /// A frame could not be queued or sent.
    Control,
}

/// The safe stop: why, and in which control period (counted from the first).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stop {
    /// Why.
    pub reason: StopReason,
    /// The period.
    pub tick: u32,
}

/// Why the control loop stops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ControlError {
    /// A frame could not be built or queued.
    Can(CanError),
    /// The step cannot be driven (legs out of reach, too fast).
    Motion(MotionError),
    /// The CAN peripheral refused a frame.
    Bus,
    /// Not every axis reached closed loop at start-up.
    StartupFailed,
    /// The start-up's roll call found a node missing, two devices on one node id, or firmware
    /// the codec does not speak; nothing was armed.
    StartupRefused(RollCallRefusal),
}

impl From<CanError> for ControlError {
    fn from(error: CanError) -> Self {
        ControlError::Can(error)
    }
}

impl From<MotionError> for ControlError {
    fn from(error: MotionError) -> Self {
        ControlError::Motion(error)
    }
}
