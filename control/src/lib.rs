//! The wheel-legged robot's 100 Hz control loop: each period reads the axes' feedback,
//! integrates odometry, supervises the axes' health and sends one setpoint (16 ODrive CANSimple
//! frames), as the host's rig does (`firmware_sim::rig`), on any CAN peripheral behind
//! `embedded-can`.
//!
//! `#![no_std]`, no allocator, every buffer sized at compile time, so that the firmware images
//! (the QEMU images of `controller/`, the NUCLEO-G474RE image of `board/`) and the host's tests
//! (`tests/`, against the simulated axes) all run this one crate; the controller's library
//! re-exports it as `wheelleg_controller::control`.
//!
//! The loop is a state machine of one period at a time ([`Control::period`]): the start-up,
//! a step's setpoint stream and its settling are activities begun by the decision side
//! ([`Control::begin_start_up`], [`Control::begin_step`], [`Control::begin_retreat`]) and run
//! period by period, and between them every period holds the pose. So a firmware runs the
//! periods from a timer interrupt above the decision's priority, and the robot stays under
//! control however long a decision takes; the blocking [`Control::start_up`],
//! [`Control::step`] and [`Control::retreat`] run the same periods back to back.
//!
//! What a board provides is the [`Board`] trait (its CAN peripheral and the period's clock);
//! why the loop stops the robot, or an activity, is [`StopReason`] and [`ControlError`].
#![no_std]

mod board;
mod stop;

pub use board::{Board, CAN_LINK_TIMEOUT_PERIODS};
use stop::StopPlan;
pub use stop::{ControlError, Stop, StopReason};

use embedded_can::nb::Can;
use embedded_can::Frame;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::base::{MecanumBase, Odometry};

use wheelleg_runtime::can::host::{
    Commander, FeedbackTracker, Health, RollCall, TxQueue, ROLL_CALL_ROUNDS, ROLL_CALL_ROUND_US,
};
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::can::protocol::AxisState;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::{BaseDisplacement, MotionConfig, Setpoint, StepMotion};
use wheelleg_runtime::robot::Robot;

/// Transmit queue capacity: Clear_Errors and the start-up sequence (three frames per axis) and
/// one setpoint, the most one period queues (the host's rig's too).
pub const TX_FRAMES: usize = 64;
/// Hold periods of the start-up sequence: a few heartbeat periods, enough for every axis to
/// report closed loop (the rig's count).
pub const STARTUP_TICKS: u32 = 30;
/// Hold time after each step's setpoints, so the motors settle before the pose is read.
pub const SETTLE_S: f32 = 0.2;
/// An axis not heard from for this long is silent: 5 missed encoder estimates at 100 Hz (one
/// lost frame is noise, five in a row is a dead node).
pub const HEALTH_TIMEOUT_US: u64 = 50_000;

/// The loop's settings: the firmware runs the defaults; a host loop may set its own.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ControlSettings {
    /// Control rate, step duration, limits and the safe stop's deceleration time.
    pub motion: MotionConfig,
    /// Hold time after each step's setpoints.
    pub settle_s: f32,
    /// An axis not heard from for this long is silent.
    pub health_timeout_us: u64,
}

impl Default for ControlSettings {
    /// 100 Hz, [`SETTLE_S`], [`HEALTH_TIMEOUT_US`].
    fn default() -> Self {
        ControlSettings {
            motion: MotionConfig::default(),
            settle_s: SETTLE_S,
            health_timeout_us: HEALTH_TIMEOUT_US,
        }
    }
}

/// What the loop is doing, period by period.
// The variants differ in size (a roll call's tallies, a step's plan), but there is no heap to
// box them in, and the loop lives in one place for the firmware's life.
#[allow(clippy::large_enum_variant)]
#[derive(Clone, Debug)]
enum Activity {
    /// Holding the commanded legs, wheels stopped (or the safe stop).
    Holding,
    /// The roll call's periods: `period` of [`ROLL_CALL_ROUNDS`] rounds of `per_round`.
    RollCall {
        call: RollCall,
        period: u32,
        per_round: u32,
    },
    /// Armed, holding the start pose unsupervised until every axis reports closed loop.
    Arming { periods_left: u32 },
    /// A step's (or a retreat's) setpoint stream, towards `target`.
    Moving {
        motion: StepMotion,
        target: LegConfig,
    },
    /// Holding a step's target for [`ControlSettings::settle_s`].
    Settling { periods_left: u32 },
}

/// An activity that ended in this period ([`Control::period`]).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Finished {
    /// The start-up: every axis in closed loop, or why not (the loop is then in safe stop).
    StartUp(Result<(), ControlError>),
    /// A step or a retreat, settled (or ended early by a safe stop); an error stopped it.
    Step(Result<(), ControlError>),
}

impl Finished {
    /// The activity's result.
    pub fn result(self) -> Result<(), ControlError> {
        match self {
            Finished::StartUp(result) | Finished::Step(result) => result,
        }
    }
}

/// The robot's motion side: commanded legs, odometry, axis feedback and the frames out.
pub struct Control<F: Frame> {
    robot: Robot,
    settings: ControlSettings,
    commander: Commander,
    tracker: FeedbackTracker,
    tx: TxQueue<F, TX_FRAMES>,
    odometry: Odometry,
    legs: LegConfig,
    now_us: u64,
    ticks: u32,
    stop: Option<Stop>,
    /// How the safe stop comes to rest, from the period it is decided in.
    stop_plan: Option<StopPlan>,
    /// The last setpoint sent: where a stop outside a step rests.
    last_sent: Option<Setpoint>,
    /// The last step's start legs and base motion: what backing out of it undoes.
    last_step: Option<(LegConfig, BaseDisplacement)>,
    activity: Activity,
}

impl<F: Frame> Control<F> {
    /// The loop for `robot` (its geometry and CAN node map) with the legs at `start`, motors
    /// idle, with the default settings.
    pub fn new(robot: &Robot, start: LegConfig) -> Control<F> {
        Control::with_settings(robot, start, ControlSettings::default())
    }

    /// [`Control::new`] with `settings`.
    pub fn with_settings(robot: &Robot, start: LegConfig, settings: ControlSettings) -> Control<F> {
        Control {
            robot: *robot,
            settings,
            commander: Commander::new(robot.can),
            tracker: FeedbackTracker::new(robot.can),
            tx: TxQueue::new(),
            odometry: Odometry::default(),
            legs: start,
            now_us: 0,
            ticks: 0,
            stop: None,
            stop_plan: None,
            last_sent: None,
            last_step: None,
            activity: Activity::Holding,
        }
    }

    /// Whether an activity (start-up, step, retreat) is in progress; otherwise every period
    /// holds.
    pub fn busy(&self) -> bool {
        !matches!(self.activity, Activity::Holding)
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

    /// The robot driven.
    pub fn robot(&self) -> Robot {
        self.robot
    }

    /// The axes' feedback as the loop has heard it.
    pub fn feedback(&self) -> &FeedbackTracker {
        &self.tracker
    }

    /// The axes' health now, by the loop's clock and silence timeout.
    pub fn health(&self) -> Health {
        self.tracker
            .health(self.now_us, self.settings.health_timeout_us)
    }

    /// The loop's settings.
    pub fn settings(&self) -> &ControlSettings {
        &self.settings
    }

    /// What the safe stop holds once at rest, once the stop is planned (from the first period
    /// in safe stop on); `None` before, or when nothing was sent to rest on.
    pub fn stop_rest(&self) -> Option<Setpoint> {
        self.stop_plan.as_ref().and_then(StopPlan::rest)
    }

    /// Whether the safe stop has brought the robot to rest (its deceleration along the step's
    /// path is over); false when not in safe stop.
    pub fn stop_at_rest(&self) -> bool {
        self.stop.is_some() && self.stop_plan.as_ref().is_none_or(StopPlan::at_rest)
    }

    /// Control periods run so far.
    pub fn ticks(&self) -> u32 {
        self.ticks
    }

    /// Puts the robot in safe stop for `reason` from the next period on (the first reason
    /// stays).
    pub fn stop(&mut self, reason: StopReason) {
        self.stop_in(reason, self.ticks);
    }

    /// [`Self::stop`], decided in period `tick`.
    fn stop_in(&mut self, reason: StopReason, tick: u32) {
        if self.stop.is_none() {
            self.stop = Some(Stop { reason, tick });
        }
    }

    fn tick_s(&self) -> f32 {
        1.0 / self.settings.motion.control_rate_hz
    }

    /// One control period sending `setpoint` (or the safe stop): feedback in, odometry, health
    /// when `supervise`, then this period's frames out. For callers that stream a motion of
    /// their own outside the loop's activities.
    pub fn tick<B: Board<Frame = F>>(
        &mut self,
        board: &mut B,
        setpoint: &Setpoint,
        supervise: bool,
    ) -> Result<(), ControlError> {
        self.tick_in(board, setpoint, supervise, None)
    }

    /// [`Self::tick`] with setpoint `setpoint.tick` of `moving` in progress: what a safe stop
    /// decided now decelerates along.
    fn tick_in<B: Board<Frame = F>>(
        &mut self,
        board: &mut B,
        setpoint: &Setpoint,
        supervise: bool,
        moving: Option<&StepMotion>,
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
        if self.stop.is_some() {
            // Planned before this period's setpoint goes out, which it replaces.
            let plan = self
                .stop_plan
                .get_or_insert_with(|| StopPlan::new(moving, setpoint.tick, self.last_sent));
            let stop_setpoint = plan.next_setpoint();
            if let Some(rest) = plan.rest() {
                // Where the robot rests is what it holds, and where a recovery starts from.
                self.legs = rest.legs;
            }
            match stop_setpoint {
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
        self.end_period(board)
    }

    /// Sends the period's queued frames and ends the period. The period ends (its clock runs
    /// on, the board's `tick_done` comes) even when a frame is refused, as time does.
    fn end_period<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        board.sending();
        let sent = self.flush(board);
        board.tick_done();
        self.now_us += ((1.0e6 * self.tick_s()) as u64).max(1);
        self.ticks = self.ticks.wrapping_add(1);
        sent
    }

    /// Sends the queued frames. A frame the peripheral refuses drops the rest of the period's
    /// frames too: left queued they would go out ahead of the next period's (a step's stale
    /// setpoints before the safe stop), and a queue that stays full would refuse every later
    /// period's safe stop even after the peripheral recovers.
    fn flush<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        while let Some(frame) = self.tx.pop() {
            if let Err(error) = send(board.can(), &frame) {
                while self.tx.pop().is_some() {}
                return Err(error);
            }
        }
        Ok(())
    }

    /// Silent or errored axes (the rig's stop conditions; an axis merely not in closed loop
    /// yet is not one), or a lost CAN link.
    fn unhealthy(&self, link_lost: bool) -> Option<StopReason> {
        let health = self.health();
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

    /// One control period of the activity in progress (holding when there is none): call it
    /// once per period, from the period's interrupt or in a loop. Returns the activity that
    /// ended in it. A frame that cannot be queued or sent puts the robot in safe stop
    /// ([`StopReason::Control`]), as does a start-up that fails ([`StopReason::StartupFailed`]).
    pub fn period<B: Board<Frame = F>>(&mut self, board: &mut B) -> Option<Finished> {
        let activity = core::mem::replace(&mut self.activity, Activity::Holding);
        let starting = matches!(
            activity,
            Activity::RollCall { .. } | Activity::Arming { .. }
        );
        let stepping = matches!(
            activity,
            Activity::Moving { .. } | Activity::Settling { .. }
        );
        // A period that fails has ended all the same: its stop belongs to it.
        let tick = self.ticks;
        let (next, finished) = match self.run_period(board, activity) {
            Ok(outcome) => outcome,
            Err(error) if starting => {
                self.stop_in(StopReason::StartupFailed, tick);
                (Activity::Holding, Some(Finished::StartUp(Err(error))))
            }
            Err(error) => {
                self.stop_in(StopReason::Control, tick);
                (
                    Activity::Holding,
                    stepping.then_some(Finished::Step(Err(error))),
                )
            }
        };
        self.activity = next;
        finished
    }

    /// The period of `activity`: what comes after it, and what ended.
    fn run_period<B: Board<Frame = F>>(
        &mut self,
        board: &mut B,
        activity: Activity,
    ) -> Result<(Activity, Option<Finished>), ControlError> {
        Ok(match activity {
            Activity::Holding => {
                self.hold(board)?;
                (Activity::Holding, None)
            }
            Activity::RollCall {
                mut call,
                period,
                per_round,
            } => {
                self.roll_call_period(board, &mut call, period % per_round == 0)?;
                if period + 1 < per_round * u32::from(ROLL_CALL_ROUNDS) {
                    let period = period + 1;
                    return Ok((
                        Activity::RollCall {
                            call,
                            period,
                            per_round,
                        },
                        None,
                    ));
                }
                if let Err(refusal) = call.verdict() {
                    self.stop(StopReason::StartupFailed);
                    // A bus on which nothing at all answers has no motor controller to refuse.
                    let refused = if call.heard().is_empty() {
                        ControlError::StartupFailed
                    } else {
                        ControlError::StartupRefused(refusal)
                    };
                    return Ok((Activity::Holding, Some(Finished::StartUp(Err(refused)))));
                }
                self.commander.queue_clear_errors(&mut self.tx)?;
                self.commander.queue_startup(&mut self.tx)?;
                let periods_left = STARTUP_TICKS;
                (Activity::Arming { periods_left }, None)
            }
            Activity::Arming { periods_left } => {
                let hold = Setpoint::hold(&self.robot.geometry, self.legs)?;
                self.tick(board, &hold, false)?;
                if periods_left > 1 {
                    let periods_left = periods_left - 1;
                    return Ok((Activity::Arming { periods_left }, None));
                }
                let armed = Axis::ALL.into_iter().all(|axis| {
                    self.tracker
                        .axis(axis)
                        .is_some_and(|f| f.axis_state == Some(AxisState::ClosedLoopControl))
                });
                if !armed || self.unhealthy(board.link_lost()).is_some() {
                    return Err(ControlError::StartupFailed);
                }
                (Activity::Holding, Some(Finished::StartUp(Ok(()))))
            }
            Activity::Moving { mut motion, target } => match motion.next() {
                Some(setpoint) => {
                    self.tick_in(board, &setpoint, true, Some(&motion))?;
                    if self.stopped() {
                        (Activity::Holding, Some(Finished::Step(Ok(()))))
                    } else {
                        (Activity::Moving { motion, target }, None)
                    }
                }
                None => {
                    // The stream ended with the previous period: this one is the first of the
                    // settling.
                    self.legs = target;
                    let periods_left = libm_round(self.settings.settle_s / self.tick_s());
                    self.run_period(board, Activity::Settling { periods_left })?
                }
            },
            Activity::Settling { periods_left } => {
                if periods_left == 0 {
                    return Ok((Activity::Holding, Some(Finished::Step(Ok(())))));
                }
                self.hold(board)?;
                let periods_left = periods_left - 1;
                if periods_left == 0 {
                    (Activity::Holding, Some(Finished::Step(Ok(()))))
                } else {
                    (Activity::Settling { periods_left }, None)
                }
            }
        })
    }

    /// One supervised period holding the commanded legs, wheels stopped (or the safe stop).
    fn hold<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        let hold = Setpoint::hold(&self.robot.geometry, self.legs)?;
        self.tick(board, &hold, true)
    }

    /// Begins the start-up: the roll call (who is on each node, on what firmware),
    /// Clear_Errors, then arming every axis and holding the start pose until all report closed
    /// loop ([`Finished::StartUp`]). A start-up is also the way out of a safe stop: it clears
    /// the stop, and the robot re-arms where the stop left it.
    pub fn begin_start_up(&mut self) {
        self.stop = None;
        self.stop_plan = None;
        let tick_us = ((1.0e6 * self.tick_s()) as u64).max(1);
        let per_round = ROLL_CALL_ROUND_US.div_ceil(tick_us).max(1);
        self.activity = Activity::RollCall {
            call: RollCall::new(self.robot.can),
            period: 0,
            per_round: u32::try_from(per_round).unwrap_or(u32::MAX),
        };
    }

    /// One period of the roll call (of [`ROLL_CALL_ROUNDS`] rounds of Get_Version requests to
    /// every node, each [`ROLL_CALL_ROUND_US`] long, as the rig runs them): nothing but the
    /// requests is sent, so nothing moves. A node missing, two devices on one node id, or
    /// firmware the codec does not speak stops the start-up.
    fn roll_call_period<B: Board<Frame = F>>(
        &mut self,
        board: &mut B,
        call: &mut RollCall,
        round_begins: bool,
    ) -> Result<(), ControlError> {
        board.wait_for_tick();
        while let Ok(frame) = board.can().receive() {
            self.tracker.receive(&frame, self.now_us);
            call.receive(&frame);
        }
        if round_begins {
            call.begin_round();
            self.commander.queue_version_requests(&mut self.tx)?;
        }
        self.end_period(board)
    }

    /// Begins driving one decision: its setpoint stream, then [`ControlSettings::settle_s`]
    /// holding its target
    /// ([`Finished::Step`]). An action the legs cannot take is not begun (`Err`, nothing
    /// queued), as on the host. A safe stop ends the step at once (the periods after it hold
    /// the robot).
    pub fn begin_step(&mut self, action: Action) -> Result<(), ControlError> {
        let motion = StepMotion::plan(&self.robot, &self.settings.motion, self.legs, action)?;
        self.begin_motion(motion);
        Ok(())
    }

    /// Begins backing out of the last step along its inverse motion, to its start legs (the
    /// world refused the step), as the host's closed loop does; then
    /// [`ControlSettings::settle_s`] holding them. With no step to undo nothing begins ([`Self::busy`] stays false).
    pub fn begin_retreat(&mut self) -> Result<(), ControlError> {
        let Some((start, displacement)) = self.last_step else {
            return Ok(());
        };
        let back = displacement.isometry().inverse();
        let back = BaseDisplacement {
            dx_m: back.translation.x,
            dy_m: back.translation.y,
            dyaw_rad: back.rotation.angle(),
        };
        let motion = StepMotion::plan_between(
            &self.robot.geometry,
            &self.settings.motion,
            self.legs,
            start,
            back,
        )?;
        self.begin_motion(motion);
        Ok(())
    }

    /// Begins driving any planned motion (a lattice step, or a move off the lattice such as
    /// backing out of a step), then [`ControlSettings::settle_s`] holding its target
    /// ([`Finished::Step`]). The motion should start from [`Self::legs`].
    pub fn begin_motion(&mut self, motion: StepMotion) {
        let target = motion.target();
        self.last_step = Some((self.legs, motion.displacement()));
        self.activity = Activity::Moving { motion, target };
    }

    /// Runs periods until the activity in progress ends (at once when there is none).
    fn finish<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        while self.busy() {
            if let Some(finished) = self.period(board) {
                return finished.result();
            }
        }
        Ok(())
    }

    /// [`Self::begin_start_up`], its periods run back to back.
    pub fn start_up<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        self.begin_start_up();
        self.finish(board)
    }

    /// [`Self::begin_step`], its periods run back to back.
    pub fn step<B: Board<Frame = F>>(
        &mut self,
        board: &mut B,
        action: Action,
    ) -> Result<(), ControlError> {
        self.begin_step(action)?;
        self.finish(board)
    }

    /// [`Self::begin_retreat`], its periods run back to back.
    pub fn retreat<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        self.begin_retreat()?;
        self.finish(board)
    }

    /// Sends Estop to every axis (they disarm and latch `ESTOP_REQUESTED`) and puts the loop in
    /// safe stop ([`StopReason::Estop`]), in one unsupervised period so the motors see it at
    /// once; the activity in progress ends. [`Self::begin_start_up`] recovers.
    pub fn estop<B: Board<Frame = F>>(&mut self, board: &mut B) -> Result<(), ControlError> {
        self.activity = Activity::Holding;
        self.commander.queue_estop(&mut self.tx)?;
        self.stop(StopReason::Estop);
        let hold = Setpoint::hold(&self.robot.geometry, self.legs)?;
        self.tick(board, &hold, false)
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
