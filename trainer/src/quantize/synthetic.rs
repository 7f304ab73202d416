//! Synthetic observations for quantization tests and benchmarks: a few boxes on flat ground
//! and a plausible robot state. Real calibration uses the policy's own rollouts (`export`);
//! these exercise the arithmetic without a trained policy or a simulator.

use rand::Rng;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, HEIGHT_MAP_SIDE};

/// Up to five boxes (1-11 cells a side, 0.03-0.45 m tall) on a flat 32x32 height map (metres,
/// row-major), and a state of clearance 0.1-0.35 m, track 0.3-0.5 m and a target within
/// `target_within_m` on each robot axis.
pub fn synthetic_observation(rng: &mut impl Rng, target_within_m: f32) -> (Vec<f32>, Vec<f32>) {
    let side = HEIGHT_MAP_SIDE;
    let mut height = vec![0.0f32; HEIGHT_MAP_CELLS];
    for _ in 0..rng.random_range(0..6) {
        let (r0, c0) = (rng.random_range(0..side), rng.random_range(0..side));
        let (h, w) = (rng.random_range(1..12), rng.random_range(1..12));
        let top = rng.random_range(0.03..0.45);
        for r in r0..(r0 + h).min(side) {
            for c in c0..(c0 + w).min(side) {
                height[r * side + c] = top;
            }
        }
    }
    let state = vec![
        rng.random_range(0.1..0.35),
        rng.random_range(0.3..0.5),
        rng.random_range(-target_within_m..target_within_m),
        rng.random_range(-target_within_m..target_within_m),
    ];
    (height, state)
}
