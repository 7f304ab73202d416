//! Probe: planner effort on generated scenes.
use rand::SeedableRng;
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::generate::{generate_many, SceneKind};
use wheelleg_sim::planner::{plan, PlannerConfig, PlanOutcome};
fn main() {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
    let budget: usize = std::env::args().nth(1).and_then(|s| s.parse().ok()).unwrap_or(50_000);
    let w: f32 = std::env::args().nth(2).and_then(|s| s.parse().ok()).unwrap_or(1.0);
    for kind in SceneKind::ALL {
        for s in generate_many(kind, &mut rng, 4) {
            let env = Env::new(&s, EnvConfig::default()).unwrap();
            let t = std::time::Instant::now();
            let p = plan(&env, &PlannerConfig { max_expansions: budget, heuristic_weight: w, ..Default::default() });
            let o = match &p.outcome { PlanOutcome::Solved { actions, shortest } => format!("solved {} {}", actions.len(), shortest), o => format!("{o:?}") };
            println!("{:12} yaw {:5} d {:.2} {:30} exp {:7} {:.2}s", s.name, s.start.yaw_deg(), (s.target - s.start.position).norm(), o, p.expansions, t.elapsed().as_secs_f32());
        }
    }
}
