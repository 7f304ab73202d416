//! The SIMD kernels against the scalar one: row by row over random layers and extreme values,
//! and whole networks (the shipped file and synthetic random architectures) kernel against
//! kernel; input checks and kernel selection on the shipped file. The agreement of the runtime
//! with the trainer's quantized networks and an independent integer reference is
//! trainer/tests/runtime_agreement.rs.
// Test code: a failed unwrap or index is a failed test, which is what it should be.
#![allow(clippy::unwrap_used, clippy::indexing_slicing, clippy::expect_used)]

mod common;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::model::kernel::{self, Kernel};
use wheelleg_runtime::model::load::Linear;
use wheelleg_runtime::model::{DefaultPolicy, Policy};

use common::*;

#[test]
fn wrong_input_sizes_are_typed_errors() {
    let bytes = shipped_bytes();
    let policy = DefaultPolicy::from_bytes(&bytes).unwrap();
    let map = [[0i16; 16]; 16];
    assert!(matches!(
        policy.act(&map, &[0; 4]),
        Err(wheelleg_runtime::model::InferError::HeightMapShape {
            expected: 1024,
            found: 256
        })
    ));
    assert!(matches!(
        policy.evaluate(&[0; 1024], &[0; 3]),
        Err(wheelleg_runtime::model::InferError::StateLength {
            expected: 4,
            found: 3
        })
    ));
    assert!(policy.evaluate_m(&[0.0; 5000], &[0.0; 4]).is_err());
    assert!(policy.evaluate_m(&[0.0; 1024], &[0.0; 40]).is_err());
}

#[test]
fn simd_kernel_equals_scalar_kernel_on_random_rows_and_extreme_values() {
    if !Kernel::Avx2.is_supported() {
        eprintln!("AVX2 not available on this CPU: only the scalar kernel runs here");
        return;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(42);
    for case in 0..3000 {
        let rows = rng.random_range(1..=13);
        let row_len = rng.random_range(1..=300);
        let extreme = case % 3 == 0;
        // |x - zp| <= 255 and any int8 weight, bias within the format's bound.
        let input: Vec<i16> = (0..row_len)
            .map(|_| {
                if extreme {
                    if rng.random_bool(0.5) {
                        255
                    } else {
                        -255
                    }
                } else {
                    rng.random_range(-255..=255)
                }
            })
            .collect();
        let weights: Vec<u8> = (0..rows * row_len)
            .map(|_| if extreme { 0x80 } else { rng.random() })
            .collect();
        let le = |v: Vec<i32>| -> Vec<u8> { v.into_iter().flat_map(i32::to_le_bytes).collect() };
        let bias = le((0..rows)
            .map(|_| rng.random_range(-(1 << 30)..=(1 << 30)))
            .collect());
        let multipliers = le((0..rows).map(|_| rng.random_range(0..i32::MAX)).collect());
        let shifts: Vec<u8> = (0..rows)
            .map(|_| rng.random_range(-31i8..=30) as u8)
            .collect();
        let output_zero_point = rng.random();
        let relu = rng.random_bool(0.5);
        let (output_low, output_high) = Linear::int8_bounds(output_zero_point, relu);
        let linear = Linear {
            weights: &weights,
            bias: &bias,
            multipliers: &multipliers,
            shifts: &shifts,
            rows,
            row_len,
            input_zero_point: 0,
            output_zero_point,
            relu,
            output_low,
            output_high,
        };
        let mut scalar = vec![0i8; rows];
        let mut simd = vec![0i8; rows];
        kernel::linear(Kernel::Scalar, &linear, &input, &mut scalar);
        kernel::linear(Kernel::Avx2, &linear, &input, &mut simd);
        assert_eq!(scalar, simd, "case {case}: rows {rows} row_len {row_len}");
        // The same rows as int16 logits (zero point 0, full int16 range, as the action head).
        let logits = Linear {
            output_zero_point: 0,
            relu: false,
            output_low: i16::MIN,
            output_high: i16::MAX,
            ..linear
        };
        let mut scalar = vec![0i16; rows];
        let mut simd = vec![0i16; rows];
        kernel::linear(Kernel::Scalar, &logits, &input, &mut scalar);
        kernel::linear(Kernel::Avx2, &logits, &input, &mut simd);
        assert_eq!(
            scalar, simd,
            "int16 case {case}: rows {rows} row_len {row_len}"
        );
        // And both equal the plain sum before requantization.
        for row in 0..rows {
            let dot: i64 = input
                .iter()
                .zip(&weights[row * row_len..(row + 1) * row_len])
                .map(|(&x, &w)| i64::from(x) * i64::from(w as i8))
                .sum();
            assert_eq!(
                dot,
                i64::from(kernel::dot_scalar(&input, &weights[row * row_len..]))
            );
        }
    }
}

#[test]
fn detection_picks_a_supported_kernel() {
    assert!(Kernel::detect().is_supported());
    assert!(Kernel::Scalar.is_supported());
    let bytes = shipped_bytes();
    let mut policy = DefaultPolicy::from_bytes(&bytes).unwrap();
    assert_eq!(policy.kernel(), Kernel::detect());
    for kernel in Kernel::ALL {
        assert_eq!(policy.set_kernel(kernel).is_ok(), kernel.is_supported());
    }
}

/// A random layer's tensors (as the loader would borrow them) for kernel tests.
struct RandomLayer {
    weights: Vec<u8>,
    bias: Vec<u8>,
    multipliers: Vec<u8>,
    shifts: Vec<u8>,
    rows: usize,
    row_len: usize,
    output_zero_point: i8,
    relu: bool,
    /// Output bounds: int8 ones (from zero point and ReLU) or, for int16 logits, random ones.
    bounds: (i16, i16),
}

impl RandomLayer {
    fn new(rng: &mut ChaCha8Rng, rows: usize, row_len: usize, extreme: bool) -> Self {
        let le = |v: Vec<i32>| -> Vec<u8> { v.into_iter().flat_map(i32::to_le_bytes).collect() };
        RandomLayer {
            weights: (0..rows * row_len)
                .map(|_| if extreme { 0x80 } else { rng.random() })
                .collect(),
            bias: le((0..rows)
                .map(|_| rng.random_range(-(1 << 30)..=(1 << 30)))
                .collect()),
            multipliers: le((0..rows).map(|_| rng.random_range(0..i32::MAX)).collect()),
            shifts: (0..rows)
                .map(|_| rng.random_range(-31i8..=30) as u8)
                .collect(),
            rows,
            row_len,
            output_zero_point: rng.random(),
            relu: rng.random_bool(0.5),
            bounds: (0, 0),
        }
    }

    /// As an int8 layer: bounds from its zero point and ReLU.
    fn int8(mut self) -> Self {
        self.bounds = Linear::int8_bounds(self.output_zero_point, self.relu);
        self
    }

    /// As an int16 logit layer: zero point 0, int16 bounds (sometimes narrower, as a version 1
    /// head's).
    fn int16(mut self, rng: &mut ChaCha8Rng) -> Self {
        self.output_zero_point = 0;
        self.relu = false;
        self.bounds = if rng.random_bool(0.5) {
            (i16::MIN, i16::MAX)
        } else {
            let zero_point: i8 = rng.random();
            (-128 - i16::from(zero_point), 127 - i16::from(zero_point))
        };
        self
    }

    fn linear(&self) -> Linear<'_> {
        Linear {
            weights: &self.weights,
            bias: &self.bias,
            multipliers: &self.multipliers,
            shifts: &self.shifts,
            rows: self.rows,
            row_len: self.row_len,
            input_zero_point: 0,
            output_zero_point: self.output_zero_point,
            relu: self.relu,
            output_low: self.bounds.0,
            output_high: self.bounds.1,
        }
    }
}

/// The batched kernel (several conv pixels per call, padded strides with garbage in the
/// padding, the short-row path of first conv layers) against the scalar kernel, row by row.
#[test]
fn batched_simd_kernel_equals_scalar_kernel() {
    if !Kernel::Avx2.is_supported() {
        eprintln!("AVX2 not available on this CPU: batched AVX2 kernel not tested here");
        return;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(4242);
    for case in 0..2000 {
        let short = case % 2 == 0;
        let rows = rng.random_range(1..=40);
        let row_len = if short {
            rng.random_range(1..=12)
        } else {
            rng.random_range(1..=300)
        };
        let stride = match rng.random_range(0..3) {
            0 => row_len,
            1 => kernel::padded_row_len(row_len),
            _ => row_len + rng.random_range(0..20),
        };
        let count = rng.random_range(1..=9);
        let extreme = case % 5 == 0;
        let layer = RandomLayer::new(&mut rng, rows, row_len, extreme);
        let logits = RandomLayer::new(&mut rng, rows, row_len, extreme).int16(&mut rng);
        let layer = layer.int8();
        let linear = layer.linear();
        // Garbage between row_len and stride: a correct kernel never reads it into a sum.
        let inputs: Vec<i16> = (0..(count - 1) * stride + row_len)
            .map(|i| {
                if i % stride >= row_len {
                    rng.random()
                } else if extreme {
                    if rng.random_bool(0.5) {
                        255
                    } else {
                        -255
                    }
                } else {
                    rng.random_range(-255..=255)
                }
            })
            .collect();
        let mut scalar = vec![0i8; count * rows];
        let mut simd = vec![0i8; count * rows];
        kernel::linear_batch(Kernel::Scalar, &linear, &inputs, stride, &mut scalar);
        kernel::linear_batch(Kernel::Avx2, &linear, &inputs, stride, &mut simd);
        assert_eq!(
            scalar, simd,
            "case {case}: rows {rows} row_len {row_len} stride {stride} count {count}"
        );
        for pixel in 0..count {
            let mut one = vec![0i8; rows];
            let input = &inputs[pixel * stride..pixel * stride + row_len];
            kernel::linear(Kernel::Scalar, &linear, input, &mut one);
            assert_eq!(one, scalar[pixel * rows..(pixel + 1) * rows], "case {case}");
        }
        // int16 outputs through the same batched paths (short rows, pairs, single pixel).
        let logits = logits.linear();
        let mut scalar = vec![0i16; count * rows];
        let mut simd = vec![0i16; count * rows];
        kernel::linear_batch(Kernel::Scalar, &logits, &inputs, stride, &mut scalar);
        kernel::linear_batch(Kernel::Avx2, &logits, &inputs, stride, &mut simd);
        assert_eq!(
            scalar, simd,
            "int16 case {case}: rows {rows} row_len {row_len}"
        );
        // Bounds wider than the output type (never from the loader): every kernel saturates
        // the same way.
        let mut scalar = vec![0i8; count * rows];
        let mut simd = vec![0i8; count * rows];
        kernel::linear_batch(Kernel::Scalar, &logits, &inputs, stride, &mut scalar);
        kernel::linear_batch(Kernel::Avx2, &logits, &inputs, stride, &mut simd);
        assert_eq!(
            scalar, simd,
            "saturated case {case}: rows {rows} row_len {row_len}"
        );
    }
}

/// Vectorized input quantization (the height map) against the scalar one, over the whole i16
/// range and every multiplier / shift combination class.
#[test]
fn simd_input_quantization_equals_scalar() {
    if !Kernel::Avx2.is_supported() {
        eprintln!("AVX2 not available on this CPU: AVX2 input quantization not tested here");
        return;
    }
    let mut rng = ChaCha8Rng::seed_from_u64(77);
    for case in 0..500 {
        let quant = wheelleg_runtime::model::format::InputQuantRecord {
            scale_m: 0.001,
            zero_point: rng.random(),
            multiplier: if case % 7 == 0 {
                i32::MAX
            } else {
                rng.random_range(0..i32::MAX)
            },
            shift: rng.random_range(-31i8..=30),
        };
        let len = rng.random_range(0..100);
        let values: Vec<i16> = (0..len)
            .map(|i| match (case + i) % 4 {
                0 => i16::MIN,
                1 => i16::MAX,
                _ => rng.random(),
            })
            .collect();
        let mut scalar = vec![0i8; len];
        let mut simd = vec![0i8; len];
        kernel::quantize_inputs(Kernel::Scalar, &quant, &values, &mut scalar);
        kernel::quantize_inputs(Kernel::Avx2, &quant, &values, &mut simd);
        assert_eq!(scalar, simd, "case {case}: {quant:?}");
    }
}

/// The shipped file, then `count` synthetic files of random architectures drawn from `rng`.
fn shipped_and_random_files(rng: &mut ChaCha8Rng, count: usize) -> Vec<WeightsFile> {
    let mut files = vec![WeightsFile::shipped()];
    files.extend((0..count).map(|_| {
        let arch = random_architecture(rng);
        WeightsFile::synthetic(rng, &arch)
    }));
    files
}

/// Whole networks: every supported kernel gives the same logits and value as the scalar one, on
/// the shipped file and on synthetic files of random architectures.
#[test]
fn every_kernel_gives_the_scalar_outputs_on_whole_networks() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed);
    let files = shipped_and_random_files(&mut rng, 100);
    let mut decisions = 0;
    let mut distinct = std::collections::HashSet::new();
    for (index, file) in files.iter().enumerate() {
        let arch = file.architecture();
        let bytes = file.to_bytes();
        let mut policy = Policy::<65_536, 8_192>::from_bytes(&bytes)
            .unwrap_or_else(|e| panic!("file {index} {arch:?}: {e}"));
        for _ in 0..10 {
            let (height, state) = random_inputs_mm(&mut rng, &arch);
            policy.set_kernel(Kernel::Scalar).unwrap();
            let scalar = policy.evaluate(&height, &state).unwrap();
            assert_eq!(scalar.value.is_some(), arch.value_head);
            distinct.extend(scalar.action_logits.iter().copied());
            for kernel in Kernel::ALL.into_iter().filter(|k| k.is_supported()) {
                policy.set_kernel(kernel).unwrap();
                let outputs = policy.evaluate(&height, &state).unwrap();
                assert_eq!(
                    outputs.action_logits.as_slice(),
                    scalar.action_logits.as_slice(),
                    "file {index} {kernel:?}"
                );
                assert_eq!(outputs.value, scalar.value, "file {index} {kernel:?}");
            }
            decisions += 1;
        }
    }
    assert_eq!(decisions, 1010);
    // The synthetic parameters keep the logits spread (not saturated, not constant), so the
    // comparison sees the arithmetic.
    assert!(distinct.len() > 500, "{} distinct logits", distinct.len());
}

/// A host's buffers reused from observation to observation, and from one network to another
/// (so they hold what a larger network left), give the outputs of fresh zeroed buffers.
#[test]
fn reused_buffers_give_the_outputs_of_fresh_ones() {
    let mut rng = ChaCha8Rng::seed_from_u64(0xb0ff);
    let files = shipped_and_random_files(&mut rng, 20);
    let mut scratch = Box::new(wheelleg_runtime::model::Scratch::<65_536, 8_192>::new());
    let mut heights_mm = vec![0i16; 4096];
    let mut decisions = 0;
    for (index, file) in files.iter().enumerate() {
        let arch = file.architecture();
        let bytes = file.to_bytes();
        let policy = Policy::<65_536, 8_192>::from_bytes(&bytes).unwrap();
        for _ in 0..5 {
            let (height, state) = random_inputs_mm(&mut rng, &arch);
            let height_m: Vec<f32> = height.iter().map(|&mm| f32::from(mm) * 1e-3).collect();
            let state_m: Vec<f32> = state.iter().map(|&mm| mm as f32 * 1e-3).collect();
            let fresh = policy.evaluate_m(&height_m, &state_m).unwrap();
            let reused = policy
                .evaluate_m_with(&mut scratch, &mut heights_mm, &height_m, &state_m)
                .unwrap();
            assert_eq!(fresh, reused, "file {index} {arch:?}");
            decisions += 1;
        }
    }
    assert_eq!(decisions, 105);
    // A buffer too short for the map is a typed error, not a panic.
    let bytes = shipped_bytes();
    let policy = DefaultPolicy::from_bytes(&bytes).unwrap();
    let mut small = Box::new(wheelleg_runtime::model::Scratch::new());
    assert!(policy
        .evaluate_m_with(&mut small, &mut [0i16; 16], &[0.0; 1024], &[0.0; 4])
        .is_err());
}
