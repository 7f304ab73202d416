//! The trainer's f32 forward pass of the default network at batch 1, the float reference of the
//! runtime's int8 decision, beside the int8 runtime on the same network (seeded random weights,
//! quantized by the trainer) with each kernel this CPU runs, in one run. The int8 decision on
//! the shipped weights file is the runtime's own bench
//! (`cargo bench -p wheelleg-runtime --bench inference`).
//!
//! `cargo bench -p wheelleg-trainer --bench inference_f32`
// Bench setup: a failed unwrap is a broken benchmark, reported loudly.
#![allow(clippy::unwrap_used, clippy::expect_used, clippy::indexing_slicing)]
// criterion's macros generate undocumented public functions.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::model::{DefaultPolicy, Kernel, Scratch};
use wheelleg_trainer::network_f32::{Architecture, NetworkF32};
use wheelleg_trainer::quantize::{observation_mm, quantize, Calibration, RangeMethod};

/// A few boxes on flat ground, and a plausible state.
fn observation(rng: &mut ChaCha8Rng) -> (Vec<f32>, Vec<f32>) {
    let mut height = vec![0.0f32; 32 * 32];
    for _ in 0..4 {
        let (r0, c0) = (rng.random_range(0..28), rng.random_range(0..28));
        let top = rng.random_range(0.05..0.45);
        for r in r0..r0 + 4 {
            for c in c0..c0 + 4 {
                height[r * 32 + c] = top;
            }
        }
    }
    let state = vec![
        0.2,
        0.4,
        rng.random_range(-3.0..3.0),
        rng.random_range(-3.0..3.0),
    ];
    (height, state)
}

fn bench_decision(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let network = NetworkF32::random(&Architecture::default_policy(), &mut rng);
    let observations: Vec<_> = (0..64).map(|_| observation(&mut rng)).collect();
    let calibration = Calibration::from_observations(
        &network,
        observations
            .iter()
            .map(|(h, s)| (h.as_slice(), s.as_slice())),
    );
    let bytes = quantize(&network, &calibration, RangeMethod::MinMax)
        .unwrap()
        .to_bytes()
        .unwrap();
    let (height_m, state) = &observations[0];
    let (height_mm, state_mm) = observation_mm(height_m, state);

    let mut group = c.benchmark_group("decision");
    for kernel in Kernel::ALL.into_iter().filter(|k| k.is_supported()) {
        let mut policy = DefaultPolicy::from_bytes(&bytes).unwrap();
        policy.set_kernel(kernel).unwrap();
        let mut scratch = Scratch::new();
        group.bench_function(format!("int8_{kernel:?}").to_lowercase(), |b| {
            b.iter(|| {
                policy
                    .evaluate_with(&mut scratch, black_box(&height_mm), black_box(&state_mm))
                    .unwrap()
            })
        });
    }
    group.bench_function("f32_trainer_forward", |b| {
        b.iter(|| network.forward(black_box(height_m), black_box(state)))
    });
    group.finish();
}

criterion_group!(benches, bench_decision);
criterion_main!(benches);
