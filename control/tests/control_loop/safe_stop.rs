//! The safe stop: each fault a board or the axes report ends the step in progress with its
//! reason, in time; the robot decelerates along the step's own path and then rests there,
//! wheels stopped and joints held, for good.

use crate::sim_board::{
    decoded, frames_of, plan, robot, start_legs, started, SimBoard, TestBoard, PERIOD_US,
};
use wheelleg_control::{
    Control, ControlError, Finished, Stop, StopReason, CAN_LINK_TIMEOUT_PERIODS, HEALTH_TIMEOUT_US,
};
use wheelleg_firmware_sim::axis::AxisConfig;
use wheelleg_runtime::action::{Action, Step};
use wheelleg_runtime::can::host::AxisSet;
use wheelleg_runtime::can::node_map::{Axis, Joint};
use wheelleg_runtime::can::protocol::Message;
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::motion::MotionConfig;
use wheelleg_runtime::robot::LegId;

const FORWARD: Action = Action {
    move_x: Step::Plus,
    ..Action::IDLE
};

/// Setpoints of the step streamed before a fault: well inside its 50.
const BEFORE_FAULT: u32 = 10;

fn only(axis: Axis) -> AxisSet {
    AxisSet(1 << axis.index())
}

/// A started robot `BEFORE_FAULT` periods into a step forward.
fn stepping() -> (Control<CanFrame>, SimBoard) {
    let (mut control, mut board) = started();
    control.begin_step(FORWARD).unwrap();
    for _ in 0..BEFORE_FAULT {
        assert_eq!(control.period(&mut board), None);
    }
    (control, board)
}

/// Runs periods until one finishes an activity, at most `limit`: how many it took (the first
/// counts as 1), what finished, and the tick of the period it finished in.
fn until_finished(
    control: &mut Control<CanFrame>,
    board: &mut SimBoard,
    limit: u32,
) -> (u32, Finished, u32) {
    for period in 1..=limit {
        let tick = control.ticks();
        if let Some(finished) = control.period(board) {
            return (period, finished, tick);
        }
    }
    panic!("nothing finished in {limit} periods");
}

/// The last period's frames hold the robot at rest: every wheel's velocity setpoint zero,
/// every joint at a position with no feed-forward. Returns the joints' positions.
fn assert_at_rest(board: &SimBoard) -> Vec<(Axis, f32)> {
    let robot = robot();
    let frames = decoded(&robot, board.last_period());
    assert_eq!(frames.len(), 16, "{frames:?}");
    let mut joints = Vec::new();
    for (axis, message) in frames {
        match (axis, message) {
            (
                Axis::Wheel(_),
                Message::SetInputVel {
                    vel_turns_per_s, ..
                },
            ) => assert_eq!(vel_turns_per_s, 0.0, "{axis}"),
            (
                Axis::Joint(..),
                Message::SetInputPos {
                    pos_turns,
                    vel_ff_turns_per_s,
                    ..
                },
            ) => {
                assert_eq!(vel_ff_turns_per_s, 0.0, "{axis}");
                joints.push((axis, pos_turns));
            }
            other => panic!("not at rest: {other:?}"),
        }
    }
    joints
}

/// Periods of the stop's deceleration ([`MotionConfig::stop_s`]).
fn stop_periods() -> u32 {
    let config = MotionConfig::default();
    (config.stop_s * config.control_rate_hz).round() as u32
}

/// The frames of the stop of [`stepping`]'s step decided before its setpoint `tick_in_step`
/// went out, period by period: the deceleration along the step's path, then `rest_periods` of
/// its rest.
fn stop_frames(tick_in_step: u32, rest_periods: usize) -> Vec<Vec<CanFrame>> {
    let robot = robot();
    let stop = plan(&robot, start_legs(), FORWARD)
        .unwrap()
        .stop_after(tick_in_step)
        .unwrap();
    let mut frames: Vec<Vec<CanFrame>> = Vec::new();
    let mut stop = stop;
    for setpoint in stop.by_ref() {
        frames.push(frames_of(&robot, &setpoint));
    }
    let rest = frames_of(&robot, &stop.rest());
    frames.extend(std::iter::repeat_n(rest, rest_periods));
    frames
}

#[test]
fn an_axis_silent_mid_step_stops_the_robot_along_the_steps_path_and_it_rests_there() {
    let knee = Axis::Joint(LegId::FrontLeft, Joint::Knee);
    let (mut control, mut board) = stepping();
    board.silence(knee);
    let first = board.sent().len();
    let (periods, finished, tick) = until_finished(&mut control, &mut board, 100);
    assert_eq!(finished, Finished::Step(Ok(())));
    let timeout_periods = (HEALTH_TIMEOUT_US / PERIOD_US) as u32;
    // Not before the timeout (a late estimate is no fault), and soon after it.
    assert!(
        periods > timeout_periods && periods <= timeout_periods + 2,
        "stopped {periods} periods after the axis went silent"
    );
    assert_eq!(
        control.stop_state(),
        Some(Stop {
            reason: StopReason::Silent(only(knee)),
            tick
        })
    );
    // From the stop's own period on, every axis (the silent knee too) gets the step's path
    // slowed to rest, then the rest: the stop replaced the setpoint its period would have sent.
    for _ in 0..50 {
        assert_eq!(control.period(&mut board), None);
        assert!(!control.busy());
    }
    let tick_in_step = BEFORE_FAULT + periods - 1;
    let sent = &board.sent()[first + periods as usize - 1..];
    let expected = stop_frames(tick_in_step, 51 - stop_periods() as usize);
    assert_eq!(sent.len(), expected.len());
    for (period, (got, want)) in sent.iter().zip(&expected).enumerate() {
        assert_eq!(got, want, "period {period} of the stop");
    }
    // The rest is on the step's path, past where the step was when it stopped, short of its
    // target.
    let rest = control.stop_rest().unwrap();
    let step = plan(&robot(), start_legs(), FORWARD).unwrap();
    assert!(rest.ideal_pose.translation.x > 0.0);
    assert!(rest.ideal_pose.translation.x < step.displacement().dx_m);
    assert_eq!(control.legs(), rest.legs);
    // Half a second later the wheels have stopped and the joints are where they are held.
    let held = assert_at_rest(&board);
    assert!(
        board.wheel_speed_sum() < 1e-3,
        "{}",
        board.wheel_speed_sum()
    );
    for (axis, pos_turns) in held {
        let motor = board.firmware().axis(axis).unwrap();
        assert!(
            (motor.pos_turns() - pos_turns).abs() < 1e-3,
            "{axis} at {} turns, held at {pos_turns}",
            motor.pos_turns()
        );
    }
    assert_eq!(
        control.stop_state().unwrap().reason,
        StopReason::Silent(only(knee))
    );
}

#[test]
fn an_axis_reporting_an_error_stops_the_robot() {
    let wheel = Axis::Wheel(LegId::RearLeft);
    let (mut control, mut board) = stepping();
    board.fault(wheel);
    let (periods, finished, tick) = until_finished(&mut control, &mut board, 100);
    assert_eq!(finished, Finished::Step(Ok(())));
    // The error shows in the axis's next heartbeat.
    let heartbeat_periods = (AxisConfig::WHEEL.heartbeat_period_us / PERIOD_US) as u32;
    assert!(periods <= heartbeat_periods + 2, "{periods} periods");
    assert_eq!(
        control.stop_state(),
        Some(Stop {
            reason: StopReason::AxisError(only(wheel)),
            tick
        })
    );
    let tick_in_step = BEFORE_FAULT + periods - 1;
    assert_eq!(board.last_period(), stop_frames(tick_in_step, 0)[0]);
    for _ in 0..stop_periods() {
        assert_eq!(control.period(&mut board), None);
    }
    assert_at_rest(&board);
}

#[test]
fn a_lost_link_stops_the_robot_in_the_period_it_is_reported() {
    let (mut control, mut board) = stepping();
    board.set_link_lost(true);
    let (periods, finished, tick) = until_finished(&mut control, &mut board, 100);
    assert_eq!(finished, Finished::Step(Ok(())));
    assert_eq!(periods, 1);
    assert_eq!(
        control.stop_state(),
        Some(Stop {
            reason: StopReason::CanLink,
            tick
        })
    );
    // Well before the axes would have gone silent: the link's own timeout is no longer than
    // theirs.
    assert!(u64::from(CAN_LINK_TIMEOUT_PERIODS) * PERIOD_US <= HEALTH_TIMEOUT_US);
    // The link back, the loop stays in safe stop: a stop is for good.
    board.set_link_lost(false);
    for _ in 0..stop_periods() + 10 {
        assert_eq!(control.period(&mut board), None);
    }
    assert_at_rest(&board);
    assert_eq!(control.stop_state().unwrap().reason, StopReason::CanLink);
}

#[test]
fn a_frame_the_peripheral_refuses_stops_the_robot_and_ends_the_step_with_an_error() {
    let (mut control, mut board) = stepping();
    board.set_refusing(true);
    let (periods, finished, tick) = until_finished(&mut control, &mut board, 100);
    assert_eq!(periods, 1);
    assert_eq!(finished, Finished::Step(Err(ControlError::Bus)));
    assert_eq!(
        control.stop_state(),
        Some(Stop {
            reason: StopReason::Control,
            tick
        })
    );
    assert!(board.last_period().is_empty());
    // The later periods' refused frames end nothing more: no activity is left, and the stop
    // keeps its reason.
    for _ in 0..5 {
        assert_eq!(control.period(&mut board), None);
        assert!(!control.busy());
    }
    assert_eq!(control.stop_state().unwrap().reason, StopReason::Control);
    // Once the peripheral takes frames again, each period sends the stop's one setpoint
    // alone: the refused periods' frames were dropped, not left queued ahead of it. The step
    // ended with the refusal, so the stop rests where its last setpoint was, wheels stopped.
    board.set_refusing(false);
    let robot = robot();
    let last = plan(&robot, start_legs(), FORWARD)
        .unwrap()
        .nth(BEFORE_FAULT as usize)
        .unwrap();
    let rest = frames_of(&robot, &control.stop_rest().unwrap());
    for _ in 0..3 {
        assert_eq!(control.period(&mut board), None);
        assert_eq!(board.last_period(), rest);
        assert_at_rest(&board);
    }
    assert_eq!(control.stop_rest().unwrap().legs, last.legs);
}

#[test]
fn a_stop_between_steps_rests_where_the_robot_holds() {
    let (mut control, mut board) = started();
    let tick = control.ticks();
    control.stop(StopReason::ObservationStalled);
    let first = Some(Stop {
        reason: StopReason::ObservationStalled,
        tick,
    });
    assert_eq!(control.stop_state(), first);
    let hold = crate::sim_board::hold_frames(&robot(), control.legs());
    for _ in 0..3 {
        assert_eq!(control.period(&mut board), None);
        assert_eq!(board.last_period(), hold);
    }
    control.stop(StopReason::ObservationCorrupt);
    // A fault the loop finds itself later does not replace the first reason either.
    board.silence(Axis::Wheel(LegId::FrontRight));
    for _ in 0..20 {
        assert_eq!(control.period(&mut board), None);
        assert_eq!(board.last_period(), hold);
    }
    assert_eq!(control.stop_state(), first);
    assert!(control.stopped());
}
