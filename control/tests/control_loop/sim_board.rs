//! The test board: the host's rig board ([`RigBoard`]) with the 16 simulated ODrive axes on an
//! in-process bus, advanced one control period (ten 1 ms physics steps, as the rig and the
//! firmware-in-the-loop plant run them) after each period's frames, recording every frame the
//! loop sends, with switches for the faults the loop must survive.

use wheelleg_control::{Control, ControlError, Finished, SETTLE_S, TX_FRAMES};
use wheelleg_firmware_sim::bus::Faults;
use wheelleg_firmware_sim::rig::{true_wheel_speed_sum, RigBoard};
use wheelleg_runtime::action::Action;
use wheelleg_runtime::can::host::{Commander, TxQueue};
use wheelleg_runtime::can::node_map::Axis;
use wheelleg_runtime::can::protocol::{decode, Message};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::{MotionConfig, Setpoint, StepMotion};
use wheelleg_runtime::robot::Robot;

/// The control period, as the loop's default motion settings run it.
pub const PERIOD_US: u64 = 10_000;
/// The motors' physics step (the rig's).
pub const PHYSICS_US: u64 = 1_000;
/// The axes' watchdog, as the rig and the firmware-in-the-loop plant configure it.
pub const WATCHDOG_TIMEOUT_US: u64 = 100_000;
/// Measured legs against the target after a step and its settling: the closed loop's
/// tolerance (docs/can-protocol.md, "Tolerances of the closed loop").
pub const LEG_TOLERANCE_M: f32 = 0.0005;
/// Achieved base motion against the ideal one, the same tolerance.
pub const POSITION_TOLERANCE_M: f32 = 0.002;
/// Achieved heading against the ideal one, the same tolerance: 0.2°.
pub const YAW_TOLERANCE_RAD: f32 = 0.2 * std::f32::consts::PI / 180.0;

/// The shipped robot.
pub fn robot() -> Robot {
    Robot::WHEELLEG
}

/// The shipped robot's default legs: a start pose the simulated axes take (their motor
/// positions come from its leg IK).
pub fn start_legs() -> LegConfig {
    let geometry = robot().geometry;
    LegConfig {
        clearance_m: geometry.default_clearance_m,
        track_m: geometry.default_track_m,
    }
}

/// The host's board with the robot's 16 simulated axes on an in-process bus: the rig's, so
/// the loop is tested on the board the host runs it on.
pub type SimBoard = RigBoard;

/// The robot's axes with the legs at `start`, wheels at rest, all idle, watchdog on, recording
/// every frame the loop sends.
pub fn sim_board(robot: &Robot, start: LegConfig) -> RigBoard {
    let mut board = RigBoard::in_process(
        robot,
        start,
        Faults::NONE,
        WATCHDOG_TIMEOUT_US,
        PERIOD_US,
        PHYSICS_US,
    )
    .unwrap();
    board.record_sent();
    board
}

/// The faults and views the tests use on the board.
pub trait TestBoard {
    /// Makes `axis` stop transmitting from the next period on (it still obeys commands).
    fn silence(&mut self, axis: Axis);
    /// Makes `axis` latch an error (an emergency stop): its heartbeats report it from the next
    /// one on.
    fn fault(&mut self, axis: Axis);
    /// The frames of the last period.
    fn last_period(&self) -> &[CanFrame];
    /// The legs as the simulated joints really are.
    fn legs_now(&self) -> LegConfig;
    /// Sum of the simulated wheels' absolute speeds, turns/s.
    fn wheel_speed_sum(&self) -> f32;
}

impl TestBoard for RigBoard {
    fn silence(&mut self, axis: Axis) {
        self.firmware_mut().axis_mut(axis).unwrap().set_silent(true);
    }

    fn fault(&mut self, axis: Axis) {
        let now_us = self.now_us();
        self.firmware_mut()
            .axis_mut(axis)
            .unwrap()
            .handle(&Message::Estop, now_us);
    }

    fn last_period(&self) -> &[CanFrame] {
        self.sent().last().map(Vec::as_slice).unwrap_or(&[])
    }

    fn legs_now(&self) -> LegConfig {
        self.true_legs().unwrap()
    }

    fn wheel_speed_sum(&self) -> f32 {
        true_wheel_speed_sum(self.firmware())
    }
}

/// Runs periods until the activity in progress ends, at most `limit`: how many periods it took
/// and how it ended. Every period before the last finishes nothing and leaves the loop busy.
pub fn run_until_finished(
    control: &mut Control<CanFrame>,
    board: &mut SimBoard,
    limit: u32,
) -> (u32, Finished) {
    for period in 1..=limit {
        assert!(control.busy(), "idle before anything finished");
        if let Some(finished) = control.period(board) {
            assert!(!control.busy(), "{finished:?} ended, yet still busy");
            return (period, finished);
        }
    }
    panic!("nothing finished in {limit} periods");
}

/// The loop and its board after a successful start-up, legs at `start`.
pub fn started_at(start: LegConfig) -> (Control<CanFrame>, SimBoard) {
    let robot = robot();
    let mut board = sim_board(&robot, start);
    let mut control = Control::new(&robot, start);
    control.begin_start_up();
    let (_, finished) = run_until_finished(&mut control, &mut board, 100);
    assert_eq!(finished, Finished::StartUp(Ok(())));
    (control, board)
}

/// [`started_at`] the default legs.
pub fn started() -> (Control<CanFrame>, SimBoard) {
    started_at(start_legs())
}

/// Setpoints of a step or retreat under the loop's motion settings.
pub fn setpoints_per_motion() -> u32 {
    let config = MotionConfig::default();
    (config.control_rate_hz * config.step_duration_s).round() as u32
}

/// Periods of settling after a motion's setpoints.
pub fn settle_periods() -> u32 {
    (SETTLE_S * MotionConfig::default().control_rate_hz).round() as u32
}

/// The frames the loop sends for `setpoint`, in its order.
pub fn frames_of(robot: &Robot, setpoint: &Setpoint) -> Vec<CanFrame> {
    let mut queue: TxQueue<CanFrame, TX_FRAMES> = TxQueue::new();
    Commander::new(robot.can)
        .queue_setpoint(&mut queue, setpoint)
        .unwrap();
    std::iter::from_fn(|| queue.pop()).collect()
}

/// The frames of holding `legs`, wheels stopped.
pub fn hold_frames(robot: &Robot, legs: LegConfig) -> Vec<CanFrame> {
    frames_of(robot, &Setpoint::hold(&robot.geometry, legs).unwrap())
}

/// The step the loop plans for `action` from `legs`.
pub fn plan(robot: &Robot, legs: LegConfig, action: Action) -> Result<StepMotion, ControlError> {
    Ok(StepMotion::plan(
        robot,
        &MotionConfig::default(),
        legs,
        action,
    )?)
}

/// Each frame's axis and message.
pub fn decoded(robot: &Robot, frames: &[CanFrame]) -> Vec<(Axis, Message)> {
    frames
        .iter()
        .map(|frame| {
            let (node, message) = decode(frame).unwrap();
            (robot.can.axis_on(node).unwrap(), message)
        })
        .collect()
}
