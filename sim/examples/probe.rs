//! Probe: planner effort on generated scenes.
//!
//! `cargo run --release -p wheelleg-sim --example probe -- [BUDGET] [WEIGHT] [PER_KIND] [SEED] [KIND]`
//! plans `PER_KIND` generated scenes of every kind, or only of `KIND` (e.g. `spread`; the scenes
//! are the same as in a run over every kind), with exact search with `WEIGHT`, then, if the
//! budget runs out, the weighted fallback, and prints per scene the outcome, expansions and
//! time, then a summary per kind.
use rand::SeedableRng;
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::generate::{generate_many, SceneKind};
use wheelleg_sim::planner::{plan_with_fallback, PlanOutcome, PlannerConfig};

fn describe(outcome: &PlanOutcome) -> String {
    match outcome {
        PlanOutcome::Solved { actions, shortest } => {
            format!(
                "solved {}{}",
                actions.len(),
                if *shortest { " (shortest)" } else { "" }
            )
        }
        PlanOutcome::Unsolvable => "unsolvable".to_string(),
        PlanOutcome::BudgetExceeded => "budget".to_string(),
    }
}

fn main() {
    let arg = |i: usize| std::env::args().nth(i);
    let budget: usize = arg(1).and_then(|s| s.parse().ok()).unwrap_or(20_000);
    let weight: f32 = arg(2).and_then(|s| s.parse().ok()).unwrap_or(1.0);
    let per_kind: usize = arg(3).and_then(|s| s.parse().ok()).unwrap_or(4);
    let seed: u64 = arg(4).and_then(|s| s.parse().ok()).unwrap_or(1);
    let only = arg(5);
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(seed);
    let config = PlannerConfig {
        max_expansions: budget,
        heuristic_weight: weight,
        ..Default::default()
    };
    let mut summary = Vec::new();
    for kind in SceneKind::ALL {
        let (mut exact, mut fallback, mut unsolved, mut seconds, mut max_seconds) =
            (0, 0, 0, 0.0, 0.0f32);
        let mut expansions = Vec::new();
        // Every kind draws from the one generator, so a skipped kind still draws its scenes.
        let scenes = generate_many(
            wheelleg_sim::generate::SceneRobot::shipped(),
            kind,
            &mut rng,
            per_kind,
        );
        if only.as_deref().is_some_and(|name| name != kind.name()) {
            continue;
        }
        for s in scenes {
            let env = Env::new(&s, EnvConfig::default()).expect("generated scenes validate");
            let t = std::time::Instant::now();
            let p = plan_with_fallback(&env, &config);
            let elapsed = t.elapsed().as_secs_f32();
            seconds += elapsed;
            max_seconds = max_seconds.max(elapsed);
            expansions.push(p.exact.expansions);
            match (&p.exact.outcome, p.outcome()) {
                (PlanOutcome::Solved { .. }, _) => exact += 1,
                (_, PlanOutcome::Solved { .. }) => fallback += 1,
                _ => unsolved += 1,
            }
            println!(
                "{:12} yaw {:5} d {:.2}  exact: {:20} exp {:7}  fallback: {:12} exp {:7}  {:.2}s",
                s.name,
                s.start.yaw_deg(),
                (s.target - s.start.position).norm(),
                describe(&p.exact.outcome),
                p.exact.expansions,
                p.fallback
                    .as_ref()
                    .map_or("-".to_string(), |f| describe(&f.outcome)),
                p.fallback.as_ref().map_or(0, |f| f.expansions),
                elapsed
            );
        }
        expansions.sort_unstable();
        summary.push(format!(
            "{:8} exact {}/{n}  fallback {}/{n}  neither {}/{n}  exact-search expansions median {} max {}  time mean {:.2}s max {:.2}s",
            kind.name(),
            exact,
            fallback,
            unsolved,
            expansions[expansions.len() / 2],
            expansions[expansions.len() - 1],
            seconds / per_kind as f32,
            max_seconds,
            n = per_kind,
        ));
    }
    println!();
    for line in summary {
        println!("{line}");
    }
}
