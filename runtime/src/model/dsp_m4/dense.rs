//! A layer's rows on the DSP extension: input rows through the assembly loops
//! (`wheelleg_dsp_dot_2x2` finishing int8 rows itself, `wheelleg_dsp_dot_1x4` with its sums
//! finished here), Rust for tails, leftovers and inputs the loops cannot take.

use super::super::kernel::{le_i32, output_bounds, Output, OutputSlice};
use super::super::load::Linear;
use super::super::quant::{requantize_clamped, MAX_SHIFT, MIN_SHIFT};
use super::loops::{wheelleg_dsp_dot_1x4, wheelleg_dsp_dot_2x2};

/// The dot product of a [`super::gather::permute`]d input row and a weight row in natural order, in Rust:
/// for the tails and leftovers the loops do not cover, and as the fallback.
#[inline]
fn dot_permuted(input: &[i16], weights: &[u8]) -> i32 {
    let whole = input.len() / 4 * 4;
    let (groups, tail) = input.split_at(whole.min(input.len()));
    let (group_weights, tail_weights) = weights.split_at(whole.min(weights.len()));
    let mut sum = 0i32;
    for (x, w) in groups.chunks_exact(4).zip(group_weights.chunks_exact(4)) {
        if let (&[x0, x2, x1, x3], &[w0, w1, w2, w3]) = (x, w) {
            sum += i32::from(x0) * i32::from(w0 as i8)
                + i32::from(x1) * i32::from(w1 as i8)
                + i32::from(x2) * i32::from(w2 as i8)
                + i32::from(x3) * i32::from(w3 as i8);
        }
    }
    for (&x, &w) in tail.iter().zip(tail_weights) {
        sum += i32::from(x) * i32::from(w as i8);
    }
    sum
}

/// [`super::super::kernel::linear_batch`] on the DSP extension, for inputs whose rows were
/// [`super::gather::permute`]d: input row `p` is `inputs[p * stride..][..row_len]`, its outputs
/// `outputs[p * rows..][..rows]`. Pixels go in pairs through `wheelleg_dsp_dot_2x2`, a last odd one
/// and a batch of one through `wheelleg_dsp_dot_1x4`. Lengths that do not fit run what fits (no panic); an
/// input that is not word-aligned runs in Rust.
pub fn linear_batch_dsp<T: Output>(
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    outputs: &mut [T],
) {
    // One copy of the code for both output types (flash is scarce on a controller): the
    // type only decides the store.
    let bounds = bounds::<T>(linear);
    linear_batch_any(linear, inputs, stride, T::slice(outputs), bounds);
}

/// Stores `value` (already within the layer's bounds) at `index`.
#[inline(always)]
fn put(out: &mut OutputSlice<'_>, index: usize, value: i16) {
    match out {
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

/// Outputs in the slice.
fn len(out: &OutputSlice<'_>) -> usize {
    match out {
        OutputSlice::Int8(out) => out.len(),
        OutputSlice::Int16(out) => out.len(),
    }
}

/// [`linear_batch_dsp`] for either output type.
pub(super) fn linear_batch_any(
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    mut outputs: OutputSlice<'_>,
    bounds: (i32, i32, i32),
) {
    let outputs = &mut outputs;
    let rows = linear.rows;
    let row_len = linear.row_len;
    if rows == 0 || stride == 0 {
        return;
    }
    let pixels = len(outputs) / rows;
    // Every input row the loops read, and every weight row, must be in its slice.
    let inputs_fit = pixels == 0
        || (pixels - 1)
            .checked_mul(stride)
            .and_then(|start| start.checked_add(row_len))
            .is_some_and(|end| end <= inputs.len());
    let weights_fit = rows
        .checked_mul(row_len)
        .is_some_and(|len| len <= linear.weights.len());
    let aligned = inputs.as_ptr() as usize % 4 == 0 && stride % 2 == 0;
    if !(inputs_fit && weights_fit && linear.bias.len() >= 4 * rows) {
        return;
    }
    if !aligned {
        permuted_rust(linear, inputs, stride, outputs, pixels, bounds);
        return;
    }
    let groups = row_len / 4;
    let whole = 4 * groups;
    let in_asm = asm_finishes(linear, outputs, bounds);
    // Written by the loops before it is read; zero for rows too short for them. Where the
    // assembly finishes the rows it holds their table instead (`row_table`).
    let mut sums = [0i32; SUMS];
    if in_asm {
        row_table(linear, &mut sums);
    }
    let mut pixel = 0;
    if in_asm && finish_in_asm(linear, inputs, stride, outputs, (pixels / 2, &sums), bounds) {
        pixel = pixels / 2 * 2;
    }
    while pixel < pixels {
        let pair = pixel + 1 < pixels;
        let Some(a) = inputs.get(pixel * stride..) else {
            return;
        };
        let first = pixel * rows;
        if pair {
            pixel_pair(
                linear,
                a,
                stride,
                (groups, whole),
                outputs,
                first,
                &mut sums,
                bounds,
            );
        } else {
            single_pixel(
                linear,
                a,
                (groups, whole),
                outputs,
                first,
                &mut sums,
                bounds,
            );
        }
        pixel += 1 + usize::from(pair);
    }
}

/// The scalar kernel's requantization ([`super::super::quant::requantize_clamped`]) in 32-bit
/// steps where it can be. For a right shift `r` of 33 or more (every layer of a network whose
/// real multipliers are below 1/2), with `p` the 64-bit product and `h = p >> 32` its high
/// word (`SMMUL`): `(p + 2^(r-1)) >> r = ((p >> (r-1)) + 1) >> 1` (write `p >> (r-1)` as
/// `q` and the rest as `m < 2^(r-1)`: adding half of `2^r` and dividing rounds `q / 2` the
/// same way), and `p >> (r-1) = h >> (r-33)` (arithmetic shifts compose). The result is below
/// 2^30 in magnitude, so it and the zero point fit an i32. Other shifts take the 64-bit
/// formula itself.
#[inline(always)]
fn requantize(acc: i32, multiplier: i32, shift: i8, bounds: (i32, i32, i32)) -> i16 {
    let (zero_point, low, high) = bounds;
    let right = 31 - i32::from(shift.clamp(MIN_SHIFT, MAX_SHIFT));
    if right < 33 {
        return requantize_clamped(
            acc,
            multiplier,
            shift,
            zero_point as i8,
            low as i16,
            high as i16,
        );
    }
    let high_word = ((i64::from(acc) * i64::from(multiplier)) >> 32) as i32;
    let value = ((high_word >> (right - 33)) + 1) >> 1;
    (value + zero_point).min(high).max(low) as i16
}

/// A layer's zero point and output bounds for [`requantize`].
#[inline(always)]
pub(super) fn bounds<T: Output>(linear: &Linear<'_>) -> (i32, i32, i32) {
    let (low, high) = output_bounds::<T>(linear);
    (
        i32::from(linear.output_zero_point),
        i32::from(low),
        i32::from(high),
    )
}

/// Bias, multiplier and shift of each row, in lock-step.
#[inline(always)]
fn row_params<'a>(linear: &'a Linear<'_>) -> impl Iterator<Item = (i32, i32, i8)> + Clone + 'a {
    linear
        .bias
        .chunks_exact(4)
        .zip(linear.multipliers.chunks_exact(4))
        .zip(linear.shifts)
        .map(|((bias, multiplier), &shift)| (le_i32(bias), le_i32(multiplier), shift as i8))
}

/// Sums one call of an assembly loop writes at most: 64 rows of two pixels, 128 of one.
pub(super) const SUMS: usize = 128;

/// Whether a batch's pixel pairs can run whole in `wheelleg_dsp_dot_2x2`, requantization
/// included ([`finish_in_asm`]): int8 outputs with the high bound 127 (what `SSAT` clamps to),
/// an even number of rows whose [`row_table`] fits the sums' buffer (at most `SUMS / 3`), at
/// least one group of four, and every row's shift at most -2 (a right shift of 33 or more:
/// `requantize`'s 32-bit steps). Checked once per batch.
pub(super) fn asm_finishes(
    linear: &Linear<'_>,
    out: &OutputSlice<'_>,
    bounds: (i32, i32, i32),
) -> bool {
    let rows = linear.rows;
    let (_, low, high) = bounds;
    let shifts_fit = linear.shifts.get(..rows).is_some_and(|shifts| {
        shifts
            .iter()
            .all(|&s| (MIN_SHIFT..=-2).contains(&(s as i8)))
    });
    matches!(out, OutputSlice::Int8(_))
        && rows % 2 == 0
        && 3 * rows <= SUMS
        && linear.row_len >= 4
        && high == 127
        && (-128..=127).contains(&low)
        && shifts_fit
        && linear.bias.len() >= 4 * rows
        && linear.multipliers.len() >= 4 * rows
        && linear.weights.len() >= rows * linear.row_len
}

/// What `wheelleg_dsp_dot_2x2` reads per row to finish it, in `table` (3 words a row, for
/// `LDM`): the bias, the multiplier, and the right shift of `requantize`'s high word,
/// `right - 33 = -2 - shift` (at least 0: [`asm_finishes`]).
pub(super) fn row_table(linear: &Linear<'_>, table: &mut [i32; SUMS]) {
    for (entry, (bias, multiplier, shift)) in table.chunks_exact_mut(3).zip(row_params(linear)) {
        if let [b, m, s] = entry {
            (*b, *m, *s) = (bias, multiplier, -2 - i32::from(shift));
        }
    }
}

/// The first `2 * pairs` pixels of the batch (inputs from `a`, outputs from the slice's start)
/// whole in one call of `wheelleg_dsp_dot_2x2`, for a layer [`asm_finishes`] accepted, with
/// its [`row_table`] in `table`. Returns whether it ran (not when the inputs or outputs are
/// short: a caller bug).
pub(super) fn finish_in_asm(
    linear: &Linear<'_>,
    a: &[i16],
    stride: usize,
    out: &mut OutputSlice<'_>,
    (pairs, table): (usize, &[i32; SUMS]),
    bounds: (i32, i32, i32),
) -> bool {
    let (rows, row_len) = (linear.rows, linear.row_len);
    let groups = row_len / 4;
    let (zero_point, low, _) = bounds;
    let OutputSlice::Int8(out) = out else {
        return false;
    };
    let Some(outputs) = out.get_mut(..2 * pairs * rows) else {
        return false;
    };
    if pairs == 0 || a.len() < (2 * pairs - 1) * stride + row_len {
        return false;
    }
    let params = [
        (2 * stride) as u32,
        row_len as u32,
        groups as u32,
        (rows / 2) as u32,
        (row_len - 4 * groups) as u32,
        table.as_ptr() as u32,
        0,
        0,
        outputs.as_mut_ptr() as u32,
        rows as u32,
        // (t + 1) / 2 + zero point = (t + 1 + 2 zero point) / 2, floored: `SSAT`'s `ASR #1`.
        (2 * zero_point + 1) as u32,
        // Four copies, for the byte-wise maximum (`SSUB8`, `SEL`).
        u32::from(low as u8) * 0x0101_0101,
        pairs as u32,
    ];
    // SAFETY: as in `single_pixel` for the inputs (`a` holds the `2 * pairs` rows, the last
    // ending at `(2 * pairs - 1) * stride + row_len`, checked above; word-aligned:
    // `linear_batch_any` checked the input and the even stride) and the weights (`rows` rows
    // of `row_len`, `asm_finishes`), tail included (the `row_len - 4 * groups` elements after
    // the whole groups of each row); per row it reads 3 words of `table` (`3 * rows <= SUMS`:
    // `asm_finishes`); it writes `outputs[2 * k * rows + p * rows + r]` for pair `k <
    // pairs`, pixel `p < 2`, row `r < rows`, within `outputs` (`2 * pairs * rows` long); its
    // last argument is unused.
    unsafe {
        wheelleg_dsp_dot_2x2(
            a.as_ptr(),
            linear.weights.as_ptr(),
            params.as_ptr(),
            core::ptr::null_mut(),
        );
    }
    true
}

/// Two pixels: input rows `a[..row_len]` and `a[stride..][..row_len]`, outputs `out[..rows]`
/// and `out[rows..2 * rows]`, where `wheelleg_dsp_dot_2x2` cannot finish them
/// ([`asm_finishes`]): one pixel after the other (no layer of the shipped network takes that
/// path, so it shares [`single_pixel`]'s code rather than adding its own).
#[allow(clippy::too_many_arguments)]
fn pixel_pair(
    linear: &Linear<'_>,
    a: &[i16],
    stride: usize,
    (groups, whole): (usize, usize),
    out: &mut OutputSlice<'_>,
    first: usize,
    sums: &mut [i32; SUMS],
    bounds: (i32, i32, i32),
) {
    single_pixel(linear, a, (groups, whole), out, first, sums, bounds);
    if let Some(b) = a.get(stride..) {
        single_pixel(
            linear,
            b,
            (groups, whole),
            out,
            first + linear.rows,
            sums,
            bounds,
        );
    }
}

/// One pixel: input row `a[..row_len]`, outputs `out[..rows]`, four rows at a time.
fn single_pixel(
    linear: &Linear<'_>,
    a: &[i16],
    (groups, whole): (usize, usize),
    out: &mut OutputSlice<'_>,
    first: usize,
    sums: &mut [i32; SUMS],
    bounds: (i32, i32, i32),
) {
    let (rows, row_len) = (linear.rows, linear.row_len);
    let Some(input) = a.get(..row_len) else {
        return;
    };
    let tail_x = input.get(whole..).unwrap_or(&[]);
    let quads = rows / 4 * 4;
    let has_tail = whole < row_len;
    let mut weight_rows = linear.weights.chunks_exact(row_len);
    let mut requant = row_params(linear);
    let mut outputs = first..first + rows;
    let mut done = 0;
    while done < quads {
        let chunk = (quads - done).min(SUMS);
        let Some(weights) = linear.weights.get(done * row_len..(done + chunk) * row_len) else {
            return;
        };
        if groups > 0 {
            let params = [row_len as u32, groups as u32, (chunk / 4) as u32];
            // SAFETY: for each of `chunk / 4` row quads the loop reads `whole` (<= `row_len`)
            // inputs of `input` (word-aligned, as in `pixel_pair`) and `whole` weights of each
            // of the quad's rows, all within `weights` (`chunk` rows of `row_len`); it writes
            // `chunk <= SUMS` sums.
            unsafe {
                wheelleg_dsp_dot_1x4(
                    input.as_ptr(),
                    weights.as_ptr(),
                    params.as_ptr(),
                    sums.as_mut_ptr(),
                );
            }
        }
        for (&sum, ((w, p), y)) in sums.iter().take(chunk).zip(
            weight_rows
                .by_ref()
                .zip(requant.by_ref())
                .zip(outputs.by_ref()),
        ) {
            let mut acc = sum + p.0;
            if has_tail {
                acc += tail_dot(tail_x, w.get(whole..).unwrap_or(&[]));
            }
            put(out, y, requantize(acc, p.1, p.2, bounds));
        }
        done += chunk;
    }
    // The rows after the last whole quad.
    for ((w, p), y) in weight_rows.zip(requant).zip(outputs) {
        put(
            out,
            y,
            requantize(dot_permuted(input, w) + p.0, p.1, p.2, bounds),
        );
    }
}

/// The dot product of the elements after the loops' whole groups (in natural order).
#[inline(always)]
fn tail_dot(input: &[i16], weights: &[u8]) -> i32 {
    input
        .iter()
        .zip(weights)
        .map(|(&x, &w)| i32::from(x) * i32::from(w as i8))
        .sum()
}

/// The whole batch in Rust, for inputs the loops cannot take.
fn permuted_rust(
    linear: &Linear<'_>,
    inputs: &[i16],
    stride: usize,
    out: &mut OutputSlice<'_>,
    pixels: usize,
    bounds: (i32, i32, i32),
) {
    let (rows, row_len) = (linear.rows, linear.row_len);
    for pixel in 0..pixels {
        let Some(input) = inputs.get(pixel * stride..pixel * stride + row_len) else {
            return;
        };
        for (r, (w, p)) in linear
            .weights
            .chunks_exact(row_len)
            .zip(row_params(linear))
            .enumerate()
        {
            put(
                out,
                pixel * rows + r,
                requantize(dot_permuted(input, w) + p.0, p.1, p.2, bounds),
            );
        }
    }
}
