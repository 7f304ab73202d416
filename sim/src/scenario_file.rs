//! Scenario files: JSON, read and written by the CLI.
//!
//! ```json
//! {"scenarios":[{"name":"bar-0","robot":{"x":0.0,"y":0.0,"yaw_deg":30.0},
//!   "target":{"x":0.8,"y":0.0},
//!   "obstacles":[{"kind":"bar","x":0.375,"y":0.125,"yaw_deg":0}]}]}
//! ```
//! Lengths in metres, angles in degrees. A file is read and written for one robot: the robot's
//! yaw must lie on its action lattice (5 degree steps for the shipped robot); obstacle yaw is 0
//! or 90 (180 and 270 are the same boxes and are accepted).
//!
//! The robot may also give its start leg pose, `"clearance_m"` and `"track_m"`, each on its
//! action lattice from its default pose (0.02 m steps from 0.12 m and 0.36 m for the shipped
//! robot). Absent means the default, and they are written only when not default.

use crate::obstacle::{Obstacle, ObstacleKind, ObstacleYaw};
use crate::robot::SimulatedRobot;
use crate::scenario::{Scenario, ScenarioError};
use crate::state::RobotState;
use nalgebra::Point2;
use serde::{Deserialize, Serialize};
use std::path::Path;
use wheelleg_runtime::robot::RobotGeometry;

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct FileRecord {
    scenarios: Vec<ScenarioRecord>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ScenarioRecord {
    name: String,
    robot: RobotRecord,
    target: PointRecord,
    #[serde(default)]
    obstacles: Vec<ObstacleRecord>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct RobotRecord {
    x: f64,
    y: f64,
    yaw_deg: f64,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    clearance_m: Option<f64>,
    #[serde(default, skip_serializing_if = "Option::is_none")]
    track_m: Option<f64>,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct PointRecord {
    x: f64,
    y: f64,
}

#[derive(Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
struct ObstacleRecord {
    kind: String,
    x: f64,
    y: f64,
    yaw_deg: f64,
}

/// Why a scenario file could not be used.
#[derive(Debug)]
pub enum ScenarioFileError {
    /// The file could not be read or written.
    Io {
        /// The file.
        path: String,
        /// The cause.
        source: std::io::Error,
    },
    /// Not JSON of the scenario file's shape.
    Syntax {
        /// Where in the document (e.g. `scenarios[1].robot.x`) and what.
        message: String,
    },
    /// Well-formed, but a scenario in it is impossible.
    Invalid(ScenarioError),
}

impl std::fmt::Display for ScenarioFileError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            ScenarioFileError::Io { path, source } => write!(f, "{path}: {source}"),
            ScenarioFileError::Syntax { message } => {
                write!(f, "malformed scenario file: {message}")
            }
            ScenarioFileError::Invalid(e) => write!(f, "impossible scenario: {e}"),
        }
    }
}

impl std::error::Error for ScenarioFileError {}

/// Parses and validates scenario JSON.
pub fn parse(json: &str, robot: &SimulatedRobot) -> Result<Vec<Scenario>, ScenarioFileError> {
    let mut deserializer = serde_json::Deserializer::from_str(json);
    let file: FileRecord = serde_path_to_error::deserialize(&mut deserializer).map_err(|e| {
        ScenarioFileError::Syntax {
            message: format!("at `{}`: {}", e.path(), e.inner()),
        }
    })?;
    file.scenarios
        .into_iter()
        .enumerate()
        .map(|(i, record)| {
            let scenario = from_record(i, record, robot)?;
            scenario.validate(robot)?;
            Ok(scenario)
        })
        .collect::<Result<_, ScenarioError>>()
        .map_err(ScenarioFileError::Invalid)
}

/// Reads and validates a scenario file.
pub fn load(path: &Path, robot: &SimulatedRobot) -> Result<Vec<Scenario>, ScenarioFileError> {
    let json = std::fs::read_to_string(path).map_err(|source| ScenarioFileError::Io {
        path: path.display().to_string(),
        source,
    })?;
    parse(&json, robot)
}

/// Serializes scenarios as a scenario file.
pub fn to_json(scenarios: &[Scenario], robot: &SimulatedRobot) -> String {
    let file = FileRecord {
        scenarios: scenarios
            .iter()
            .map(|s| to_record(s, robot.geometry()))
            .collect(),
    };
    // Serializing plain records of strings and numbers cannot fail.
    serde_json::to_string_pretty(&file).unwrap_or_default()
}

/// Writes a scenario file atomically: a reader never sees half a file, and a failed write leaves
/// the old file in place.
pub fn save(
    path: &Path,
    scenarios: &[Scenario],
    robot: &SimulatedRobot,
) -> Result<(), ScenarioFileError> {
    crate::atomic_write(path, to_json(scenarios, robot).as_bytes()).map_err(|source| {
        ScenarioFileError::Io {
            path: path.display().to_string(),
            source,
        }
    })
}

fn from_record(
    index: usize,
    r: ScenarioRecord,
    robot: &SimulatedRobot,
) -> Result<Scenario, ScenarioError> {
    let (geometry, lattice) = (robot.geometry(), robot.lattice());
    let label = if r.name.is_empty() {
        format!("#{index}")
    } else {
        format!("\"{}\" (#{index})", r.name)
    };
    let fail = |field: String, problem: &str| ScenarioError {
        scenario: label.clone(),
        field,
        problem: problem.to_string(),
    };
    let number = |v: f64, field: &str| -> Result<f32, ScenarioError> {
        if v.is_finite() && v.abs() < 1.0e4 {
            Ok(v as f32)
        } else {
            Err(fail(
                field.to_string(),
                "must be a finite number below 10^4",
            ))
        }
    };
    let yaw_deg = number(r.robot.yaw_deg, "robot.yaw_deg")?;
    let yaw_step_deg = lattice.yaw_step_deg;
    let yaw_steps = (yaw_deg / yaw_step_deg).round();
    if (yaw_steps * yaw_step_deg - yaw_deg).abs() > 1e-3 || yaw_steps.abs() > 1.0e6 {
        return Err(fail(
            "robot.yaw_deg".into(),
            &format!("must be a multiple of {yaw_step_deg} degrees (the robot's yaw lattice)"),
        ));
    }
    let mut start = RobotState::new(
        Point2::new(number(r.robot.x, "robot.x")?, number(r.robot.y, "robot.y")?),
        yaw_steps as i32,
        lattice,
    );
    // A leg pose off the action lattice could never be reached again by any action, and the
    // state stores whole steps: refuse rather than round.
    let lattice_steps = |value: Option<f64>, field: &str, default_m: f32, step_m: f32| {
        let Some(value) = value else {
            return Ok(0);
        };
        let value_m = number(value, field)?;
        let steps = ((value_m - default_m) / step_m).round();
        if (default_m + steps * step_m - value_m).abs() > 1.0e-4 || steps.abs() > 100.0 {
            return Err(fail(
                field.to_string(),
                &format!(
                    "must be {default_m} m plus a whole number of {step_m} m steps (the \
                     robot's leg lattice)"
                ),
            ));
        }
        Ok(steps as i32)
    };
    start.clearance_steps = lattice_steps(
        r.robot.clearance_m,
        "robot.clearance_m",
        geometry.default_clearance_m,
        lattice.clearance_step_m,
    )?;
    start.track_steps = lattice_steps(
        r.robot.track_m,
        "robot.track_m",
        geometry.default_track_m,
        lattice.track_step_m,
    )?;
    let target = Point2::new(
        number(r.target.x, "target.x")?,
        number(r.target.y, "target.y")?,
    );
    let mut obstacles = Vec::with_capacity(r.obstacles.len());
    for (i, o) in r.obstacles.into_iter().enumerate() {
        let kind = ObstacleKind::ALL
            .into_iter()
            .find(|k| k.name() == o.kind)
            .ok_or_else(|| {
                fail(
                    format!("obstacles[{i}].kind"),
                    &format!("unknown kind {:?} (expected bar, slab or block)", o.kind),
                )
            })?;
        let yaw_field = format!("obstacles[{i}].yaw_deg");
        let yaw = number(o.yaw_deg, &yaw_field)?;
        let yaw = match (yaw.rem_euclid(180.0) * 1000.0).round() as i32 {
            0 | 180_000 => ObstacleYaw::Deg0,
            90_000 => ObstacleYaw::Deg90,
            _ => return Err(fail(yaw_field, "must be 0 or 90 degrees")),
        };
        obstacles.push(Obstacle::new(
            kind,
            number(o.x, &format!("obstacles[{i}].x"))?,
            number(o.y, &format!("obstacles[{i}].y"))?,
            yaw,
        ));
    }
    Ok(Scenario {
        name: if r.name.is_empty() {
            format!("#{index}")
        } else {
            r.name
        },
        start,
        target,
        obstacles,
    })
}

fn to_record(s: &Scenario, geometry: &RobotGeometry) -> ScenarioRecord {
    // Values are printed at 0.1 mm: scenario coordinates live on mm-scale lattices, and this
    // keeps files readable (no 0.30000001) while reading back to the same f32.
    let round = |v: f32| (v as f64 * 1.0e4).round() / 1.0e4;
    let legs = s.start.leg_config(geometry);
    ScenarioRecord {
        name: s.name.clone(),
        robot: RobotRecord {
            x: round(s.start.position.x),
            y: round(s.start.position.y),
            yaw_deg: s.start.yaw_deg() as f64,
            clearance_m: (s.start.clearance_steps != 0).then(|| round(legs.clearance_m)),
            track_m: (s.start.track_steps != 0).then(|| round(legs.track_m)),
        },
        target: PointRecord {
            x: round(s.target.x),
            y: round(s.target.y),
        },
        obstacles: s
            .obstacles
            .iter()
            .map(|o| ObstacleRecord {
                kind: o.kind.name().to_string(),
                x: round(o.centre.x),
                y: round(o.centre.y),
                yaw_deg: o.yaw.degrees() as f64,
            })
            .collect(),
    }
}
