//! `wheelleg plan --scenarios FILE [--json] [--max-expansions N] [--jobs N] [--robot FILE]`.

use super::robot::RobotArg;
use super::CliResult;
use serde_json::json;
use std::path::PathBuf;
use std::sync::atomic::{AtomicUsize, Ordering as AtomicOrdering};
use std::sync::Mutex;
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::planner::{plan_with_fallback, PlanOutcome, PlannerConfig};

/// Arguments of `plan`.
#[derive(clap::Args)]
pub struct Args {
    /// Scenario file (JSON).
    #[arg(long)]
    scenarios: PathBuf,
    /// Print JSON instead of a table.
    #[arg(long)]
    json: bool,
    /// Search effort per scenario and search, in expanded states. When the exact search runs
    /// out, a weighted search with the same budget can still prove the scenario solvable (its
    /// step count is then not proven shortest).
    #[arg(long, default_value_t = 20_000)]
    max_expansions: usize,
    /// Scenarios planned at once, one thread each (default: every core). The output is the
    /// same for any number: results in file order, each scenario's search independent.
    #[arg(long)]
    jobs: Option<usize>,
    /// The robot planned for.
    #[command(flatten)]
    robot: RobotArg,
}

/// What the planner found for one scenario.
struct Found {
    solvable: Option<bool>,
    steps: Option<usize>,
    shortest: bool,
    expansions: usize,
}

/// Plans every scenario, `jobs` at once (each thread takes the next unplanned one); results in
/// file order.
fn plan_all(
    scenarios: &[wheelleg_sim::scenario::Scenario],
    env_config: EnvConfig,
    config: &PlannerConfig,
    jobs: usize,
) -> Result<Vec<Found>, String> {
    let next = AtomicUsize::new(0);
    let slots: Vec<Mutex<Option<Result<Found, String>>>> =
        scenarios.iter().map(|_| Mutex::new(None)).collect();
    let work = || loop {
        let i = next.fetch_add(1, AtomicOrdering::Relaxed);
        let Some(scenario) = scenarios.get(i) else {
            break;
        };
        let found = Env::new(scenario, env_config)
            .map(|env| {
                let found = plan_with_fallback(&env, config);
                let (solvable, steps, shortest) = match found.outcome() {
                    PlanOutcome::Solved { actions, shortest } => {
                        (Some(true), Some(actions.len()), *shortest)
                    }
                    PlanOutcome::Unsolvable => (Some(false), None, false),
                    PlanOutcome::BudgetExceeded => (None, None, false),
                };
                Found {
                    solvable,
                    steps,
                    shortest,
                    expansions: found.expansions(),
                }
            })
            .map_err(|e| e.to_string());
        *slots[i].lock().unwrap() = Some(found);
    };
    std::thread::scope(|scope| {
        for _ in 1..jobs.min(scenarios.len()) {
            scope.spawn(work);
        }
        work();
    });
    slots
        .into_iter()
        .map(|slot| slot.into_inner().unwrap().expect("every scenario planned"))
        .collect()
}

/// Runs `plan`.
pub fn run(args: Args) -> CliResult {
    let (_, simulated) = args.robot.simulated()?;
    let scenarios = wheelleg_sim::scenario_file::load(&args.scenarios, &simulated)?;
    let env_config = EnvConfig {
        robot: simulated,
        ..EnvConfig::default()
    };
    let config = PlannerConfig {
        max_expansions: args.max_expansions,
        ..PlannerConfig::default()
    };
    let jobs = match args.jobs {
        Some(0) => return Err("--jobs must be at least 1".into()),
        Some(jobs) => jobs,
        None => std::thread::available_parallelism().map_or(1, |n| n.get()),
    };
    let found = plan_all(&scenarios, env_config, &config, jobs)?;
    let mut results = Vec::with_capacity(scenarios.len());
    if !args.json {
        outln!(
            "{:<24} {:>9} {:>6} {:>9} {:>10}",
            "scenario",
            "solvable",
            "steps",
            "shortest",
            "expanded"
        );
    }
    for (scenario, found) in scenarios.iter().zip(&found) {
        if args.json {
            results.push(json!({
                "name": scenario.name,
                "solvable": found.solvable,
                "steps": found.steps,
                "shortest": found.shortest,
                "expansions": found.expansions,
            }));
        } else {
            let show = |v: Option<String>| v.unwrap_or_else(|| "-".to_string());
            let solvable = match found.solvable {
                Some(true) => "yes".to_string(),
                Some(false) => "no".to_string(),
                None => "budget".to_string(),
            };
            outln!(
                "{:<24} {:>9} {:>6} {:>9} {:>10}",
                scenario.name,
                solvable,
                show(found.steps.map(|s| s.to_string())),
                if found.shortest { "yes" } else { "-" },
                found.expansions
            );
        }
    }
    if args.json {
        outln!(
            "{}",
            serde_json::to_string_pretty(&json!({ "results": results }))?
        );
    }
    Ok(())
}
