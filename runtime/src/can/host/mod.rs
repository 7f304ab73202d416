//! The runtime's side of the bus: commands out through a bounded queue, feedback in through a
//! tracker that knows what every axis last reported.
//!
//! Nothing here touches hardware. The control loop asks the [`Commander`] to put a tick's
//! frames in a [`TxQueue`], drains the queue into whatever CAN driver it has (an MCU HAL, the
//! in-process bus, SocketCAN), and hands every received frame to the [`FeedbackTracker`]. A
//! frame the tracker cannot use is counted in [`BusStats`] and otherwise ignored: a noisy bus
//! must never stop the controller, and a silent node must show up in [`Health`], not as a panic.
//!
//! Before anything moves, a [`RollCall`] asks every node of the map who it is (Get_Version) and
//! refuses a bus with a node missing, two devices on one id, or firmware whose CANSimple layout
//! the codec does not speak: each of those would otherwise surface only later, in motion.

//!
//! Pieces: the commands out and their queue in `commands.rs`, the feedback in and the bus's
//! health in `feedback.rs`, the start-up's roll call in `roll_call.rs`.

mod commands;
mod feedback;
mod roll_call;

pub use commands::*;
pub use feedback::*;
pub use roll_call::*;

use crate::base::WheelSpeeds;
use crate::can::node_map::{Axis, AxisKind, Joint, NodeMap, AXIS_COUNT};
use crate::can::protocol::{
    decode, encode, AxisState, CmdId, ControlMode, DecodeError, EncodeError, InputMode, Message,
    NodeId, Version,
};
use crate::leg::{JointAngles, LegConfig};
use crate::motion::Setpoint;
use crate::robot::{LegId, RobotGeometry};
use embedded_can::Frame;
use heapless::Deque;

/// A set of axes as a bit mask over [`Axis::ALL`] indices.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct AxisSet(pub u16);

impl AxisSet {
    /// Whether `axis` is in the set.
    pub fn contains(&self, axis: Axis) -> bool {
        self.0 & (1 << axis.index()) != 0
    }

    pub(crate) fn insert(&mut self, axis: Axis) {
        self.0 |= 1 << axis.index();
    }

    /// Whether the set is empty.
    pub fn is_empty(&self) -> bool {
        self.0 == 0
    }

    /// The axes in the set, in node order.
    pub fn iter(self) -> impl Iterator<Item = Axis> {
        Axis::ALL.into_iter().filter(move |a| self.contains(*a))
    }
}

#[cfg(test)]
mod tests;
