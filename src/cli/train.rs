//! `wheelleg train baseline|secondary|randomize|primary|all|label --config FILE --out runs/NAME
//! [--seed S] [--resume] [--robot FILE]`; `primary` also `[--init CHECKPOINT] [--batch FILE]... [--labels FILE]...`;
//! `label` also `--policy FILE --scenes N [--kind K] [--every K] [--max-expansions N]
//! [--weighted-fallback] [--jobs N] [stack options]`.

use super::stack_args::StackArgs;
use super::CliResult;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::PathBuf;
use std::time::Instant;
use wheelleg_sim::generate::{generate_many, SceneRobot};
use wheelleg_trainer::config::TrainConfig;
use wheelleg_trainer::curriculum::{
    left_out_behaviours, run_all, run_label, run_primary_with, run_randomize, run_secondary,
    CurriculumOptions, PrimaryInputs,
};
use wheelleg_trainer::runner::{train, RunOptions};
use wheelleg_trainer::trajectory::expert_labels::{LabelConfig, LABELS_FILE};

/// What to train.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
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
    /// Expert labels (DAgger): drive --policy through --scenes scenes with the stack, label the
    /// states it visits with the expert's way (--expert: the full stack's, or the planner's
    /// shortest): OUT/labels.wltb, a trajectory batch for `train primary --labels`. Resumes a
    /// killed run.
    Label,
}

/// Options of `train primary` alone.
#[derive(clap::Args)]
#[command(next_help_heading = "Primary (train primary)")]
struct PrimaryArgs {
    /// Start a fresh primary from this checkpoint's network instead of the config's
    /// `curriculum.primary_init` (a fine-tune; the run counts its own env steps from 0 to the
    /// config's budget). Where OUT/primary/ holds a checkpoint, the run resumes that instead,
    /// so the same command continues a killed fine-tune.
    #[arg(long, value_name = "CHECKPOINT")]
    init: Option<PathBuf>,
    /// Replay these trajectory batches together (repeat the option) instead of OUT/batch.wltb:
    /// the secondaries' batch and a `train label` batch, say.
    #[arg(long = "batch", value_name = "FILE")]
    batches: Vec<PathBuf>,
    /// Expert labels (`train label`; repeat the option to aggregate rounds), replayed and
    /// cloned beside the batch, `curriculum.label_steps_per_iteration` steps per iteration.
    #[arg(long = "labels", value_name = "FILE")]
    labels: Vec<PathBuf>,
}

/// Who labels the states `train label` visits.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
enum ExpertArg {
    /// The full decision stack (look-ahead and its searches) driving the same policy.
    Full,
    /// The planner's shortest way.
    Planner,
}

/// Options of `train label` alone.
#[derive(clap::Args)]
#[command(next_help_heading = "Labelling (train label)")]
struct LabelArgs {
    /// The policy driven: a run's checkpoint.ckpt (float) or a `.wlw` weights file (int8).
    #[arg(long)]
    policy: Option<PathBuf>,
    /// Scenes driven, generated as `wheelleg generate --kind K --count N --seed S` makes them
    /// (--seed: never a held-out, calibration or validation seed, which are refused).
    #[arg(long, value_name = "N")]
    scenes: Option<usize>,
    /// Kind of the scenes.
    #[arg(long, value_enum, default_value_t = super::generate::KindArg::Complex)]
    kind: super::generate::KindArg,
    /// Of a successful episode, label every K-th visited state (all of a failed one).
    #[arg(long, value_name = "K", default_value_t = LabelConfig::default().every)]
    every: usize,
    /// Who labels a visited state: the full stack's rollout from it with the same policy
    /// (`full`: what the companion computer would have done), or the planner's shortest way.
    #[arg(long, value_enum, default_value_t = ExpertArg::Full)]
    expert: ExpertArg,
    /// Expansions each plan may take (`--expert planner`); a state whose search runs out gets
    /// no label.
    #[arg(long, value_name = "N", default_value_t = LabelConfig::default().planner_expansions)]
    max_expansions: usize,
    /// Where the exact search runs out, search again weighted (same budget): a proven way,
    /// not a proven shortest one. The states the stack fails from need it most.
    #[arg(long)]
    weighted_fallback: bool,
    /// States labelled at once, one thread each (the planner's searches, or the full stack's
    /// batches of 64 states; default: the config's `run.threads`). The file is the same for
    /// any number.
    #[arg(long, value_name = "N")]
    jobs: Option<usize>,
    /// The stack that drives the policy (default: the on-board stack, `robot`).
    #[command(flatten)]
    stack: StackArgs,
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
    /// Seed of every random choice (for `label`: of the scenes).
    #[arg(long, default_value_t = wheelleg_sim::seeds::TRAINING)]
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
    #[command(flatten)]
    primary: PrimaryArgs,
    #[command(flatten)]
    label: LabelArgs,
}

impl Args {
    /// Refuses a stage's options given to another stage, naming the first.
    fn check_options(&self) -> Result<(), String> {
        let PrimaryArgs {
            init,
            batches,
            labels,
        } = &self.primary;
        let primary = [
            (init.is_some(), "--init"),
            (!batches.is_empty(), "--batch"),
            (!labels.is_empty(), "--labels"),
        ];
        let l = &self.label;
        let label = [
            (l.policy.is_some(), "--policy"),
            (l.scenes.is_some(), "--scenes"),
            (l.kind != super::generate::KindArg::Complex, "--kind"),
            (l.every != LabelConfig::default().every, "--every"),
            (
                l.max_expansions != LabelConfig::default().planner_expansions,
                "--max-expansions",
            ),
            (l.weighted_fallback, "--weighted-fallback"),
            (l.expert != ExpertArg::Full, "--expert"),
            (l.jobs.is_some(), "--jobs"),
            (!l.stack.is_robot_default(), "--stack and its layer options"),
        ];
        for (options, stage) in [(&primary[..], Stage::Primary), (&label[..], Stage::Label)] {
            if let Some((_, option)) = options.iter().find(|(given, _)| *given) {
                if self.stage != stage {
                    return Err(format!(
                        "{option}: only `train {}` takes it",
                        stage_name(stage)
                    ));
                }
            }
        }
        Ok(())
    }
}

fn stage_name(stage: Stage) -> String {
    clap::ValueEnum::to_possible_value(&stage).map_or_else(String::new, |v| v.get_name().into())
}

/// Runs `train`.
pub fn run(args: Args) -> CliResult {
    args.check_options()?;
    let mut config = TrainConfig::load(&args.config)?;
    if let Some(path) = &args.robot {
        config.set_robot(path)?;
    }
    for (behaviour, why) in left_out_behaviours(&config)? {
        if !matches!(args.stage, Stage::Baseline | Stage::Label) {
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
        Stage::Label => return label(&config, &args),
        Stage::Primary => run_primary_with(
            &config,
            &curriculum,
            &PrimaryInputs {
                init: args.primary.init.clone(),
                batches: args.primary.batches.clone(),
                labels: args.primary.labels.clone(),
            },
        )?,
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

/// `train label`: the expert labels of the states the stack visits, into OUT/labels.wltb.
fn label(config: &TrainConfig, args: &Args) -> CliResult {
    let l = &args.label;
    let policy = l
        .policy
        .as_ref()
        .ok_or("train label needs --policy FILE (a checkpoint or a .wlw weights file)")?;
    let count = match l.scenes {
        None => return Err("train label needs --scenes N, the number of scenes driven".into()),
        Some(0) => return Err("--scenes must be at least 1".into()),
        Some(n) => n,
    };
    let env = config.episode_rules().map_err(|e| e.to_string())?;
    let label_config = LabelConfig {
        stack: l.stack.config()?,
        env,
        robot: config.robot.clone(),
        seed: args.seed,
        every: l.every,
        planner_expansions: l.max_expansions,
        weighted_fallback: l.weighted_fallback,
        expert_stack: (l.expert == ExpertArg::Full).then(|| wheelleg_stack::Preset::Full.config()),
        threads: l.jobs.unwrap_or(config.run.threads),
        ..LabelConfig::default()
    };
    label_config
        .check()
        .map_err(|e| format!("train label: {e}"))?;
    let kind = l.kind.scene_kind();
    let scene_robot = SceneRobot::of(&env.robot);
    scene_robot.has_kind(kind).map_err(|why| {
        format!(
            "no {} scenes for robot '{}': {why}",
            kind.name(),
            config.robot.name
        )
    })?;
    let scenarios = generate_many(
        scene_robot,
        kind,
        &mut ChaCha8Rng::seed_from_u64(args.seed),
        count,
    );
    let curriculum = CurriculumOptions {
        out: args.out.clone(),
        seed: args.seed,
        progress: !args.quiet,
        stop_at_env_steps: None,
    };
    let started = Instant::now();
    let stats = super::eval::with_policy(policy, &config.robot, |policy| {
        run_label(policy, &scenarios, &label_config, &curriculum)
    })?;
    let seconds = started.elapsed().as_secs_f64();
    outln!(
        "drove {} {} scenes: {} reached the target, {} decisions",
        stats.episodes,
        kind.name(),
        stats.successes,
        stats.decisions
    );
    outln!(
        "states to label {}: labelled {} ({} steps, {:.1} per label), no way {}, budget ran out \
         {}, the expert stack failed {}, unusable {}",
        stats.states,
        stats.labelled,
        stats.label_steps,
        stats.label_steps as f64 / stats.labelled.max(1) as f64,
        stats.no_way,
        stats.out_of_budget,
        stats.expert_failed,
        stats.unusable
    );
    if stats.planned_here == 0 && stats.states > 0 {
        outln!("the labels were complete already: nothing planned");
    } else if stats.resumed_at_state > 0 {
        outln!(
            "resumed at state {} ({} bytes of a cut chunk dropped)",
            stats.resumed_at_state,
            stats.discarded_tail_bytes
        );
    }
    outln!(
        "planned {} states in {:.1} s ({:.1} states/s, rollouts included); {} ({} bytes)",
        stats.planned_here,
        seconds,
        stats.planned_here as f64 / seconds.max(1e-9),
        args.out.join(LABELS_FILE).display(),
        stats.file_bytes
    );
    Ok(())
}
