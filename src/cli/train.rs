//! `wheelleg train baseline|secondary|randomize|primary|all --config FILE --out runs/NAME
//! [--seed S] [--resume] [--robot FILE]`.

use super::CliResult;
use std::path::PathBuf;
use wheelleg_trainer::config::TrainConfig;
use wheelleg_trainer::curriculum::{
    left_out_behaviours, run_all, run_primary, run_randomize, run_secondary, CurriculumOptions,
};
use wheelleg_trainer::runner::{train, RunOptions};

/// What to train.
#[derive(Clone, Copy, Debug, clap::ValueEnum)]
pub enum Stage {
    /// PPO from scratch on the config's scene kind (the paper's baseline on complex scenes).
    Baseline,
    /// Algorithm 1: one policy per behaviour (straight first, the others from it) into
    /// OUT/secondary-<behaviour>/, each keeping its latest successful trajectories.
    Secondary,
    /// The domain-randomized trajectory batch from the stored trajectories: OUT/batch.wltb.
    Randomize,
    /// Algorithm 2: the primary policy on complex scenes with replayed samples: OUT/primary/.
    Primary,
    /// Secondary, randomize and primary in order; each stage resumes where it stopped.
    All,
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
    /// Continue the run in --out from its last checkpoint (baseline; the curriculum stages
    /// always resume what they find).
    #[arg(long)]
    resume: bool,
    /// No progress bar.
    #[arg(long)]
    quiet: bool,
    /// Stop the baseline or the primary, with a checkpoint, once it has this many env steps,
    /// short of the config's budget (a comparison at a smaller budget); `--resume` later goes
    /// on to the config's total on the same schedules.
    #[arg(long, value_name = "N")]
    stop_at_env_steps: Option<u64>,
    /// Robot description trained for, in place of the config's `run.robot` (robots/NAME.toml).
    #[arg(long, value_name = "FILE")]
    robot: Option<PathBuf>,
}

/// Runs `train`.
pub fn run(args: Args) -> CliResult {
    let mut config = TrainConfig::load(&args.config)?;
    if let Some(path) = &args.robot {
        config.set_robot(path)?;
    }
    for (behaviour, why) in left_out_behaviours(&config)? {
        if !matches!(args.stage, Stage::Baseline) {
            eprintln!(
                "curriculum: robot '{}' trains no {} policy: {why}",
                config.robot.name,
                behaviour.name()
            );
        }
    }
    let curriculum = CurriculumOptions {
        out: args.out.clone(),
        seed: args.seed,
        progress: !args.quiet,
        stop_at_env_steps: args.stop_at_env_steps,
    };
    let summary = match args.stage {
        Stage::Baseline => return baseline(&config, &args),
        Stage::Secondary => return Ok(run_secondary(&config, &curriculum)?),
        Stage::Randomize => return Ok(run_randomize(&config, &curriculum).map(|_| ())?),
        Stage::Primary => run_primary(&config, &curriculum)?,
        Stage::All => run_all(&config, &curriculum)?,
    };
    outln!(
        "primary policy: {} iterations, {} env steps; checkpoint {}",
        summary.iterations,
        summary.env_steps,
        summary.checkpoint.display()
    );
    Ok(())
}

fn baseline(config: &TrainConfig, args: &Args) -> CliResult {
    let opts = RunOptions {
        out: args.out.clone(),
        seed: args.seed,
        resume: args.resume,
        progress: !args.quiet,
        max_iterations: None,
        stop_at_env_steps: args.stop_at_env_steps,
        kind: "baseline".into(),
    };
    let summary = train(config, &opts)?;
    outln!(
        "trained {} iterations, {} env steps; checkpoint {}",
        summary.iterations,
        summary.env_steps,
        summary.checkpoint.display()
    );
    if let Some(m) = summary.last {
        outln!(
            "last iteration: success {:.1}%, collision-free {:.1}%, return {:.2}",
            100.0 * m.success_rate,
            100.0 * m.collision_free_rate,
            m.mean_return
        );
    }
    Ok(())
}
