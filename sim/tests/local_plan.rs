//! The last-metres search on the robot's own map: its plans hold in the scene itself, and it
//! searches only when due.
//!
//! Run in release mode (`cargo test --release -p wheelleg-sim --test local_plan`): seconds.

use nalgebra::Point2;
use wheelleg_sim::env::{Env, EnvConfig, Status};
use wheelleg_sim::local_plan::{LastMetres, LastMetresConfig, LocalPlanner, LocalPlannerConfig};
use wheelleg_sim::obstacle::{Obstacle, ObstacleKind, ObstacleYaw};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;

fn episode(start: (f32, f32), target: (f32, f32), obstacles: Vec<Obstacle>) -> Env {
    let scenario = Scenario {
        name: "last metres".to_string(),
        start: RobotState::new(
            Point2::new(start.0, start.1),
            0,
            &wheelleg_runtime::action::ActionLattice::PAPER,
        ),
        target: Point2::new(target.0, target.1),
        obstacles,
    };
    Env::new(&scenario, EnvConfig::default()).expect("a valid scene")
}

/// The endings the policy fails most, a metre away: astride a slab, beside a slab with a block
/// behind the target, beside a block past a bar along the way.
fn endings() -> Vec<Env> {
    vec![
        episode(
            (-0.625, 0.125),
            (0.375, 0.125),
            vec![Obstacle::new(
                ObstacleKind::Slab,
                0.375,
                0.125,
                ObstacleYaw::Deg0,
            )],
        ),
        episode(
            (-0.625, 0.125),
            (0.375, 0.125),
            vec![
                Obstacle::new(ObstacleKind::Slab, 0.375, 0.375, ObstacleYaw::Deg90),
                Obstacle::new(ObstacleKind::Block, 0.875, 0.125, ObstacleYaw::Deg0),
            ],
        ),
        episode(
            (-0.625, 0.125),
            (0.375, 0.125),
            vec![
                Obstacle::new(ObstacleKind::Block, 0.375, 0.375, ObstacleYaw::Deg0),
                Obstacle::new(ObstacleKind::Bar, 0.125, 0.125, ObstacleYaw::Deg0),
            ],
        ),
    ]
}

#[test]
fn a_plan_found_on_the_robots_map_reaches_the_target_in_the_scene_without_collision() {
    for (i, env) in endings().into_iter().enumerate() {
        let mut planner = LocalPlanner::new(LocalPlannerConfig::default());
        let found = planner.plan(&env);
        let actions = found
            .actions()
            .unwrap_or_else(|| panic!("ending {i}: no plan: {found:?}"))
            .to_vec();
        assert!(!actions.is_empty(), "ending {i}: the robot starts away");
        let mut env = env;
        for (k, action) in actions.iter().enumerate() {
            let outcome = env.step(*action).expect("the plan ends with the episode");
            assert_eq!(outcome.invalid, None, "ending {i}: step {k} refused");
        }
        assert_eq!(env.status(), Status::Success, "ending {i}");
        assert_eq!(env.collisions(), 0, "ending {i}");
    }
}

#[test]
fn the_search_waits_for_the_policy_near_the_target_and_stops_at_its_limit() {
    let env = endings().remove(0);
    // Near enough at a metre.
    let near_m = 1.1;
    let hopeless = LastMetresConfig {
        // One expansion finds no plan here: the searches are counted, nothing is taken.
        planner: LocalPlannerConfig {
            max_expansions: 1,
            ..LocalPlannerConfig::default()
        },
        near_m,
        after_decisions: 3,
        max_searches: 2,
    };
    let mut last = LastMetres::new(hopeless);
    let searches: Vec<u32> = (0..12)
        .map(|_| {
            assert_eq!(last.next_action(&env), None);
            last.searches()
        })
        .collect();
    // Searches before the 4th and the 7th of the policy's decisions, then no more.
    assert_eq!(searches, [0, 0, 0, 1, 1, 1, 2, 2, 2, 2, 2, 2]);
    assert_eq!(last.plans(), 0);

    // With a budget it finds the way at the first search and hands it out, one per step.
    let mut last = LastMetres::new(LastMetresConfig {
        near_m,
        after_decisions: 3,
        ..LastMetresConfig::default()
    });
    let mut env = env;
    for _ in 0..3 {
        assert_eq!(last.next_action(&env), None);
    }
    while let Some(action) = last.next_action(&env) {
        env.step(action).expect("the plan ends with the episode");
    }
    assert_eq!(last.plans(), 1);
    assert_eq!(env.status(), Status::Success);

    // Far from the target it never searches.
    let mut far = LastMetres::new(LastMetresConfig {
        near_m: 0.9,
        after_decisions: 1,
        ..LastMetresConfig::default()
    });
    let env = endings().remove(0);
    for _ in 0..5 {
        assert_eq!(far.next_action(&env), None);
    }
    assert_eq!(far.searches(), 0);
    // Unless told the policy is lost (the look-ahead found no way): then it searches at
    // once wherever the robot stands, within the same limit of searches.
    assert!(far.search_now(&env), "a plan from 1 m away");
    assert_eq!((far.searches(), far.plans()), (1, 1));
    let mut followed = env.clone();
    while let Some(action) = far.next_action(&followed) {
        followed
            .step(action)
            .expect("the plan ends with the episode");
    }
    assert_eq!(followed.status(), Status::Success);
    let mut spent = LastMetres::new(LastMetresConfig {
        max_searches: 1,
        ..hopeless
    });
    assert!(!spent.search_now(&env));
    assert!(!spent.search_now(&env));
    assert_eq!(spent.searches(), 1);
}
