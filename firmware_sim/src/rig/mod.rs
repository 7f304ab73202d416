//! The closed loop without a policy: the robot's control loop -> CAN -> simulated axes -> CAN
//! -> feedback -> forward kinematics.
//!
//! A [`Rig`] is the robot's control loop, the one the firmware runs
//! ([`wheelleg_control::Control`]), on the host's board ([`RigBoard`]: a bus transport with the
//! 16 simulated axes on it when the bus is in-process). [`Rig::step`] executes one decision and
//! reports the achieved pose (odometry from the *measured* wheel speeds) and leg configuration
//! (forward kinematics of the *measured* joint angles) beside the ideal ones. Whatever a test or
//! the demo does to the loop, it does through here, so the policy's world and the motors' world
//! meet in one place.
//!
//! Safety is the control loop's: every period it checks the axes' health; a node silent for
//! longer than `health_timeout_us`, or reporting an error, puts the robot in safe stop for good
//! ([`StopReason`]). Inside a step the robot decelerates along the step's own path (all 16 axes,
//! the silent one included, ramp the step's progress rate to zero over `MotionConfig::stop_s`)
//! and then holds the pose reached ([`Rig::stop_rest`]); between steps it holds the last pose
//! commanded (docs/can-protocol.md, "Safety").
//!
//! For fault tests on the in-process bus the board also keeps the *ground truth* the loop
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
//! Pieces: the rig here; the host's board (transport, physics, log, ground truth, injected
//! faults) in `board.rs`; settings, errors and reports (the ground truth's too) in
//! `config.rs`.

use crate::bus::{InProcessBus, Transport};
use crate::candump::CandumpWriter;
use crate::firmware::Firmware;
use nalgebra::Isometry2;
use std::io::Write;
use wheelleg_control::{Control, ControlError, ControlSettings, Finished};
use wheelleg_runtime::action::Action;
use wheelleg_runtime::can::host::FeedbackTracker;
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::{ideal_step, MotionConfig, Setpoint, StepMotion};
use wheelleg_runtime::robot::Robot;

mod board;
mod config;

pub use board::RigBoard;
pub use config::{
    MeasuredBusLoad, RigConfig, RigError, StepReport, StopReason, TimedFault, TrafficCounts,
    TrueSample,
};
pub use wheelleg_control::STARTUP_TICKS;
pub use wheelleg_runtime::can::host::ROLL_CALL_ROUND_US;

/// The robot's control loop on the host's board, stepped together.
pub struct Rig {
    config: RigConfig,
    control: Control<CanFrame>,
    board: RigBoard,
}

impl Rig {
    /// A rig for `robot` on an in-process bus, legs at `start`, motors idle; call
    /// [`Rig::start_up`] next.
    pub fn in_process(robot: &Robot, config: RigConfig, start: LegConfig) -> Result<Rig, RigError> {
        let board = RigBoard::in_process(
            robot,
            start,
            config.faults,
            config.watchdog_timeout_us,
            period_us(&config),
            config.physics_dt_us,
        )?;
        Ok(Rig::on(robot, config, start, board))
    }

    /// A rig whose motors are on `host`'s bus elsewhere (for example `firmware_sim --can vcan0`
    /// in another process, or real ODrives): no local simulation, control periods paced by
    /// the wall clock. The remote axes must start with the legs at `start`, and their watchdog
    /// is their own configuration (`firmware_sim --watchdog-ms`, an ODrive's saved
    /// `watchdog_timeout`): [`RigConfig::watchdog_timeout_us`] cannot reach them.
    pub fn remote(
        robot: &Robot,
        config: RigConfig,
        start: LegConfig,
        host: Box<dyn Transport>,
    ) -> Result<Rig, RigError> {
        robot.geometry.leg_ik(start)?;
        let board = RigBoard::remote(robot, host, period_us(&config));
        Ok(Rig::on(robot, config, start, board))
    }

    fn on(robot: &Robot, config: RigConfig, start: LegConfig, board: RigBoard) -> Rig {
        let settings = ControlSettings {
            motion: config.motion,
            settle_s: config.settle_s,
            health_timeout_us: config.health_timeout_us,
        };
        Rig {
            config,
            control: Control::with_settings(robot, start, settings),
            board,
        }
    }

    /// The control loop.
    pub fn control(&self) -> &Control<CanFrame> {
        &self.control
    }

    /// The host's board: transport, simulated axes, log, ground truth, injected faults.
    pub fn board(&self) -> &RigBoard {
        &self.board
    }

    /// The host's board, to inject faults.
    pub fn board_mut(&mut self) -> &mut RigBoard {
        &mut self.board
    }

    /// Logs every frame the controller sends or receives, in `candump -L` format.
    pub fn log_to(&mut self, writer: CandumpWriter<Box<dyn Write>>) {
        self.board.log_to(writer);
    }

    /// Stops logging and returns the writer (flushed).
    pub fn take_log(&mut self) -> Result<Option<Box<dyn Write>>, RigError> {
        self.board.take_log()
    }

    /// Simulated time.
    pub fn now_us(&self) -> u64 {
        self.board.now_us()
    }

    /// The controller's view of the bus.
    pub fn feedback(&self) -> &FeedbackTracker {
        self.control.feedback()
    }

    /// The simulated motors (none for a [`Rig::remote`] rig).
    pub fn firmware(&self) -> &Firmware {
        self.board.firmware()
    }

    /// The simulated motors, for fault injection.
    pub fn firmware_mut(&mut self) -> &mut Firmware {
        self.board.firmware_mut()
    }

    /// The in-process bus (fault counters, changing faults).
    pub fn bus(&self) -> &InProcessBus {
        self.board.bus()
    }

    /// Pose by odometry since start-up.
    pub fn pose(&self) -> Isometry2<f32> {
        self.control.odometry().pose
    }

    /// Commanded leg configuration.
    pub fn legs(&self) -> LegConfig {
        self.control.legs()
    }

    /// Everything on the bus so far.
    pub fn traffic(&self) -> TrafficCounts {
        self.board.traffic()
    }

    /// The bus load measured since the rig was made, at `bitrate_bps` (1 Mbit/s for this
    /// robot); `None` before any time has passed.
    pub fn bus_load(&self, bitrate_bps: f64) -> Option<MeasuredBusLoad> {
        let now_us = self.now_us();
        if now_us == 0 || bitrate_bps <= 0.0 {
            return None;
        }
        let traffic = self.traffic();
        let elapsed_s = now_us as f64 * 1e-6;
        let capacity_bits = bitrate_bps * elapsed_s;
        Some(MeasuredBusLoad {
            frames_per_s: traffic.frames as f64 / elapsed_s,
            nominal: traffic.bits_nominal as f64 / capacity_bits,
            worst_case: traffic.bits_worst_case as f64 / capacity_bits,
        })
    }

    /// Why the controller stopped the robot, if it did.
    pub fn stopped(&self) -> Option<StopReason> {
        self.control.stop_state().map(|stop| stop.reason)
    }

    /// When the controller went into safe stop (the start of the period it decided in), if
    /// it did.
    pub fn stopped_at_us(&self) -> Option<u64> {
        let period_us = period_us(&self.config);
        self.control
            .stop_state()
            .map(|stop| u64::from(stop.tick) * period_us)
    }

    /// Where the safe stop holds the legs, once it has been decided.
    pub fn stop_rest(&self) -> Option<Setpoint> {
        self.control.stop_rest()
    }

    /// One period of the loop's activity (holding, when there is none); the board's transport
    /// or log error, if one came.
    fn period(&mut self) -> Result<Option<Finished>, RigError> {
        let finished = self.control.period(&mut self.board);
        match self.board.take_error() {
            Some(error) => Err(error),
            None => Ok(finished),
        }
    }

    /// Runs periods until the activity in progress ends.
    fn finish(&mut self) -> Result<(), RigError> {
        while self.control.busy() {
            if let Some(finished) = self.period()? {
                return finished.result().map_err(|error| self.rig_error(error));
            }
        }
        Ok(())
    }

    /// Why the loop failed, as the rig reports it: the transport's own error where there is
    /// one.
    fn rig_error(&mut self, error: ControlError) -> RigError {
        if let Some(error) = self.board.take_error() {
            return error;
        }
        match error {
            ControlError::Can(error) => RigError::Can(error),
            ControlError::Motion(error) => RigError::Motion(error),
            ControlError::Bus => RigError::Refused,
            ControlError::StartupFailed => RigError::StartupFailed(self.control.health()),
            ControlError::StartupRefused(refusal) => RigError::StartupRefused(refusal),
        }
    }

    /// Starts the robot: asks every node of the map for its version and refuses to go on if a
    /// node is missing, two devices share a node id, or a node runs firmware the codec does not
    /// speak ([`RigError::StartupRefused`], naming the node); then clears every axis's latched
    /// errors, arms every axis and holds the start pose until all report closed loop.
    ///
    /// A bus on which nothing at all is heard is [`RigError::StartupFailed`] (every node
    /// silent): no motor controller is there to refuse.
    pub fn start_up(&mut self) -> Result<(), RigError> {
        self.control.begin_start_up();
        self.finish()
    }

    /// Runs one supervised control period with `setpoint` (for callers that drive a
    /// [`StepMotion`] themselves, for example to interrupt it).
    pub fn drive(&mut self, setpoint: &Setpoint) -> Result<(), RigError> {
        let sent = self.control.tick(&mut self.board, setpoint, true);
        if let Some(error) = self.board.take_error() {
            return Err(error);
        }
        sent.map_err(|error| self.rig_error(error))
    }

    /// Holds the current legs with wheels stopped for `duration_s` (still supervised; in safe
    /// stop, the stop's setpoints).
    pub fn hold(&mut self, duration_s: f32) -> Result<(), RigError> {
        let ticks = (duration_s * self.config.motion.control_rate_hz).round() as u32;
        for _ in 0..ticks {
            self.period()?;
        }
        Ok(())
    }

    /// Executes one decision: its setpoint stream, then `settle_s` of holding the target.
    pub fn step(&mut self, action: Action) -> Result<StepReport, RigError> {
        let robot = self.control.robot();
        let motion = StepMotion::plan(&robot, &self.config.motion, self.legs(), action)?;
        debug_assert_eq!(
            (motion.displacement().isometry(), motion.target()),
            ideal_step(self.legs(), action, &robot.actions)
        );
        self.execute(motion)
    }

    /// Executes any planned motion (a lattice step, or a move off the lattice such as backing
    /// out of a step the world refused), then `settle_s` of holding its target. The motion
    /// should start from [`Rig::legs`]; the legs it ends at become the commanded ones. A safe
    /// stop in the middle of it decelerates along its path, and the report comes once the
    /// robot rests there and has settled.
    pub fn execute(&mut self, motion: StepMotion) -> Result<StepReport, RigError> {
        let ideal_pose = motion.displacement().isometry();
        let ideal_legs = motion.target();
        let start_pose = self.pose();
        self.control.begin_motion(motion);
        self.finish()?;
        if self.control.stopped() {
            while !self.control.stop_at_rest() {
                self.period()?;
            }
            self.hold(self.config.settle_s)?;
        }
        let achieved_legs = self
            .control
            .measured_legs()
            .ok_or_else(|| RigError::StartupFailed(self.control.health()))?;
        Ok(StepReport {
            ideal_pose,
            achieved_pose: start_pose.inverse() * self.pose(),
            ideal_legs,
            achieved_legs,
            stopped: self.stopped(),
        })
    }

    /// Sends Estop to every axis (they disarm and latch `ESTOP_REQUESTED`) and keeps the rig in
    /// safe stop ([`StopReason::Estop`]); the motors see it in the same period.
    pub fn estop(&mut self) -> Result<(), RigError> {
        let sent = self.control.estop(&mut self.board);
        if let Some(error) = self.board.take_error() {
            return Err(error);
        }
        sent.map_err(|error| self.rig_error(error))
    }

    /// Recovers from a stop: the start-up sequence again ([`Rig::start_up`]: roll call,
    /// Clear_Errors to every axis, arming), with the transmit path working again. Axes still
    /// armed get no setpoint during the roll call, so their watchdog may idle them first (the
    /// robot is at rest); all re-arm where they are, then move (within their speed limits) to
    /// the commanded legs; the odometry pose is kept.
    pub fn recover(&mut self) -> Result<(), RigError> {
        self.board.pause_commands(false);
        self.start_up()
    }

    /// Injects `fault` at the first physics step at or after `at_us` (in-process bus only: a
    /// remote rig has no physics steps, and its motors are out of reach).
    pub fn schedule(&mut self, at_us: u64, fault: TimedFault) {
        self.board.schedule(at_us, fault);
    }

    /// Simulates a controller whose transmit path hangs: it keeps listening but sends nothing.
    pub fn pause_commands(&mut self, paused: bool) {
        self.board.pause_commands(paused);
    }

    /// Where the robot really is relative to where it started: odometry of the simulated
    /// wheels' true speeds at every physics step, with the true leg track. Unlike
    /// [`Rig::pose`], a silent or lying node cannot corrupt it. Identity for a remote rig.
    pub fn true_pose(&self) -> Isometry2<f32> {
        self.board.true_pose()
    }

    /// The legs as the simulated joints really are (forward kinematics of their true
    /// positions, averaged over the four legs); `None` for a remote rig.
    pub fn true_legs(&self) -> Option<LegConfig> {
        self.board.true_legs()
    }

    /// Starts (or stops) recording the ground truth at the end of every control period; what
    /// was recorded so far is kept until [`Rig::take_truth`].
    pub fn record_truth(&mut self, on: bool) {
        self.board.record_truth(on);
    }

    /// The ground truth recorded since the last call (empty when not recording).
    pub fn take_truth(&mut self) -> Vec<TrueSample> {
        self.board.take_truth()
    }

    /// Motion settings (control rate, step duration, limits).
    pub fn motion_config(&self) -> &MotionConfig {
        &self.config.motion
    }
}

/// The control period, in whole microseconds.
fn period_us(config: &RigConfig) -> u64 {
    (1e6 * (1.0 / config.motion.control_rate_hz)) as u64
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
