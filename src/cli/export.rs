//! `wheelleg export --policy CKPT [--out weights/policy.wlw]`: quantize a trained checkpoint to
//! the robot's int8 weights file and write its model card beside it.

use super::CliResult;
use std::path::PathBuf;
use wheelleg_sim::generate::SceneKind;
use wheelleg_trainer::checkpoint::Checkpoint;
use wheelleg_trainer::export::{card_path, export_policy, write_atomic, ExportOptions};
use wheelleg_trainer::network::BackendKind;
use wheelleg_trainer::quantize::{ActionRange, Agreement, RangeMethod};

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
    #[arg(long, default_value_t = 2_000_000)]
    seed: u64,
    /// Observations to calibrate activation ranges on.
    #[arg(long, default_value_t = 20_000)]
    calibration: usize,
    /// Held-out observations to measure int8/float agreement on.
    #[arg(long, default_value_t = 10_000)]
    holdout: usize,
    /// Range of each tensor: `minmax`, or `percentile:LOW:HIGH` (e.g. percentile:0.01:99.99).
    #[arg(long, default_value = "minmax")]
    range: String,
    /// Action head range from `contenders` (each head's two largest logits: what decides the
    /// argmax the robot acts on) or `all-logits`.
    #[arg(long, default_value = "contenders")]
    action_range: String,
    /// Scenes of the rollouts: straight, around, lift, spread, squeeze, complex.
    #[arg(long, default_value = "complex")]
    kind: String,
}

fn parse_range(text: &str) -> Result<RangeMethod, String> {
    if text == "minmax" {
        return Ok(RangeMethod::MinMax);
    }
    let bad = || format!("--range {text:?}: expected `minmax` or `percentile:LOW:HIGH`");
    let mut parts = text.split(':');
    match (parts.next(), parts.next(), parts.next(), parts.next()) {
        (Some("percentile"), Some(low), Some(high), None) => {
            let low: f32 = low.parse().map_err(|_| bad())?;
            let high: f32 = high.parse().map_err(|_| bad())?;
            if !(0.0..high).contains(&low) || high > 100.0 {
                return Err(format!(
                    "--range {text:?}: percentiles must satisfy 0 <= LOW < HIGH <= 100"
                ));
            }
            Ok(RangeMethod::Percentile { low, high })
        }
        _ => Err(bad()),
    }
}

/// Runs `export`.
pub fn run(args: Args) -> CliResult {
    let kind = SceneKind::from_name(&args.kind).ok_or_else(|| {
        format!(
            "unknown --kind {:?} (straight, around, lift, spread, squeeze, complex)",
            args.kind
        )
    })?;
    if args.calibration == 0 || args.holdout == 0 {
        return Err("--calibration and --holdout must be at least 1".into());
    }
    let action_range = match args.action_range.as_str() {
        "contenders" => ActionRange::Contenders,
        "all-logits" => ActionRange::AllLogits,
        other => {
            return Err(
                format!("--action-range {other:?}: expected contenders or all-logits").into(),
            )
        }
    };
    let options = ExportOptions {
        action_range,
        scene_kind: kind,
        seed: args.seed,
        calibration_observations: args.calibration,
        holdout_observations: args.holdout,
        range: parse_range(&args.range)?,
    };
    let checkpoint = Checkpoint::load(&args.policy)?;
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
    write_atomic(&args.out, &bytes)
        .map_err(|e| format!("cannot write {}: {e}", args.out.display()))?;
    let card_file = card_path(&args.out);
    write_atomic(&card_file, serde_json::to_string_pretty(&card)?.as_bytes())
        .map_err(|e| format!("cannot write {}: {e}", card_file.display()))?;
    println!(
        "wrote {} ({} bytes, {} parameters, {} MACs per decision) and {}",
        args.out.display(),
        card.file_bytes,
        card.parameters,
        card.macs_per_decision,
        card_file.display()
    );
    println!(
        "calibrated on {} observations ({}); agreement with float on {} held-out observations:",
        card.calibration_observations, card.range, card.agreement.observations
    );
    for (name, share) in Agreement::DIMENSION_NAMES
        .iter()
        .zip(card.agreement.per_dimension)
    {
        println!("  {name:<8} {:.2}%", 100.0 * share);
    }
    println!(
        "  whole action {:.2}%  (mean |logit error| {:.4})",
        100.0 * card.agreement.whole_action,
        card.agreement.mean_logit_error
    );
    Ok(())
}
