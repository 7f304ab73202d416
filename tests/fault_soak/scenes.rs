//! The soak's scenes: solvable ones, each with the planner's actions.

use crate::SWEEP_SAMPLES;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use wheelleg::closed_loop::{Driver, LoopConfig, PlannerDriver};
use wheelleg_runtime::action::Action;
use wheelleg_sim::env::{Env, Status};
use wheelleg_sim::generate::{generate, Behaviour, SceneKind};
use wheelleg_sim::planner::PlannerConfig;
use wheelleg_sim::scenario::Scenario;

/// A solvable scene and the planner's action sequence for it.
pub(crate) struct Planned {
    pub(crate) scene: Scenario,
    pub(crate) actions: Vec<Action>,
}

pub(crate) fn planned_scenes() -> Vec<Planned> {
    let planner = PlannerConfig {
        max_expansions: 2_000,
        ..PlannerConfig::default()
    };
    let mut out = Vec::new();
    // The seeds of tests/closed_loop/mechanics.rs: scenes the planner solves quickly (proving a scene
    // unsolvable can take minutes, which a soak should not spend).
    let kinds = [
        (SceneKind::Complex, 4, 21),
        (SceneKind::Behaviour(Behaviour::LiftOver), 1, 22),
    ];
    for (kind, count, seed) in kinds {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let mut found = 0;
        for i in 0..10 * count {
            let scene = generate(
                wheelleg_sim::generate::SceneRobot::shipped(),
                kind,
                &mut rng,
                format!("{}-{i}", kind.name()),
            );
            let mut env = Env::new(&scene, LoopConfig::default().env).unwrap();
            let Ok(mut driver) = PlannerDriver::new(&env, &planner) else {
                continue;
            };
            let mut actions = Vec::new();
            // Where a safe stop can leave the robot: anywhere along a step's path. The world
            // proves every step clear all the way, so sampled at every control tick the planned
            // path touches nothing either.
            while !env.status().is_done() {
                let action = driver.decide(&env).unwrap();
                let from = *env.state();
                env.step(action).unwrap();
                let on_the_way = env.check_swept(&from, env.state(), SWEEP_SAMPLES, 0.0);
                assert!(
                    on_the_way.is_ok(),
                    "{}: step {} of the plan touches an obstacle on the way: {on_the_way:?}",
                    scene.name,
                    actions.len()
                );
                actions.push(action);
            }
            assert_eq!(env.status(), Status::Success);
            assert_eq!(
                env.collisions(),
                0,
                "the planner's paths are collision-free"
            );
            out.push(Planned { scene, actions });
            found += 1;
            if found == count {
                break;
            }
        }
        assert_eq!(found, count, "not enough solvable {} scenes", kind.name());
    }
    let steps: usize = out.iter().map(|p| p.actions.len()).sum();
    eprintln!("planned steps: {steps}");
    out
}

pub(crate) fn plan_states(planned: &Planned) -> Vec<wheelleg_sim::state::RobotState> {
    let mut env = Env::new(&planned.scene, LoopConfig::default().env).unwrap();
    let mut states = vec![*env.state()];
    for &action in &planned.actions {
        env.step(action).unwrap();
        states.push(*env.state());
    }
    states
}
