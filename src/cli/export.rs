//! `wheelleg export --policy CKPT [--out weights/policy.wlw] [--qat-steps N ...]`: quantize a
//! trained checkpoint to the robot's int8 weights file (optionally after quantization-aware
//! fine-tuning) and write its model card beside it.

use super::CliResult;
use std::path::PathBuf;
use wheelleg_sim::atomic_write;
use wheelleg_trainer::checkpoint::Checkpoint;
use wheelleg_trainer::export::{card_path, export_policy, ExportOptions};
use wheelleg_trainer::network::BackendKind;
use wheelleg_trainer::quantize::qat::RECOMMENDED_STEPS;
use wheelleg_trainer::quantize::{ActionRange, Agreement, QatOptions, RangeMethod};

/// What sets the action head's output range (`--action-range`).
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum ActionRangeArg {
    /// Each head's two largest logits: what decides the argmax the robot acts on.
    Contenders,
    /// Every logit.
    AllLogits,
}

/// Arguments of `export`.
#[derive(clap::Args)]
pub struct Args {
    /// Policy checkpoint (a run's checkpoint.ckpt).
    #[arg(long)]
    policy: PathBuf,
    /// Weights file to write (its model card goes to `<out>.card.json`).
    #[arg(long, default_value = "weights/policy.wlw")]
    out: PathBuf,
    /// Seed of the calibration scenes (held-out scenes: seed + 1).
    #[arg(long, default_value_t = wheelleg_sim::seeds::CALIBRATION)]
    seed: u64,
    /// Observations to calibrate activation ranges on.
    #[arg(long, default_value_t = 20_000)]
    calibration: usize,
    /// Held-out observations to measure int8/float agreement on.
    #[arg(long, default_value_t = 10_000)]
    holdout: usize,
    /// Range of each tensor: `minmax`, or `percentile:LOW:HIGH` (e.g. percentile:0.01:99.99).
    #[arg(long, default_value = "minmax", value_parser = parse_range)]
    range: RangeMethod,
    /// Action head range from `contenders` (each head's two largest logits: what decides the
    /// argmax the robot acts on) or `all-logits`.
    #[arg(long, value_enum, default_value_t = ActionRangeArg::Contenders)]
    action_range: ActionRangeArg,
    /// Scenes of the rollouts.
    #[arg(long, value_enum, default_value_t = super::generate::KindArg::Complex)]
    kind: super::generate::KindArg,
    /// Quantization-aware fine-tuning steps before quantizing (0: plain post-training
    /// quantization of the checkpoint).
    #[arg(long, default_value_t = RECOMMENDED_STEPS)]
    qat_steps: usize,
    /// Fine-tuning learning rate (Adam, at the first step; cosine decay to 0).
    #[arg(long, default_value_t = QatOptions::default().learning_rate)]
    qat_lr: f64,
    /// Observations per fine-tuning step.
    #[arg(long, default_value_t = QatOptions::default().batch)]
    qat_batch: usize,
    /// Observations to fine-tune on (stochastic rollouts of the checkpoint).
    #[arg(long, default_value_t = QatOptions::default().observations)]
    qat_observations: usize,
    /// Seed of the fine-tuning rollouts and minibatches (keep it apart from --seed and
    /// --seed + 1, so the held-out agreement stays held out).
    #[arg(long, default_value_t = QatOptions::default().seed)]
    qat_seed: u64,
    /// Distillation temperature.
    #[arg(long, default_value_t = QatOptions::default().temperature)]
    qat_temperature: f32,
    /// Extra weight of near-tie decisions: 1 + W * exp(-margin / --qat-near-tie-margin).
    #[arg(long, default_value_t = QatOptions::default().near_tie_weight)]
    qat_near_tie_weight: f32,
    /// Logit margin scale of the near-tie weight.
    #[arg(long, default_value_t = QatOptions::default().near_tie_margin)]
    qat_near_tie_margin: f32,
    /// Fine-tuning steps between recalibrations of the activation ranges.
    #[arg(long, default_value_t = QatOptions::default().recalibrate_every)]
    qat_recalibrate_every: usize,
}

fn parse_range(text: &str) -> Result<RangeMethod, String> {
    if text == "minmax" {
        return Ok(RangeMethod::MinMax);
    }
    let bad = || format!("{text:?}: expected `minmax` or `percentile:LOW:HIGH`");
    let mut parts = text.split(':');
    match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some("percentile"), Some(low), Some(high), None) => {
            let low: f32 = low.parse().map_err(|_| bad())?;
            let high: f32 = high.parse().map_err(|_| bad())?;
            if !(0.0..high).contains(&low) || high > 100.0 {
                return Err(format!(
                    "{text:?}: percentiles must satisfy 0 <= LOW < HIGH <= 100"
                ));
            }
            Ok(RangeMethod::Percentile { low, high })
        }
        _ => Err(bad()),
    }
}

/// Runs `export`.
pub fn run(args: Args) -> CliResult {
    let kind = args.kind.scene_kind();
    if args.calibration == 0 || args.holdout == 0 {
        return Err("--calibration and --holdout must be at least 1".into());
    }
    let action_range = match args.action_range {
        ActionRangeArg::Contenders => ActionRange::Contenders,
        ActionRangeArg::AllLogits => ActionRange::AllLogits,
    };
    if args.qat_steps > 0
        && (args.qat_seed == args.seed || Some(args.qat_seed) == args.seed.checked_add(1))
    {
        return Err(format!(
            "--qat-seed {} is the calibration or held-out seed: pick another (default {})",
            args.qat_seed,
            QatOptions::default().seed
        )
        .into());
    }
    let qat = QatOptions {
        steps: args.qat_steps,
        learning_rate: args.qat_lr,
        batch: args.qat_batch,
        temperature: args.qat_temperature,
        near_tie_weight: args.qat_near_tie_weight,
        near_tie_margin: args.qat_near_tie_margin,
        recalibrate_every: args.qat_recalibrate_every,
        observations: args.qat_observations,
        seed: args.qat_seed,
        ..QatOptions::default()
    };
    qat.validate()?;
    let (checkpoint, extras) = Checkpoint::load_with_extras(&args.policy)?;
    let options = ExportOptions {
        qat,
        action_range,
        scene_kind: kind,
        seed: args.seed,
        calibration_observations: args.calibration,
        holdout_observations: args.holdout,
        range: args.range,
        robot: extras.robot()?,
    };
    let network = checkpoint.network.to_network()?;
    let source = format!(
        "{} ({} run, iteration {}, {} env steps, seed {})",
        args.policy.display(),
        checkpoint.kind,
        checkpoint.iteration,
        checkpoint.env_steps,
        checkpoint.seed
    );
    let device = BackendKind::Flex.device()?;
    let (bytes, card) = export_policy(&network, &device, &source, &options)?;
    if let Some(dir) = args.out.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    }
    atomic_write(&args.out, &bytes)
        .map_err(|e| format!("cannot write {}: {e}", args.out.display()))?;
    let card_file = card_path(&args.out);
    atomic_write(&card_file, serde_json::to_string_pretty(&card)?.as_bytes())
        .map_err(|e| format!("cannot write {}: {e}", card_file.display()))?;
    outln!(
        "wrote {} ({} bytes, {} parameters, {} MACs per decision) and {}",
        args.out.display(),
        card.file_bytes,
        card.parameters,
        card.macs_per_decision,
        card_file.display()
    );
    outln!(
        "calibrated on {} observations ({}); agreement with float on {} held-out observations:",
        card.calibration_observations,
        card.range,
        card.agreement.observations
    );
    match &card.qat {
        None => print_agreement(&card.agreement, None),
        Some(qat) => {
            outln!(
                "  after {} QAT steps (loss {:.5} -> {:.5}); plain PTQ of the checkpoint in brackets",
                qat.report.steps, qat.report.loss_first, qat.report.loss_last
            );
            print_agreement(&card.agreement, Some(&qat.ptq_agreement));
        }
    }
    Ok(())
}

fn print_agreement(agreement: &Agreement, ptq: Option<&Agreement>) {
    let before = |share: Option<f32>| {
        share
            .map(|s| format!("  ({:.2}%)", 100.0 * s))
            .unwrap_or_default()
    };
    for (dim, name) in Agreement::DIMENSION_NAMES.iter().enumerate() {
        outln!(
            "  {name:<8} {:.2}%{}",
            100.0 * agreement.per_dimension[dim],
            before(ptq.map(|p| p.per_dimension[dim]))
        );
    }
    outln!(
        "  whole action {:.2}%{}  (mean |logit error| {:.4})",
        100.0 * agreement.whole_action,
        before(ptq.map(|p| p.whole_action)),
        agreement.mean_logit_error
    );
}
