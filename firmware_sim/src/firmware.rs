//! All the simulated axes of the robot behind one bus connection.

use crate::axis::{AxisConfig, SimAxis};
use crate::bus::{BusError, Transport};
use wheelleg_runtime::base::WheelSpeeds;
use wheelleg_runtime::can::node_map::{Axis, AxisKind, Joint, NodeMap};
use wheelleg_runtime::can::protocol::{decode, NodeId, Version};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::{IkError, JointAngles, LegConfig};
use wheelleg_runtime::robot::{LegId, RobotGeometry};

/// Counters of the traffic the firmware received.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct FirmwareStats {
    /// Frames received.
    pub received: u64,
    /// Frames that did not decode as CANSimple; ignored.
    pub malformed: u64,
    /// Frames for nodes no simulated axis has; ignored.
    pub foreign: u64,
}

/// A set of simulated axes sharing a bus, like the robot's 16 ODrive nodes.
#[derive(Clone, Debug, PartialEq)]
pub struct Firmware {
    axes: Vec<SimAxis>,
    /// Which node is which robot axis.
    map: NodeMap,
    stats: FirmwareStats,
    outbox: Vec<CanFrame>,
}

impl Firmware {
    /// Any set of axes; `map` says which of them is which robot axis.
    pub fn new(axes: Vec<SimAxis>, map: NodeMap) -> Firmware {
        Firmware {
            axes,
            map,
            stats: FirmwareStats::default(),
            outbox: Vec::new(),
        }
    }

    /// The robot's 16 axes per `map`, legs at `start` (motor positions from the leg IK),
    /// wheels at 0, all idle.
    pub fn for_robot(
        geometry: &RobotGeometry,
        map: &NodeMap,
        start: LegConfig,
    ) -> Result<Firmware, IkError> {
        let joints = geometry.leg_ik(start)?;
        let axes = Axis::ALL
            .into_iter()
            .map(|axis| {
                let (config, angle_rad) = match axis {
                    Axis::Joint(_, Joint::Hip) => (AxisConfig::JOINT, joints.hip_rad),
                    Axis::Joint(_, Joint::Knee) => (AxisConfig::JOINT, joints.knee_rad),
                    Axis::Joint(_, Joint::WheelMount) => {
                        (AxisConfig::JOINT, joints.wheel_mount_rad)
                    }
                    Axis::Wheel(_) => (AxisConfig::WHEEL, 0.0),
                };
                let pos_turns = match axis.kind() {
                    AxisKind::Joint => map.get(axis).to_motor_turns(angle_rad),
                    AxisKind::Wheel => 0.0,
                };
                SimAxis::new(map.node_id(axis), config, pos_turns)
            })
            .collect();
        Ok(Firmware::new(axes, *map))
    }

    /// Sets every axis's watchdog timeout (0: off, the axes' default). A controller that relies
    /// on the watchdog to idle the motors when it goes silent sets it, as it would configure
    /// real ODrives before use.
    pub fn set_watchdog_timeout_us(&mut self, timeout_us: u64) {
        for axis in &mut self.axes {
            axis.config_mut().watchdog_timeout_us = timeout_us;
        }
    }

    /// Sets what every axis answers to Get_Version (`None`: firmware without it, 0.5.x).
    pub fn set_version(&mut self, version: Option<Version>) {
        for axis in &mut self.axes {
            axis.config_mut().version = version;
        }
    }

    /// Puts one more axis on the bus, for example a second device on a node id already taken
    /// (both then hear that node's commands and both answer).
    pub fn add_axis(&mut self, axis: SimAxis) {
        self.axes.push(axis);
    }

    /// Traffic counters.
    pub fn stats(&self) -> FirmwareStats {
        self.stats
    }

    /// All axes.
    pub fn axes(&self) -> &[SimAxis] {
        &self.axes
    }

    /// The (first) axis on `node`.
    pub fn node(&self, node: NodeId) -> Option<&SimAxis> {
        self.axes.iter().find(|a| a.node() == node)
    }

    /// The (first) axis on `node`, mutable (for fault injection).
    pub fn node_mut(&mut self, node: NodeId) -> Option<&mut SimAxis> {
        self.axes.iter_mut().find(|a| a.node() == node)
    }

    /// The simulated motor of a robot axis.
    pub fn axis(&self, axis: Axis) -> Option<&SimAxis> {
        self.node(self.map.node_id(axis))
    }

    /// The legs as the simulated joints really are: forward kinematics of their true
    /// positions through `map`, averaged over the four legs; `None` if an axis is missing.
    pub fn true_legs(&self, map: &NodeMap, geometry: &RobotGeometry) -> Option<LegConfig> {
        let (mut clearance_m, mut track_m) = (0.0, 0.0);
        for leg in LegId::ALL {
            let angle = |joint| {
                let axis = Axis::Joint(leg, joint);
                Some(map.get(axis).to_angle_rad(self.axis(axis)?.pos_turns()))
            };
            let joints = JointAngles {
                hip_rad: angle(Joint::Hip)?,
                knee_rad: angle(Joint::Knee)?,
                wheel_mount_rad: angle(Joint::WheelMount)?,
            };
            let c = geometry.config_from_joints(joints);
            clearance_m += 0.25 * c.clearance_m;
            track_m += 0.25 * c.track_m;
        }
        Some(LegConfig {
            clearance_m,
            track_m,
        })
    }

    /// The wheels' true speeds through `map`; `None` if an axis is missing.
    pub fn true_wheel_speeds(&self, map: &NodeMap) -> Option<WheelSpeeds> {
        let mut speeds = WheelSpeeds::ZERO;
        for (leg, out) in LegId::ALL.into_iter().zip(speeds.radps.iter_mut()) {
            let axis = Axis::Wheel(leg);
            *out = map
                .get(axis)
                .to_speed_radps(self.axis(axis)?.vel_turns_per_s());
        }
        Some(speeds)
    }

    /// The simulated motor of a robot axis, mutable (for fault injection).
    pub fn axis_mut(&mut self, axis: Axis) -> Option<&mut SimAxis> {
        self.node_mut(self.map.node_id(axis))
    }

    /// Hands one received frame to its axis (to each, if several share the node id, as on a
    /// real bus).
    pub fn receive(&mut self, frame: &CanFrame, now_us: u64) {
        self.stats.received += 1;
        match decode(frame) {
            Err(_) => self.stats.malformed += 1,
            Ok((node, message)) => {
                let mut heard = false;
                for axis in self.axes.iter_mut().filter(|a| a.node() == node) {
                    axis.handle(&message, now_us);
                    heard = true;
                }
                if !heard {
                    self.stats.foreign += 1;
                }
            }
        }
    }

    /// One simulation step ending at `now_us`: take in everything that has arrived, move every
    /// motor by `dt_s`, send whatever reports are due.
    pub fn run<T: Transport + ?Sized>(
        &mut self,
        transport: &mut T,
        now_us: u64,
        dt_s: f32,
    ) -> Result<(), BusError> {
        while let Some(frame) = transport.recv(now_us)? {
            self.receive(&frame, now_us);
        }
        self.outbox.clear();
        for axis in &mut self.axes {
            axis.step(dt_s, now_us);
            axis.poll_tx(now_us, &mut self.outbox);
        }
        for frame in &self.outbox {
            transport.send(frame, now_us)?;
        }
        Ok(())
    }
}
