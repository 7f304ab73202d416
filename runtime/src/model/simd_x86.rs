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
#![allow(unsafe_code)]

use core::arch::asm;
use core::arch::x86_64::{
    __cpuid_count, __m128i, __m256i, _mm256_add_epi32, _mm256_add_epi64, _mm256_and_si256,
    _mm256_blendv_epi8, _mm256_castsi256_si128, _mm256_cmpgt_epi64, _mm256_cvtepi16_epi32,
    _mm256_cvtepi32_epi64, _mm256_cvtepi8_epi16, _mm256_cvtepi8_epi64, _mm256_extracti128_si256,
    _mm256_hadd_epi32, _mm256_loadu_si256, _mm256_madd_epi16, _mm256_permutevar8x32_epi32,
    _mm256_set1_epi32, _mm256_set1_epi64x, _mm256_setr_epi32, _mm256_setzero_si256,
    _mm256_sllv_epi64, _mm256_srlv_epi64, _mm256_sub_epi64, _mm256_xor_si256, _mm_add_epi32,
    _mm_cvtsi128_si32, _mm_cvtsi128_si64, _mm_cvtsi32_si128, _mm_loadu_si128, _mm_max_epi8,
    _mm_min_epi8, _mm_packs_epi16, _mm_packs_epi32, _mm_set1_epi32, _mm_set1_epi8,
    _mm_setzero_si128, _mm_storeu_si128, _xgetbv,
};
use core::sync::atomic::{AtomicU8, Ordering};

use super::format::InputQuantRecord;
use super::infer::gather_pixels;
use super::kernel::{finish, linear_batch_scalar, quantize_inputs_scalar, Output, OutputSlice};
use super::load::{i32_at, ConvLayer, Linear};
use super::quant::{MAX_SHIFT, MIN_SHIFT};

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

/// Sums each of four 8-lane accumulators: `[sum(a), sum(b), sum(c), sum(d)]`.
#[target_feature(enable = "avx2")]
#[inline]
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
/// AVX2 must be available.
#[target_feature(enable = "avx2")]
unsafe fn load_tail_weights(weights: &[u8], start: usize) -> __m256i {
    if start.saturating_add(16) <= weights.len() {
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

/// The last `tail` (< 16) inputs of a row starting at `start`, zero in the other lanes. Reads
/// the 16 lanes directly and masks them when they are inside `inputs` (always, in the padded
/// layout `infer` uses), and copies otherwise.
#[target_feature(enable = "avx2")]
fn tail_inputs(inputs: &[i16], start: usize, tail: usize, mask: __m256i) -> __m256i {
    if tail == 0 {
        return _mm256_setzero_si256();
    }
    match inputs.get(start..start.saturating_add(16)) {
        // SAFETY: `block` is 16 i16 (32 bytes); loadu has no alignment requirement.
        Some(block) => _mm256_and_si256(unsafe { _mm256_loadu_si256(block.as_ptr().cast()) }, mask),
        None => {
            let mut padded = [0i16; 16];
            let values = inputs.get(start..).unwrap_or(&[]).iter().take(tail);
            for (slot, value) in padded.iter_mut().zip(values) {
                *slot = *value;
            }
            // SAFETY: `padded` is 16 i16.
            unsafe { _mm256_loadu_si256(padded.as_ptr().cast()) }
        }
    }
}

/// Requantization constants of 4 output rows, one per 64-bit lane.
#[derive(Clone, Copy)]
struct Requant4 {
    /// The 4 multipliers as i32 (sign-extended where used: see [`requant4`]).
    multiplier: __m128i,
    /// The right shift `31 - shift`, in `1..=62`.
    right: __m256i,
    /// `2^(right - 1)`: rounds halves towards +infinity.
    half: __m256i,
    /// `2^63 >> right`: undoes the 2^63 offset of the logical shift.
    offset: __m256i,
    /// Output zero point.
    zero_point: __m256i,
    /// Lowest output (int8: the zero point under ReLU, else -128; int16 logits: -32768).
    low: __m256i,
    /// Highest output (int8: 127; int16 logits: 32767).
    high: __m256i,
}

impl Requant4 {
    /// Constants from 4 multipliers and 4 shifts (shifts clamped as the scalar code does) and
    /// the output bounds.
    #[target_feature(enable = "avx2")]
    #[inline]
    fn new(multipliers: __m128i, shifts: __m128i, zero_point: i8, low: i16, high: i16) -> Requant4 {
        let shifts = _mm_min_epi8(
            _mm_max_epi8(shifts, _mm_set1_epi8(MIN_SHIFT)),
            _mm_set1_epi8(MAX_SHIFT),
        );
        let right = _mm256_sub_epi64(_mm256_set1_epi64x(31), _mm256_cvtepi8_epi64(shifts));
        let one = _mm256_set1_epi64x(1);
        Requant4 {
            multiplier: multipliers,
            right,
            half: _mm256_sllv_epi64(one, _mm256_sub_epi64(right, one)),
            offset: _mm256_srlv_epi64(_mm256_set1_epi64x(i64::MIN), right),
            zero_point: _mm256_set1_epi64x(i64::from(zero_point)),
            low: _mm256_set1_epi64x(i64::from(low)),
            high: _mm256_set1_epi64x(i64::from(high)),
        }
    }

    /// The constants of rows `row..row + 4` of a layer.
    ///
    /// # Safety
    /// AVX2 must be available and `row + 4 <= linear.rows`, with the tensor lengths checked by
    /// [`linear_batch_avx2`].
    #[target_feature(enable = "avx2")]
    #[inline]
    unsafe fn for_rows(linear: &Linear<'_>, row: usize) -> Requant4 {
        // SAFETY: rows `row..row + 4` exist, so 16 multiplier bytes at 4 * row are in bounds.
        let multipliers =
            unsafe { _mm_loadu_si128(linear.multipliers.as_ptr().add(4 * row).cast()) };
        let shifts = match linear.shifts.get(row..row + 4) {
            Some(&[a, b, c, d]) => i32::from_le_bytes([a, b, c, d]),
            _ => 0,
        };
        Requant4::new(
            multipliers,
            _mm_cvtsi32_si128(shifts),
            linear.output_zero_point,
            linear.output_low,
            linear.output_high,
        )
    }
}

/// `requantize_clamped` of 4 accumulators at once: `clamp(zp + floor((acc * M + 2^(r-1)) /
/// 2^r), low, high)` (min with `high`, then max with `low`, as the scalar code) with the exact 64-bit product, as 4 i32 lanes. The arithmetic right shift is a logical
/// one of `t + 2^63` (xor of the sign bit) minus `2^63 >> r`, exact because `2^r` divides
/// `2^63`; `|t| < 2^62 + 2^61` so nothing wraps.
#[target_feature(enable = "avx2")]
#[inline]
fn requant4(acc: __m128i, c: &Requant4) -> __m128i {
    let product = vpmuldq(
        _mm256_cvtepi32_epi64(acc),
        _mm256_cvtepi32_epi64(c.multiplier),
    );
    let biased = _mm256_xor_si256(
        _mm256_add_epi64(product, c.half),
        _mm256_set1_epi64x(i64::MIN),
    );
    let scaled = _mm256_sub_epi64(vpsrlvq(biased, c.right), c.offset);
    let q = _mm256_add_epi64(scaled, c.zero_point);
    let q = _mm256_blendv_epi8(q, c.high, _mm256_cmpgt_epi64(q, c.high));
    let q = _mm256_blendv_epi8(q, c.low, _mm256_cmpgt_epi64(c.low, q));
    // Low 32 bits of each 64-bit lane (the values fit the output type by now).
    let low_halves = _mm256_permutevar8x32_epi32(q, _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6));
    _mm256_castsi256_si128(low_halves)
}

/// `vpmuldq` (`_mm256_mul_epi32`) as exactly that instruction. LLVM rewrites the intrinsic
/// as a generic 64-bit multiply and, when the constants come back from the stack and it can no
/// longer prove them sign-extended, lowers that to three `vpmuludq` and shifts.
#[target_feature(enable = "avx2")]
#[inline]
fn vpmuldq(a: __m256i, b: __m256i) -> __m256i {
    let out: __m256i;
    // SAFETY: a register-only AVX2 instruction (AVX2 is enabled for this function).
    unsafe {
        asm!("vpmuldq {o}, {a}, {b}", a = in(ymm_reg) a, b = in(ymm_reg) b,
             o = lateout(ymm_reg) out, options(pure, nomem, nostack, preserves_flags));
    }
    out
}

/// `vpsrlvq` (`_mm256_srlv_epi64`) as exactly that instruction: LLVM otherwise adds a
/// compare-and-mask for shift counts above 63 that it cannot rule out (ours are in 1..=62).
#[target_feature(enable = "avx2")]
#[inline]
fn vpsrlvq(a: __m256i, count: __m256i) -> __m256i {
    let out: __m256i;
    // SAFETY: a register-only AVX2 instruction (AVX2 is enabled for this function).
    unsafe {
        asm!("vpsrlvq {o}, {a}, {c}", a = in(ymm_reg) a, c = in(ymm_reg) count,
             o = lateout(ymm_reg) out, options(pure, nomem, nostack, preserves_flags));
    }
    out
}

/// Writes 4 requantized lanes (each within the output type's range) to `out[at..at + 4]`.
#[target_feature(enable = "avx2")]
#[inline]
fn store4<T: Output>(values: __m128i, out: &mut [T], at: usize) {
    // Saturating packs: exact, since the lanes are already within the output bounds.
    let words = _mm_packs_epi32(values, values);
    match T::slice(out) {
        OutputSlice::Int8(out) => {
            let bytes = _mm_packs_epi16(words, _mm_setzero_si128());
            let word = _mm_cvtsi128_si32(bytes).to_le_bytes().map(|b| b as i8);
            if let Some(slot) = out.get_mut(at..at + 4) {
                slot.copy_from_slice(&word);
            }
        }
        OutputSlice::Int16(out) => {
            let bytes = _mm_cvtsi128_si64(words).to_le_bytes();
            if let Some(slot) = out.get_mut(at..at + 4) {
                for (o, pair) in slot.iter_mut().zip(bytes.chunks_exact(2)) {
                    if let &[lo, hi] = pair {
                        *o = i16::from_le_bytes([lo, hi]);
                    }
                }
            }
        }
    }
}

/// `P` input rows (pixels) against all output rows of a layer.
///
/// # Safety
/// AVX2 must be available; every `starts[p] + row_len <= inputs.len()`, every
/// `outs[p] + rows <= outputs.len()`, and the tensor lengths checked by [`linear_batch_avx2`].
#[target_feature(enable = "avx2")]
unsafe fn pixels<T: Output, const P: usize, const TAIL: bool>(
    linear: &Linear<'_>,
    inputs: &[i16],
    starts: [usize; P],
    outs: [usize; P],
    tail_mask: __m256i,
    outputs: &mut [T],
) {
    let row_len = linear.row_len;
    let rows = linear.rows;
    let tail = row_len % 16;
    let body = row_len - tail;
    let w = linear.weights.as_ptr();
    let x = starts.map(|start| inputs.as_ptr().wrapping_add(start));
    let x_tail = starts.map(|start| tail_inputs(inputs, start + body, tail, tail_mask));
    // `TAIL` is `tail != 0`, as a constant: conv rows of 16-channel multiples have no partial
    // block, and without the branch the compiler keeps the accumulators in registers.

    let mut row = 0;
    while row + 4 <= rows {
        let mut acc = [[_mm256_setzero_si256(); 4]; P];
        let mut i = 0;
        while i < body {
            // SAFETY: i + 16 <= body <= row_len and starts[p] + row_len <= inputs.len(), so
            // 16 i16 (32 bytes) are in bounds; loadu has no alignment requirement.
            let xs = x.map(|x| unsafe { _mm256_loadu_si256(x.add(i).cast::<__m256i>()) });
            for r in 0..4 {
                // SAFETY: (row + r) < rows and i + 16 <= row_len, so the 16 bytes at
                // (row + r) * row_len + i are inside `weights` (rows * row_len bytes).
                let ws = _mm256_cvtepi8_epi16(unsafe {
                    _mm_loadu_si128(w.add((row + r) * row_len + i).cast())
                });
                for (acc, xs) in acc.iter_mut().zip(xs) {
                    if let Some(acc) = acc.get_mut(r) {
                        *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(xs, ws));
                    }
                }
            }
            i += 16;
        }
        if TAIL {
            for r in 0..4 {
                // SAFETY: AVX2 is available.
                let ws = unsafe { load_tail_weights(linear.weights, (row + r) * row_len + body) };
                for (acc, xs) in acc.iter_mut().zip(x_tail) {
                    if let Some(acc) = acc.get_mut(r) {
                        *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(xs, ws));
                    }
                }
            }
        }
        // SAFETY: row + 4 <= rows, so the 16 bias bytes at 4 * row are inside `bias`.
        let bias = unsafe { _mm_loadu_si128(linear.bias.as_ptr().add(4 * row).cast()) };
        // SAFETY: row + 4 <= rows; tensor lengths per this function's contract.
        let constants = unsafe { Requant4::for_rows(linear, row) };
        for ([a, b, c, d], &out) in acc.into_iter().zip(&outs) {
            let sums = _mm_add_epi32(hsum4(a, b, c, d), bias);
            store4(requant4(sums, &constants), outputs, out + row);
        }
        row += 4;
    }
    while row < rows {
        let mut acc = [_mm256_setzero_si256(); P];
        let mut i = 0;
        while i < body {
            // SAFETY: as in the 4-row loop, for the single row `row < rows`.
            let ws =
                _mm256_cvtepi8_epi16(unsafe { _mm_loadu_si128(w.add(row * row_len + i).cast()) });
            for (acc, x) in acc.iter_mut().zip(x) {
                // SAFETY: as in the 4-row loop.
                let xs = unsafe { _mm256_loadu_si256(x.add(i).cast::<__m256i>()) };
                *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(xs, ws));
            }
            i += 16;
        }
        if TAIL {
            // SAFETY: AVX2 is available.
            let ws = unsafe { load_tail_weights(linear.weights, row * row_len + body) };
            for (acc, xs) in acc.iter_mut().zip(x_tail) {
                *acc = _mm256_add_epi32(*acc, _mm256_madd_epi16(xs, ws));
            }
        }
        let zero = _mm256_setzero_si256();
        let bias = i32_at(linear.bias, row);
        for (acc, &out) in acc.into_iter().zip(&outs) {
            let sum = _mm_cvtsi128_si32(hsum4(acc, zero, zero, zero)) + bias;
            if let Some(slot) = outputs.get_mut(out + row) {
                *slot = finish(linear, row, sum);
            }
        }
        row += 1;
    }
}

/// Longest row (in input pairs) of the short-row path: a first conv layer on a one-channel map
/// with a 3 x 3 kernel has 9 inputs per output, 5 pairs.
const SHORT_PAIRS: usize = 5;

/// Short rows (at most `2 * SHORT_PAIRS` inputs, a first conv layer): the dot-product layout
/// would fill 9 of 16 lanes and spend more on horizontal sums and per-row requantization than
/// on multiplying. Instead the outputs are the lanes: the weights of 16 rows are packed once
/// per call as `[pair][row][2]` (10 registers), and each pixel broadcasts an input pair to all
/// lanes, so 10 `vpmaddwd` give 16 outputs that are requantized and stored together (HWC is
/// row-contiguous per pixel).
///
/// # Safety
/// AVX2 must be available, the lengths checked by [`linear_batch_avx2`] must hold,
/// `row_len <= 2 * SHORT_PAIRS` and `stride >= 2 * SHORT_PAIRS`.
#[target_feature(enable = "avx2")]
unsafe fn short_rows<T: Output>(
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    count: usize,
    outputs: &mut [T],
) {
    let rows = linear.rows;
    let row_len = linear.row_len;
    let mut first_row = 0;
    while first_row < rows {
        let chunk = (rows - first_row).min(16);
        // Packed weights, and bias and requantization constants, of rows first_row..+chunk;
        // rows past the layer's end get zero weights and are not stored.
        let mut packed = [[0i16; 32]; 2 * SHORT_PAIRS];
        for r in 0..chunk {
            let row = first_row + r;
            let weights = linear
                .weights
                .get(row * row_len..(row + 1) * row_len)
                .unwrap_or(&[]);
            for (k, &w) in weights.iter().enumerate() {
                // pair k / 2, register r / 8, lane pair r % 8, position k % 2.
                if let Some(slot) = packed
                    .get_mut(2 * (k / 2) + r / 8)
                    .and_then(|v| v.get_mut(2 * (r % 8) + k % 2))
                {
                    *slot = i16::from(w as i8);
                }
            }
        }
        // SAFETY: each packed vector is 32 i16 (2 x 256 bits); the first 16 are loaded.
        let w = packed.map(|v| unsafe { _mm256_loadu_si256(v.as_ptr().cast()) });
        let (bias_lo, bias_hi, constants) = chunk_constants(linear, first_row, chunk);
        for pixel in 0..count {
            let x = inputs.as_ptr().wrapping_add(pixel * stride).cast::<i32>();
            let mut lo = bias_lo;
            let mut hi = bias_hi;
            for pair in 0..SHORT_PAIRS {
                // SAFETY: AVX2 is available; `x` is the row's start, as `pair_at` requires
                // (it reads inside `inputs` only).
                let xs = unsafe { pair_at(inputs, x, pixel * stride, pair) };
                if let (Some(&w_lo), Some(&w_hi)) = (w.get(2 * pair), w.get(2 * pair + 1)) {
                    lo = _mm256_add_epi32(lo, _mm256_madd_epi16(xs, w_lo));
                    hi = _mm256_add_epi32(hi, _mm256_madd_epi16(xs, w_hi));
                }
            }
            store16(lo, hi, &constants, outputs, pixel * rows + first_row, chunk);
        }
        first_row += chunk;
    }
}

/// Bias (2 x 8 lanes) and requantization constants (4 x 4 rows) of the rows
/// `first_row..first_row + chunk` (at most 16) of a layer; missing rows get zeros.
#[target_feature(enable = "avx2")]
fn chunk_constants(
    linear: &Linear<'_>,
    first_row: usize,
    chunk: usize,
) -> (__m256i, __m256i, [Requant4; 4]) {
    let mut bias = [0i32; 16];
    let mut multipliers = [0i32; 16];
    let mut shifts = [0u8; 16];
    for r in 0..chunk.min(16) {
        let row = first_row + r;
        if let (Some(b), Some(m), Some(s), Some(&shift)) = (
            bias.get_mut(r),
            multipliers.get_mut(r),
            shifts.get_mut(r),
            linear.shifts.get(row),
        ) {
            *b = i32_at(linear.bias, row);
            *m = i32_at(linear.multipliers, row);
            *s = shift;
        }
    }
    // SAFETY (loads): each array holds 16 elements, at least what is read.
    let bias_lo = unsafe { _mm256_loadu_si256(bias.as_ptr().cast()) };
    let bias_hi = unsafe { _mm256_loadu_si256(bias.as_ptr().add(8).cast()) };
    let mut constants = [Requant4::new(_mm_setzero_si128(), _mm_setzero_si128(), 0, -128, 127); 4];
    for (quarter, c) in constants.iter_mut().enumerate() {
        let m = unsafe { _mm_loadu_si128(multipliers.as_ptr().add(4 * quarter).cast()) };
        let s = match shifts.get(4 * quarter..4 * quarter + 4) {
            Some(&[a, b, c, d]) => i32::from_le_bytes([a, b, c, d]),
            _ => 0,
        };
        *c = Requant4::new(
            m,
            _mm_cvtsi32_si128(s),
            linear.output_zero_point,
            linear.output_low,
            linear.output_high,
        );
    }
    (bias_lo, bias_hi, constants)
}

/// Requantizes 16 accumulators (rows `0..16` of a chunk, as two 8-lane vectors) and writes
/// the first `chunk` of them to `out[at..]`.
#[target_feature(enable = "avx2")]
#[inline]
fn store16<T: Output>(
    lo: __m256i,
    hi: __m256i,
    c: &[Requant4; 4],
    out: &mut [T],
    at: usize,
    chunk: usize,
) {
    let [c0, c1, c2, c3] = c;
    let a = requant4(_mm256_castsi256_si128(lo), c0);
    let b = requant4(_mm256_extracti128_si256::<1>(lo), c1);
    let c = requant4(_mm256_castsi256_si128(hi), c2);
    let d = requant4(_mm256_extracti128_si256::<1>(hi), c3);
    // Saturating packs: exact, since the lanes are already within the output bounds.
    let (ab, cd) = (_mm_packs_epi32(a, b), _mm_packs_epi32(c, d));
    match T::slice(out) {
        OutputSlice::Int8(out) => {
            let mut sixteen = [0i8; 16];
            // SAFETY: `sixteen` is 16 bytes.
            unsafe { _mm_storeu_si128(sixteen.as_mut_ptr().cast(), _mm_packs_epi16(ab, cd)) };
            store_chunk(out, at, chunk, sixteen);
        }
        OutputSlice::Int16(out) => {
            let mut sixteen = [0i16; 16];
            // SAFETY: `sixteen` is 32 bytes: two 16-byte stores.
            unsafe {
                _mm_storeu_si128(sixteen.as_mut_ptr().cast(), ab);
                _mm_storeu_si128(sixteen.as_mut_ptr().add(8).cast(), cd);
            }
            store_chunk(out, at, chunk, sixteen);
        }
    }
}

/// Copies the first `chunk` of `sixteen` values to `out[at..]` (nothing if out of bounds).
#[inline(always)]
fn store_chunk<V: Copy>(out: &mut [V], at: usize, chunk: usize, sixteen: [V; 16]) {
    if let Some(slot) = out.get_mut(at..at + chunk) {
        // A whole chunk is one fixed-size copy (a store, not a `memcpy` call).
        match <&mut [V; 16]>::try_from(&mut *slot) {
            Ok(slot) => *slot = sixteen,
            Err(_) => {
                for (o, v) in slot.iter_mut().zip(sixteen) {
                    *o = v;
                }
            }
        }
    }
}

/// A conv layer on a one-channel map with a 3 x 3 kernel (the first layer), straight from the
/// int8 map: no patch gather at all. For each output row the three input rows it reads are
/// widened once (minus the zero point, zero-padded) into `scratch`; then kernel cells
/// (ky, 0..2) and (ky, 2..4) of a pixel are adjacent i16 pairs of such a row, read as one i32
/// and broadcast, against weights packed per call as `[ky][pair][row][2]` (the (ky, 3) weight
/// is 0). 16 output channels per vector pair, requantized and stored together. Returns
/// `false`, having done nothing, when the layer is not of that shape, the CPU has no AVX2 or
/// `scratch` is too short (the caller then takes the general path).
pub fn conv3x3_one_channel_avx2(
    conv: &ConvLayer<'_>,
    src: &[i8],
    out: &mut [i8],
    scratch: &mut [i16],
) -> bool {
    let linear = &conv.linear;
    let rows = linear.rows;
    let padding = usize::from(conv.record.padding);
    let stride = usize::from(conv.record.stride);
    // One padded row, plus one slack element for the last pixel's (ky, 3) read.
    let width = conv.in_cols + 2 * padding + 1;
    let applicable = conv.in_channels == 1
        && conv.record.kernel == 3
        && rows > 0
        && conv.out_cols > 0
        && linear.row_len == 9
        && linear.weights.len() == rows.saturating_mul(9)
        && linear.bias.len() == rows.saturating_mul(4)
        && linear.multipliers.len() == rows.saturating_mul(4)
        && linear.shifts.len() == rows
        && src.len() >= conv.in_rows.saturating_mul(conv.in_cols)
        && out.len() >= conv.out_rows.saturating_mul(conv.out_cols).saturating_mul(rows)
        && scratch.len() >= 3 * width
        // Reads of pixel ox reach padded column ox * stride + 3.
        && (conv.out_cols - 1) * stride + 4 <= width
        && avx2_supported();
    if applicable {
        // SAFETY: AVX2 is supported and the bounds above hold.
        unsafe { conv3x3_one_channel_unchecked(conv, src, out, scratch, width) };
    }
    applicable
}

/// # Safety
/// AVX2 must be available and the conditions checked by [`conv3x3_one_channel_avx2`] hold.
#[target_feature(enable = "avx2")]
unsafe fn conv3x3_one_channel_unchecked(
    conv: &ConvLayer<'_>,
    src: &[i8],
    out: &mut [i8],
    scratch: &mut [i16],
    width: usize,
) {
    let linear = &conv.linear;
    let rows = linear.rows;
    let padding = usize::from(conv.record.padding);
    let stride = usize::from(conv.record.stride);
    let zero_point = i16::from(linear.input_zero_point);
    let mut first_row = 0;
    while first_row < rows {
        let chunk = (rows - first_row).min(16);
        // Weights: vector 2 * (2 * ky + pair) + r / 8, lanes 2 * (r % 8) + (kx % 2).
        let mut packed = [[0i16; 32]; 12];
        for r in 0..chunk {
            let row = first_row + r;
            let weights = linear.weights.get(row * 9..row * 9 + 9).unwrap_or(&[]);
            for (k, &w) in weights.iter().enumerate() {
                let (ky, kx) = (k / 3, k % 3);
                if let Some(slot) = packed
                    .get_mut(2 * (2 * ky + kx / 2) + r / 8)
                    .and_then(|v| v.get_mut(2 * (r % 8) + kx % 2))
                {
                    *slot = i16::from(w as i8);
                }
            }
        }
        // SAFETY: each packed vector is 32 i16 (2 x 256 bits); the first 16 are loaded.
        let w = packed.map(|v| unsafe { _mm256_loadu_si256(v.as_ptr().cast()) });
        let (bias_lo, bias_hi, constants) = chunk_constants(linear, first_row, chunk);
        for oy in 0..conv.out_rows {
            // The three input rows of this output row, widened and zero-padded.
            for (ky, line) in scratch.chunks_exact_mut(width).take(3).enumerate() {
                let iy = (oy * stride + ky).checked_sub(padding);
                let cells = iy
                    .filter(|&iy| iy < conv.in_rows)
                    .and_then(|iy| src.get(iy * conv.in_cols..(iy + 1) * conv.in_cols));
                line.fill(0);
                if let (Some(cells), Some(inside)) =
                    (cells, line.get_mut(padding..padding + conv.in_cols))
                {
                    for (x, &q) in inside.iter_mut().zip(cells) {
                        *x = i16::from(q) - zero_point;
                    }
                }
            }
            let base = scratch.as_ptr();
            for ox in 0..conv.out_cols {
                let mut lo = bias_lo;
                let mut hi = bias_hi;
                for ky in 0..3 {
                    for pair in 0..2 {
                        // SAFETY: ky * width + ox * stride + 2 * pair + 1 < 3 * width <=
                        // scratch.len() (checked by the caller: (out_cols - 1) * stride + 4
                        // <= width); read_unaligned has no alignment requirement.
                        let xs = _mm256_set1_epi32(unsafe {
                            base.add(ky * width + ox * stride + 2 * pair)
                                .cast::<i32>()
                                .read_unaligned()
                        });
                        let v = 2 * (2 * ky + pair);
                        if let (Some(&w_lo), Some(&w_hi)) = (w.get(v), w.get(v + 1)) {
                            lo = _mm256_add_epi32(lo, _mm256_madd_epi16(xs, w_lo));
                            hi = _mm256_add_epi32(hi, _mm256_madd_epi16(xs, w_hi));
                        }
                    }
                }
                let at = (oy * conv.out_cols + ox) * rows + first_row;
                store16(lo, hi, &constants, out, at, chunk);
            }
        }
        first_row += chunk;
    }
}

/// Inputs `2 * pair` and `2 * pair + 1` of the row at `start`, broadcast to every 32-bit lane;
/// an input past the slice reads as 0 (its weight is 0 anyway).
///
/// # Safety
/// AVX2 must be available; `x` is `inputs.as_ptr() + start` (as `i32` pointer).
#[target_feature(enable = "avx2")]
#[inline]
unsafe fn pair_at(inputs: &[i16], x: *const i32, start: usize, pair: usize) -> __m256i {
    let at = start + 2 * pair;
    if at + 2 <= inputs.len() {
        // SAFETY: the two i16 at `at` are inside `inputs`; read_unaligned has no alignment need.
        _mm256_set1_epi32(unsafe { x.add(pair).read_unaligned() })
    } else {
        let lo = inputs.get(at).copied().unwrap_or(0);
        let hi = inputs.get(at + 1).copied().unwrap_or(0);
        _mm256_set1_epi32(i32::from(lo as u16) | (i32::from(hi) << 16))
    }
}

/// # Safety
/// AVX2 must be available and the lengths checked by [`linear_batch_avx2`] must hold.
#[target_feature(enable = "avx2")]
unsafe fn linear_batch_unchecked<T: Output>(
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    count: usize,
    outputs: &mut [T],
) {
    let rows = linear.rows;
    if linear.row_len <= 2 * SHORT_PAIRS && stride >= 2 * SHORT_PAIRS {
        // SAFETY: forwarded contract, plus `stride >= 2 * SHORT_PAIRS` (checked just above).
        unsafe { short_rows(linear, inputs, stride, count, outputs) };
        return;
    }
    let tail = linear.row_len % 16;
    let mut lanes = [0i16; 16];
    for (lane, slot) in lanes.iter_mut().enumerate() {
        *slot = if lane < tail { -1 } else { 0 };
    }
    // SAFETY: `lanes` is 16 i16.
    let tail_mask = unsafe { _mm256_loadu_si256(lanes.as_ptr().cast()) };
    let mut pixel = 0;
    while pixel + 2 <= count {
        let starts = [pixel * stride, (pixel + 1) * stride];
        let outs = [pixel * rows, (pixel + 1) * rows];
        // SAFETY: pixel + 1 < count, so both rows are inside `inputs` and `outputs` (checked
        // by the caller for the last row `count - 1`).
        unsafe {
            if tail == 0 {
                pixels::<T, 2, false>(linear, inputs, starts, outs, tail_mask, outputs);
            } else {
                pixels::<T, 2, true>(linear, inputs, starts, outs, tail_mask, outputs);
            }
        }
        pixel += 2;
    }
    if pixel < count {
        let (starts, outs) = ([pixel * stride], [pixel * rows]);
        // SAFETY: as above for the single row `pixel < count`.
        unsafe {
            if tail == 0 {
                pixels::<T, 1, false>(linear, inputs, starts, outs, tail_mask, outputs);
            } else {
                pixels::<T, 1, true>(linear, inputs, starts, outs, tail_mask, outputs);
            }
        }
    }
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
