//! `wheelleg render --scenarios FILE --out DIR [--robot FILE]`.

use super::robot::RobotArg;
use super::CliResult;
use std::path::PathBuf;
use wheelleg_sim::env::{Env, EnvConfig, Observation};
use wheelleg_sim::planner::{plan_with_fallback, PlanOutcome, PlannerConfig};
use wheelleg_sim::render::{height_map_image, top_view};

/// Arguments of `render`.
#[derive(clap::Args)]
pub struct Args {
    /// Scenario file (JSON).
    #[arg(long)]
    scenarios: PathBuf,
    /// Directory for the PNGs (created if missing).
    #[arg(long)]
    out: PathBuf,
    /// Planner effort per scenario, in expanded states (0: draw no path).
    #[arg(long, default_value_t = 5_000)]
    max_expansions: usize,
    /// The robot drawn and simulated.
    #[command(flatten)]
    robot: RobotArg,
}

/// Runs `render`: `<name>.png` (top view) and `<name>-heightmap.png` per scenario.
pub fn run(args: Args) -> CliResult {
    let (_, simulated) = args.robot.simulated()?;
    let scenarios = wheelleg_sim::scenario_file::load(&args.scenarios, &simulated)?;
    let env_config = EnvConfig {
        robot: simulated,
        ..EnvConfig::default()
    };
    std::fs::create_dir_all(&args.out)
        .map_err(|e| format!("cannot create {}: {e}", args.out.display()))?;
    for scenario in &scenarios {
        let env = Env::new(scenario, env_config)?;
        let mut path = vec![*env.state()];
        if args.max_expansions > 0 {
            let config = PlannerConfig {
                max_expansions: args.max_expansions,
                ..PlannerConfig::default()
            };
            if let PlanOutcome::Solved { actions, .. } =
                plan_with_fallback(&env, &config).outcome().clone()
            {
                let mut replay = env.clone();
                for action in actions {
                    if replay.step(action).is_err() {
                        break;
                    }
                    path.push(*replay.state());
                }
            }
        }
        let file_stem = sanitize(&scenario.name);
        let top = args.out.join(format!("{file_stem}.png"));
        top_view(scenario, simulated.geometry(), &path, &[])?.save_png(&top)?;
        let mut observation = Observation::default();
        env.observe(&mut observation);
        let map = args.out.join(format!("{file_stem}-heightmap.png"));
        height_map_image(&observation.height_map)?.save_png(&map)?;
        outln!("{}: {} and {}", scenario.name, top.display(), map.display());
    }
    Ok(())
}

/// A file name from a scenario name: anything but letters, digits, '-' and '_' becomes '_'.
fn sanitize(name: &str) -> String {
    name.chars()
        .map(|c| {
            if c.is_ascii_alphanumeric() || c == '-' || c == '_' {
                c
            } else {
                '_'
            }
        })
        .collect()
}
