//! The robot record of a version 3 or 4 file, checked into the robot the runtime drives.

use super::LoadError;
use crate::action::ActionLattice;
use crate::can::node_map::{AxisCalibration, NodeMapError, AXIS_COUNT};
use crate::can::{NodeId, NodeMap};
use crate::model::format::{RobotRecord, MAX_ROBOT_NAME_BYTES};
use crate::robot::{GeometryError, Robot, RobotGeometry};

/// The robot a file was trained for, as the loader found it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrainedFor<'a> {
    /// The robot's name (`"wheelleg"` for files before the robot record).
    pub name: &'a str,
    /// Geometry, action lattice and CAN wiring.
    pub robot: Robot,
    /// The CAN bus's bit rate.
    pub bit_rate_bps: u32,
}

impl TrainedFor<'_> {
    /// What files before [`crate::model::format::ROBOT_RECORD_VERSION`] were trained for.
    pub const SHIPPED: TrainedFor<'static> = TrainedFor {
        name: "wheelleg",
        robot: Robot::WHEELLEG,
        bit_rate_bps: 1_000_000,
    };
}

fn invalid(what: &'static str) -> LoadError {
    LoadError::InvalidRobot { what }
}

/// Checks a robot record with its wheel offset (0 for a version 3 file): a name a description
/// could have, a geometry the runtime can drive, a positive action lattice, a node map of
/// distinct ids with ±1 directions and positive ratios.
pub fn trained_for(
    record: RobotRecord<'_>,
    wheel_offset_m: f32,
) -> Result<TrainedFor<'_>, LoadError> {
    let name_ok = !record.name.is_empty()
        && record.name.len() <= MAX_ROBOT_NAME_BYTES
        && record
            .name
            .bytes()
            .all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_');
    if !name_ok {
        return Err(invalid("name"));
    }
    let geometry = RobotGeometry::from_array(record.geometry, wheel_offset_m);
    geometry.check().map_err(|e| match e {
        GeometryError::BadLength => invalid("geometry: a length"),
        GeometryError::BadRange => invalid("geometry: a range"),
        GeometryError::DefaultUnreachable => invalid("geometry: the default pose"),
        GeometryError::BadWheelOffset => invalid("geometry: the wheel offset"),
    })?;
    let [move_step_m, yaw_step_deg, clearance_step_m, track_step_m] = record.actions;
    if !record.actions.iter().all(|v| v.is_finite() && *v > 0.0) {
        return Err(invalid("action lattice"));
    }
    let mut node_ids = [NodeId::MIN; AXIS_COUNT];
    let mut calibration = [AxisCalibration {
        gear_ratio: 1.0,
        direction: 1.0,
        zero_offset_turns: 0.0,
    }; AXIS_COUNT];
    for (i, (id, cal)) in node_ids.iter_mut().zip(calibration.iter_mut()).enumerate() {
        let raw = record.node_ids.get(i).copied().unwrap_or(0);
        *id = NodeId::new(raw).ok_or(invalid("node id above 63"))?;
        *cal = AxisCalibration {
            gear_ratio: record.gear_ratios.get(i).copied().unwrap_or(f32::NAN),
            direction: f32::from(record.directions.get(i).copied().unwrap_or(0)),
            zero_offset_turns: 0.0,
        };
    }
    let can = NodeMap::new(node_ids, calibration).map_err(|e| match e {
        NodeMapError::SharedNodeId(..) => invalid("node ids: two axes share one"),
        NodeMapError::FactoryNodeId(_) => invalid("node ids: an axis on node 0"),
        NodeMapError::BadGearRatio(_) => invalid("gear ratio"),
        NodeMapError::BadDirection(_) => invalid("motor direction"),
        NodeMapError::BadZeroOffset(_) => invalid("zero offset"),
    })?;
    if record.bit_rate_bps == 0 {
        return Err(invalid("bit rate"));
    }
    Ok(TrainedFor {
        name: record.name,
        robot: Robot {
            geometry,
            actions: ActionLattice {
                move_step_m,
                yaw_step_deg,
                clearance_step_m,
                track_step_m,
            },
            can,
        },
        bit_rate_bps: record.bit_rate_bps,
    })
}
