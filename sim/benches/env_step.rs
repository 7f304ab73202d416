#![allow(missing_docs)] // criterion_group! generates an undocumented function.
//! Environment speed: steps per second on one core, height-map rendering included.
//!
//! `env_step/*` times `step` + `observe` (what training does per sample) on behaviour and complex
//! scenes under random actions; `height_map` and `transition_check` show where the time goes.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use std::hint::black_box;
use wheelleg_runtime::action::{Action, COUNT};
use wheelleg_sim::env::{Env, EnvConfig, Observation};
use wheelleg_sim::generate::{generate_many, SceneKind};
use wheelleg_sim::height_map::render;

/// Steps `STEPS` random actions through a rotation of scenes, resetting finished episodes.
fn run_steps(
    envs: &[Env],
    rng: &mut rand_chacha::ChaCha8Rng,
    observation: &mut Observation,
    steps: usize,
) -> f32 {
    let mut total = 0.0;
    let mut index = 0;
    let mut env = envs[0].clone();
    for _ in 0..steps {
        let action = Action::from_index(rng.random_range(0..COUNT)).unwrap_or(Action::IDLE);
        match env.step(action) {
            Ok(outcome) => {
                total += outcome.reward.total();
                if outcome.status.is_done() {
                    index = (index + 1) % envs.len();
                    env = envs[index].clone();
                }
            }
            Err(_) => env = envs[index].clone(),
        }
        env.observe(observation);
        total += observation.height_map[0];
    }
    total
}

const STEPS: usize = 10_000;

fn bench_env(c: &mut Criterion) {
    let mut group = c.benchmark_group("env_step");
    group.throughput(Throughput::Elements(STEPS as u64));
    group.sample_size(20);
    for kind in [
        SceneKind::from_name("straight"),
        SceneKind::from_name("lift"),
        SceneKind::from_name("complex"),
    ] {
        let kind = kind.expect("known kind");
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(1);
        let envs: Vec<Env> = generate_many(
            wheelleg_sim::generate::SceneRobot::shipped(),
            kind,
            &mut rng,
            64,
        )
        .iter()
        .map(|s| Env::new(s, EnvConfig::default()).expect("generated scenes are valid"))
        .collect();
        let mut observation = Observation::default();
        group.bench_function(kind.name(), |b| {
            b.iter(|| black_box(run_steps(&envs, &mut rng, &mut observation, STEPS)))
        });
    }
    group.finish();

    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(2);
    let scenes = generate_many(
        wheelleg_sim::generate::SceneRobot::shipped(),
        SceneKind::Complex,
        &mut rng,
        64,
    );
    let boxes: Vec<Vec<_>> = scenes
        .iter()
        .map(|s| s.obstacles.iter().map(|o| o.ground_box()).collect())
        .collect();
    let mut map = [0.0; wheelleg_runtime::observation::HEIGHT_MAP_CELLS];
    c.bench_function("height_map/complex", |b| {
        let mut i = 0;
        b.iter(|| {
            i = (i + 1) % scenes.len();
            render(
                &boxes[i],
                scenes[i].start.position,
                scenes[i].start.yaw_rad(),
                &mut map,
            );
            black_box(map[0])
        })
    });
    let lift = generate_many(
        wheelleg_sim::generate::SceneRobot::shipped(),
        SceneKind::from_name("lift").expect("known kind"),
        &mut rng,
        8,
    );
    let env = Env::new(&lift[0], EnvConfig::default()).expect("valid");
    c.bench_function("transition_check/lift_start", |b| {
        let from = *env.state();
        let mut i = 0;
        b.iter(|| {
            i = (i + 1) % COUNT;
            let to = from.after(Action::from_index(i).unwrap_or(Action::IDLE));
            black_box(env.check_transition(&from, &to).is_ok())
        })
    });
}

criterion_group! {
    name = benches;
    config = Criterion::default();
    targets = bench_env
}
criterion_main!(benches);
