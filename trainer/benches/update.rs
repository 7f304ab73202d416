//! Training speed: the PPO update step (forward + backward + Adam on one minibatch of 256,
//! reported as samples/s), the native conv kernel's part of it, and whole training iterations
//! (rollout + update, env steps/s).
//!
//! `cargo bench -p wheelleg-trainer --bench update`; backend from `WHEELLEG_BACKEND` (flex by
//! default; others need their cargo feature), conv layers from `WHEELLEG_CONV_KERNEL`
//! (`ppo.conv_kernel`: `native` by default, or `burn`). Figures: docs/decisions.md,
//! docs/results.md.

#![allow(missing_docs)] // criterion_group! generates an undocumented function.

use criterion::{criterion_group, criterion_main, Criterion, Throughput};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use std::time::Duration;
use wheelleg_runtime::action::DIMS;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_trainer::config::{PpoConfig, TrainConfig};
use wheelleg_trainer::conv_kernel::{self, ConvTape};
use wheelleg_trainer::network::{init_policy, BackendKind};
use wheelleg_trainer::network_f32::Architecture;
use wheelleg_trainer::ppo::Ppo;
use wheelleg_trainer::runner::{train, RunOptions};
use wheelleg_trainer::storage::Batch;

const MINIBATCH: usize = 256;

fn backend() -> BackendKind {
    let name = std::env::var("WHEELLEG_BACKEND").unwrap_or_else(|_| "flex".into());
    BackendKind::from_name(&name).expect("WHEELLEG_BACKEND")
}

fn conv_kernel() -> String {
    std::env::var("WHEELLEG_CONV_KERNEL").unwrap_or_else(|_| PpoConfig::default().conv_kernel)
}

fn random_batch(n: usize, rng: &mut ChaCha8Rng) -> Batch {
    Batch {
        heights_m: (0..n * HEIGHT_MAP_CELLS)
            .map(|_| rng.random_range(0.0..0.3))
            .collect(),
        states: (0..n * STATE_LEN)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect(),
        actions: (0..n * DIMS).map(|_| rng.random_range(0..3u8)).collect(),
        old_log_probs: vec![-5.5; n],
        advantages: (0..n).map(|_| rng.random_range(-1.0..1.0)).collect(),
        returns: (0..n).map(|_| rng.random_range(-1.0..1.0)).collect(),
        imitation: vec![0.0; n],
    }
}

fn update_step(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let net = init_policy(&Architecture::default_policy(), &mut rng);
    let device = backend().device().expect("backend");
    let config = PpoConfig {
        conv_kernel: conv_kernel(),
        ..PpoConfig::default()
    };
    let mut ppo = Ppo::new(net, config, device).expect("ppo");
    let batch = random_batch(MINIBATCH, &mut rng);
    let idx: Vec<usize> = (0..MINIBATCH).collect();
    let mut group = c.benchmark_group("ppo");
    group.throughput(Throughput::Elements(MINIBATCH as u64));
    group.measurement_time(Duration::from_secs(10));
    group.bench_function("update_minibatch_256", |b| {
        b.iter(|| ppo.minibatch_step(&batch, &idx).expect("step"))
    });
    let infer = random_batch(64, &mut rng);
    group.throughput(Throughput::Elements(64));
    group.bench_function("forward_batch_64", |b| {
        b.iter(|| {
            ppo.evaluate(&infer.heights_m, &infer.states, 64)
                .expect("eval")
        })
    });
    group.finish();
}

/// The native conv kernel alone on one minibatch: where the update's products and data movement
/// are, apart from burn's dense layers and Adam.
fn conv_stack(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(0);
    let net = init_policy(&Architecture::default_policy(), &mut rng);
    let batch = random_batch(MINIBATCH, &mut rng);
    let (rows, cols) = (net.arch.height_rows, net.arch.height_cols);
    let forward = |tape: &mut ConvTape| {
        conv_kernel::forward_into(&net.convs, rows, cols, &batch.heights_m, MINIBATCH, tape)
            .expect("forward")
    };
    let mut tape = ConvTape::default();
    let d_features: Vec<f32> = (0..forward(&mut tape).len())
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let mut group = c.benchmark_group("conv");
    group.throughput(Throughput::Elements(MINIBATCH as u64));
    group.bench_function("forward_256", |b| b.iter(|| forward(&mut tape)));
    group.bench_function("backward_256", |b| {
        b.iter(|| conv_kernel::backward(&net.convs, &mut tape, &d_features).expect("backward"))
    });
    group.finish();
}

fn training_iteration(c: &mut Criterion) {
    let mut config = TrainConfig::default();
    config.run.backend = std::env::var("WHEELLEG_BACKEND").unwrap_or_else(|_| "flex".into());
    config.run.scene_kind = "complex".into();
    config.ppo.conv_kernel = conv_kernel();
    config.run.steps_per_iteration = 2_000;
    config.run.num_envs = 50;
    config.run.total_env_steps = 2_000;
    let dir = std::env::temp_dir().join(format!("wheelleg-bench-{}", std::process::id()));
    let mut group = c.benchmark_group("training");
    group.throughput(Throughput::Elements(config.run.steps_per_iteration as u64));
    group.sample_size(10);
    group.measurement_time(Duration::from_secs(30));
    group.bench_function("iteration_2000_env_steps_complex", |b| {
        b.iter(|| {
            let _ = std::fs::remove_dir_all(&dir);
            let opts = RunOptions {
                out: dir.clone(),
                seed: 1,
                resume: false,
                progress: false,
                max_iterations: None,
                stop_at_env_steps: None,
                kind: "bench".into(),
            };
            train(&config, &opts).expect("train")
        })
    });
    group.finish();
    let _ = std::fs::remove_dir_all(&dir);
}

criterion_group!(benches, update_step, conv_stack, training_iteration);
criterion_main!(benches);
