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

/// A leg behaviour an episode used: a run of consecutive states whose legs left the default
/// pose one way.
#[derive(Clone, Debug, PartialEq)]
pub struct LegBehaviour {
    /// `lift` (body raised), `spread` (legs widened) or `squeeze` (legs narrowed).
    pub name: &'static str,
    /// First and last state of the run (0: the start).
    pub states: (usize, usize),
    /// Where the body centre was at the run's first and last state, world metres.
    pub from_m: (f32, f32),
    /// See `from_m`.
    pub to_m: (f32, f32),
    /// The farthest the run took the legs from the default pose, in lattice steps.
    pub most_steps: i32,
}

/// How many lattice steps a state's legs are off the default pose one way (0 or less: not).
type StepsOff = fn(&RobotState) -> i32;

/// The leg behaviours along `path`, in the order they began.
pub fn leg_behaviours(path: &[RobotState]) -> Vec<LegBehaviour> {
    let kinds: [(&'static str, StepsOff); 3] = [
        ("lift", |s| s.clearance_steps),
        ("spread", |s| s.track_steps),
        ("squeeze", |s| -s.track_steps),
    ];
    let mut found = Vec::new();
    for (name, steps) in kinds {
        let mut run: Option<LegBehaviour> = None;
        for (i, state) in path.iter().enumerate() {
            let at = (state.position.x, state.position.y);
            match (steps(state) > 0, run.as_mut()) {
                (true, Some(r)) => {
                    r.states.1 = i;
                    r.to_m = at;
                    r.most_steps = r.most_steps.max(steps(state));
                }
                (true, None) => {
                    run = Some(LegBehaviour {
                        name,
                        states: (i, i),
                        from_m: at,
                        to_m: at,
                        most_steps: steps(state),
                    })
                }
                (false, _) => found.extend(run.take()),
            }
        }
        found.extend(run);
    }
    found.sort_by_key(|b| b.states.0);
    found
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Point2;

    fn state(x: f32, clearance_steps: i32, track_steps: i32) -> RobotState {
        RobotState {
            clearance_steps,
            track_steps,
            ..RobotState::new(
                Point2::new(x, 0.0),
                0,
                &wheelleg_runtime::action::ActionLattice::PAPER,
            )
        }
    }

    #[test]
    fn each_run_off_the_default_pose_is_one_behaviour() {
        let path = [
            state(0.0, 0, 0),
            state(0.1, 1, 0),
            state(0.2, 3, -1),
            state(0.3, 0, -2),
            state(0.4, 0, 0),
            state(0.5, -1, 4),
            state(0.6, 0, 0),
        ];
        let found = leg_behaviours(&path);
        let summary: Vec<_> = found
            .iter()
            .map(|b| (b.name, b.states, b.most_steps))
            .collect();
        assert_eq!(
            summary,
            [
                ("lift", (1, 2), 3),
                ("squeeze", (2, 3), 2),
                ("spread", (5, 5), 4)
            ]
        );
        assert_eq!(found[0].from_m, (0.1, 0.0));
        assert_eq!(found[0].to_m, (0.2, 0.0));
        assert!(leg_behaviours(&path[..1]).is_empty());
    }
}
