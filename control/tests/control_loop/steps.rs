//! Steps and retreats: the setpoint stream, the settling, where the legs and the base end; an
//! action the legs cannot take; holding between activities; the blocking calls.

use crate::sim_board::{
    frames_of, hold_frames, plan, robot, run_until_finished, setpoints_per_motion, settle_periods,
    sim_board, start_legs, started, started_at, TestBoard, LEG_TOLERANCE_M, POSITION_TOLERANCE_M,
    YAW_TOLERANCE_RAD,
};
use wheelleg_control::{Control, ControlError, Finished};
use wheelleg_runtime::action::{Action, Step};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::{target_config, MotionError};

/// Forward, lower and wider at once: base and legs both move.
const ACTION: Action = Action {
    move_x: Step::Plus,
    move_y: Step::Zero,
    yaw: Step::Zero,
    clearance: Step::Minus,
    track: Step::Plus,
};

fn assert_legs_near(measured: Option<LegConfig>, target: LegConfig, what: &str) {
    let measured = measured.unwrap();
    assert!(
        (measured.clearance_m - target.clearance_m).abs() < LEG_TOLERANCE_M
            && (measured.track_m - target.track_m).abs() < LEG_TOLERANCE_M,
        "{what}: measured {measured:?}, target {target:?}"
    );
}

#[test]
fn a_step_streams_its_setpoints_then_settles_at_its_target() {
    let robot = robot();
    let (mut control, mut board) = started();
    let start = control.legs();
    let motion = plan(&robot, start, ACTION).unwrap();
    let target = motion.target();
    let ideal = motion.displacement();
    let setpoints: Vec<_> = motion.collect();
    assert_eq!(setpoints.len() as u32, setpoints_per_motion());
    let first = board.sent().len();

    control.begin_step(ACTION).unwrap();
    let (periods, finished) = run_until_finished(&mut control, &mut board, 500);
    assert_eq!(finished, Finished::Step(Ok(())));
    assert_eq!(periods, setpoints_per_motion() + settle_periods());
    // A 0.5 s step at 100 Hz, then 0.2 s of settling.
    assert_eq!(periods, 70);

    // Each period of the stream sends its setpoint; the settling holds the target.
    let sent = &board.sent()[first..];
    for (period, setpoint) in setpoints.iter().enumerate() {
        assert_eq!(
            sent[period],
            frames_of(&robot, setpoint),
            "setpoint {period}"
        );
    }
    let hold = hold_frames(&robot, target);
    for (period, frames) in sent.iter().enumerate().skip(setpoints.len()) {
        assert_eq!(*frames, hold, "settling period {period}");
    }
    assert_eq!(control.legs(), target);
    assert_legs_near(control.measured_legs(), target, "measured");
    assert_legs_near(Some(board.legs_now()), target, "true");
    let pose = control.odometry().pose;
    let ideal = ideal.isometry();
    let off = (pose.translation.vector - ideal.translation.vector).norm();
    let yaw = (pose.rotation.angle() - ideal.rotation.angle()).abs();
    assert!(off < POSITION_TOLERANCE_M, "{off} m off the ideal step");
    assert!(yaw < YAW_TOLERANCE_RAD, "{yaw} rad off the ideal step");
    assert!(control.stop_state().is_none());
}

#[test]
fn a_retreat_undoes_the_step() {
    let (mut control, mut board) = started();
    let start = control.legs();
    control.begin_step(ACTION).unwrap();
    run_until_finished(&mut control, &mut board, 500);
    assert_ne!(control.legs(), start);

    control.begin_retreat().unwrap();
    let (periods, finished) = run_until_finished(&mut control, &mut board, 500);
    assert_eq!(finished, Finished::Step(Ok(())));
    assert_eq!(periods, setpoints_per_motion() + settle_periods());
    let back = control.legs();
    assert!(
        (back.clearance_m - start.clearance_m).abs() < 1e-6
            && (back.track_m - start.track_m).abs() < 1e-6,
        "{back:?} against {start:?}"
    );
    assert_legs_near(control.measured_legs(), start, "measured");
    let pose = control.odometry().pose;
    let off = pose.translation.vector.norm();
    let yaw = pose.rotation.angle().abs();
    // Two steps' residuals at most: the step's and the retreat's.
    assert!(off < 2.0 * POSITION_TOLERANCE_M, "{off} m from the start");
    assert!(yaw < 2.0 * YAW_TOLERANCE_RAD, "{yaw} rad from the start");
}

#[test]
fn an_action_the_legs_cannot_take_is_refused_and_nothing_is_sent() {
    let robot = robot();
    let up = Action {
        clearance: Step::Plus,
        ..Action::IDLE
    };
    // The highest legs on the lattice from the default pose: one more step up has no leg
    // solution.
    let mut top = start_legs();
    while plan(&robot, top, up).is_ok() {
        top = target_config(top, up, &robot.actions);
    }
    assert!(top.clearance_m > start_legs().clearance_m);
    let (mut control, mut board) = started_at(top);

    let refused = control.begin_step(up);
    assert!(
        matches!(
            refused,
            Err(ControlError::Motion(MotionError::Unreachable(_)))
        ),
        "{refused:?}"
    );
    assert!(!control.busy());
    // Nothing was begun: the next periods hold the same pose, and there is no step to undo.
    for _ in 0..5 {
        assert_eq!(control.period(&mut board), None);
        assert_eq!(board.last_period(), hold_frames(&robot, top));
    }
    control.begin_retreat().unwrap();
    assert!(!control.busy());
    assert_eq!(control.legs(), top);
}

#[test]
fn holding_with_no_activity_finishes_nothing_and_keeps_the_pose() {
    let robot = robot();
    let (mut control, mut board) = started();
    let legs = board.legs_now();
    let hold = hold_frames(&robot, control.legs());
    for period in 0..100 {
        assert_eq!(control.period(&mut board), None, "period {period}");
        assert!(!control.busy());
        assert_eq!(board.last_period(), hold, "period {period}");
    }
    let now = board.legs_now();
    assert!((now.clearance_m - legs.clearance_m).abs() < 1e-5, "{now:?}");
    assert!((now.track_m - legs.track_m).abs() < 1e-5, "{now:?}");
    assert!(board.wheel_speed_sum() < 1e-6);
    assert!(control.stop_state().is_none());
}

#[test]
fn the_blocking_calls_send_the_frames_of_the_periods_run_by_hand() {
    let robot = robot();
    let mut blocking_board = sim_board(&robot, start_legs());
    let mut blocking: Control<CanFrame> = Control::new(&robot, start_legs());
    blocking.start_up(&mut blocking_board).unwrap();
    blocking.step(&mut blocking_board, ACTION).unwrap();
    blocking.retreat(&mut blocking_board).unwrap();

    let mut board = sim_board(&robot, start_legs());
    let mut control: Control<CanFrame> = Control::new(&robot, start_legs());
    control.begin_start_up();
    assert_eq!(
        run_until_finished(&mut control, &mut board, 500).1,
        Finished::StartUp(Ok(()))
    );
    control.begin_step(ACTION).unwrap();
    assert_eq!(
        run_until_finished(&mut control, &mut board, 500).1,
        Finished::Step(Ok(()))
    );
    control.begin_retreat().unwrap();
    assert_eq!(
        run_until_finished(&mut control, &mut board, 500).1,
        Finished::Step(Ok(()))
    );

    assert_eq!(blocking.ticks(), control.ticks());
    assert_eq!(blocking_board.sent().len(), board.sent().len());
    for (period, (a, b)) in blocking_board.sent().iter().zip(board.sent()).enumerate() {
        assert_eq!(a, b, "period {period}");
    }
    assert_eq!(blocking.measured_legs(), control.measured_legs());
    assert_eq!(blocking.odometry().pose, control.odometry().pose);
}
