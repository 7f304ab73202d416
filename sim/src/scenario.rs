//! A scenario: where the robot starts, where it must go, what stands in the way.

use crate::collision::{ObstacleSet, RobotParts};
use crate::obstacle::Obstacle;
use crate::robot::SimulatedRobot;
use crate::state::RobotState;
use core::fmt;
use nalgebra::Point2;

/// One navigation problem.
#[derive(Clone, Debug, PartialEq)]
pub struct Scenario {
    /// A name to report it by.
    pub name: String,
    /// The robot's start, leg pose included (generated scenes start in the default pose, except
    /// the start-stage curriculum's, `generate::generate_staged`).
    pub start: RobotState,
    /// The point to reach.
    pub target: Point2<f32>,
    /// The obstacles.
    pub obstacles: Vec<Obstacle>,
}

/// A scenario that cannot be used, naming the scenario and the field at fault.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct ScenarioError {
    /// The scenario's name, or its position in the file when it has none.
    pub scenario: String,
    /// Path of the offending field, e.g. `obstacles[2].kind`.
    pub field: String,
    /// What is wrong with it.
    pub problem: String,
}

impl fmt::Display for ScenarioError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "scenario {}: field `{}`: {}",
            self.scenario, self.field, self.problem
        )
    }
}

impl std::error::Error for ScenarioError {}

impl Scenario {
    /// Checks what the type system cannot: finite numbers, a start on `robot`'s lattice and
    /// not inside an obstacle.
    pub fn validate(&self, robot: &SimulatedRobot) -> Result<(), ScenarioError> {
        let fail = |field: &str, problem: &str| ScenarioError {
            scenario: format!("\"{}\"", self.name),
            field: field.to_string(),
            problem: problem.to_string(),
        };
        if self.start.lattice != *robot.lattice() {
            return Err(fail(
                "robot",
                "its start counts yaw and leg steps on another action lattice than the \
                 simulated robot's: the scene was made for another robot",
            ));
        }
        let geometry = robot.geometry();
        let finite = |v: f32| v.is_finite() && v.abs() < 1.0e4;
        if !finite(self.start.position.x) {
            return Err(fail("robot.x", "must be a finite number of metres"));
        }
        if !finite(self.start.position.y) {
            return Err(fail("robot.y", "must be a finite number of metres"));
        }
        if !finite(self.target.x) {
            return Err(fail("target.x", "must be a finite number of metres"));
        }
        if !finite(self.target.y) {
            return Err(fail("target.y", "must be a finite number of metres"));
        }
        for (i, o) in self.obstacles.iter().enumerate() {
            if !finite(o.centre.x) {
                return Err(fail(
                    &format!("obstacles[{i}].x"),
                    "must be a finite number of metres",
                ));
            }
            if !finite(o.centre.y) {
                return Err(fail(
                    &format!("obstacles[{i}].y"),
                    "must be a finite number of metres",
                ));
            }
        }
        let legs = self.start.leg_config(geometry);
        // Name the leg field(s) the file set, so an unreachable pose points at what to change.
        let legs_field = match (self.start.clearance_steps != 0, self.start.track_steps != 0) {
            (true, false) => "robot.clearance_m",
            (false, true) => "robot.track_m",
            (true, true) => "robot.clearance_m/robot.track_m",
            (false, false) => "robot",
        };
        let parts = RobotParts::new(geometry, self.start.position, self.start.yaw_rad(), legs)
            .map_err(|e| {
                fail(
                    legs_field,
                    &format!(
                        "start leg pose (clearance {:.2} m, track {:.2} m) unreachable by the \
                         leg IK: {e:?}",
                        legs.clearance_m, legs.track_m
                    ),
                )
            })?;
        if ObstacleSet::new(&self.obstacles).collides(&parts) {
            let pose = if legs_field == "robot" {
                String::new()
            } else {
                format!(
                    " (in its start leg pose: clearance {:.2} m, track {:.2} m)",
                    legs.clearance_m, legs.track_m
                )
            };
            return Err(fail(
                "robot",
                &format!("the robot starts inside an obstacle{pose}"),
            ));
        }
        Ok(())
    }
}
