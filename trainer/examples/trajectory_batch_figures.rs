//! The figures of docs/curriculum.md: planner-made trajectories of every behaviour, randomized,
//! with keep rates per behaviour, bytes per stored trajectory on disk and in memory, the size
//! of the essential areas and the generation speed.
//!
//! `cargo run --release -p wheelleg-trainer --example trajectory_batch_figures -- [SCENES]
//! [PER_TRAJECTORY] [EXPANSIONS] [WEIGHT] [BEHAVIOURS]` (defaults 8, 200, 4000, 3.0, all;
//! BEHAVIOURS is a comma-separated list of names). Scenes the planner does not solve within the
//! budget (search with the heuristic inflated by WEIGHT) are skipped and counted.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::time::Instant;
use wheelleg_runtime::action::{Action, Step};
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::generate::{generate, Behaviour, SceneKind};
use wheelleg_sim::obstacle::ObstacleKind;
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig, FALLBACK_WEIGHT};
use wheelleg_sim::scenario::Scenario;
use wheelleg_trainer::trajectory::batch_file::TrajectoryBatch;
use wheelleg_trainer::trajectory::randomize::{prepare, randomize_batch_with, RandomizeConfig};
use wheelleg_trainer::trajectory::Trajectory;

fn arg(i: usize, default: usize) -> usize {
    std::env::args()
        .nth(i)
        .and_then(|a| a.parse().ok())
        .unwrap_or(default)
}

/// Turns to face +x, spreads the legs to 0.56 m at 0.08 m clearance and moves sideways onto the
/// line of the slab nearest the start; returns the actions taken (stepped in `env`).
fn spread_prefix(env: &mut Env, scenario: &Scenario) -> Vec<Action> {
    let mut actions = Vec::new();
    let mut act = |env: &mut Env, action: Action| {
        if env.step(action).is_ok() {
            actions.push(action);
        }
    };
    while env.state().yaw_steps != 0 && !env.status().is_done() {
        let yaw = if env.state().yaw_steps <= env.state().yaw_steps_per_turn() / 2 {
            Step::Minus
        } else {
            Step::Plus
        };
        act(
            env,
            Action {
                yaw,
                ..Action::IDLE
            },
        );
    }
    for i in 0..10 {
        let clearance = if i < 2 { Step::Minus } else { Step::Zero };
        act(
            env,
            Action {
                track: Step::Plus,
                clearance,
                ..Action::IDLE
            },
        );
    }
    let lane_y = scenario
        .obstacles
        .iter()
        .filter(|o| o.kind == ObstacleKind::Slab)
        .map(|o| o.centre.y)
        .min_by(|a, b| {
            (a - scenario.start.position.y)
                .abs()
                .total_cmp(&(b - scenario.start.position.y).abs())
        })
        .unwrap_or(scenario.start.position.y);
    while (env.state().position.y - lane_y).abs() > 0.025 && !env.status().is_done() {
        let move_y = if env.state().position.y < lane_y {
            Step::Plus
        } else {
            Step::Minus
        };
        act(
            env,
            Action {
                move_y,
                ..Action::IDLE
            },
        );
    }
    actions
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let (scenes, per_trajectory, expansions) = (arg(1, 8), arg(2, 200), arg(3, 4000));
    let weight = std::env::args()
        .nth(4)
        .and_then(|a| a.parse().ok())
        .unwrap_or(FALLBACK_WEIGHT);
    let only = std::env::args().nth(5).unwrap_or_default();
    let planner = PlannerConfig {
        max_expansions: expansions,
        heuristic_weight: weight,
        ..PlannerConfig::default()
    };
    let config = RandomizeConfig {
        per_trajectory,
        seed: 1,
        ..RandomizeConfig::default()
    };
    let mut sources: Vec<Trajectory> = Vec::new();
    println!("behaviour  solved  area_m2  kept_obst  placements  steps");
    for behaviour in Behaviour::ALL {
        if !only.is_empty() && !only.split(',').any(|name| name == behaviour.name()) {
            continue;
        }
        let mut rng = ChaCha8Rng::seed_from_u64(100 + behaviour as u64);
        let (mut solved, mut area, mut kept, mut placements, mut steps) = (0, 0.0, 0, 0, 0);
        for i in 0..scenes {
            let scenario = generate(
                wheelleg_sim::generate::SceneRobot::shipped(),
                SceneKind::Behaviour(behaviour),
                &mut rng,
                format!("{}-{i}", behaviour.name()),
            );
            let mut env = Env::new(&scenario, EnvConfig::default())?;
            // The planner rarely finds the spread in budget (docs/planner.md): set the legs wide
            // and line up with the slab by hand first, then plan the rest from there.
            let prefix = if behaviour == Behaviour::SpreadOver {
                spread_prefix(&mut env, &scenario)
            } else {
                Vec::new()
            };
            if let PlanOutcome::Solved { actions, .. } = plan(&env, &planner).outcome {
                let actions = prefix.into_iter().chain(actions).collect();
                let t = Trajectory::new(scenario, actions, behaviour);
                let p = prepare(&t, &config)?;
                solved += 1;
                area += p.area.raster_area_m2();
                kept += p.kept.len();
                placements += p.placements.len();
                steps += t.actions.len();
                sources.push(t);
            }
        }
        let n = solved.max(1) as f32;
        println!(
            "{:<9} {:>4}/{:<3} {:>6.2} {:>9.1} {:>11.0} {:>6.1}",
            behaviour.name(),
            solved,
            scenes,
            area / n,
            kept as f32 / n,
            placements as f32 / n,
            steps as f32 / n
        );
    }
    let dir = std::env::temp_dir().join(format!("wheelleg-figures-{}", std::process::id()));
    std::fs::create_dir_all(&dir)?;
    let out = dir.join("batch.wltb");
    let started = Instant::now();
    let stats = randomize_batch_with(&sources, &config, &out, |_| {})?;
    let seconds = started.elapsed().as_secs_f64();
    println!("\nbehaviour  kept/tried  keep_rate");
    for (behaviour, (kept, tried)) in Behaviour::ALL.iter().zip(stats.by_behaviour) {
        if tried == 0 {
            continue;
        }
        println!(
            "{:<9} {:>6}/{:<6} {:>8.2}%",
            behaviour.name(),
            kept,
            tried,
            100.0 * kept as f64 / tried.max(1) as f64
        );
    }
    let started_load = Instant::now();
    let batch = TrajectoryBatch::load(&out)?;
    let load_s = started_load.elapsed().as_secs_f64();
    println!(
        "\n{} sources ({} rejected), {} trajectories ({} originals), {} bytes on disk: {:.1} \
         bytes/trajectory; {:.1} bytes/trajectory in memory",
        stats.sources,
        stats.sources_rejected,
        stats.trajectories(),
        stats.originals,
        stats.file_bytes,
        stats.bytes_per_trajectory(),
        batch.memory_bytes() as f64 / batch.len().max(1) as f64
    );
    println!(
        "generation {:.1} s ({:.0} replays/s, one thread), load {:.3} s",
        seconds,
        stats.tried as f64 / seconds,
        load_s
    );
    std::fs::remove_dir_all(&dir)?;
    Ok(())
}
