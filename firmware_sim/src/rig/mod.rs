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
//! Safety: every control tick the controller checks its
//! [`Health`](wheelleg_runtime::can::host::Health). A node silent for longer than
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
//!
//! Start-up ([`Rig::start_up`]) first asks every node of the map who it is (Get_Version) and
//! refuses to move on a bus with a node missing, two devices on one node id or firmware the
//! codec does not speak ([`RigError::StartupRefused`]); then Clear_Errors, then arming.
//!
//! The in-process axes' watchdog is the rig's to configure, as real ODrives are configured
//! before use: [`RigConfig::watchdog_timeout_us`] (100 ms by default) idles every axis that
//! goes that long without a setpoint once armed, which the fault tests rely on.
//!
//! Pieces: the rig and its control tick here; settings, errors and reports in `config.rs`;
//! start-up in `start_up.rs`; ground truth and injected faults in `faults.rs`; the safe stop in
//! `safe_stop.rs`.

use crate::bus::{Faults, InProcessBus, Port, Transport};
use crate::candump::CandumpWriter;
use crate::firmware::Firmware;
use nalgebra::Isometry2;
use std::io::Write;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::base::{MecanumBase, Odometry};
use wheelleg_runtime::can::host::{Commander, FeedbackTracker, RollCall, TxQueue};
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::{ideal_step, MotionConfig, Setpoint, StepMotion, StopMotion};
use wheelleg_runtime::robot::Robot;

mod config;
mod faults;
mod safe_stop;
mod start_up;

pub use config::{
    MeasuredBusLoad, RigConfig, RigError, StepReport, StopReason, TimedFault, TrafficCounts,
};
pub use faults::TrueSample;
pub use start_up::STARTUP_TICKS;
pub use wheelleg_runtime::can::host::ROLL_CALL_ROUND_US;

/// Capacity of the controller's transmit queue: two ticks' worth of start-up frames.
pub const TX_QUEUE_FRAMES: usize = 64;

/// The controller and, on an in-process bus, the simulated motors, stepped together.
pub struct Rig {
    /// The robot driven: its geometry, action lattice and node map.
    robot: Robot,
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

impl Rig {
    /// A rig for `robot` on an in-process bus, legs at `start`, motors idle; call
    /// [`Rig::start_up`] next.
    pub fn in_process(robot: &Robot, config: RigConfig, start: LegConfig) -> Result<Rig, RigError> {
        let bus = InProcessBus::new(config.faults);
        let host = bus.port();
        let firmware_port = bus.port();
        let mut firmware = Firmware::for_robot(&robot.geometry, &robot.can, start)?;
        firmware.set_watchdog_timeout_us(config.watchdog_timeout_us);
        Ok(Rig {
            robot: *robot,
            config,
            commander: Commander::new(robot.can),
            tracker: FeedbackTracker::new(robot.can),
            tx: TxQueue::new(),
            firmware,
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
    /// wall clock. The remote axes must start with the legs at `start`, and their watchdog is
    /// their own configuration (`firmware_sim --watchdog-ms`, an ODrive's saved
    /// `watchdog_timeout`): [`RigConfig::watchdog_timeout_us`] cannot reach them.
    pub fn remote(
        robot: &Robot,
        config: RigConfig,
        start: LegConfig,
        host: Box<dyn Transport>,
    ) -> Result<Rig, RigError> {
        robot.geometry.leg_ik(start)?;
        Ok(Rig {
            robot: *robot,
            config,
            commander: Commander::new(robot.can),
            tracker: FeedbackTracker::new(robot.can),
            tx: TxQueue::new(),
            firmware: Firmware::new(Vec::new(), robot.can),
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

    fn tick_s(&self) -> f32 {
        1.0 / self.config.motion.control_rate_hz
    }

    /// One control period: read feedback, integrate odometry, check health, send commands
    /// (the setpoint, or the safe stop), then let the motors run until the next tick.
    fn control_tick(&mut self, setpoint: &Setpoint, supervise: bool) -> Result<(), RigError> {
        self.read_feedback(None)?;
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
            self.flush_tx()?;
        }
        self.advance_tick()
    }

    /// Takes in every frame that has arrived (into the tracker and, during the start-up roll
    /// call, into `roll_call` too) and integrates odometry over the tick.
    fn read_feedback(&mut self, mut roll_call: Option<&mut RollCall>) -> Result<(), RigError> {
        while let Some(frame) = self.host.recv(self.now_us)? {
            if let Some(log) = &mut self.log {
                log.log(self.now_us, &frame)?;
            }
            self.traffic.count(&frame);
            self.tracker.receive(&frame, self.now_us);
            if let Some(roll_call) = roll_call.as_deref_mut() {
                roll_call.receive(&frame);
            }
        }
        if let (Some(wheels), Some(legs)) = (
            self.tracker.wheel_speeds(),
            self.tracker.leg_config(&self.robot.geometry),
        ) {
            let base = MecanumBase::at(&self.robot.geometry, legs)?;
            self.odometry
                .integrate_wheels(&base, wheels, self.tick_s())?;
        }
        Ok(())
    }

    /// Sends everything queued.
    fn flush_tx(&mut self) -> Result<(), RigError> {
        while let Some(frame) = self.tx.pop() {
            if let Some(log) = &mut self.log {
                log.log(self.now_us, &frame)?;
            }
            self.traffic.count(&frame);
            self.host.send(&frame, self.now_us)?;
        }
        Ok(())
    }

    /// Lets the motors run until the next control tick: simulated physics on the in-process
    /// bus, the wall clock otherwise.
    fn advance_tick(&mut self) -> Result<(), RigError> {
        let tick_us = (1e6 * self.tick_s()) as u64;
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
                        let base = MecanumBase::at(&self.robot.geometry, legs)?;
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

    /// Runs one supervised control tick with `setpoint` (for callers that drive a
    /// [`StepMotion`] themselves, for example to interrupt it).
    pub fn drive(&mut self, setpoint: &Setpoint) -> Result<(), RigError> {
        self.control_tick(setpoint, true)
    }

    /// Holds the current legs with wheels stopped for `duration_s` (still supervised).
    pub fn hold(&mut self, duration_s: f32) -> Result<(), RigError> {
        let hold = Setpoint::hold(&self.robot.geometry, self.legs)?;
        let ticks = (duration_s / self.tick_s()).round() as u32;
        for _ in 0..ticks {
            self.control_tick(&hold, true)?;
        }
        Ok(())
    }

    /// Executes one decision: its setpoint stream, then `settle_s` of holding the target.
    pub fn step(&mut self, action: Action) -> Result<StepReport, RigError> {
        let motion = StepMotion::plan(&self.robot, &self.config.motion, self.legs, action)?;
        debug_assert_eq!(
            (motion.displacement().isometry(), motion.target()),
            ideal_step(self.legs, action, &self.robot.actions)
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
                .leg_config(&self.robot.geometry)
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
