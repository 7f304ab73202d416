//! Quantization-aware fine-tuning on the shipped baseline checkpoint, at a small scale: it must
//! not lower the int8 network's agreement with the original float network below what plain
//! post-training quantization reaches, its file must load in the robot's runtime, and it must be
//! deterministic given its seed.
#![allow(clippy::unwrap_used, clippy::indexing_slicing)]

use std::path::PathBuf;

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::model::format::FORMAT_VERSION;
use wheelleg_runtime::model::DefaultPolicy;
use wheelleg_trainer::checkpoint::Checkpoint;
use wheelleg_trainer::export::{export_policy, ExportOptions};
use wheelleg_trainer::network::BackendKind;
use wheelleg_trainer::network_f32::NetworkF32;
use wheelleg_trainer::quantize::{fine_tune, ActionRange, QatOptions, QatSettings, RangeMethod};

fn baseline() -> NetworkF32 {
    // Plain PPO (configs/baseline.toml, seed 0).
    let path = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("tests/fixtures/baseline.ckpt");
    Checkpoint::load(&path)
        .unwrap()
        .network
        .to_network()
        .unwrap()
}

/// 64 observations of random ground up to 20 cm and random targets within 2 m.
fn random_observations(seed: u64) -> Vec<(Vec<f32>, Vec<f32>)> {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    (0..64)
        .map(|_| {
            let height = (0..32 * 32).map(|_| rng.random_range(0.0..0.2)).collect();
            let state = vec![
                0.2,
                0.4,
                rng.random_range(-2.0..2.0),
                rng.random_range(-2.0..2.0),
            ];
            (height, state)
        })
        .collect()
}

#[test]
fn fine_tuning_does_not_lower_agreement_and_the_file_loads() {
    let network = baseline();
    let device = BackendKind::Flex.device().unwrap();
    let options = ExportOptions {
        calibration_observations: 3_000,
        holdout_observations: 4_000,
        qat: QatOptions {
            steps: 120,
            batch: 128,
            observations: 4_000,
            recalibrate_every: 40,
            ..QatOptions::default()
        },
        ..ExportOptions::default()
    };
    let (bytes, card) = export_policy(&network, &device, "test", &options).unwrap();
    let qat = card.qat.as_ref().unwrap();
    let (after, before) = (&card.agreement, &qat.ptq_agreement);
    println!("PTQ {before:?}\nQAT {after:?}\n{:?}", qat.report);
    assert_eq!(qat.report.steps, 120);
    assert!(
        qat.report.loss_last < qat.report.loss_first,
        "{:?}",
        qat.report
    );
    assert!(
        after.worst_dimension() >= before.worst_dimension(),
        "worst dimension {} after QAT, {} before",
        after.worst_dimension(),
        before.worst_dimension()
    );
    assert!(
        after.whole_action >= before.whole_action,
        "whole action {} after QAT, {} before",
        after.whole_action,
        before.whole_action
    );
    // The robot's own policy type (compile-time buffers of the firmware) takes the file.
    let policy = DefaultPolicy::from_bytes(&bytes).unwrap();
    assert_eq!(policy.model().parameter_count(), network.parameter_count());
    assert_eq!(card.format_version, FORMAT_VERSION);
}

#[test]
fn fine_tuning_is_deterministic_and_checks_its_inputs() {
    let network = baseline();
    let device = BackendKind::Flex.device().unwrap();
    let observations = random_observations(5);
    let settings = QatSettings {
        range: RangeMethod::MinMax,
        action_range: ActionRange::Contenders,
        version: FORMAT_VERSION,
    };
    let options = QatOptions {
        steps: 3,
        batch: 16,
        recalibrate_every: 2,
        seed: 9,
        ..QatOptions::default()
    };
    let run = |options: &QatOptions| {
        fine_tune(
            &network,
            &device,
            &observations,
            &observations,
            &settings,
            options,
        )
    };
    let (first, _) = run(&options).unwrap();
    let (second, _) = run(&options).unwrap();
    assert_eq!(first, second, "same seed, same student");
    assert_ne!(first, network, "three steps moved the weights");
    let (other, _) = run(&QatOptions {
        seed: 10,
        ..options.clone()
    })
    .unwrap();
    assert_ne!(first, other, "another seed, other minibatches");
    // Zero steps is plain PTQ: the network itself.
    let (same, report) = run(&QatOptions {
        steps: 0,
        ..options.clone()
    })
    .unwrap();
    assert_eq!((same, report.steps), (network.clone(), 0));

    let error = run(&QatOptions {
        learning_rate: 0.0,
        ..options.clone()
    })
    .unwrap_err();
    assert!(error.to_string().contains("learning rate"), "{error}");
    let short = vec![(vec![0.0; 10], vec![0.0; 4])];
    let error = fine_tune(
        &network,
        &device,
        &observations,
        &short,
        &settings,
        &options,
    )
    .unwrap_err();
    assert!(error.to_string().contains("cells"), "{error}");
    let error = fine_tune(&network, &device, &[], &observations, &settings, &options).unwrap_err();
    assert!(error.to_string().contains("observations"), "{error}");
}
