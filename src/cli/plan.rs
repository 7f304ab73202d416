//! `wheelleg plan --scenarios FILE [--json] [--max-expansions N]`.

use super::CliResult;
use serde_json::json;
use std::path::PathBuf;
use wheelleg_runtime::robot::WHEELLEG;
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
}

/// Runs `plan`.
pub fn run(args: Args) -> CliResult {
    let scenarios = wheelleg_sim::scenario_file::load(&args.scenarios, &WHEELLEG)?;
    let config = PlannerConfig {
        max_expansions: args.max_expansions,
        ..PlannerConfig::default()
    };
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
    for scenario in &scenarios {
        let env = Env::new(scenario, EnvConfig::default())?;
        let found = plan_with_fallback(&env, &config);
        let (solvable, steps, shortest) = match found.outcome() {
            PlanOutcome::Solved { actions, shortest } => {
                (Some(true), Some(actions.len()), *shortest)
            }
            PlanOutcome::Unsolvable => (Some(false), None, false),
            PlanOutcome::BudgetExceeded => (None, None, false),
        };
        if args.json {
            results.push(json!({
                "name": scenario.name,
                "solvable": solvable,
                "steps": steps,
                "shortest": shortest,
                "expansions": found.expansions(),
            }));
        } else {
            let show = |v: Option<String>| v.unwrap_or_else(|| "-".to_string());
            let solvable = match solvable {
                Some(true) => "yes".to_string(),
                Some(false) => "no".to_string(),
                None => "budget".to_string(),
            };
            outln!(
                "{:<24} {:>9} {:>6} {:>9} {:>10}",
                scenario.name,
                solvable,
                show(steps.map(|s| s.to_string())),
                if shortest { "yes" } else { "-" },
                found.expansions()
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
