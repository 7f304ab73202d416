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

/// Frames one control tick sends: a position setpoint per joint, a velocity per wheel.
pub const FRAMES_PER_SETPOINT: usize = AXIS_COUNT;

/// Why frames could not be queued.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum CanError {
    /// Not enough room in the transmit queue; nothing was queued.
    QueueFull,
    /// A value could not be encoded; nothing was queued.
    Encode(EncodeError),
}

impl From<EncodeError> for CanError {
    fn from(e: EncodeError) -> Self {
        CanError::Encode(e)
    }
}

/// A bounded FIFO of frames waiting for the CAN driver; capacity `N` is fixed at compile time.
pub struct TxQueue<F, const N: usize> {
    frames: Deque<F, N>,
}

impl<F, const N: usize> Default for TxQueue<F, N> {
    fn default() -> Self {
        TxQueue {
            frames: Deque::new(),
        }
    }
}

impl<F, const N: usize> TxQueue<F, N> {
    /// An empty queue.
    pub fn new() -> Self {
        TxQueue::default()
    }

    /// Frames waiting.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame is waiting.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Room left.
    pub fn free(&self) -> usize {
        N - self.frames.len()
    }

    /// The oldest frame, removed from the queue.
    pub fn pop(&mut self) -> Option<F> {
        self.frames.pop_front()
    }

    /// Appends one frame.
    pub fn push(&mut self, frame: F) -> Result<(), CanError> {
        self.frames
            .push_back(frame)
            .map_err(|_| CanError::QueueFull)
    }

    /// Appends all of `frames` or none of them, so a tick's commands never go out half-sent.
    fn push_all<const M: usize>(&mut self, frames: heapless::Vec<F, M>) -> Result<(), CanError> {
        if self.free() < frames.len() {
            return Err(CanError::QueueFull);
        }
        for frame in frames {
            self.push(frame)?;
        }
        Ok(())
    }
}

/// Builds the frames for the robot's commands from the node map.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Commander {
    /// Which node is which axis, and the unit conversions.
    pub map: NodeMap,
}

impl Commander {
    /// A commander for `map`.
    pub fn new(map: NodeMap) -> Commander {
        Commander { map }
    }

    fn frame<F: Frame>(&self, axis: Axis, message: Message) -> Result<F, CanError> {
        Ok(encode(self.map.node_id(axis), &message)?)
    }

    /// Queues one tick's setpoint: a Set_Input_Pos (with velocity feed-forward) for each of the
    /// 12 joints, a Set_Input_Vel for each of the 4 wheels.
    pub fn queue_setpoint<F: Frame, const N: usize>(
        &self,
        queue: &mut TxQueue<F, N>,
        setpoint: &Setpoint,
    ) -> Result<(), CanError> {
        let mut frames: heapless::Vec<F, FRAMES_PER_SETPOINT> = heapless::Vec::new();
        for axis in Axis::ALL {
            let cal = self.map.get(axis);
            let message = match axis {
                Axis::Joint(_, joint) => {
                    // All legs share the joint angles (left-leg convention); the mirrored
                    // mounting of the right legs is in the calibration's direction.
                    let (angle_rad, rate_radps) = match joint {
                        Joint::Hip => (setpoint.joints.hip_rad, setpoint.joint_rates.hip_radps),
                        Joint::Knee => (setpoint.joints.knee_rad, setpoint.joint_rates.knee_radps),
                        Joint::WheelMount => (
                            setpoint.joints.wheel_mount_rad,
                            setpoint.joint_rates.wheel_mount_radps,
                        ),
                    };
                    Message::SetInputPos {
                        pos_turns: cal.to_motor_turns(angle_rad),
                        vel_ff_turns_per_s: cal.to_motor_turns_per_s(rate_radps),
                        torque_ff_nm: 0.0,
                    }
                }
                Axis::Wheel(leg) => Message::SetInputVel {
                    vel_turns_per_s: cal.to_motor_turns_per_s(setpoint.wheels.get(leg)),
                    torque_ff_nm: 0.0,
                },
            };
            frames
                .push(self.frame(axis, message)?)
                .map_err(|_| CanError::QueueFull)?;
        }
        queue.push_all(frames)
    }

    /// Queues the start-up sequence: position control for the joints, velocity control for the
    /// wheels (both passthrough: the runtime already smooths its setpoints), then closed loop.
    pub fn queue_startup<F: Frame, const N: usize>(
        &self,
        queue: &mut TxQueue<F, N>,
    ) -> Result<(), CanError> {
        let mut frames: heapless::Vec<F, { 2 * AXIS_COUNT }> = heapless::Vec::new();
        for axis in Axis::ALL {
            let control_mode = match axis.kind() {
                AxisKind::Joint => ControlMode::Position,
                AxisKind::Wheel => ControlMode::Velocity,
            };
            let mode = Message::SetControllerMode {
                control_mode,
                input_mode: InputMode::Passthrough,
            };
            frames
                .push(self.frame(axis, mode)?)
                .map_err(|_| CanError::QueueFull)?;
        }
        for axis in Axis::ALL {
            let closed = Message::SetAxisState(AxisState::ClosedLoopControl);
            frames
                .push(self.frame(axis, closed)?)
                .map_err(|_| CanError::QueueFull)?;
        }
        queue.push_all(frames)
    }

    /// Queues a Get_Version request (a remote frame) for every axis: one round of the
    /// start-up [`RollCall`].
    pub fn queue_version_requests<F: Frame, const N: usize>(
        &self,
        queue: &mut TxQueue<F, N>,
    ) -> Result<(), CanError> {
        self.queue_broadcast(queue, Message::Request(CmdId::GetVersion))
    }

    /// Queues the same argument-less message (Estop, Clear_Errors, a request) for every axis.
    fn queue_broadcast<F: Frame, const N: usize>(
        &self,
        queue: &mut TxQueue<F, N>,
        message: Message,
    ) -> Result<(), CanError> {
        let mut frames: heapless::Vec<F, AXIS_COUNT> = heapless::Vec::new();
        for axis in Axis::ALL {
            frames
                .push(self.frame(axis, message)?)
                .map_err(|_| CanError::QueueFull)?;
        }
        queue.push_all(frames)
    }

    /// Queues an Estop for every axis: all motors disarm (the legs then rest on their
    /// gearboxes). For a controlled stop that keeps the legs powered, use
    /// [`Commander::queue_safe_stop`].
    pub fn queue_estop<F: Frame, const N: usize>(
        &self,
        queue: &mut TxQueue<F, N>,
    ) -> Result<(), CanError> {
        self.queue_broadcast(queue, Message::Estop)
    }

    /// Queues Clear_Errors for every axis.
    pub fn queue_clear_errors<F: Frame, const N: usize>(
        &self,
        queue: &mut TxQueue<F, N>,
    ) -> Result<(), CanError> {
        self.queue_broadcast(queue, Message::ClearErrors)
    }

    /// Queues the fallback safe stop, for a controller that knows no motion to stop along:
    /// every wheel to 0 turns/s, every joint held where it was last measured (zero
    /// feed-forward). Axes never heard from get no position command (there is nothing safe to
    /// send them); their own watchdog idles them. Returns how many frames were queued.
    ///
    /// Inside a step, the controlled stop is better: [`crate::motion::StepMotion::stop_after`]
    /// yields setpoints (sent with [`Commander::queue_setpoint`]) that decelerate legs and
    /// wheels together along the step's path. This one leaves the path (wheels coast while the
    /// joints freeze, and a silent joint's last measurement is up to the silence timeout old),
    /// so it is the last resort (docs/can-protocol.md, "Safety").
    pub fn queue_safe_stop<F: Frame, const N: usize>(
        &self,
        queue: &mut TxQueue<F, N>,
        feedback: &FeedbackTracker,
    ) -> Result<usize, CanError> {
        let mut frames: heapless::Vec<F, AXIS_COUNT> = heapless::Vec::new();
        for axis in Axis::ALL {
            let message = match axis.kind() {
                AxisKind::Wheel => Message::SetInputVel {
                    vel_turns_per_s: 0.0,
                    torque_ff_nm: 0.0,
                },
                AxisKind::Joint => match feedback.axis(axis) {
                    Some(AxisFeedback {
                        estimate_at_us: Some(_),
                        pos_turns,
                        ..
                    }) => Message::SetInputPos {
                        pos_turns,
                        vel_ff_turns_per_s: 0.0,
                        torque_ff_nm: 0.0,
                    },
                    _ => continue,
                },
            };
            frames
                .push(self.frame(axis, message)?)
                .map_err(|_| CanError::QueueFull)?;
        }
        let count = frames.len();
        queue.push_all(frames)?;
        Ok(count)
    }
}

/// What one axis last reported.
#[derive(Clone, Copy, Debug, PartialEq, Default)]
pub struct AxisFeedback {
    /// Motor position from the last encoder estimate.
    pub pos_turns: f32,
    /// Motor velocity from the last encoder estimate.
    pub vel_turns_per_s: f32,
    /// When the last encoder estimate arrived.
    pub estimate_at_us: Option<u64>,
    /// State from the last heartbeat.
    pub axis_state: Option<AxisState>,
    /// Error bits from the last heartbeat.
    pub axis_error: u32,
    /// When the last heartbeat arrived.
    pub heartbeat_at_us: Option<u64>,
    /// What the last Get_Version answer reported.
    pub version: Option<Version>,
}

impl AxisFeedback {
    /// When anything was last heard from the axis.
    pub fn last_seen_us(&self) -> Option<u64> {
        match (self.estimate_at_us, self.heartbeat_at_us) {
            (Some(a), Some(b)) => Some(a.max(b)),
            (a, b) => a.or(b),
        }
    }
}

/// Counters of received traffic.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct BusStats {
    /// Frames used (heartbeats, encoder estimates and version answers from mapped nodes).
    pub accepted: u32,
    /// Frames that do not decode as CANSimple (bad length, unknown command, bad value, ...).
    pub malformed: u32,
    /// Valid frames the host has no use for: from unmapped nodes, or commands and requests
    /// (another master on the bus, or our own echo).
    pub unexpected: u32,
}

/// What the tracker did with a frame.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Received {
    /// Feedback from this axis was recorded.
    Accepted(Axis),
    /// The frame did not decode; counted in [`BusStats::malformed`].
    Malformed(DecodeError),
    /// The frame decoded but was not for us; counted in [`BusStats::unexpected`].
    Unexpected,
}

/// A set of axes as a bit mask over [`Axis::ALL`] indices.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct AxisSet(pub u16);

impl AxisSet {
    /// Whether `axis` is in the set.
    pub fn contains(&self, axis: Axis) -> bool {
        self.0 & (1 << axis.index()) != 0
    }

    fn insert(&mut self, axis: Axis) {
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

/// The bus as the controller sees it at one instant.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct Health {
    /// Axes not heard from within the timeout (or never).
    pub silent: AxisSet,
    /// Axes whose last heartbeat carried error bits.
    pub errored: AxisSet,
    /// Axes whose last heartbeat was not closed-loop control.
    pub not_closed_loop: AxisSet,
}

impl Health {
    /// Whether every axis is heard from, error-free and in closed loop.
    pub fn is_ok(&self) -> bool {
        self.silent.is_empty() && self.errored.is_empty() && self.not_closed_loop.is_empty()
    }
}

/// Keeps the latest feedback of every axis; decodes frames without ever panicking.
#[derive(Clone, Debug, PartialEq)]
pub struct FeedbackTracker {
    map: NodeMap,
    axes: [AxisFeedback; AXIS_COUNT],
    stats: BusStats,
}

impl FeedbackTracker {
    /// A tracker that has heard nothing yet.
    pub fn new(map: NodeMap) -> FeedbackTracker {
        FeedbackTracker {
            map,
            axes: [AxisFeedback::default(); AXIS_COUNT],
            stats: BusStats::default(),
        }
    }

    /// Traffic counters.
    pub fn stats(&self) -> BusStats {
        self.stats
    }

    /// Latest feedback of one axis.
    pub fn axis(&self, axis: Axis) -> Option<AxisFeedback> {
        self.axes.get(axis.index()).copied()
    }

    /// Records a received frame, received at `now_us`.
    pub fn receive<F: Frame>(&mut self, frame: &F, now_us: u64) -> Received {
        let (node, message) = match decode(frame) {
            Ok(decoded) => decoded,
            Err(e) => {
                self.stats.malformed = self.stats.malformed.saturating_add(1);
                return Received::Malformed(e);
            }
        };
        let slot = self.map.axis_on(node).and_then(|axis| {
            let slot = self.axes.get_mut(axis.index())?;
            Some((axis, slot))
        });
        let accepted = match (slot, message) {
            (
                Some((axis, slot)),
                Message::EncoderEstimates {
                    pos_turns,
                    vel_turns_per_s,
                },
            ) => {
                slot.pos_turns = pos_turns;
                slot.vel_turns_per_s = vel_turns_per_s;
                slot.estimate_at_us = Some(now_us);
                Some(axis)
            }
            (
                Some((axis, slot)),
                Message::Heartbeat {
                    axis_error,
                    axis_state,
                },
            ) => {
                slot.axis_error = axis_error;
                slot.axis_state = Some(axis_state);
                slot.heartbeat_at_us = Some(now_us);
                Some(axis)
            }
            (Some((axis, slot)), Message::Version(version)) => {
                slot.version = Some(version);
                Some(axis)
            }
            _ => None,
        };
        match accepted {
            Some(axis) => {
                self.stats.accepted = self.stats.accepted.saturating_add(1);
                Received::Accepted(axis)
            }
            None => {
                self.stats.unexpected = self.stats.unexpected.saturating_add(1);
                Received::Unexpected
            }
        }
    }

    fn angle_rad(&self, axis: Axis) -> Option<f32> {
        let fb = self.axis(axis)?;
        fb.estimate_at_us?;
        Some(self.map.get(axis).to_angle_rad(fb.pos_turns))
    }

    /// Measured joint angles of one leg (left-leg convention); `None` until all three joints
    /// have reported.
    pub fn leg_joints(&self, leg: LegId) -> Option<JointAngles> {
        Some(JointAngles {
            hip_rad: self.angle_rad(Axis::Joint(leg, Joint::Hip))?,
            knee_rad: self.angle_rad(Axis::Joint(leg, Joint::Knee))?,
            wheel_mount_rad: self.angle_rad(Axis::Joint(leg, Joint::WheelMount))?,
        })
    }

    /// Measured leg configuration: forward kinematics of each leg, averaged over the four (the
    /// command is symmetric, so the spread is a measure of tracking error, not of intent).
    pub fn leg_config(&self, geometry: &RobotGeometry) -> Option<LegConfig> {
        let (mut clearance_m, mut track_m) = (0.0, 0.0);
        for leg in LegId::ALL {
            let c = geometry.config_from_joints(self.leg_joints(leg)?);
            clearance_m += 0.25 * c.clearance_m;
            track_m += 0.25 * c.track_m;
        }
        Some(LegConfig {
            clearance_m,
            track_m,
        })
    }

    /// Measured wheel speeds; `None` until every wheel has reported.
    pub fn wheel_speeds(&self) -> Option<WheelSpeeds> {
        let mut speeds = WheelSpeeds::ZERO;
        for (leg, out) in LegId::ALL.into_iter().zip(speeds.radps.iter_mut()) {
            let axis = Axis::Wheel(leg);
            let fb = self.axis(axis)?;
            fb.estimate_at_us?;
            *out = self.map.get(axis).to_speed_radps(fb.vel_turns_per_s);
        }
        Some(speeds)
    }

    /// Which axes are silent (nothing for `timeout_us`), in error, or not in closed loop.
    pub fn health(&self, now_us: u64, timeout_us: u64) -> Health {
        let mut health = Health::default();
        for (axis, fb) in Axis::ALL.into_iter().zip(self.axes.iter()) {
            let fresh = fb
                .last_seen_us()
                .is_some_and(|t| now_us.saturating_sub(t) <= timeout_us);
            if !fresh {
                health.silent.insert(axis);
            }
            if fb.axis_error != 0 {
                health.errored.insert(axis);
            }
            if fb.axis_state != Some(AxisState::ClosedLoopControl) {
                health.not_closed_loop.insert(axis);
            }
        }
        health
    }
}

/// Get_Version rounds of the start-up [`RollCall`]: more than one, so that a lost frame is not
/// a missing node and a duplicated one is not a second device.
pub const ROLL_CALL_ROUNDS: u8 = 3;

/// How long each roll-call round waits for Get_Version answers. An axis answers within a
/// millisecond or two; the rest is room for a bus that delays frames and for a real-time link
/// through a busy host, so that a slow answer is not taken for a missing node (nor counted in
/// the next round as a second device).
pub const ROLL_CALL_ROUND_US: u64 = 50_000;

/// What is wrong with one node at the start-up roll call.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum RollCallProblem {
    /// Nothing heard from the node: no answer to Get_Version, no heartbeat, no estimate.
    Missing,
    /// Two devices on one node id: two different answers, or two answers to every request.
    TwoDevices,
    /// Firmware whose major.minor this codec does not speak (see
    /// [`Version::speaks_this_codec`]).
    UnsupportedFirmware(Version),
}

impl core::fmt::Display for RollCallProblem {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        match self {
            RollCallProblem::Missing => f.write_str(
                "missing: nothing heard from it (is it powered, on the bus, on this node id?)",
            ),
            RollCallProblem::TwoDevices => {
                f.write_str("answered Get_Version twice: two devices share this node id")
            }
            RollCallProblem::UnsupportedFirmware(version) => write!(
                f,
                "reports {version}; this controller speaks the CANSimple layout of \
                 firmware {}.{}.x only",
                crate::can::protocol::SPOKEN_FW_VERSION.0,
                crate::can::protocol::SPOKEN_FW_VERSION.1
            ),
        }
    }
}

/// Why the roll call refuses to let the robot move: the first axis, in node order, with a
/// problem.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct RollCallRefusal {
    /// The axis.
    pub axis: Axis,
    /// Its node id.
    pub node: NodeId,
    /// What is wrong.
    pub problem: RollCallProblem,
}

impl core::fmt::Display for RollCallRefusal {
    fn fmt(&self, f: &mut core::fmt::Formatter<'_>) -> core::fmt::Result {
        write!(
            f,
            "node {} ({}): {}",
            self.node.get(),
            self.axis,
            self.problem
        )
    }
}

/// The start-up roll call: who answers Get_Version on each node of the map, how often, and with
/// what. Fixed-size, never allocates.
///
/// Use: for each of [`ROLL_CALL_ROUNDS`] rounds, [`RollCall::begin_round`], queue the requests
/// ([`Commander::queue_version_requests`]), hand every received frame to
/// [`RollCall::receive`] for a bounded time; then [`RollCall::verdict`].
#[derive(Clone, Debug, PartialEq)]
pub struct RollCall {
    map: NodeMap,
    rounds: u8,
    /// Answers per axis in the round in progress.
    this_round: [u8; AXIS_COUNT],
    /// Finished rounds in which the axis answered more than once.
    rounds_doubled: [u8; AXIS_COUNT],
    versions: [Option<Version>; AXIS_COUNT],
    conflicting: AxisSet,
    heard: AxisSet,
}

impl RollCall {
    /// A roll call of `map`'s nodes that has heard nothing yet.
    pub fn new(map: NodeMap) -> RollCall {
        RollCall {
            map,
            rounds: 0,
            this_round: [0; AXIS_COUNT],
            rounds_doubled: [0; AXIS_COUNT],
            versions: [None; AXIS_COUNT],
            conflicting: AxisSet::default(),
            heard: AxisSet::default(),
        }
    }

    /// Closes the round in progress, if any, and opens the next; call it before sending the
    /// round's requests.
    pub fn begin_round(&mut self) {
        self.close_round();
        self.rounds = self.rounds.saturating_add(1);
    }

    fn close_round(&mut self) {
        for (now, doubled) in self
            .this_round
            .iter_mut()
            .zip(self.rounds_doubled.iter_mut())
        {
            if *now >= 2 {
                *doubled = doubled.saturating_add(1);
            }
            *now = 0;
        }
    }

    /// Rounds begun so far.
    pub fn rounds(&self) -> u8 {
        self.rounds
    }

    /// Takes in a received frame: any frame from a mapped node shows it is on the bus; a
    /// version answer is recorded. Returns the axis whose version answer this was, if it was one.
    pub fn receive<F: Frame>(&mut self, frame: &F) -> Option<Axis> {
        let (node, message) = decode(frame).ok()?;
        let axis = self.map.axis_on(node)?;
        if !message.is_command() {
            self.heard.insert(axis);
        }
        match message {
            Message::Version(version) => {
                self.record(axis, version);
                Some(axis)
            }
            _ => None,
        }
    }

    /// Records one version answer from `axis` in the round in progress.
    pub fn record(&mut self, axis: Axis, version: Version) {
        let i = axis.index();
        self.heard.insert(axis);
        if let Some(count) = self.this_round.get_mut(i) {
            *count = count.saturating_add(1);
        }
        if let Some(slot) = self.versions.get_mut(i) {
            match slot {
                None => *slot = Some(version),
                // A bus may repeat a frame but never alters one: different contents on one id
                // are two devices.
                Some(first) if *first != version => self.conflicting.insert(axis),
                Some(_) => {}
            }
        }
    }

    /// The version `axis` reported (its first answer), if it answered.
    pub fn version(&self, axis: Axis) -> Option<Version> {
        self.versions.get(axis.index()).copied().flatten()
    }

    /// The axes that answered Get_Version at least once.
    pub fn answered(&self) -> AxisSet {
        let mut set = AxisSet::default();
        for axis in Axis::ALL {
            if self.version(axis).is_some() {
                set.insert(axis);
            }
        }
        set
    }

    /// The axes anything was heard from (a version answer or any other report).
    pub fn heard(&self) -> AxisSet {
        self.heard
    }

    /// Whether every node may be driven: each answered, once per request, with firmware this
    /// codec speaks. Otherwise the first axis in node order with a problem. The round in
    /// progress counts as finished.
    pub fn verdict(&self) -> Result<(), RollCallRefusal> {
        let rounds = self.rounds.max(1);
        for axis in Axis::ALL {
            let i = axis.index();
            let now = self.this_round.get(i).copied().unwrap_or(0);
            let doubled = self
                .rounds_doubled
                .get(i)
                .copied()
                .unwrap_or(0)
                .saturating_add(u8::from(now >= 2));
            let problem = match self.version(axis) {
                // ODrive firmware before 0.6 has no Get_Version: a node heard otherwise (its
                // heartbeat) runs the 0.5.x layout this codec speaks.
                None if self.heard.contains(axis) => None,
                None => Some(RollCallProblem::Missing),
                // A bus that repeats a frame now and then doubles an answer in some round,
                // rarely in every round; a second device answers twice every time.
                Some(_) if self.conflicting.contains(axis) || doubled >= rounds => {
                    Some(RollCallProblem::TwoDevices)
                }
                Some(version) if !version.speaks_this_codec() => {
                    Some(RollCallProblem::UnsupportedFirmware(version))
                }
                Some(_) => None,
            };
            if let Some(problem) = problem {
                return Err(RollCallRefusal {
                    axis,
                    node: self.map.node_id(axis),
                    problem,
                });
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
