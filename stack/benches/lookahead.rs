//! The look-ahead's cost: the shipped int8 policy driving the first held-out complex scenes to
//! their end with the robot's stack (guard on the 1 cm map, arrival), without and with the
//! look-ahead's rollouts on the robot's map, and with its search for a shorter way as well.
//! The figures are the ratios to the stack alone, per episode.
//!
//! `cargo bench -p wheelleg-stack --bench lookahead`. Figures: docs/results.md, "Rollouts on
//! the robot's map" and "A search for a shorter way".

#![allow(missing_docs)] // criterion_group! generates an undocumented function.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::Path;
use std::time::Duration;
use wheelleg_sim::env::EnvConfig;
use wheelleg_stack::episodes::run_episodes;
use wheelleg_stack::lookahead::LookaheadConfig;
use wheelleg_stack::policy::Int8Policy;
use wheelleg_stack::{Preset, StackConfig};

const EPISODES: usize = 16;

fn episodes(c: &mut Criterion) {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
    let bytes = std::fs::read(root.join("weights/policy.wlw")).expect("weights/policy.wlw");
    let policy = Int8Policy::from_bytes(&bytes).expect("a weights file");
    let scenarios = wheelleg_sim::scenario_file::load(
        &root.join("eval/heldout-complex-s1000000.json"),
        &wheelleg_sim::robot::SimulatedRobot::SHIPPED,
    )
    .expect("the held-out scenes");
    let scenarios = &scenarios[..EPISODES];
    let stack = Preset::Robot.config();
    let looking = StackConfig {
        lookahead: Some(LookaheadConfig::default()),
        ..stack
    };
    let searching = StackConfig {
        lookahead: Some(LookaheadConfig {
            search_expansions: 500,
            ..LookaheadConfig::default()
        }),
        ..stack
    };
    let mut group = c.benchmark_group("episodes");
    group.throughput(Throughput::Elements(EPISODES as u64));
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(20));
    for (name, options) in [
        ("stack", &stack),
        ("stack+lookahead", &looking),
        ("stack+lookahead+search", &searching),
    ] {
        group.bench_function(name, |b| {
            b.iter(|| {
                let mut rng = ChaCha8Rng::seed_from_u64(0);
                run_episodes(
                    &policy,
                    scenarios,
                    options,
                    EnvConfig::default(),
                    &mut rng,
                    &mut |_| {},
                )
                .expect("episodes run")
            })
        });
    }
    group.finish();
}

criterion_group!(benches, episodes);
criterion_main!(benches);
