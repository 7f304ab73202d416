//! Feedback in: what every axis last reported ([`FeedbackTracker`]), the frames the bus
//! brought ([`BusStats`]) and its health.

use super::*;

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
