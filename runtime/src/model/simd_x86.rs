//! x86_64 AVX2 kernel and CPU feature detection without `std`.
//!
//! The only `unsafe` code of the crate lives here: CPUID/XGETBV reads and the AVX2 intrinsics.
//! Detection follows Intel's SDM (vol. 1, 14.3): AVX2 is usable when CPUID reports AVX2 and
//! OSXSAVE, and XCR0 shows the OS saves SSE and AVX state. The answer is cached in an atomic,
//! because CPUID traps to the hypervisor on virtual machines and costs microseconds.
//!
//! The kernel computes 4 output rows at a time so every activation load feeds 4 `vpmaddwd`
//! (16 int16 x int16 products summed pairwise into 8 int32 lanes, exact for our ranges: |x| <=
//! 255, |w| <= 128). Integer addition is associative, so the result equals the scalar kernel's
//! bit for bit; tests in `tests/kernels.rs` hold it to that.
#![allow(unsafe_code)]

use core::arch::x86_64::{
    __cpuid_count, __m256i, _mm256_add_epi32, _mm256_castsi256_si128, _mm256_cvtepi8_epi16,
    _mm256_extracti128_si256, _mm256_loadu_si256, _mm256_madd_epi16, _mm256_setzero_si256,
    _mm_add_epi32, _mm_cvtsi128_si32, _mm_loadu_si128, _mm_shuffle_epi32, _xgetbv,
};
use core::sync::atomic::{AtomicU8, Ordering};

use super::kernel::{dot_scalar, finish, linear_scalar};
use super::load::{i32_at, Linear};

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

/// [`super::kernel::linear_scalar`]'s contract, with AVX2 when the CPU has it (falls back to the
/// scalar kernel otherwise, so calling it is always safe).
pub fn linear_avx2(linear: &Linear<'_>, input: &[i16], output: &mut [i8]) {
    let row_len = linear.row_len;
    // The bounds the unsafe code relies on, checked once here rather than trusted.
    let shapes_ok = input.len() == row_len
        && output.len() == linear.rows
        && linear.weights.len() == linear.rows.saturating_mul(row_len);
    if !shapes_ok || !avx2_supported() {
        linear_scalar(linear, input, output);
        return;
    }
    // SAFETY: AVX2 is supported (checked just above) and the slice lengths the function
    // indexes with raw pointers were checked against `rows` and `row_len`.
    unsafe { linear_avx2_unchecked(linear, input, output) }
}

/// Sums the 8 int32 lanes.
#[target_feature(enable = "avx2")]
fn hsum(v: __m256i) -> i32 {
    let sum = _mm_add_epi32(_mm256_castsi256_si128(v), _mm256_extracti128_si256::<1>(v));
    let sum = _mm_add_epi32(sum, _mm_shuffle_epi32::<0b01_00_11_10>(sum));
    let sum = _mm_add_epi32(sum, _mm_shuffle_epi32::<0b10_11_00_01>(sum));
    _mm_cvtsi128_si32(sum)
}

/// # Safety
/// AVX2 must be available; `input.len() == row_len`, `output.len() == rows` and
/// `weights.len() == rows * row_len`.
#[target_feature(enable = "avx2")]
unsafe fn linear_avx2_unchecked(linear: &Linear<'_>, input: &[i16], output: &mut [i8]) {
    let row_len = linear.row_len;
    let rows = linear.rows;
    // Elements handled by whole 16-wide blocks; the rest by the scalar dot product.
    let body = row_len - row_len % 16;
    let x = input.as_ptr();
    let w = linear.weights.as_ptr();

    let mut row = 0;
    while row + 4 <= rows {
        let mut acc = [_mm256_setzero_si256(); 4];
        let mut i = 0;
        while i < body {
            // SAFETY: i + 16 <= body <= row_len = input.len(), so 16 i16 (32 bytes) are in
            // bounds; loadu has no alignment requirement.
            let xs = unsafe { _mm256_loadu_si256(x.add(i).cast::<__m256i>()) };
            for (r, acc) in acc.iter_mut().enumerate() {
                // SAFETY: (row + r) < rows and i + 16 <= row_len, so the 16 bytes at
                // (row + r) * row_len + i are inside `weights` (rows * row_len bytes).
                let ws = unsafe { _mm_loadu_si128(w.add((row + r) * row_len + i).cast()) };
                *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(xs, _mm256_cvtepi8_epi16(ws)));
            }
            i += 16;
        }
        for (r, acc) in acc.iter().enumerate() {
            let index = row + r;
            let start = index * row_len;
            let tail_w = linear
                .weights
                .get(start + body..start + row_len)
                .unwrap_or(&[]);
            let tail_x = input.get(body..).unwrap_or(&[]);
            let sum = hsum(*acc) + dot_scalar(tail_x, tail_w) + i32_at(linear.bias, index);
            if let Some(out) = output.get_mut(index) {
                *out = finish(linear, index, sum);
            }
        }
        row += 4;
    }
    while row < rows {
        let mut acc = _mm256_setzero_si256();
        let mut i = 0;
        while i < body {
            // SAFETY: as in the 4-row loop, for the single row `row < rows`.
            let xs = unsafe { _mm256_loadu_si256(x.add(i).cast::<__m256i>()) };
            // SAFETY: as above.
            let ws = unsafe { _mm_loadu_si128(w.add(row * row_len + i).cast()) };
            acc = _mm256_add_epi32(acc, _mm256_madd_epi16(xs, _mm256_cvtepi8_epi16(ws)));
            i += 16;
        }
        let start = row * row_len;
        let tail_w = linear
            .weights
            .get(start + body..start + row_len)
            .unwrap_or(&[]);
        let tail_x = input.get(body..).unwrap_or(&[]);
        let sum = hsum(acc) + dot_scalar(tail_x, tail_w) + i32_at(linear.bias, row);
        if let Some(out) = output.get_mut(row) {
            *out = finish(linear, row, sum);
        }
        row += 1;
    }
}
