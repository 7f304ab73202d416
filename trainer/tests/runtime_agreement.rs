//! The export path as a pair: networks quantized by the trainer, written as weights files and
//! run by the runtime, bit-exact against an independent integer reference of the quantized
//! network (random architectures of the family, both format versions, every kernel this CPU
//! runs, the default network through the firmware API, the first-layer path of the AVX2
//! kernel), and the trainer's files accepted by the runtime's loader.
// Test code: a failed unwrap or index is a failed test, which is what it should be.
#![allow(clippy::unwrap_used, clippy::indexing_slicing, clippy::expect_used)]

mod common;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::model::format::FORMAT_VERSION;
use wheelleg_runtime::model::kernel::Kernel;
use wheelleg_runtime::model::load::Model;
use wheelleg_runtime::model::{DefaultPolicy, LoadError, Outputs};
use wheelleg_trainer::network_f32::{Architecture, ConvSpec};
use wheelleg_trainer::quantize::file_bytes::envelope_bytes;
use wheelleg_trainer::quantize::{Int8Policy, RangeMethod};

use common::*;

fn check_against_reference(
    policy: &Int8Policy<'_>,
    outputs: &Outputs,
    expected: &(Vec<i16>, Option<i8>),
) {
    assert_eq!(outputs.action_logits.as_slice(), expected.0.as_slice());
    assert_eq!(outputs.value.map(|(q, _, _)| q), expected.1);
    assert_eq!(outputs.value.is_some(), policy.model().value_head.is_some());
}
#[test]
fn int8_inference_is_bit_exact_with_the_reference_on_random_networks() {
    let mut rng = ChaCha8Rng::seed_from_u64(0x5eed);
    let mut decisions = 0;
    for net_index in 0..150 {
        let arch = random_architecture(&mut rng);
        let method = if net_index % 2 == 0 {
            RangeMethod::MinMax
        } else {
            RangeMethod::Percentile {
                low: 1.0,
                high: 99.0,
            }
        };
        // Every third network as a format version 1 file (int8 logits): the runtime still
        // reads those, through the same int16 logit path with int8 bounds.
        let version = if net_index % 3 == 2 { 1 } else { 2 };
        let (_, quantized) = random_quantized_version(&mut rng, &arch, method, version);
        let bytes = quantized.to_bytes().unwrap();
        let mut policy = Int8Policy::from_bytes(&bytes)
            .unwrap_or_else(|e| panic!("network {net_index} {arch:?}: {e}"));
        assert_eq!(policy.model().version, version);
        for _ in 0..20 {
            let (height, state) = random_inputs_mm(&mut rng, &arch);
            let expected = reference_forward(&quantized, &height, &state);
            for kernel in Kernel::ALL.into_iter().filter(|k| k.is_supported()) {
                policy.set_kernel(kernel).unwrap();
                let outputs = policy.evaluate(&height, &state).unwrap();
                check_against_reference(&policy, &outputs, &expected);
            }
            decisions += 1;
        }
    }
    assert_eq!(decisions, 3000);
}

#[test]
fn default_network_is_bit_exact_and_acts_through_the_firmware_api() {
    for seed in 0..3 {
        let (_, quantized) = default_quantized(seed);
        let bytes = quantized.to_bytes().unwrap();
        let policy = DefaultPolicy::from_bytes(&bytes).unwrap();
        let mut rng = ChaCha8Rng::seed_from_u64(seed + 100);
        for _ in 0..50 {
            let (height, state) = random_inputs_mm(&mut rng, &quantized.arch);
            let mut map = [[0i16; 32]; 32];
            for (row, chunk) in map.iter_mut().zip(height.chunks_exact(32)) {
                row.copy_from_slice(chunk);
            }
            let action = policy.act(&map, &state).unwrap();
            let (logits, value) = reference_forward(&quantized, &height, &state);
            let outputs = policy.evaluate(&height, &state).unwrap();
            assert_eq!(outputs.action_logits.as_slice(), logits.as_slice());
            assert_eq!(outputs.value.map(|v| v.0), value);
            // Greedy action = first maximum of each head of the reference logits.
            let indices: Vec<usize> = logits
                .chunks_exact(3)
                .map(|head| {
                    let best = *head.iter().max().unwrap();
                    head.iter().position(|&l| l == best).unwrap()
                })
                .collect();
            assert_eq!(action.head_indices().to_vec(), indices);
        }
    }
}

/// The first-layer path of the AVX2 kernel (one input channel, 3 x 3 kernel, read straight from
/// the int8 map) over every stride and padding, channel counts below, at and above its 16-lane
/// chunk, odd map sizes, and a later layer with one input channel, against the reference.
#[test]
fn one_channel_3x3_conv_path_is_bit_exact() {
    let mut rng = ChaCha8Rng::seed_from_u64(33);
    let mut checked = 0;
    for stride in 1..=3 {
        for padding in 0..=2 {
            for out_channels in [1, 5, 16, 20, 33] {
                let (rows, cols) = (rng.random_range(3..=21), rng.random_range(3..=21));
                let first = ConvSpec {
                    in_channels: 1,
                    out_channels,
                    kernel: 3,
                    stride,
                    padding,
                };
                let (h, w) = (first.output_side(rows), first.output_side(cols));
                let mut convs = vec![first];
                if out_channels == 1 && h >= 3 && w >= 3 {
                    convs.push(ConvSpec {
                        in_channels: 1,
                        out_channels: 7,
                        kernel: 3,
                        stride: 1,
                        padding: 1,
                    });
                }
                let arch = Architecture {
                    height_rows: rows,
                    height_cols: cols,
                    state_len: 4,
                    convs,
                    hidden: vec![12],
                    value_head: true,
                };
                let (_, quantized) = random_quantized(&mut rng, &arch, RangeMethod::MinMax);
                let bytes = quantized.to_bytes().unwrap();
                let mut policy = Int8Policy::from_bytes(&bytes).unwrap();
                for _ in 0..5 {
                    let (height, state) = random_inputs_mm(&mut rng, &arch);
                    let expected = reference_forward(&quantized, &height, &state);
                    for kernel in Kernel::ALL.into_iter().filter(|k| k.is_supported()) {
                        policy.set_kernel(kernel).unwrap();
                        let outputs = policy.evaluate(&height, &state).unwrap();
                        check_against_reference(&policy, &outputs, &expected);
                    }
                    checked += 1;
                }
            }
        }
    }
    assert_eq!(checked, 3 * 3 * 5 * 5);
}

/// Files the trainer writes load in the runtime; every prefix of one is truncated, and the
/// trainer's envelope of a newer version is refused with that version.
#[test]
fn trainer_files_load_and_newer_envelopes_are_refused() {
    for seed in 0..3 {
        let (_, quantized) = default_quantized(seed);
        let bytes = quantized.to_bytes().unwrap();
        let policy = DefaultPolicy::from_bytes(&bytes).unwrap();
        assert_eq!(policy.model().version, FORMAT_VERSION);
        for len in (0..bytes.len()).step_by(97) {
            assert_eq!(
                Model::parse(&bytes[..len]).err(),
                Some(LoadError::Truncated),
                "prefix of {len} bytes"
            );
        }
        let payload = quantized.payload_bytes().unwrap();
        assert_eq!(envelope_bytes(FORMAT_VERSION, &payload).unwrap(), bytes);
    }
    let future = envelope_bytes(FORMAT_VERSION + 1, b"anything").unwrap();
    assert!(matches!(
        Model::parse(&future),
        Err(LoadError::UnsupportedVersion { found, .. }) if found == FORMAT_VERSION + 1
    ));
}
