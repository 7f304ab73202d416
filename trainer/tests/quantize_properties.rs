//! Property tests of the trainer's int8 arithmetic (trainer/src/quantize/params.rs) and of the
//! postcard round trip of checkpoints: the bounds the int8 runtime and a resumed run rely on,
//! over whole input ranges (docs/robustness.md).

use proptest::prelude::*;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::model::quant::{requantize, MAX_SHIFT, MIN_SHIFT};
use wheelleg_trainer::checkpoint::{Checkpoint, NetworkRecord};
use wheelleg_trainer::network_f32::{Architecture, ConvSpec, NetworkF32};
use wheelleg_trainer::ppo::Adam;
use wheelleg_trainer::quantize::params::{quantize_multiplier, quantize_rows, ActQuant};
use wheelleg_trainer::vec_env::EnvSnapshot;

/// A range as calibration produces them: finite, possibly one-sided, possibly degenerate.
fn range() -> impl Strategy<Value = (f32, f32)> {
    prop_oneof![
        (-1e4f32..1e4, -1e4f32..1e4),
        (-1e-3f32..1e-3, -1e-3f32..1e-3),
        (0.0f32..100.0).prop_map(|h| (0.0, h)),
        Just((0.0, 0.0)),
    ]
    .prop_map(|(a, b)| (a.min(b), a.max(b)))
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(8192))]

    /// The activation scheme: a positive scale, real 0 exactly representable (padding and the
    /// ReLU floor depend on it), every value of the range within half a step after a round trip,
    /// and values outside it clamped to the ends.
    #[test]
    fn activation_quantization_is_bounded((low, high) in range(), t in 0.0f32..=1.0,
                                          outside in 1.0f32..1e6) {
        let q = ActQuant::from_range(low, high);
        prop_assert!(q.scale > 0.0 && q.scale.is_finite());
        prop_assert_eq!(q.dequantize(q.zero_point), 0.0);
        prop_assert_eq!(q.quantize(0.0), q.zero_point);
        let (lo, hi) = (low.min(0.0), high.max(0.0));
        let x = lo + t * (hi - lo);
        let back = q.dequantize(q.quantize(x));
        // Half a step, plus f32 rounding of the scale and of x itself.
        let slack = 0.5 * q.scale * (1.0 + 1e-3) + 1e-6 * x.abs();
        prop_assert!((back - x).abs() <= slack, "[{lo}, {hi}] scale {}: {x} -> {back}", q.scale);
        if hi - lo > f32::EPSILON {
            prop_assert_eq!(q.quantize(hi + outside * (hi - lo)), 127);
            prop_assert_eq!(q.quantize(lo - outside * (hi - lo)), -128);
        }
    }

    /// Every multiplier the runtime can represent comes back to within 2^-30 relative; the
    /// fixed-point pair is normalised; and the runtime's `requantize` with it multiplies by the
    /// real value to within one unit.
    #[test]
    fn multipliers_are_normalised_and_accurate(exponent in -31i32..30, fraction in 0.5f64..1.0,
                                               value in -1_000_000i32..1_000_000) {
        let real = fraction * 2f64.powi(exponent);
        let (m, shift) = quantize_multiplier(real).unwrap();
        prop_assert!((MIN_SHIFT..=MAX_SHIFT).contains(&shift), "{real}: shift {shift}");
        if m != 0 {
            prop_assert!((1 << 30..=i32::MAX).contains(&m), "{real}: {m}");
            let back = f64::from(m) * 2f64.powi(i32::from(shift) - 31);
            prop_assert!((back - real).abs() <= real * 2f64.powi(-30), "{real} -> {back}");
            let got = requantize(value, m, shift) as f64;
            let want = f64::from(value) * real;
            prop_assert!((got - want).abs() <= 0.5 + want.abs() * 2f64.powi(-29) + 1e-9,
                "{value} * {real}: {got} vs {want}");
        }
    }

    /// Negative, non-finite and too large multipliers are refused, not wrapped.
    #[test]
    fn unrepresentable_multipliers_are_refused(big in 2f64.powi(31)..1e300) {
        prop_assert!(quantize_multiplier(big).is_err());
        prop_assert!(quantize_multiplier(-big).is_err());
        prop_assert!(quantize_multiplier(f64::NAN).is_err());
        prop_assert!(quantize_multiplier(f64::INFINITY).is_err());
    }

    /// Per-row symmetric weights: every int8 within [-127, 127], every weight within half a
    /// step of its row's scale, and each row's largest weight mapped to ±127.
    #[test]
    fn weight_rows_are_bounded(row_len in 1usize..12, rows in 1usize..6,
                               seed in any::<u64>(), magnitude in 1e-6f32..1e3) {
        let mut rng = ChaCha8Rng::seed_from_u64(seed);
        let weights: Vec<f32> = (0..row_len * rows)
            .map(|_| magnitude * (rand::Rng::random::<f32>(&mut rng) * 2.0 - 1.0))
            .collect();
        let (q, scales) = quantize_rows(&weights, row_len);
        prop_assert_eq!(q.len(), weights.len());
        prop_assert_eq!(scales.len(), rows);
        for ((row_q, row_w), &scale) in q.chunks(row_len).zip(weights.chunks(row_len)).zip(&scales) {
            prop_assert!(scale > 0.0);
            for (&qi, &w) in row_q.iter().zip(row_w) {
                prop_assert!((-127..=127).contains(&qi));
                // Half a step, plus the f32 rounding of the product and of the difference:
                // a few units in the last place of |w| (at |w| ~ 9, an ulp is 1e-6, more than
                // the relative slack of the step alone).
                let slack = 0.5 * scale * (1.0 + 1e-5) + 2.0 * f32::EPSILON * w.abs() + 1e-12;
                prop_assert!((f32::from(qi) * scale - w).abs() <= slack,
                    "w {w}, q {qi}, scale {scale}");
            }
            let max = row_w.iter().fold(0.0f32, |m, w| m.max(w.abs()));
            if max > 0.0 {
                prop_assert_eq!(row_q.iter().map(|q| q.unsigned_abs()).max(), Some(127));
            }
        }
    }
}

/// A small architecture of the supported family, chosen by the strategy's numbers.
fn architecture() -> impl Strategy<Value = Architecture> {
    (
        3usize..8,
        3usize..8,
        0usize..5,
        0usize..3,
        prop::collection::vec(1usize..10, 0..3),
        any::<bool>(),
    )
        .prop_map(|(rows, cols, state_len, convs, hidden, value_head)| {
            let mut c = 1;
            let convs = (0..convs)
                .map(|i| {
                    let spec = ConvSpec {
                        in_channels: c,
                        out_channels: 2 + i,
                        kernel: 2,
                        stride: 1,
                        padding: 0,
                    };
                    c = spec.out_channels;
                    spec
                })
                .collect();
            Architecture {
                height_rows: rows,
                height_cols: cols,
                state_len,
                convs,
                hidden,
                value_head,
            }
        })
}

proptest! {
    #![proptest_config(ProptestConfig::with_cases(256))]

    /// A checkpoint writes to bytes and reads back equal, whatever its network, optimizer
    /// state, environments and counters; and any single flipped byte is refused, not read as
    /// a different checkpoint.
    #[test]
    fn checkpoints_round_trip_through_postcard(arch in architecture(), seed in any::<u64>(),
                                               counters in any::<(u64, u64, u128)>(),
                                               actions in prop::collection::vec(any::<u8>(), 0..40),
                                               text in ".{0,40}", flip in any::<prop::sample::Index>()) {
        let network = NetworkF32::random(&arch, &mut ChaCha8Rng::seed_from_u64(seed));
        let mut adam = Adam::new(&network);
        adam.step = counters.0;
        let checkpoint = Checkpoint {
            kind: text.clone(),
            config_toml: format!("# {text}\n"),
            seed,
            iteration: counters.0,
            env_steps: counters.1,
            network: NetworkRecord::from_network(&network),
            adam,
            sampler_word_pos: counters.2,
            envs: vec![EnvSnapshot {
                scene_rng_word_pos: counters.2,
                scenario_json: text,
                actions,
                episodes_started: counters.1,
            }],
            elapsed_s: counters.0 as f64 * 0.25,
        };
        let bytes = checkpoint.to_bytes().unwrap();
        let back = Checkpoint::from_bytes(&bytes).unwrap();
        prop_assert_eq!(&back, &checkpoint);
        prop_assert_eq!(back.network.to_network().unwrap(), network);
        let mut damaged = bytes.clone();
        let at = flip.index(damaged.len());
        damaged[at] ^= 0x5A;
        prop_assert!(Checkpoint::from_bytes(&damaged).is_err(), "flip at {at} accepted");
    }
}
