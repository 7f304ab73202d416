//! The numbers of the int8 scheme: activation scale and zero point from a range, symmetric
//! per-channel weight scales, and real multipliers as fixed-point multiplier + shift.

use wheelleg_runtime::model::quant::{MAX_SHIFT, MIN_SHIFT};

/// Affine int8 quantization of an activation: real = `scale * (q - zero_point)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ActQuant {
    /// Real units per step (> 0).
    pub scale: f32,
    /// Integer standing for real 0.
    pub zero_point: i8,
}

impl ActQuant {
    /// Maps `[low, high]` (which must contain 0) onto `[-128, 127]`. A degenerate range gets
    /// scale 1 so that nothing divides by zero (the tensor is then all zeros anyway).
    pub fn from_range(low: f32, high: f32) -> ActQuant {
        let (low, high) = (low.min(0.0), high.max(0.0));
        let span = high - low;
        if span.is_nan() || span <= f32::EPSILON || !span.is_finite() {
            return ActQuant {
                scale: 1.0,
                zero_point: 0,
            };
        }
        let scale = span / 255.0;
        // -128 + round(-low / scale): real 0 must be an exact integer (padding, ReLU floor).
        let zero_point = (-128.0 - (low / scale).round()).clamp(-128.0, 127.0) as i8;
        ActQuant { scale, zero_point }
    }

    /// Nearest int8 of a real value.
    pub fn quantize(&self, real: f32) -> i8 {
        ((real / self.scale).round() + f32::from(self.zero_point)).clamp(-128.0, 127.0) as i8
    }

    /// Real value of an int8.
    pub fn dequantize(&self, q: i8) -> f32 {
        self.scale * (f32::from(q) - f32::from(self.zero_point))
    }

    /// The action head's int16 logit quantization (format version 2): zero point 0, and a
    /// scale that puts `LOGIT_HEADROOM` times the largest calibrated magnitude at 32,767.
    /// Symmetric because the logits are signed and only compared, never padded or ReLU'd (no
    /// need for an exact real 0 at an offset); [`ActQuant::quantize`] and
    /// [`ActQuant::dequantize`] are int8 and do not apply to it. A degenerate range gets
    /// scale 1 as in [`ActQuant::from_range`].
    pub fn logits16(low: f32, high: f32) -> ActQuant {
        let max = low.abs().max(high.abs()) * LOGIT_HEADROOM;
        if max.is_nan() || max <= f32::EPSILON || !max.is_finite() {
            return ActQuant {
                scale: 1.0,
                zero_point: 0,
            };
        }
        ActQuant {
            scale: max / f32::from(i16::MAX),
            zero_point: 0,
        }
    }
}

/// How far beyond the calibrated range int16 logits stay unclamped. Why 2: held-out logits can
/// exceed the calibration's extremes, and a clamp matters only when two logits of one head both
/// clamp (a false tie); a factor of 2 makes that practically impossible while the step stays
/// 64 times finer per unit of range than int8's 255 steps over `[min, max]` (about 128 times
/// for the baseline policy's roughly symmetric logits), which is what removes the output
/// rounding from the argmax.
pub const LOGIT_HEADROOM: f32 = 2.0;

/// A real multiplier is not representable by the runtime.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MultiplierOutOfRange(pub f64);

/// `real` as `(multiplier, shift)` with `real ~= multiplier * 2^(shift - 31)`, `multiplier` in
/// `[2^30, 2^31)`. Zero, negative-zero and multipliers below the smallest representable
/// (about 2^-32) become `(0, 0)`: their products round to 0 anyway.
pub fn quantize_multiplier(real: f64) -> Result<(i32, i8), MultiplierOutOfRange> {
    if !real.is_finite() || real < 0.0 {
        return Err(MultiplierOutOfRange(real));
    }
    if real == 0.0 {
        return Ok((0, 0));
    }
    // real = fraction * 2^exponent with fraction in [0.5, 1).
    let mut exponent = 0i32;
    let mut fraction = real;
    while fraction >= 1.0 {
        fraction /= 2.0;
        exponent += 1;
    }
    while fraction < 0.5 {
        fraction *= 2.0;
        exponent -= 1;
    }
    let mut multiplier = (fraction * (1u64 << 31) as f64).round() as i64;
    if multiplier == 1 << 31 {
        // Rounded up to 1.0: renormalize.
        multiplier /= 2;
        exponent += 1;
    }
    if exponent < i32::from(MIN_SHIFT) {
        return Ok((0, 0));
    }
    if exponent > i32::from(MAX_SHIFT) {
        return Err(MultiplierOutOfRange(real));
    }
    Ok((multiplier as i32, exponent as i8))
}

/// Symmetric per-row int8 quantization: scale = max |w| / 127 per row (1 for an all-zero row),
/// weights rounded and clamped to `[-127, 127]`.
pub fn quantize_rows(weights: &[f32], row_len: usize) -> (Vec<i8>, Vec<f32>) {
    let mut quantized = Vec::with_capacity(weights.len());
    let mut scales = Vec::with_capacity(weights.len() / row_len.max(1));
    for row in weights.chunks_exact(row_len) {
        let max = row.iter().fold(0.0f32, |m, w| m.max(w.abs()));
        let scale = if max > 0.0 { max / 127.0 } else { 1.0 };
        quantized.extend(
            row.iter()
                .map(|w| (w / scale).round().clamp(-127.0, 127.0) as i8),
        );
        scales.push(scale);
    }
    (quantized, scales)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn multipliers_round_trip() {
        for &real in &[1.0, 0.5, 0.75, 1e-3, 3.9e-6, 123.456, 0.999_999_999_9] {
            let (m, shift) = quantize_multiplier(real).unwrap();
            assert!((1 << 30..=i32::MAX).contains(&m), "{real}: {m}");
            let back = f64::from(m) * 2f64.powi(i32::from(shift) - 31);
            assert!((back - real).abs() <= real * 1e-9, "{real} -> {back}");
        }
        assert_eq!(quantize_multiplier(0.0), Ok((0, 0)));
        assert_eq!(quantize_multiplier(1e-12), Ok((0, 0)));
        assert!(quantize_multiplier(-1.0).is_err());
        assert!(quantize_multiplier(1e12).is_err());
    }

    #[test]
    fn activation_zero_point_makes_zero_exact() {
        let relu = ActQuant::from_range(0.0, 2.55);
        assert_eq!(relu.zero_point, -128);
        assert_eq!(relu.quantize(0.0), -128);
        assert_eq!(relu.quantize(2.55), 127);
        let signed = ActQuant::from_range(-1.0, 3.0);
        assert_eq!(signed.dequantize(signed.zero_point), 0.0);
        assert_eq!(ActQuant::from_range(0.0, 0.0).scale, 1.0);
    }

    #[test]
    fn logit_quantization_is_symmetric_with_headroom() {
        let q = ActQuant::logits16(-40.0, 10.0);
        assert_eq!(q.zero_point, 0);
        assert!((q.scale * 32767.0 - 80.0).abs() < 1e-3, "{}", q.scale);
        assert_eq!(ActQuant::logits16(0.0, 0.0).scale, 1.0);
    }

    #[test]
    fn rows_are_scaled_per_row() {
        let (q, scales) = quantize_rows(&[0.25, -1.0, 0.0, 0.0, 2.0, 0.5], 3);
        assert_eq!(q, vec![32, -127, 0, 0, 127, 32]);
        assert_eq!(scales, vec![1.0 / 127.0, 2.0 / 127.0]);
    }
}
