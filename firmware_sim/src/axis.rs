//! One simulated ODrive axis: state machine, controller, motor response, periodic reports.
//!
//! What it models, and why each piece is there:
//!
//! - **States**: idle (motor off) and closed-loop control. Requesting closed loop with a latched
//!   error is refused, as on an ODrive: errors must be cleared first. Calibration states are
//!   not simulated; requesting one latches `INVALID_STATE`.
//! - **Controller**: position mode commands a velocity `vel_ff + pos_gain * (input_pos - pos)`;
//!   velocity mode commands `input_vel`. The commanded velocity is clamped to the velocity limit,
//!   and the motor follows it with a first-order lag (`time_constant_s`) whose rate of change is
//!   clamped to the acceleration limit.
//! - **Idle**: no torque, so the speed decays to zero with `idle_decay_s` (friction and, for the
//!   leg joints, the high-ratio gearbox's self-locking): wheels spin down, legs stay where they
//!   are. This is the "wheels stop, legs hold" safe state the watchdog falls back to.
//! - **Watchdog**: off unless configured, as on an ODrive (`axis.config.enable_watchdog`,
//!   `watchdog_timeout`). With `watchdog_timeout_us` set, in closed loop a setpoint must be
//!   accepted every `watchdog_timeout_us` (arming starts the count); if none is, the axis goes
//!   idle and latches `WATCHDOG_TIMER_EXPIRED`. A client that waits for the heartbeat to show
//!   closed loop before it streams setpoints thus never sees an unconfigured axis trip.
//! - **Range checks**: a setpoint beyond the velocity limit or the position limits latches
//!   `CONTROLLER_FAILED` and idles the axis (an ODrive disarms on a controller error).
//! - **Estop** latches `ESTOP_REQUESTED` and idles; **Clear_Errors** clears every latched bit.
//! - **Reports**: encoder estimates and heartbeats at their own periods, plus on request (RTR);
//!   Get_Version on request only, when the axis runs firmware that has it
//!   ([`AxisConfig::version`]: ODrive 0.6 on; 0.5.x, the default, stays silent to it).
//! - **Fault injection**: a silent axis keeps executing commands but transmits nothing (a
//!   broken transmitter); a deaf one hears nothing (with silence: a node off the bus), so it
//!   runs on its last setpoint until its watchdog idles it, as a real ODrive would.

use wheelleg_runtime::can::protocol::{
    axis_error, encode, AxisState, CmdId, ControlMode, InputMode, Message, NodeId, Version,
};
use wheelleg_runtime::can::CanFrame;

/// Parameters of one simulated axis (motor side: turns, turns/s). [`AxisConfig::JOINT`] and
/// [`AxisConfig::WHEEL`] have no watchdog, like an ODrive whose watchdog nobody enabled: whoever
/// drives the axes enables it (`watchdog_timeout_us`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct AxisConfig {
    /// Largest commanded speed; setpoints beyond it are errors.
    pub vel_limit_turns_per_s: f32,
    /// Largest rate of change of speed.
    pub accel_limit_turns_per_s2: f32,
    /// First-order lag of the speed behind its command.
    pub time_constant_s: f32,
    /// Position loop gain: commanded speed per turn of position error.
    pub pos_gain_per_s: f32,
    /// Allowed position setpoints `[min, max]`; `None` for a wheel (unbounded).
    pub pos_limits_turns: Option<[f32; 2]>,
    /// Time constant of the speed decay when idle.
    pub idle_decay_s: f32,
    /// Watchdog timeout; 0 (the default, as on an ODrive) disables the watchdog.
    pub watchdog_timeout_us: u64,
    /// Period of encoder estimate reports; 0 disables them.
    pub encoder_period_us: u64,
    /// Period of heartbeats; 0 disables them.
    pub heartbeat_period_us: u64,
    /// What the axis answers to Get_Version; `None` (the default) for firmware without it,
    /// ODrive's before 0.6.
    pub version: Option<Version>,
}

impl AxisConfig {
    /// A leg joint actuator (9:1 gearbox): ±10 motor turns/s (≈7 rad/s at the joint), a 10 ms
    /// speed loop, position limits of ±8 motor turns (±5.6 rad at the joint) that cover every
    /// joint range of `WHEELLEG` (the wheel mount reaches -4.3 rad) with margin.
    pub const JOINT: AxisConfig = AxisConfig {
        vel_limit_turns_per_s: 10.0,
        accel_limit_turns_per_s2: 200.0,
        time_constant_s: 0.01,
        pos_gain_per_s: 40.0,
        pos_limits_turns: Some([-8.0, 8.0]),
        idle_decay_s: 0.005,
        watchdog_timeout_us: 0,
        encoder_period_us: 10_000,
        heartbeat_period_us: 100_000,
        version: None,
    };

    /// A direct-drive hub wheel: ±10 turns/s (≈3 m/s at 5 cm radius), a 20 ms speed loop, a
    /// quarter-second spin-down when idle.
    pub const WHEEL: AxisConfig = AxisConfig {
        vel_limit_turns_per_s: 10.0,
        accel_limit_turns_per_s2: 100.0,
        time_constant_s: 0.02,
        pos_gain_per_s: 20.0,
        pos_limits_turns: None,
        idle_decay_s: 0.05,
        watchdog_timeout_us: 0,
        encoder_period_us: 10_000,
        heartbeat_period_us: 100_000,
        version: None,
    };
}

/// Counters of what an axis did with the commands it got.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct AxisStats {
    /// Commands executed.
    pub commands: u32,
    /// Commands refused (out of range, or not applicable in the current state or mode).
    pub refused: u32,
    /// Watchdog expiries.
    pub watchdog_trips: u32,
}

/// A simulated ODrive axis.
#[derive(Clone, Debug, PartialEq)]
pub struct SimAxis {
    node: NodeId,
    config: AxisConfig,
    state: AxisState,
    error: u32,
    control_mode: ControlMode,
    input_mode: InputMode,
    input_pos_turns: f32,
    vel_ff_turns_per_s: f32,
    input_vel_turns_per_s: f32,
    pos_turns: f32,
    vel_turns_per_s: f32,
    last_setpoint_us: u64,
    watchdog_trip_us: Option<u64>,
    next_estimate_us: u64,
    next_heartbeat_us: u64,
    /// Requests to answer at the next transmission: heartbeat, encoder estimates, version.
    pending_requests: [bool; 3],
    silent: bool,
    deaf: bool,
    stats: AxisStats,
}

impl SimAxis {
    /// An idle axis at `pos_turns`, at rest, in position control.
    pub fn new(node: NodeId, config: AxisConfig, pos_turns: f32) -> SimAxis {
        SimAxis {
            node,
            config,
            state: AxisState::Idle,
            error: 0,
            control_mode: ControlMode::Position,
            input_mode: InputMode::Passthrough,
            input_pos_turns: pos_turns,
            vel_ff_turns_per_s: 0.0,
            input_vel_turns_per_s: 0.0,
            pos_turns,
            vel_turns_per_s: 0.0,
            last_setpoint_us: 0,
            watchdog_trip_us: None,
            next_estimate_us: 0,
            next_heartbeat_us: 0,
            pending_requests: [false; 3],
            silent: false,
            deaf: false,
            stats: AxisStats::default(),
        }
    }

    /// The axis's node id.
    pub fn node(&self) -> NodeId {
        self.node
    }

    /// The axis's parameters.
    pub fn config(&self) -> &AxisConfig {
        &self.config
    }

    /// The axis's parameters, to change (for example the watchdog timeout, as ODrive's
    /// configuration is changed over USB); they apply from the next step.
    pub fn config_mut(&mut self) -> &mut AxisConfig {
        &mut self.config
    }

    /// Current state.
    pub fn state(&self) -> AxisState {
        self.state
    }

    /// Latched error bits.
    pub fn error(&self) -> u32 {
        self.error
    }

    /// True position.
    pub fn pos_turns(&self) -> f32 {
        self.pos_turns
    }

    /// True speed.
    pub fn vel_turns_per_s(&self) -> f32 {
        self.vel_turns_per_s
    }

    /// Command counters.
    pub fn stats(&self) -> AxisStats {
        self.stats
    }

    /// When the axis last accepted a setpoint or was armed: the watchdog, if configured, counts
    /// from here.
    pub fn last_setpoint_us(&self) -> u64 {
        self.last_setpoint_us
    }

    /// When the watchdog last idled the axis, if it ever did (fault tests time it against
    /// [`SimAxis::last_setpoint_us`]).
    pub fn last_watchdog_trip_us(&self) -> Option<u64> {
        self.watchdog_trip_us
    }

    /// Makes the axis stop (or resume) transmitting; it still obeys commands.
    pub fn set_silent(&mut self, silent: bool) {
        self.silent = silent;
    }

    /// Whether the axis transmits nothing.
    pub fn is_silent(&self) -> bool {
        self.silent
    }

    /// Makes the axis stop (or resume) receiving: commands for it are lost, so it keeps its
    /// last setpoint until its watchdog idles it (or for good, if it has none).
    pub fn set_deaf(&mut self, deaf: bool) {
        self.deaf = deaf;
    }

    /// Whether the axis receives nothing.
    pub fn is_deaf(&self) -> bool {
        self.deaf
    }

    fn fail(&mut self, bits: u32) {
        self.error |= bits;
        self.state = AxisState::Idle;
        self.stats.refused += 1;
    }

    fn in_vel_limit(&self, vel: f32) -> bool {
        vel.abs() <= self.config.vel_limit_turns_per_s
    }

    /// Executes one command received at `now_us` (nothing, if the axis is deaf).
    pub fn handle(&mut self, message: &Message, now_us: u64) {
        if self.deaf {
            return;
        }
        match *message {
            Message::Estop => {
                self.error |= axis_error::ESTOP_REQUESTED;
                self.state = AxisState::Idle;
                self.stats.commands += 1;
            }
            Message::ClearErrors => {
                self.error = 0;
                self.stats.commands += 1;
            }
            Message::SetAxisState(AxisState::Idle) => {
                self.state = AxisState::Idle;
                self.stats.commands += 1;
            }
            Message::SetAxisState(AxisState::ClosedLoopControl) => {
                if self.error != 0 {
                    // ODrive refuses to arm with latched errors.
                    self.stats.refused += 1;
                    return;
                }
                // Arm where the motor is, so closing the loop does not jump.
                self.input_pos_turns = self.pos_turns;
                self.vel_ff_turns_per_s = 0.0;
                self.input_vel_turns_per_s = 0.0;
                self.state = AxisState::ClosedLoopControl;
                self.last_setpoint_us = now_us;
                self.stats.commands += 1;
            }
            Message::SetAxisState(_) => self.fail(axis_error::INVALID_STATE),
            Message::SetControllerMode {
                control_mode,
                input_mode,
            } => match (control_mode, input_mode) {
                (ControlMode::Position | ControlMode::Velocity, InputMode::Passthrough) => {
                    self.control_mode = control_mode;
                    self.input_mode = input_mode;
                    self.stats.commands += 1;
                }
                // Only what the runtime uses is simulated; anything else is refused loudly
                // rather than silently behaving like passthrough.
                _ => {
                    self.stats.refused += 1;
                }
            },
            Message::SetInputPos {
                pos_turns,
                vel_ff_turns_per_s,
                ..
            } => {
                let in_range = self
                    .config
                    .pos_limits_turns
                    .is_none_or(|[lo, hi]| (lo..=hi).contains(&pos_turns));
                if !in_range || !self.in_vel_limit(vel_ff_turns_per_s) {
                    self.fail(axis_error::CONTROLLER_FAILED);
                    return;
                }
                self.input_pos_turns = pos_turns;
                self.vel_ff_turns_per_s = vel_ff_turns_per_s;
                self.last_setpoint_us = now_us;
                self.stats.commands += 1;
            }
            Message::SetInputVel {
                vel_turns_per_s, ..
            } => {
                if !self.in_vel_limit(vel_turns_per_s) {
                    self.fail(axis_error::CONTROLLER_FAILED);
                    return;
                }
                self.input_vel_turns_per_s = vel_turns_per_s;
                self.last_setpoint_us = now_us;
                self.stats.commands += 1;
            }
            Message::Request(CmdId::Heartbeat) => self.pending_requests[0] = true,
            Message::Request(CmdId::GetEncoderEstimates) => self.pending_requests[1] = true,
            Message::Request(CmdId::GetVersion) => self.pending_requests[2] = true,
            // Reports from other axes, or requests this axis does not simulate.
            _ => {}
        }
    }

    /// Advances the motor by `dt_s` ending at `now_us` (watchdog checked first).
    pub fn step(&mut self, dt_s: f32, now_us: u64) {
        let timeout = self.config.watchdog_timeout_us;
        if self.state == AxisState::ClosedLoopControl
            && timeout > 0
            && now_us.saturating_sub(self.last_setpoint_us) > timeout
        {
            self.error |= axis_error::WATCHDOG_TIMER_EXPIRED;
            self.state = AxisState::Idle;
            self.stats.watchdog_trips += 1;
            self.watchdog_trip_us = Some(now_us);
        }
        let v0 = self.vel_turns_per_s;
        let v1 = if self.state == AxisState::ClosedLoopControl {
            let limit = self.config.vel_limit_turns_per_s;
            let target = match self.control_mode {
                ControlMode::Velocity => self.input_vel_turns_per_s,
                _ => {
                    self.vel_ff_turns_per_s
                        + self.config.pos_gain_per_s * (self.input_pos_turns - self.pos_turns)
                }
            }
            .clamp(-limit, limit);
            // Exact discretisation of the first-order lag, then the acceleration clamp.
            let alpha = 1.0 - (-dt_s / self.config.time_constant_s).exp();
            let max_dv = self.config.accel_limit_turns_per_s2 * dt_s;
            v0 + ((target - v0) * alpha).clamp(-max_dv, max_dv)
        } else {
            v0 * (-dt_s / self.config.idle_decay_s).exp()
        };
        self.vel_turns_per_s = v1;
        self.pos_turns += 0.5 * (v0 + v1) * dt_s;
    }

    /// Frames due at `now_us` (periodic reports and answers to requests), appended to `out`.
    pub fn poll_tx(&mut self, now_us: u64, out: &mut Vec<CanFrame>) {
        let hb_due = due(
            &mut self.next_heartbeat_us,
            self.config.heartbeat_period_us,
            now_us,
        );
        let est_due = due(
            &mut self.next_estimate_us,
            self.config.encoder_period_us,
            now_us,
        );
        let [hb_req, est_req, version_req] = std::mem::take(&mut self.pending_requests);
        if self.silent {
            return;
        }
        if let (true, Some(version)) = (version_req, self.config.version) {
            out.extend(encode::<CanFrame>(self.node, &Message::Version(version)).ok());
        }
        if hb_due || hb_req {
            let hb = Message::Heartbeat {
                axis_error: self.error,
                axis_state: self.state,
            };
            out.extend(encode::<CanFrame>(self.node, &hb).ok());
        }
        if est_due || est_req {
            let est = Message::EncoderEstimates {
                pos_turns: self.pos_turns,
                vel_turns_per_s: self.vel_turns_per_s,
            };
            out.extend(encode::<CanFrame>(self.node, &est).ok());
        }
    }
}

/// Whether a periodic report is due, advancing its schedule if so.
fn due(next_us: &mut u64, period_us: u64, now_us: u64) -> bool {
    if period_us == 0 || now_us < *next_us {
        return false;
    }
    // Catch up without bursting if the caller skipped time.
    *next_us = (*next_us + period_us).max(now_us + 1);
    true
}

#[cfg(test)]
mod tests;
