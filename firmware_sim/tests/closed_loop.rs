//! The closed loop without a policy: runtime motion -> CAN frames -> in-process bus ->
//! simulated ODrive axes -> encoder estimates -> runtime decoding -> forward kinematics.
//!
//! Tolerances (documented in docs/can-protocol.md): after a step and 0.2 s of settling, the
//! odometry pose is within 2 mm and 0.2° of the ideal step, and the measured leg configuration
//! within 0.5 mm of the target. The residual comes from sampling the wheel speeds at 100 Hz
//! while the motors lag their commands by a 20 ms first-order response.

use std::io::Write;
use std::sync::{Arc, Mutex};
use wheelleg_firmware_sim::bus::Faults;
use wheelleg_firmware_sim::bus::Transport;
use wheelleg_firmware_sim::candump::{parse_log, CandumpWriter, Replay, DEFAULT_EPOCH_US};
use wheelleg_firmware_sim::rig::{true_wheel_speed_sum, Rig, RigConfig, StepReport, StopReason};
use wheelleg_runtime::action::{Action, Step};
use wheelleg_runtime::can::host::FeedbackTracker;
use wheelleg_runtime::can::node_map::{Axis, Joint};
use wheelleg_runtime::can::protocol::{axis_error, AxisState};
use wheelleg_runtime::can::NodeMap;
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::motion::{MotionConfig, StepMotion};
use wheelleg_runtime::robot::{LegId, Robot, WHEELLEG};

const POSITION_TOLERANCE_M: f32 = 0.002;
const YAW_TOLERANCE_RAD: f32 = 0.2 * std::f32::consts::PI / 180.0;
const LEG_TOLERANCE_M: f32 = 0.0005;

fn default_legs() -> LegConfig {
    LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    }
}

fn started(config: RigConfig) -> Rig {
    let mut rig = Rig::in_process(&Robot::WHEELLEG, config, default_legs()).unwrap();
    rig.start_up().unwrap();
    rig
}

fn assert_close(report: &StepReport, what: &str, scale: f32) {
    assert!(
        report.position_error_m() < scale * POSITION_TOLERANCE_M,
        "{what}: position error {} m, {report:?}",
        report.position_error_m()
    );
    assert!(
        report.yaw_error_rad() < scale * YAW_TOLERANCE_RAD,
        "{what}: yaw error {} rad",
        report.yaw_error_rad()
    );
    let legs = report.achieved_legs;
    assert!(
        (legs.clearance_m - report.ideal_legs.clearance_m).abs() < scale * LEG_TOLERANCE_M,
        "{what}: {legs:?} vs {:?}",
        report.ideal_legs
    );
    assert!((legs.track_m - report.ideal_legs.track_m).abs() < scale * LEG_TOLERANCE_M);
    assert_eq!(report.stopped, None, "{what}");
}

#[test]
fn achieved_steps_match_the_ideal_steps() {
    let mut rig = started(RigConfig::default());
    let steps = [
        Action {
            move_x: Step::Plus,
            ..Action::IDLE
        },
        Action {
            move_y: Step::Minus,
            yaw: Step::Plus,
            ..Action::IDLE
        },
        // Legs and base at once: lower and widen while moving diagonally and turning.
        Action {
            move_x: Step::Plus,
            move_y: Step::Plus,
            yaw: Step::Minus,
            clearance: Step::Minus,
            track: Step::Plus,
        },
        Action {
            clearance: Step::Plus,
            track: Step::Minus,
            ..Action::IDLE
        },
    ];
    for action in steps {
        let legs_before = rig.legs();
        let report = rig.step(action).unwrap();
        eprintln!(
            "{action:?}: position error {:.2e} m, yaw error {:.2e} rad, legs {:?} vs {:?}",
            report.position_error_m(),
            report.yaw_error_rad(),
            report.achieved_legs,
            report.ideal_legs
        );
        assert_close(&report, &format!("{action:?}"), 1.0);
        // The step really moved something: the test is not comparing zero with zero.
        let moved = report.ideal_pose.translation.vector.norm()
            + report.ideal_pose.rotation.angle().abs()
            + (report.ideal_legs.track_m - legs_before.track_m).abs()
            + (report.ideal_legs.clearance_m - legs_before.clearance_m).abs();
        assert!(moved > 0.01);
    }
    assert!(rig.feedback().stats().malformed == 0);
}

#[test]
fn a_lossy_bus_degrades_the_step_gracefully() {
    let faults = Faults {
        drop_probability: 0.02,
        delay_probability: 0.05,
        delay_us: 3_000,
        duplicate_probability: 0.02,
        seed: 42,
    };
    let mut rig = started(RigConfig {
        faults,
        ..RigConfig::default()
    });
    let report = rig
        .step(Action {
            move_x: Step::Plus,
            yaw: Step::Plus,
            track: Step::Plus,
            ..Action::IDLE
        })
        .unwrap();
    let counters = rig.bus().counters();
    assert!(counters.dropped > 10 && counters.duplicated > 10 && counters.delayed > 10);
    // A lost wheel command holds the previous speed for one tick; a lost estimate leaves
    // odometry one sample stale. Both stay within a few times the clean-bus tolerance.
    assert_close(&report, "lossy bus", 5.0);
}

#[test]
fn watchdog_stops_wheels_holds_legs_and_reports_the_error() {
    let mut rig = started(RigConfig::default());
    // Half-way through a step that moves and lowers the body, the controller's transmit path
    // hangs while the wheels are turning and the legs are moving.
    let action = Action {
        move_x: Step::Plus,
        clearance: Step::Minus,
        ..Action::IDLE
    };
    let motion = StepMotion::plan(
        &Robot::WHEELLEG,
        &MotionConfig::default(),
        rig.legs(),
        action,
    )
    .unwrap();
    let half = motion.len() / 2;
    for setpoint in motion.take(half) {
        rig.drive(&setpoint).unwrap();
    }
    assert!(
        true_wheel_speed_sum(rig.firmware()) > 1.0,
        "wheels were turning"
    );
    rig.pause_commands(true);
    rig.hold(0.5).unwrap();
    for axis in Axis::ALL {
        let sim = rig.firmware().axis(axis).unwrap();
        assert_eq!(sim.state(), AxisState::Idle, "{axis:?}");
        assert_ne!(sim.error() & axis_error::WATCHDOG_TIMER_EXPIRED, 0);
        // The controller hears about it through the heartbeats.
        let fb = rig.feedback().axis(axis).unwrap();
        assert_ne!(fb.axis_error & axis_error::WATCHDOG_TIMER_EXPIRED, 0);
    }
    assert!(matches!(rig.stopped(), Some(StopReason::AxisError(set)) if set.0 == 0xFFFF));
    assert!(true_wheel_speed_sum(rig.firmware()) < 1e-3);
    // Legs hold: where the motors were when the watchdog fired is where they stay.
    let hip = Axis::Joint(LegId::FrontLeft, Joint::Hip);
    let hip_at_trip = rig.firmware().axis(hip).unwrap().pos_turns();
    rig.hold(0.5).unwrap();
    let hip_later = rig.firmware().axis(hip).unwrap().pos_turns();
    assert!(
        (hip_later - hip_at_trip).abs() < 1e-4,
        "{hip_at_trip} -> {hip_later}"
    );
    let legs = rig.feedback().leg_config(&WHEELLEG).unwrap();
    // Half-way between 0.12 m and 0.10 m, give or take the motor lag.
    assert!((legs.clearance_m - 0.11).abs() < 0.003, "{legs:?}");
}

#[test]
fn a_silent_node_stops_the_robot_safely_and_is_reported() {
    let mut rig = started(RigConfig::default());
    let silent = Axis::Wheel(LegId::RearLeft);
    let knee = Axis::Joint(LegId::FrontRight, Joint::Knee);
    let knee_before = rig.firmware().axis(knee).unwrap().pos_turns();
    rig.firmware_mut()
        .axis_mut(silent)
        .unwrap()
        .set_silent(true);
    let report = rig
        .step(Action {
            move_x: Step::Plus,
            ..Action::IDLE
        })
        .unwrap();
    match report.stopped {
        Some(StopReason::Silent(set)) => {
            assert!(set.contains(silent));
            assert_eq!(set.iter().count(), 1, "only the silent node");
        }
        other => panic!("expected a silent-node stop, got {other:?}"),
    }
    // The robot did not complete the step: it stopped early.
    assert!(report.achieved_pose.translation.x < 0.5 * report.ideal_pose.translation.x);
    assert!(true_wheel_speed_sum(rig.firmware()) < 1e-3);
    let knee_after = rig.firmware().axis(knee).unwrap().pos_turns();
    assert!((knee_after - knee_before).abs() < 1e-3);
    // The healthy axes are still armed: safe stop holds them, it does not drop them.
    assert_eq!(
        rig.firmware().axis(knee).unwrap().state(),
        AxisState::ClosedLoopControl
    );
    // The operator escalates: Estop disarms everything and latches the error...
    rig.estop().unwrap();
    for axis in Axis::ALL {
        let sim = rig.firmware().axis(axis).unwrap();
        assert_eq!(sim.state(), AxisState::Idle);
        assert_ne!(sim.error() & axis_error::ESTOP_REQUESTED, 0);
    }
    // ...and once the node talks again, Clear_Errors and start-up bring the robot back.
    rig.firmware_mut()
        .axis_mut(silent)
        .unwrap()
        .set_silent(false);
    rig.recover().unwrap();
    assert_eq!(rig.stopped(), None);
    let report = rig
        .step(Action {
            move_y: Step::Plus,
            ..Action::IDLE
        })
        .unwrap();
    assert_close(&report, "after recovery", 1.0);
}

#[derive(Clone, Default)]
struct SharedBuf(Arc<Mutex<Vec<u8>>>);

impl Write for SharedBuf {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        self.0.lock().unwrap().extend_from_slice(buf);
        Ok(buf.len())
    }
    fn flush(&mut self) -> std::io::Result<()> {
        Ok(())
    }
}

#[test]
fn logged_traffic_replays_into_the_same_feedback() {
    let mut rig = Rig::in_process(&Robot::WHEELLEG, RigConfig::default(), default_legs()).unwrap();
    let buf = SharedBuf::default();
    rig.log_to(CandumpWriter::new(
        Box::new(buf.clone()),
        "can0",
        DEFAULT_EPOCH_US,
    ));
    rig.start_up().unwrap();
    rig.step(Action {
        move_x: Step::Plus,
        track: Step::Plus,
        ..Action::IDLE
    })
    .unwrap();
    rig.take_log().unwrap();
    let text = String::from_utf8(buf.0.lock().unwrap().clone()).unwrap();
    let entries = parse_log(&text).unwrap();
    // Start-up (32) plus one setpoint (16) per tick, plus feedback.
    assert!(entries.len() > 32 + 16 * 70, "{} lines", entries.len());
    let mut replay = Replay::new(entries);
    let mut tracker = FeedbackTracker::new(NodeMap::NOMINAL);
    let mut now_us = 0;
    while !replay.is_done() {
        while let Some(frame) = replay.recv(now_us).unwrap() {
            tracker.receive(&frame, now_us);
        }
        now_us += 1_000;
    }
    // Replayed feedback ends where the live run ended; commands in the log are the "unexpected"
    // frames a listener sees from another master.
    let live = rig.feedback().leg_config(&WHEELLEG).unwrap();
    let replayed = tracker.leg_config(&WHEELLEG).unwrap();
    assert_eq!(live, replayed);
    assert!(tracker.stats().unexpected > 16 * 70);
    assert_eq!(tracker.stats().malformed, 0);
    if let Ok(path) = std::env::var("WHEELLEG_CANDUMP_OUT") {
        std::fs::write(path, text).unwrap();
    }
}

#[test]
fn a_stop_in_the_middle_of_a_step_rests_on_the_steps_path() {
    use wheelleg_firmware_sim::rig::TimedFault;
    use wheelleg_runtime::action::{CLEARANCE_STEP_M, TRACK_STEP_M};
    use wheelleg_runtime::motion::BaseDisplacement;
    // Moving, turning, lifting and narrowing at once: freezing any part while another goes
    // on would leave the path.
    let action = Action {
        move_x: Step::Plus,
        yaw: Step::Plus,
        clearance: Step::Plus,
        track: Step::Minus,
        ..Action::IDLE
    };
    let cases = [
        // A mute knee still hears: the whole robot follows the stop (the residual is the
        // motors' lag and the sampled odometry).
        (
            TimedFault::Silence(Axis::Joint(LegId::RearLeft, Joint::Knee)),
            0.001,
            0.0005,
        ),
        // A wheel off the bus runs on at its last speed until its watchdog idles it: the base
        // strays a few millimetres, the legs stay on the path.
        (
            TimedFault::Disconnect(Axis::Wheel(LegId::FrontRight)),
            0.006,
            0.0005,
        ),
    ];
    for (fault, pose_tolerance_m, legs_tolerance_m) in cases {
        let mut rig = started(RigConfig::default());
        let start = rig.legs();
        rig.schedule(rig.now_us() + 150_000, fault);
        let report = rig.step(action).unwrap();
        assert!(
            matches!(report.stopped, Some(StopReason::Silent(_))),
            "{fault:?}: {report:?}"
        );
        rig.hold(0.3).unwrap();
        assert!(true_wheel_speed_sum(rig.firmware()) < 1e-3, "{fault:?}");
        // Where along the step the legs really stopped, and what the path has there.
        let legs = rig.true_legs().unwrap();
        let s = (legs.clearance_m - start.clearance_m) / CLEARANCE_STEP_M;
        assert!(s > 0.1 && s < 0.9, "{fault:?}: stopped at progress {s}");
        let track_on_path_m = start.track_m - s * TRACK_STEP_M;
        assert!(
            (legs.track_m - track_on_path_m).abs() < legs_tolerance_m,
            "{fault:?}: legs {legs:?} off the path at progress {s}"
        );
        let on_path = BaseDisplacement::of_action(action, &Robot::WHEELLEG.actions).isometry_at(s);
        let off = on_path.inverse() * rig.true_pose();
        assert!(
            off.translation.vector.norm() < pose_tolerance_m,
            "{fault:?}: rests {} m off the path at progress {s}",
            off.translation.vector.norm()
        );
        // The controller holds a pose of the path: its commanded rest is the step's at the
        // progress the stop reached.
        let rest = rig.stop_rest().unwrap();
        let rest_s = (rest.legs.clearance_m - start.clearance_m) / CLEARANCE_STEP_M;
        assert!((rest.legs.track_m - (start.track_m - rest_s * TRACK_STEP_M)).abs() < 1e-5);
        assert_eq!(
            rig.legs(),
            rest.legs,
            "{fault:?}: recovery starts from the rest"
        );
        if let TimedFault::Disconnect(axis) = fault {
            let motor = rig.firmware().axis(axis).unwrap();
            assert_eq!(motor.state(), AxisState::Idle, "idled by its own watchdog");
            assert_ne!(motor.error() & axis_error::WATCHDOG_TIMER_EXPIRED, 0);
        }
    }
}
