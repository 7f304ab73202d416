//! `wheelleg train baseline --config FILE --out runs/NAME [--seed S] [--resume]`.

use super::CliResult;
use std::path::PathBuf;
use wheelleg_trainer::config::TrainConfig;
use wheelleg_trainer::runner::{train, RunOptions};

/// What to train.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Stage {
    /// PPO from scratch on the config's scene kind (the paper's baseline on complex scenes).
    Baseline,
}

/// Arguments of `train`.
#[derive(clap::Args)]
pub struct Args {
    /// What to train.
    #[arg(value_enum)]
    stage: Stage,
    /// Training config (TOML; configs/baseline.toml).
    #[arg(long)]
    config: PathBuf,
    /// Run folder (metrics.jsonl, checkpoint.ckpt, config.toml).
    #[arg(long)]
    out: PathBuf,
    /// Seed of every random choice.
    #[arg(long, default_value_t = 0)]
    seed: u64,
    /// Continue the run in --out from its last checkpoint.
    #[arg(long)]
    resume: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
}

/// Runs `train`.
pub fn run(args: Args) -> CliResult {
    let config = TrainConfig::load(&args.config)?;
    let Stage::Baseline = args.stage;
    let opts = RunOptions {
        out: args.out.clone(),
        seed: args.seed,
        resume: args.resume,
        progress: !args.quiet,
        max_iterations: None,
        kind: "baseline".into(),
    };
    let summary = train(&config, &opts)?;
    println!(
        "trained {} iterations, {} env steps; checkpoint {}",
        summary.iterations,
        summary.env_steps,
        summary.checkpoint.display()
    );
    if let Some(m) = summary.last {
        println!(
            "last iteration: success {:.1}%, collision-free {:.1}%, return {:.2}",
            100.0 * m.success_rate,
            100.0 * m.collision_free_rate,
            m.mean_return
        );
    }
    Ok(())
}
