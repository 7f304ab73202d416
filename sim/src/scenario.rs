//! A scenario: where the robot starts, where it must go, what stands in the way.

use crate::collision::{ObstacleSet, RobotParts};
use crate::obstacle::Obstacle;
use crate::state::RobotState;
use core::fmt;
use nalgebra::Point2;
use wheelleg_runtime::robot::RobotGeometry;

/// One navigation problem.
#[derive(Clone, Debug, PartialEq)]
pub struct Scenario {
    /// A name to report it by.
    pub name: String,
    /// The robot's start (default leg pose).
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
    /// Checks what the type system cannot: finite numbers and a start that is not inside an
    /// obstacle.
    pub fn validate(&self, geometry: &RobotGeometry) -> Result<(), ScenarioError> {
        let fail = |field: &str, problem: &str| ScenarioError {
            scenario: format!("\"{}\"", self.name),
            field: field.to_string(),
            problem: problem.to_string(),
        };
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
        let parts = RobotParts::new(geometry, self.start.position, self.start.yaw_rad(), legs)
            .map_err(|e| fail("robot", &format!("start leg pose unreachable: {e:?}")))?;
        if ObstacleSet::new(&self.obstacles).collides(&parts) {
            return Err(fail("robot", "the robot starts inside an obstacle"));
        }
        Ok(())
    }
}
