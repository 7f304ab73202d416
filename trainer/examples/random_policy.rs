//! Writes the default network with seeded random weights as a `.wlw` file and prints the
//! action index the runtime takes on the fixed observation of `runtime/nostd-check`, then the one it
//! takes if that action is refused (`decision::Decider`), so that the no_std binary's decisions
//! can be checked against the host's:
//! `cargo run --release -p wheelleg-trainer --example random_policy -- OUT.wlw`
// A host tool: failing loudly on bad arguments or I/O is its whole error handling.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::std_instead_of_core
)]

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::arrival::{Arrival, DEFAULT_RADIUS_M};
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_runtime::guard::{CollisionGuard, HeightMapRef, DEFAULT_MARGIN_M};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::model::DefaultPolicy;
use wheelleg_runtime::observation::HEIGHT_MAP_CELLS;
use wheelleg_runtime::robot::{Robot, WHEELLEG};
use wheelleg_sim::atomic_write;
use wheelleg_trainer::network_f32::{Architecture, NetworkF32};
use wheelleg_trainer::quantize::{observation_mm, quantize, Calibration, RangeMethod};

/// The observation of runtime/nostd-check/src/main.rs, in metres: flat ground with a 0.2 m box 0.5 m
/// ahead, clearance 0.25 m, track 0.4 m, target 2 m ahead and 0.5 m to the left.
fn observation() -> (Vec<f32>, Vec<f32>) {
    let mut height = vec![0.0f32; 32 * 32];
    for row in 2..8 {
        for col in 12..20 {
            height[row * 32 + col] = 0.2;
        }
    }
    (height, vec![0.25, 0.4, 2.0, 0.5])
}

fn main() {
    let path = std::env::args()
        .nth(1)
        .expect("usage: random_policy OUT.wlw");
    let mut rng = ChaCha8Rng::seed_from_u64(7);
    let network = NetworkF32::random(&Architecture::default_policy(), &mut rng);
    let (height, state) = observation();
    let calibration =
        Calibration::from_observations(&network, [(height.as_slice(), state.as_slice())]);
    let bytes = quantize(&network, &calibration, RangeMethod::MinMax)
        .unwrap()
        .to_bytes()
        .unwrap();
    atomic_write(std::path::Path::new(&path), &bytes).unwrap();
    let (height_mm, state_mm) = observation_mm(&height, &state);
    let policy = DefaultPolicy::from_bytes(&bytes).unwrap();
    let outputs = policy.evaluate(&height_mm, &state_mm).unwrap();
    let key = ObservationKey::of_mm(&height_mm, &state_mm);
    let mut decider: Decider = Decider::new();
    let first = decider.choose(key, &outputs.action_logits);
    assert_eq!(
        first,
        outputs.action(),
        "nothing refused: the per-head argmax"
    );
    // Refused: the same observation again.
    let second = decider.choose(key, &outputs.action_logits);
    // The third with the collision guard, at the default pose.
    let guard = CollisionGuard::new(&Robot::WHEELLEG, DEFAULT_MARGIN_M);
    let legs = LegConfig {
        clearance_m: WHEELLEG.default_clearance_m,
        track_m: WHEELLEG.default_track_m,
    };
    let map: &[i16; HEIGHT_MAP_CELLS] = height_mm.as_slice().try_into().unwrap();
    let third = guard.choose(
        &mut decider,
        key,
        &outputs.action_logits,
        HeightMapRef::Millimetres(map),
        legs,
        Some(&Arrival::from_state_mm(
            &state_mm,
            DEFAULT_RADIUS_M,
            &Robot::WHEELLEG.actions,
        )),
    );
    println!(
        "{} {} {} {:?}",
        first.index(),
        second.index(),
        third.action.index(),
        third.level
    );
}
