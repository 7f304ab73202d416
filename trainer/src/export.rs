//! From a trained checkpoint to the robot's weights file: calibration rollouts, optional
//! quantization-aware fine-tuning ([`crate::quantize::qat`]), post-training int8 quantization,
//! a check through the runtime itself, the agreement figure on held-out observations, and an
//! atomic write.

use crate::batch_policy::FloatPolicy;
use crate::error::TrainError;
use crate::evaluate::{collect_observations, EvalOptions, RecordedObservation};
use crate::network_f32::NetworkF32;
use crate::quantize::qat::fine_tune;
use crate::quantize::{
    agreement, quantize, ActionRange, Agreement, Calibration, Int8Policy, QatOptions, QatReport,
    QatSettings, QuantizedNetwork, RangeMethod,
};
use burn::tensor::Device;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::Serialize;
use std::path::{Path, PathBuf};
use wheelleg_robot::RobotDescription;
use wheelleg_sim::generate::{generate_many, SceneKind, SceneRobot};

/// Where calibration and agreement observations come from.
#[derive(Clone, Debug)]
pub struct ExportOptions {
    /// Scenes the observations are collected in.
    pub scene_kind: SceneKind,
    /// Seed of the calibration scenes; the held-out scenes use `seed + 1`. Pick seeds not used
    /// in training or evaluation (the default 2,000,000 is neither).
    pub seed: u64,
    /// Observations the activation ranges are taken from.
    pub calibration_observations: usize,
    /// Held-out observations the agreement is measured on.
    pub holdout_observations: usize,
    /// How a tensor's range is chosen from its observed values.
    pub range: RangeMethod,
    /// Which logits set the action head's output range.
    pub action_range: ActionRange,
    /// Quantization-aware fine-tuning before quantization (`steps: 0`, the default here:
    /// none; `wheelleg export` takes [`crate::quantize::qat::RECOMMENDED_STEPS`] by default).
    pub qat: QatOptions,
    /// The robot the policy was trained for (its checkpoint's): the scenes the observations
    /// come from are built for it, and the weights file records it.
    pub robot: RobotDescription,
}

impl Default for ExportOptions {
    fn default() -> Self {
        ExportOptions {
            scene_kind: SceneKind::Complex,
            seed: wheelleg_sim::seeds::CALIBRATION,
            calibration_observations: 20_000,
            holdout_observations: 10_000,
            range: RangeMethod::MinMax,
            // The robot acts on the argmax. With int8 logits this raised greedy agreement on
            // the baseline policy; with int16 logits (format version 2) it makes no measurable
            // difference (docs/results.md, "Quantization") and stays the default of `wheelleg export`.
            action_range: ActionRange::Contenders,
            qat: QatOptions::default(),
            robot: RobotDescription::shipped(),
        }
    }
}

/// What was exported and how well it matches the float network: written beside the weights
/// as `<file>.card.json`.
#[derive(Clone, Debug, Serialize)]
pub struct ModelCard {
    /// The checkpoint (or other source) the float network came from.
    pub source: String,
    /// Weights format version of the file (2: int16 state features and action logits).
    pub format_version: u16,
    /// Bits of each quantized state feature (16 in version 2, 8 in version 1).
    pub state_bits: u32,
    /// Bits of the stored action logits (16 in version 2, 8 in version 1).
    pub logit_bits: u32,
    /// Size of the weights file.
    pub file_bytes: usize,
    /// Parameters.
    pub parameters: usize,
    /// Multiply-accumulates per decision.
    pub macs_per_decision: usize,
    /// Scene kind of the calibration and held-out rollouts.
    pub scene_kind: String,
    /// Seed of the calibration scenes (held-out: seed + 1).
    pub seed: u64,
    /// Observations calibrated on.
    pub calibration_observations: usize,
    /// Range method (`minmax` or `percentile low-high`).
    pub range: String,
    /// Which logits set the action head's range (`all-logits` or `contenders`).
    pub action_range: String,
    /// Greedy agreement of int8 with float on the held-out observations (with QAT: of the
    /// fine-tuned int8 network with the original float network, the teacher).
    pub agreement: Agreement,
    /// The fine-tuning, if any.
    #[serde(skip_serializing_if = "Option::is_none")]
    pub qat: Option<QatCard>,
}

/// The quantization-aware fine-tuning behind a weights file.
#[derive(Clone, Debug, Serialize)]
pub struct QatCard {
    /// Its settings.
    pub options: QatOptions,
    /// What it did.
    pub report: QatReport,
    /// Greedy agreement of the plain post-training quantization of the original network (no
    /// fine-tuning) with it, on the same held-out observations: what the fine-tuning gained.
    pub ptq_agreement: Agreement,
}

/// Observations from stochastic rollouts of `network` in freshly generated scenes, until
/// `count` are collected. Stochastic: the sampled actions visit more of the state space than
/// the greedy path, so calibration also sees what a slightly off-course robot sees. Public so
/// that quantization variants can be compared on exactly the export's observations.
pub fn rollout_observations(
    policy: &FloatPolicy,
    robot: &RobotDescription,
    kind: SceneKind,
    seed: u64,
    count: usize,
) -> Result<Vec<RecordedObservation>, TrainError> {
    let simulated = wheelleg_sim::robot::SimulatedRobot::of(robot)
        .map_err(|e| TrainError::Config(crate::config::ConfigError::Robot(e)))?;
    let mut scenes_rng = ChaCha8Rng::seed_from_u64(seed);
    let mut actions_rng = ChaCha8Rng::seed_from_u64(seed);
    actions_rng.set_stream(1);
    let options = EvalOptions {
        stack: wheelleg_stack::StackConfig {
            rule: wheelleg_stack::DecisionRule::Sample,
            ..wheelleg_stack::Preset::Policy.config()
        },
        planner_expansions: 0,
        env_config: wheelleg_sim::env::EnvConfig {
            robot: simulated,
            ..EvalOptions::default().env_config
        },
        ..EvalOptions::default()
    };
    let scene_robot = SceneRobot::of(&simulated);
    let mut observations = Vec::with_capacity(count);
    while observations.len() < count {
        let scenes = generate_many(scene_robot, kind, &mut scenes_rng, 64);
        let more = collect_observations(
            policy,
            &scenes,
            &options,
            &mut actions_rng,
            count - observations.len(),
        )?;
        if more.is_empty() {
            return Err(TrainError::Nothing {
                what: "observations from the rollouts",
            });
        }
        observations.extend(more);
    }
    Ok(observations)
}

fn range_name(range: RangeMethod) -> String {
    match range {
        RangeMethod::MinMax => "minmax".into(),
        RangeMethod::Percentile { low, high } => format!("percentile {low}-{high}"),
    }
}

/// Quantizes `network` as [`ExportOptions`] say and checks the result through the runtime:
/// the weights file bytes and their model card.
pub fn export_policy(
    network: &NetworkF32,
    device: &Device,
    source: &str,
    options: &ExportOptions,
) -> Result<(Vec<u8>, ModelCard), TrainError> {
    options.qat.validate()?;
    let holdout_seed = options.seed.checked_add(1).ok_or_else(|| {
        TrainError::setting(
            "calibration seed",
            "must be below u64::MAX (held-out scenes use seed + 1)",
        )
    })?;
    // Every observation set comes from the original network's rollouts, so the held-out set
    // and the calibration set are the same with and without fine-tuning.
    let float = FloatPolicy::new(network, device)?;
    let calibration_set = rollout_observations(
        &float,
        &options.robot,
        options.scene_kind,
        options.seed,
        options.calibration_observations,
    )?;
    let holdout = rollout_observations(
        &float,
        &options.robot,
        options.scene_kind,
        holdout_seed,
        options.holdout_observations,
    )?;
    let calibrate_and_quantize =
        |net: &NetworkF32| -> Result<(Calibration, QuantizedNetwork, Vec<u8>), TrainError> {
            let mut calibration = Calibration::from_observations(
                net,
                calibration_set
                    .iter()
                    .map(|(h, s)| (h.as_slice(), s.as_slice())),
            );
            calibration.action_range = options.action_range;
            let quantized = QuantizedNetwork {
                robot: options.robot.clone(),
                ..quantize(net, &calibration, options.range)
                    .map_err(|e| TrainError::stage("quantize", e))?
            };
            let bytes = quantized
                .to_bytes()
                .map_err(|e| TrainError::stage("encode weights", e))?;
            Ok((calibration, quantized, bytes))
        };
    let measure = |bytes: &[u8]| -> Result<Agreement, TrainError> {
        let policy = Int8Policy::from_bytes(bytes).map_err(TrainError::Refused)?;
        // Always against the original float network: that is the policy that was trained.
        agreement(network, &policy, &holdout)
    };
    let (calibration, quantized, bytes, qat) = if options.qat.steps == 0 {
        let (calibration, quantized, bytes) = calibrate_and_quantize(network)?;
        (calibration, quantized, bytes, None)
    } else {
        let (_, ptq, ptq_bytes) = calibrate_and_quantize(network)?;
        let ptq_agreement = measure(&ptq_bytes)?;
        let training_set = rollout_observations(
            &float,
            &options.robot,
            options.scene_kind,
            options.qat.seed,
            options.qat.observations,
        )?;
        let (student, report) = fine_tune(
            network,
            device,
            &calibration_set,
            &training_set,
            &QatSettings {
                range: options.range,
                action_range: options.action_range,
                version: ptq.version,
            },
            &options.qat,
        )?;
        let (calibration, quantized, bytes) = calibrate_and_quantize(&student)?;
        let card = QatCard {
            options: options.qat.clone(),
            report,
            ptq_agreement,
        };
        (calibration, quantized, bytes, Some(card))
    };
    let agreement = measure(&bytes)?;
    let policy = Int8Policy::from_bytes(&bytes).map_err(TrainError::Refused)?;
    let (parameters, macs_per_decision) = (policy.model().parameter_count(), policy.model().macs());
    let (state_bits, logit_bits) = (policy.model().state_bits(), policy.model().logit_bits());
    drop(policy);
    let card = ModelCard {
        source: source.to_string(),
        format_version: quantized.version,
        state_bits,
        logit_bits,
        file_bytes: bytes.len(),
        parameters,
        macs_per_decision,
        scene_kind: format!("{:?}", options.scene_kind).to_lowercase(),
        seed: options.seed,
        calibration_observations: calibration.count,
        range: range_name(options.range),
        action_range: match options.action_range {
            ActionRange::AllLogits => "all-logits".into(),
            ActionRange::Contenders => "contenders".into(),
        },
        agreement,
        qat,
    };
    Ok((bytes, card))
}

/// The model card's path for a weights file: `policy.wlw` -> `policy.wlw.card.json`.
pub fn card_path(weights: &Path) -> PathBuf {
    let mut name = weights.as_os_str().to_owned();
    name.push(".card.json");
    PathBuf::from(name)
}
