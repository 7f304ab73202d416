//! Which motor is which CAN node, and how joint angles become ODrive turns.
//!
//! Sixteen axes, one ODrive node each. A robot's description sets each axis's node id (1 to 63,
//! no two alike) and calibration; the shipped robot's map is [`NodeMap::NOMINAL`]
//! (`robots/wheelleg.toml`; docs/can-protocol.md has the same table):
//!
//! | node | axis                  | node | axis                  |
//! |------|-----------------------|------|-----------------------|
//! | 1    | front-left hip        | 7    | rear-left hip         |
//! | 2    | front-left knee       | 8    | rear-left knee        |
//! | 3    | front-left wheel mount| 9    | rear-left wheel mount |
//! | 4    | front-right hip       | 10   | rear-right hip        |
//! | 5    | front-right knee      | 11   | rear-right knee       |
//! | 6    | front-right wheel mount | 12 | rear-right wheel mount|
//! | 13   | front-left wheel      | 15   | rear-left wheel       |
//! | 14   | front-right wheel     | 16   | rear-right wheel      |
//!
//! Leg joints come first, in [`LegId::ALL`] order and hip, knee, wheel mount within a leg; then
//! the four wheels in the same leg order. Node 0 is left free because a factory-fresh ODrive
//! answers there, so an unconfigured board can never be mistaken for a joint. A lower id wins
//! arbitration, so joint traffic has priority over wheel traffic.
//!
//! Units on the bus are ODrive's: motor-side turns and turns/s. The conversion is
//! `motor_turns = zero_offset_turns + direction * gear_ratio * angle_rad / 2π`:
//!
//! - `gear_ratio`: motor turns per output turn (9 for the joint actuators' planetary gearbox,
//!   1 for the direct-drive hub wheel motors);
//! - `direction`: +1 or -1. Joint angles are in the left-leg convention of
//!   [`crate::leg::JointAngles`]; right legs are mirror-image assemblies, so their motors are
//!   mounted mirrored too and the same number means the same mirrored pose: +1 for every joint.
//!   Wheel speeds are positive when rolling forward ([`crate::base::WheelSpeeds`]); the right
//!   hub motors face the other way, so they are -1;
//! - `zero_offset_turns`: the motor position when the joint is at 0 rad (hip: thigh horizontal;
//!   knee: leg straight; wheel mount: aligned with the shank), found by homing at start-up.
//!   Wheels have no meaningful zero; their offset is 0.

use crate::can::protocol::NodeId;
use crate::robot::LegId;
use core::f32::consts::TAU;

/// Number of axes on the bus.
pub const AXIS_COUNT: usize = 16;
/// Number of leg joint axes.
pub const JOINT_AXIS_COUNT: usize = 12;
/// Node id of the first axis of the nominal map; the rest follow in [`Axis::ALL`] order.
pub const FIRST_NODE_ID: u8 = 1;

/// One of a leg's three joints.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Joint {
    /// Hip.
    Hip,
    /// Knee.
    Knee,
    /// Wheel mount.
    WheelMount,
}

impl Joint {
    /// The three joints in node order.
    pub const ALL: [Joint; 3] = [Joint::Hip, Joint::Knee, Joint::WheelMount];

    const fn index(self) -> usize {
        match self {
            Joint::Hip => 0,
            Joint::Knee => 1,
            Joint::WheelMount => 2,
        }
    }
}

/// One motor axis of the robot.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum Axis {
    /// A leg joint, position controlled.
    Joint(LegId, Joint),
    /// A wheel, velocity controlled.
    Wheel(LegId),
}

/// Whether an axis is position or velocity controlled.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
pub enum AxisKind {
    /// Leg joint: position control.
    Joint,
    /// Wheel: velocity control.
    Wheel,
}

impl Axis {
    /// All axes in node order.
    // Evaluated at compile time: an out-of-bounds index would be a build error, not a panic.
    #[allow(clippy::indexing_slicing)]
    pub const ALL: [Axis; AXIS_COUNT] = {
        let mut all = [Axis::Wheel(LegId::FrontLeft); AXIS_COUNT];
        let mut leg = 0;
        while leg < 4 {
            let id = LegId::ALL[leg];
            all[3 * leg] = Axis::Joint(id, Joint::Hip);
            all[3 * leg + 1] = Axis::Joint(id, Joint::Knee);
            all[3 * leg + 2] = Axis::Joint(id, Joint::WheelMount);
            all[JOINT_AXIS_COUNT + leg] = Axis::Wheel(id);
            leg += 1;
        }
        all
    };

    /// Position in [`Axis::ALL`].
    pub const fn index(self) -> usize {
        match self {
            Axis::Joint(leg, joint) => 3 * leg.index() + joint.index(),
            Axis::Wheel(leg) => JOINT_AXIS_COUNT + leg.index(),
        }
    }

    /// The axis at a position in [`Axis::ALL`].
    pub fn from_index(index: usize) -> Option<Axis> {
        Axis::ALL.get(index).copied()
    }

    /// Position or velocity controlled.
    pub const fn kind(self) -> AxisKind {
        match self {
            Axis::Joint(..) => AxisKind::Joint,
            Axis::Wheel(_) => AxisKind::Wheel,
        }
    }

    /// The axis in words, as the node map's table names it: "front-left hip", "rear-right
    /// wheel".
    pub const fn name(self) -> &'static str {
        use Joint::{Hip, Knee, WheelMount};
        use LegId::{FrontLeft as FL, FrontRight as FR, RearLeft as RL, RearRight as RR};
        match self {
            Axis::Joint(FL, Hip) => "front-left hip",
            Axis::Joint(FL, Knee) => "front-left knee",
            Axis::Joint(FL, WheelMount) => "front-left wheel mount",
            Axis::Joint(FR, Hip) => "front-right hip",
            Axis::Joint(FR, Knee) => "front-right knee",
            Axis::Joint(FR, WheelMount) => "front-right wheel mount",
            Axis::Joint(RL, Hip) => "rear-left hip",
            Axis::Joint(RL, Knee) => "rear-left knee",
            Axis::Joint(RL, WheelMount) => "rear-left wheel mount",
            Axis::Joint(RR, Hip) => "rear-right hip",
            Axis::Joint(RR, Knee) => "rear-right knee",
            Axis::Joint(RR, WheelMount) => "rear-right wheel mount",
            Axis::Wheel(FL) => "front-left wheel",
            Axis::Wheel(FR) => "front-right wheel",
            Axis::Wheel(RL) => "rear-left wheel",
            Axis::Wheel(RR) => "rear-right wheel",
        }
    }
}

impl core::fmt::Display for Axis {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        f.write_str(self.name())
    }
}

/// Motor-to-joint conversion of one axis (see the module docs for the convention).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisCalibration {
    /// Motor turns per output turn.
    pub gear_ratio: f32,
    /// +1 or -1: sign of motor rotation for a positive joint angle or forward wheel speed.
    pub direction: f32,
    /// Motor position at joint angle 0.
    pub zero_offset_turns: f32,
}

impl AxisCalibration {
    /// Motor position for an output angle.
    pub fn to_motor_turns(&self, angle_rad: f32) -> f32 {
        self.zero_offset_turns + self.direction * self.gear_ratio * angle_rad / TAU
    }

    /// Motor speed for an output speed.
    pub fn to_motor_turns_per_s(&self, speed_radps: f32) -> f32 {
        self.direction * self.gear_ratio * speed_radps / TAU
    }

    /// Output angle for a motor position.
    pub fn to_angle_rad(&self, motor_turns: f32) -> f32 {
        (motor_turns - self.zero_offset_turns) * TAU / (self.direction * self.gear_ratio)
    }

    /// Output speed for a motor speed.
    pub fn to_speed_radps(&self, motor_turns_per_s: f32) -> f32 {
        motor_turns_per_s * TAU / (self.direction * self.gear_ratio)
    }
}

/// Gear ratio of the leg joint actuators.
pub const JOINT_GEAR_RATIO: f32 = 9.0;
/// Gear ratio of the wheel hub motors.
pub const WHEEL_GEAR_RATIO: f32 = 1.0;

/// Why a node map was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum NodeMapError {
    /// Two axes on one node id: the second axis, in [`Axis::ALL`] order, and the id.
    SharedNodeId(Axis, NodeId),
    /// An axis on node 0, where a factory-fresh ODrive answers.
    FactoryNodeId(Axis),
    /// A gear ratio that is not finite and positive.
    BadGearRatio(Axis),
    /// A direction other than +1 or -1.
    BadDirection(Axis),
    /// A zero offset that is not finite.
    BadZeroOffset(Axis),
}

/// Node id and calibration of every axis, indexed like [`Axis::ALL`]: the robot's CAN wiring.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct NodeMap {
    /// One node id per axis, no two alike.
    node_ids: [NodeId; AXIS_COUNT],
    /// One entry per axis.
    pub calibration: [AxisCalibration; AXIS_COUNT],
}

impl NodeMap {
    /// The nominal robot: ratios and directions as documented, zero offsets 0.
    // Evaluated at compile time: an out-of-bounds index would be a build error, not a panic.
    #[allow(clippy::indexing_slicing)]
    pub const NOMINAL: NodeMap = {
        let joint = AxisCalibration {
            gear_ratio: JOINT_GEAR_RATIO,
            direction: 1.0,
            zero_offset_turns: 0.0,
        };
        let mut calibration = [joint; AXIS_COUNT];
        let mut leg = 0;
        while leg < 4 {
            calibration[JOINT_AXIS_COUNT + leg] = AxisCalibration {
                gear_ratio: WHEEL_GEAR_RATIO,
                direction: LegId::ALL[leg].side_sign(),
                zero_offset_turns: 0.0,
            };
            leg += 1;
        }
        let mut node_ids = [NodeId::MIN; AXIS_COUNT];
        let mut index = 0;
        while index < AXIS_COUNT {
            // FIRST_NODE_ID + 15 = 16 is below MAX_NODE_ID.
            node_ids[index] = match NodeId::new(FIRST_NODE_ID + index as u8) {
                Some(id) => id,
                None => NodeId::MIN,
            };
            index += 1;
        }
        NodeMap {
            node_ids,
            calibration,
        }
    };

    /// A map from each axis's node id and calibration (indexed like [`Axis::ALL`]), refused
    /// when two axes share an id, an axis sits on the factory id 0, or a calibration cannot
    /// convert (zero or non-finite ratio, direction not ±1).
    pub fn new(
        node_ids: [NodeId; AXIS_COUNT],
        calibration: [AxisCalibration; AXIS_COUNT],
    ) -> Result<NodeMap, NodeMapError> {
        for (index, (&id, cal)) in node_ids.iter().zip(calibration.iter()).enumerate() {
            let axis = Axis::from_index(index).unwrap_or(Axis::Wheel(LegId::FrontLeft));
            if id == NodeId::MIN {
                return Err(NodeMapError::FactoryNodeId(axis));
            }
            if node_ids.iter().take(index).any(|&earlier| earlier == id) {
                return Err(NodeMapError::SharedNodeId(axis, id));
            }
            if !(cal.gear_ratio.is_finite() && cal.gear_ratio > 0.0) {
                return Err(NodeMapError::BadGearRatio(axis));
            }
            if cal.direction != 1.0 && cal.direction != -1.0 {
                return Err(NodeMapError::BadDirection(axis));
            }
            if !cal.zero_offset_turns.is_finite() {
                return Err(NodeMapError::BadZeroOffset(axis));
            }
        }
        Ok(NodeMap {
            node_ids,
            calibration,
        })
    }

    /// The CAN node id of `axis`.
    pub fn node_id(&self, axis: Axis) -> NodeId {
        // index() < AXIS_COUNT by construction; the fallback is never taken.
        self.node_ids
            .get(axis.index())
            .copied()
            .unwrap_or(NodeId::MIN)
    }

    /// The axis on node `node`, if any.
    pub fn axis_on(&self, node: NodeId) -> Option<Axis> {
        let index = self.node_ids.iter().position(|&id| id == node)?;
        Axis::from_index(index)
    }

    /// Calibration of one axis.
    pub fn get(&self, axis: Axis) -> AxisCalibration {
        // index() < AXIS_COUNT by construction; the fallback is never taken.
        self.calibration
            .get(axis.index())
            .copied()
            .unwrap_or(AxisCalibration {
                gear_ratio: 1.0,
                direction: 1.0,
                zero_offset_turns: 0.0,
            })
    }
}

impl Default for NodeMap {
    fn default() -> Self {
        NodeMap::NOMINAL
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn node_ids_follow_the_documented_table() {
        let map = NodeMap::NOMINAL;
        let id = |axis| map.node_id(axis).get();
        assert_eq!(id(Axis::Joint(LegId::FrontLeft, Joint::Hip)), 1);
        assert_eq!(id(Axis::Joint(LegId::FrontRight, Joint::WheelMount)), 6);
        assert_eq!(id(Axis::Joint(LegId::RearRight, Joint::Knee)), 11);
        assert_eq!(id(Axis::Wheel(LegId::FrontLeft)), 13);
        assert_eq!(id(Axis::Wheel(LegId::RearRight)), 16);
        for (i, axis) in Axis::ALL.into_iter().enumerate() {
            assert_eq!(axis.index(), i);
            assert_eq!(map.axis_on(map.node_id(axis)), Some(axis));
        }
        assert_eq!(map.axis_on(NodeId::new(0).unwrap()), None);
        assert_eq!(map.axis_on(NodeId::new(17).unwrap()), None);
    }

    #[test]
    fn a_map_of_any_ids_is_kept_and_a_bad_one_refused() {
        let calibration = NodeMap::NOMINAL.calibration;
        let ids: [NodeId; AXIS_COUNT] =
            core::array::from_fn(|i| NodeId::new(40 - i as u8).unwrap());
        let map = NodeMap::new(ids, calibration).unwrap();
        let knee = Axis::Joint(LegId::FrontLeft, Joint::Knee);
        assert_eq!(map.node_id(knee).get(), 39);
        assert_eq!(map.axis_on(NodeId::new(39).unwrap()), Some(knee));
        assert_eq!(map.axis_on(NodeId::new(1).unwrap()), None);

        let mut shared = ids;
        shared[5] = shared[2];
        assert_eq!(
            NodeMap::new(shared, calibration),
            Err(NodeMapError::SharedNodeId(
                Axis::Joint(LegId::FrontRight, Joint::WheelMount),
                shared[2]
            ))
        );
        let mut factory = ids;
        factory[0] = NodeId::MIN;
        assert!(matches!(
            NodeMap::new(factory, calibration),
            Err(NodeMapError::FactoryNodeId(_))
        ));
        let mut ratio = calibration;
        ratio[3].gear_ratio = 0.0;
        assert!(matches!(
            NodeMap::new(ids, ratio),
            Err(NodeMapError::BadGearRatio(_))
        ));
        let mut direction = calibration;
        direction[12].direction = 0.5;
        assert!(matches!(
            NodeMap::new(ids, direction),
            Err(NodeMapError::BadDirection(_))
        ));
    }

    #[test]
    fn conversions_round_trip_and_use_gear_and_direction() {
        let map = NodeMap::NOMINAL;
        let hip = map.get(Axis::Joint(LegId::RearLeft, Joint::Hip));
        // Quarter output turn through a 9:1 gearbox is 2.25 motor turns.
        assert!((hip.to_motor_turns(core::f32::consts::FRAC_PI_2) - 2.25).abs() < 1e-6);
        let right_wheel = map.get(Axis::Wheel(LegId::FrontRight));
        assert!(right_wheel.to_motor_turns_per_s(TAU) + 1.0 < 1e-6);
        let offset = AxisCalibration {
            zero_offset_turns: 3.5,
            ..hip
        };
        let back = offset.to_angle_rad(offset.to_motor_turns(0.7));
        assert!((back - 0.7).abs() < 1e-5);
    }
}
