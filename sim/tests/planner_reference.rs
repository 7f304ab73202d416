//! The planner's fast proof of the way there (docs/planner.md, "The way there without the
//! simulator") changes no result: the searches below give the very plans, expansion counts and
//! outcomes the planner gave before it (recorded from commit 523e3ff, which asked
//! `Env::check_transition` for every step near an obstacle), but for one plan the simulator's
//! own fix changed (see `REFERENCE`).

use rand::SeedableRng;
use wheelleg_sim::env::{Env, EnvConfig};
use wheelleg_sim::generate::{generate_many, SceneKind};
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig, FALLBACK_WEIGHT};

/// One line per search: scene, search, outcome, plan length, expansions, FNV-1a hash of the
/// plan's action indices.
fn describe(name: &str, search: &str, env: &Env, config: &PlannerConfig) -> String {
    let found = plan(env, config);
    let (outcome, actions) = match &found.outcome {
        PlanOutcome::Solved { actions, shortest } => (
            if *shortest { "shortest" } else { "solved" },
            actions.clone(),
        ),
        PlanOutcome::Unsolvable => ("unsolvable", Vec::new()),
        PlanOutcome::BudgetExceeded => ("budget", Vec::new()),
    };
    let mut hash = 0xcbf2_9ce4_8422_2325u64;
    for a in &actions {
        hash = (hash ^ a.index() as u64).wrapping_mul(0x100_0000_01b3);
    }
    format!(
        "{name} {search} {outcome} {} {} {hash:016x}",
        actions.len(),
        found.expansions
    )
}

fn results() -> Vec<String> {
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(7);
    let exact = PlannerConfig {
        max_expansions: 120,
        ..PlannerConfig::default()
    };
    let weighted = PlannerConfig {
        max_expansions: 250,
        heuristic_weight: FALLBACK_WEIGHT,
        ..PlannerConfig::default()
    };
    let mut out = Vec::new();
    // The kinds of the recording, in its order: composed came later.
    let recorded = SceneKind::ALL
        .into_iter()
        .filter(|&k| k != SceneKind::Composed);
    for kind in recorded {
        for scene in generate_many(
            wheelleg_sim::generate::SceneRobot::shipped(),
            kind,
            &mut rng,
            3,
        ) {
            let env = Env::new(&scene, EnvConfig::default()).unwrap();
            out.push(describe(&scene.name, "exact", &env, &exact));
            out.push(describe(&scene.name, "weighted", &env, &weighted));
        }
    }
    out
}

#[test]
fn plans_are_the_ones_the_planner_gave_before_the_fast_proof() {
    let got = results();
    if std::env::var_os("PRINT_PLANNER_REFERENCE").is_some() {
        for line in &got {
            println!("    \"{line}\",");
        }
    }
    assert_eq!(got, REFERENCE);
}

/// Recorded with commit 523e3ff's planner.
const REFERENCE: [&str; 36] = [
    "straight-0 exact shortest 11 25 d3f81b635e353264",
    "straight-0 weighted solved 14 18 9b417fcbc87f52ff",
    "straight-1 exact shortest 14 31 47c5d6f2d80a1a0d",
    "straight-1 weighted solved 16 19 b0926d0d8704ecf5",
    "straight-2 exact shortest 11 12 ffb172c26337802e",
    "straight-2 weighted solved 11 12 ffb172c26337802e",
    "around-0 exact budget 0 120 cbf29ce484222325",
    "around-0 weighted budget 0 250 cbf29ce484222325",
    "around-1 exact budget 0 120 cbf29ce484222325",
    "around-1 weighted solved 29 98 92b18f9935b430ae",
    "around-2 exact budget 0 120 cbf29ce484222325",
    "around-2 weighted solved 25 74 31117e93031cc3ad",
    "lift-0 exact shortest 11 39 5d49a566a58ac4d2",
    // Recorded as ec38d88ea54ea83e: as long, as many expansions, another plan since the
    // simulator's clearance stopped trusting parry's distances (a step of the recorded plan
    // passed a part closer than parry said).
    "lift-0 weighted solved 16 63 8113fdf07cc8b798",
    "lift-1 exact shortest 13 54 875fb96a467342f9",
    "lift-1 weighted solved 27 114 50f5265a36733967",
    "lift-2 exact budget 0 120 cbf29ce484222325",
    "lift-2 weighted solved 20 30 728ce3ebb0a1fc28",
    "spread-0 exact budget 0 120 cbf29ce484222325",
    "spread-0 weighted solved 28 45 de1bc2fe0cc0a074",
    "spread-1 exact budget 0 120 cbf29ce484222325",
    "spread-1 weighted solved 24 39 ce227796f877217b",
    "spread-2 exact budget 0 120 cbf29ce484222325",
    "spread-2 weighted solved 30 50 754b61cab372a049",
    "squeeze-0 exact budget 0 120 cbf29ce484222325",
    "squeeze-0 weighted budget 0 250 cbf29ce484222325",
    "squeeze-1 exact budget 0 120 cbf29ce484222325",
    "squeeze-1 weighted solved 17 150 fa5fabbf961888ac",
    "squeeze-2 exact budget 0 120 cbf29ce484222325",
    "squeeze-2 weighted budget 0 250 cbf29ce484222325",
    "complex-0 exact shortest 10 26 44af5202286b407f",
    "complex-0 weighted solved 11 14 c134afe5ecca488c",
    "complex-1 exact shortest 12 33 ad9c5eec771996c8",
    "complex-1 weighted solved 14 16 e2620827fdca8005",
    "complex-2 exact budget 0 120 cbf29ce484222325",
    "complex-2 weighted solved 21 51 0a17c5bf858daae0",
];
