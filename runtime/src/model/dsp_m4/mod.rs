//! The kernel on the Cortex-M4's DSP extension (Armv7E-M): `SMLAD` multiplies two pairs of
//! 16-bit values and adds both products to an accumulator, and `SXTB16` sign-extends bytes 0
//! and 2 of a word (or, rotated by 8 bits, bytes 1 and 3) into such a pair. So four int8
//! weights loaded as one word become two pairs in two instructions, and meet four int16 inputs
//! in two more: four multiply-accumulates in four instructions, plus the loads.
//!
//! `SXTB16` pairs weights 0 with 2 and 1 with 3, so the inputs must come in that order: every
//! whole group of four inputs `x0 x1 x2 x3` is stored as `x0 x2 x1 x3`. Conv patches are
//! gathered straight into it ([`gather_permuted`]: `SXTB16` widens input bytes 0 and 2, then
//! 1 and 3, which is that order, and `SSUB16` subtracts the zero point from both halves; the
//! first layer's one-channel 3 x 3 patches by [`gather_3x3_padded`] from a copy of the map
//! padded with its zero point, so that border patches take the same 21 instructions);
//! other rows are [`permute`]d once after they are written. Elements after the last whole
//! group stay in order.
//!
//! Two inner loops, hand-scheduled in assembly (`global_asm!`, AAPCS functions) so that the
//! accumulators, inputs and weights stay in registers:
//! - `wheelleg_dsp_dot_2x2`: two input rows (two conv pixels) by two weight rows: each input
//!   pair loaded serves two rows and each weight pair two pixels, 16 MACs in 16 instructions,
//!   four groups of four per loop turn; it also requantizes each row pair into int8 outputs
//!   (`SMMUL`, `SSAT`, `SEL`: 32 instructions per 4 outputs), so conv layers never leave
//!   assembly;
//! - `wheelleg_dsp_dot_1x4`: one input row by four weight rows (the dense layers), 16 MACs in
//!   21, two groups per turn, its sums finished in Rust (`dense::requantize`).
//!
//! Integer sums are exact in any order (the loader bounds every partial sum within an i32),
//! and requantization is the scalar kernel's formula ([`super::kernel::finish`]) in 32-bit
//! steps that give the same integers, so the results are the scalar kernel's bit for bit;
//! `runtime/tests` cannot run this on the host, so scripts/mcu.sh checks it in QEMU against
//! the scalar kernel on every decision and against the host's decisions.
//!
//! Cycle estimate (Cortex-M4 Technical Reference Manual, instruction timings): `SMLAD`,
//! `SXTB16`, `SSUB16`, `SSUB8`, `SEL`, `SMMUL`, `SSAT`, `BFI`, `MLA` and other ALU operations 1 cycle each, `LDR`
//! 2 cycles (1 when pipelined with the next load or store), `LDRD` and `STRD` 3, `LDM` of 3
//! registers 4, `STR`/`STRB` 1, a taken branch 2 to 4 (1 + pipeline refill):
//! - `dot_2x2`'s turn of 64 MACs: 8 `LDRD` (24) + 8 `LDR` (16) + 16 `SXTB16` (16) + 32
//!   `SMLAD` (32) + `LDR`, `CMP`, `BNE` (2 + 1 + 3) = 94 cycles, 1.47 cycles per MAC (67
//!   instructions);
//! - its requantization of a row pair (4 outputs): 2 `LDM` (8) + `LDRD` (3) + 3 `LDR` (6) + 2 `STR`
//!   and 2 `STRH` (4) + 22 ALU (22: `SMMUL`, shift, zero point, `SSAT`, `BFI`, the ReLU's
//!   `SSUB8`/`SEL`) = 43 cycles, 10.75 per output (the bias is where the sums start); a tail element (the first conv's 9th
//!   input) 4 loads (5), 4 `MLA` (4), `SUBS`, `BNE` (4) = 13 cycles;
//! - `gather::widen_permuted`'s turn of 8 inputs: 2 `LDR` (3) + 4 `SXTB16` + 4 `SSUB16` (8) + 2
//!   `STRD` (6) + `CMP`, `BNE` (4) = 21 cycles, 2.6 per input;
//! - [`gather_3x3_padded`]'s patch of 9 inputs: 3 `LDR` (4) + 6 `SXTB16`, 3 `PKHBT`/`PKHTB`,
//!   5 `SSUB16`, `LSR` (15) + 2 `STRD` (6) + `STRH` (1) = 26 cycles, 2.9 per input;
//! - `dot_1x4`'s turn of 32 MACs: 2 `LDRD` (6) + 8 `LDR` (16) + 16 `SXTB16` (16) + 16
//!   `SMLAD` (16) + `CMP`, `BNE` (4) = 58, 1.81 per MAC.
//!
//! On a part with flash wait states (170 MHz: 4 on an STM32G4) the weights' loads may cost
//! more unless they hit the flash accelerator's prefetch and cache, which sequential loads do.
//!
//! The pieces: [`loops`] holds the two assembly loops, [`gather`] writes conv patches in the
//! permuted order, [`dense`] runs a layer's rows through the loops and finishes them; a conv
//! layer here is the two together ([`conv_dsp`]).

#![allow(unsafe_code)]

mod dense;
mod gather;
mod loops;

use super::format::InputQuantRecord;
use super::kernel::OutputSlice;
use super::load::ConvLayer;
use super::quant::{MAX_SHIFT, MIN_SHIFT};
pub use dense::linear_batch_dsp;
use dense::{asm_finishes, bounds, finish_in_asm, linear_batch_any, row_table, SUMS};
pub use gather::permute;
use gather::{gather_3x3_padded, gather_permuted, pad_input};

/// A conv layer on the DSP extension: the output pixels in batches of `batch` (`stride` apart
/// in `row`), each gathered by [`gather_permuted`] (a one-channel 3 x 3 layer by
/// [`gather_3x3_padded`] from the copy [`pad_input`] writes after its input in `src`) and run
/// by [`finish_in_asm`], with the checks of [`asm_finishes`] and the [`row_table`] done once
/// for the layer rather than once per batch. A batch the assembly cannot finish (an odd count)
/// runs as [`linear_batch_dsp`] runs it. Returns the pixels done, all but for a layer neither
/// gather takes (then 0: the caller runs the rest with the portable gather).
pub fn conv_dsp(
    conv: &ConvLayer<'_>,
    src: &mut [i8],
    outputs: &mut [i8],
    row: &mut [i16],
    stride: usize,
    batch: usize,
) -> usize {
    let linear = &conv.linear;
    let rows = linear.rows;
    if rows == 0 || batch == 0 {
        return 0;
    }
    let bounds = bounds::<i8>(linear);
    let in_asm = asm_finishes(linear, &OutputSlice::Int8(&mut []), bounds);
    let mut table = [0i32; SUMS];
    if in_asm {
        row_table(linear, &mut table);
    }
    let padded = pad_input(conv, src);
    let src = &*src;
    let mut first = 0;
    for out in outputs.chunks_mut(batch * rows) {
        let count = out.len() / rows;
        let Some(patches) = row.get_mut(..count * stride) else {
            break;
        };
        let gathered = match padded {
            Some((start, width)) => src
                .get(start..)
                .is_some_and(|image| gather_3x3_padded(conv, image, width, first, patches, stride)),
            None => gather_permuted(conv, src, first, patches, stride),
        };
        if !gathered {
            break;
        }
        let mut slice = OutputSlice::Int8(out);
        if !(in_asm
            && count % 2 == 0
            && patches.as_ptr() as usize % 4 == 0
            && stride % 2 == 0
            && finish_in_asm(
                linear,
                patches,
                stride,
                &mut slice,
                (count / 2, &table),
                bounds,
            ))
        {
            linear_batch_any(linear, patches, stride, slice, bounds);
        }
        first += count;
    }
    first
}

/// [`super::kernel::quantize_inputs_scalar`] in 32-bit steps where the input's shift allows:
/// for a right shift of 33 or more as in `dense::requantize`; for a right shift `r` of 17 to 32 the
/// rounded high word (`SMMULR`) of the product with the input moved up by `32 - r` bits:
/// `(x * m + 2^(r-1)) >> r = (x * 2^(32-r) * m + 2^31) >> 32` (both sides scaled by
/// `2^(32-r)`), where `x * 2^(32-r)` fits an i32 for an int16 input; the scalar kernel's
/// otherwise.
pub fn quantize_inputs_dsp(quant: &InputQuantRecord, values_mm: &[i16], out: &mut [i8]) {
    let right = 31 - i32::from(quant.shift.clamp(MIN_SHIFT, MAX_SHIFT));
    let multiplier = i64::from(quant.multiplier);
    let zero_point = i32::from(quant.zero_point);
    let pairs = out.iter_mut().zip(values_mm);
    if right >= 33 {
        let shift = right - 33;
        for (q, &mm) in pairs {
            let high_word = ((i64::from(mm) * multiplier) >> 32) as i32;
            *q = ((((high_word >> shift) + 1) >> 1) + zero_point).clamp(-128, 127) as i8;
        }
    } else if right >= 17 {
        let up = 32 - right;
        for (q, &mm) in pairs {
            let value = ((i64::from(i32::from(mm) << up) * multiplier + (1 << 31)) >> 32) as i32;
            *q = (value + zero_point).clamp(-128, 127) as i8;
        }
    } else {
        super::kernel::quantize_inputs_scalar(quant, values_mm, out);
    }
}
