use super::*;
use crate::can::frame::CanFrame;
use crate::can::protocol::{axis_error, NodeId};
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
