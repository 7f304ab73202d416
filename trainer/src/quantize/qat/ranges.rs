//! The student's activation ranges and the teacher's targets, on burn's batched forward pass.

use super::*;

/// Observations evaluated per burn forward pass when calibrating or taking teacher targets.
pub(super) const CHUNK: usize = 512;

/// [`Calibration::from_observations`] on burn's batched forward pass: the same observers fed
/// the same tensors in the same order, many times faster than the plain f32 reference (used
/// for the recalibrations during fine-tuning; the export calibrates with the reference).
pub(super) fn calibrate_batched(
    network: &NetworkF32,
    device: &Device,
    observations: &[RecordedObservation],
    action_range: ActionRange,
) -> Result<Calibration, TrainError> {
    let mut calibration = Calibration::new(network);
    calibration.action_range = action_range;
    for chunk in observations.chunks(CHUNK) {
        let (heights, states) = flatten(chunk);
        let trace = batch_trace(network, device, heights, states, chunk.len());
        let conv_len: Vec<usize> = trace.convs.iter().map(|c| c.len() / chunk.len()).collect();
        let hidden_len: Vec<usize> = trace.hidden.iter().map(|h| h.len() / chunk.len()).collect();
        let logits = trace.logits.len() / chunk.len();
        for (i, (height_m, state)) in chunk.iter().enumerate() {
            calibration.observe(&Trace {
                height_m: height_m.clone(),
                state: state.clone(),
                convs: trace
                    .convs
                    .iter()
                    .zip(&conv_len)
                    .map(|(c, &n)| c[i * n..(i + 1) * n].to_vec())
                    .collect(),
                hidden: trace
                    .hidden
                    .iter()
                    .zip(&hidden_len)
                    .map(|(h, &n)| h[i * n..(i + 1) * n].to_vec())
                    .collect(),
                action_logits: trace.logits[i * logits..(i + 1) * logits].to_vec(),
                value: trace.values.get(i).copied(),
            });
        }
    }
    Ok(calibration)
}

/// Every intermediate tensor of a batched float forward pass, each flattened batch-major.
pub(super) struct BatchTrace {
    pub(super) convs: Vec<Vec<f32>>,
    pub(super) hidden: Vec<Vec<f32>>,
    pub(super) logits: Vec<f32>,
    pub(super) values: Vec<f32>,
}

/// The plain float forward pass of `network` on burn, keeping what calibration observes.
pub(super) fn batch_trace(
    network: &NetworkF32,
    device: &Device,
    heights: Vec<f32>,
    states: Vec<f32>,
    batch: usize,
) -> BatchTrace {
    let arch = &network.arch;
    let mut x: Tensor<4> = Tensor::from_data(
        TensorData::new(heights, [batch, 1, arch.height_rows, arch.height_cols]),
        device,
    );
    let mut convs = Vec::with_capacity(network.convs.len());
    for conv in &network.convs {
        let s = conv.spec;
        let w: Tensor<4> = Tensor::from_data(
            TensorData::new(
                conv.weights.clone(),
                [s.out_channels, s.in_channels, s.kernel, s.kernel],
            ),
            device,
        );
        let options = ConvOptions::new([s.stride, s.stride], [s.padding, s.padding], [1, 1], 1);
        let b: Tensor<1> =
            Tensor::from_data(TensorData::new(conv.bias.clone(), [s.out_channels]), device);
        x = relu(conv2d(x, w, Some(b), options));
        convs.push(to_vec(x.clone()));
    }
    let features: Tensor<2> = x.reshape([batch, arch.features_len()]);
    let state: Tensor<2> =
        Tensor::from_data(TensorData::new(states, [batch, arch.state_len]), device);
    let mut h = Tensor::cat(vec![features, state], 1);
    let dense = |h: Tensor<2>, layer: &DenseF32| {
        let w: Tensor<2> = Tensor::from_data(
            TensorData::new(
                layer.weights.clone(),
                [layer.out_features, layer.in_features],
            ),
            device,
        );
        let b: Tensor<1> = Tensor::from_data(
            TensorData::new(layer.bias.clone(), [layer.out_features]),
            device,
        );
        h.matmul(w.transpose()) + b.unsqueeze::<2>()
    };
    let mut hidden = Vec::with_capacity(network.hidden.len());
    for layer in &network.hidden {
        h = relu(dense(h, layer));
        hidden.push(to_vec(h.clone()));
    }
    let logits = to_vec(dense(h.clone(), &network.action_head));
    let values = network
        .value_head
        .as_ref()
        .map(|head| to_vec(dense(h, head)))
        .unwrap_or_default();
    BatchTrace {
        convs,
        hidden,
        logits,
        values,
    }
}

pub(super) fn flatten(observations: &[RecordedObservation]) -> (Vec<f32>, Vec<f32>) {
    let mut heights = Vec::new();
    let mut states = Vec::new();
    for (h, s) in observations {
        heights.extend_from_slice(h);
        states.extend_from_slice(s);
    }
    (heights, states)
}

/// The parameters of the fake-quantized forward pass for `student`: quantized by the
/// exporter's [`quantize_for_version`] with `calibration`'s ranges.
pub(super) fn fake_quant_params(
    student: &NetworkF32,
    calibration: &Calibration,
    method: RangeMethod,
    version: u16,
) -> Result<(FakeQuant, QuantizedNetwork), TrainError> {
    let quantized = quantize_for_version(student, calibration, method, version)
        .map_err(|e| TrainError::stage("QAT: quantize the student", e))?;
    let action_output = quantized.action_head.layer.output;
    let action = if version >= 2 {
        (action_output, f32::from(i16::MIN), f32::from(i16::MAX))
    } else {
        (action_output, -128.0, 127.0)
    };
    let fq = FakeQuant {
        effective: dequantize(student, &quantized),
        convs: quantized.convs.iter().map(|c| c.layer.output).collect(),
        hidden: quantized.hidden.iter().map(|d| d.layer.output).collect(),
        action,
    };
    Ok((fq, quantized))
}
