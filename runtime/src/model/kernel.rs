//! The one compute kernel every layer reduces to: for each output row, a dot product of an
//! int16 input row (activations minus their zero point) with an int8 weight row, plus bias, then
//! requantization to the layer's output type ([`Output`]: int8 activations, or the action
//! head's int16 logits). Conv layers call it on a batch of output pixels' gathered patches
//! ([`linear_batch`]); dense layers with the whole input vector as a batch of one.
//!
//! Two implementations, bit-exact by construction: integer sums are exact in any order (the
//! loader bounds row length and bias so that no partial sum can overflow an i32), and the AVX2
//! requantization computes the scalar one's exact 64-bit formula of [`super::quant`] 4 lanes at
//! a time; the DSP kernel (Cortex-M4) calls the scalar requantization itself. The AVX2 side also has a first-layer path that needs no patches
//! (`simd_x86::conv3x3_one_channel_avx2`, called by `infer`).

use super::format::InputQuantRecord;
use super::load::{i32_at, Linear};
use super::quant::{quantize_mm, requantize_clamped};

mod sealed {
    /// Only the runtime's own output types implement [`super::Output`].
    pub trait Sealed {}
    impl Sealed for i8 {}
    impl Sealed for i16 {}
}

/// An output slice seen as its concrete type, so that a generic kernel picks the matching
/// store (after monomorphization the match has one arm left: no run-time branch).
#[derive(Debug)]
pub enum OutputSlice<'a> {
    /// int8 activations.
    Int8(&'a mut [i8]),
    /// int16 logits.
    Int16(&'a mut [i16]),
}

/// What a layer writes: `i8` (activations between layers) or `i16` (the action head's logits,
/// format version 2). The kernels are generic over it so that both share one dot product and
/// one requantization, and stay bit-exact with each other by construction.
pub trait Output: Copy + Default + sealed::Sealed {
    /// Smallest value of the type.
    const MIN: i16;
    /// Largest value of the type.
    const MAX: i16;
    /// `value` as this type: exact for values in `[MIN, MAX]` (callers clamp to
    /// [`output_bounds`] first), wrapping otherwise.
    fn narrow(value: i16) -> Self;
    /// The slice as its concrete type.
    fn slice(out: &mut [Self]) -> OutputSlice<'_>;
}

impl Output for i8 {
    const MIN: i16 = i8::MIN as i16;
    const MAX: i16 = i8::MAX as i16;

    #[inline(always)]
    fn narrow(value: i16) -> i8 {
        value as i8
    }

    #[inline(always)]
    fn slice(out: &mut [i8]) -> OutputSlice<'_> {
        OutputSlice::Int8(out)
    }
}

impl Output for i16 {
    const MIN: i16 = i16::MIN;
    const MAX: i16 = i16::MAX;

    #[inline(always)]
    fn narrow(value: i16) -> i16 {
        value
    }

    #[inline(always)]
    fn slice(out: &mut [i16]) -> OutputSlice<'_> {
        OutputSlice::Int16(out)
    }
}

/// A layer's output bounds limited to the output type `T`, computed once per layer so that
/// each output needs one clamp and an exact narrowing. The loader's bounds always fit the type
/// (int8 layers `[-128, 127]` at most); limiting them keeps the kernels total and equal to the
/// SIMD kernel's saturating packs for any hand-made `Linear` (clamping to limited bounds equals
/// saturating a clamp to the original ones, as saturation is monotone).
#[inline(always)]
pub fn output_bounds<T: Output>(linear: &Linear<'_>) -> (i16, i16) {
    (
        linear.output_low.clamp(T::MIN, T::MAX),
        linear.output_high.clamp(T::MIN, T::MAX),
    )
}

/// Which implementation of the kernel runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// Portable Rust, any target.
    Scalar,
    /// x86_64 AVX2 (`vpmaddwd`, 16 multiply-accumulates per instruction).
    Avx2,
    /// Arm Cortex-M4/M7 DSP extension (`SMLAD` on `SXTB16`-widened weight pairs), chosen at
    /// compile time for targets with the `dsp` feature (thumbv7em).
    Dsp,
}

impl Kernel {
    /// Every kernel, for tests and benchmarks.
    pub const ALL: [Kernel; 3] = [Kernel::Scalar, Kernel::Avx2, Kernel::Dsp];

    /// The fastest kernel this CPU runs: the DSP one where the target has it (known at
    /// compile time), else AVX2 if CPUID reports it (works without `std`), else scalar.
    pub fn detect() -> Kernel {
        if Kernel::Dsp.is_supported() {
            Kernel::Dsp
        } else if Kernel::Avx2.is_supported() {
            Kernel::Avx2
        } else {
            Kernel::Scalar
        }
    }

    /// Whether this CPU (and its operating system) can run the kernel.
    pub fn is_supported(self) -> bool {
        match self {
            Kernel::Scalar => true,
            Kernel::Avx2 => avx2_supported(),
            Kernel::Dsp => cfg!(all(target_arch = "arm", target_feature = "dsp")),
        }
    }
}

#[cfg(target_arch = "x86_64")]
fn avx2_supported() -> bool {
    super::simd_x86::avx2_supported()
}

#[cfg(not(target_arch = "x86_64"))]
fn avx2_supported() -> bool {
    false
}

/// Dot product of an activation row and an int8 weight row (bytes reinterpreted as i8).
#[inline(always)]
pub fn dot_scalar(input: &[i16], weights: &[u8]) -> i32 {
    input
        .iter()
        .zip(weights)
        .map(|(&x, &w)| i32::from(x) * i32::from(w as i8))
        .sum()
}

/// Runs one layer's rows on `input` (length `linear.row_len`) into `output` (length
/// `linear.rows`) with the portable kernel.
pub fn linear_scalar<T: Output>(linear: &Linear<'_>, input: &[i16], output: &mut [T]) {
    // Lock-step iterators over the per-row tensors: no index arithmetic or bounds checks per row.
    let rows = linear
        .weights
        .chunks_exact(linear.row_len)
        .zip(linear.bias.chunks_exact(4))
        .zip(linear.multipliers.chunks_exact(4))
        .zip(linear.shifts);
    let (low, high) = output_bounds::<T>(linear);
    for (out, (((weights, bias), multiplier), &shift)) in output.iter_mut().zip(rows) {
        let acc = dot_scalar(input, weights) + le_i32(bias);
        *out = T::narrow(requantize_clamped(
            acc,
            le_i32(multiplier),
            shift as i8,
            linear.output_zero_point,
            low,
            high,
        ));
    }
}

/// An i32 from 4 little-endian bytes (0 if fewer: lengths were checked by the loader).
#[inline(always)]
pub fn le_i32(bytes: &[u8]) -> i32 {
    match bytes {
        &[a, b, c, d] => i32::from_le_bytes([a, b, c, d]),
        _ => 0,
    }
}

/// Requantizes one accumulator of row `row` (shared by every kernel).
#[inline(always)]
pub fn finish<T: Output>(linear: &Linear<'_>, row: usize, acc: i32) -> T {
    let shift = linear.shifts.get(row).map_or(0, |&s| s as i8);
    let (low, high) = output_bounds::<T>(linear);
    T::narrow(requantize_clamped(
        acc,
        i32_at(linear.multipliers, row),
        shift,
        linear.output_zero_point,
        low,
        high,
    ))
}

/// Runs one layer with the chosen kernel. The caller passes slices of exactly `row_len` and
/// `rows` elements; an unsupported kernel falls back to the scalar one.
#[inline]
pub fn linear<T: Output>(kernel: Kernel, linear: &Linear<'_>, input: &[i16], output: &mut [T]) {
    linear_batch(kernel, linear, input, linear.row_len, output);
}

/// Input rows handled per call in the padded layout of [`linear_batch`]: row lengths are
/// rounded up to a multiple of this, so that SIMD kernels read whole 16-lane blocks.
pub const ROW_ALIGN: usize = 16;

/// `row_len` rounded up to [`ROW_ALIGN`] (the stride [`linear_batch`] runs fastest with).
#[inline]
pub const fn padded_row_len(row_len: usize) -> usize {
    row_len.div_ceil(ROW_ALIGN) * ROW_ALIGN
}

/// Puts one input row (its first `row_len` elements) in the order the kernel reads: a no-op
/// but for [`Kernel::Dsp`], whose `SXTB16` pairs weights 0 with 2 and 1 with 3 (see
/// `dsp_m4::permute`). Every producer of [`linear_batch`]'s inputs calls it once per row.
#[inline(always)]
pub fn prepare_row(kernel: Kernel, row: &mut [i16]) {
    match kernel {
        #[cfg(all(target_arch = "arm", target_feature = "dsp"))]
        Kernel::Dsp => super::dsp_m4::permute(row),
        _ => {
            let _ = row;
        }
    }
}

/// Runs one layer on several input rows at once (the patches of several conv output pixels):
/// input row `p` is `inputs[p * stride..p * stride + row_len]`, its outputs go to
/// `outputs[p * rows..(p + 1) * rows]` (pixel-major, which is HWC for a conv), and the number
/// of rows run is `outputs.len() / rows`.
///
/// Batching is what makes the SIMD kernels fast: each weight block is loaded and widened once
/// for two pixels, and requantization runs 4 rows at a time in vector registers. Elements
/// between `row_len` and `stride` are never used, so their content does not matter. Mismatched
/// lengths (a caller bug) make the scalar kernel run on what fits instead of panicking.
#[inline]
pub fn linear_batch<T: Output>(
    kernel: Kernel,
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    outputs: &mut [T],
) {
    match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => super::simd_x86::linear_batch_avx2(linear, inputs, stride, outputs),
        #[cfg(all(target_arch = "arm", target_feature = "dsp"))]
        Kernel::Dsp => super::dsp_m4::linear_batch_dsp(linear, inputs, stride, outputs),
        _ => linear_batch_scalar(linear, inputs, stride, outputs),
    }
}

/// [`linear_batch`] with the portable kernel: one [`linear_scalar`] per input row.
pub fn linear_batch_scalar<T: Output>(
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    outputs: &mut [T],
) {
    if linear.rows == 0 || stride == 0 {
        return;
    }
    // On a controller one copy serves both output types (flash is scarce there): the type
    // only decides the store.
    #[cfg(target_arch = "arm")]
    {
        let (low, high) = output_bounds::<T>(linear);
        linear_batch_scalar_any(linear, inputs, stride, T::slice(outputs), (low, high));
    }
    #[cfg(not(target_arch = "arm"))]
    for (pixel, output) in outputs.chunks_exact_mut(linear.rows).enumerate() {
        let start = pixel.saturating_mul(stride);
        let Some(input) = inputs.get(start..start.saturating_add(linear.row_len)) else {
            return;
        };
        linear_scalar(linear, input, output);
    }
}

/// [`linear_batch_scalar`] for either output type, within `bounds` (the type's
/// [`output_bounds`]): the same sums and requantization as [`linear_scalar`].
#[cfg(target_arch = "arm")]
#[inline(never)]
fn linear_batch_scalar_any(
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    mut outputs: OutputSlice<'_>,
    (low, high): (i16, i16),
) {
    let total = match &outputs {
        OutputSlice::Int8(out) => out.len(),
        OutputSlice::Int16(out) => out.len(),
    };
    let pixels = total / linear.rows;
    for pixel in 0..pixels {
        let start = pixel.saturating_mul(stride);
        let Some(input) = inputs.get(start..start.saturating_add(linear.row_len)) else {
            return;
        };
        let rows = linear
            .weights
            .chunks_exact(linear.row_len)
            .zip(linear.bias.chunks_exact(4))
            .zip(linear.multipliers.chunks_exact(4))
            .zip(linear.shifts);
        for (r, (((weights, bias), multiplier), &shift)) in rows.enumerate() {
            let value = requantize_clamped(
                dot_scalar(input, weights) + le_i32(bias),
                le_i32(multiplier),
                shift as i8,
                linear.output_zero_point,
                low,
                high,
            );
            let index = pixel * linear.rows + r;
            match &mut outputs {
                OutputSlice::Int8(out) => {
                    if let Some(slot) = out.get_mut(index) {
                        *slot = value as i8;
                    }
                }
                OutputSlice::Int16(out) => {
                    if let Some(slot) = out.get_mut(index) {
                        *slot = value;
                    }
                }
            }
        }
    }
}

/// Quantizes raw inputs in millimetres (the height map) to int8 with one
/// [`InputQuantRecord`]: `clamp(zero_point + rescale(mm), -128, 127)` per element, over the
/// shorter of the two slices.
#[inline]
pub fn quantize_inputs(
    kernel: Kernel,
    quant: &InputQuantRecord,
    values_mm: &[i16],
    out: &mut [i8],
) {
    match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => super::simd_x86::quantize_inputs_avx2(quant, values_mm, out),
        #[cfg(all(target_arch = "arm", target_feature = "dsp"))]
        Kernel::Dsp => super::dsp_m4::quantize_inputs_dsp(quant, values_mm, out),
        _ => quantize_inputs_scalar(quant, values_mm, out),
    }
}

/// [`quantize_inputs`] with the portable kernel.
pub fn quantize_inputs_scalar(quant: &InputQuantRecord, values_mm: &[i16], out: &mut [i8]) {
    for (q, &mm) in out.iter_mut().zip(values_mm) {
        *q = quantize_mm(
            i32::from(mm),
            quant.multiplier,
            quant.shift,
            quant.zero_point,
        );
    }
}
