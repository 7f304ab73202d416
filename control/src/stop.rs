//! Why the loop holds the robot in safe stop, how it comes to rest, and why an activity ends
//! in error.

use wheelleg_runtime::base::{BaseVelocity, WheelSpeeds};
use wheelleg_runtime::can::host::{AxisSet, CanError, RollCallRefusal};
use wheelleg_runtime::motion::{JointRates, MotionError, Setpoint, StepMotion, StopMotion};

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
    /// An emergency stop was sent to every axis ([`Control::estop`](crate::Control::estop)).
    Estop,
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

/// How the safe stop brings the robot to rest, planned in the period it is decided: inside a
/// step, the step's own path slowed to rest ([`StepMotion::stop_after`]) for every axis, the
/// silent one included (if it still hears, it follows; if not, its own watchdog idles it), so
/// legs and wheels stop together on a pose the step passes through anyway; outside a step, the
/// last setpoint sent with the wheels and joint rates zeroed. With nothing sent yet there is
/// no plan, and the commander holds the measured joints.
#[derive(Clone, Debug)]
pub(crate) struct StopPlan {
    /// The deceleration along the step's path, while it lasts.
    stopping: Option<StopMotion>,
    /// What is held once at rest.
    rest: Option<Setpoint>,
}

impl StopPlan {
    /// The plan for a stop decided before setpoint `tick_in_step` of `moving` went out (or
    /// between steps, `moving` being `None`, after `last_sent`).
    pub(crate) fn new(
        moving: Option<&StepMotion>,
        tick_in_step: u32,
        last_sent: Option<Setpoint>,
    ) -> StopPlan {
        let stopping = moving.and_then(|motion| motion.stop_after(tick_in_step).ok());
        let rest = match &stopping {
            Some(stop) => Some(stop.rest()),
            None => last_sent.map(|sent| Setpoint {
                joint_rates: JointRates::default(),
                base: BaseVelocity::ZERO,
                wheels: WheelSpeeds::ZERO,
                ..sent
            }),
        };
        StopPlan { stopping, rest }
    }

    /// This period's setpoint: the next of the deceleration, then the rest; `None` without a
    /// plan (the commander then holds the measured joints).
    pub(crate) fn next_setpoint(&mut self) -> Option<Setpoint> {
        if let Some(stop) = &mut self.stopping {
            match stop.next() {
                Some(setpoint) => return Some(setpoint),
                None => {
                    self.rest = Some(stop.rest());
                    self.stopping = None;
                }
            }
        }
        self.rest
    }

    /// Whether the robot has come to rest (the deceleration is over).
    pub(crate) fn at_rest(&self) -> bool {
        self.stopping.is_none()
    }

    /// What is held at rest, if known: while decelerating, where the stop has got to so far.
    pub(crate) fn rest(&self) -> Option<Setpoint> {
        match &self.stopping {
            Some(stop) => Some(stop.rest()),
            None => self.rest,
        }
    }
}
