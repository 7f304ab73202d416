//! A robot on another action lattice than the paper's: its states step by its own lattice, the
//! generators build its scenes on its start and yaw lattices, scene files read and write on it,
//! the planner's answers match an independent breadth-first search over its states, and a scene
//! made on one lattice is refused by an episode on another.
//!
//! Run in release mode (`cargo test --release -p wheelleg-sim --test lattice`): seconds.

mod common;

use common::{brute_force, shortest};
use nalgebra::Point2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::action::{Action, ActionLattice, Step};
use wheelleg_runtime::robot::WHEELLEG;
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::generate::{generate_many, SceneKind, SceneRobot};
use wheelleg_sim::obstacle::{Obstacle, ObstacleKind, ObstacleYaw};
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig};
use wheelleg_sim::robot::SimulatedRobot;
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::scenario_file;
use wheelleg_sim::state::RobotState;

/// The shipped robot's body on a coarser lattice: 6.25 cm moves (four to a scene cell), 7.5
/// degree turns (48 to a full turn), 2 cm of clearance and 3 cm of track per step.
const COARSE: ActionLattice = ActionLattice {
    move_step_m: 0.0625,
    yaw_step_deg: 7.5,
    clearance_step_m: 0.02,
    track_step_m: 0.03,
};

fn coarse() -> SimulatedRobot {
    SimulatedRobot::new(WHEELLEG, COARSE).expect("divides the quarter turn and the cell")
}

fn rules() -> EnvConfig {
    EnvConfig {
        robot: coarse(),
        ..EnvConfig::default()
    }
}

#[test]
fn a_state_steps_by_its_own_lattice() {
    let start = RobotState::new(Point2::new(0.0, 0.0), 0, &COARSE);
    let ahead = start.after(Action {
        move_x: Step::Plus,
        track: Step::Minus,
        ..Action::IDLE
    });
    assert_eq!(ahead.position, Point2::new(0.0625, 0.0));
    let legs = ahead.leg_config(&WHEELLEG);
    assert!((legs.track_m - (WHEELLEG.default_track_m - 0.03)).abs() < 1e-6);
    let turn = Action {
        yaw: Step::Plus,
        ..Action::IDLE
    };
    let mut state = start;
    for _ in 0..12 {
        state = state.after(turn);
    }
    assert!((state.yaw_deg() - 90.0).abs() < 1e-4);
    for _ in 0..36 {
        state = state.after(turn);
    }
    assert_eq!(state, start, "48 turns of 7.5 degrees are a full turn");
}

#[test]
fn scenes_start_on_the_robots_lattices_and_read_back_for_it_alone() {
    let robot = SceneRobot::of(&coarse());
    let mut rng = ChaCha8Rng::seed_from_u64(11);
    for kind in SceneKind::ALL {
        if robot.has_kind(kind).is_err() {
            continue;
        }
        let scenes = generate_many(robot, kind, &mut rng, 4);
        for scene in &scenes {
            scene.validate(&coarse()).unwrap();
            assert_eq!(scene.start.lattice, COARSE);
            // Start and target on whole move steps, so that every cell centre (0.125 +
            // 0.25 k, an even number of steps) is on the same lattice.
            for value_m in [
                scene.start.position.x,
                scene.start.position.y,
                scene.target.x,
                scene.target.y,
            ] {
                let steps = value_m / 0.0625;
                assert!(
                    (steps - steps.round()).abs() < 1e-3,
                    "{}: {value_m}",
                    scene.name
                );
            }
        }
        let json = scenario_file::to_json(&scenes, &coarse());
        assert_eq!(scenario_file::parse(&json, &coarse()).unwrap(), scenes);
        // The shipped robot steps 5 degrees: a start at 7.5 degrees is not on its lattice.
        if scenes.iter().any(|s| s.start.yaw_steps % 2 == 1) {
            let error = scenario_file::parse(&json, &SimulatedRobot::SHIPPED).unwrap_err();
            assert!(
                error.to_string().contains("multiple of 5 degrees"),
                "{error}"
            );
        }
    }
}

#[test]
fn an_episode_refuses_a_scene_made_on_another_lattice() {
    let scene = Scenario {
        name: "paper".into(),
        start: RobotState::new(Point2::new(0.0, 0.125), 0, &ActionLattice::PAPER),
        target: Point2::new(0.75, 0.125),
        obstacles: Vec::new(),
    };
    let error = Env::new(&scene, rules()).unwrap_err();
    assert_eq!(error.field, "robot");
    assert!(error.problem.contains("another action lattice"), "{error}");
}

fn episode(obstacles: Vec<Obstacle>) -> Env {
    let scene = Scenario {
        name: "coarse".into(),
        start: RobotState::new(Point2::new(-0.125, 0.125), 0, &COARSE),
        target: Point2::new(0.75, 0.125),
        obstacles,
    };
    Env::new(&scene, rules()).unwrap()
}

#[test]
fn the_planner_matches_brute_force_on_the_robots_lattice() {
    // Around a block on moves alone.
    let env = episode(vec![Obstacle::new(
        ObstacleKind::Block,
        0.375,
        0.125,
        ObstacleYaw::Deg0,
    )]);
    let moves_only = PlannerConfig::default()
        .restricted(|a| a.yaw == Step::Zero && a.clearance == Step::Zero && a.track == Step::Zero);
    let expected = brute_force(&env, &moves_only, 30).expect("the detour exists");
    // 0.875 m straight is 14 steps of 6.25 cm: the block forces more.
    assert!(expected > 14, "{expected}");
    assert_eq!(shortest(&env, &moves_only), expected);

    // Over a bar, straight ahead with the legs free: lifting by 2 cm steps passes it.
    let env = episode(vec![Obstacle::new(
        ObstacleKind::Bar,
        0.375,
        0.125,
        ObstacleYaw::Deg0,
    )]);
    let along_x =
        PlannerConfig::default().restricted(|a| a.move_y == Step::Zero && a.yaw == Step::Zero);
    let expected = brute_force(&env, &along_x, 30).expect("lifting passes the bar");
    assert_eq!(shortest(&env, &along_x), expected);
    let frozen = PlannerConfig::default()
        .restricted(|a| a.move_y == Step::Zero && a.yaw == Step::Zero && a.clearance == Step::Zero);
    assert_eq!(plan(&env, &frozen).outcome, PlanOutcome::Unsolvable);
}
