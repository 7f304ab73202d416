use super::*;
use crate::action::Step;
use crate::base::{Odometry, WheelSpeeds};
use crate::robot::{Robot, WHEELLEG};

fn default_legs() -> LegConfig {
    LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    }
}

fn busy_action() -> Action {
    Action {
        move_x: Step::Plus,
        move_y: Step::Minus,
        yaw: Step::Plus,
        clearance: Step::Plus,
        track: Step::Minus,
    }
}

#[test]
fn default_stream_has_one_setpoint_per_tick_at_100_hz() {
    let m = StepMotion::plan(
        &Robot::WHEELLEG,
        &MotionConfig::default(),
        default_legs(),
        busy_action(),
    )
    .unwrap();
    assert_eq!(m.len(), 50);
    let all: heapless::Vec<Setpoint, 64> = m.collect();
    assert_eq!(all.len(), 50);
    assert!((all[1].start_s - 0.01).abs() < 1e-6);
}

#[test]
fn integrated_commands_land_on_the_ideal_step() {
    let start = default_legs();
    for index in 0..crate::action::COUNT {
        let action = Action::from_index(index).unwrap();
        let Ok(m) = StepMotion::plan(&Robot::WHEELLEG, &MotionConfig::default(), start, action)
        else {
            continue;
        };
        let tick_s = m.tick_s();
        let mut odo = Odometry::default();
        let mut last: Option<Setpoint> = None;
        for sp in m {
            // The wheels were solved at the tick's mean track; legs move linearly in
            // progress, so that is the mean of the tick's end points.
            let previous_track_m = last.map_or(start.track_m, |p| p.legs.track_m);
            let mean_track_m = 0.5 * (previous_track_m + sp.legs.track_m);
            let base = MecanumBase::new(&WHEELLEG, mean_track_m).unwrap();
            // Odometry from the wheel commands, the way the robot would measure them.
            let v = base.body_velocity(sp.wheels).unwrap();
            odo.integrate(v, tick_s).unwrap();
            last = Some(sp);
        }
        let last = last.unwrap();
        let (pose, legs) = ideal_step(start, action, &Robot::WHEELLEG.actions);
        let err = odo.pose.inverse() * pose;
        assert!(err.translation.vector.norm() < 1e-5, "{action:?}: {odo:?}");
        assert!(err.rotation.angle().abs() < 1e-5);
        assert_eq!(last.legs, legs);
        assert_eq!(last.ideal_pose.rotation.angle(), pose.rotation.angle());
    }
}

#[test]
fn velocities_start_and_end_at_rest_and_stay_within_limits() {
    let config = MotionConfig::default();
    let m = StepMotion::plan(&Robot::WHEELLEG, &config, default_legs(), busy_action()).unwrap();
    let all: heapless::Vec<Setpoint, 64> = m.collect();
    let first = all.first().unwrap();
    let last = all.last().unwrap();
    let peak = all
        .iter()
        .map(|s| s.base.yaw_rate_radps)
        .fold(0.0f32, f32::max);
    // The raised-cosine profile: the end ticks move far less than the middle ones.
    assert!(first.base.yaw_rate_radps < 0.02 * peak);
    assert!(last.base.yaw_rate_radps < 0.02 * peak);
    // Peak is twice the mean (5 degrees over 0.5 s) within discretisation.
    let mean_radps = 5.0f32.to_radians() / 0.5;
    assert!(
        (peak - 2.0 * mean_radps).abs() < 0.01 * mean_radps,
        "{peak}"
    );
    for s in &all {
        assert!(s.wheels.max_abs_radps() <= config.max_wheel_radps);
        assert!(s.joint_rates.max_abs_radps() <= config.max_joint_radps);
    }
}

#[test]
fn legs_follow_ik_at_every_tick() {
    let m = StepMotion::plan(
        &Robot::WHEELLEG,
        &MotionConfig::default(),
        default_legs(),
        busy_action(),
    )
    .unwrap();
    let mut previous = default_legs();
    for sp in m {
        let back = WHEELLEG.config_from_joints(sp.joints);
        assert!((back.track_m - sp.legs.track_m).abs() < 1e-5);
        assert!((back.clearance_m - sp.legs.clearance_m).abs() < 1e-5);
        // Monotone interpolation: clearance only rises, track only narrows.
        assert!(sp.legs.clearance_m >= previous.clearance_m - 1e-7);
        assert!(sp.legs.track_m <= previous.track_m + 1e-7);
        previous = sp.legs;
    }
}

#[test]
fn impossible_or_too_fast_steps_are_refused() {
    let top = LegConfig {
        clearance_m: 0.24,
        track_m: 0.36,
    };
    let up = Action {
        clearance: Step::Plus,
        ..Action::IDLE
    };
    assert!(matches!(
        StepMotion::plan(&Robot::WHEELLEG, &MotionConfig::default(), top, up),
        Err(MotionError::Unreachable(_))
    ));
    let hasty = MotionConfig {
        step_duration_s: 0.02,
        ..MotionConfig::default()
    };
    let forward = Action {
        move_x: Step::Plus,
        ..Action::IDLE
    };
    assert!(matches!(
        StepMotion::plan(&Robot::WHEELLEG, &hasty, default_legs(), forward),
        Err(MotionError::WheelSpeedLimit { .. })
    ));
    let slow_joints = MotionConfig {
        max_joint_radps: 0.01,
        ..MotionConfig::default()
    };
    assert!(matches!(
        StepMotion::plan(&Robot::WHEELLEG, &slow_joints, default_legs(), up),
        Err(MotionError::JointSpeedLimit { .. })
    ));
    let no_rate = MotionConfig {
        control_rate_hz: f32::NAN,
        ..MotionConfig::default()
    };
    assert_eq!(
        StepMotion::plan(&Robot::WHEELLEG, &no_rate, default_legs(), forward),
        Err(MotionError::BadTiming)
    );
}

#[test]
fn a_stop_decelerates_along_the_steps_own_path() {
    let config = MotionConfig::default();
    let start = default_legs();
    let step = StepMotion::plan(&Robot::WHEELLEG, &config, start, busy_action()).unwrap();
    let tick_s = step.tick_s();
    for sent in [0, 1, 10, 25, 40, 49, 50] {
        let stop = step.stop_after(sent).unwrap();
        let s0 = stop.progress();
        let r0 = if sent == 0 {
            0.0
        } else {
            (progress(sent as f32 / 50.0) - progress((sent - 1) as f32 / 50.0)) / tick_s
        };
        let mut odo = Odometry {
            pose: step.displacement().isometry_at(s0),
        };
        let mut previous_s = s0;
        let mut count = 0;
        let mut stop_iter = stop.clone();
        for sp in stop_iter.by_ref() {
            count += 1;
            // On the path: legs and pose are the step's at some progress, never going back.
            let s = (sp.legs.clearance_m - start.clearance_m) / crate::action::CLEARANCE_STEP_M;
            assert!(s >= previous_s - 1e-5 && s <= 1.0 + 1e-5, "{sent}: {s}");
            let ideal = step.displacement().isometry_at(s);
            assert!((ideal.translation.vector - sp.ideal_pose.translation.vector).norm() < 1e-5);
            assert!(sp.wheels.max_abs_radps() <= config.max_wheel_radps);
            let previous_track_m = start.track_m - previous_s * crate::action::TRACK_STEP_M;
            let base =
                MecanumBase::new(&WHEELLEG, 0.5 * (previous_track_m + sp.legs.track_m)).unwrap();
            odo.integrate(base.body_velocity(sp.wheels).unwrap(), tick_s)
                .unwrap();
            previous_s = s;
        }
        assert!(count <= 10, "a stop takes at most stop_s");
        let rest = stop_iter.rest();
        assert_eq!(rest.wheels, WheelSpeeds::ZERO);
        // Never beyond the step's end, never more than the ramp allows.
        assert!(stop_iter.progress() <= 1.0);
        assert!(stop_iter.progress() <= s0 + 0.5 * r0 * config.stop_s + 1e-5);
        // The wheel commands integrate to the rest pose: the base stops on the path too.
        let err = odo.pose.inverse() * stop_iter.rest_pose();
        assert!(err.translation.vector.norm() < 1e-5, "{sent}: {err:?}");
        assert!(err.rotation.angle().abs() < 1e-5);
    }
    // Nothing sent yet: the robot rests where the step starts.
    let stop = step.stop_after(0).unwrap();
    assert_eq!(stop.rest().legs, start);
}

#[test]
fn control_rate_is_configurable() {
    let config = MotionConfig {
        control_rate_hz: 250.0,
        step_duration_s: 0.8,
        ..MotionConfig::default()
    };
    let m = StepMotion::plan(&Robot::WHEELLEG, &config, default_legs(), busy_action()).unwrap();
    assert_eq!(m.ticks(), 200);
    assert!((m.tick_s() - 0.004).abs() < 1e-7);
}

#[test]
fn a_robot_s_own_lattice_sets_its_steps() {
    let mut robot = Robot::WHEELLEG;
    robot.actions = crate::action::ActionLattice {
        move_step_m: 0.10,
        yaw_step_deg: 10.0,
        clearance_step_m: 0.04,
        track_step_m: 0.04,
    };
    let action = Action {
        move_x: Step::Plus,
        yaw: Step::Minus,
        clearance: Step::Plus,
        track: Step::Minus,
        ..Action::IDLE
    };
    let (pose, legs) = ideal_step(default_legs(), action, &robot.actions);
    assert!((pose.translation.vector.x - 0.10).abs() < 1e-6, "{pose:?}");
    assert!((pose.rotation.angle() + 10f32.to_radians()).abs() < 1e-6);
    assert!((legs.clearance_m - (default_legs().clearance_m + 0.04)).abs() < 1e-6);
    assert!((legs.track_m - (default_legs().track_m - 0.04)).abs() < 1e-6);
    // The planned motion ends there too, and the arrival test steps as far.
    let m = StepMotion::plan(&robot, &MotionConfig::default(), default_legs(), action).unwrap();
    assert_eq!(m.target(), legs);
    let target = nalgebra::Vector2::new(0.10, 0.0);
    let forward = Action {
        move_x: Step::Plus,
        ..Action::IDLE
    };
    assert!(crate::arrival::Arrival::new(target, 0.01, &robot.actions).reached_by(forward));
    assert!(
        !crate::arrival::Arrival::new(target, 0.01, &Robot::WHEELLEG.actions).reached_by(forward)
    );
    // The guard's window reaches one (longer) step farther.
    let window = |r: &Robot| {
        crate::guard::CollisionGuard::new(r, 0.0)
            .fine_window(128, 0.01)
            .cells()
    };
    assert!(window(&robot) > window(&Robot::WHEELLEG));
}
