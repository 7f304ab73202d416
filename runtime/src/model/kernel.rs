//! The one compute kernel every layer reduces to: for each output row, a dot product of an
//! int16 input row (activations minus their zero point) with an int8 weight row, plus bias, then
//! requantization. Conv layers call it once per output pixel with the gathered patch; dense
//! layers once with the whole input vector.
//!
//! Two implementations, bit-exact by construction: integer sums are exact in any order (the
//! loader bounds row length and bias so that no partial sum can overflow an i32), and both share
//! the scalar requantization of [`super::quant`].

use super::load::{i32_at, Linear};
use super::quant::to_int8;

/// Which implementation of the kernel runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// Portable Rust, any target.
    Scalar,
    /// x86_64 AVX2 (`vpmaddwd`, 16 multiply-accumulates per instruction).
    Avx2,
}

impl Kernel {
    /// Every kernel, for tests and benchmarks.
    pub const ALL: [Kernel; 2] = [Kernel::Scalar, Kernel::Avx2];

    /// The fastest kernel this CPU runs, found by reading CPUID (works without `std`).
    pub fn detect() -> Kernel {
        if Kernel::Avx2.is_supported() {
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
pub fn linear_scalar(linear: &Linear<'_>, input: &[i16], output: &mut [i8]) {
    // Lock-step iterators over the per-row tensors: no index arithmetic or bounds checks per row.
    let rows = linear
        .weights
        .chunks_exact(linear.row_len)
        .zip(linear.bias.chunks_exact(4))
        .zip(linear.multipliers.chunks_exact(4))
        .zip(linear.shifts);
    for (out, (((weights, bias), multiplier), &shift)) in output.iter_mut().zip(rows) {
        let acc = dot_scalar(input, weights) + le_i32(bias);
        *out = to_int8(
            acc,
            le_i32(multiplier),
            shift as i8,
            linear.output_zero_point,
            linear.relu,
        );
    }
}

/// An i32 from 4 little-endian bytes (0 if fewer: lengths were checked by the loader).
#[inline(always)]
fn le_i32(bytes: &[u8]) -> i32 {
    match bytes {
        &[a, b, c, d] => i32::from_le_bytes([a, b, c, d]),
        _ => 0,
    }
}

/// Requantizes one accumulator of row `row` (shared by every kernel).
#[inline(always)]
pub fn finish(linear: &Linear<'_>, row: usize, acc: i32) -> i8 {
    let shift = linear.shifts.get(row).map_or(0, |&s| s as i8);
    to_int8(
        acc,
        i32_at(linear.multipliers, row),
        shift,
        linear.output_zero_point,
        linear.relu,
    )
}

/// Runs one layer with the chosen kernel. The caller passes slices of exactly `row_len` and
/// `rows` elements; an unsupported kernel falls back to the scalar one.
#[inline]
pub fn linear(kernel: Kernel, linear: &Linear<'_>, input: &[i16], output: &mut [i8]) {
    match kernel {
        #[cfg(target_arch = "x86_64")]
        Kernel::Avx2 => super::simd_x86::linear_avx2(linear, input, output),
        _ => linear_scalar(linear, input, output),
    }
}
