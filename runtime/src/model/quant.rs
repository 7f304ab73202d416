//! Integer requantization, the only arithmetic between an int32 accumulator and a layer output
//! (an int8 activation, or an int16 action logit since weights format version 2). No floating
//! point: a real multiplier `m` is stored as `multiplier * 2^(shift-31)` with `multiplier` in
//! `[2^30, 2^31)` (or 0), as in TFLite and CMSIS-NN.

/// Smallest shift the runtime accepts (multipliers down to about 2^-62).
pub const MIN_SHIFT: i8 = -31;
/// Largest shift the runtime accepts (multipliers up to about 2^30).
pub const MAX_SHIFT: i8 = 30;

/// `round(value * multiplier * 2^(shift - 31))`, rounding halves towards +infinity.
///
/// One rounding step on the exact 64-bit product (TFLite's "single rounding" variant): the
/// product of an i32 and a multiplier below 2^31 stays below 2^62 in magnitude, and the right
/// shift `31 - shift` is in `1..=62` for shifts the loader accepts, so nothing overflows. Shifts
/// outside `[MIN_SHIFT, MAX_SHIFT]` never reach here (the loader rejects them); they are clamped
/// rather than trusted so that this function stays total.
#[inline(always)]
pub fn requantize(value: i32, multiplier: i32, shift: i8) -> i64 {
    let right = 31 - i32::from(shift.clamp(MIN_SHIFT, MAX_SHIFT));
    let product = i64::from(value) * i64::from(multiplier);
    let half = 1i64 << (right - 1);
    (product + half) >> right
}

/// Requantizes an accumulator to an int8 activation: adds the output zero point and clamps to
/// int8, or to `[zero_point, 127]` when a ReLU is fused (real values below 0 become 0).
#[inline(always)]
pub fn to_int8(acc: i32, multiplier: i32, shift: i8, zero_point: i8, relu: bool) -> i8 {
    let low = if relu { i64::from(zero_point) } else { -128 };
    let value = requantize(acc, multiplier, shift) + i64::from(zero_point);
    // Clamped into [-128, 127] just above, so the narrowing cannot truncate.
    value.clamp(low, 127) as i8
}

/// Requantizes an accumulator to any layer output: `clamp(zero_point + requantize(acc), low,
/// high)`. Every kernel's output goes through this formula: int8 activations use
/// `[-128 or zero_point under ReLU, 127]`, the action head's int16 logits `[-32768, 32767]` with
/// zero point 0 (see `load::Linear`). The order (min with `high`, then max with `low`) is the
/// SIMD kernel's too, so that even `low > high` (never produced by the loader) gives the same
/// result, `low`, in every kernel instead of a panic.
#[inline(always)]
pub fn requantize_clamped(
    acc: i32,
    multiplier: i32,
    shift: i8,
    zero_point: i8,
    low: i16,
    high: i16,
) -> i16 {
    let value = requantize(acc, multiplier, shift) + i64::from(zero_point);
    // Between two i16 bounds after the two comparisons, so the narrowing is exact.
    value.min(i64::from(high)).max(i64::from(low)) as i16
}

/// Quantizes one raw input (a height or a state value in millimetres) to int8.
#[inline]
pub fn quantize_mm(value_mm: i32, multiplier: i32, shift: i8, zero_point: i8) -> i8 {
    to_int8(value_mm, multiplier, shift, zero_point, false)
}

/// Quantizes one state feature in millimetres to the int16 grid of weights format version 2:
/// `clamp(256 * zero_point + rescale(value_mm), -32768, 32767)`, the int8 grid of `zero_point`
/// refined by [`super::format::STATE_FRACTION_BITS`] bits: `u / 256` is, in int8 steps, the
/// value [`quantize_mm`] rounds to an integer (with a multiplier 256 times smaller).
#[inline]
pub fn quantize_mm16(value_mm: i32, multiplier: i32, shift: i8, zero_point: i8) -> i16 {
    let offset = i64::from(zero_point) << super::format::STATE_FRACTION_BITS;
    let value = requantize(value_mm, multiplier, shift) + offset;
    // Clamped into the i16 range just before, so the narrowing is exact.
    value.clamp(i64::from(i16::MIN), i64::from(i16::MAX)) as i16
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn requantize_rounds_half_up_and_scales() {
        // multiplier 2^30, shift 0: times 0.5.
        let half = 1 << 30;
        assert_eq!(requantize(10, half, 0), 5);
        assert_eq!(requantize(11, half, 0), 6, "5.5 rounds up");
        assert_eq!(requantize(-11, half, 0), -5, "-5.5 rounds towards +inf");
        // shift +2: times 2.
        assert_eq!(requantize(7, half, 2), 14);
        // extreme inputs do not overflow.
        // (-2^31 * (2^31 - 1) + 1) / 2, floored: no overflow at the extremes.
        assert_eq!(
            requantize(i32::MIN, i32::MAX, MAX_SHIFT),
            -(1i64 << 61) + (1i64 << 30)
        );
    }

    #[test]
    fn requantize_clamped_matches_to_int8_and_reaches_int16() {
        let one = 1 << 30;
        for acc in [-100_000, -300, -129, -5, 0, 5, 127, 128, 100_000] {
            for (zero_point, relu) in [(0, false), (-100, true), (17, false)] {
                let low = if relu { i16::from(zero_point) } else { -128 };
                assert_eq!(
                    requantize_clamped(acc, one, 1, zero_point, low, 127),
                    i16::from(to_int8(acc, one, 1, zero_point, relu))
                );
            }
        }
        assert_eq!(
            requantize_clamped(1000, one, 1, 0, i16::MIN, i16::MAX),
            1000
        );
        assert_eq!(
            requantize_clamped(i32::MAX, one, 1, 0, i16::MIN, i16::MAX),
            i16::MAX
        );
        assert_eq!(
            requantize_clamped(i32::MIN, one, 1, 0, i16::MIN, i16::MAX),
            i16::MIN
        );
        assert_eq!(
            requantize_clamped(0, one, 1, 0, 5, -5),
            5,
            "inverted bounds: no panic"
        );
    }

    #[test]
    fn state_at_16_bits_refines_the_int8_grid() {
        // 1 mm per int8 step as multiplier 2^30, shift 1; 256 times that for int16.
        let (m, s8, s16) = (1 << 30, 1i8, 9i8);
        for mm in [-300, -129, -5, 0, 3, 100, 127, 128, 5000] {
            for zero_point in [-128i8, -7, 0, 40] {
                let q16 = quantize_mm16(mm, m, s16, zero_point);
                let q8 = quantize_mm(mm, m, s8, zero_point);
                // Where the int8 value is not clamped, the int16 one is exactly 256 times it.
                if (-128..127).contains(&(i32::from(zero_point) + mm)) {
                    assert_eq!(i32::from(q16), 256 * i32::from(q8), "{mm} {zero_point}");
                }
                // Inputs on the int8 grid: u / 256 is the int8 value (clamps included).
                assert_eq!(q16 >> 8, i16::from(q8), "{mm} {zero_point}");
            }
        }
        assert_eq!(quantize_mm16(i32::MAX, m, s16, 0), i16::MAX);
        assert_eq!(quantize_mm16(i32::MIN, m, s16, 0), i16::MIN);
    }

    #[test]
    fn to_int8_clamps_and_applies_relu() {
        let one = 1 << 30; // 0.5 at shift 0; use shift 1 for 1.0
        assert_eq!(to_int8(1000, one, 1, 0, false), 127);
        assert_eq!(to_int8(-1000, one, 1, 0, false), -128);
        assert_eq!(
            to_int8(-5, one, 1, -100, true),
            -100,
            "ReLU floor is the zero point"
        );
        assert_eq!(to_int8(5, one, 1, -100, true), -95);
    }
}
