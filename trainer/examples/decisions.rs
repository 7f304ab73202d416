//! Runs N decisions of the default network with one kernel, for instruction counting:
//! `valgrind --tool=callgrind target/release/examples/decisions avx2 1000` minus the same with
//! 0 decisions, divided by 1000, is the instruction count of one decision
//! (`tools/callgrind_policy.sh` does exactly that for every kernel).
//!
//! Usage: `decisions scalar|avx2|f32 N [WEIGHTS.wlw]`. Without a weights file the network has
//! seeded random weights; with one, the int8 kernels run that file (`f32` needs no file: it is
//! the trainer's float forward of the same architecture, random weights).
// A host measuring tool: failing loudly on a bad argument is its whole error handling.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::panic,
    clippy::std_instead_of_core
)]

use std::hint::black_box;

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::model::{DefaultPolicy, Kernel, Scratch};
use wheelleg_trainer::network_f32::{Architecture, NetworkF32};
use wheelleg_trainer::quantize::{observation_mm, quantize, Calibration, RangeMethod};

fn main() {
    let mut args = std::env::args().skip(1);
    let kernel = match args.next().as_deref() {
        Some("scalar") => Kernel::Scalar,
        Some("avx2") => Kernel::Avx2,
        Some("f32") => Kernel::Scalar,
        other => panic!("usage: decisions scalar|avx2|f32 N [WEIGHTS.wlw] (got {other:?})"),
    };
    let float = std::env::args().nth(1).as_deref() == Some("f32");
    let count: usize = args.next().map_or(1, |n| n.parse().unwrap());
    let weights_file = args
        .next()
        .map(|path| std::fs::read(path).expect("read weights file"));

    let mut rng = ChaCha8Rng::seed_from_u64(2024);
    let network = NetworkF32::random(&Architecture::default_policy(), &mut rng);
    let height_m: Vec<f32> = (0..1024)
        .map(|i| if i % 7 == 0 { 0.2 } else { 0.0 })
        .collect();
    let state = vec![0.2, 0.4, 1.5, -0.5];
    let calibration =
        Calibration::from_observations(&network, [(height_m.as_slice(), state.as_slice())]);
    let bytes = match weights_file {
        Some(bytes) => bytes,
        None => quantize(&network, &calibration, RangeMethod::MinMax)
            .unwrap()
            .to_bytes()
            .unwrap(),
    };
    let (height_mm, state_mm) = observation_mm(&height_m, &state);
    let mut policy = DefaultPolicy::from_bytes(&bytes).unwrap();
    policy
        .set_kernel(kernel)
        .expect("kernel not supported on this CPU");
    let mut scratch = Scratch::new();
    let mut checksum = 0i64;
    for _ in 0..count {
        if float {
            let (logits, _) = network.forward(black_box(&height_m), black_box(&state));
            checksum += logits[0] as i64;
        } else {
            let outputs = policy
                .evaluate_with(&mut scratch, black_box(&height_mm), black_box(&state_mm))
                .unwrap();
            checksum += i64::from(outputs.action_logits[0]);
        }
    }
    println!("{count} decisions ({kernel:?}, float={float}), checksum {checksum}");
}
