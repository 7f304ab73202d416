//! x86_64 AVX2 kernel and CPU feature detection without `std`.
//!
//! The only `unsafe` code of the crate lives here: CPUID/XGETBV reads and the AVX2 intrinsics.
//! Detection follows Intel's SDM (vol. 1, 14.3): AVX2 is usable when CPUID reports AVX2 and
//! OSXSAVE, and XCR0 shows the OS saves SSE and AVX state. The answer is cached in an atomic,
//! because CPUID traps to the hypervisor on virtual machines and costs microseconds.
//!
//! The kernel is a small matrix product: 2 input rows (conv output pixels) x 4 output rows
//! (channels) per step, so every widened weight block feeds 2 `vpmaddwd` and every activation
//! block 4 (`vpmaddwd`: 16 int16 x int16 products summed pairwise into 8 int32 lanes, exact for
//! our ranges: |x| <= 255, |w| <= 128). Integer addition is associative, so the sums equal the
//! scalar kernel's bit for bit. Requantization runs 4 outputs per vector on exact 64-bit
//! products (`vpmuldq`); AVX2 has no 64-bit arithmetic right shift, so the shift is done as a
//! logical one on the value offset by 2^63 (see [`requant4`]). Tests in `tests/inference.rs`
//! hold every path to the scalar kernel and to an independent reference.
//!
//! Pieces: detection and the safe entry points here; the matrix product in `linear.rs`; the
//! one-channel 3 x 3 conv in `conv.rs`; requantization and stores in `requant.rs`.
#![allow(unsafe_code)]

mod conv;
mod linear;
mod requant;

pub use conv::conv3x3_one_channel_avx2;
use linear::linear_batch_unchecked;
use requant::{requant4, Requant4};

use core::arch::x86_64::{
    __cpuid_count, _mm256_castsi256_si128, _mm256_cvtepi16_epi32, _mm256_extracti128_si256,
    _mm_loadu_si128, _mm_packs_epi16, _mm_packs_epi32, _mm_set1_epi32, _mm_set1_epi8,
    _mm_setzero_si128, _mm_storeu_si128, _xgetbv,
};
use core::sync::atomic::{AtomicU8, Ordering};

use super::format::InputQuantRecord;
use super::infer::gather_pixels;
use super::kernel::{linear_batch_scalar, quantize_inputs_scalar, Output};
use super::load::{ConvLayer, Linear};

/// 0: not yet detected, 1: no AVX2, 2: AVX2.
static AVX2_STATE: AtomicU8 = AtomicU8::new(0);

/// Whether AVX2 is usable, from CPUID and XCR0 (cached after the first call).
pub fn avx2_supported() -> bool {
    match AVX2_STATE.load(Ordering::Relaxed) {
        1 => false,
        2 => true,
        _ => {
            let supported = detect_avx2();
            AVX2_STATE.store(if supported { 2 } else { 1 }, Ordering::Relaxed);
            supported
        }
    }
}

fn detect_avx2() -> bool {
    // SAFETY: CPUID exists on every x86_64 processor; leaf 0 reports the highest leaf, which is
    // checked before leaf 7 is read.
    #[allow(unused_unsafe)]
    let max_leaf = unsafe { __cpuid_count(0, 0) }.eax;
    if max_leaf < 7 {
        return false;
    }
    // SAFETY: leaf 1 exists on every x86_64 processor.
    #[allow(unused_unsafe)]
    let leaf1 = unsafe { __cpuid_count(1, 0) };
    let osxsave = leaf1.ecx & (1 << 27) != 0;
    let avx = leaf1.ecx & (1 << 28) != 0;
    if !(osxsave && avx) {
        return false;
    }
    // SAFETY: OSXSAVE is set, so XGETBV is enabled by the OS and `read_xcr0` may execute.
    let xcr0 = unsafe { read_xcr0() };
    // Bits 1 (SSE) and 2 (AVX upper halves) must both be saved by the OS on context switches.
    if xcr0 & 0b110 != 0b110 {
        return false;
    }
    // SAFETY: leaf 7 exists (checked against the highest leaf above).
    #[allow(unused_unsafe)]
    let leaf7 = unsafe { __cpuid_count(7, 0) };
    leaf7.ebx & (1 << 5) != 0
}

/// Reads XCR0.
///
/// # Safety
/// The caller must have checked CPUID.1:ECX.OSXSAVE.
#[target_feature(enable = "xsave")]
unsafe fn read_xcr0() -> u64 {
    // SAFETY: per this function's contract, XGETBV is enabled.
    unsafe { _xgetbv(0) }
}

/// [`super::kernel::linear_batch`] with AVX2 when the CPU has it (falls back to the scalar
/// kernel otherwise, and on inconsistent lengths, so calling it is always safe).
pub fn linear_batch_avx2<T: Output>(
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    outputs: &mut [T],
) {
    let rows = linear.rows;
    let row_len = linear.row_len;
    let count = outputs.len().checked_div(rows).unwrap_or(0);
    // The bounds the unsafe code relies on, checked once here rather than trusted.
    let shapes_ok = rows > 0
        && row_len > 0
        && stride >= row_len
        && outputs.len() == count.saturating_mul(rows)
        && count
            .checked_sub(1)
            .is_none_or(|last| last.saturating_mul(stride).saturating_add(row_len) <= inputs.len())
        && linear.weights.len() == rows.saturating_mul(row_len)
        && linear.bias.len() == rows.saturating_mul(4)
        && linear.multipliers.len() == rows.saturating_mul(4)
        && linear.shifts.len() == rows;
    if !shapes_ok || !avx2_supported() {
        linear_batch_scalar(linear, inputs, stride, outputs);
        return;
    }
    // SAFETY: AVX2 is supported (checked just above) and the slice lengths the function
    // reads with raw pointers were checked against `rows`, `row_len`, `stride` and `count`.
    unsafe { linear_batch_unchecked(linear, inputs, stride, count, outputs) }
}

/// The conv patch gather of `infer`, compiled for AVX2 when the CPU has it.
pub fn gather_avx2(
    conv: &ConvLayer<'_>,
    src: &[i8],
    first: usize,
    patches: &mut [i16],
    stride: usize,
) {
    if avx2_supported() {
        // SAFETY: AVX2 is supported (checked just above); the body is safe code.
        unsafe { gather_avx2_unchecked(conv, src, first, patches, stride) }
    } else {
        gather_pixels(conv, src, first, patches, stride);
    }
}

/// # Safety
/// AVX2 must be available.
#[target_feature(enable = "avx2")]
unsafe fn gather_avx2_unchecked(
    conv: &ConvLayer<'_>,
    src: &[i8],
    first: usize,
    patches: &mut [i16],
    stride: usize,
) {
    gather_pixels(conv, src, first, patches, stride);
}

/// [`super::kernel::quantize_inputs`] with AVX2 when the CPU has it.
pub fn quantize_inputs_avx2(quant: &InputQuantRecord, values_mm: &[i16], out: &mut [i8]) {
    if !avx2_supported() {
        quantize_inputs_scalar(quant, values_mm, out);
        return;
    }
    // SAFETY: AVX2 is supported (checked just above).
    unsafe { quantize_inputs_unchecked(quant, values_mm, out) }
}

/// # Safety
/// AVX2 must be available.
#[target_feature(enable = "avx2")]
unsafe fn quantize_inputs_unchecked(quant: &InputQuantRecord, values_mm: &[i16], out: &mut [i8]) {
    let multipliers = _mm_set1_epi32(quant.multiplier);
    let shifts = _mm_set1_epi8(quant.shift);
    let constants = Requant4::new(multipliers, shifts, quant.zero_point, -128, 127);
    let mut chunks = values_mm.chunks_exact(8).zip(out.chunks_exact_mut(8));
    for (values, bytes) in &mut chunks {
        // SAFETY: `values` is 8 i16 (16 bytes).
        let wide = _mm256_cvtepi16_epi32(unsafe { _mm_loadu_si128(values.as_ptr().cast()) });
        let low = requant4(_mm256_castsi256_si128(wide), &constants);
        let high = requant4(_mm256_extracti128_si256::<1>(wide), &constants);
        let packed = _mm_packs_epi16(_mm_packs_epi32(low, high), _mm_setzero_si128());
        let mut eight = [0i8; 16];
        // SAFETY: `eight` is 16 bytes.
        unsafe { _mm_storeu_si128(eight.as_mut_ptr().cast(), packed) };
        for (slot, value) in bytes.iter_mut().zip(eight) {
            *slot = value;
        }
    }
    let done = values_mm.len().min(out.len()) / 8 * 8;
    if let (Some(values), Some(bytes)) = (values_mm.get(done..), out.get_mut(done..)) {
        quantize_inputs_scalar(quant, values, bytes);
    }
}
