//! Scenario files, generator determinism, that each behaviour scene needs its behaviour, and
//! that the planner proves generated around, lift, spread and squeeze scenes solvable: for the
//! shipped robot and for the strider (`robots/strider.toml`), each on scenes fitted to it.

use nalgebra::Point2;
use rand::SeedableRng;
use wheelleg_runtime::action::{Action, Step};
use wheelleg_sim::collision::{ObstacleSet, RobotParts};
use wheelleg_sim::env::Env;
use wheelleg_sim::generate::{generate_many, Behaviour, SceneKind, SceneRobot};
use wheelleg_sim::obstacle::ObstacleKind;
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig, FALLBACK_WEIGHT};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::scenario_file::{self, ScenarioFileError};

mod common;
use common::{env_config, fence_blocks, lattice_legs, prove_solvable, robots, weighted, LegFilter};

fn rng(seed: u64) -> rand_chacha::ChaCha8Rng {
    rand_chacha::ChaCha8Rng::seed_from_u64(seed)
}

#[test]
fn the_same_seed_gives_the_same_scenes() {
    for kind in SceneKind::ALL {
        let a = generate_many(
            wheelleg_sim::generate::SceneRobot::shipped(),
            kind,
            &mut rng(11),
            20,
        );
        let b = generate_many(
            wheelleg_sim::generate::SceneRobot::shipped(),
            kind,
            &mut rng(11),
            20,
        );
        let c = generate_many(
            wheelleg_sim::generate::SceneRobot::shipped(),
            kind,
            &mut rng(12),
            20,
        );
        assert_eq!(a, b, "{}", kind.name());
        assert_ne!(a, c, "{}", kind.name());
    }
}

#[test]
fn scenario_files_round_trip_exactly() {
    let dir = std::env::temp_dir().join(format!("wheelleg-scenarios-{}", std::process::id()));
    std::fs::create_dir_all(&dir).unwrap();
    let path = dir.join("scenes.json");
    for kind in SceneKind::ALL {
        let scenes = generate_many(
            wheelleg_sim::generate::SceneRobot::shipped(),
            kind,
            &mut rng(3),
            25,
        );
        scenario_file::save(
            &path,
            &scenes,
            &wheelleg_sim::robot::SimulatedRobot::SHIPPED,
        )
        .unwrap();
        let loaded =
            scenario_file::load(&path, &wheelleg_sim::robot::SimulatedRobot::SHIPPED).unwrap();
        assert_eq!(loaded, scenes, "{}", kind.name());
    }
    std::fs::remove_dir_all(&dir).unwrap();
}

#[test]
fn the_documented_example_file_loads() {
    let json = r#"{"scenarios":[{"name":"example","robot":{"x":0.0,"y":0.0,"yaw_deg":30.0},
        "target":{"x":0.8,"y":0.0},
        "obstacles":[{"kind":"bar","x":0.375,"y":0.125,"yaw_deg":0}]}]}"#;
    let scenes = scenario_file::parse(json, &wheelleg_sim::robot::SimulatedRobot::SHIPPED).unwrap();
    assert_eq!(scenes.len(), 1);
    assert_eq!(scenes[0].obstacles[0].kind, ObstacleKind::Bar);
    assert_eq!(scenes[0].start.yaw_steps, 6);
}

/// Parses `json`, expecting a refusal whose message names every string in `names`.
fn refused(json: &str, names: &[&str]) {
    let error = scenario_file::parse(json, &wheelleg_sim::robot::SimulatedRobot::SHIPPED)
        .expect_err("must be refused");
    let message = error.to_string();
    for name in names {
        assert!(message.contains(name), "{message:?} should name {name:?}");
    }
}

fn one(robot: &str, obstacles: &str) -> String {
    format!(
        r#"{{"scenarios":[{{"name":"ok","robot":{{"x":0,"y":0,"yaw_deg":0}},"target":{{"x":0.8,"y":0}},"obstacles":[]}},
        {{"name":"bad","robot":{robot},"target":{{"x":0.8,"y":0}},"obstacles":[{obstacles}]}}]}}"#
    )
}

#[test]
fn bad_files_are_refused_naming_the_scenario_and_field() {
    let robot = r#"{"x":0,"y":0,"yaw_deg":0}"#;
    refused(
        &one(robot, r#"{"kind":"wall","x":1,"y":1,"yaw_deg":0}"#),
        &["bad", "obstacles[0].kind", "wall"],
    );
    refused(
        &one(robot, r#"{"kind":"block","x":0.125,"y":0.125,"yaw_deg":0}"#),
        &["bad", "robot", "inside an obstacle"],
    );
    refused(
        &one(r#"{"x":"NaN","y":0,"yaw_deg":0}"#, ""),
        &["scenarios[1].robot.x"],
    );
    refused(
        &one(r#"{"x":1e999,"y":0,"yaw_deg":0}"#, ""),
        &["scenarios[1].robot.x"],
    );
    refused(
        &one(r#"{"x":0,"y":0,"yaw_deg":7}"#, ""),
        &["bad", "robot.yaw_deg", "multiple of 5"],
    );
    refused(
        &one(robot, r#"{"kind":"bar","x":1,"y":1,"yaw_deg":45}"#),
        &["bad", "obstacles[0].yaw_deg"],
    );
    refused(
        &one(r#"{"x":0,"y":0}"#, ""),
        &["scenarios[1].robot", "yaw_deg"],
    );
    refused("{\"scenarios\": [", &["malformed"]);
    let missing = scenario_file::load(
        std::path::Path::new("/nonexistent/scenes.json"),
        &wheelleg_sim::robot::SimulatedRobot::SHIPPED,
    );
    assert!(matches!(missing, Err(ScenarioFileError::Io { .. })));
}

#[test]
fn each_fence_needs_its_behaviour() {
    // For each robot, its fences (fitted to it, `generate::SceneRobot`) block the legs with the
    // behaviour's dimension frozen, and let the robot through in its passing pose.
    for (name, simulated) in robots() {
        let geometry = *simulated.geometry();
        let robot = SceneRobot::of(&simulated);
        let cases: [(Behaviour, LegFilter); 3] = [
            // Lift over: blocked with the body height frozen.
            (Behaviour::LiftOver, |c, _| c == 0),
            // Spread over and squeeze: blocked with the track frozen.
            (Behaviour::SpreadOver, |_, t| t == 0),
            (Behaviour::Squeeze, |_, t| t == 0),
        ];
        for (behaviour, frozen) in cases {
            let passing = robot.passing_legs(behaviour);
            for scene in generate_many(robot, SceneKind::Behaviour(behaviour), &mut rng(5), 2) {
                assert!(
                    fence_blocks(&scene, &geometry, &lattice_legs(&simulated, frozen)),
                    "{name} {} must block frozen legs",
                    scene.name
                );
                let in_passing_pose = lattice_legs(&simulated, |c, t| (c, t) == passing);
                assert_eq!(in_passing_pose.len(), 1, "{name}: {passing:?} reachable");
                assert!(
                    !fence_blocks(&scene, &geometry, &in_passing_pose),
                    "{name} {} must let the behaviour through",
                    scene.name
                );
            }
        }
    }
}

#[test]
fn around_scenes_block_the_straight_line() {
    for (name, simulated) in robots() {
        let geometry = *simulated.geometry();
        for scene in generate_many(
            SceneRobot::of(&simulated),
            SceneKind::Behaviour(Behaviour::Around),
            &mut rng(6),
            10,
        ) {
            let obstacles = ObstacleSet::new(&scene.obstacles);
            let legs = lattice_legs(&simulated, |_, _| true);
            // Wherever the straight line crosses a block, no pose of the robot centred there
            // is free.
            let on_line = scene
                .obstacles
                .iter()
                .map(|o| Point2::new(o.centre.x, scene.start.position.y));
            let blocked = on_line.into_iter().any(|p| {
                (0..72).all(|yaw| {
                    legs.iter().all(|&l| {
                        RobotParts::new(&geometry, p, (yaw as f32 * 5.0).to_radians(), l)
                            .is_ok_and(|parts| obstacles.collides(&parts))
                    })
                })
            });
            assert!(blocked, "{name} {}", scene.name);
        }
    }
}

#[test]
fn every_robot_starts_clear_of_its_fence_at_any_yaw() {
    // The fence lead (`SceneRobot`) is sized from the robot's reach: it can turn on the spot
    // before it does anything else.
    for (name, simulated) in robots() {
        let geometry = *simulated.geometry();
        let robot = SceneRobot::of(&simulated);
        for behaviour in [
            Behaviour::Around,
            Behaviour::LiftOver,
            Behaviour::SpreadOver,
            Behaviour::Squeeze,
        ] {
            for scene in generate_many(robot, SceneKind::Behaviour(behaviour), &mut rng(8), 10) {
                let obstacles = ObstacleSet::new(&scene.obstacles);
                let legs = lattice_legs(&simulated, |c, t| (c, t) == (0, 0));
                for yaw in 0..72 {
                    let yaw_rad = (yaw as f32 * 5.0).to_radians();
                    let parts = RobotParts::new(&geometry, scene.start.position, yaw_rad, legs[0])
                        .expect("the default pose");
                    assert!(
                        !obstacles.collides(&parts),
                        "{name} {}: collides at {} degrees",
                        scene.name,
                        yaw * 5
                    );
                }
            }
        }
    }
}

#[test]
fn lined_up_starts_stay_within_their_band_and_the_draws_are_pinned() {
    use wheelleg_sim::generate::{generate, generate_with_start, StartYaw};
    let kind = SceneKind::Behaviour(Behaviour::SpreadOver);
    let mut seen_backwards = false;
    let mut r = rng(11);
    for i in 0..200 {
        let s = generate_with_start(
            wheelleg_sim::generate::SceneRobot::shipped(),
            kind,
            StartYaw::within_deg(15.0),
            &mut r,
            format!("s{i}"),
        );
        let yaw = s.start.yaw_deg().rem_euclid(360.0);
        let from_x = yaw.min((yaw - 180.0).abs()).min(360.0 - yaw);
        assert!(from_x <= 15.0 + 1e-3, "{} starts at {yaw} deg", s.name);
        seen_backwards |= (yaw - 180.0).abs() <= 15.0;
    }
    assert!(seen_backwards, "facing away from the target is drawn too");
    // The draws are pinned: one scene per kind family from a fixed seed, as the file format
    // writes it. A change to what the generator draws, or in what order, shows up here (and
    // breaks every seeded figure in docs/results.md, so it must be deliberate).
    let complex = generate(
        wheelleg_sim::generate::SceneRobot::shipped(),
        SceneKind::Complex,
        &mut rng(5),
        "c0".to_string(),
    );
    let lift = generate(
        wheelleg_sim::generate::SceneRobot::shipped(),
        SceneKind::Behaviour(Behaviour::LiftOver),
        &mut rng(5),
        "l0".to_string(),
    );
    for (scene, golden) in [(complex, GOLDEN_COMPLEX), (lift, GOLDEN_LIFT)] {
        assert_eq!(
            compact(&scenario_file::to_json(
                &[scene],
                &wheelleg_sim::robot::SimulatedRobot::SHIPPED
            )),
            golden
        );
    }
    // `within_deg(90)` is `Any`: the same draws give the same scene.
    let wide = generate_with_start(
        wheelleg_sim::generate::SceneRobot::shipped(),
        SceneKind::Complex,
        StartYaw::within_deg(90.0),
        &mut rng(5),
        "c0".to_string(),
    );
    assert_eq!(
        compact(&scenario_file::to_json(
            &[wide],
            &wheelleg_sim::robot::SimulatedRobot::SHIPPED
        )),
        GOLDEN_COMPLEX
    );
}

/// A scenario file without its layout whitespace (names here have no spaces).
fn compact(json: &str) -> String {
    json.split_whitespace().collect()
}

/// `generate(wheelleg_sim::generate::SceneRobot::shipped(), SceneKind::Complex, seed 5, "c0")` as a scenario file.
const GOLDEN_COMPLEX: &str = r#"{"scenarios":[{"name":"c0","robot":{"x":-0.025,"y":-0.025,"yaw_deg":95.0},"target":{"x":0.825,"y":-0.025},"obstacles":[{"kind":"block","x":1.125,"y":-0.375,"yaw_deg":90.0},{"kind":"bar","x":1.375,"y":0.625,"yaw_deg":0.0},{"kind":"block","x":0.125,"y":0.375,"yaw_deg":90.0},{"kind":"block","x":0.125,"y":-0.375,"yaw_deg":0.0}]}]}"#;

/// `generate(wheelleg_sim::generate::SceneRobot::shipped(), lift, seed 5, "l0")` as a scenario file.
const GOLDEN_LIFT: &str = concat!(
    r#"{"scenarios":[{"name":"l0","robot":{"x":-0.025,"y":-0.025,"yaw_deg":95.0},"targe"#,
    r#"t":{"x":0.925,"y":-0.025},"obstacles":["#,
    r#"{"kind":"bar","x":0.625,"y":-1.625,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":-1.375,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":-1.125,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":-0.875,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":-0.625,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":-0.375,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":-0.125,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":0.125,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":0.375,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":0.625,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":0.875,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":1.125,"yaw_deg":0.0},"#,
    r#"{"kind":"bar","x":0.625,"y":1.375,"yaw_deg":0.0}]}]}"#,
);

#[test]
fn generated_spread_scenes_are_solvable() {
    // The planner proves it: a plan it returns has been replayed to success in the simulator.
    // Exact search does not finish on spread scenes (docs/planner.md), so this is the weighted
    // search the fallback runs, which finds them in a few hundred expansions at most.
    let config = PlannerConfig {
        max_expansions: 3_000,
        heuristic_weight: FALLBACK_WEIGHT,
        ..PlannerConfig::default()
    };
    for (name, simulated) in robots() {
        let robot = SceneRobot::of(&simulated);
        let (_, spread) = robot.passing_legs(Behaviour::SpreadOver);
        for scene in generate_many(
            robot,
            SceneKind::Behaviour(Behaviour::SpreadOver),
            &mut rng(21),
            20,
        ) {
            let env = Env::new(&scene, env_config(&simulated)).unwrap();
            let found = plan(&env, &config);
            match found.outcome {
                PlanOutcome::Solved { actions, shortest } => {
                    assert!(
                        !shortest,
                        "{name} {}: a weighted plan is not proven shortest",
                        scene.name
                    );
                    // The fence needs the legs spread: the plan widens them most of the way
                    // to the passing pose.
                    let widened = actions.iter().filter(|a| a.track == Step::Plus).count();
                    assert!(
                        widened as i32 >= spread / 2,
                        "{name} {}: only {widened} track steps",
                        scene.name
                    );
                }
                other => panic!(
                    "{name} {}: {other:?} after {} expansions",
                    scene.name, found.expansions
                ),
            }
        }
    }
}

#[test]
fn generated_around_scenes_are_solvable() {
    // Going around needs no leg change: the legs stay in the default pose, which makes a node
    // one pose (27 moves to try, not hundreds of leg variants). The fallback's weight (3)
    // wanders in front of the block on some scenes; 5 finds all 20 in a few thousand
    // expansions at most.
    let config = weighted(5.0).restricted(|a| a.clearance == Step::Zero && a.track == Step::Zero);
    for (name, simulated) in robots() {
        let scenes = generate_many(
            SceneRobot::of(&simulated),
            SceneKind::Behaviour(Behaviour::Around),
            &mut rng(21),
            20,
        );
        let paths = prove_solvable(&scenes, &simulated, |_| Vec::new(), &[config]);
        for (scene, path) in scenes.iter().zip(paths) {
            // The block stands on the straight line (`around_scenes_block_the_straight_line`):
            // the plan leaves it by more than the block's half width.
            let y0 = scene.start.position.y;
            let off_m = path
                .iter()
                .map(|s| (s.position.y - y0).abs())
                .fold(0.0f32, f32::max);
            assert!(off_m > 0.1, "{name} {}: {off_m} m off the line", scene.name);
        }
    }
}

#[test]
fn generated_lift_scenes_are_solvable() {
    // The search the fallback runs, every action allowed: it finds each in a few hundred
    // expansions at most.
    let config = weighted(FALLBACK_WEIGHT);
    for (name, simulated) in robots() {
        let scenes = generate_many(
            SceneRobot::of(&simulated),
            SceneKind::Behaviour(Behaviour::LiftOver),
            &mut rng(21),
            20,
        );
        let paths = prove_solvable(&scenes, &simulated, |_| Vec::new(), &[config]);
        for (scene, path) in scenes.iter().zip(paths) {
            // The fence blocks the default height (`each_fence_needs_its_behaviour`): the plan
            // lifts the body.
            let lifted = path.iter().map(|s| s.clearance_steps).max().unwrap_or(0);
            assert!(lifted >= 1, "{name} {}: lifted {lifted} steps", scene.name);
        }
    }
}

#[test]
fn generated_squeeze_scenes_are_solvable() {
    // The weighted search over every action runs out of 20,000 expansions on some scenes (so
    // does it over poses alone with the legs narrowed where they stand): the 0.30 m corridor
    // takes a pose lined up to a few degrees and centimetres, and the search widens over every
    // pose in front of it. So the plan is built in two parts. First, in place at the start (the
    // fence lead lets the robot turn there), turn the short way to face along x (towards or
    // away from the target) and move the legs to the passing pose (`SceneRobot::passing_legs`:
    // the shipped robot's track 0.20 m, the strider's ten track steps narrower and one
    // clearance step lower). Then the planner, legs frozen in that pose (a node is one pose).
    // The shipped robot's plans come from the fallback's weight in a few thousand expansions at
    // most. The strider's corridor leaves 15 mm each side at yaw 0 and none a yaw step off, and
    // which weight dives through it depends on the scene: the first of five that finds a plan
    // proves it (64,000 expansions at most over them). With the heading frozen too, some scenes
    // are unsolvable: a target just past the fence cannot be reached without turning while the
    // rear wheels are still in the corridor. The whole sequence is replayed in a fresh episode.
    let configs = [FALLBACK_WEIGHT, 2.0, 5.0, 1.5, 8.0]
        .map(|w| weighted(w).restricted(|a| a.clearance == Step::Zero && a.track == Step::Zero));
    for (name, simulated) in robots() {
        let robot = SceneRobot::of(&simulated);
        let (clearance_steps, track_steps) = robot.passing_legs(Behaviour::Squeeze);
        let prefix = |scene: &Scenario| {
            let yaw = scene.start.yaw_steps.rem_euclid(72);
            let (turn, turns) = match yaw {
                0..=18 => (Step::Minus, yaw),
                19..=35 => (Step::Plus, 36 - yaw),
                36..=53 => (Step::Minus, yaw - 36),
                _ => (Step::Plus, 72 - yaw),
            };
            let step = |steps: i32| if steps < 0 { Step::Minus } else { Step::Plus };
            let mut actions = vec![
                Action {
                    yaw: turn,
                    ..Action::IDLE
                };
                turns as usize
            ];
            // Lower first, then narrow: every pose on the way is one the legs reach.
            actions.extend(vec![
                Action {
                    clearance: step(clearance_steps),
                    ..Action::IDLE
                };
                clearance_steps.unsigned_abs() as usize
            ]);
            actions.extend(vec![
                Action {
                    track: step(track_steps),
                    ..Action::IDLE
                };
                track_steps.unsigned_abs() as usize
            ]);
            actions
        };
        let scenes = generate_many(
            robot,
            SceneKind::Behaviour(Behaviour::Squeeze),
            &mut rng(21),
            20,
        );
        let paths = prove_solvable(&scenes, &simulated, prefix, &configs);
        for (scene, path) in scenes.iter().zip(paths) {
            // The fence blocks the default track (`each_fence_needs_its_behaviour`): the plan
            // crosses it narrowed.
            let last = path.last().expect("a path");
            assert_eq!(last.track_steps, track_steps, "{name} {}", scene.name);
        }
    }
}
