//! `wheelleg relevance --policy CKPT --scenarios FILE [--name NAME] --out relevance.png [--json]`:
//! the paper's relevance figure. Rolls the float policy (by the robot's decision rule) in one
//! scene, then once with each obstacle removed, measures how far the trajectory moves (symmetric mean closest-point
//! distance between the paths, trainer::trajectory::relevance), prints the figures and draws
//! the obstacles white to red by relevance beside the trajectories.

use super::robot::RobotArg;
use super::CliResult;
use std::fmt::Write as _;
use std::io::Write as _;
use std::path::PathBuf;
use wheelleg_sim::env::EnvConfig;
use wheelleg_trainer::trajectory::relevance::{relevance, render, DecidingPolicy};

/// Arguments of `relevance`.
#[derive(clap::Args)]
pub struct Args {
    /// A run's checkpoint.ckpt (the float policy, run greedily).
    #[arg(long)]
    policy: PathBuf,
    /// Scenario file (JSON).
    #[arg(long, alias = "scenario")]
    scenarios: PathBuf,
    /// Name of the scenario to use from --scenarios; the first one when not given.
    #[arg(long)]
    name: Option<String>,
    /// The PNG to write.
    #[arg(long)]
    out: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// The robot simulated; the checkpoint must be trained for it.
    #[command(flatten)]
    robot: RobotArg,
}

/// Runs `relevance`.
pub fn run(args: Args) -> CliResult {
    let (description, simulated) = args.robot.simulated()?;
    let scenarios = wheelleg_sim::scenario_file::load(&args.scenarios, &simulated)?;
    let scenario = match &args.name {
        Some(name) => scenarios.iter().find(|s| &s.name == name).ok_or_else(|| {
            format!(
                "--name {name:?}: {} holds no scenario of that name",
                args.scenarios.display()
            )
        })?,
        None => scenarios
            .first()
            .ok_or_else(|| format!("{}: contains no scenario", args.scenarios.display()))?,
    };
    let network = wheelleg_trainer::checkpoint::load_policy(&args.policy)?;
    wheelleg_trainer::network::check_policy_shape(&network)
        .map_err(|e| format!("{}: {e}", args.policy.display()))?;
    wheelleg_trainer::checkpoint::check_robot(&args.policy, &description)?;
    let config = EnvConfig {
        robot: simulated,
        ..EnvConfig::default()
    };
    let mut policy = DecidingPolicy::new(&network);
    let report = relevance(scenario, config, &mut |obs| policy.act(obs))?;
    render(scenario, &report, simulated.geometry(), &config)?
        .save_png(&args.out)
        .map_err(|e| format!("cannot write {}: {e}", args.out.display()))?;
    let status = |s: wheelleg_sim::env::Status| format!("{s:?}");
    let mut text = String::new();
    if args.json {
        let obstacles: Vec<serde_json::Value> = report
            .obstacles
            .iter()
            .map(|o| {
                let obstacle = &scenario.obstacles[o.index];
                serde_json::json!({
                    "index": o.index,
                    "kind": obstacle.kind.name(),
                    "x": obstacle.centre.x,
                    "y": obstacle.centre.y,
                    "relevance_m": o.relevance_m,
                    "status": status(o.run.status),
                    "steps": o.run.path.len() - 1,
                })
            })
            .collect();
        let json = serde_json::json!({
            "scenario": scenario.name,
            "baseline": {
                "status": status(report.baseline.status),
                "steps": report.baseline.path.len() - 1,
                "collisions": report.baseline.collisions,
            },
            "obstacles": obstacles,
            "png": args.out.display().to_string(),
        });
        writeln!(text, "{json:#}")?;
    } else {
        writeln!(
            text,
            "scenario {}: with every obstacle {:?} in {} steps ({} collisions)",
            scenario.name,
            report.baseline.status,
            report.baseline.path.len() - 1,
            report.baseline.collisions
        )?;
        writeln!(
            text,
            "{:>5} {:>6} {:>7} {:>7} {:>12}  without it",
            "index", "kind", "x_m", "y_m", "relevance_m"
        )?;
        for o in &report.obstacles {
            let obstacle = &scenario.obstacles[o.index];
            writeln!(
                text,
                "{:>5} {:>6} {:>7.3} {:>7.3} {:>12.3}  {:?} in {} steps",
                o.index,
                obstacle.kind.name(),
                obstacle.centre.x,
                obstacle.centre.y,
                o.relevance_m,
                o.run.status,
                o.run.path.len() - 1
            )?;
        }
        writeln!(text, "wrote {}", args.out.display())?;
    }
    // Written in one go, and a closed pipe (`| head`) is an error to report, not a panic.
    std::io::stdout()
        .lock()
        .write_all(text.as_bytes())
        .map_err(|e| format!("cannot write to standard output: {e}"))?;
    Ok(())
}
