//! The start-stage curriculum's generator (`generate::generate_staged`) and the scenario file's
//! start leg pose.

use rand::SeedableRng;
use wheelleg_runtime::action::{Action, Step};
use wheelleg_sim::env::{Env, EnvConfig, Status};
use wheelleg_sim::generate::{
    generate_staged, generate_with_start, Behaviour, SceneKind, StartYaw,
};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::scenario_file;

fn rng(seed: u64) -> rand_chacha::ChaCha8Rng {
    rand_chacha::ChaCha8Rng::seed_from_u64(seed)
}

const PASSAGES: [Behaviour; 4] = [
    Behaviour::Around,
    Behaviour::LiftOver,
    Behaviour::SpreadOver,
    Behaviour::Squeeze,
];

#[test]
fn stage_one_is_the_normal_generator() {
    for kind in SceneKind::ALL {
        for start_yaw in [StartYaw::Any, StartYaw::within_deg(15.0)] {
            let (mut a, mut b) = (rng(21), rng(21));
            for i in 0..30 {
                let name = format!("s{i}");
                assert_eq!(
                    generate_staged(
                        wheelleg_sim::generate::SceneRobot::shipped(),
                        kind,
                        start_yaw,
                        1.0,
                        &mut a,
                        name.clone()
                    ),
                    generate_with_start(
                        wheelleg_sim::generate::SceneRobot::shipped(),
                        kind,
                        start_yaw,
                        &mut b,
                        name
                    ),
                    "{} scene {i}",
                    kind.name()
                );
            }
        }
    }
}

/// Drives the robot straight ahead (towards the target along x, in whichever direction it
/// faces) until its centre is 0.3 m past the last obstacle row; `Err` names the first step
/// that was undone.
fn drive_through(scene: &Scenario) -> Result<u32, String> {
    let rules = EnvConfig {
        max_steps: 200,
        // Never end early: the test is whether the whole passage is free, not the target.
        success_radius_m: -1.0,
        give_up_margin_m: 100.0,
        arena_margin_m: 100.0,
        ..EnvConfig::default()
    };
    let mut env = Env::new(scene, rules).map_err(|e| e.to_string())?;
    let facing_target = scene.start.yaw_rad().cos() > 0.0;
    let action = Action {
        move_x: if facing_target {
            Step::Plus
        } else {
            Step::Minus
        },
        ..Action::default()
    };
    let beyond_m = scene
        .obstacles
        .iter()
        .map(|o| o.centre.x)
        .fold(f32::MIN, f32::max)
        + 0.3;
    let mut steps = 0;
    while env.state().position.x < beyond_m {
        let outcome = env.step(action).map_err(|_| "episode over".to_string())?;
        steps += 1;
        if let Some(why) = outcome.invalid {
            return Err(format!(
                "step {steps} at x = {:.3}: {why:?}",
                env.state().position.x
            ));
        }
        if outcome.status != Status::Running {
            return Err(format!("ended {:?}", outcome.status));
        }
    }
    Ok(steps)
}

#[test]
fn stage_zero_starts_lined_up_in_the_passing_pose_and_drives_through() {
    for behaviour in PASSAGES {
        let kind = SceneKind::Behaviour(behaviour);
        let mut r = rng(7);
        for i in 0..40 {
            let scene = generate_staged(
                wheelleg_sim::generate::SceneRobot::shipped(),
                kind,
                StartYaw::Any,
                0.0,
                &mut r,
                format!("z{i}"),
            );
            let (clearance, track) =
                wheelleg_sim::generate::SceneRobot::shipped().passing_legs(behaviour);
            assert_eq!(
                (scene.start.clearance_steps, scene.start.track_steps),
                (clearance, track),
                "{}",
                scene.name
            );
            assert_eq!(scene.start.yaw_steps % 36, 0, "lined up: {}", scene.name);
            scene
                .validate(&wheelleg_sim::robot::SimulatedRobot::SHIPPED)
                .unwrap();
            // The drive is a real test: in the default pose the same start does not get through.
            if behaviour != Behaviour::Around {
                let mut plain = scene.clone();
                (plain.start.clearance_steps, plain.start.track_steps) = (0, 0);
                assert!(drive_through(&plain).is_err(), "{}", scene.name);
            }
            if let Err(e) = drive_through(&scene) {
                panic!(
                    "{} {}: {e}\n{}",
                    behaviour.name(),
                    scene.name,
                    scenario_file::to_json(
                        std::slice::from_ref(&scene),
                        &wheelleg_sim::robot::SimulatedRobot::SHIPPED
                    )
                );
            }
        }
    }
}

#[test]
fn every_stage_keeps_the_scene_and_moves_only_the_start() {
    for behaviour in PASSAGES {
        let kind = SceneKind::Behaviour(behaviour);
        let (clearance, track) =
            wheelleg_sim::generate::SceneRobot::shipped().passing_legs(behaviour);
        for tenth in 0..10 {
            let stage = tenth as f32 / 10.0;
            let (mut a, mut b) = (rng(100 + tenth), rng(100 + tenth));
            for i in 0..20 {
                let name = format!("t{i}");
                let staged = generate_staged(
                    wheelleg_sim::generate::SceneRobot::shipped(),
                    kind,
                    StartYaw::Any,
                    stage,
                    &mut a,
                    name.clone(),
                );
                let drawn = generate_with_start(
                    wheelleg_sim::generate::SceneRobot::shipped(),
                    kind,
                    StartYaw::Any,
                    &mut b,
                    name,
                );
                assert_eq!(staged.obstacles, drawn.obstacles);
                assert_eq!(staged.target, drawn.target);
                Env::new(&staged, EnvConfig::default()).unwrap();
                // No start fell back to the drawn one: the legs follow the schedule.
                let relax = (2.0 * stage - 1.0).max(0.0);
                let expected = (
                    (clearance as f32 * (1.0 - relax)).round() as i32,
                    (track as f32 * (1.0 - relax)).round() as i32,
                );
                assert_eq!(
                    (staged.start.clearance_steps, staged.start.track_steps),
                    expected,
                    "{} stage {stage} {}",
                    behaviour.name(),
                    staged.name
                );
                assert!(staged.start.position.x <= drawn.target.x - 0.2);
            }
        }
    }
}

#[test]
fn the_same_seed_and_stage_give_the_same_scenes() {
    let kind = SceneKind::Behaviour(Behaviour::SpreadOver);
    let draw = |seed, stage| {
        let mut r = rng(seed);
        (0..20)
            .map(|i| {
                generate_staged(
                    wheelleg_sim::generate::SceneRobot::shipped(),
                    kind,
                    StartYaw::Any,
                    stage,
                    &mut r,
                    format!("d{i}"),
                )
            })
            .collect::<Vec<_>>()
    };
    assert_eq!(draw(3, 0.3), draw(3, 0.3));
    assert_ne!(draw(3, 0.3), draw(3, 0.7));
    assert_ne!(draw(3, 0.3), draw(4, 0.3));
}

#[test]
fn start_leg_poses_round_trip_and_default_ones_are_not_written() {
    let kind = SceneKind::Behaviour(Behaviour::SpreadOver);
    let mut r = rng(5);
    let scenes: Vec<Scenario> = (0..10)
        .map(|i| {
            generate_staged(
                wheelleg_sim::generate::SceneRobot::shipped(),
                kind,
                StartYaw::Any,
                0.1 * i as f32,
                &mut r,
                format!("p{i}"),
            )
        })
        .collect();
    assert!(scenes.iter().any(|s| s.start.track_steps == 10));
    let json = scenario_file::to_json(&scenes, &wheelleg_sim::robot::SimulatedRobot::SHIPPED);
    assert!(json.contains("\"track_m\": 0.56"), "{json}");
    assert!(json.contains("\"clearance_m\": 0.08"), "{json}");
    assert_eq!(
        scenario_file::parse(&json, &wheelleg_sim::robot::SimulatedRobot::SHIPPED).unwrap(),
        scenes
    );
    // Default poses: the file is as before the fields existed.
    let plain = wheelleg_sim::generate::generate_many(
        wheelleg_sim::generate::SceneRobot::shipped(),
        kind,
        &mut rng(5),
        5,
    );
    let json = scenario_file::to_json(&plain, &wheelleg_sim::robot::SimulatedRobot::SHIPPED);
    assert!(!json.contains("clearance_m") && !json.contains("track_m"));
    assert_eq!(
        scenario_file::parse(&json, &wheelleg_sim::robot::SimulatedRobot::SHIPPED).unwrap(),
        plain
    );
}

fn one(robot: &str, obstacles: &str) -> String {
    format!(
        r#"{{"scenarios":[{{"name":"pose","robot":{{{robot}}},"target":{{"x":0.8,"y":0.0}},
        "obstacles":[{obstacles}]}}]}}"#
    )
}

fn refused(json: &str, names: &[&str]) {
    let message = scenario_file::parse(json, &wheelleg_sim::robot::SimulatedRobot::SHIPPED)
        .expect_err("must be refused")
        .to_string();
    for name in names {
        assert!(message.contains(name), "{message:?} should name {name:?}");
    }
}

#[test]
fn bad_start_leg_poses_are_refused_naming_the_field() {
    let ok = one(
        r#""x":0,"y":0,"yaw_deg":0,"clearance_m":0.08,"track_m":0.56"#,
        "",
    );
    let scene =
        &scenario_file::parse(&ok, &wheelleg_sim::robot::SimulatedRobot::SHIPPED).unwrap()[0];
    assert_eq!(
        (scene.start.clearance_steps, scene.start.track_steps),
        (-2, 10)
    );
    // Off the 0.02 m lattice.
    refused(
        &one(r#""x":0,"y":0,"yaw_deg":0,"clearance_m":0.13"#, ""),
        &["\"pose\"", "robot.clearance_m", "lattice"],
    );
    refused(
        &one(r#""x":0,"y":0,"yaw_deg":0,"track_m":0.37"#, ""),
        &["robot.track_m", "lattice"],
    );
    // On the lattice but beyond what the legs reach.
    refused(
        &one(r#""x":0,"y":0,"yaw_deg":0,"track_m":0.60"#, ""),
        &["robot.track_m", "unreachable"],
    );
    refused(
        &one(r#""x":0,"y":0,"yaw_deg":0,"clearance_m":0.30"#, ""),
        &["robot.clearance_m", "unreachable"],
    );
    refused(
        &one(r#""x":0,"y":0,"yaw_deg":0,"track_m":"wide""#, ""),
        &["robot.track_m"],
    );
    // A block beside the robot: clear of the default pose, hit by the spread one.
    let block = r#"{"kind":"block","x":0.2,"y":0.35,"yaw_deg":0}"#;
    scenario_file::parse(
        &one(r#""x":0,"y":0,"yaw_deg":0"#, block),
        &wheelleg_sim::robot::SimulatedRobot::SHIPPED,
    )
    .unwrap();
    refused(
        &one(
            r#""x":0,"y":0,"yaw_deg":0,"clearance_m":0.08,"track_m":0.56"#,
            block,
        ),
        &["robot", "inside an obstacle", "track 0.56"],
    );
}
