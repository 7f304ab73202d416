//! Fixed-point requantization.

use super::*;

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8192))]

    /// `requantize` is the real product rounded half up, exactly, for every value, multiplier
    /// and shift the loader accepts (checked in i128 arithmetic, which cannot overflow).
    #[test]
    fn requantize_is_the_rounded_real_product(value in any::<i32>(),
                                              multiplier in 0i32..=i32::MAX,
                                              shift in MIN_SHIFT..=MAX_SHIFT) {
        let got = requantize(value, multiplier, shift);
        let right = 31 - i32::from(shift);
        let exact = i128::from(value) * i128::from(multiplier);
        // floor((exact + 2^(right-1)) / 2^right): round half towards +infinity.
        let want = (exact + (1i128 << (right - 1))).div_euclid(1i128 << right);
        prop_assert_eq!(i128::from(got), want);
    }

    /// The int8 output is clamped, and a fused ReLU never goes below the zero point.
    #[test]
    fn to_int8_stays_in_range(acc in any::<i32>(), multiplier in 0i32..=i32::MAX,
                              shift in MIN_SHIFT..=MAX_SHIFT, zero_point in any::<i8>(),
                              relu in any::<bool>()) {
        let q = to_int8(acc, multiplier, shift, zero_point, relu);
        if relu {
            prop_assert!(q >= zero_point);
        }
        let unclamped = requantize(acc, multiplier, shift) + i64::from(zero_point);
        if (-128..=127).contains(&unclamped) && (!relu || unclamped >= i64::from(zero_point)) {
            prop_assert_eq!(i64::from(q), unclamped);
        }
    }
}
