use super::*;
use crate::can::frame::CanFrame;
use crate::can::protocol::{axis_error, CmdId, NodeId, Version};
use crate::robot::WHEELLEG;

fn estimate(axis: Axis, pos_turns: f32, vel_turns_per_s: f32) -> CanFrame {
    encode(
        NodeMap::NOMINAL.node_id(axis),
        &Message::EncoderEstimates {
            pos_turns,
            vel_turns_per_s,
        },
    )
    .unwrap()
}

fn hold() -> Setpoint {
    Setpoint::hold(
        &WHEELLEG,
        LegConfig {
            clearance_m: 0.12,
            track_m: 0.36,
        },
    )
    .unwrap()
}

#[test]
fn a_setpoint_is_sixteen_frames_or_none() {
    let commander = Commander::new(NodeMap::NOMINAL);
    let mut q: TxQueue<CanFrame, 20> = TxQueue::new();
    commander.queue_setpoint(&mut q, &hold()).unwrap();
    assert_eq!(q.len(), 16);
    // Only 4 slots left: the next tick is refused whole, the queue untouched.
    assert_eq!(
        commander.queue_setpoint(&mut q, &hold()),
        Err(CanError::QueueFull)
    );
    assert_eq!(q.len(), 16);
    let mut ids = heapless::Vec::<u32, 16>::new();
    while let Some(f) = q.pop() {
        ids.push(f.raw_id()).unwrap();
    }
    assert_eq!(ids[0], 1 << 5 | 0x0C, "front-left hip, Set_Input_Pos");
    assert_eq!(ids[15], 16 << 5 | 0x0D, "rear-right wheel, Set_Input_Vel");
}

#[test]
fn feedback_round_trips_through_the_node_map() {
    let commander = Commander::new(NodeMap::NOMINAL);
    let mut q: TxQueue<CanFrame, 16> = TxQueue::new();
    let mut sp = hold();
    sp.wheels.radps = [1.0, -2.0, 3.0, -4.0];
    commander.queue_setpoint(&mut q, &sp).unwrap();
    let mut tracker = FeedbackTracker::new(NodeMap::NOMINAL);
    // Echo every command back as if the axis had reached it exactly.
    while let Some(f) = q.pop() {
        let (node, msg) = decode(&f).unwrap();
        let axis = NodeMap::NOMINAL.axis_on(node).unwrap();
        let echo = match msg {
            Message::SetInputPos { pos_turns, .. } => estimate(axis, pos_turns, 0.0),
            Message::SetInputVel {
                vel_turns_per_s, ..
            } => estimate(axis, 0.0, vel_turns_per_s),
            other => panic!("unexpected {other:?}"),
        };
        assert_eq!(tracker.receive(&echo, 10), Received::Accepted(axis));
    }
    let legs = tracker.leg_config(&WHEELLEG).unwrap();
    assert!((legs.track_m - 0.36).abs() < 1e-5 && (legs.clearance_m - 0.12).abs() < 1e-5);
    let w = tracker.wheel_speeds().unwrap();
    for (got, want) in w.radps.iter().zip(sp.wheels.radps) {
        assert!((got - want).abs() < 1e-5, "{w:?}");
    }
}

#[test]
fn junk_is_counted_and_ignored() {
    let mut tracker = FeedbackTracker::new(NodeMap::NOMINAL);
    let short = CanFrame::standard(1 << 5 | 0x09, &[0; 3]).unwrap();
    assert!(matches!(tracker.receive(&short, 0), Received::Malformed(_)));
    let foreign = estimate(Axis::Wheel(LegId::FrontLeft), 0.0, 0.0);
    let foreign =
        CanFrame::standard((40 << 5) | (foreign.raw_id() as u16 & 0x1F), foreign.data()).unwrap();
    assert_eq!(tracker.receive(&foreign, 0), Received::Unexpected);
    let command: CanFrame = encode(NodeId::new(1).unwrap(), &Message::Estop).unwrap();
    assert_eq!(tracker.receive(&command, 0), Received::Unexpected);
    assert_eq!(
        tracker.stats(),
        BusStats {
            accepted: 0,
            malformed: 1,
            unexpected: 2
        }
    );
    assert_eq!(tracker.wheel_speeds(), None, "nothing real was heard");
}

#[test]
fn health_reports_silent_and_errored_axes() {
    let mut tracker = FeedbackTracker::new(NodeMap::NOMINAL);
    for axis in Axis::ALL {
        let hb: CanFrame = encode(
            NodeMap::NOMINAL.node_id(axis),
            &Message::Heartbeat {
                axis_error: 0,
                axis_state: AxisState::ClosedLoopControl,
            },
        )
        .unwrap();
        tracker.receive(&hb, 1_000);
    }
    assert!(tracker.health(50_000, 100_000).is_ok());
    let knee = Axis::Joint(LegId::RearLeft, Joint::Knee);
    let bad: CanFrame = encode(
        NodeMap::NOMINAL.node_id(knee),
        &Message::Heartbeat {
            axis_error: axis_error::WATCHDOG_TIMER_EXPIRED,
            axis_state: AxisState::Idle,
        },
    )
    .unwrap();
    tracker.receive(&bad, 150_000);
    let h = tracker.health(200_000, 100_000);
    assert_eq!(
        h.errored.iter().collect::<heapless::Vec<Axis, 16>>(),
        [knee]
    );
    assert!(h.not_closed_loop.contains(knee));
    // Everyone else has been quiet for 199 ms.
    assert_eq!(h.silent.iter().count(), 15);
    assert!(!h.silent.contains(knee));
}

#[test]
fn safe_stop_stops_wheels_and_holds_measured_joints() {
    let commander = Commander::new(NodeMap::NOMINAL);
    let mut tracker = FeedbackTracker::new(NodeMap::NOMINAL);
    let hip = Axis::Joint(LegId::FrontLeft, Joint::Hip);
    tracker.receive(&estimate(hip, 1.25, 0.5), 0);
    let mut q: TxQueue<CanFrame, 32> = TxQueue::new();
    // Only the hip has reported: 4 wheels + 1 joint.
    assert_eq!(commander.queue_safe_stop(&mut q, &tracker).unwrap(), 5);
    let (_, first) = decode(&q.pop().unwrap()).unwrap();
    assert_eq!(
        first,
        Message::SetInputPos {
            pos_turns: 1.25,
            vel_ff_turns_per_s: 0.0,
            torque_ff_nm: 0.0
        }
    );
    while let Some(f) = q.pop() {
        let (_, m) = decode(&f).unwrap();
        assert_eq!(
            m,
            Message::SetInputVel {
                vel_turns_per_s: 0.0,
                torque_ff_nm: 0.0
            }
        );
    }
}

const V0_5_6: Version = Version::ODRIVE_0_5_6;

fn version_answer(axis: Axis, version: Version) -> CanFrame {
    encode(NodeMap::NOMINAL.node_id(axis), &Message::Version(version)).unwrap()
}

/// A roll call of `rounds` rounds in which every axis answers `answers(axis)` times per round
/// with `version(axis)`.
fn roll_call(
    rounds: u8,
    answers: impl Fn(Axis, u8) -> u8,
    version: impl Fn(Axis) -> Version,
) -> RollCall {
    let mut roll = RollCall::new(NodeMap::NOMINAL);
    for round in 0..rounds {
        roll.begin_round();
        for axis in Axis::ALL {
            for _ in 0..answers(axis, round) {
                assert_eq!(
                    roll.receive(&version_answer(axis, version(axis))),
                    Some(axis)
                );
            }
        }
    }
    roll
}

#[test]
fn version_requests_are_one_remote_frame_per_node() {
    let commander = Commander::new(NodeMap::NOMINAL);
    let mut q: TxQueue<CanFrame, 16> = TxQueue::new();
    commander.queue_version_requests(&mut q).unwrap();
    assert_eq!(q.len(), 16);
    for axis in Axis::ALL {
        let f = q.pop().unwrap();
        assert!(f.is_remote_frame());
        assert_eq!(
            decode(&f).unwrap(),
            (
                NodeMap::NOMINAL.node_id(axis),
                Message::Request(CmdId::GetVersion)
            )
        );
    }
}

#[test]
fn a_full_roll_call_of_0_5_firmware_passes_and_the_tracker_keeps_the_versions() {
    let roll = roll_call(ROLL_CALL_ROUNDS, |_, _| 1, |_| V0_5_6);
    assert_eq!(roll.verdict(), Ok(()));
    assert_eq!(roll.answered(), AxisSet(0xFFFF));
    let mut tracker = FeedbackTracker::new(NodeMap::NOMINAL);
    let wheel = Axis::Wheel(LegId::RearRight);
    assert_eq!(
        tracker.receive(&version_answer(wheel, V0_5_6), 5),
        Received::Accepted(wheel)
    );
    assert_eq!(tracker.axis(wheel).unwrap().version, Some(V0_5_6));
    assert_eq!(tracker.stats().unexpected, 0);
}

#[test]
fn a_missing_node_is_refused_by_name() {
    let knee = Axis::Joint(LegId::FrontRight, Joint::Knee);
    let mut roll = roll_call(ROLL_CALL_ROUNDS, |a, _| u8::from(a != knee), |_| V0_5_6);
    let refusal = roll.verdict().unwrap_err();
    assert_eq!(
        refusal,
        RollCallRefusal {
            axis: knee,
            node: NodeId::new(5).unwrap(),
            problem: RollCallProblem::Missing,
        }
    );
    let shown = text(refusal);
    assert!(
        shown.starts_with("node 5 (front-right knee): missing"),
        "{shown}"
    );
    // A node that sends heartbeats but never answers Get_Version runs 0.5.x, which has none:
    // accepted.
    let hb: CanFrame = encode(
        NodeMap::NOMINAL.node_id(knee),
        &Message::Heartbeat {
            axis_error: 0,
            axis_state: AxisState::Idle,
        },
    )
    .unwrap();
    assert_eq!(roll.receive(&hb), None);
    assert_eq!(roll.verdict(), Ok(()));
}

#[test]
fn two_answers_to_every_request_are_two_devices_on_one_id() {
    let hip = Axis::Joint(LegId::RearLeft, Joint::Hip);
    let twice = |a: Axis, _| if a == hip { 2 } else { 1 };
    let refusal = roll_call(ROLL_CALL_ROUNDS, twice, |_| V0_5_6)
        .verdict()
        .unwrap_err();
    assert_eq!(
        (refusal.axis, refusal.node.get(), refusal.problem),
        (hip, 7, RollCallProblem::TwoDevices)
    );
    assert!(text(refusal).contains("node 7 (rear-left hip): answered Get_Version twice"));
    // One round is enough to tell, when it is the only one.
    assert_eq!(
        roll_call(1, twice, |_| V0_5_6)
            .verdict()
            .unwrap_err()
            .problem,
        RollCallProblem::TwoDevices
    );
    // Two devices with different firmware differ in what they say, even once each.
    let other = Version {
        fw_version_revision: 4,
        ..V0_5_6
    };
    let mut roll = roll_call(ROLL_CALL_ROUNDS, |_, _| 1, |_| V0_5_6);
    roll.receive(&version_answer(hip, other));
    assert_eq!(
        roll.verdict().unwrap_err().problem,
        RollCallProblem::TwoDevices
    );
}

#[test]
fn a_bus_that_repeats_or_loses_some_frames_is_not_a_fault() {
    // Round 0: one answer doubled (a bus repeat); round 1: another lost; every node still
    // answered once per request at least once.
    let wheel = Axis::Wheel(LegId::FrontLeft);
    let roll = roll_call(
        ROLL_CALL_ROUNDS,
        |a, round| match (a == wheel, round) {
            (true, 0) => 2,
            (true, 1) => 0,
            _ => 1,
        },
        |_| V0_5_6,
    );
    assert_eq!(roll.verdict(), Ok(()));
}

#[test]
fn firmware_0_6_is_refused_by_name() {
    let wheel = Axis::Wheel(LegId::FrontRight);
    let v0_6_11 = Version {
        fw_version_minor: 6,
        fw_version_revision: 11,
        ..V0_5_6
    };
    let refusal = roll_call(
        ROLL_CALL_ROUNDS,
        |_, _| 1,
        |a| if a == wheel { v0_6_11 } else { V0_5_6 },
    )
    .verdict()
    .unwrap_err();
    assert_eq!(
        (refusal.node.get(), refusal.problem),
        (14, RollCallProblem::UnsupportedFirmware(v0_6_11))
    );
    let shown = text(refusal);
    assert!(
        shown.starts_with("node 14 (front-right wheel): reports fw 0.6.11"),
        "{shown}"
    );
    // Any 0.5 revision keeps the layout.
    let v0_5_0 = Version {
        fw_version_revision: 0,
        ..V0_5_6
    };
    assert_eq!(
        roll_call(ROLL_CALL_ROUNDS, |_, _| 1, |_| v0_5_0).verdict(),
        Ok(())
    );
}

/// `x` formatted on the stack: the crate has no `alloc`, so no `to_string`.
fn text(x: impl core::fmt::Display) -> heapless::String<256> {
    let mut s = heapless::String::new();
    core::fmt::write(&mut s, format_args!("{x}")).unwrap();
    s
}
