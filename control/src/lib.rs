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
pub use stop::{ControlError, Stop, StopReason};

use embedded_can::nb::Can;
use embedded_can::Frame;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::base::{MecanumBase, Odometry};

use wheelleg_runtime::can::host::{
    Commander, FeedbackTracker, RollCall, TxQueue, ROLL_CALL_ROUNDS, ROLL_CALL_ROUND_US,
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
/// Hold time after each step's setpoints, so the motors settle (the rig's 0.2 s).
pub const SETTLE_S: f32 = 0.2;
/// An axis not heard from for this long is silent: 5 missed encoder estimates at 100 Hz.
pub const HEALTH_TIMEOUT_US: u64 = 50_000;

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
    /// Holding a step's target for [`SETTLE_S`].
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
    activity: Activity,
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
        board.sending();
        self.flush(board)?;
        board.tick_done();
        self.now_us += (1.0e6 * self.tick_s()) as u64;
        self.ticks = self.ticks.wrapping_add(1);
        Ok(())
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
        let (next, finished) = match self.run_period(board, activity) {
            Ok(outcome) => outcome,
            Err(error) if starting => {
                self.stop(StopReason::StartupFailed);
                (Activity::Holding, Some(Finished::StartUp(Err(error))))
            }
            Err(error) => {
                self.stop(StopReason::Control);
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
                    let refused = Err(ControlError::StartupRefused(refusal));
                    return Ok((Activity::Holding, Some(Finished::StartUp(refused))));
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
                    self.tick(board, &setpoint, true)?;
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
                    let periods_left = libm_round(SETTLE_S / self.tick_s());
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

    /// Begins the start-up as the host's rig runs it: the roll call (who is on each node, on
    /// what firmware), Clear_Errors, then arming every axis and holding the start pose until
    /// all report closed loop ([`Finished::StartUp`]).
    pub fn begin_start_up(&mut self) {
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
        board.sending();
        self.flush(board)?;
        board.tick_done();
        self.now_us += ((1.0e6 * self.tick_s()) as u64).max(1);
        self.ticks = self.ticks.wrapping_add(1);
        Ok(())
    }

    /// Begins driving one decision: its setpoint stream, then [`SETTLE_S`] holding its target
    /// ([`Finished::Step`]). An action the legs cannot take is not begun (`Err`, nothing
    /// queued), as on the host. A safe stop ends the step at once (the periods after it hold
    /// the robot).
    pub fn begin_step(&mut self, action: Action) -> Result<(), ControlError> {
        let motion = StepMotion::plan(&self.robot, &self.motion, self.legs, action)?;
        self.begin_motion(motion);
        Ok(())
    }

    /// Begins backing out of the last step along its inverse motion, to its start legs (the
    /// world refused the step), as the host's closed loop does; then [`SETTLE_S`] holding
    /// them. With no step to undo nothing begins ([`Self::busy`] stays false).
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
        let motion =
            StepMotion::plan_between(&self.robot.geometry, &self.motion, self.legs, start, back)?;
        self.begin_motion(motion);
        Ok(())
    }

    fn begin_motion(&mut self, motion: StepMotion) {
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
