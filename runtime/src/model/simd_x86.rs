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
    __cpuid_count, __m128i, __m256i, _mm256_add_epi32, _mm256_castsi256_si128,
    _mm256_cvtepi8_epi16, _mm256_extracti128_si256, _mm256_hadd_epi32, _mm256_loadu_si256,
    _mm256_madd_epi16, _mm256_setzero_si256, _mm_add_epi32, _mm_cvtsi128_si32, _mm_loadu_si128,
    _mm_storeu_si128, _xgetbv,
};
use core::sync::atomic::{AtomicU8, Ordering};

use super::kernel::{finish, linear_scalar};
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
    let rows = linear.rows;
    // The bounds the unsafe code relies on, checked once here rather than trusted.
    let shapes_ok = input.len() == linear.row_len
        && output.len() == rows
        && linear.weights.len() == rows.saturating_mul(linear.row_len)
        && linear.bias.len() == rows.saturating_mul(4)
        && linear.multipliers.len() == rows.saturating_mul(4)
        && linear.shifts.len() == rows;
    if !shapes_ok || !avx2_supported() {
        linear_scalar(linear, input, output);
        return;
    }
    // SAFETY: AVX2 is supported (checked just above) and the slice lengths the function
    // reads with raw pointers were checked against `rows` and `row_len`.
    unsafe { linear_avx2_unchecked(linear, input, output) }
}

/// Sums each of four 8-lane accumulators: `[sum(a), sum(b), sum(c), sum(d)]`.
#[target_feature(enable = "avx2")]
fn hsum4(a: __m256i, b: __m256i, c: __m256i, d: __m256i) -> __m128i {
    // Within each 128-bit half: pairwise sums of a,b then c,d, then of those.
    let ab = _mm256_hadd_epi32(a, b);
    let cd = _mm256_hadd_epi32(c, d);
    let abcd = _mm256_hadd_epi32(ab, cd);
    _mm_add_epi32(
        _mm256_castsi256_si128(abcd),
        _mm256_extracti128_si256::<1>(abcd),
    )
}

/// 16 weights of a row's last, partial block. Lanes past the row's end multiply zero inputs,
/// so whatever they hold (the next row's weights, or zeros past the tensor) adds nothing.
///
/// # Safety
/// AVX2 must be available and `start < weights.len()`.
#[target_feature(enable = "avx2")]
unsafe fn load_tail_weights(weights: &[u8], start: usize) -> __m256i {
    if start + 16 <= weights.len() {
        // SAFETY: the 16 bytes at `start` are inside `weights` (checked just above).
        _mm256_cvtepi8_epi16(unsafe { _mm_loadu_si128(weights.as_ptr().add(start).cast()) })
    } else {
        let mut padded = [0u8; 16];
        for (slot, byte) in padded.iter_mut().zip(weights.get(start..).unwrap_or(&[])) {
            *slot = *byte;
        }
        // SAFETY: `padded` is 16 bytes.
        _mm256_cvtepi8_epi16(unsafe { _mm_loadu_si128(padded.as_ptr().cast()) })
    }
}

/// # Safety
/// AVX2 must be available; `input.len() == row_len`, `output.len() == rows`,
/// `weights.len() == rows * row_len`, `bias.len() == multipliers.len() == 4 * rows` and
/// `shifts.len() == rows`.
#[target_feature(enable = "avx2")]
unsafe fn linear_avx2_unchecked(linear: &Linear<'_>, input: &[i16], output: &mut [i8]) {
    let row_len = linear.row_len;
    let rows = linear.rows;
    let tail = row_len % 16;
    // Elements handled by whole 16-wide blocks; the last partial block is zero-padded.
    let body = row_len - tail;
    let x = input.as_ptr();
    let w = linear.weights.as_ptr();
    let mut x_tail = [0i16; 16];
    for (slot, value) in x_tail.iter_mut().zip(input.get(body..).unwrap_or(&[])) {
        *slot = *value;
    }
    // SAFETY: `x_tail` is 16 i16.
    let x_tail = unsafe { _mm256_loadu_si256(x_tail.as_ptr().cast()) };

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
        if tail != 0 {
            for (r, acc) in acc.iter_mut().enumerate() {
                // SAFETY: AVX2 is available; the start is inside `weights` since tail > 0.
                let ws = unsafe { load_tail_weights(linear.weights, (row + r) * row_len + body) };
                *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(x_tail, ws));
            }
        }
        let [a, b, c, d] = acc;
        // SAFETY: row + 4 <= rows, so the 16 bias bytes at 4 * row are inside `bias`.
        let bias = unsafe { _mm_loadu_si128(linear.bias.as_ptr().add(4 * row).cast()) };
        let mut sums = [0i32; 4];
        // SAFETY: `sums` is 16 bytes.
        unsafe {
            _mm_storeu_si128(
                sums.as_mut_ptr().cast(),
                _mm_add_epi32(hsum4(a, b, c, d), bias),
            )
        };
        for (r, sum) in sums.into_iter().enumerate() {
            if let Some(out) = output.get_mut(row + r) {
                *out = finish(linear, row + r, sum);
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
        if tail != 0 {
            // SAFETY: AVX2 is available; the start is inside `weights` since tail > 0.
            let ws = unsafe { load_tail_weights(linear.weights, row * row_len + body) };
            acc = _mm256_add_epi32(acc, _mm256_madd_epi16(x_tail, ws));
        }
        let zero = _mm256_setzero_si256();
        let sum = _mm_cvtsi128_si32(hsum4(acc, zero, zero, zero)) + i32_at(linear.bias, row);
        if let Some(out) = output.get_mut(row) {
            *out = finish(linear, row, sum);
        }
        row += 1;
    }
}
