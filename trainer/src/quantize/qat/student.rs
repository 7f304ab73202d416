//! The student's fake-quantized forward pass: its weights as the int8 file holds them, every
//! activation rounded to its grid (straight-through), and the gradients back to its parameters.

use super::*;

/// The quantization parameters the fake-quantized forward pass uses, and the student's
/// weights as the int8 file will hold them.
pub(super) struct FakeQuant {
    /// The student dequantized: what the int8 network multiplies with.
    pub(super) effective: NetworkF32,
    /// Each conv output's int8 quantization.
    pub(super) convs: Vec<ActQuant>,
    /// Each hidden output's int8 quantization.
    pub(super) hidden: Vec<ActQuant>,
    /// The action logits' quantization and their integer range.
    pub(super) action: (ActQuant, f32, f32),
}

/// Dequantizes `quantized` (of `network`'s architecture) back into float weights and biases:
/// the float network that the int8 file computes, up to the rounding of its activations. The
/// layer that reads the flattened features ++ state has its state columns unfolded, and its
/// bias carries the folding's rounding (see [`QuantizedNetwork`] and `build::fold_state`): with
/// folded int8 weights `q` (row scale `s_o`), the runtime adds `sum_j q_j s_o s_x (zp_j -
/// zp_x)` where the float network had `sum_j W_j t_j (zp_j - zp_x)`.
pub fn dequantize(network: &NetworkF32, quantized: &QuantizedNetwork) -> NetworkF32 {
    let mut out = network.clone();
    for (conv, q) in out.convs.iter_mut().zip(&quantized.convs) {
        let spec = conv.spec;
        let k = spec.kernel;
        let cin = spec.in_channels;
        let layer = &q.layer;
        for o in 0..spec.out_channels {
            let scale = layer.weight_scales[o];
            for ky in 0..k {
                for kx in 0..k {
                    for i in 0..cin {
                        // File: OHWI; float network: OIHW.
                        let stored = layer.weights[((o * k + ky) * k + kx) * cin + i];
                        conv.weights[((o * cin + i) * k + ky) * k + kx] = f32::from(stored) * scale;
                    }
                }
            }
        }
        conv.bias = bias_real(layer);
    }
    let features_len = network.arch.features_len();
    let fold = |dense: &mut DenseF32, layer: &QuantizedLayer, folded: bool| {
        let mut bias = bias_real(layer);
        for (o, row) in dense
            .weights
            .chunks_exact_mut(dense.in_features)
            .enumerate()
        {
            let scale = layer.weight_scales[o];
            let stored = &layer.weights[o * dense.in_features..(o + 1) * dense.in_features];
            for (w, &q) in row.iter_mut().zip(stored) {
                *w = f32::from(q) * scale;
            }
            if folded {
                let s_x = quantized.features.scale;
                let zp_x = f32::from(quantized.features.zero_point);
                for (j, state) in quantized.state.iter().enumerate() {
                    let column = features_len + j;
                    let (t, zp) = (state.act.scale, f32::from(state.act.zero_point));
                    bias[o] += row[column] * s_x * (zp - zp_x);
                    row[column] *= s_x / t;
                }
            }
        }
        dense.bias = bias;
    };
    let no_hidden = out.hidden.is_empty();
    for (index, (dense, q)) in out.hidden.iter_mut().zip(&quantized.hidden).enumerate() {
        fold(dense, &q.layer, index == 0);
    }
    fold(
        &mut out.action_head,
        &quantized.action_head.layer,
        no_hidden,
    );
    if let (Some(head), Some(q)) = (&mut out.value_head, &quantized.value_head) {
        fold(head, &q.layer, no_hidden);
    }
    out
}

/// A layer's int32 biases in real units (input scale x weight scale per row).
pub(super) fn bias_real(layer: &QuantizedLayer) -> Vec<f32> {
    layer
        .bias
        .iter()
        .zip(&layer.weight_scales)
        .map(|(&b, &s)| (f64::from(b) * f64::from(layer.input.scale) * f64::from(s)) as f32)
        .collect()
}

/// Observations as the int8 network sees them: heights on their int8 grid and state features
/// on theirs (int16 in version 2), in real units, with the runtime's own integer functions.
pub(super) fn quantized_inputs(
    quantized: &QuantizedNetwork,
    height_m: &[f32],
    state: &[f32],
    heights_out: &mut Vec<f32>,
    states_out: &mut Vec<f32>,
) {
    let h = &quantized.height;
    heights_out.extend(height_m.iter().map(|&m| {
        // The runtime's millimetres: rounded, saturated to i16 (`Policy::evaluate_m`).
        let mm = i32::from((m * 1000.0).round() as i16);
        let q = quantize_mm(mm, h.multiplier, h.shift, h.act.zero_point);
        h.act.scale * (f32::from(q) - f32::from(h.act.zero_point))
    }));
    states_out.extend(quantized.state.iter().zip(state).map(|(s, &m)| {
        let mm = (m * 1000.0).round() as i32;
        if s.fraction_bits == 0 {
            let q = quantize_mm(mm, s.multiplier, s.shift, s.act.zero_point);
            s.act.scale * (f32::from(q) - f32::from(s.act.zero_point))
        } else {
            let u = quantize_mm16(mm, s.multiplier, s.shift, s.act.zero_point);
            let steps = f32::from(1u16 << s.fraction_bits);
            s.act.scale * (f32::from(u) - f32::from(s.act.zero_point) * steps) / steps
        }
    }));
}

/// Parameters of one layer on the graph: the student's leaf (which gets the gradient) plus the
/// constant rounding error of its int8 version.
pub(super) struct Param<const D: usize> {
    pub(super) leaf: Tensor<D>,
    pub(super) used: Tensor<D>,
}

pub(super) fn param<const D: usize>(
    float: &[f32],
    effective: &[f32],
    shape: [usize; D],
    device: &Device,
) -> Param<D> {
    let leaf =
        Tensor::<D>::from_data(TensorData::new(float.to_vec(), shape), device).require_grad();
    let delta: Vec<f32> = effective.iter().zip(float).map(|(e, f)| e - f).collect();
    // Straight-through: forward uses the dequantized value, backward sees the identity.
    let delta = Tensor::<D>::from_data(TensorData::new(delta, shape), device);
    Param {
        used: leaf.clone() + delta,
        leaf,
    }
}

/// `x` rounded to the grid of `q` and clamped to `[low, high]` integers, straight-through.
pub(super) fn fake_quant<const D: usize>(
    x: Tensor<D>,
    q: ActQuant,
    low: f32,
    high: f32,
) -> Tensor<D> {
    let zp = f32::from(q.zero_point);
    let detached = x.clone().detach();
    let rounded = detached
        .clone()
        .div_scalar(q.scale)
        .round()
        .add_scalar(zp)
        .clamp(low, high)
        .sub_scalar(zp)
        .mul_scalar(q.scale);
    x + (rounded - detached)
}

/// The graph's parameters in [`network::parameters`] order, with the action head's logits.
pub(super) struct Graph {
    pub(super) leaves: Vec<Tensor<2>>,
    pub(super) conv_leaves: Vec<Tensor<4>>,
    pub(super) biases: Vec<Tensor<1>>,
    pub(super) logits: Tensor<2>,
}

/// The fake-quantized forward pass of `student` on a batch of quantized inputs.
pub(super) fn student_logits(
    student: &NetworkF32,
    fq: &FakeQuant,
    heights: Vec<f32>,
    states: Vec<f32>,
    batch: usize,
    device: &Device,
) -> Graph {
    let arch = &student.arch;
    let mut conv_leaves = Vec::new();
    let mut leaves = Vec::new();
    let mut biases = Vec::new();
    let mut x: Tensor<4> = Tensor::from_data(
        TensorData::new(heights, [batch, 1, arch.height_rows, arch.height_cols]),
        device,
    );
    for ((conv, eff), q) in student.convs.iter().zip(&fq.effective.convs).zip(&fq.convs) {
        let s = conv.spec;
        let shape = [s.out_channels, s.in_channels, s.kernel, s.kernel];
        let w = param(&conv.weights, &eff.weights, shape, device);
        let b = param(&conv.bias, &eff.bias, [s.out_channels], device);
        let options = ConvOptions::new([s.stride, s.stride], [s.padding, s.padding], [1, 1], 1);
        let y = relu(conv2d(x, w.used, Some(b.used), options));
        x = fake_quant(y, *q, f32::from(q.zero_point), 127.0);
        conv_leaves.push(w.leaf);
        biases.push(b.leaf);
    }
    let features: Tensor<2> = x.reshape([batch, arch.features_len()]);
    let state: Tensor<2> =
        Tensor::from_data(TensorData::new(states, [batch, arch.state_len]), device);
    let mut h = Tensor::cat(vec![features, state], 1);
    let mut dense = |h: Tensor<2>, layer: &DenseF32, eff: &DenseF32| {
        let w = param(
            &layer.weights,
            &eff.weights,
            [layer.out_features, layer.in_features],
            device,
        );
        let b = param(&layer.bias, &eff.bias, [layer.out_features], device);
        let y = h.matmul(w.used.transpose()) + b.used.unsqueeze::<2>();
        leaves.push(w.leaf);
        biases.push(b.leaf);
        y
    };
    for ((layer, eff), q) in student
        .hidden
        .iter()
        .zip(&fq.effective.hidden)
        .zip(&fq.hidden)
    {
        h = fake_quant(
            relu(dense(h, layer, eff)),
            *q,
            f32::from(q.zero_point),
            127.0,
        );
    }
    let logits = dense(h, &student.action_head, &fq.effective.action_head);
    let (q, low, high) = fq.action;
    Graph {
        leaves,
        conv_leaves,
        biases,
        logits: fake_quant(logits, q, low, high),
    }
}

/// Gradients in [`network::parameters`] order (conv w, b, dense w, b, ...; the value head, not
/// on the graph, gets zeros).
pub(super) fn gradients(student: &NetworkF32, graph: &Graph, grads: &Gradients) -> Vec<Vec<f32>> {
    fn grad<const D: usize>(t: &Tensor<D>, grads: &Gradients, len: usize) -> Vec<f32> {
        t.grad(grads)
            .map(to_vec)
            .filter(|g| g.len() == len)
            .unwrap_or_else(|| vec![0.0; len])
    }
    let mut out = Vec::new();
    let mut bias = graph.biases.iter();
    for (conv, leaf) in student.convs.iter().zip(&graph.conv_leaves) {
        out.push(grad(leaf, grads, conv.weights.len()));
        out.push(
            bias.next()
                .map(|b| grad(b, grads, conv.bias.len()))
                .unwrap_or_else(|| vec![0.0; conv.bias.len()]),
        );
    }
    let mut leaves = graph.leaves.iter();
    for layer in student.dense_layers() {
        match (leaves.next(), bias.next()) {
            (Some(w), Some(b)) => {
                out.push(grad(w, grads, layer.weights.len()));
                out.push(grad(b, grads, layer.bias.len()));
            }
            _ => {
                out.push(vec![0.0; layer.weights.len()]);
                out.push(vec![0.0; layer.bias.len()]);
            }
        }
    }
    out
}
