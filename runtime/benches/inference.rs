//! Per-decision latency of the shipped network (`weights/policy.wlw`) at batch 1: the int8
//! runtime with each kernel this CPU runs, through `act` with its stack scratch, and the load
//! and validation of the file. onnxruntime's figures for the same network come from
//! `tools/onnx_reference.py` (docs/model.md, "Speed"); the trainer's f32 forward pass as the
//! float reference is `cargo bench -p wheelleg-trainer --bench inference_f32`. The collision
//! guard's check of one action, in the same group, puts its cost beside a decision's.
//!
//! `cargo bench -p wheelleg-runtime --bench inference`
// Bench setup: a failed unwrap is a broken benchmark, reported loudly.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::std_instead_of_core
)]
// criterion's macros generate undocumented public functions.
#![allow(missing_docs)]

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::guard::{CollisionGuard, GridMap, HeightMapRef, DEFAULT_MARGIN_M};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::model::{DefaultPolicy, Kernel, Scratch};
use wheelleg_runtime::observation::HEIGHT_MAP_CELLS;
use wheelleg_runtime::robot::{Robot, WHEELLEG};

/// A few boxes on flat ground (millimetres), and a plausible state (clearance, track, target x,
/// target y, millimetres).
fn observation_mm(rng: &mut ChaCha8Rng) -> (Vec<i16>, Vec<i32>) {
    let mut height = vec![0i16; 32 * 32];
    for _ in 0..4 {
        let (r0, c0) = (rng.random_range(0..28), rng.random_range(0..28));
        let top = rng.random_range(50..450);
        for r in r0..r0 + 4 {
            for c in c0..c0 + 4 {
                height[r * 32 + c] = top;
            }
        }
    }
    let state = vec![
        200,
        400,
        rng.random_range(-3000..3000),
        rng.random_range(-3000..3000),
    ];
    (height, state)
}

fn bench_decision(c: &mut Criterion) {
    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let bytes = std::fs::read(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../weights/policy.wlw"
    ))
    .expect("weights/policy.wlw is committed with the repository");
    let (height_mm, state_mm) = observation_mm(&mut rng);

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
    let policy = DefaultPolicy::from_bytes(&bytes).unwrap();
    group.bench_function("int8_act_detected_kernel_stack_scratch", |b| {
        let mut map = [[0i16; 32]; 32];
        for (row, chunk) in map.iter_mut().zip(height_mm.chunks_exact(32)) {
            row.copy_from_slice(chunk);
        }
        b.iter(|| policy.act(black_box(&map), black_box(&state_mm)).unwrap())
    });
    group.bench_function("load_and_validate", |b| {
        b.iter(|| DefaultPolicy::from_bytes(black_box(&bytes)).unwrap())
    });
    // The collision guard's check of one action that passes (so every pose and column is
    // looked at: its full cost), beside a wall and a bar near the robot.
    let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
    let legs = LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    };
    let mut map = [0i16; HEIGHT_MAP_CELLS];
    for row in 7..10 {
        for col in 8..24 {
            map[row * 32 + col] = 400;
        }
    }
    for row in 12..20 {
        for col in 4..6 {
            map[row * 32 + col] = 150;
        }
    }
    assert!(guard
        .check(HeightMapRef::Millimetres(&map), legs, Action::IDLE)
        .is_ok());
    group.bench_function("guard_check_one_clear_action", |b| {
        b.iter(|| {
            guard.check(
                HeightMapRef::Millimetres(black_box(&map)),
                black_box(legs),
                black_box(Action::IDLE),
            )
        })
    });
    // The same scene on a 1 cm map (128 x 128): each 5 cm cell becomes 5 x 5 fine ones.
    const FINE_SIDE: usize = 128;
    let mut fine = vec![0.0f32; FINE_SIDE * FINE_SIDE];
    // Cell centres line up: coarse (row, col) centre at (15.5 - row) * 0.05, fine at
    // (63.5 - r) * 0.01, so fine r = 5 * row - 14 .. 5 * row - 10.
    for (index, &mm) in map.iter().enumerate() {
        let (row, col) = (index / 32, index % 32);
        for r in (5 * row).saturating_sub(14)..(5 * row).saturating_sub(9) {
            for c in (5 * col).saturating_sub(14)..(5 * col).saturating_sub(9) {
                if let Some(cell) = fine.get_mut(r * FINE_SIDE + c) {
                    *cell = f32::from(mm) * 1.0e-3;
                }
            }
        }
    }
    let fine_map = GridMap::new(&fine, FINE_SIDE, 0.01).unwrap();
    assert!(guard
        .check(HeightMapRef::Grid(fine_map), legs, Action::IDLE)
        .is_ok());
    group.bench_function("guard_check_one_clear_action_1cm_map", |b| {
        b.iter(|| {
            guard.check(
                HeightMapRef::Grid(black_box(fine_map)),
                black_box(legs),
                black_box(Action::IDLE),
            )
        })
    });
    group.finish();
}

criterion_group!(benches, bench_decision);
criterion_main!(benches);
