//! The policy network on the robot: int8 weights file, loader and integer inference.
//!
//! ```ignore
//! use wheelleg_runtime::model::DefaultPolicy;
//! let policy = DefaultPolicy::from_bytes(include_bytes!("policy.wlw"))?;
//! let action = policy.act(&height_map_mm, &state_mm)?; // [[i16; 32]; 32], [i32; 4]
//! ```
//!
//! - [`format`]: the `.wlw` file's records and envelope (byte level: docs/weights-format.md).
//! - [`load`]: checks a file once and borrows its tensors ([`Model`]); typed [`LoadError`]s.
//! - [`quant`]: fixed-point requantization (multiplier + shift, no floating point).
//! - [`kernel`]: the dot-product kernel, scalar, AVX2 ([`Kernel`], chosen by CPUID) or the
//!   Cortex-M4's DSP extension (chosen at compile time for thumbv7em).
//! - [`infer`]: the forward pass over ping-pong buffers sized by const generics ([`Scratch`]).
//!
//! Scheme (TFLite / CMSIS-NN): weights int8, symmetric, one scale per output channel; activations
//! int8 with scale and zero point; int32 bias and accumulators; requantization by a fixed-point
//! multiplier and shift per output channel. Two exceptions at 16 bits (format version 2), both
//! where rounding to 255 steps decided the greedy action: the action head writes int16 logits,
//! and the state features (clearance, track, target x and y) enter the first dense layer as
//! int16. Inputs arrive in millimetres (heights as i16, state as i32) and are quantized by the
//! same integer multiply-shift.

pub mod crc32;
#[cfg(all(target_arch = "arm", target_feature = "dsp"))]
mod dsp_m4;
pub mod format;
pub mod infer;
pub mod kernel;
pub mod load;
pub mod quant;
#[cfg(target_arch = "x86_64")]
mod simd_x86;

pub use infer::{InferError, Outputs, Scratch};
pub use kernel::{Kernel, Output};
pub use load::{Capacity, LayerRef, LoadError, Model, Requirements, ACTION_LOGITS};

use crate::action::{Action, CHOICES, DIMS};

/// Activation buffer capacity (int8 elements) of [`DefaultPolicy`]: the default network's
/// largest tensor is the first conv output, 16 x 16 x 16 = 4096.
pub const DEFAULT_ACTIVATION_ELEMENTS: usize = 4096;
/// Row buffer capacity (int16 elements) of [`DefaultPolicy`]: the default network's longest
/// row is the first dense layer's input, 512 + 4 = 516; rounded up for small variations.
pub const DEFAULT_ROW_ELEMENTS: usize = 1024;

/// The policy with buffers sized for the default network (see docs/model.md).
pub type DefaultPolicy<'a> = Policy<'a, DEFAULT_ACTIVATION_ELEMENTS, DEFAULT_ROW_ELEMENTS>;

/// A loaded policy whose activations fit `ACT` int8 elements per buffer and whose patches and
/// dense inputs fit `ROW` int16 elements.
#[derive(Clone, Debug)]
pub struct Policy<'a, const ACT: usize, const ROW: usize> {
    model: Model<'a>,
    kernel: Kernel,
}

/// The chosen kernel cannot run on this CPU.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct UnsupportedKernel(pub Kernel);

impl<'a, const ACT: usize, const ROW: usize> Policy<'a, ACT, ROW> {
    /// Checks a weights file (envelope, shapes, parameters, and that it fits this policy's
    /// buffers) and picks the fastest kernel of this CPU. Borrows the tensors from `bytes`.
    pub fn from_bytes(bytes: &'a [u8]) -> Result<Self, LoadError> {
        let model = Model::parse(bytes)?;
        let needs = model.requirements;
        if needs.activation_elements > ACT {
            return Err(LoadError::ExceedsCapacity {
                what: Capacity::ActivationElements,
                required: needs.activation_elements,
                capacity: ACT,
            });
        }
        if needs.row_elements > ROW {
            return Err(LoadError::ExceedsCapacity {
                what: Capacity::RowElements,
                required: needs.row_elements,
                capacity: ROW,
            });
        }
        Ok(Policy {
            model,
            kernel: Kernel::detect(),
        })
    }

    /// The decoded model (architecture, quantization, borrowed tensors).
    pub fn model(&self) -> &Model<'a> {
        &self.model
    }

    /// The kernel in use.
    pub fn kernel(&self) -> Kernel {
        self.kernel
    }

    /// Selects a kernel (for tests and benchmarks); refuses one this CPU cannot run.
    pub fn set_kernel(&mut self, kernel: Kernel) -> Result<(), UnsupportedKernel> {
        if kernel.is_supported() {
            self.kernel = kernel;
            Ok(())
        } else {
            Err(UnsupportedKernel(kernel))
        }
    }

    /// One decision: greedy action (argmax per head) from a `R x C` height map in millimetres
    /// (row = robot x, column = robot y) and the state in millimetres (clearance, track, target
    /// x, target y in the robot frame). Uses a [`Scratch`] on the stack.
    pub fn act<const R: usize, const C: usize>(
        &self,
        height_mm: &[[i16; C]; R],
        state_mm: &[i32],
    ) -> Result<Action, InferError> {
        Ok(self.evaluate(height_mm.as_flattened(), state_mm)?.action())
    }

    /// The raw outputs of one decision (row-major height map), with a stack [`Scratch`].
    pub fn evaluate(&self, height_mm: &[i16], state_mm: &[i32]) -> Result<Outputs, InferError> {
        let mut scratch = Scratch::<ACT, ROW>::new();
        self.evaluate_with(&mut scratch, height_mm, state_mm)
    }

    /// The raw outputs of one decision, in caller-owned buffers (for example a `static`).
    pub fn evaluate_with(
        &self,
        scratch: &mut Scratch<ACT, ROW>,
        height_mm: &[i16],
        state_mm: &[i32],
    ) -> Result<Outputs, InferError> {
        infer::forward(&self.model, self.kernel, scratch, height_mm, state_mm)
    }

    /// The raw outputs of one decision in caller-owned buffers of any size that fits the
    /// model (see [`infer::forward_in`]): for a controller that lends the same RAM to other
    /// work between decisions.
    pub fn evaluate_in(
        &self,
        ping: &mut [i8],
        pong: &mut [i8],
        row: &mut [i16],
        height_mm: &[i16],
        state_mm: &[i32],
    ) -> Result<Outputs, InferError> {
        infer::forward_in(
            &self.model,
            self.kernel,
            ping,
            pong,
            row,
            height_mm,
            state_mm,
        )
    }

    /// Convenience for hosts with floating point: heights and state in metres, rounded to
    /// millimetres (saturating) and run through the integer path.
    pub fn evaluate_m(&self, height_m: &[f32], state_m: &[f32]) -> Result<Outputs, InferError> {
        let mut heights = [0i16; ACT];
        self.evaluate_m_with(&mut Scratch::new(), &mut heights, height_m, state_m)
    }

    /// [`Policy::evaluate_m`] in caller-owned buffers, for a host that evaluates many
    /// observations: `scratch` for the forward pass and `heights_mm` (at least as long as
    /// `height_m`) for the map in millimetres. [`Policy::evaluate_m`] zeroes both (over
    /// 250 KiB for a host's buffers) at every call.
    pub fn evaluate_m_with(
        &self,
        scratch: &mut Scratch<ACT, ROW>,
        heights_mm: &mut [i16],
        height_m: &[f32],
        state_m: &[f32],
    ) -> Result<Outputs, InferError> {
        let cells = heights_mm
            .get_mut(..height_m.len())
            .ok_or(InferError::HeightMapShape {
                expected: usize::from(self.model.input.rows) * usize::from(self.model.input.cols),
                found: height_m.len(),
            })?;
        for (mm, &m) in cells.iter_mut().zip(height_m) {
            // `as` saturates (and maps NaN to 0), which is the intended clamp.
            *mm = libm::roundf(m * 1000.0) as i16;
        }
        let mut state = [0i32; load::MAX_STATE_FEATURES];
        let values = state
            .get_mut(..state_m.len())
            .ok_or(InferError::StateLength {
                expected: self.model.state.len(),
                found: state_m.len(),
            })?;
        for (mm, &m) in values.iter_mut().zip(state_m) {
            *mm = libm::roundf(m * 1000.0) as i32;
        }
        self.evaluate_with(scratch, cells, values)
    }
}

impl Outputs {
    /// Greedy action: the largest logit of each head (the first one on ties).
    pub fn action(&self) -> Action {
        let mut indices = [0usize; DIMS];
        for (index, head) in indices
            .iter_mut()
            .zip(self.action_logits.chunks_exact(CHOICES))
        {
            let mut best = 0;
            for (choice, &logit) in head.iter().enumerate() {
                if head.get(best).is_some_and(|&b| logit > b) {
                    best = choice;
                }
            }
            *index = best;
        }
        // Indices are below CHOICES by construction.
        Action::from_head_indices(indices).unwrap_or(Action::IDLE)
    }

    /// The action logits in real units: `scale * q` (int16 logits have zero point 0).
    pub fn action_logits_f32(&self) -> [f32; ACTION_LOGITS] {
        self.action_logits.map(|q| self.action_scale * f32::from(q))
    }

    /// The value estimate in real units, if the model has a value head.
    pub fn value_f32(&self) -> Option<f32> {
        self.value
            .map(|(q, scale, zero_point)| scale * (f32::from(q) - f32::from(zero_point)))
    }
}
