//! Planner optimality and completeness on small hand-made cases, checked against hand
//! arguments and against an independent breadth-first search over full robot states that uses
//! nothing but the simulator's own `check_transition`.
//!
//! Run in release mode (`cargo test --release -p wheelleg-sim`): a few seconds.

mod common;

use common::{brute_force, brute_force_within, shortest};
use nalgebra::Point2;
use wheelleg_runtime::action::{Action, Step};
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::generate::{generate_many, Behaviour, SceneKind};
use wheelleg_sim::obstacle::{Obstacle, ObstacleKind, ObstacleYaw};
use wheelleg_sim::planner::{plan, plan_with_fallback, plan_within, PlanOutcome, PlannerConfig};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;

fn scene(
    start: (f32, f32),
    yaw_steps: i32,
    target: (f32, f32),
    obstacles: Vec<Obstacle>,
) -> Scenario {
    Scenario {
        name: "hand-made".to_string(),
        start: RobotState::new(
            Point2::new(start.0, start.1),
            yaw_steps,
            &wheelleg_runtime::action::ActionLattice::PAPER,
        ),
        target: Point2::new(target.0, target.1),
        obstacles,
    }
}

fn block(x: f32, y: f32) -> Obstacle {
    Obstacle::new(ObstacleKind::Block, x, y, ObstacleYaw::Deg0)
}

#[test]
fn straight_ahead_at_yaw_zero_takes_eight_steps() {
    // 0.45 m to the success circle: nine straight steps, but turning towards a diagonal heading
    // while moving pays off already: the brute force over every base move (legs frozen, they
    // cannot help in open space) finds eight, and no plan of seven.
    let env = Env::new(
        &scene((0.025, 0.025), 0, (0.525, 0.025), vec![]),
        EnvConfig::default(),
    )
    .unwrap();
    assert_eq!(shortest(&env, &PlannerConfig::default()), 8);
    let legs_frozen =
        PlannerConfig::default().restricted(|a| a.clearance == Step::Zero && a.track == Step::Zero);
    assert_eq!(shortest(&env, &legs_frozen), 8);
    assert_eq!(brute_force(&env, &legs_frozen, 8), Some(8));
    let no_turn = PlannerConfig::default().restricted(|a| a.yaw == Step::Zero);
    assert_eq!(
        shortest(&env, &no_turn),
        9,
        "without turning, nine straight steps"
    );
}

#[test]
fn diagonal_target_takes_ten_diagonal_steps() {
    // 0.707 m away: at most 0.0707 m per step, so at least ceil(0.657 / 0.0707) = 10 steps;
    // ten diagonal moves land exactly on the target.
    let env = Env::new(
        &scene((0.025, 0.025), 0, (0.525, 0.525), vec![]),
        EnvConfig::default(),
    )
    .unwrap();
    assert_eq!(shortest(&env, &PlannerConfig::default()), 10);
}

#[test]
fn target_straight_ahead_at_minus_45_degrees_is_seven_diagonal_steps() {
    // Facing -45 degrees, the robot's (forward, left) diagonal points along world x: 0.45 m at
    // 0.0707 m per step is 7 steps, and no step is longer.
    let env = Env::new(
        &scene((0.025, 0.025), -9, (0.525, 0.025), vec![]),
        EnvConfig::default(),
    )
    .unwrap();
    assert_eq!(shortest(&env, &PlannerConfig::default()), 7);
}

/// A block right on the line to the target, and a planner with yaw and legs frozen so that
/// the reference search stays small.
fn detour_scene() -> (Env, PlannerConfig) {
    let env = Env::new(
        &scene(
            (-0.125, 0.125),
            0,
            (0.725, 0.125),
            vec![block(0.375, 0.125)],
        ),
        EnvConfig::default(),
    )
    .unwrap();
    let moves_only = PlannerConfig::default()
        .restricted(|a| a.yaw == Step::Zero && a.clearance == Step::Zero && a.track == Step::Zero);
    (env, moves_only)
}

#[test]
fn detour_around_a_block_matches_brute_force() {
    let (env, moves_only) = detour_scene();
    let expected = brute_force(&env, &moves_only, 40).expect("the detour exists");
    assert!(
        expected > 16,
        "the block must force a detour, got {expected}"
    );
    assert_eq!(shortest(&env, &moves_only), expected);
}

/// A search from a state mid-episode, farther from the target than the start, keeps to the
/// episode's give-up distance: one counted from the current state would allow a detour that
/// the episode ends as too far (the stack's look-ahead and the expert labeller plan from there).
#[test]
fn a_search_mid_episode_keeps_the_episodes_give_up_distance() {
    let (_, moves_only) = detour_scene();
    let back = Action {
        move_x: Step::Minus,
        ..Action::IDLE
    };
    // The robot stands in a pocket open behind it: the way out backs away from the target,
    // past the start, before it turns towards it.
    let pocket = (-1..=3)
        .map(|j| block(0.375, -0.375 + 0.25 * j as f32))
        .chain(
            [-0.125, 0.125]
                .into_iter()
                .flat_map(|x| [block(x, -0.375), block(x, 0.625)]),
        )
        .collect::<Vec<_>>();
    let mut binding = 0;
    for margin_cm in (5..=100).step_by(5) {
        let mut env = Env::new(
            &scene((-0.125, 0.125), 0, (0.725, 0.125), pocket.clone()),
            EnvConfig {
                give_up_margin_m: margin_cm as f32 / 100.0,
                // Room for the way round the pocket.
                arena_margin_m: 1.5,
                ..EnvConfig::default()
            },
        )
        .unwrap();
        for _ in 0..4 {
            if env.step(back).is_err() {
                break;
            }
        }
        if env.status().is_done() {
            continue;
        }
        let expected = brute_force(&env, &moves_only, 60);
        let from_here = brute_force_within(
            &env,
            &moves_only,
            60,
            env.distance_to_target_m() + env.config().give_up_margin_m,
        );
        binding += usize::from(expected != from_here);
        // `plan` replays what it finds in the episode's rules and panics where that fails.
        let found = match plan(&env, &moves_only).outcome {
            PlanOutcome::Solved { actions, .. } => Some(actions.len()),
            _ => None,
        };
        assert_eq!(found, expected, "give-up margin {margin_cm} cm");
    }
    assert!(
        binding > 0,
        "no margin where the episode's give-up distance binds: the test checks nothing"
    );
}

#[test]
fn a_step_limit_below_the_shortest_way_proves_none_that_short() {
    let (env, config) = detour_scene();
    let steps = shortest(&env, &config);
    let at = plan_within(&env, &config, steps as u32);
    match at.outcome {
        PlanOutcome::Solved { actions, shortest } => {
            assert_eq!(actions.len(), steps);
            assert!(shortest);
        }
        other => panic!("a way of {steps} steps exists: {other:?}"),
    }
    let below = plan_within(&env, &config, steps as u32 - 1);
    assert_eq!(below.outcome, PlanOutcome::Unsolvable);
    // The limit prunes: proving that nothing is shorter costs less than finding the way.
    assert!(
        below.expansions < plan(&env, &config).expansions,
        "{} against {}",
        below.expansions,
        plan(&env, &config).expansions
    );
}

/// Two blocks leave a 0.30 m gap centred on y = 0.125, narrower than the default pose.
fn squeeze_scene() -> Scenario {
    scene(
        (-0.075, 0.125),
        0,
        (0.725, 0.125),
        vec![block(0.375, -0.125), block(0.375, 0.375)],
    )
}

#[test]
fn squeeze_needs_leg_changes_and_matches_brute_force() {
    let env = Env::new(&squeeze_scene(), EnvConfig::default()).unwrap();
    // Straight ahead only (no sideways move, no turn), legs free: the reference search is
    // over x and the two leg dimensions.
    let along_x =
        PlannerConfig::default().restricted(|a| a.move_y == Step::Zero && a.yaw == Step::Zero);
    let expected = brute_force(&env, &along_x, 40).expect("narrowing the legs passes the gap");
    assert_eq!(shortest(&env, &along_x), expected);
    let frozen_track = PlannerConfig::default()
        .restricted(|a| a.move_y == Step::Zero && a.yaw == Step::Zero && a.track == Step::Zero);
    assert_eq!(plan(&env, &frozen_track).outcome, PlanOutcome::Unsolvable);
}

#[test]
fn lift_over_a_bar_matches_brute_force_and_needs_clearance() {
    // A bar lengthwise under the robot's path: pass only by straddling it, body lifted.
    let bar = Obstacle::new(ObstacleKind::Bar, 0.375, 0.125, ObstacleYaw::Deg0);
    let env = Env::new(
        &scene((-0.075, 0.125), 0, (0.725, 0.125), vec![bar]),
        EnvConfig::default(),
    )
    .unwrap();
    let along_x =
        PlannerConfig::default().restricted(|a| a.move_y == Step::Zero && a.yaw == Step::Zero);
    let expected = brute_force(&env, &along_x, 40).expect("lifting passes the bar");
    assert_eq!(shortest(&env, &along_x), expected);
    let frozen_clearance = PlannerConfig::default()
        .restricted(|a| a.move_y == Step::Zero && a.yaw == Step::Zero && a.clearance == Step::Zero);
    assert_eq!(
        plan(&env, &frozen_clearance).outcome,
        PlanOutcome::Unsolvable
    );
}

#[test]
fn enclosed_target_is_unsolvable() {
    // Blocks on the eight cells around the target's cell: the robot (0.5 m long) cannot get in.
    let (tx, ty) = (0.625, 0.125);
    let ring: Vec<Obstacle> = [-1, 0, 1]
        .iter()
        .flat_map(|&i| [-1, 0, 1].map(|j| (i, j)))
        .filter(|&(i, j)| (i, j) != (0, 0))
        .map(|(i, j)| block(tx + 0.25 * i as f32, ty + 0.25 * j as f32))
        .collect();
    let config = EnvConfig {
        max_steps: 16,
        ..EnvConfig::default()
    };
    let env = Env::new(&scene((-0.125, 0.125), 0, (tx, ty), ring), config).unwrap();
    let found = plan(&env, &PlannerConfig::default());
    assert_eq!(
        found.outcome,
        PlanOutcome::Unsolvable,
        "after {} expansions",
        found.expansions
    );
}

#[test]
fn generated_lift_scene_needs_the_clearance_dimension() {
    let mut rng = <rand_chacha::ChaCha8Rng as rand::SeedableRng>::seed_from_u64(7);
    let scenario = generate_many(
        wheelleg_sim::generate::SceneRobot::shipped(),
        SceneKind::Behaviour(Behaviour::LiftOver),
        &mut rng,
        1,
    )
    .remove(0);
    let env = Env::new(&scenario, EnvConfig::default()).unwrap();
    let frozen = PlannerConfig {
        max_expansions: 3_000,
        ..PlannerConfig::default()
    }
    .restricted(|a| a.clearance == Step::Zero);
    let outcome = plan_with_fallback(&env, &frozen);
    assert!(
        !matches!(outcome.outcome(), PlanOutcome::Solved { .. }),
        "a lift scene was solved with the body height frozen: {:?}",
        outcome.outcome()
    );
}

#[test]
fn fallback_proves_solvable_when_the_exact_budget_runs_out() {
    let env = Env::new(&squeeze_scene(), EnvConfig::default()).unwrap();
    let along_x =
        PlannerConfig::default().restricted(|a| a.move_y == Step::Zero && a.yaw == Step::Zero);
    // Some budget is too small for the exact search but enough for the weighted one.
    let mut rescued = None;
    for budget in 1..400 {
        let mut config = along_x;
        config.max_expansions = budget;
        let found = plan_with_fallback(&env, &config);
        if found.exact.outcome != PlanOutcome::BudgetExceeded {
            break;
        }
        if let PlanOutcome::Solved { shortest, .. } = found.outcome() {
            rescued = Some((budget, *shortest));
            break;
        }
    }
    let (budget, shortest) =
        rescued.expect("the weighted fallback solves where exact search runs out");
    assert!(
        !shortest,
        "a weighted plan (budget {budget}) must not claim to be shortest"
    );
}
