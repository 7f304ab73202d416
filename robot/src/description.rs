//! `robots/NAME.toml`: a robot description as a file, read with every key checked.
//!
//! The file's keys carry their units (`_m`, `_rad`, `_deg`, `_bps`). Unknown keys, missing keys
//! and values the robot cannot have are refused with the key named; a description that loads
//! is one the runtime can drive ([`validate`](crate::validate) says what is checked).

use crate::validate::{validate, DescriptionError};
use serde::{Deserialize, Serialize};
use std::path::Path;
use wheelleg_runtime::can::node_map::{Axis, Joint, AXIS_COUNT};
use wheelleg_runtime::model::format::RobotRecord;
use wheelleg_runtime::model::load::{trained_for, TrainedFor};
use wheelleg_runtime::robot::{LegId, Robot, RobotGeometry};

/// The shipped robot's description, `robots/wheelleg.toml`, as compiled into the tools.
pub const SHIPPED_TOML: &str = include_str!("../../robots/wheelleg.toml");

/// A checked robot description: what the runtime drives, with its name and bus.
#[derive(Clone, Debug, PartialEq)]
pub struct RobotDescription {
    /// The robot's name (`name`): weights, checkpoints and batches are tied to it.
    pub name: String,
    /// Geometry, action lattice and CAN wiring.
    pub robot: Robot,
    /// The CAN bus's bit rate (`can.bit_rate_bps`).
    pub bit_rate_bps: u32,
}

impl Default for RobotDescription {
    /// The shipped robot.
    fn default() -> RobotDescription {
        RobotDescription::shipped()
    }
}

impl RobotDescription {
    /// The shipped robot: the runtime's [`TrainedFor::SHIPPED`], which `robots/wheelleg.toml`
    /// describes bit for bit (`tests/description.rs`).
    pub fn shipped() -> RobotDescription {
        let shipped = TrainedFor::SHIPPED;
        RobotDescription {
            name: shipped.name.into(),
            robot: shipped.robot,
            bit_rate_bps: shipped.bit_rate_bps,
        }
    }

    /// Reads and checks a description from TOML text.
    pub fn from_toml(text: &str) -> Result<RobotDescription, DescriptionError> {
        let value: toml::Table = text
            .parse()
            .map_err(|e: toml::de::Error| DescriptionError::syntax(e.to_string()))?;
        let file: DescriptionFile = serde_path_to_error::deserialize(toml::Value::Table(value))
            .map_err(|e| {
                let key = e.path().to_string();
                DescriptionError::new(key, e.into_inner().message().to_string())
            })?;
        validate(&file)?;
        file.into_description()
    }

    /// Reads and checks `path`; errors name the file.
    pub fn load(path: &Path) -> Result<RobotDescription, String> {
        let text = std::fs::read_to_string(path)
            .map_err(|e| format!("cannot read robot description {}: {e}", path.display()))?;
        RobotDescription::from_toml(&text)
            .map_err(|e| format!("robot description {}: {e}", path.display()))
    }

    /// The robot as a weights file records it ([`TrainedFor`]), for [`RobotDescription::accepts`].
    pub fn trained_for(&self) -> TrainedFor<'_> {
        TrainedFor {
            name: &self.name,
            robot: self.robot,
            bit_rate_bps: self.bit_rate_bps,
        }
    }

    /// Whether a policy trained for `trained` (a weights file's robot) may drive this robot:
    /// the same name, geometry, action lattice, CAN wiring and bit rate. The error names both
    /// robots and what differs; `what` names the file for the message.
    pub fn accepts(&self, trained: &TrainedFor<'_>, what: &str) -> Result<(), String> {
        match self.difference(trained) {
            Some("name") => Err(format!(
                "{what} was trained for robot '{}', and this run drives robot '{}': a policy \
                 drives only the robot it was trained for",
                trained.name, self.name
            )),
            Some(part) => Err(format!(
                "{what} was trained for a robot '{}' whose {part} differs from this run's robot \
                 '{}': a policy drives only the robot it was trained for",
                trained.name, self.name
            )),
            None => Ok(()),
        }
    }

    /// What tells `other` from this robot, the first of `name`, `geometry`, `action lattice`
    /// and `CAN wiring` that differs; `None` when they are the same robot.
    pub fn difference(&self, other: &TrainedFor<'_>) -> Option<&'static str> {
        if other.name != self.name {
            Some("name")
        } else if other.robot.geometry != self.robot.geometry {
            Some("geometry")
        } else if other.robot.actions != self.robot.actions {
            Some("action lattice")
        } else if other.robot.can != self.robot.can || other.bit_rate_bps != self.bit_rate_bps {
            Some("CAN wiring")
        } else {
            None
        }
    }

    /// The description as a file's TOML text, which [`RobotDescription::from_toml`] reads back
    /// to this description.
    pub fn to_toml(&self) -> String {
        let file = DescriptionFile::from_description(self);
        // Every field is a number, a string, an array or a table: serialization cannot fail.
        toml::to_string(&file).unwrap_or_default()
    }
}

/// The file's layout: one struct per table, no key unknown, none missing.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct DescriptionFile {
    /// The robot's name.
    pub name: String,
    /// The body box.
    pub body: BodyKeys,
    /// The front-left leg; the others mirror it.
    pub legs: LegKeys,
    /// The wheels.
    pub wheels: WheelKeys,
    /// The commanded pose's ranges and default.
    pub pose: PoseKeys,
    /// The action lattice.
    pub actions: ActionKeys,
    /// The CAN bus and its axes.
    pub can: CanKeys,
}

/// `[body]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct BodyKeys {
    /// Along body x.
    pub length_m: f64,
    /// Along body y.
    pub width_m: f64,
    /// Along body z.
    pub thickness_m: f64,
}

/// `[legs]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LegKeys {
    /// Body x of the front hips.
    pub hip_x_m: f64,
    /// Body y of the left hips.
    pub hip_y_m: f64,
    /// Hip joint to knee joint.
    pub thigh_m: f64,
    /// Knee joint to wheel axle.
    pub shank_m: f64,
    /// Radius of the links' collision capsules.
    pub link_radius_m: f64,
    /// Thigh angle below the outward horizontal, `[min, max]`.
    pub hip_range_rad: [f64; 2],
    /// Shank angle relative to the thigh, `[min, max]`.
    pub knee_range_rad: [f64; 2],
}

/// `[wheels]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct WheelKeys {
    /// Wheel radius.
    pub radius_m: f64,
    /// Wheel width along its axle.
    pub width_m: f64,
    /// Where the wheel's centre sits along its axle from the wheel mount's joint, outward
    /// (negative: inward); 0 when not given, and then not written.
    #[serde(default, skip_serializing_if = "is_zero")]
    pub offset_m: f64,
}

fn is_zero(value: &f64) -> bool {
    *value == 0.0
}

/// `[pose]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct PoseKeys {
    /// Ground to body underside, `[min, max]`.
    pub clearance_range_m: [f64; 2],
    /// Wheel centre to wheel centre, `[min, max]`.
    pub track_range_m: [f64; 2],
    /// Clearance of the default pose.
    pub default_clearance_m: f64,
    /// Track of the default pose.
    pub default_track_m: f64,
}

/// `[actions]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ActionKeys {
    /// Translation per step.
    pub move_step_m: f64,
    /// Rotation per step.
    pub yaw_step_deg: f64,
    /// Clearance change per step.
    pub clearance_step_m: f64,
    /// Track change per step.
    pub track_step_m: f64,
}

/// `[can]`.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct CanKeys {
    /// The bus's bit rate.
    pub bit_rate_bps: u32,
    /// The 16 axes by name.
    pub axes: AxisTable,
}

/// How an ODrive axis is driven.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum ControlMode {
    /// Position setpoints with velocity feed-forward (`Set_Input_Pos`).
    Position,
    /// Velocity setpoints (`Set_Input_Vel`).
    Velocity,
}

/// One axis of `[can.axes]`.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct AxisKeys {
    /// The ODrive's node id.
    pub node_id: u8,
    /// +1 or -1.
    pub direction: i8,
    /// Motor turns per output turn.
    pub gear_ratio: f64,
    /// How the axis is driven.
    pub control_mode: ControlMode,
}

macro_rules! axis_table {
    ($($field:ident => $axis:expr),* $(,)?) => {
        /// `[can.axes]`: every axis by name, in [`Axis::ALL`] order.
        #[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
        #[serde(deny_unknown_fields)]
        pub struct AxisTable {
            $(
                #[doc = concat!("`", stringify!($field), "`.")]
                pub $field: AxisKeys,
            )*
        }

        impl AxisTable {
            /// Each axis with its key name and entry, in [`Axis::ALL`] order.
            pub fn entries(&self) -> [(Axis, &'static str, AxisKeys); AXIS_COUNT] {
                [$(($axis, stringify!($field), self.$field)),*]
            }

            /// The table with `entry(axis)` for each axis.
            pub fn from_fn(entry: impl Fn(Axis) -> AxisKeys) -> AxisTable {
                AxisTable { $($field: entry($axis)),* }
            }
        }
    };
}

axis_table! {
    front_left_hip => Axis::Joint(LegId::FrontLeft, Joint::Hip),
    front_left_knee => Axis::Joint(LegId::FrontLeft, Joint::Knee),
    front_left_wheel_mount => Axis::Joint(LegId::FrontLeft, Joint::WheelMount),
    front_right_hip => Axis::Joint(LegId::FrontRight, Joint::Hip),
    front_right_knee => Axis::Joint(LegId::FrontRight, Joint::Knee),
    front_right_wheel_mount => Axis::Joint(LegId::FrontRight, Joint::WheelMount),
    rear_left_hip => Axis::Joint(LegId::RearLeft, Joint::Hip),
    rear_left_knee => Axis::Joint(LegId::RearLeft, Joint::Knee),
    rear_left_wheel_mount => Axis::Joint(LegId::RearLeft, Joint::WheelMount),
    rear_right_hip => Axis::Joint(LegId::RearRight, Joint::Hip),
    rear_right_knee => Axis::Joint(LegId::RearRight, Joint::Knee),
    rear_right_wheel_mount => Axis::Joint(LegId::RearRight, Joint::WheelMount),
    front_left_wheel => Axis::Wheel(LegId::FrontLeft),
    front_right_wheel => Axis::Wheel(LegId::FrontRight),
    rear_left_wheel => Axis::Wheel(LegId::RearLeft),
    rear_right_wheel => Axis::Wheel(LegId::RearRight),
}

/// The shortest decimal that reads back to `value`: a file written from `f32`s says `0.05`,
/// not `0.05000000074505806`.
fn decimal(value: f32) -> f64 {
    value.to_string().parse().unwrap_or(f64::from(value))
}

fn pair(range: [f32; 2]) -> [f64; 2] {
    [decimal(range[0]), decimal(range[1])]
}

fn narrow(range: [f64; 2]) -> [f32; 2] {
    [range[0] as f32, range[1] as f32]
}

impl DescriptionFile {
    /// The runtime's view of a checked file.
    fn into_description(self) -> Result<RobotDescription, DescriptionError> {
        let entries = self.can.axes.entries();
        // The runtime's own reading of a weights file's robot record: a description and the
        // weights trained on it become the same `Robot`.
        let record = RobotRecord {
            name: &self.name,
            geometry: self.geometry().to_array(),
            actions: [
                self.actions.move_step_m as f32,
                self.actions.yaw_step_deg as f32,
                self.actions.clearance_step_m as f32,
                self.actions.track_step_m as f32,
            ],
            node_ids: entries.map(|(_, _, e)| e.node_id),
            directions: entries.map(|(_, _, e)| e.direction),
            gear_ratios: entries.map(|(_, _, e)| e.gear_ratio as f32),
            bit_rate_bps: self.can.bit_rate_bps,
        };
        let robot = trained_for(record, self.wheels.offset_m as f32)
            .map_err(|e| DescriptionError::new(String::new(), format!("{e}")))?
            .robot;
        Ok(RobotDescription {
            name: self.name.clone(),
            robot,
            bit_rate_bps: self.can.bit_rate_bps,
        })
    }

    /// The geometry the file describes, unchecked.
    pub(crate) fn geometry(&self) -> RobotGeometry {
        RobotGeometry {
            body_length_m: self.body.length_m as f32,
            body_width_m: self.body.width_m as f32,
            body_thickness_m: self.body.thickness_m as f32,
            hip_x_m: self.legs.hip_x_m as f32,
            hip_y_m: self.legs.hip_y_m as f32,
            thigh_m: self.legs.thigh_m as f32,
            shank_m: self.legs.shank_m as f32,
            link_radius_m: self.legs.link_radius_m as f32,
            wheel_radius_m: self.wheels.radius_m as f32,
            wheel_width_m: self.wheels.width_m as f32,
            wheel_offset_m: self.wheels.offset_m as f32,
            hip_range_rad: narrow(self.legs.hip_range_rad),
            knee_range_rad: narrow(self.legs.knee_range_rad),
            track_range_m: narrow(self.pose.track_range_m),
            clearance_range_m: narrow(self.pose.clearance_range_m),
            default_track_m: self.pose.default_track_m as f32,
            default_clearance_m: self.pose.default_clearance_m as f32,
        }
    }

    /// The file that reads back to `description`.
    pub fn from_description(description: &RobotDescription) -> DescriptionFile {
        let g = &description.robot.geometry;
        let a = &description.robot.actions;
        let map = &description.robot.can;
        DescriptionFile {
            name: description.name.clone(),
            body: BodyKeys {
                length_m: decimal(g.body_length_m),
                width_m: decimal(g.body_width_m),
                thickness_m: decimal(g.body_thickness_m),
            },
            legs: LegKeys {
                hip_x_m: decimal(g.hip_x_m),
                hip_y_m: decimal(g.hip_y_m),
                thigh_m: decimal(g.thigh_m),
                shank_m: decimal(g.shank_m),
                link_radius_m: decimal(g.link_radius_m),
                hip_range_rad: pair(g.hip_range_rad),
                knee_range_rad: pair(g.knee_range_rad),
            },
            wheels: WheelKeys {
                radius_m: decimal(g.wheel_radius_m),
                width_m: decimal(g.wheel_width_m),
                offset_m: decimal(g.wheel_offset_m),
            },
            pose: PoseKeys {
                clearance_range_m: pair(g.clearance_range_m),
                track_range_m: pair(g.track_range_m),
                default_clearance_m: decimal(g.default_clearance_m),
                default_track_m: decimal(g.default_track_m),
            },
            actions: ActionKeys {
                move_step_m: decimal(a.move_step_m),
                yaw_step_deg: decimal(a.yaw_step_deg),
                clearance_step_m: decimal(a.clearance_step_m),
                track_step_m: decimal(a.track_step_m),
            },
            can: CanKeys {
                bit_rate_bps: description.bit_rate_bps,
                axes: AxisTable::from_fn(|axis| {
                    let cal = map.get(axis);
                    AxisKeys {
                        node_id: map.node_id(axis).get(),
                        direction: if cal.direction < 0.0 { -1 } else { 1 },
                        gear_ratio: decimal(cal.gear_ratio),
                        control_mode: match axis {
                            Axis::Joint(..) => ControlMode::Position,
                            Axis::Wheel(_) => ControlMode::Velocity,
                        },
                    }
                }),
            },
        }
    }
}
