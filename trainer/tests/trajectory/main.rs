//! Stored trajectories, their essential areas, the randomized batch and its file.
//!
//! Source trajectories come from the planner on generated scenes (straight, lift), so every
//! test starts from real solutions. Run in release mode: a few seconds.

use nalgebra::Point2;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;
use std::sync::OnceLock;
use wheelleg_runtime::action::{Action, Step, COUNT};
use wheelleg_sim::env::{Env, EnvConfig, InvalidAction, Observation, Status};
use wheelleg_sim::generate::{generate, Behaviour, SceneKind};
use wheelleg_sim::obstacle::{is_cell_centre, Obstacle, ObstacleKind, ObstacleYaw};
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig, FALLBACK_WEIGHT};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;
use wheelleg_trainer::trajectory::batch_file::{
    partial_path, BatchFileError, TrajectoryBatch, MAGIC, PREAMBLE_LEN,
};
use wheelleg_trainer::trajectory::randomize::{
    prepare, randomize_batch, randomize_batch_with, randomize_source, RandomizeConfig,
};
use wheelleg_trainer::trajectory::relevance::{relevance, render, trajectory_distance_m};
use wheelleg_trainer::trajectory::sweep::{EssentialArea, GroundRect, DEFAULT_MARGIN_M};
use wheelleg_trainer::trajectory::{behaviour_code, behaviour_of_code, Trajectory};

fn scratch(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("wheelleg-traj-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).unwrap();
    dir
}

/// A planner-made trajectory of a generated scene of `behaviour`.
fn planned(behaviour: Behaviour, seed: u64) -> Trajectory {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let kind = SceneKind::Behaviour(behaviour);
    let scenario = generate(
        wheelleg_sim::generate::SceneRobot::shipped(),
        kind,
        &mut rng,
        format!("{}-{seed}", behaviour.name()),
    );
    let env = Env::new(&scenario, EnvConfig::default()).unwrap();
    let config = PlannerConfig {
        max_expansions: 20_000,
        heuristic_weight: FALLBACK_WEIGHT,
        ..PlannerConfig::default()
    };
    match plan(&env, &config).outcome {
        PlanOutcome::Solved { actions, .. } => Trajectory::new(scenario, actions, behaviour),
        other => panic!(
            "{} seed {seed}: planner found no plan: {other:?}",
            behaviour.name()
        ),
    }
}

/// Two straight and one lift trajectory, planned once for all tests.
fn sources() -> Vec<Trajectory> {
    static SOURCES: OnceLock<Vec<Trajectory>> = OnceLock::new();
    SOURCES
        .get_or_init(|| {
            vec![
                planned(Behaviour::Straight, 1),
                planned(Behaviour::LiftOver, 2),
                planned(Behaviour::Straight, 3),
            ]
        })
        .clone()
}

/// `trajectory` with one action inserted that collides (and is undone) somewhere near an
/// obstacle: the same path, one collision more.
fn with_a_collision(trajectory: &Trajectory) -> Trajectory {
    let config = EnvConfig::default();
    let mut env = Env::new(&trajectory.scenario, config).unwrap();
    for (i, &next) in trajectory.actions.iter().enumerate() {
        for index in 0..COUNT {
            let action = Action::from_index(index).unwrap();
            let mut probe = env.clone();
            if probe.step(action).unwrap().invalid == Some(InvalidAction::Collision) {
                let mut actions = trajectory.actions.clone();
                actions.insert(i, action);
                return Trajectory {
                    actions,
                    ..trajectory.clone()
                };
            }
        }
        env.step(next).unwrap();
    }
    panic!("no colliding action anywhere along the path");
}

mod batch_file;
mod essential_area;
mod expert_labels;
mod relevance;
mod replay;
