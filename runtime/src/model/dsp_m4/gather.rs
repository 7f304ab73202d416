//! Conv patches gathered straight into the permuted order the loops read (`x0 x2 x1 x3` per
//! group of four).

use super::super::load::ConvLayer;

/// Puts every whole group of four of `row` in `SXTB16` order: `x0 x1 x2 x3` -> `x0 x2 x1 x3`.
#[inline]
pub fn permute(row: &mut [i16]) {
    for group in row.chunks_exact_mut(4) {
        group.swap(1, 2);
    }
}

/// Widens `src` minus `zero_point` into `out` in [`permute`]d order, 8 inputs per turn of an
/// assembly loop (`SXTB16` pairs bytes 0 and 2, and 1 and 3, which is that order; `SSUB16`
/// subtracts the zero point from both halves, exactly: the differences are within +-255),
/// the last whole groups of four in Rust. `src.len()` must be a multiple of 4 and `out` word-
/// aligned and as long; otherwise nothing is written and it returns `false`.
#[inline(always)]
fn widen_permuted(src: &[i8], zero_point: i8, out: &mut [i16]) -> bool {
    if src.len() % 4 != 0 || out.len() != src.len() || out.as_ptr() as usize % 4 != 0 {
        return false;
    }
    let eights = src.len() / 8 * 8;
    let (head, rest) = src.split_at(eights);
    let (out_head, out_rest) = out.split_at_mut(eights);
    let pair = u32::from(i16::from(zero_point) as u16) * 0x1_0001;
    if eights > 0 {
        // SAFETY: reads `eights` bytes of `head` (word loads, unaligned allowed on the M4 for
        // normal memory) and writes `eights` i16 of `out_head` (word-aligned: checked above,
        // and `eights` is even, for STRD), both exactly their lengths.
        unsafe {
            core::arch::asm!(
                "1:",
                "ldr {w0}, [{src}], #4",
                "ldr {w1}, [{src}], #4",
                "sxtb16 {a}, {w0}",
                "sxtb16 {b}, {w0}, ror #8",
                "ssub16 {a}, {a}, {zp}",
                "ssub16 {b}, {b}, {zp}",
                "strd {a}, {b}, [{dst}], #8",
                "sxtb16 {a}, {w1}",
                "sxtb16 {b}, {w1}, ror #8",
                "ssub16 {a}, {a}, {zp}",
                "ssub16 {b}, {b}, {zp}",
                "strd {a}, {b}, [{dst}], #8",
                "cmp {src}, {end}",
                "bne 1b",
                src = inout(reg) head.as_ptr() => _,
                dst = inout(reg) out_head.as_mut_ptr() => _,
                end = in(reg) head.as_ptr().wrapping_add(eights),
                zp = in(reg) pair,
                w0 = out(reg) _,
                w1 = out(reg) _,
                a = out(reg) _,
                b = out(reg) _,
                options(nostack),
            );
        }
    }
    let zero_point = i16::from(zero_point);
    for (x, y) in rest.chunks_exact(4).zip(out_rest.chunks_exact_mut(4)) {
        if let (&[x0, x1, x2, x3], [y0, y1, y2, y3]) = (x, y) {
            (*y0, *y1, *y2, *y3) = (
                i16::from(x0) - zero_point,
                i16::from(x2) - zero_point,
                i16::from(x1) - zero_point,
                i16::from(x3) - zero_point,
            );
        }
    }
    true
}

/// The patches of output pixels `first..` into `patches`, one every `stride` elements, as
/// `infer`'s gather writes them and then [`permute`]d, in one pass: for input channels in
/// multiples of 4 every run (and every padding run) is whole groups of four, so each is
/// widened straight into the permuted order ([`widen_permuted`]). Returns `false`, having
/// written nothing, for other layers, short buffers, or unaligned patches.
pub fn gather_permuted(
    conv: &ConvLayer<'_>,
    src: &[i8],
    first: usize,
    patches: &mut [i16],
    stride: usize,
) -> bool {
    let channels = conv.in_channels;
    let side = usize::from(conv.record.kernel);
    let step = usize::from(conv.record.stride);
    let padding = usize::from(conv.record.padding);
    let zero_point = conv.linear.input_zero_point;
    let run = side * channels;
    let cols = conv.out_cols.max(1);
    if channels % 4 != 0
        || stride % 2 != 0
        || stride < side * run
        || patches.as_ptr() as usize % 4 != 0
    {
        return false;
    }
    for (offset, patch) in patches.chunks_exact_mut(stride).enumerate() {
        let pixel = first + offset;
        let (y0, x0) = ((pixel / cols) * step, (pixel % cols) * step);
        // Kernel columns inside the map: ix = x0 + kx - padding in [0, in_cols).
        let first_col = padding.saturating_sub(x0).min(side);
        let last_col = (conv.in_cols + padding)
            .saturating_sub(x0)
            .clamp(first_col, side);
        for (ky, segment) in patch.chunks_exact_mut(run).take(side).enumerate() {
            let source = (y0 + ky)
                .checked_sub(padding)
                .filter(|&iy| iy < conv.in_rows)
                .and_then(|iy| {
                    let ix = (x0 + first_col).checked_sub(padding)?;
                    let start = (iy * conv.in_cols + ix) * channels;
                    src.get(start..start + (last_col - first_col) * channels)
                });
            let split = source.and_then(|pixels| {
                let (before, rest) = segment.split_at_mut_checked(first_col * channels)?;
                let (inside, after) = rest.split_at_mut_checked(pixels.len())?;
                Some((pixels, before, inside, after))
            });
            match split {
                Some((pixels, before, inside, after)) => {
                    if !before.is_empty() {
                        before.fill(0);
                    }
                    if !widen_permuted(pixels, zero_point, inside) {
                        inside.fill(0);
                    }
                    if !after.is_empty() {
                        after.fill(0);
                    }
                }
                None => segment.fill(0),
            }
        }
    }
    true
}

/// For a one-channel 3 x 3 conv (the first layer), its input (the first `in_rows * in_cols` of
/// `src`) copied again right after it with `padding` cells of the input zero point around (0
/// once the zero point is subtracted: what the padding stands for), and 4 more bytes for the
/// word loads of [`gather_3x3_padded`]; returns where the copy starts and its width. `None`
/// (nothing written) for other layers, or when `src` has no room for the copy.
pub(super) fn pad_input(conv: &ConvLayer<'_>, src: &mut [i8]) -> Option<(usize, usize)> {
    let padding = usize::from(conv.record.padding);
    let (rows, cols) = (conv.in_rows, conv.in_cols);
    if conv.in_channels != 1 || conv.record.kernel != 3 || cols == 0 {
        return None;
    }
    let width = cols + 2 * padding;
    let (input, rest) = src.split_at_mut_checked(rows * cols)?;
    let image = rest.get_mut(..width * (rows + 2 * padding) + 4)?;
    image.fill(conv.linear.input_zero_point);
    for (line, out) in input
        .chunks_exact(cols)
        .zip(image.chunks_exact_mut(width).skip(padding))
    {
        out.get_mut(padding..padding + cols)?.copy_from_slice(line);
    }
    Some((rows * cols, width))
}

/// The patches of output pixels `first..` of a one-channel 3 x 3 conv into `patches`, one
/// every `stride` elements, from its padded input `image` (`width` cells a row, [`pad_input`]),
/// straight into the [`permute`]d order `x0 x2 x1 x3 x4 x6 x5 x7 x8`: a word load per kernel
/// row, `SXTB16` of bytes 0 and 2 and of bytes 1 and 3 (or 3 and 1), the pairs the order needs
/// repacked by `PKHBT`/`PKHTB`, the zero point subtracted from both halves by `SSUB16`: 21
/// instructions a patch, none of them a branch. Returns `false`, having written nothing, for
/// unaligned or short patches or an image smaller than the layer's patches need.
pub(super) fn gather_3x3_padded(
    conv: &ConvLayer<'_>,
    image: &[i8],
    width: usize,
    first: usize,
    patches: &mut [i16],
    stride: usize,
) -> bool {
    let step = usize::from(conv.record.stride);
    let cols = conv.out_cols.max(1);
    let base = |pixel: usize| (pixel / cols) * step * width + (pixel % cols) * step;
    let pixels = patches.len() / stride.max(1);
    // Each patch's words end within its rows (`(cols - 1) * step + 3 <= width`), and no patch
    // starts after the last one, whose last word must be in the image.
    if pixels == 0
        || stride < 9
        || stride % 2 != 0
        || patches.as_ptr() as usize % 4 != 0
        || (cols - 1) * step + 3 > width
        || base(first + pixels - 1) + 2 * width + 4 > image.len()
    {
        return pixels == 0;
    }
    let zero_point = u32::from(i16::from(conv.linear.input_zero_point) as u16) * 0x1_0001;
    for (offset, patch) in patches.chunks_exact_mut(stride).enumerate() {
        // SAFETY: reads the three words at `base`, `base + width` and `base + 2 * width` of
        // `image` (checked above for the last patch; every other one starts before it; word
        // loads may be unaligned on the M4 for normal memory), and writes the first 9 i16 of
        // `patch` (`stride >= 9`; word-aligned for `STRD`: the slice's start and the even
        // stride).
        unsafe {
            core::arch::asm!(
                "ldr {a}, [{p}]",
                "ldr {b}, [{p}, {w}]",
                "ldr {c}, [{p}, {w}, lsl #1]",
                "sxtb16 {x}, {a}",
                "sxtb16 {a}, {a}, ror #8",
                "sxtb16 {t}, {b}",
                "sxtb16 {b}, {b}, ror #8",
                "pkhbt {a}, {a}, {t}, lsl #16",
                "ssub16 {x}, {x}, {zp}",
                "ssub16 {a}, {a}, {zp}",
                "strd {x}, {a}, [{out}]",
                "sxtb16 {x}, {c}",
                "pkhbt {a}, {b}, {x}, lsl #16",
                "sxtb16 {c}, {c}, ror #24",
                "pkhtb {b}, {c}, {t}, asr #16",
                "ssub16 {a}, {a}, {zp}",
                "ssub16 {b}, {b}, {zp}",
                "strd {a}, {b}, [{out}, #8]",
                "ssub16 {x}, {x}, {zp}",
                "lsr {x}, {x}, #16",
                "strh {x}, [{out}, #16]",
                p = in(reg) image.as_ptr().wrapping_add(base(first + offset)),
                w = in(reg) width,
                zp = in(reg) zero_point,
                out = in(reg) patch.as_mut_ptr(),
                a = out(reg) _,
                b = out(reg) _,
                c = out(reg) _,
                t = out(reg) _,
                x = out(reg) _,
                options(nostack, preserves_flags),
            );
        }
    }
    true
}
