//! Training side of the wheel-legged robot's navigation policy.
//!
//! For now it holds the path from a float network to the bytes the robot runs:
//!
//! - [`network_f32`]: the policy network in plain f32 (architecture + tensors) and its forward
//!   pass, the float reference every int8 result is compared with.
//! - [`quantize`]: post-training int8 quantization (calibration ranges, per-channel weight
//!   scales, fixed-point multipliers) and the `.wlw` weights file bytes.
//! - [`export`]: writing a weights file atomically.
//!
//! The int8 policy is evaluated through `wheelleg_runtime::model` itself, so what is measured
//! here is what ships.

pub mod export;
pub mod network_f32;
pub mod quantize;
