//! The start-up: the roll call, then Clear_Errors and arming, or a refusal before anything
//! moves.

use crate::sim_board::{
    decoded, robot, run_until_finished, sim_board, start_legs, TestBoard, PERIOD_US,
};
use wheelleg_control::{Control, ControlError, Finished, StopReason, STARTUP_TICKS};
use wheelleg_runtime::can::host::{
    RollCallProblem, RollCallRefusal, ROLL_CALL_ROUNDS, ROLL_CALL_ROUND_US,
};
use wheelleg_runtime::can::node_map::{Axis, Joint};
use wheelleg_runtime::can::protocol::{AxisState, CmdId, Message};
use wheelleg_runtime::can::CanFrame;
use wheelleg_runtime::robot::LegId;

/// Periods of the roll call: its rounds, each as many periods as its wait takes.
fn roll_call_periods() -> u32 {
    let per_round = ROLL_CALL_ROUND_US.div_ceil(PERIOD_US) as u32;
    u32::from(ROLL_CALL_ROUNDS) * per_round
}

#[test]
fn start_up_arms_every_axis_in_the_documented_number_of_periods() {
    let robot = robot();
    let mut board = sim_board(&robot, start_legs());
    let mut control: Control<CanFrame> = Control::new(&robot, start_legs());
    control.begin_start_up();
    let (periods, finished) = run_until_finished(&mut control, &mut board, 200);
    assert_eq!(finished, Finished::StartUp(Ok(())));
    assert_eq!(periods, roll_call_periods() + STARTUP_TICKS);
    // 3 rounds of 50 ms at 100 Hz, then 30 periods of holding the start pose.
    assert_eq!(periods, 45);
    assert_eq!(control.ticks(), periods);
    assert_eq!(control.stop_state(), None);
    for motor in board.firmware().axes() {
        assert_eq!(motor.state(), AxisState::ClosedLoopControl);
        assert_eq!(motor.error(), 0);
    }
    // The roll call only asks (one Get_Version request per node at each round's start); the
    // first period after it clears, sets the modes, arms and holds, in that order.
    let sent = board.sent();
    for (period, frames) in sent.iter().enumerate().take(roll_call_periods() as usize) {
        let asks = decoded(&robot, frames)
            .iter()
            .all(|(_, message)| *message == Message::Request(CmdId::GetVersion));
        let round_start = period as u64 % ROLL_CALL_ROUND_US.div_ceil(PERIOD_US) == 0;
        assert!(asks, "period {period}");
        assert_eq!(frames.len(), if round_start { 16 } else { 0 }, "{period}");
    }
    let arming = decoded(&robot, &sent[roll_call_periods() as usize]);
    let kinds: Vec<CmdId> = arming.iter().map(|(_, m)| m.cmd()).collect();
    let expected: Vec<CmdId> = [CmdId::ClearErrors; 16]
        .into_iter()
        .chain([CmdId::SetControllerMode; 16])
        .chain([CmdId::SetAxisState; 16])
        .chain(Axis::ALL.into_iter().map(|axis| match axis {
            Axis::Joint(..) => CmdId::SetInputPos,
            Axis::Wheel(_) => CmdId::SetInputVel,
        }))
        .collect();
    assert_eq!(kinds, expected);
}

#[test]
fn a_missing_node_is_refused_by_the_roll_call_and_nothing_is_armed() {
    let robot = robot();
    let knee = Axis::Joint(LegId::RearRight, Joint::Knee);
    let mut board = sim_board(&robot, start_legs());
    board.silence(knee);
    let mut control: Control<CanFrame> = Control::new(&robot, start_legs());
    control.begin_start_up();
    let (periods, finished) = run_until_finished(&mut control, &mut board, 200);
    let refusal = RollCallRefusal {
        axis: knee,
        node: robot.can.node_id(knee),
        problem: RollCallProblem::Missing,
    };
    assert_eq!(
        finished,
        Finished::StartUp(Err(ControlError::StartupRefused(refusal)))
    );
    assert_eq!(periods, roll_call_periods());
    assert_eq!(
        control.stop_state().map(|stop| stop.reason),
        Some(StopReason::StartupFailed)
    );
    // The loop goes on holding in safe stop; no axis is ever cleared, put in a mode or armed.
    for _ in 0..20 {
        assert_eq!(control.period(&mut board), None);
    }
    for motor in board.firmware().axes() {
        assert_eq!(motor.state(), AxisState::Idle);
    }
    for frames in board.sent() {
        for (axis, message) in decoded(&robot, frames) {
            assert!(
                !matches!(
                    message,
                    Message::ClearErrors
                        | Message::SetControllerMode { .. }
                        | Message::SetAxisState(_)
                ),
                "{axis}: {message:?}"
            );
        }
    }
}
