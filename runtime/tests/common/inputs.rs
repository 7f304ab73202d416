//! Raw integer inputs for the tests that run one network on both sides (the runtime's int8
//! kernels, the trainer's float reference): one file, included by both crates' tests, so that
//! both draw the same kind of inputs.

use rand::Rng;
use rand_chacha::ChaCha8Rng;

/// `height_cells` heights and `state_len` state values, in millimetres: usually plausible,
/// sometimes far out of range, to exercise clamping.
pub fn raw_inputs_mm(
    rng: &mut ChaCha8Rng,
    height_cells: usize,
    state_len: usize,
) -> (Vec<i16>, Vec<i32>) {
    let wild = rng.random_bool(0.2);
    let height = (0..height_cells)
        .map(|_| {
            if wild {
                rng.random()
            } else {
                rng.random_range(-20..600)
            }
        })
        .collect();
    let state = (0..state_len)
        .map(|_| {
            if wild {
                rng.random()
            } else {
                rng.random_range(-8000..8000)
            }
        })
        .collect();
    (height, state)
}
