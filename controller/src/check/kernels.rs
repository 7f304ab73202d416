//! The DSP kernel's input quantization against the portable scalar kernel's over the whole
//! range of shifts the loader accepts, beyond the one shipped network's: each of its 32-bit
//! formulas (right shift of 33 or more; 17 to 32 by the rounded high word) and the scalar
//! fallback must give the scalar kernel's integers on every input.

use wheelleg_runtime::model::format::InputQuantRecord;
use wheelleg_runtime::model::kernel::{quantize_inputs, quantize_inputs_scalar};
use wheelleg_runtime::model::quant::{MAX_SHIFT, MIN_SHIFT};
use wheelleg_runtime::model::Kernel;

/// Inputs per call: the int16 range in steps of 1,021 (a prime, so the low bits vary), with
/// both ends and the values around 0.
const INPUTS: usize = 72;

/// Multipliers in `[2^30, 2^31)` (both ends and a middle one) and 0.
const MULTIPLIERS: [i32; 4] = [1 << 30, 0x5A82_7999, i32::MAX, 0];

/// Zero points: the ends of int8 and one in between.
const ZERO_POINTS: [i8; 3] = [-128, 0, 37];

/// Input records (shift, multiplier, zero point) whose outputs differ between the two
/// kernels on at least one of the inputs: 0 expected.
#[inline(never)]
pub fn input_quantization_mismatches() -> u64 {
    let mut inputs_mm = [0i16; INPUTS];
    for (k, x) in inputs_mm.iter_mut().enumerate() {
        *x = match k {
            0 => i16::MIN,
            1 => i16::MAX,
            2..=6 => k as i16 - 4,
            _ => (i32::from(i16::MIN) + 1_021 * (k as i32 - 6)) as i16,
        };
    }
    let mut mismatches = 0;
    for shift in MIN_SHIFT..=MAX_SHIFT {
        for multiplier in MULTIPLIERS {
            for zero_point in ZERO_POINTS {
                let quant = InputQuantRecord {
                    scale_m: 1.0,
                    zero_point,
                    multiplier,
                    shift,
                };
                let (mut fast, mut reference) = ([0i8; INPUTS], [0i8; INPUTS]);
                quantize_inputs(Kernel::Dsp, &quant, &inputs_mm, &mut fast);
                quantize_inputs_scalar(&quant, &inputs_mm, &mut reference);
                mismatches += u64::from(fast != reference);
            }
        }
    }
    mismatches
}
