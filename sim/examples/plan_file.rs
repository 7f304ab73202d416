//! Plans a sample of a scenario file on one thread, for timing the planner on its own.
//!
//! `cargo run --release -p wheelleg-sim --example plan_file -- SCENARIOS [BUDGET] [STRIDE] [OFFSET]`
//! plans every `STRIDE`-th scenario from `OFFSET` (default: all of them) as `wheelleg plan` does
//! (exact search, then the weighted fallback, `BUDGET` expansions each, default 5,000) and prints
//! one JSON line per scenario with the fields of `wheelleg plan --json`, in file order.
//! `tools/planner_speed.sh` builds it against two versions of the planner and compares them.
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::planner::{plan_with_fallback, PlanOutcome, PlannerConfig};

fn main() {
    let arg = |i: usize| std::env::args().nth(i);
    let path = arg(1).expect("usage: plan_file SCENARIOS [BUDGET] [STRIDE] [OFFSET]");
    let budget: usize = arg(2).and_then(|s| s.parse().ok()).unwrap_or(5_000);
    let stride: usize = arg(3).and_then(|s| s.parse().ok()).unwrap_or(1).max(1);
    let offset: usize = arg(4).and_then(|s| s.parse().ok()).unwrap_or(0);
    let scenarios = wheelleg_sim::scenario_file::load(
        std::path::Path::new(&path),
        &wheelleg_sim::robot::SimulatedRobot::SHIPPED,
    )
    .expect("a scenario file");
    let config = PlannerConfig {
        max_expansions: budget,
        ..PlannerConfig::default()
    };
    for scenario in scenarios.iter().skip(offset).step_by(stride) {
        let env = Env::new(scenario, EnvConfig::default()).expect("a valid scenario");
        let found = plan_with_fallback(&env, &config);
        let (solvable, steps, shortest) = match found.outcome() {
            PlanOutcome::Solved { actions, shortest } => {
                ("true", actions.len().to_string(), *shortest)
            }
            PlanOutcome::Unsolvable => ("false", "null".to_string(), false),
            PlanOutcome::BudgetExceeded => ("null", "null".to_string(), false),
        };
        println!(
            "{{\"name\": {:?}, \"solvable\": {solvable}, \"steps\": {steps}, \"shortest\": {shortest}, \"expansions\": {}}}",
            scenario.name,
            found.expansions()
        );
    }
}
