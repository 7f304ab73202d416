//! Which single quantization step flips the greedy decisions of a checkpoint: the float network
//! with exactly one step of the int8 scheme applied (inputs rounded to their int8 grid, one
//! layer's weights rounded to per-row int8, the features or the hidden output rounded), against
//! the plain float network, per action dimension, on the held-out observations of
//! `wheelleg export`. Where the remaining int8/float disagreement comes from (docs/results.md).
//!
//! Usage: `quantize_diagnose CKPT`.
// A measuring tool: failing loudly is its whole error handling; the closures read best inline.
#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    clippy::indexing_slicing,
    clippy::type_complexity
)]

use wheelleg_trainer::batch_policy::FloatPolicy;
use wheelleg_trainer::checkpoint::Checkpoint;
use wheelleg_trainer::export::{rollout_observations, ExportOptions};
use wheelleg_trainer::network::BackendKind;
use wheelleg_trainer::network_f32::NetworkF32;
use wheelleg_trainer::quantize::params::quantize_rows;
use wheelleg_trainer::quantize::{ActQuant, Calibration, RangeMethod};

fn argmax(v: &[f32]) -> usize {
    let mut best = 0;
    for (i, &x) in v.iter().enumerate() {
        if x > v[best] {
            best = i;
        }
    }
    best
}

fn round(q: ActQuant, x: f32) -> f32 {
    q.dequantize(q.quantize(x))
}

fn fake_rows(weights: &mut [f32], row_len: usize) {
    let (q, scales) = quantize_rows(weights, row_len);
    for (row, (qs, s)) in weights
        .chunks_exact_mut(row_len)
        .zip(q.chunks_exact(row_len).zip(&scales))
    {
        for (w, &qw) in row.iter_mut().zip(qs) {
            *w = f32::from(qw) * s;
        }
    }
}

fn main() {
    let path = std::env::args().nth(1).unwrap();
    let checkpoint = Checkpoint::load(std::path::Path::new(&path)).unwrap();
    let network = checkpoint.network.to_network().unwrap();
    let device = BackendKind::Flex.device().unwrap();
    let float = FloatPolicy::new(&network, &device).unwrap();
    let options = ExportOptions::default();
    let calib = rollout_observations(
        &float,
        &options.robot,
        options.scene_kind,
        options.seed,
        20_000,
    )
    .unwrap();
    let holdout = rollout_observations(
        &float,
        &options.robot,
        options.scene_kind,
        options.seed + 1,
        10_000,
    )
    .unwrap();
    let calibration = Calibration::from_observations(
        &network,
        calib.iter().map(|(h, s)| (h.as_slice(), s.as_slice())),
    );
    let m = RangeMethod::MinMax;
    let aq = |o: &wheelleg_trainer::quantize::RangeObserver| {
        let (l, h) = o.range(m);
        ActQuant::from_range(l, h)
    };
    let state_q: Vec<ActQuant> = calibration.state.iter().map(aq).collect();
    let height_q = aq(&calibration.height);
    let conv_q: Vec<ActQuant> = calibration.convs.iter().map(aq).collect();
    let hidden_q: Vec<ActQuant> = calibration.hidden.iter().map(aq).collect();
    println!("state scales {:?}", state_q);
    println!(
        "height {:?} convs {:?} hidden {:?}",
        height_q, conv_q, hidden_q
    );

    let mut variants: Vec<(String, NetworkF32)> = Vec::new();
    for i in 0..network.convs.len() {
        let mut n = network.clone();
        let row = n.convs[i].weights.len() / n.convs[i].spec.out_channels;
        fake_rows(&mut n.convs[i].weights, row);
        variants.push((format!("conv{i} weights"), n));
    }
    for i in 0..network.hidden.len() {
        let mut n = network.clone();
        let row = n.hidden[i].in_features;
        fake_rows(&mut n.hidden[i].weights, row);
        variants.push((format!("hidden{i} weights"), n));
    }
    {
        let mut n = network.clone();
        let row = n.action_head.in_features;
        fake_rows(&mut n.action_head.weights, row);
        variants.push(("head weights".into(), n));
    }
    {
        // Every layer's weights at once (activations and inputs float): how much of the int8
        // network's disagreement the weights alone explain.
        let mut n = network.clone();
        for conv in &mut n.convs {
            let row = conv.weights.len() / conv.spec.out_channels;
            fake_rows(&mut conv.weights, row);
        }
        for layer in n.hidden.iter_mut().chain([&mut n.action_head]) {
            let row = layer.in_features;
            fake_rows(&mut layer.weights, row);
        }
        variants.push(("all weights".into(), n));
    }
    let report = |name: &str, f: &dyn Fn(&[f32], &[f32]) -> Vec<f32>| {
        let mut same = [0usize; 5];
        for (h, s) in &holdout {
            let (reference, _) = network.forward(h, s);
            let other = f(h, s);
            for d in 0..5 {
                if argmax(&reference[3 * d..3 * d + 3]) == argmax(&other[3 * d..3 * d + 3]) {
                    same[d] += 1;
                }
            }
        }
        let n = holdout.len() as f32;
        println!(
            "{name:<24} {:?}",
            same.map(|x| (x as f32 / n * 10000.0).round() / 100.0)
        );
    };
    report("state rounding", &|h, s| {
        let s: Vec<f32> = s
            .iter()
            .zip(&state_q)
            .map(|(&x, &q)| round(q, (x * 1000.0).round() / 1000.0))
            .collect();
        network.forward(h, &s).0
    });
    // Version 2: the same grid 256 times finer (int16 state), after the millimetre rounding.
    report("state rounding 16 bits", &|h, s| {
        let s: Vec<f32> = s
            .iter()
            .zip(&state_q)
            .map(|(&x, &q)| {
                let step = q.scale / 256.0;
                ((x * 1000.0).round() / 1000.0 / step).round() * step
            })
            .collect();
        network.forward(h, &s).0
    });
    report("state mm rounding only", &|h, s| {
        let s: Vec<f32> = s.iter().map(|&x| (x * 1000.0).round() / 1000.0).collect();
        network.forward(h, &s).0
    });
    report("height rounding", &|h, s| {
        let h: Vec<f32> = h
            .iter()
            .map(|&x| round(height_q, (x * 1000.0).round() / 1000.0))
            .collect();
        network.forward(&h, s).0
    });
    for (name, n) in &variants {
        report(name, &|h, s| n.forward(h, s).0);
    }
    report("features rounding", &|h, s| {
        let t = network.trace(h, s);
        let mut x: Vec<f32> = t
            .convs
            .last()
            .unwrap()
            .iter()
            .map(|&v| round(*conv_q.last().unwrap(), v))
            .collect();
        x.extend_from_slice(s);
        for layer in &network.hidden {
            x = layer.forward(&x, true);
        }
        network.action_head.forward(&x, false)
    });
    report("hidden out rounding", &|h, s| {
        let t = network.trace(h, s);
        let x: Vec<f32> = t
            .hidden
            .last()
            .unwrap()
            .iter()
            .map(|&v| round(*hidden_q.last().unwrap(), v))
            .collect();
        network.action_head.forward(&x, false)
    });
}
