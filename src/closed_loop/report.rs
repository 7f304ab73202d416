//! What the loop reports: each decision's fate, how closely the motors followed, and the
//! episode's end.

use super::{Fault, StepError};
use wheelleg_firmware_sim::rig::{MeasuredBusLoad, StepReport, TrafficCounts};
use wheelleg_runtime::action::Action;
use wheelleg_runtime::can::host::BusStats;
use wheelleg_sim::env::{Status, StepOutcome};
use wheelleg_sim::state::RobotState;

/// What happened to one decision.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StepKind {
    /// Executed by the motors and accepted by the world.
    Moved,
    /// Executed, refused by the world (collision or arena), and backed out of.
    Undone,
    /// Never sent to the motors: the legs cannot reach the target.
    Refused,
    /// Interrupted by a fault; the world did not move.
    Faulted,
}

/// One decision through the loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepRecord {
    /// The decision.
    pub action: Action,
    /// What became of it.
    pub kind: StepKind,
    /// The world's verdict (none when the step faulted before the world moved).
    pub outcome: Option<StepOutcome>,
    /// The rig's report of the step's motion (none when it was refused).
    pub report: Option<StepReport>,
    /// The rig's report of backing out (for [`StepKind::Undone`]).
    pub retreat: Option<StepReport>,
}

/// How closely the motors followed, over an episode.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct Tracking {
    /// Steps executed and accepted.
    pub moved: u32,
    /// Steps executed, refused by the world and backed out of.
    pub undone: u32,
    /// Steps never sent (unreachable legs).
    pub refused: u32,
    /// Largest error of any executed motion (steps and retreats) against its ideal.
    pub max_error: StepError,
}

/// The end of an episode through the loop.
#[derive(Clone, Debug, PartialEq)]
pub struct EpisodeReport {
    /// The world's verdict.
    pub status: Status,
    /// Decisions taken.
    pub steps: u32,
    /// Collisions the world counted.
    pub collisions: u32,
    /// Why the robot was stopped early, if it was.
    pub fault: Option<Fault>,
    /// How closely the motors followed.
    pub tracking: Tracking,
    /// The world's lattice states, from the start, one per accepted step.
    pub path: Vec<RobotState>,
    /// The states the robot stood in when the world undid a step of it for a collision.
    pub collided_at: Vec<RobotState>,
    /// Odometry against the world at the end: position difference (the drift a localiser
    /// would correct; the world itself snaps every step).
    pub odometry_drift_m: f32,
    /// Heading difference of odometry against the world at the end.
    pub odometry_drift_rad: f32,
    /// Simulated (or, on SocketCAN, real) time since the rig was made.
    pub elapsed_s: f64,
    /// Frames and bits on the bus.
    pub traffic: TrafficCounts,
    /// Bus load at [`BITRATE_BPS`].
    pub bus_load: Option<MeasuredBusLoad>,
    /// What the controller made of the feedback it received.
    pub feedback: BusStats,
}
