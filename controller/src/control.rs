//! The 100 Hz control loop: each period reads the axes' feedback, integrates odometry,
//! supervises the axes' health and sends one setpoint (16 ODrive CANSimple frames), as the
//! host's rig does (`firmware_sim::rig`), on any CAN peripheral behind `embedded-can`.

use embedded_can::nb::Can;
use embedded_can::Frame;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::base::{MecanumBase, Odometry};

use wheelleg_runtime::can::host::{
    AxisSet, CanError, Commander, FeedbackTracker, RollCall, RollCallRefusal, TxQueue,
    ROLL_CALL_ROUNDS, ROLL_CALL_ROUND_US,
};
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::can::protocol::AxisState;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::{BaseDisplacement, MotionConfig, MotionError, Setpoint, StepMotion};
use wheelleg_runtime::robot::Robot;

/// Transmit queue capacity: Clear_Errors and the start-up sequence (three frames per axis) and
/// one setpoint, the most one period queues (the host's rig's too).
pub const TX_FRAMES: usize = 64;
/// Hold periods of the start-up sequence: a few heartbeat periods, enough for every axis to
/// report closed loop (the rig's count).
pub const STARTUP_TICKS: u32 = 30;
/// Hold time after each step's setpoints, so the motors settle (the rig's 0.2 s).
pub const SETTLE_S: f32 = 0.2;
/// An axis not heard from for this long is silent: 5 missed encoder estimates at 100 Hz.
pub const HEALTH_TIMEOUT_US: u64 = 50_000;

/// An adapter not heard from for this many control periods is lost (its status poll of each
/// period unanswered): 50 ms, the axes' health timeout.
pub const CAN_LINK_TIMEOUT_PERIODS: u32 = 5;

/// What the control loop needs of a board: its CAN peripheral and the control period's clock.
pub trait Board {
    /// The CAN peripheral's frame type.
    type Frame: Frame;
    /// The CAN peripheral (a HAL's bxCAN or FDCAN driver, or QEMU's replay).
    type Can: Can<Frame = Self::Frame>;
    /// The CAN peripheral.
    fn can(&mut self) -> &mut Self::Can;
    /// Waits for the start of the next control period.
    fn wait_for_tick(&mut self);
    /// Whether the link to the CAN bus is lost (an SLCAN adapter that stopped answering; a
    /// peripheral on the board's own bus never is).
    fn link_lost(&self) -> bool {
        false
    }
    /// The period's work is done (its frames are sent): a board that measures the period's
    /// cost reads its clock here.
    fn tick_done(&mut self) {}
}

/// Why the control loop holds the robot in safe stop.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum StopReason {
    /// Axes not heard from within [`HEALTH_TIMEOUT_US`].
    Silent(AxisSet),
    /// Axes whose heartbeat reported errors.
    AxisError(AxisSet),
    /// The CAN link is lost ([`Board::link_lost`]).
    CanLink,
    /// No observation within the observation timeout (the board's program decides).
    ObservationStalled,
    /// Only corrupt observation frames within the observation timeout.
    ObservationCorrupt,
    /// Not every axis reached closed loop at start-up.
    StartupFailed,
    /// A frame could not be queued or sent.
    Control,
}

/// The safe stop: why, and in which control period (counted from the first).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Stop {
    /// Why.
    pub reason: StopReason,
    /// The period.
    pub tick: u32,
}

/// Why the control loop stops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum ControlError {
    /// A frame could not be built or queued.
    Can(CanError),
    /// The step cannot be driven (legs out of reach, too fast).
    Motion(MotionError),
    /// The CAN peripheral refused a frame.
    Bus,
    /// Not every axis reached closed loop at start-up.
    StartupFailed,
    /// The start-up's roll call found a node missing, two devices on one node id, or firmware
    /// the codec does not speak; nothing was armed.
    StartupRefused(RollCallRefusal),
}

impl From<CanError> for ControlError {
    fn from(error: CanError) -> Self {
        ControlError::Can(error)
    }
}

impl From<MotionError> for ControlError {
    fn from(error: MotionError) -> Self {
        ControlError::Motion(error)
    }
}

/// The robot's motion side: commanded legs, odometry, axis feedback and the frames out.
pub struct Control<F: Frame> {
    robot: Robot,
    motion: MotionConfig,
    commander: Commander,
    tracker: FeedbackTracker,
    tx: TxQueue<F, TX_FRAMES>,
    odometry: Odometry,
    legs: LegConfig,
    now_us: u64,
    ticks: u32,
    stop: Option<Stop>,
    /// The last step's start legs and base motion: what backing out of it undoes.
    last_step: Option<(LegConfig, BaseDisplacement)>,
}

impl<F: Frame> Control<F> {
    /// The loop for `robot` (its geometry and CAN node map) with the legs at `start`, motors
    /// idle.
    pub fn new(robot: &Robot, start: LegConfig) -> Control<F> {
        Control {
            robot: *robot,
            motion: MotionConfig::default(),
            commander: Commander::new(robot.can),
            tracker: FeedbackTracker::new(robot.can),
            tx: TxQueue::new(),
            odometry: Odometry::default(),
            legs: start,
            now_us: 0,
            ticks: 0,
            stop: None,
            last_step: None,
        }
    }

    /// The commanded legs.
    pub fn legs(&self) -> LegConfig {
        self.legs
    }

    /// The pose integrated from the wheels' measured speeds.
    pub fn odometry(&self) -> &Odometry {
        &self.odometry
    }

    /// Whether the loop has put the robot in safe stop.
    pub fn stopped(&self) -> bool {
        self.stop.is_some()
    }

    /// The safe stop, once the loop is in it.
    pub fn stop_state(&self) -> Option<Stop> {
        self.stop
    }

    /// Control periods run so far.
    pub fn ticks(&self) -> u32 {
        self.ticks
    }

    /// Puts the robot in safe stop for `reason` from the next period on (the first reason
    /// stays).
    pub fn stop(&mut self, reason: StopReason) {
        if self.stop.is_none() {
            self.stop = Some(Stop {
                reason,
                tick: self.ticks,
            });
        }
    }

    fn tick_s(&self) -> f32 {
        1.0 / self.motion.control_rate_hz
    }

    /// One control period: feedback in, odometry, health, then this period's frames out.
    pub fn tick<B: Board<Frame = F>>(
        &mut self,
        board: &mut B,
        setpoint: &Setpoint,
        supervise: bool,
    ) -> Result<(), ControlError> {
        board.wait_for_tick();
        while let Ok(frame) = board.can().receive() {
            self.tracker.receive(&frame, self.now_us);
        }
        if let (Some(wheels), Some(legs)) = (
            self.tracker.wheel_speeds(),
            self.tracker.leg_config(&self.robot.geometry),
        ) {
            // A measured configuration the base cannot take is skipped, not fatal: the
            // health check below is what stops the robot.
            if let Ok(base) = MecanumBase::at(&self.robot.geometry, legs) {
                let _ = self.odometry.integrate_wheels(&base, wheels, self.tick_s());
            }
        }
        if supervise && self.stop.is_none() {
            if let Some(reason) = self.unhealthy(board.link_lost()) {
                self.stop(reason);
            }
        }
        // The rig slows a step in progress to rest along its own path first; the controller
        // holds the measured joints with the wheels stopped at once (the commander's safe
        // stop), which needs no plan kept across periods.
        if self.stop.is_some() {
            self.commander
                .queue_safe_stop(&mut self.tx, &self.tracker)?;
        } else {
            self.commander.queue_setpoint(&mut self.tx, setpoint)?;
        }
        while let Some(frame) = self.tx.pop() {
            send(board.can(), &frame)?;
        }
        board.tick_done();
        self.now_us += (1.0e6 * self.tick_s()) as u64;
        self.ticks = self.ticks.wrapping_add(1);
        Ok(())
    }

    /// Silent or errored axes (the rig's stop conditions; an axis merely not in closed loop
    /// yet is not one), or a lost CAN link.
    fn unhealthy(&self, link_lost: bool) -> Option<StopReason> {
        let health = self.tracker.health(self.now_us, HEALTH_TIMEOUT_US);
        if link_lost {
            Some(StopReason::CanLink)
        } else if !health.silent.is_empty() {
            Some(StopReason::Silent(health.silent))
        } else if !health.errored.is_empty() {
            Some(StopReason::AxisError(health.errored))
        } else {
            None
        }
    }

    /// One supervised period holding the commanded legs, wheels stopped (or the safe stop).
    pub fn hold<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        let hold = Setpoint::hold(&self.robot.geometry, self.legs)?;
        self.tick(board, &hold, true)
    }

    /// Starts the robot as the host's rig does: the roll call (who is on each node, on what
    /// firmware), Clear_Errors, then arms every axis and holds the start pose until all report
    /// closed loop.
    pub fn start_up<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        self.roll_call(board)?;
        self.commander.queue_clear_errors(&mut self.tx)?;
        self.commander.queue_startup(&mut self.tx)?;
        let hold = Setpoint::hold(&self.robot.geometry, self.legs)?;
        for _ in 0..STARTUP_TICKS {
            self.tick(board, &hold, false)?;
        }
        let armed = Axis::ALL.into_iter().all(|axis| {
            self.tracker
                .axis(axis)
                .is_some_and(|f| f.axis_state == Some(AxisState::ClosedLoopControl))
        });
        if armed && self.unhealthy(board.link_lost()).is_none() {
            Ok(())
        } else {
            Err(ControlError::StartupFailed)
        }
    }

    /// [`ROLL_CALL_ROUNDS`] rounds of Get_Version requests to every node, each
    /// [`ROLL_CALL_ROUND_US`] long, period by period as the rig runs them; nothing but the
    /// requests is sent, so nothing moves. A node missing, two devices on one node id, or
    /// firmware the codec does not speak stops the start-up.
    fn roll_call<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        let tick_us = ((1.0e6 * self.tick_s()) as u64).max(1);
        let ticks_per_round = ROLL_CALL_ROUND_US.div_ceil(tick_us).max(1);
        let mut roll_call = RollCall::new(self.robot.can);
        for _ in 0..ROLL_CALL_ROUNDS {
            for tick in 0..ticks_per_round {
                board.wait_for_tick();
                while let Ok(frame) = board.can().receive() {
                    self.tracker.receive(&frame, self.now_us);
                    roll_call.receive(&frame);
                }
                if tick == 0 {
                    roll_call.begin_round();
                    self.commander.queue_version_requests(&mut self.tx)?;
                }
                while let Some(frame) = self.tx.pop() {
                    send(board.can(), &frame)?;
                }
                board.tick_done();
                self.now_us += tick_us;
                self.ticks = self.ticks.wrapping_add(1);
            }
        }
        roll_call.verdict().map_err(ControlError::StartupRefused)
    }

    /// Drives one decision: its setpoint stream, then [`SETTLE_S`] holding its target. An
    /// action the legs cannot take is not sent (`Err`, nothing queued), as on the host. A safe
    /// stop ends the step at once (the periods after it hold the robot).
    pub fn step<B: Board<Frame = F>>(
        &mut self,
        board: &mut B,
        action: Action,
    ) -> Result<(), ControlError> {
        let motion = StepMotion::plan(&self.robot, &self.motion, self.legs, action)?;
        self.drive(board, motion)
    }

    /// Backs out of the last step along its inverse motion, to its start legs (the world
    /// refused the step), as the host's closed loop does; then [`SETTLE_S`] holding them.
    pub fn retreat<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        let Some((start, displacement)) = self.last_step else {
            return Ok(());
        };
        let back = displacement.isometry().inverse();
        let back = BaseDisplacement {
            dx_m: back.translation.x,
            dy_m: back.translation.y,
            dyaw_rad: back.rotation.angle(),
        };
        let motion =
            StepMotion::plan_between(&self.robot.geometry, &self.motion, self.legs, start, back)?;
        self.drive(board, motion)
    }

    fn drive<B: Board<Frame = F>>(
        &mut self,
        board: &mut B,
        motion: StepMotion,
    ) -> Result<(), ControlError> {
        let target = motion.target();
        self.last_step = Some((self.legs, motion.displacement()));
        for setpoint in motion {
            self.tick(board, &setpoint, true)?;
            if self.stopped() {
                return Ok(());
            }
        }
        self.legs = target;
        let hold = Setpoint::hold(&self.robot.geometry, self.legs)?;
        let ticks = libm_round(SETTLE_S / self.tick_s());
        for _ in 0..ticks {
            self.tick(board, &hold, true)?;
        }
        Ok(())
    }

    /// The measured legs, if every joint has reported.
    pub fn measured_legs(&self) -> Option<LegConfig> {
        self.tracker.leg_config(&self.robot.geometry)
    }
}

/// Rounds a small positive count of periods (no `std` `round`).
fn libm_round(periods: f32) -> u32 {
    (periods + 0.5) as u32
}

/// Sends one frame, waiting while the peripheral's mailboxes are full.
fn send<C: Can>(can: &mut C, frame: &C::Frame) -> Result<(), ControlError> {
    loop {
        match can.transmit(frame) {
            Ok(_) => return Ok(()),
            Err(nb::Error::WouldBlock) => continue,
            Err(nb::Error::Other(_)) => return Err(ControlError::Bus),
        }
    }
}
