//! The int8 network against the float one, the weights file round trip, and the default
//! model's budget (the numbers in docs/model.md).
#![allow(clippy::unwrap_used, clippy::indexing_slicing)]

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::model::format::{ConvRecord, DenseRecord, Envelope, InputRecord};
use wheelleg_runtime::model::{
    DefaultPolicy, Model, Scratch, DEFAULT_ACTIVATION_ELEMENTS, DEFAULT_ROW_ELEMENTS,
};
use wheelleg_trainer::network_f32::{Architecture, NetworkF32};
use wheelleg_trainer::quantize::{
    observation_mm, quantize, quantize_for_version, Calibration, QuantizedNetwork, RangeMethod,
};

fn observation(rng: &mut ChaCha8Rng) -> (Vec<f32>, Vec<f32>) {
    wheelleg_trainer::quantize::synthetic::synthetic_observation(rng, 5.0)
}

/// A seeded random default network and its calibration on 400 random observations.
fn calibration(seed: u64) -> (NetworkF32, Calibration, ChaCha8Rng) {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let network = NetworkF32::random(&Architecture::default_policy(), &mut rng);
    let observations: Vec<_> = (0..400).map(|_| observation(&mut rng)).collect();
    let calibration = Calibration::from_observations(
        &network,
        observations
            .iter()
            .map(|(h, s)| (h.as_slice(), s.as_slice())),
    );
    (network, calibration, rng)
}

/// The action head's output step of [`calibrated`] as an int8 (format version 1) head.
fn int8_logit_step(seed: u64, method: RangeMethod) -> f32 {
    let (network, calibration, _) = calibration(seed);
    let old = quantize_for_version(&network, &calibration, method, 1).unwrap();
    old.action_head.layer.output.scale
}

fn calibrated(seed: u64, method: RangeMethod) -> (NetworkF32, QuantizedNetwork, ChaCha8Rng) {
    let (network, calibration, rng) = calibration(seed);
    let quantized = quantize(&network, &calibration, method).unwrap();
    (network, quantized, rng)
}

fn argmax(head: &[f32]) -> usize {
    let mut best = 0;
    for (i, &v) in head.iter().enumerate() {
        if v > head[best] {
            best = i;
        }
    }
    best
}

/// On held-out observations: int8 logits stay within a few quantization steps of the float
/// logits, and the greedy choice of each head agrees except where the float logits are nearly
/// tied (a random network has many near ties; a trained one far fewer).
#[test]
fn int8_logits_track_float_logits_and_argmax_agrees() {
    for (seed, method) in [
        (11, RangeMethod::MinMax),
        (
            12,
            RangeMethod::Percentile {
                low: 0.01,
                high: 99.99,
            },
        ),
    ] {
        let (network, quantized, mut rng) = calibrated(seed, method);
        let bytes = quantized.to_bytes().unwrap();
        let policy = DefaultPolicy::from_bytes(&bytes).unwrap();
        // The logits are int16 (format version 2) with a step far below the error the int8
        // activations upstream bring; the bounds below are in steps of the int8 logit grid of
        // the same calibration (format version 1), the scale of that upstream error.
        let step = int8_logit_step(seed, method);
        assert!(quantized.action_head.layer.output.scale < step / 50.0);
        let (mut agree, mut total, mut clear_disagree) = (0, 0, 0);
        let mut sum_error = 0.0f32;
        let mut max_error = 0.0f32;
        let mut logit_spread = 0.0f32;
        for _ in 0..1000 {
            let (height, state) = observation(&mut rng);
            let (float_logits, float_value) = network.forward(&height, &state);
            let (height_mm, state_mm) = observation_mm(&height, &state);
            let outputs = policy.evaluate(&height_mm, &state_mm).unwrap();
            let int8_logits = outputs.action_logits_f32();
            for (f, q) in float_logits.iter().zip(&int8_logits) {
                let error = (f - q).abs();
                sum_error += error;
                max_error = max_error.max(error);
                logit_spread += f.abs();
            }
            for (f, q) in float_logits
                .chunks_exact(3)
                .zip(int8_logits.chunks_exact(3))
            {
                total += 1;
                if argmax(f) == argmax(q) {
                    agree += 1;
                } else {
                    // Disagreement is only acceptable where the float margin is within the
                    // int8 error: a few steps.
                    let mut sorted = f.to_vec();
                    sorted.sort_by(|a, b| b.total_cmp(a));
                    if sorted[0] - sorted[1] > 6.0 * step {
                        clear_disagree += 1;
                    }
                }
            }
            let value_error = (float_value.unwrap() - outputs.value_f32().unwrap()).abs();
            assert!(
                value_error < 0.1 * float_value.unwrap().abs().max(1.0),
                "{value_error}"
            );
        }
        let mean_error = sum_error / (total * 3) as f32;
        let mean_abs_logit = logit_spread / (total * 3) as f32;
        let agreement = agree as f32 / total as f32;
        eprintln!(
            "{method:?}: agreement {agreement:.4}, mean |error| {mean_error:.4} \
             (mean |logit| {mean_abs_logit:.3}, step {step:.4}), max {max_error:.4}, \
             clear disagreements {clear_disagree}"
        );
        assert!(
            mean_error < 0.03 * mean_abs_logit,
            "mean error {mean_error}"
        );
        if method == RangeMethod::MinMax {
            // Percentile ranges clip rare outliers on purpose, so only min/max bounds the
            // worst case.
            assert!(
                max_error < 12.0 * step,
                "max error {max_error} vs step {step}"
            );
        }
        assert!(agreement > 0.97, "agreement {agreement}");
        assert_eq!(clear_disagree, 0);
    }
}

#[test]
fn records_and_files_round_trip_through_postcard() {
    let (_, quantized, _) = calibrated(21, RangeMethod::MinMax);
    let bytes = quantized.to_bytes().unwrap();
    // Deterministic bytes.
    assert_eq!(bytes, quantized.to_bytes().unwrap());

    // The envelope decodes with plain postcard and re-encodes to the same bytes.
    let envelope: Envelope<'_> = postcard::from_bytes(&bytes).unwrap();
    assert_eq!(postcard::to_allocvec(&envelope).unwrap(), bytes);
    assert_eq!(
        envelope.payload,
        quantized.payload_bytes().unwrap().as_slice()
    );

    // Single records round trip, tensors borrowed (zero copy) from the encoded bytes.
    let weights = [1u8, 2, 255];
    let record = DenseRecord {
        in_features: 3,
        out_features: 1,
        relu: true,
        output: wheelleg_runtime::model::format::ActQuantRecord {
            scale: 0.5,
            zero_point: -128,
        },
        weights: &weights,
        bias: &[0, 0, 0, 1],
        multipliers: &[0, 0, 0, 0x40],
        shifts: &[0],
    };
    let encoded = postcard::to_allocvec(&record).unwrap();
    let decoded: DenseRecord<'_> = postcard::from_bytes(&encoded).unwrap();
    assert_eq!(decoded, record);
    let range = encoded.as_ptr_range();
    assert!(
        range.contains(&decoded.weights.as_ptr()),
        "tensor is borrowed, not copied"
    );

    // The runtime's decoded model is the quantized network, field for field.
    let model = Model::parse(&bytes).unwrap();
    let input: InputRecord = model.input;
    assert_eq!((input.rows, input.cols), (32, 32));
    assert_eq!(input.height.multiplier, quantized.height.multiplier);
    assert_eq!(model.state.len(), 4);
    for (conv, q) in model.convs.iter().zip(&quantized.convs) {
        let record: ConvRecord<'_> = conv.record;
        let weights: Vec<i8> = record.weights.iter().map(|&b| b as i8).collect();
        assert_eq!(weights, q.layer.weights);
        let bias: Vec<i32> = record
            .bias
            .chunks_exact(4)
            .map(|b| i32::from_le_bytes(b.try_into().unwrap()))
            .collect();
        assert_eq!(bias, q.layer.bias);
        assert_eq!(record.shifts.len(), q.layer.shifts.len());
        assert!(bytes.as_ptr_range().contains(&record.weights.as_ptr()));
    }
    assert_eq!(model.hidden[0].linear.rows, 128);
    assert!(model.value_head.is_some());
}

/// The numbers of docs/model.md, computed.
#[test]
fn default_model_budget() {
    let (network, quantized, _) = calibrated(31, RangeMethod::MinMax);
    let bytes = quantized.to_bytes().unwrap();
    let model = Model::parse(&bytes).unwrap();
    let needs = model.requirements;
    let scratch =
        core::mem::size_of::<Scratch<DEFAULT_ACTIVATION_ELEMENTS, DEFAULT_ROW_ELEMENTS>>();
    eprintln!(
        "parameters {} (float {}), MACs {}, file {} bytes, tensors {} bytes, \
         activations {} elements, row {} elements, minimum RAM {} bytes, DefaultPolicy scratch {} bytes",
        model.parameter_count(),
        network.parameter_count(),
        model.macs(),
        bytes.len(),
        model.tensor_bytes(),
        needs.activation_elements,
        needs.row_elements,
        2 * needs.activation_elements + 2 * needs.row_elements,
        scratch,
    );
    let policy_bytes = core::mem::size_of::<DefaultPolicy<'static>>();
    eprintln!("DefaultPolicy value: {policy_bytes} bytes");
    // A layer table of borrowed slices, not a copy of the tensors.
    assert!(policy_bytes < 4096, "{policy_bytes}");
    assert_eq!(model.parameter_count(), 82_288);
    assert_eq!(network.parameter_count(), 82_288);
    // conv 36,864 + 294,912 + 147,456; dense 66,048; heads 1,920 + 128.
    assert_eq!(model.macs(), 547_328);
    assert_eq!(needs.activation_elements, 4096);
    assert_eq!(needs.row_elements, 516);
    assert_eq!(scratch, 2 * 4096 + 2 * 1024);
    // Tensors: 82,064 int8 weights + 224 rows x (4 bias + 4 multiplier + 1 shift) bytes.
    assert_eq!(model.tensor_bytes(), 82_064 + 224 * 9);
    // Envelope, records and varints add well under 1 KiB.
    assert!(bytes.len() > model.tensor_bytes() && bytes.len() < model.tensor_bytes() + 1024);
}
