//! The closed loop without a policy: runtime motion -> CAN -> simulated axes -> CAN -> runtime
//! feedback -> forward kinematics.
//!
//! A [`Rig`] is the robot's controller (the runtime's [`Commander`] and [`FeedbackTracker`] with
//! a [`TxQueue`]) wired to a bus, with the 16 simulated axes on the same bus when the bus is
//! in-process. [`Rig::step`] executes one decision and reports the achieved pose (odometry from
//! the *measured* wheel speeds) and leg configuration (forward kinematics of the *measured*
//! joint angles) beside the ideal ones. Whatever a test or the demo does to the loop, it does
//! through here, so the policy's world and the motors' world meet in one place.
//!
//! Safety: every control tick the controller checks [`Health`]. A node silent for longer than
//! `health_timeout_us`, or reporting an error, puts the rig in safe stop for good, reported as
//! [`StopReason`]. Inside a step the robot decelerates along the step's own path
//! ([`StepMotion::stop_after`]: all 16 axes, the silent one included, ramp the step's progress
//! rate to zero over `MotionConfig::stop_s`) and then holds the pose reached ([`Rig::stop_rest`]);
//! between steps it holds the last pose commanded. Legs and wheels thus stop together on a pose
//! the step passes through anyway, instead of wheels coasting while the legs freeze
//! (docs/can-protocol.md, "Safety").
//!
//! For fault tests on the in-process bus the rig also keeps the *ground truth* the controller
//! cannot see ([`Rig::true_pose`], [`Rig::true_legs`]: integrated from the simulated motors' own
//! state every physics step) and can inject a fault at a chosen instant, in the middle of a
//! motion ([`Rig::schedule`], [`TimedFault`]).

use crate::bus::{BusError, Faults, InProcessBus, Port, Transport};
use crate::candump::CandumpWriter;
use crate::firmware::Firmware;
use nalgebra::Isometry2;
use std::io::Write;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::base::{BaseError, MecanumBase, Odometry, WheelSpeeds};
use wheelleg_runtime::can::bus_load::frame_bits;
use wheelleg_runtime::can::host::{CanError, Commander, FeedbackTracker, Health, TxQueue};
use wheelleg_runtime::can::node_map::{Axis, NodeMap};
use wheelleg_runtime::can::protocol::AxisState;
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::{IkError, LegConfig};
use wheelleg_runtime::motion::{
    ideal_step, MotionConfig, MotionError, Setpoint, StepMotion, StopMotion,
};
use wheelleg_runtime::robot::RobotGeometry;

/// Capacity of the controller's transmit queue: two ticks' worth of start-up frames.
pub const TX_QUEUE_FRAMES: usize = 64;

/// Settings of the closed loop.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RigConfig {
    /// Control rate, step duration and limits.
    pub motion: MotionConfig,
    /// Physics step of the simulated axes (in-process bus only).
    pub physics_dt_us: u64,
    /// Hold time after each step's setpoints, so the motors settle before the pose is read.
    pub settle_s: f32,
    /// An axis not heard from for this long is silent.
    pub health_timeout_us: u64,
    /// Fault injection on the in-process bus.
    pub faults: Faults,
    /// Node map and calibration.
    pub map: NodeMap,
}

impl Default for RigConfig {
    /// 100 Hz control, 1 kHz physics, 0.2 s settling, 50 ms silence timeout (5 missed encoder
    /// estimates at 100 Hz: one lost frame is noise, five in a row is a dead node).
    fn default() -> Self {
        RigConfig {
            motion: MotionConfig::default(),
            physics_dt_us: 1_000,
            settle_s: 0.2,
            health_timeout_us: 50_000,
            faults: Faults::NONE,
            map: NodeMap::NOMINAL,
        }
    }
}

/// Why the rig cannot go on.
#[derive(Debug)]
pub enum RigError {
    /// The step is impossible or too fast.
    Motion(MotionError),
    /// A leg configuration has no IK solution.
    Ik(IkError),
    /// The base kinematics refused a measured value.
    Base(BaseError),
    /// Frames could not be queued.
    Can(CanError),
    /// The transport failed.
    Bus(BusError),
    /// Writing the traffic log failed.
    Log(std::io::Error),
    /// The axes did not all reach closed loop at start-up.
    StartupFailed(Health),
}

impl std::fmt::Display for RigError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "{self:?}")
    }
}

impl std::error::Error for RigError {}

macro_rules! from_error {
    ($($variant:ident($t:ty)),*) => {$(
        impl From<$t> for RigError {
            fn from(e: $t) -> Self {
                RigError::$variant(e)
            }
        }
    )*};
}
from_error!(
    Motion(MotionError),
    Ik(IkError),
    Base(BaseError),
    Can(CanError),
    Bus(BusError),
    Log(std::io::Error)
);

/// Why the controller went into safe stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopReason {
    /// These axes were not heard from within the timeout.
    Silent(wheelleg_runtime::can::host::AxisSet),
    /// These axes reported errors (for example `WATCHDOG_TIMER_EXPIRED`).
    AxisError(wheelleg_runtime::can::host::AxisSet),
}

/// A fault the rig injects by itself when simulated time reaches a chosen instant, so that a
/// test can hit the middle of a motion rather than the gap between two steps.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TimedFault {
    /// The axis stops transmitting for good (it still obeys commands): a broken transmitter.
    Silence(Axis),
    /// The axis drops off the bus for good: it neither transmits nor receives (a cut cable, a
    /// node in bus-off), so it runs on its last setpoint until its watchdog idles it.
    Disconnect(Axis),
    /// The controller's transmit path hangs (it keeps listening), as [`Rig::pause_commands`].
    HangCommands,
}

/// What one step achieved, beside what it should have.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepReport {
    /// Ideal pose change (in the frame of the step's start pose).
    pub ideal_pose: Isometry2<f32>,
    /// Measured pose change, by odometry from the measured wheel speeds.
    pub achieved_pose: Isometry2<f32>,
    /// Ideal leg configuration at the end of the step.
    pub ideal_legs: LegConfig,
    /// Measured leg configuration at the end of the step (forward kinematics).
    pub achieved_legs: LegConfig,
    /// Set if the controller stopped the robot during the step.
    pub stopped: Option<StopReason>,
}

impl StepReport {
    /// Distance between ideal and achieved position.
    pub fn position_error_m(&self) -> f32 {
        (self.ideal_pose.inverse() * self.achieved_pose)
            .translation
            .vector
            .norm()
    }

    /// Angle between ideal and achieved heading.
    pub fn yaw_error_rad(&self) -> f32 {
        (self.ideal_pose.inverse() * self.achieved_pose)
            .rotation
            .angle()
            .abs()
    }
}

/// Traffic the controller put on or heard from the bus since the rig was made: every frame of
/// the robot's bus passes the controller, so this is the bus's whole traffic.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct TrafficCounts {
    /// Frames sent and received.
    pub frames: u64,
    /// Their bits on the wire without stuff bits (including intermission).
    pub bits_nominal: u64,
    /// Their bits on the wire with worst-case stuffing.
    pub bits_worst_case: u64,
}

impl TrafficCounts {
    fn count(&mut self, frame: &CanFrame) {
        use embedded_can::Frame;
        // A remote frame carries a DLC but no data bits.
        let data_len = if frame.is_remote_frame() {
            0
        } else {
            frame.data().len() as u8
        };
        let bits = frame_bits(data_len);
        self.frames += 1;
        self.bits_nominal += u64::from(bits.nominal);
        self.bits_worst_case += u64::from(bits.worst_case);
    }
}

/// Measured bus load: traffic over elapsed time, as a fraction of the bus's capacity.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeasuredBusLoad {
    /// Frames per second.
    pub frames_per_s: f64,
    /// Fraction of capacity used, without stuff bits.
    pub nominal: f64,
    /// Fraction of capacity used, with worst-case stuffing.
    pub worst_case: f64,
}

/// The controller and, on an in-process bus, the simulated motors, stepped together.
pub struct Rig {
    geometry: RobotGeometry,
    config: RigConfig,
    commander: Commander,
    tracker: FeedbackTracker,
    tx: TxQueue<CanFrame, TX_QUEUE_FRAMES>,
    bus: InProcessBus,
    host: Box<dyn Transport>,
    firmware: Firmware,
    /// The simulated axes' port on the in-process bus; `None` when the motors are elsewhere
    /// (another process on SocketCAN, or real hardware) and time is real.
    firmware_port: Option<Port>,
    /// Wall-clock origin when time is real.
    realtime_origin: Option<std::time::Instant>,
    now_us: u64,
    odometry: Odometry,
    legs: LegConfig,
    stopped: Option<StopReason>,
    stopped_at_us: Option<u64>,
    /// The step being executed, while its setpoints are sent: what a stop decelerates along.
    active: Option<StepMotion>,
    /// The controlled stop in progress, if the stop came in the middle of a step.
    stopping: Option<StopMotion>,
    /// What the safe stop holds once the robot has come to rest; `None` if the stop had
    /// nothing planned to rest on (then the measured joints are held).
    rest: Option<Setpoint>,
    /// The last setpoint sent: where a stop outside a known step rests.
    last_sent: Option<Setpoint>,
    commands_paused: bool,
    log: Option<CandumpWriter<Box<dyn Write>>>,
    traffic: TrafficCounts,
    /// Faults still to inject, (time, fault).
    scheduled: Vec<(u64, TimedFault)>,
    /// Pose integrated from the simulated wheels' true speeds (in-process only).
    true_odometry: Odometry,
    /// Ground truth at the end of every control tick, while recording ([`Rig::record_truth`]).
    truth: Option<Vec<TrueSample>>,
}

/// Where the robot really was at one instant (in-process bus only): what a fault test checks
/// for collisions at every control tick, not only after each step.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrueSample {
    /// Simulated time.
    pub at_us: u64,
    /// [`Rig::true_pose`] then.
    pub pose: Isometry2<f32>,
    /// [`Rig::true_legs`] then.
    pub legs: LegConfig,
}

impl Rig {
    /// A rig on an in-process bus, legs at `start`, motors idle; call [`Rig::start_up`] next.
    pub fn in_process(
        geometry: &RobotGeometry,
        config: RigConfig,
        start: LegConfig,
    ) -> Result<Rig, RigError> {
        let bus = InProcessBus::new(config.faults);
        let host = bus.port();
        let firmware_port = bus.port();
        Ok(Rig {
            geometry: *geometry,
            config,
            commander: Commander::new(config.map),
            tracker: FeedbackTracker::new(config.map),
            tx: TxQueue::new(),
            firmware: Firmware::for_robot(geometry, &config.map, start)?,
            bus,
            host: Box::new(host),
            firmware_port: Some(firmware_port),
            realtime_origin: None,
            now_us: 0,
            odometry: Odometry::default(),
            legs: start,
            stopped: None,
            stopped_at_us: None,
            active: None,
            stopping: None,
            rest: None,
            last_sent: None,
            commands_paused: false,
            log: None,
            traffic: TrafficCounts::default(),
            scheduled: Vec::new(),
            true_odometry: Odometry::default(),
            truth: None,
        })
    }

    /// A rig whose motors are on `host`'s bus elsewhere (for example `firmware_sim --can vcan0`
    /// in another process, or real ODrives): no local simulation, control ticks paced by the
    /// wall clock. The remote axes must start with the legs at `start`.
    pub fn remote(
        geometry: &RobotGeometry,
        config: RigConfig,
        start: LegConfig,
        host: Box<dyn Transport>,
    ) -> Result<Rig, RigError> {
        geometry.leg_ik(start)?;
        Ok(Rig {
            geometry: *geometry,
            config,
            commander: Commander::new(config.map),
            tracker: FeedbackTracker::new(config.map),
            tx: TxQueue::new(),
            firmware: Firmware::new(Vec::new()),
            bus: InProcessBus::new(Faults::NONE),
            host,
            firmware_port: None,
            realtime_origin: Some(std::time::Instant::now()),
            now_us: 0,
            odometry: Odometry::default(),
            legs: start,
            stopped: None,
            stopped_at_us: None,
            active: None,
            stopping: None,
            rest: None,
            last_sent: None,
            commands_paused: false,
            log: None,
            traffic: TrafficCounts::default(),
            scheduled: Vec::new(),
            true_odometry: Odometry::default(),
            truth: None,
        })
    }

    /// Logs every frame the controller sends or receives, in `candump -L` format.
    pub fn log_to(&mut self, writer: CandumpWriter<Box<dyn Write>>) {
        self.log = Some(writer);
    }

    /// Stops logging and returns the writer (flushed).
    pub fn take_log(&mut self) -> Result<Option<Box<dyn Write>>, RigError> {
        match self.log.take() {
            Some(w) => Ok(Some(w.finish()?)),
            None => Ok(None),
        }
    }

    /// Simulated time.
    pub fn now_us(&self) -> u64 {
        self.now_us
    }

    /// The controller's view of the bus.
    pub fn feedback(&self) -> &FeedbackTracker {
        &self.tracker
    }

    /// The simulated motors (none for a [`Rig::remote`] rig).
    pub fn firmware(&self) -> &Firmware {
        &self.firmware
    }

    /// The simulated motors, for fault injection.
    pub fn firmware_mut(&mut self) -> &mut Firmware {
        &mut self.firmware
    }

    /// The in-process bus (fault counters, changing faults).
    pub fn bus(&self) -> &InProcessBus {
        &self.bus
    }

    /// Pose by odometry since start-up.
    pub fn pose(&self) -> Isometry2<f32> {
        self.odometry.pose
    }

    /// Commanded leg configuration.
    pub fn legs(&self) -> LegConfig {
        self.legs
    }

    /// Everything on the bus so far.
    pub fn traffic(&self) -> TrafficCounts {
        self.traffic
    }

    /// The bus load measured since the rig was made, at `bitrate_bps` (1 Mbit/s for this
    /// robot); `None` before any time has passed.
    pub fn bus_load(&self, bitrate_bps: f64) -> Option<MeasuredBusLoad> {
        if self.now_us == 0 || bitrate_bps <= 0.0 {
            return None;
        }
        let elapsed_s = self.now_us as f64 * 1e-6;
        let capacity_bits = bitrate_bps * elapsed_s;
        Some(MeasuredBusLoad {
            frames_per_s: self.traffic.frames as f64 / elapsed_s,
            nominal: self.traffic.bits_nominal as f64 / capacity_bits,
            worst_case: self.traffic.bits_worst_case as f64 / capacity_bits,
        })
    }

    /// Why the controller stopped the robot, if it did.
    pub fn stopped(&self) -> Option<StopReason> {
        self.stopped
    }

    /// When the controller went into safe stop (simulated time), if it did.
    pub fn stopped_at_us(&self) -> Option<u64> {
        self.stopped_at_us
    }

    /// Injects `fault` at the first physics step at or after `at_us` (in-process bus only: a
    /// remote rig has no physics steps, and its motors are out of reach).
    pub fn schedule(&mut self, at_us: u64, fault: TimedFault) {
        self.scheduled.push((at_us, fault));
    }

    /// Where the robot really is relative to where it started: odometry of the simulated
    /// wheels' true speeds at every physics step, with the true leg track. Unlike
    /// [`Rig::pose`], a silent or lying node cannot corrupt it. Identity for a remote rig.
    pub fn true_pose(&self) -> Isometry2<f32> {
        self.true_odometry.pose
    }

    /// The legs as the simulated joints really are (forward kinematics of their true
    /// positions, averaged over the four legs); `None` for a remote rig.
    pub fn true_legs(&self) -> Option<LegConfig> {
        self.firmware.true_legs(&self.config.map, &self.geometry)
    }

    fn true_wheel_speeds(&self) -> Option<WheelSpeeds> {
        self.firmware.true_wheel_speeds(&self.config.map)
    }

    /// Starts (or stops) recording the ground truth at the end of every control tick; what was
    /// recorded so far is kept until [`Rig::take_truth`].
    pub fn record_truth(&mut self, on: bool) {
        match (on, &self.truth) {
            (true, None) => self.truth = Some(Vec::new()),
            (false, Some(_)) => self.truth = None,
            _ => {}
        }
    }

    /// The ground truth recorded since the last call (empty when not recording).
    pub fn take_truth(&mut self) -> Vec<TrueSample> {
        self.truth.as_mut().map(std::mem::take).unwrap_or_default()
    }

    /// Applies the scheduled faults that are due at `now_us`.
    fn inject_due_faults(&mut self) {
        let now_us = self.now_us;
        let (due, later): (Vec<_>, Vec<_>) = self
            .scheduled
            .drain(..)
            .partition(|(at_us, _)| *at_us <= now_us);
        self.scheduled = later;
        for (_, fault) in due {
            match fault {
                TimedFault::Silence(axis) => {
                    if let Some(motor) = self.firmware.axis_mut(axis) {
                        motor.set_silent(true);
                    }
                }
                TimedFault::Disconnect(axis) => {
                    if let Some(motor) = self.firmware.axis_mut(axis) {
                        motor.set_silent(true);
                        motor.set_deaf(true);
                    }
                }
                TimedFault::HangCommands => self.commands_paused = true,
            }
        }
    }

    /// Simulates a controller whose transmit path hangs: it keeps listening but sends nothing.
    pub fn pause_commands(&mut self, paused: bool) {
        self.commands_paused = paused;
    }

    /// Arms every axis and holds the start pose until all report closed loop.
    pub fn start_up(&mut self) -> Result<(), RigError> {
        self.commander.queue_startup(&mut self.tx)?;
        let hold = Setpoint::hold(&self.geometry, self.legs)?;
        // A few heartbeat periods: enough for every axis to report its new state.
        for _ in 0..30 {
            self.control_tick(&hold, false)?;
        }
        let health = self
            .tracker
            .health(self.now_us, self.config.health_timeout_us);
        let all_armed = Axis::ALL.into_iter().all(|a| {
            self.tracker
                .axis(a)
                .is_some_and(|f| f.axis_state == Some(AxisState::ClosedLoopControl))
        });
        if !health.is_ok() || !all_armed {
            return Err(RigError::StartupFailed(health));
        }
        Ok(())
    }

    fn tick_s(&self) -> f32 {
        1.0 / self.config.motion.control_rate_hz
    }

    /// One control period: read feedback, integrate odometry, check health, send commands
    /// (the setpoint, or the safe stop), then let the motors run until the next tick.
    fn control_tick(&mut self, setpoint: &Setpoint, supervise: bool) -> Result<(), RigError> {
        let tick_us = (1e6 * self.tick_s()) as u64;
        while let Some(frame) = self.host.recv(self.now_us)? {
            if let Some(log) = &mut self.log {
                log.log(self.now_us, &frame)?;
            }
            self.traffic.count(&frame);
            self.tracker.receive(&frame, self.now_us);
        }
        if let (Some(wheels), Some(legs)) = (
            self.tracker.wheel_speeds(),
            self.tracker.leg_config(&self.geometry),
        ) {
            let base = MecanumBase::at(&self.geometry, legs)?;
            self.odometry
                .integrate_wheels(&base, wheels, self.tick_s())?;
        }
        if supervise && self.stopped.is_none() {
            let health = self
                .tracker
                .health(self.now_us, self.config.health_timeout_us);
            if !health.silent.is_empty() {
                self.stopped = Some(StopReason::Silent(health.silent));
            } else if !health.errored.is_empty() {
                self.stopped = Some(StopReason::AxisError(health.errored));
            }
            if self.stopped.is_some() {
                self.stopped_at_us = Some(self.now_us);
                self.begin_stop(setpoint.tick);
            }
        }
        if !self.commands_paused {
            if self.stopped.is_some() {
                match self.next_stop_setpoint() {
                    Some(stop) => self.commander.queue_setpoint(&mut self.tx, &stop)?,
                    None => {
                        self.commander
                            .queue_safe_stop(&mut self.tx, &self.tracker)?;
                    }
                }
            } else {
                self.commander.queue_setpoint(&mut self.tx, setpoint)?;
                self.last_sent = Some(*setpoint);
            }
            while let Some(frame) = self.tx.pop() {
                if let Some(log) = &mut self.log {
                    log.log(self.now_us, &frame)?;
                }
                self.traffic.count(&frame);
                self.host.send(&frame, self.now_us)?;
            }
        }
        let end_us = self.now_us + tick_us;
        match (self.firmware_port.is_some(), self.realtime_origin) {
            (true, _) => {
                let dt_s = self.config.physics_dt_us as f32 * 1e-6;
                while self.now_us < end_us {
                    self.now_us += self.config.physics_dt_us;
                    if let Some(port) = &mut self.firmware_port {
                        self.firmware.run(port, self.now_us, dt_s)?;
                    }
                    if let (Some(legs), Some(wheels)) = (self.true_legs(), self.true_wheel_speeds())
                    {
                        let base = MecanumBase::at(&self.geometry, legs)?;
                        self.true_odometry.integrate_wheels(&base, wheels, dt_s)?;
                    }
                    if !self.scheduled.is_empty() {
                        self.inject_due_faults();
                    }
                }
                if self.truth.is_some() {
                    if let Some(legs) = self.true_legs() {
                        let sample = TrueSample {
                            at_us: self.now_us,
                            pose: self.true_odometry.pose,
                            legs,
                        };
                        self.truth.get_or_insert_with(Vec::new).push(sample);
                    }
                }
            }
            (false, Some(origin)) => {
                let deadline = origin + std::time::Duration::from_micros(end_us);
                if let Some(wait) = deadline.checked_duration_since(std::time::Instant::now()) {
                    std::thread::sleep(wait);
                }
                self.now_us = end_us.max(origin.elapsed().as_micros() as u64);
            }
            (false, None) => self.now_us = end_us,
        }
        Ok(())
    }

    /// Plans the safe stop the moment it is decided, before this tick's setpoint (tick
    /// `tick_in_step` of the active step) goes out: inside a step, decelerate along the step's
    /// path ([`StepMotion::stop_after`]) for every axis, the silent one included (if it still
    /// hears, it follows; if not, its own watchdog idles it); outside a step, rest where the
    /// last setpoint sent put the robot.
    fn begin_stop(&mut self, tick_in_step: u32) {
        self.stopping = self
            .active
            .as_ref()
            .and_then(|motion| motion.stop_after(tick_in_step).ok());
        self.rest = match &self.stopping {
            Some(stop) => Some(stop.rest()),
            None => self.last_sent.map(|sent| Setpoint {
                joint_rates: Default::default(),
                base: wheelleg_runtime::base::BaseVelocity::ZERO,
                wheels: WheelSpeeds::ZERO,
                ..sent
            }),
        };
    }

    /// The safe stop's command for this tick: the next setpoint of the controlled stop, then
    /// its rest pose; `None` when no plan is known (the commander then holds the measured
    /// joints).
    fn next_stop_setpoint(&mut self) -> Option<Setpoint> {
        if let Some(stop) = &mut self.stopping {
            match stop.next() {
                Some(setpoint) => return Some(setpoint),
                None => {
                    self.rest = Some(stop.rest());
                    self.stopping = None;
                }
            }
        }
        self.rest
    }

    /// Where the safe stop holds the legs, once it has been decided.
    pub fn stop_rest(&self) -> Option<Setpoint> {
        self.rest
    }

    /// Sends Estop to every axis (they disarm and latch `ESTOP_REQUESTED`) and keeps the rig in
    /// safe stop; then runs one control period so the motors see it.
    pub fn estop(&mut self) -> Result<(), RigError> {
        self.commander.queue_estop(&mut self.tx)?;
        let health = self
            .tracker
            .health(self.now_us, self.config.health_timeout_us);
        if self.stopped.is_none() {
            self.stopped = Some(StopReason::AxisError(health.errored));
            self.stopped_at_us = Some(self.now_us);
            self.begin_stop(0);
        }
        let hold = Setpoint::hold(&self.geometry, self.legs)?;
        self.control_tick(&hold, false)
    }

    /// Recovers from a stop: Clear_Errors to every axis, then the start-up sequence again. Axes
    /// re-arm where they are, then move (within their speed limits) to the commanded legs; the
    /// odometry pose is kept.
    pub fn recover(&mut self) -> Result<(), RigError> {
        self.commander.queue_clear_errors(&mut self.tx)?;
        self.stopped = None;
        self.stopped_at_us = None;
        self.stopping = None;
        self.rest = None;
        self.commands_paused = false;
        self.start_up()
    }

    /// Runs one supervised control tick with `setpoint` (for callers that drive a
    /// [`StepMotion`] themselves, for example to interrupt it).
    pub fn drive(&mut self, setpoint: &Setpoint) -> Result<(), RigError> {
        self.control_tick(setpoint, true)
    }

    /// Holds the current legs with wheels stopped for `duration_s` (still supervised).
    pub fn hold(&mut self, duration_s: f32) -> Result<(), RigError> {
        let hold = Setpoint::hold(&self.geometry, self.legs)?;
        let ticks = (duration_s / self.tick_s()).round() as u32;
        for _ in 0..ticks {
            self.control_tick(&hold, true)?;
        }
        Ok(())
    }

    /// Executes one decision: its setpoint stream, then `settle_s` of holding the target.
    pub fn step(&mut self, action: Action) -> Result<StepReport, RigError> {
        let motion = StepMotion::plan(&self.geometry, &self.config.motion, self.legs, action)?;
        debug_assert_eq!(
            (motion.displacement().isometry(), motion.target()),
            ideal_step(self.legs, action)
        );
        self.execute(motion)
    }

    /// Executes any planned motion (a lattice step, or a move off the lattice such as backing
    /// out of a step the world refused), then `settle_s` of holding its target. The motion
    /// should start from [`Rig::legs`]; the legs it ends at become the commanded ones.
    pub fn execute(&mut self, mut motion: StepMotion) -> Result<StepReport, RigError> {
        let ideal_pose = motion.displacement().isometry();
        let ideal_legs = motion.target();
        let start_pose = self.odometry.pose;
        self.active = Some(motion.clone());
        let sent = motion.try_for_each(|setpoint| self.control_tick(&setpoint, true));
        self.active = None;
        sent?;
        // A stop in the middle of the step rests on the step's path, not at its target: the
        // commanded legs are where the stop holds them (a later recovery starts from there).
        self.legs = match (&self.stopping, self.rest) {
            (Some(stop), _) => {
                let mut to_the_end = stop.clone();
                to_the_end.by_ref().for_each(drop);
                to_the_end.rest().legs
            }
            (None, Some(rest)) => rest.legs,
            (None, None) => ideal_legs,
        };
        self.hold(self.config.settle_s)?;
        let achieved_legs =
            self.tracker
                .leg_config(&self.geometry)
                .ok_or(RigError::StartupFailed(
                    self.tracker
                        .health(self.now_us, self.config.health_timeout_us),
                ))?;
        Ok(StepReport {
            ideal_pose,
            achieved_pose: start_pose.inverse() * self.odometry.pose,
            ideal_legs,
            achieved_legs,
            stopped: self.stopped,
        })
    }

    /// Motion settings (control rate, step duration, limits).
    pub fn motion_config(&self) -> &MotionConfig {
        &self.config.motion
    }
}

/// Sum of the absolute speeds of the simulated wheel motors, in turns/s: zero when the base is
/// really stopped, whatever the controller believes.
pub fn true_wheel_speed_sum(firmware: &Firmware) -> f32 {
    Axis::ALL
        .into_iter()
        .filter(|a| matches!(a, Axis::Wheel(_)))
        .filter_map(|a| firmware.axis(a))
        .map(|a| a.vel_turns_per_s().abs())
        .sum()
}
