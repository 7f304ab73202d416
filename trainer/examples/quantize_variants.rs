//! Greedy agreement of several quantizations of one checkpoint on the same calibration and
//! held-out observations as `wheelleg export` (format version 1 and 2 action heads, action range
//! from all logits or the contenders), and optionally writes the variants for closed-loop runs.
//!
//! Usage: `quantize_variants CKPT [OUT_DIR]`.
#![allow(clippy::unwrap_used, clippy::expect_used)]

use wheelleg_trainer::batch_policy::FloatPolicy;
use wheelleg_trainer::checkpoint::Checkpoint;
use wheelleg_trainer::export::{rollout_observations, ExportOptions};
use wheelleg_trainer::network::BackendKind;
use wheelleg_trainer::quantize::{
    agreement, quantize_for_version, ActionRange, Calibration, Int8Policy,
};

fn main() {
    let mut args = std::env::args().skip(1);
    let path = args
        .next()
        .expect("usage: quantize_variants CKPT [OUT_DIR]");
    let out_dir = args.next();
    let checkpoint = Checkpoint::load(std::path::Path::new(&path)).unwrap();
    let network = checkpoint.network.to_network().unwrap();
    let device = BackendKind::Flex.device().unwrap();
    let float = FloatPolicy::new(&network, &device).unwrap();
    let options = ExportOptions::default();
    let calibration_set = rollout_observations(
        &float,
        &options.robot,
        options.scene_kind,
        options.seed,
        options.calibration_observations,
    )
    .unwrap();
    let holdout = rollout_observations(
        &float,
        &options.robot,
        options.scene_kind,
        options.seed + 1,
        options.holdout_observations,
    )
    .unwrap();
    let mut calibration = Calibration::from_observations(
        &network,
        calibration_set
            .iter()
            .map(|(h, s)| (h.as_slice(), s.as_slice())),
    );
    for version in [1u16, 2] {
        for range in [ActionRange::AllLogits, ActionRange::Contenders] {
            calibration.action_range = range;
            let quantized =
                quantize_for_version(&network, &calibration, options.range, version).unwrap();
            let bytes = quantized.to_bytes().unwrap();
            let policy = Int8Policy::from_bytes(&bytes).unwrap();
            let a = agreement(&network, &policy, &holdout).unwrap();
            println!(
                "v{version} {range:?}: per dimension {:?} whole {:.4} worst {:.4} logit error {:.4}",
                a.per_dimension.map(|x| (x * 10000.0).round() / 100.0),
                a.whole_action,
                a.worst_dimension(),
                a.mean_logit_error
            );
            if let Some(dir) = &out_dir {
                let name = format!("{dir}/v{version}_{range:?}.wlw");
                std::fs::write(&name, &bytes).unwrap();
            }
        }
    }
}
