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
//!   21, two groups per turn, its sums finished in Rust ([`requantize`]).
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
//! - [`widen_permuted`]'s turn of 8 inputs: 2 `LDR` (3) + 4 `SXTB16` + 4 `SSUB16` (8) + 2
//!   `STRD` (6) + `CMP`, `BNE` (4) = 21 cycles, 2.6 per input;
//! - [`gather_3x3_padded`]'s patch of 9 inputs: 3 `LDR` (4) + 6 `SXTB16`, 3 `PKHBT`/`PKHTB`,
//!   5 `SSUB16`, `LSR` (15) + 2 `STRD` (6) + `STRH` (1) = 26 cycles, 2.9 per input;
//! - `dot_1x4`'s turn of 32 MACs: 2 `LDRD` (6) + 8 `LDR` (16) + 16 `SXTB16` (16) + 16
//!   `SMLAD` (16) + `CMP`, `BNE` (4) = 58, 1.81 per MAC.
//!
//! On a part with flash wait states (170 MHz: 4 on an STM32G4) the weights' loads may cost
//! more unless they hit the flash accelerator's prefetch and cache, which sequential loads do.
#![allow(unsafe_code)]

use super::format::InputQuantRecord;
use super::kernel::{le_i32, output_bounds, Output, OutputSlice};
use super::load::{ConvLayer, Linear};
use super::quant::{requantize_clamped, MAX_SHIFT, MIN_SHIFT};

// The 2 x 2 loop over row pairs, requantization included: `r0` input row a (input row b is
// `stride` bytes further), `r1` the first weight row, `r2` parameters [stride in bytes,
// weight row length in bytes, groups of four per row, row pairs, tail, row table, -, -,
// outputs, rows, 2 * zero point + 1, low bound in each byte, pixel pairs]; `r3` is unused.
// Pixel pair `k` reads input rows `2k` and `2k + 1` (`2 * k * stride` bytes on) and writes
// its outputs `2 * k * rows` bytes on. Input rows must be
// word-aligned (LDRD).
//
// It finishes each row pair as `requantize` does for a right shift of 33 or more (the caller
// checked every row's shift for it) into int8 outputs with the high bound 127: the `tail`
// (0 to 3) elements after the whole groups, in natural order, by `MLA`; then from the row
// table (`row_table`: bias, multiplier, shift per row, one `LDM` a row; the accumulators
// start from the bias) `SMMUL`
// (the high word of the 64-bit product), the arithmetic shift by `-2 - shift`; then
// `(t + 1) / 2 + zero point` as `(t + 1 + 2 * zero point) / 2` (exact: the added term is
// even, and `|t|` is below 2^30) by `ADD` and `SSAT`'s `ASR #1`, which also clamps to int8;
// last the four bytes packed into a word (`BFI`) and the low bound (ReLU) as their byte-wise
// maximum with it (`SSUB8` sets a lane's flag where the output is not below it, `SEL` keeps
// those). Pixel a's outputs (rows A, B) go to `outputs[row..]` and pixel b's `rows` bytes on,
// each pair by one `STRH`. Per row pair after the sums: 32 instructions for 4 outputs. The
// leftover groups after the unrolled turns (bits 1 and 0 of the group count) branch on one
// `LSLS`'s carry and sign (the blocks between set no flags).
//
// Stack frame: [sp] the outputs' address, [sp, #4] input a's end of the unrolled turns,
// [sp, #8] groups, [sp, #16] row pairs left, [sp, #20] from one row
// pair's weights (after the loop and the tail) to the next, [sp, #24] stride, [sp, #28]
// tail, [sp, #32] the row table, [sp, #36] input row a and [sp, #40] input row b (one `LDRD`),
// [sp, #44] rows, [sp, #48] 2 * zero point + 1, [sp, #52]
// the low bound in each byte, [sp, #56] row pairs, [sp, #60] pixel pairs left, [sp, #64]
// the first weight row, [sp, #68] the row table.
core::arch::global_asm!(
    ".syntax unified",
    ".thumb",
    ".section .text.wheelleg_dsp_dot_2x2,\"ax\",%progbits",
    ".global wheelleg_dsp_dot_2x2",
    ".type wheelleg_dsp_dot_2x2,%function",
    ".thumb_func",
    "wheelleg_dsp_dot_2x2:",
    "push {{r4-r11, lr}}",
    "sub sp, sp, #72",
    "str r0, [sp, #36]",
    "ldr r12, [r2, #8]",
    "str r12, [sp, #8]",
    "lsrs r4, r12, #2",
    "add r4, r0, r4, lsl #5",
    "str r4, [sp, #4]",
    "ldr r4, [r2, #12]",
    "str r4, [sp, #16]",
    "ldr r4, [r2, #16]",
    "str r4, [sp, #28]",
    "ldr r3, [r2, #4]",
    "lsls r5, r3, #1",
    "sub r5, r5, r12, lsl #2",
    "sub r5, r5, r4",
    "str r5, [sp, #20]",
    "ldr r4, [r2]",
    "str r4, [sp, #24]",
    "add r4, r4, r0",
    "str r4, [sp, #40]",
    "ldr r4, [r2, #36]",
    "str r4, [sp, #44]",
    "ldr r4, [r2, #40]",
    "str r4, [sp, #48]",
    "ldr r4, [r2, #44]",
    "str r4, [sp, #52]",
    "ldr r4, [r2, #20]",
    "str r4, [sp, #32]",
    "str r4, [sp, #68]",
    "ldr r4, [r2, #32]",
    "str r4, [sp]",
    "ldr r4, [r2, #48]",
    "str r4, [sp, #60]",
    "str r1, [sp, #64]",
    "ldr r4, [r2, #12]",
    "str r4, [sp, #56]",
    "ldr r4, [sp, #60]",
    "cmp r4, #0",
    "beq 9f",
    "ldr r4, [sp, #16]",
    "cmp r4, #0",
    "beq 9f",
    "5:",
    "ldrd r0, r2, [sp, #36]",
    "ldr r12, [sp, #32]",
    "ldr r4, [r12]",
    "ldr r6, [r12, #12]",
    "mov r5, r4",
    "mov r7, r6",
    "ldr lr, [sp, #4]",
    "cmp r0, lr",
    "beq 2f",
    "1:",
    "ldrd r8, r9, [r0], #8",
    "ldrd r10, r11, [r2], #8",
    "ldr r12, [r1, r3]",
    "sxtb16 lr, r12",
    "smlad r6, lr, r8, r6",
    "smlad r7, lr, r10, r7",
    "sxtb16 lr, r12, ror #8",
    "smlad r6, lr, r9, r6",
    "smlad r7, lr, r11, r7",
    "ldr r12, [r1], #4",
    "sxtb16 lr, r12",
    "smlad r4, lr, r8, r4",
    "smlad r5, lr, r10, r5",
    "sxtb16 lr, r12, ror #8",
    "smlad r4, lr, r9, r4",
    "smlad r5, lr, r11, r5",
    "ldrd r8, r9, [r0], #8",
    "ldrd r10, r11, [r2], #8",
    "ldr r12, [r1, r3]",
    "sxtb16 lr, r12",
    "smlad r6, lr, r8, r6",
    "smlad r7, lr, r10, r7",
    "sxtb16 lr, r12, ror #8",
    "smlad r6, lr, r9, r6",
    "smlad r7, lr, r11, r7",
    "ldr r12, [r1], #4",
    "sxtb16 lr, r12",
    "smlad r4, lr, r8, r4",
    "smlad r5, lr, r10, r5",
    "sxtb16 lr, r12, ror #8",
    "smlad r4, lr, r9, r4",
    "smlad r5, lr, r11, r5",
    "ldrd r8, r9, [r0], #8",
    "ldrd r10, r11, [r2], #8",
    "ldr r12, [r1, r3]",
    "sxtb16 lr, r12",
    "smlad r6, lr, r8, r6",
    "smlad r7, lr, r10, r7",
    "sxtb16 lr, r12, ror #8",
    "smlad r6, lr, r9, r6",
    "smlad r7, lr, r11, r7",
    "ldr r12, [r1], #4",
    "sxtb16 lr, r12",
    "smlad r4, lr, r8, r4",
    "smlad r5, lr, r10, r5",
    "sxtb16 lr, r12, ror #8",
    "smlad r4, lr, r9, r4",
    "smlad r5, lr, r11, r5",
    "ldrd r8, r9, [r0], #8",
    "ldrd r10, r11, [r2], #8",
    "ldr r12, [r1, r3]",
    "sxtb16 lr, r12",
    "smlad r6, lr, r8, r6",
    "smlad r7, lr, r10, r7",
    "sxtb16 lr, r12, ror #8",
    "smlad r6, lr, r9, r6",
    "smlad r7, lr, r11, r7",
    "ldr r12, [r1], #4",
    "sxtb16 lr, r12",
    "smlad r4, lr, r8, r4",
    "smlad r5, lr, r10, r5",
    "sxtb16 lr, r12, ror #8",
    "smlad r4, lr, r9, r4",
    "smlad r5, lr, r11, r5",
    "ldr lr, [sp, #4]",
    "cmp r0, lr",
    "bne 1b",
    "2:",
    "ldr r12, [sp, #8]",
    "lsls r12, r12, #31",
    "bcc 6f",
    "ldrd r8, r9, [r0], #8",
    "ldrd r10, r11, [r2], #8",
    "ldr r12, [r1, r3]",
    "sxtb16 lr, r12",
    "smlad r6, lr, r8, r6",
    "smlad r7, lr, r10, r7",
    "sxtb16 lr, r12, ror #8",
    "smlad r6, lr, r9, r6",
    "smlad r7, lr, r11, r7",
    "ldr r12, [r1], #4",
    "sxtb16 lr, r12",
    "smlad r4, lr, r8, r4",
    "smlad r5, lr, r10, r5",
    "sxtb16 lr, r12, ror #8",
    "smlad r4, lr, r9, r4",
    "smlad r5, lr, r11, r5",
    "ldrd r8, r9, [r0], #8",
    "ldrd r10, r11, [r2], #8",
    "ldr r12, [r1, r3]",
    "sxtb16 lr, r12",
    "smlad r6, lr, r8, r6",
    "smlad r7, lr, r10, r7",
    "sxtb16 lr, r12, ror #8",
    "smlad r6, lr, r9, r6",
    "smlad r7, lr, r11, r7",
    "ldr r12, [r1], #4",
    "sxtb16 lr, r12",
    "smlad r4, lr, r8, r4",
    "smlad r5, lr, r10, r5",
    "sxtb16 lr, r12, ror #8",
    "smlad r4, lr, r9, r4",
    "smlad r5, lr, r11, r5",
    "6:",
    "bpl 3f",
    "ldrd r8, r9, [r0], #8",
    "ldrd r10, r11, [r2], #8",
    "ldr r12, [r1, r3]",
    "sxtb16 lr, r12",
    "smlad r6, lr, r8, r6",
    "smlad r7, lr, r10, r7",
    "sxtb16 lr, r12, ror #8",
    "smlad r6, lr, r9, r6",
    "smlad r7, lr, r11, r7",
    "ldr r12, [r1], #4",
    "sxtb16 lr, r12",
    "smlad r4, lr, r8, r4",
    "smlad r5, lr, r10, r5",
    "sxtb16 lr, r12, ror #8",
    "smlad r4, lr, r9, r4",
    "smlad r5, lr, r11, r5",
    "3:",
    "ldr r12, [sp, #28]",
    "cmp r12, #0",
    "beq 4f",
    "7:",
    "ldrsb r9, [r1, r3]",
    "ldrsb r8, [r1], #1",
    "ldrsh r10, [r0], #2",
    "ldrsh r11, [r2], #2",
    "mla r4, r8, r10, r4",
    "mla r5, r8, r11, r5",
    "mla r6, r9, r10, r6",
    "mla r7, r9, r11, r7",
    "subs r12, r12, #1",
    "bne 7b",
    "4:",
    "ldr r12, [sp, #32]",
    "ldm r12!, {{r8, r9, r10}}",
    "smmul r4, r4, r9",
    "smmul r5, r5, r9",
    "asr r4, r4, r10",
    "asr r5, r5, r10",
    "ldm r12!, {{r8, r9, r10}}",
    "str r12, [sp, #32]",
    "smmul r6, r6, r9",
    "smmul r7, r7, r9",
    "asr r6, r6, r10",
    "asr r7, r7, r10",
    "ldrd r10, r11, [sp, #48]",
    "add r4, r4, r10",
    "add r5, r5, r10",
    "add r6, r6, r10",
    "add r7, r7, r10",
    "ssat r4, #8, r4, asr #1",
    "ssat r5, #8, r5, asr #1",
    "ssat r6, #8, r6, asr #1",
    "ssat r7, #8, r7, asr #1",
    "bfi r4, r6, #8, #8",
    "bfi r4, r5, #16, #8",
    "bfi r4, r7, #24, #8",
    "ssub8 r8, r4, r11",
    "sel r4, r4, r11",
    "ldr r12, [sp]",
    "ldr r10, [sp, #44]",
    "lsr r8, r4, #16",
    "strh r8, [r12, r10]",
    "strh r4, [r12], #2",
    "str r12, [sp]",
    "ldrd r12, lr, [sp, #16]",
    "add r1, r1, lr",
    "subs r12, r12, #1",
    "str r12, [sp, #16]",
    "bne 5b",
    "ldr r12, [sp, #60]",
    "subs r12, r12, #1",
    "beq 9f",
    "str r12, [sp, #60]",
    "ldr r12, [sp, #56]",
    "str r12, [sp, #16]",
    "ldr r1, [sp, #64]",
    "ldr r12, [sp, #68]",
    "str r12, [sp, #32]",
    "ldr r12, [sp, #24]",
    "ldrd r10, r11, [sp, #36]",
    "add r10, r10, r12, lsl #1",
    "add r11, r11, r12, lsl #1",
    "strd r10, r11, [sp, #36]",
    "ldr r10, [sp, #4]",
    "add r10, r10, r12, lsl #1",
    "str r10, [sp, #4]",
    "ldr r12, [sp]",
    "ldr r10, [sp, #44]",
    "add r12, r12, r10",
    "str r12, [sp]",
    "b 5b",
    "9:",
    "add sp, sp, #72",
    "pop {{r4-r11, pc}}",
    ".size wheelleg_dsp_dot_2x2, . - wheelleg_dsp_dot_2x2",
);

// The 1 x 4 loop over row quads: `r0` the input row, `r1` the first weight row, `r2`
// parameters [weight row length in bytes, groups of four per row, row quads], `r3` where to
// store the sums, 4 per quad. The input row must be word-aligned (LDRD). Registers: r1 and r2
// weight rows 0 and 2 (rows 1 and 3 one row length further, r3), r10 the input's end of the
// unrolled turns, r11 groups. Stack frame: [sp] the sums' address, [sp, #4] the input row,
// [sp, #8] quads left, [sp, #12] from one quad's weights (after the loop) to the next.
core::arch::global_asm!(
    ".syntax unified",
    ".thumb",
    ".section .text.wheelleg_dsp_dot_1x4,\"ax\",%progbits",
    ".global wheelleg_dsp_dot_1x4",
    ".type wheelleg_dsp_dot_1x4,%function",
    ".thumb_func",
    "wheelleg_dsp_dot_1x4:",
    "push {{r4-r11, lr}}",
    "sub sp, sp, #16",
    "str r3, [sp]",
    "str r0, [sp, #4]",
    "ldr r11, [r2, #4]",
    "ldr r4, [r2, #8]",
    "str r4, [sp, #8]",
    "ldr r3, [r2]",
    "lsls r4, r3, #2",
    "sub r4, r4, r11, lsl #2",
    "str r4, [sp, #12]",
    "lsrs r10, r11, #1",
    "add r10, r0, r10, lsl #4",
    "ldr r4, [sp, #8]",
    "cmp r4, #0",
    "beq 9f",
    "5:",
    "ldr r0, [sp, #4]",
    "add r2, r1, r3, lsl #1",
    "movs r4, #0",
    "movs r5, #0",
    "movs r6, #0",
    "movs r7, #0",
    "cmp r0, r10",
    "beq 2f",
    "1:",
    "ldrd r8, r9, [r0], #8",
    "ldr r12, [r1, r3]",
    "sxtb16 lr, r12",
    "smlad r5, lr, r8, r5",
    "sxtb16 lr, r12, ror #8",
    "smlad r5, lr, r9, r5",
    "ldr r12, [r1], #4",
    "sxtb16 lr, r12",
    "smlad r4, lr, r8, r4",
    "sxtb16 lr, r12, ror #8",
    "smlad r4, lr, r9, r4",
    "ldr r12, [r2, r3]",
    "sxtb16 lr, r12",
    "smlad r7, lr, r8, r7",
    "sxtb16 lr, r12, ror #8",
    "smlad r7, lr, r9, r7",
    "ldr r12, [r2], #4",
    "sxtb16 lr, r12",
    "smlad r6, lr, r8, r6",
    "sxtb16 lr, r12, ror #8",
    "smlad r6, lr, r9, r6",
    "ldrd r8, r9, [r0], #8",
    "ldr r12, [r1, r3]",
    "sxtb16 lr, r12",
    "smlad r5, lr, r8, r5",
    "sxtb16 lr, r12, ror #8",
    "smlad r5, lr, r9, r5",
    "ldr r12, [r1], #4",
    "sxtb16 lr, r12",
    "smlad r4, lr, r8, r4",
    "sxtb16 lr, r12, ror #8",
    "smlad r4, lr, r9, r4",
    "ldr r12, [r2, r3]",
    "sxtb16 lr, r12",
    "smlad r7, lr, r8, r7",
    "sxtb16 lr, r12, ror #8",
    "smlad r7, lr, r9, r7",
    "ldr r12, [r2], #4",
    "sxtb16 lr, r12",
    "smlad r6, lr, r8, r6",
    "sxtb16 lr, r12, ror #8",
    "smlad r6, lr, r9, r6",
    "cmp r0, r10",
    "bne 1b",
    "2:",
    "tst r11, #1",
    "beq 3f",
    "ldrd r8, r9, [r0], #8",
    "ldr r12, [r1, r3]",
    "sxtb16 lr, r12",
    "smlad r5, lr, r8, r5",
    "sxtb16 lr, r12, ror #8",
    "smlad r5, lr, r9, r5",
    "ldr r12, [r1], #4",
    "sxtb16 lr, r12",
    "smlad r4, lr, r8, r4",
    "sxtb16 lr, r12, ror #8",
    "smlad r4, lr, r9, r4",
    "ldr r12, [r2, r3]",
    "sxtb16 lr, r12",
    "smlad r7, lr, r8, r7",
    "sxtb16 lr, r12, ror #8",
    "smlad r7, lr, r9, r7",
    "ldr r12, [r2], #4",
    "sxtb16 lr, r12",
    "smlad r6, lr, r8, r6",
    "sxtb16 lr, r12, ror #8",
    "smlad r6, lr, r9, r6",
    "3:",
    "ldr r12, [sp]",
    "stm r12!, {{r4-r7}}",
    "str r12, [sp]",
    "ldr r12, [sp, #12]",
    "add r1, r1, r12",
    "ldr r12, [sp, #8]",
    "subs r12, r12, #1",
    "str r12, [sp, #8]",
    "bne 5b",
    "9:",
    "add sp, sp, #16",
    "pop {{r4-r11, pc}}",
    ".size wheelleg_dsp_dot_1x4, . - wheelleg_dsp_dot_1x4",
);

extern "C" {
    fn wheelleg_dsp_dot_2x2(a: *const i16, weights: *const u8, params: *const u32, sums: *mut i32);
    fn wheelleg_dsp_dot_1x4(x: *const i16, weights: *const u8, params: *const u32, sums: *mut i32);
}

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
/// for a right shift of 33 or more as in [`requantize`]; for a right shift `r` of 17 to 32 the
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

/// The dot product of a [`permute`]d input row and a weight row in natural order, in Rust:
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

/// [`super::kernel::linear_batch`] on the DSP extension, for inputs whose rows were
/// [`permute`]d: input row `p` is `inputs[p * stride..][..row_len]`, its outputs
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
fn linear_batch_any(
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

/// The scalar kernel's requantization ([`super::quant::requantize_clamped`]) in 32-bit
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
fn bounds<T: Output>(linear: &Linear<'_>) -> (i32, i32, i32) {
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
const SUMS: usize = 128;

/// Whether a batch's pixel pairs can run whole in `wheelleg_dsp_dot_2x2`, requantization
/// included ([`finish_in_asm`]): int8 outputs with the high bound 127 (what `SSAT` clamps to),
/// an even number of rows whose [`row_table`] fits the sums' buffer (at most `SUMS / 3`), at
/// least one group of four, and every row's shift at most -2 (a right shift of 33 or more:
/// `requantize`'s 32-bit steps). Checked once per batch.
fn asm_finishes(linear: &Linear<'_>, out: &OutputSlice<'_>, bounds: (i32, i32, i32)) -> bool {
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
fn row_table(linear: &Linear<'_>, table: &mut [i32; SUMS]) {
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
fn finish_in_asm(
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

/// For a one-channel 3 x 3 conv (the first layer), its input (the first `in_rows * in_cols` of
/// `src`) copied again right after it with `padding` cells of the input zero point around (0
/// once the zero point is subtracted: what the padding stands for), and 4 more bytes for the
/// word loads of [`gather_3x3_padded`]; returns where the copy starts and its width. `None`
/// (nothing written) for other layers, or when `src` has no room for the copy.
fn pad_input(conv: &ConvLayer<'_>, src: &mut [i8]) -> Option<(usize, usize)> {
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
fn gather_3x3_padded(
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
