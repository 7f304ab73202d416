//! The rig's settings, errors and reports: what a caller sets and what a step tells it.

use crate::bus::{BusError, Faults};
use nalgebra::Isometry2;
use wheelleg_runtime::base::BaseError;
use wheelleg_runtime::can::bus_load::frame_bits;
use wheelleg_runtime::can::host::{CanError, Health, RollCallRefusal};
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::{IkError, LegConfig};
use wheelleg_runtime::motion::{MotionConfig, MotionError};

pub use wheelleg_control::StopReason;

/// Settings of the closed loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigConfig {
    /// Control rate, step duration and limits.
    pub motion: MotionConfig,
    /// Physics step of the simulated axes (in-process bus only).
    pub physics_dt_us: u64,
    /// Hold time after each step's setpoints, so the motors settle before the pose is read.
    pub settle_s: f32,
    /// An axis not heard from for this long is silent.
    pub health_timeout_us: u64,
    /// Fault injection on the in-process bus.
    pub faults: Faults,
    /// Watchdog timeout the rig configures on the in-process axes (0: off, their own default).
    /// The safety design relies on it: an axis that hears no setpoint for this long idles
    /// (docs/can-protocol.md, "Safety").
    pub watchdog_timeout_us: u64,
}

impl Default for RigConfig {
    /// 100 Hz control, 1 kHz physics, 0.2 s settling, 50 ms silence timeout (5 missed encoder
    /// estimates at 100 Hz: one lost frame is noise, five in a row is a dead node), 100 ms axis
    /// watchdog (ten control ticks: a hung controller is caught, a late tick is not).
    fn default() -> Self {
        RigConfig {
            motion: MotionConfig::default(),
            physics_dt_us: 1_000,
            settle_s: 0.2,
            health_timeout_us: 50_000,
            faults: Faults::NONE,
            watchdog_timeout_us: 100_000,
        }
    }
}

/// Why the rig cannot go on.
#[derive(Debug)]
pub enum RigError {
    /// The step is impossible or too fast.
    Motion(MotionError),
    /// A leg configuration has no IK solution.
    Ik(IkError),
    /// The base kinematics refused a measured value.
    Base(BaseError),
    /// Frames could not be queued.
    Can(CanError),
    /// The transport failed.
    Bus(BusError),
    /// Writing the traffic log failed.
    Log(std::io::Error),
    /// The axes did not all reach closed loop at start-up (or nothing at all answered).
    StartupFailed(Health),
    /// The start-up roll call found a node missing, two devices on one node id, or firmware the
    /// codec does not speak: nothing was armed.
    StartupRefused(RollCallRefusal),
    /// The CAN peripheral refused a frame.
    Refused,
}

impl std::fmt::Display for RigError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            RigError::StartupRefused(refusal) => {
                write!(f, "start-up refused, nothing armed: {refusal}")
            }
            other => write!(f, "{other:?}"),
        }
    }
}

impl std::error::Error for RigError {}

macro_rules! from_error {
    ($($variant:ident($t:ty)),*) => {$(
        impl From<$t> for RigError {
            fn from(e: $t) -> Self {
                RigError::$variant(e)
            }
        }
    )*};
}
from_error!(
    Motion(MotionError),
    Ik(IkError),
    Base(BaseError),
    Can(CanError),
    Bus(BusError),
    Log(std::io::Error)
);

/// A fault the rig injects by itself when simulated time reaches a chosen instant, so that a
/// test can hit the middle of a motion rather than the gap between two steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimedFault {
    /// The axis stops transmitting for good (it still obeys commands): a broken transmitter.
    Silence(Axis),
    /// The axis drops off the bus for good: it neither transmits nor receives (a cut cable, a
    /// node in bus-off), so it runs on its last setpoint until its watchdog idles it.
    Disconnect(Axis),
    /// The controller's transmit path hangs (it keeps listening), as
    /// [`Rig::pause_commands`](super::Rig::pause_commands).
    HangCommands,
}

/// What one step achieved, beside what it should have.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepReport {
    /// Ideal pose change (in the frame of the step's start pose).
    pub ideal_pose: Isometry2<f32>,
    /// Measured pose change, by odometry from the measured wheel speeds.
    pub achieved_pose: Isometry2<f32>,
    /// Ideal leg configuration at the end of the step.
    pub ideal_legs: LegConfig,
    /// Measured leg configuration at the end of the step (forward kinematics).
    pub achieved_legs: LegConfig,
    /// Set if the controller stopped the robot during the step.
    pub stopped: Option<StopReason>,
}

impl StepReport {
    /// Distance between ideal and achieved position.
    pub fn position_error_m(&self) -> f32 {
        (self.ideal_pose.inverse() * self.achieved_pose)
            .translation
            .vector
            .norm()
    }

    /// Angle between ideal and achieved heading.
    pub fn yaw_error_rad(&self) -> f32 {
        (self.ideal_pose.inverse() * self.achieved_pose)
            .rotation
            .angle()
            .abs()
    }
}

/// Traffic the controller put on or heard from the bus since the rig was made: every frame of
/// the robot's bus passes the controller, so this is the bus's whole traffic.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct TrafficCounts {
    /// Frames sent and received.
    pub frames: u64,
    /// Their bits on the wire without stuff bits (including intermission).
    pub bits_nominal: u64,
    /// Their bits on the wire with worst-case stuffing.
    pub bits_worst_case: u64,
}

impl TrafficCounts {
    pub(super) fn count(&mut self, frame: &CanFrame) {
        use embedded_can::Frame;
        // A remote frame carries a DLC but no data bits.
        let data_len = if frame.is_remote_frame() {
            0
        } else {
            frame.data().len() as u8
        };
        let bits = frame_bits(data_len);
        self.frames += 1;
        self.bits_nominal += u64::from(bits.nominal);
        self.bits_worst_case += u64::from(bits.worst_case);
    }
}

/// Measured bus load: traffic over elapsed time, as a fraction of the bus's capacity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeasuredBusLoad {
    /// Frames per second.
    pub frames_per_s: f64,
    /// Fraction of capacity used, without stuff bits.
    pub nominal: f64,
    /// Fraction of capacity used, with worst-case stuffing.
    pub worst_case: f64,
}

/// Where the robot really was at one instant (in-process bus only): what a fault test checks
/// for collisions at every control period, not only after each step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrueSample {
    /// Simulated time.
    pub at_us: u64,
    /// [`Rig::true_pose`](super::Rig::true_pose) then.
    pub pose: Isometry2<f32>,
    /// [`Rig::true_legs`](super::Rig::true_legs) then.
    pub legs: LegConfig,
}
