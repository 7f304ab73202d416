use super::*;
use crate::network::{init_policy, BackendKind};
use crate::network_f32::Architecture;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;

/// How far (in units of the learning rate) the native-kernel and burn-conv updates may
/// move a parameter differently. The gradients agree to ~1e-6 relative (conv_kernel
/// tests); what remains is mostly the f32 rounding of the parameters themselves (|p| ~ 0.5
/// rounds at 3e-8, i.e. 3e-5 lr at lr 1e-3). Measured: at most 7e-5 lr over three steps; a
/// wrong gradient moves parameters order 1 lr apart (Adam's first steps are ~lr * sign).
const UPDATE_TOLERANCE_LR: f32 = 1e-3;

#[test]
fn global_norm_clipping_scales_jointly() {
    let mut g = vec![vec![3.0], vec![4.0]];
    assert_eq!(clip_global_norm(&mut g, 1.0), 5.0);
    assert!((g[0][0] - 0.6).abs() < 1e-5 && (g[1][0] - 0.8).abs() < 1e-5);
}

#[test]
fn sampling_follows_the_probabilities_and_greedy_takes_the_mode() {
    let lp = |p: [f32; 3]| p.map(f32::ln);
    let mut log_probs = Vec::new();
    for _ in 0..DIMS {
        log_probs.extend(lp([0.1, 0.2, 0.7]));
    }
    let out = PolicyOutput {
        log_probs,
        values: vec![0.0],
    };
    assert_eq!(out.greedy(0), [2; DIMS]);
    let mut rng = ChaCha8Rng::seed_from_u64(1);
    let draws = 5000;
    let twos = (0..draws)
        .filter(|_| out.sample(0, &mut rng)[0] == 2)
        .count();
    assert!((twos as f32 / draws as f32 - 0.7).abs() < 0.03);
}

/// Runs one update on 32 random observations that all took the action "every head
/// chooses 2", with the given advantages and imitation weights; returns how many of them
/// made that action more probable, and the update's gradient steps.
fn samples_gaining(advantage: impl Fn(usize) -> f32, imitation: f32) -> (usize, usize) {
    let arch = Architecture::default_policy();
    let net = init_policy(&arch, &mut ChaCha8Rng::seed_from_u64(2));
    let config = PpoConfig {
        epochs: 8,
        minibatch_size: 16,
        target_kl: 0.0,
        learning_rate: 1e-3,
        normalize_advantages: false,
        ..PpoConfig::default()
    };
    let mut ppo = Ppo::new(net, config, BackendKind::Flex.device().unwrap()).unwrap();
    let n = 32;
    let mut rng = ChaCha8Rng::seed_from_u64(5);
    let heights: Vec<f32> = (0..n * HEIGHT_MAP_CELLS)
        .map(|_| rng.random_range(0.0..0.1))
        .collect();
    let states: Vec<f32> = (0..n * STATE_LEN)
        .map(|_| rng.random_range(-1.0..1.0))
        .collect();
    let before = ppo.evaluate(&heights, &states, n).unwrap();
    let actions = vec![2u8; n * DIMS];
    let old: Vec<f32> = (0..n)
        .map(|i| before.action_log_prob(i, &actions[i * DIMS..]))
        .collect();
    let batch = Batch {
        heights_m: heights.clone(),
        states: states.clone(),
        actions: actions.clone(),
        old_log_probs: old.clone(),
        advantages: (0..n).map(advantage).collect(),
        returns: vec![1.0; n],
        imitation: vec![imitation; n],
    };
    let stats = ppo.update(&batch, &mut rng).unwrap();
    let after = ppo.evaluate(&heights, &states, n).unwrap();
    let gained = (0..n)
        .filter(|&i| after.action_log_prob(i, &actions[i * DIMS..]) > old[i])
        .count();
    (gained, stats.gradient_steps)
}

/// A random rollout batch of `n` samples.
fn random_batch(n: usize, rng: &mut ChaCha8Rng) -> Batch {
    Batch {
        heights_m: (0..n * HEIGHT_MAP_CELLS)
            .map(|_| rng.random_range(0.0..0.3))
            .collect(),
        states: (0..n * STATE_LEN)
            .map(|_| rng.random_range(-1.0..1.0))
            .collect(),
        actions: (0..n * DIMS).map(|_| rng.random_range(0..3u8)).collect(),
        old_log_probs: (0..n).map(|_| rng.random_range(-6.0..-5.0)).collect(),
        advantages: (0..n).map(|_| rng.random_range(-1.0..1.0)).collect(),
        returns: (0..n).map(|_| rng.random_range(-1.0..1.0)).collect(),
        imitation: (0..n).map(|i| if i % 3 == 0 { 0.5 } else { 0.0 }).collect(),
    }
}

#[test]
fn native_and_burn_conv_kernels_give_the_same_minibatch_steps() {
    let arch = Architecture::default_policy();
    let net = init_policy(&arch, &mut ChaCha8Rng::seed_from_u64(21));
    let mut rng = ChaCha8Rng::seed_from_u64(22);
    let batch = random_batch(80, &mut rng);
    // An odd minibatch (not a multiple of the kernel's chunk) in shuffled order.
    let mut idx: Vec<usize> = (0..80).collect();
    idx.shuffle(&mut rng);
    idx.truncate(67);
    let learner = |kernel: &str| {
        let config = PpoConfig {
            conv_kernel: kernel.into(),
            learning_rate: 1e-3,
            ..PpoConfig::default()
        };
        Ppo::new(net.clone(), config, BackendKind::Flex.device().unwrap()).unwrap()
    };
    let (mut native, mut burn) = (learner("native"), learner("burn"));
    let lr = native.config.learning_rate as f32;
    for step in 0..3 {
        let a = native.minibatch_step(&batch, &idx).unwrap();
        let b = burn.minibatch_step(&batch, &idx).unwrap();
        for (x, y) in [
            (a.policy_loss, b.policy_loss),
            (a.value_loss, b.value_loss),
            (a.entropy, b.entropy),
        ] {
            assert!(
                (x - y).abs() <= 1e-5 * (1.0 + y.abs()),
                "step {step}: {x} vs {y}"
            );
        }
        let p_native = network::parameters(&native.net);
        let p_burn = network::parameters(&burn.net);
        let p_start = network::parameters(&net);
        for (t, ((n, b), s)) in p_native.iter().zip(&p_burn).zip(&p_start).enumerate() {
            // Each Adam step moves a parameter by at most ~lr whatever the gradient's
            // size, so the two paths' moves are compared in units of lr.
            let worst = n
                .iter()
                .zip(*b)
                .zip(*s)
                .map(|((n, b), s)| ((n - s) - (b - s)).abs() / lr)
                .fold(0.0f32, f32::max);
            assert!(
                worst < UPDATE_TOLERANCE_LR,
                "step {step}, tensor {t}: {worst} lr apart"
            );
        }
    }
}

#[test]
fn native_and_burn_conv_kernels_evaluate_alike() {
    let arch = Architecture::default_policy();
    let net = init_policy(&arch, &mut ChaCha8Rng::seed_from_u64(23));
    let batch = random_batch(45, &mut ChaCha8Rng::seed_from_u64(24));
    let evaluate = |kernel: &str| {
        let config = PpoConfig {
            conv_kernel: kernel.into(),
            ..PpoConfig::default()
        };
        let ppo = Ppo::new(net.clone(), config, BackendKind::Flex.device().unwrap()).unwrap();
        ppo.evaluate(&batch.heights_m, &batch.states, 45).unwrap()
    };
    let (native, burn) = (evaluate("native"), evaluate("burn"));
    // Same f32 products summed in different orders: ~1e-6 apart.
    for (a, b) in native
        .log_probs
        .iter()
        .chain(&native.values)
        .zip(burn.log_probs.iter().chain(&burn.values))
    {
        assert!((a - b).abs() < 1e-5, "{a} vs {b}");
    }
}

#[test]
fn an_update_raises_the_probability_of_advantaged_actions() {
    let (gained, gradient_steps) = samples_gaining(|i| if i % 2 == 0 { 1.0 } else { 0.5 }, 0.0);
    assert_eq!(gradient_steps, 16);
    assert!(gained > 32 * 3 / 4, "only {gained} of 32 gained");
}

#[test]
fn the_imitation_term_raises_imitated_actions_without_any_advantage() {
    let (without, _) = samples_gaining(|_| 0.0, 0.0);
    let (with, _) = samples_gaining(|_| 0.0, 1.0);
    assert!(with > 32 * 3 / 4, "only {with} of 32 gained");
    assert!(
        with > without,
        "imitation: {with} gained, without: {without}"
    );
}
