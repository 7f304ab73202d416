//! What the host injects into an episode in the loop, and why the firmware says it stopped.

use wheelleg_runtime::can::host::AxisSet;
use wheelleg_runtime::can::node_map::{Axis, NodeMap};

use super::plant::PlantFault;
use super::wire::stop_reason;

/// A fault of the observation link, injected by the host's side of it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum LinkFault {
    /// From this decision (1-based) on, nothing more is sent.
    StallAt(u32),
    /// From this decision (1-based) on, every frame is sent with one byte flipped.
    CorruptAt(u32),
}

/// Faults to inject in an episode.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Faults {
    /// On the observation link.
    pub link: Option<LinkFault>,
    /// On the CAN side, from a decision (1-based) on: injected at the first control period the
    /// firmware polls after that decision was taken (so in the middle of its step).
    pub plant: Vec<(u32, PlantFault)>,
    /// A slow decision: before this decision (1-based), the firmware is told to spend this
    /// many milliseconds busy in it (`DelayNextDecision`), as a slow decision would; the robot
    /// must hold through them.
    pub slow_decision: Option<(u32, u32)>,
}

/// Why the firmware stopped the robot, as it reported it.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct ControllerStop {
    /// One of [`wire::stop_reason`].
    pub reason: u8,
    /// The axes, for silent or errored axes.
    pub axes: AxisSet,
    /// The firmware's control period in which it stopped (counted from its first).
    pub tick: u32,
    /// Each axis's node id (in `Axis::ALL`'s order), to name the axes by.
    pub node_ids: [u8; 16],
}

impl ControllerStop {
    /// The node ids of `map`'s axes, in `Axis::ALL`'s order.
    pub fn node_ids(map: &NodeMap) -> [u8; 16] {
        let mut ids = [0; 16];
        for (id, axis) in ids.iter_mut().zip(Axis::ALL) {
            *id = map.node_id(axis).get();
        }
        ids
    }
}

impl std::fmt::Display for ControllerStop {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        let axes = || {
            self.axes
                .iter()
                .map(|axis| {
                    let id = self.node_ids.get(axis.index()).copied().unwrap_or(0);
                    format!("node {id} ({axis:?})")
                })
                .collect::<Vec<_>>()
                .join(", ")
        };
        match self.reason {
            stop_reason::SILENT_AXES => write!(f, "{} silent (no frames for 50 ms)", axes()),
            stop_reason::AXIS_ERRORS => write!(f, "{} reported errors", axes()),
            stop_reason::CAN_LINK => f.write_str("the CAN adapter stopped answering (50 ms)"),
            stop_reason::OBSERVATION_STALLED => {
                f.write_str("no observation for 1 s (observation link stalled)")
            }
            stop_reason::OBSERVATION_CORRUPT => {
                f.write_str("only corrupt frames for 1 s on the observation link")
            }
            stop_reason::STARTUP_FAILED => f.write_str("not every axis reached closed loop"),
            stop_reason::ESTOP => f.write_str("an emergency stop was sent to every axis"),
            _ => f.write_str("a step could not be driven"),
        }?;
        write!(f, ", in control period {}", self.tick)
    }
}
