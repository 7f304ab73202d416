//! Commands out: the frames of a control period, built by the [`Commander`] into a bounded
//! [`TxQueue`].

use super::*;

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
