//! Post-training int8 quantization (the TFLite / CMSIS-NN scheme) and the weights file bytes.
//!
//! 1. [`calibrate`]: run the float network on calibration observations (height maps from
//!    rollouts) and record every quantized tensor's range (min/max or percentiles).
//! 2. [`params`]: turn ranges into activation scales and zero points, weights into symmetric
//!    per-output-channel int8, real multipliers into fixed-point multiplier + shift; the action
//!    head's output into symmetric int16 logits (format version 2).
//! 3. [`build`]: quantize every layer ([`quantize`]), folding the state's own quantization into
//!    the layer that reads features ++ state, and encode the `.wlw` file
//!    ([`QuantizedNetwork::to_bytes`]).
//!
//! 4. [`agreement`]: how often the int8 network's greedy action equals the float network's.
//! 5. [`qat`]: quantization-aware fine-tuning by distillation, for when post-training
//!    quantization alone flips too many near-tie decisions: the result goes through 1-3 again.
//!
//! The int8 network is then run by `wheelleg_runtime::model` itself ([`Int8Policy`]).

pub mod agreement;
pub mod build;
pub mod calibrate;
pub mod file_bytes;
pub mod params;
pub mod qat;
pub mod synthetic;

pub use agreement::{agreement, Agreement};
pub use build::{
    quantize, quantize_for_version, InputQuant, QuantizeError, QuantizedLayer, QuantizedNetwork,
};
pub use calibrate::{ActionRange, Calibration, RangeMethod, RangeObserver};
pub use params::{quantize_multiplier, ActQuant};
pub use qat::{dequantize, fine_tune, QatOptions, QatReport, QatSettings};

pub use wheelleg_stack::policy::Int8Policy;

/// An observation in the runtime's integer units: heights in millimetres (i16, saturating) and
/// state in millimetres (i32), rounded half away from zero like `Policy::evaluate_m`.
pub fn observation_mm(height_m: &[f32], state: &[f32]) -> (Vec<i16>, Vec<i32>) {
    (
        height_m
            .iter()
            .map(|&m| (m * 1000.0).round() as i16)
            .collect(),
        state.iter().map(|&m| (m * 1000.0).round() as i32).collect(),
    )
}
