//! The world's rules: obstacle pass/fail geometry, collision undo, reward, termination, height
//! map orientation and exactness.

use nalgebra::Point2;
use rand::{Rng, SeedableRng};
use wheelleg_runtime::action::{Action, Step};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, HEIGHT_MAP_SIDE};
use wheelleg_runtime::robot::{Robot, WHEELLEG};
use wheelleg_sim::collision::{ObstacleSet, RobotParts};
use wheelleg_sim::env::{Env, EnvConfig, InvalidAction, Observation, Status};
use wheelleg_sim::height_map::{render, render_naive};
use wheelleg_sim::obstacle::{Obstacle, ObstacleKind, ObstacleYaw};
use wheelleg_sim::reward::{INVALID_PENALTY, STEP_PENALTY};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;

fn legs(clearance_m: f32, track_m: f32) -> LegConfig {
    LegConfig {
        clearance_m,
        track_m,
    }
}

/// Whether the robot at (x, y), yaw 0, with `legs` hits any of `obstacles`.
fn hits(obstacles: &[Obstacle], x: f32, y: f32, legs: LegConfig) -> bool {
    let parts = RobotParts::new(&WHEELLEG, Point2::new(x, y), 0.0, legs).expect("reachable pose");
    ObstacleSet::new(obstacles).collides(&parts)
}

/// The robot stands with its front axle over the obstacle's centre line: the legs are where
/// an obstacle of this size must be cleared (a 0.25 m obstacle fits between the axles).
const FRONT_AXLE_OVER_X: f32 = -0.20;

#[test]
fn a_bar_is_straddled_only_with_the_body_lifted_above_it() {
    let bar = [Obstacle::new(
        ObstacleKind::Bar,
        0.0,
        0.0,
        ObstacleYaw::Deg0,
    )];
    let x = FRONT_AXLE_OVER_X;
    assert!(
        hits(&bar, x, 0.0, legs(0.12, 0.36)),
        "default clearance 0.12 < bar 0.15"
    );
    assert!(hits(&bar, x, 0.0, legs(0.14, 0.36)));
    assert!(
        !hits(&bar, x, 0.0, legs(0.16, 0.36)),
        "0.16 clears the 0.15 m bar"
    );
    assert!(
        !hits(&bar, 0.0, 0.0, legs(0.16, 0.36)),
        "and the body passes over it"
    );
    // Crosswise, the 0.25 m bar fits between the wheels only at a wide track, lifted.
    let across = [Obstacle::new(
        ObstacleKind::Bar,
        0.0,
        0.0,
        ObstacleYaw::Deg90,
    )];
    assert!(hits(&across, x, 0.0, legs(0.12, 0.36)));
    assert!(
        hits(&across, x, 0.0, legs(0.16, 0.24)),
        "narrow track: the wheels hit it"
    );
    assert!(!hits(&across, x, 0.0, legs(0.16, 0.36)));
}

#[test]
fn a_slab_is_straddled_only_with_the_legs_spread() {
    let slab = [Obstacle::new(
        ObstacleKind::Slab,
        0.0,
        0.0,
        ObstacleYaw::Deg0,
    )];
    let x = FRONT_AXLE_OVER_X;
    assert!(
        hits(&slab, x, 0.0, legs(0.12, 0.36)),
        "wheels stand on the slab"
    );
    assert!(
        hits(&slab, x, 0.0, legs(0.10, 0.46)),
        "0.46 m track still lands on a 0.45 m slab"
    );
    assert!(
        !hits(&slab, x, 0.0, legs(0.08, 0.56)),
        "spread and lowered, it straddles"
    );
    assert!(
        !hits(&slab, 0.0, 0.0, legs(0.08, 0.56)),
        "and the body passes over it"
    );
    assert!(
        hits(&slab, 0.0, 0.0, legs(0.04, 0.56)),
        "body underside 0.04 below the slab top"
    );
    assert!(
        !WHEELLEG.is_reachable(legs(0.16, 0.56)),
        "spreading fully needs the body lowered"
    );
}

#[test]
fn a_block_cannot_be_passed_over_in_any_pose() {
    let block = [Obstacle::new(
        ObstacleKind::Block,
        0.0,
        0.0,
        ObstacleYaw::Deg0,
    )];
    let mut checked = 0;
    for clearance_steps in -4..=6 {
        for track_steps in -10..=10 {
            let l = legs(
                0.12 + 0.02 * clearance_steps as f32,
                0.36 + 0.02 * track_steps as f32,
            );
            if WHEELLEG.is_reachable(l) {
                assert!(hits(&block, 0.0, 0.0, l), "body over the block: {l:?}");
                assert!(
                    hits(&block, FRONT_AXLE_OVER_X, 0.0, l),
                    "legs astride the block: {l:?}"
                );
                checked += 1;
            }
        }
    }
    assert!(checked > 100);
}

#[test]
fn a_one_cell_gap_between_blocks_needs_a_squeeze() {
    // Two blocks with one free cell between them: a 0.30 m gap centred on y = 0.
    let gap = [
        Obstacle::new(ObstacleKind::Block, 0.0, 0.25, ObstacleYaw::Deg0),
        Obstacle::new(ObstacleKind::Block, 0.0, -0.25, ObstacleYaw::Deg0),
    ];
    let x = FRONT_AXLE_OVER_X;
    assert!(
        hits(&gap, x, 0.0, legs(0.12, 0.36)),
        "default pose is 0.40 m wide"
    );
    assert!(
        hits(&gap, x, 0.0, legs(0.12, 0.30)),
        "wheels 0.34 m across the outer edges"
    );
    assert!(
        !hits(&gap, x, 0.0, legs(0.10, 0.16)),
        "narrowed and lowered, the legs fit"
    );
    assert!(
        !hits(&gap, 0.0, 0.0, legs(0.10, 0.16)),
        "and so does the body"
    );
}

fn scenario(start: RobotState, target: (f32, f32), obstacles: Vec<Obstacle>) -> Scenario {
    Scenario {
        name: "test".into(),
        start,
        target: Point2::new(target.0, target.1),
        obstacles,
    }
}

fn forward() -> Action {
    Action {
        move_x: Step::Plus,
        ..Action::IDLE
    }
}

#[test]
fn a_colliding_action_is_undone_and_penalised() {
    let block = vec![Obstacle::new(
        ObstacleKind::Block,
        0.375,
        0.0,
        ObstacleYaw::Deg0,
    )];
    let start = RobotState::new(
        Point2::new(0.0, 0.0),
        0,
        &wheelleg_runtime::action::ActionLattice::PAPER,
    );
    let mut env = Env::new(&scenario(start, (0.9, 0.0), block), EnvConfig::default()).unwrap();
    // Drive at the block until the front wheels would touch it.
    let mut outcome = env.step(forward()).unwrap();
    while outcome.invalid.is_none() {
        outcome = env.step(forward()).unwrap();
    }
    assert_eq!(outcome.invalid, Some(InvalidAction::Collision));
    let before = *env.state();
    let outcome = env.step(forward()).unwrap();
    assert_eq!(*env.state(), before, "state as before the action");
    assert_eq!(outcome.reward.invalid, INVALID_PENALTY);
    assert_eq!(outcome.reward.progress, 0.0);
    assert!((outcome.reward.total() - (STEP_PENALTY + INVALID_PENALTY)).abs() < 1e-6);
    assert!(env.collisions() >= 2);

    // A configured penalty is what an undone action pays.
    let config = EnvConfig {
        invalid_reward: -1.0,
        ..EnvConfig::default()
    };
    let block = vec![Obstacle::new(
        ObstacleKind::Block,
        0.375,
        0.0,
        ObstacleYaw::Deg0,
    )];
    let mut env = Env::new(&scenario(start, (0.9, 0.0), block), config).unwrap();
    let mut outcome = env.step(forward()).unwrap();
    while outcome.invalid.is_none() {
        assert_eq!(outcome.reward.invalid, 0.0, "a valid step pays no penalty");
        outcome = env.step(forward()).unwrap();
    }
    assert_eq!(outcome.reward.invalid, -1.0);
}

#[test]
fn an_impossible_leg_pose_is_undone_and_penalised() {
    let start = RobotState::new(
        Point2::new(0.0, 0.0),
        0,
        &wheelleg_runtime::action::ActionLattice::PAPER,
    );
    let mut env = Env::new(&scenario(start, (0.9, 0.0), vec![]), EnvConfig::default()).unwrap();
    let raise = Action {
        clearance: Step::Plus,
        ..Action::IDLE
    };
    let mut last = None;
    for _ in 0..10 {
        last = env.step(raise).unwrap().invalid;
        if last.is_some() {
            break;
        }
    }
    assert!(
        matches!(last, Some(InvalidAction::Impossible(_))),
        "{last:?}"
    );
    assert!(WHEELLEG.is_reachable(env.state().leg_config(&WHEELLEG)));
}

#[test]
fn leaving_the_arena_is_invalid() {
    let start = RobotState::new(
        Point2::new(0.0, 0.0),
        0,
        &wheelleg_runtime::action::ActionLattice::PAPER,
    );
    let config = EnvConfig {
        give_up_margin_m: 10.0,
        ..EnvConfig::default()
    };
    let mut env = Env::new(&scenario(start, (0.5, 0.0), vec![]), config).unwrap();
    let left = Action {
        move_y: Step::Plus,
        ..Action::IDLE
    };
    let mut invalid = None;
    for _ in 0..20 {
        invalid = env.step(left).unwrap().invalid;
        if invalid.is_some() {
            break;
        }
    }
    assert_eq!(invalid, Some(InvalidAction::OutOfBounds));
    assert!(env.state().position.y <= config.arena_margin_m + 1e-6);
}

#[test]
fn progress_reward_is_the_distance_gained() {
    let start = RobotState::new(
        Point2::new(0.0, 0.0),
        0,
        &wheelleg_runtime::action::ActionLattice::PAPER,
    );
    let mut env = Env::new(&scenario(start, (0.8, 0.3), vec![]), EnvConfig::default()).unwrap();
    for action in [
        forward(),
        Action {
            move_y: Step::Minus,
            ..Action::IDLE
        },
        Action {
            yaw: Step::Plus,
            ..forward()
        },
    ] {
        let before = env.distance_to_target_m();
        let outcome = env.step(action).unwrap();
        let after = env.distance_to_target_m();
        assert!((outcome.reward.progress - (before - after)).abs() < 1e-6);
        assert_eq!(outcome.reward.step, STEP_PENALTY);
        assert_eq!(outcome.reward.invalid, 0.0);
    }
}

#[test]
fn episodes_end_on_success_distance_and_step_limit() {
    let start = RobotState::new(
        Point2::new(0.0, 0.0),
        0,
        &wheelleg_runtime::action::ActionLattice::PAPER,
    );
    // Success: 0.5 m ahead, 0.05 m per step, within 0.05 m after 9 steps.
    let mut env = Env::new(&scenario(start, (0.5, 0.0), vec![]), EnvConfig::default()).unwrap();
    for i in 1..=9 {
        let status = env.step(forward()).unwrap().status;
        assert_eq!(status == Status::Success, i == 9, "step {i}");
    }
    assert!(env.step(forward()).is_err(), "no steps after the end");
    // Too far: backing away more than the give-up margin.
    let mut env = Env::new(&scenario(start, (0.5, 0.0), vec![]), EnvConfig::default()).unwrap();
    let back = Action {
        move_x: Step::Minus,
        ..Action::IDLE
    };
    let mut steps = 0;
    while env.step(back).unwrap().status == Status::Running {
        steps += 1;
    }
    assert_eq!(env.status(), Status::TooFar);
    assert_eq!(
        steps + 1,
        11,
        "0.5 m margin: the 11th step backwards gives up"
    );
    // Step limit.
    let config = EnvConfig {
        max_steps: 7,
        ..EnvConfig::default()
    };
    let mut env = Env::new(&scenario(start, (0.5, 0.0), vec![]), config).unwrap();
    let spin = Action {
        yaw: Step::Plus,
        ..Action::IDLE
    };
    for _ in 0..6 {
        assert_eq!(env.step(spin).unwrap().status, Status::Running);
    }
    assert_eq!(env.step(spin).unwrap().status, Status::StepLimit);
}

/// Sum of heights in a block of rows/columns of the map.
fn mass(
    map: &[f32; HEIGHT_MAP_CELLS],
    rows: std::ops::Range<usize>,
    cols: std::ops::Range<usize>,
) -> f32 {
    rows.flat_map(|r| cols.clone().map(move |c| (r, c)))
        .map(|(r, c)| map[r * HEIGHT_MAP_SIDE + c])
        .sum()
}

#[test]
fn the_height_map_shows_ahead_at_the_top_and_left_at_the_left() {
    let half = HEIGHT_MAP_SIDE / 2;
    for yaw_steps in [0, 9, 18, 30, 45, 63] {
        let robot = RobotState::new(
            Point2::new(0.3, -0.2),
            yaw_steps,
            &wheelleg_runtime::action::ActionLattice::PAPER,
        );
        let ahead = robot.robot_to_world(nalgebra::Vector2::new(0.5, 0.0));
        let left = robot.robot_to_world(nalgebra::Vector2::new(0.0, 0.5));
        let mut observation = Observation::default();
        for (place, expect_top, expect_left) in [(ahead, true, None), (left, false, Some(true))] {
            let obstacle = Obstacle::new(ObstacleKind::Block, place.x, place.y, ObstacleYaw::Deg0);
            let s = scenario(robot, (0.3 + 0.8, -0.2), vec![obstacle]);
            Env::new(&s, EnvConfig::default())
                .unwrap()
                .observe(&mut observation);
            let map = &observation.height_map;
            let top = mass(map, 0..half, 0..HEIGHT_MAP_SIDE);
            let bottom = mass(map, half..HEIGHT_MAP_SIDE, 0..HEIGHT_MAP_SIDE);
            let left_half = mass(map, 0..HEIGHT_MAP_SIDE, 0..half);
            let right_half = mass(map, 0..HEIGHT_MAP_SIDE, half..HEIGHT_MAP_SIDE);
            assert!(
                top + bottom > 0.0,
                "obstacle visible at yaw step {yaw_steps}"
            );
            if expect_top {
                assert!(
                    top > 0.0 && bottom == 0.0,
                    "ahead shows at the top (yaw {yaw_steps})"
                );
                assert!((left_half - right_half).abs() < 0.5 * (left_half + right_half));
            }
            if expect_left == Some(true) {
                assert!(
                    left_half > 0.0 && right_half == 0.0,
                    "left shows at the left (yaw {yaw_steps})"
                );
            }
            assert!(map.iter().all(|&h| h == 0.0 || h == 0.40));
        }
    }
}

#[test]
fn the_fast_height_map_equals_the_exact_point_sampling() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let mut fast = [0.0; HEIGHT_MAP_CELLS];
    let mut naive = [0.0; HEIGHT_MAP_CELLS];
    for _ in 0..300 {
        let obstacles: Vec<Obstacle> = (0..rng.random_range(1..12))
            .map(|_| {
                let kind = ObstacleKind::ALL[rng.random_range(0..3)];
                let yaw = if rng.random_bool(0.5) {
                    ObstacleYaw::Deg0
                } else {
                    ObstacleYaw::Deg90
                };
                let cell = |rng: &mut rand_chacha::ChaCha8Rng| {
                    (rng.random_range(-5..5) as f32 + 0.5) * 0.25
                };
                Obstacle::new(kind, cell(&mut rng), cell(&mut rng), yaw)
            })
            .collect();
        let boxes: Vec<_> = obstacles.iter().map(Obstacle::ground_box).collect();
        // Positions on and off the lattice, yaws on and off the 5 degree lattice.
        let position = Point2::new(rng.random_range(-1.0..1.0), rng.random_range(-1.0..1.0));
        let yaw = if rng.random_bool(0.5) {
            (rng.random_range(0..72) as f32 * 5.0).to_radians()
        } else {
            rng.random_range(-4.0..4.0)
        };
        render(&boxes, position, yaw, &mut fast);
        render_naive(&boxes, position, yaw, &mut naive);
        assert_eq!(fast, naive, "{obstacles:?} at {position:?} yaw {yaw}");
    }
}

#[test]
fn a_simulated_step_is_the_controllers_ideal_step() {
    use nalgebra::{Isometry2, Vector2};
    for yaw_steps in [0, 7, 18, 41, 66] {
        let start = RobotState::new(
            Point2::new(0.3, -0.2),
            yaw_steps,
            &wheelleg_runtime::action::ActionLattice::PAPER,
        );
        let start_pose = Isometry2::new(Vector2::new(0.3, -0.2), start.yaw_rad());
        let legs = start.leg_config(&WHEELLEG);
        for index in 0..wheelleg_runtime::action::COUNT {
            let action = Action::from_index(index).unwrap();
            let (delta, end_legs) =
                wheelleg_runtime::motion::ideal_step(legs, action, &Robot::WHEELLEG.actions);
            let want = start_pose * delta;
            let got = start.after(action);
            assert!((got.position.coords - want.translation.vector).norm() < 1e-6);
            let yaw_error =
                (got.yaw_rad() - want.rotation.angle()).rem_euclid(std::f32::consts::TAU);
            let wrapped = yaw_error.min(std::f32::consts::TAU - yaw_error);
            assert!(wrapped < 1e-5, "yaw off by {wrapped} rad");
            assert_eq!(got.leg_config(&WHEELLEG), end_legs);
        }
    }
}
