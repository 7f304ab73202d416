//! The paper's method end to end (Algorithms 1 and 2), stage by stage, each resumable:
//!
//! 1. **Secondary policies** ([`run_secondary`]): PPO in each behaviour's simple scenes with the
//!    paper's batch of 3,000 steps; straight first, the others start from it. Each run keeps
//!    its latest successful trajectories.
//! 2. **Trajectory batch** ([`run_randomize`]): every stored trajectory replayed in new scenes
//!    whose obstacles were re-placed outside its essential area; only replays that still
//!    succeed without a collision are kept ([`crate::trajectory::randomize`]).
//! 3. **Primary policy** ([`run_primary`]): PPO on complex scenes, each update on the
//!    on-policy batch plus replayed samples whose advantages the current critic recomputes.
//!
//! Layout of `--out runs/NAME`: `secondary-<behaviour>/` (a run folder each, with
//! `trajectories.wltb`), `batch.wltb` (the trajectory batch), `primary/` (a run folder),
//! `labels.wltb` (expert labels, [`run_label`]).
//! [`run_all`] runs the stages in order; a stage whose run reached its budget is not redone,
//! one that was interrupted resumes from its checkpoint.
//!
//! A primary may also start from another run's checkpoint and replay other batches
//! ([`PrimaryInputs`], [`run_primary_with`]): a round of expert iteration fine-tunes the current
//! primary on the secondaries' batch plus the labels of the states its stack visits
//! ([`crate::trajectory::expert_labels`]).

use crate::checkpoint::{Checkpoint, CheckpointError};
use crate::config::TrainConfig;
use crate::error::TrainError;
use crate::network_f32::NetworkF32;
use crate::replay::{ReplayBalance, ReplayOptions};
use crate::runner::{train_stage, RunOptions, RunSummary, StageInputs, TRAJECTORIES_FILE};
use crate::trajectory::batch_file::TrajectoryBatch;
use crate::trajectory::expert_labels::{label_batch, LabelConfig, LabelStats, LABELS_FILE};
use crate::trajectory::randomize::{randomize_batch_with, RandomizeConfig, Stats};
use crate::trajectory::Trajectory;
use std::path::{Path, PathBuf};
use wheelleg_sim::generate::{Behaviour, SceneKind, SceneRobot};
use wheelleg_sim::scenario::Scenario;
use wheelleg_stack::policy::BatchPolicy;

/// Name of the trajectory batch in a curriculum folder.
pub const BATCH_FILE: &str = "batch.wltb";
/// Name of the primary policy's run folder.
pub const PRIMARY_DIR: &str = "primary";

/// How a curriculum command runs.
#[derive(Clone, Debug)]
pub struct CurriculumOptions {
    /// The curriculum folder.
    pub out: PathBuf,
    /// Seed of every random choice (each stage derives its own).
    pub seed: u64,
    /// Draw progress bars.
    pub progress: bool,
    /// Stop the primary stage, with a checkpoint, at this many env steps, short of its budget
    /// ([`RunOptions::stop_at_env_steps`]; the secondaries always run to theirs).
    pub stop_at_env_steps: Option<u64>,
}

/// The run folder of a behaviour's secondary policy.
pub fn secondary_dir(out: &Path, behaviour: Behaviour) -> PathBuf {
    out.join(format!("secondary-{}", behaviour.name()))
}

/// The curriculum's behaviours the robot has, in order; those it lacks are left out
/// ([`left_out_behaviours`] says why).
fn behaviours(config: &TrainConfig) -> Result<Vec<Behaviour>, TrainError> {
    let fit = SceneRobot::of(&config.simulated_robot()?);
    Ok(named_behaviours(config)?
        .into_iter()
        .filter(|&b| fit.has(b).is_ok())
        .collect())
}

/// The curriculum's behaviours the robot lacks, each with why: their secondaries are not
/// trained and the batch holds none of their trajectories.
pub fn left_out_behaviours(config: &TrainConfig) -> Result<Vec<(Behaviour, String)>, TrainError> {
    let fit = SceneRobot::of(&config.simulated_robot()?);
    Ok(named_behaviours(config)?
        .into_iter()
        .filter_map(|b| fit.has(b).err().map(|why| (b, why)))
        .collect())
}

fn named_behaviours(config: &TrainConfig) -> Result<Vec<Behaviour>, TrainError> {
    config
        .curriculum
        .behaviours
        .iter()
        .map(|name| match SceneKind::from_name(name) {
            Some(SceneKind::Behaviour(b)) => Ok(b),
            _ => Err(TrainError::setting(
                "curriculum.behaviours",
                format!("{name:?} is not a behaviour"),
            )),
        })
        .collect()
}

/// Runs (or resumes) one PPO stage in `dir`: resumes when a checkpoint is there, so a stage
/// that already reached its budget returns at once.
fn run_stage(
    config: &TrainConfig,
    dir: &Path,
    seed: u64,
    kind: &str,
    progress: bool,
    stop_at_env_steps: Option<u64>,
    inputs: StageInputs<'_>,
) -> Result<RunSummary, TrainError> {
    let resume = dir.join(crate::runner::CHECKPOINT_FILE).exists();
    let opts = RunOptions {
        out: dir.to_path_buf(),
        seed,
        resume,
        progress,
        max_iterations: None,
        stop_at_env_steps,
        kind: kind.to_string(),
    };
    train_stage(config, &opts, inputs)
}

fn load_network(config: &TrainConfig, dir: &Path) -> Result<NetworkF32, TrainError> {
    load_checkpoint_network(config, &dir.join(crate::runner::CHECKPOINT_FILE))
}

/// The network of checkpoint `path`, refused when it was trained for another robot.
fn load_checkpoint_network(config: &TrainConfig, path: &Path) -> Result<NetworkF32, TrainError> {
    let (checkpoint, extras) = Checkpoint::load_with_extras(path)?;
    extras.check_robot(&config.robot, &path.display().to_string())?;
    let network = checkpoint
        .network
        .to_network()
        .map_err(|e| CheckpointError::In {
            path: path.to_path_buf(),
            error: Box::new(e),
        })?;
    Ok(network)
}

/// [`load_checkpoint_network`] for a run to start from: its layers must be the config's
/// `[network]`, which the run's checkpoints will record.
fn load_init_network(config: &TrainConfig, path: &Path) -> Result<NetworkF32, TrainError> {
    let network = load_checkpoint_network(config, path)?;
    let wanted = config.architecture();
    if network.arch.convs != wanted.convs || network.arch.hidden != wanted.hidden {
        return Err(TrainError::NetworkMismatch {
            path: path.to_path_buf(),
            conv_channels: network.arch.convs.iter().map(|c| c.out_channels).collect(),
            hidden: network.arch.hidden.clone(),
            config_conv_channels: config.network.conv_channels.clone(),
            config_hidden: config.network.hidden.clone(),
        });
    }
    Ok(network)
}

/// The config of `behaviour`'s secondary stage (`first`: the straight-line policy, which starts
/// from scratch): the run's settings with the curriculum's secondary budget, early stop, batch,
/// epochs, entropy, start yaw and start stages.
fn secondary_stage(config: &TrainConfig, behaviour: Behaviour, first: bool) -> TrainConfig {
    let mut stage = config.clone();
    // The mix of composed scenes and the learning rate's anneal are the primary's: a
    // secondary trains on its behaviour's scenes alone, at the constant rate.
    stage.run.composed_share = 0.0;
    stage.run.exit_share = 0.0;
    stage.run.composed_from_env_steps = 0;
    stage.ppo.learning_rate_final = None;
    stage.ppo.anneal_start_env_steps = crate::config::PpoConfig::default().anneal_start_env_steps;
    stage.run.scene_kind = behaviour.name().to_string();
    stage.run.steps_per_iteration = config.curriculum.secondary_steps_per_iteration;
    if let Some(epochs) = config.curriculum.secondary_epochs {
        stage.ppo.epochs = epochs;
    }
    // The straight-line policy runs to its budget: the others start from it, and stopped at its
    // first plateau it left lift's secondary unable to learn (docs/curriculum.md).
    if !first {
        stage.run.stop_success_rate = config.curriculum.secondary_stop_success_rate;
        stage.run.stop_window = config.curriculum.secondary_stop_window;
    }
    stage.run.total_env_steps = config
        .curriculum
        .secondary_env_steps_by_behaviour
        .get(behaviour.name())
        .copied()
        .unwrap_or(config.curriculum.secondary_env_steps);
    if !first {
        stage.ppo.entropy_coef = config.curriculum.secondary_entropy_coef;
        stage.run.start_yaw_within_deg = config.curriculum.secondary_start_yaw_within_deg;
    }
    let c = &config.curriculum;
    if c.start_stage_behaviours
        .iter()
        .any(|b| b == behaviour.name())
    {
        stage.run.start_stage = c.start_stage_initial;
        stage.run.start_stage_step = c.start_stage_step;
        stage.run.start_stage_success_rate = c.start_stage_success_rate;
        stage.run.start_stage_window = c.start_stage_window;
    }
    stage
}

/// Algorithm 1: one secondary policy per behaviour, straight first, the others initialised
/// from it; each keeps its latest successful trajectories.
pub fn run_secondary(config: &TrainConfig, opts: &CurriculumOptions) -> Result<(), TrainError> {
    let behaviours = behaviours(config)?;
    let mut straight: Option<NetworkF32> = None;
    for (index, &behaviour) in behaviours.iter().enumerate() {
        let stage = secondary_stage(config, behaviour, straight.is_none());
        let dir = secondary_dir(&opts.out, behaviour);
        let summary = run_stage(
            &stage,
            &dir,
            opts.seed.wrapping_add(1 + index as u64),
            &format!("secondary-{}", behaviour.name()),
            opts.progress,
            None,
            StageInputs {
                init: straight.as_ref(),
                record: Some(behaviour),
                keep_trajectories: config.curriculum.keep_trajectories,
                ..StageInputs::default()
            },
        )?;
        report_stage(&format!("secondary {}", behaviour.name()), &summary);
        if summary.env_steps < stage.run.total_env_steps {
            println!(
                "secondary {}: learnt, stopped short of its budget of {} env steps",
                behaviour.name(),
                stage.run.total_env_steps
            );
        }
        if index == 0 {
            let mut network = load_network(config, &dir)?;
            soften_action_head(&mut network, config.curriculum.secondary_init_temperature);
            straight = Some(network);
        }
    }
    Ok(())
}

/// Divides the action logits by `temperature` (weights and bias alike, so every logit is
/// scaled and each dimension's ranking is kept while its distribution flattens).
fn soften_action_head(network: &mut NetworkF32, temperature: f32) {
    let head = &mut network.action_head;
    for w in head.weights.iter_mut().chain(head.bias.iter_mut()) {
        *w /= temperature;
    }
}

fn report_stage(name: &str, summary: &RunSummary) {
    match &summary.last {
        Some(m) => println!(
            "{name}: {} env steps, success {:.1}%, collision-free {:.1}%",
            summary.env_steps,
            100.0 * m.success_rate,
            100.0 * m.collision_free_rate
        ),
        None => println!("{name}: done earlier ({} env steps)", summary.env_steps),
    }
    // Where the stage's time went, over every iteration of its log (resumed ones included;
    // a log written before the split was timed has none).
    let run = summary
        .checkpoint
        .parent()
        .unwrap_or(std::path::Path::new("."));
    if let Ok(metrics) = crate::runner::read_metrics(run) {
        let total = metrics
            .iter()
            .fold(crate::runner::IterationTime::default(), |t, m| t + m.time);
        if total == crate::runner::IterationTime::default() {
            return;
        }
        println!(
            "{name}: time in acting {:.0} s, environments {:.0} s, replay {:.0} s, updates {:.0} s",
            total.act_s, total.env_s, total.replay_s, total.update_s
        );
    }
}

/// The stored trajectories of every secondary policy, in behaviour order. Refused when a
/// behaviour has none: the batch would then teach the primary nothing of it, and the primary
/// forgets what it cannot replay (a primary on a batch without squeeze trajectories passed 0
/// of 200 squeeze scenes; docs/results.md).
pub fn stored_trajectories(
    config: &TrainConfig,
    out: &Path,
) -> Result<Vec<Trajectory>, TrainError> {
    let mut all = Vec::new();
    for behaviour in behaviours(config)? {
        let path = secondary_dir(out, behaviour).join(TRAJECTORIES_FILE);
        let stored = TrajectoryBatch::load(&path).map_err(|e| {
            TrainError::hint(
                e,
                "train the secondary policies first: wheelleg train secondary",
            )
        })?;
        stored
            .header()
            .check_robot(&config.robot, &path.display().to_string())?;
        if stored.is_empty() {
            return Err(TrainError::NoTrajectories {
                behaviour: behaviour.name(),
                path,
            });
        }
        all.extend((0..stored.len()).filter_map(|i| stored.trajectory(i)));
    }
    Ok(all)
}

/// The trajectory batch by domain randomization (resumable: see
/// [`crate::trajectory::batch_file`]).
pub fn run_randomize(config: &TrainConfig, opts: &CurriculumOptions) -> Result<Stats, TrainError> {
    let sources = stored_trajectories(config, &opts.out)?;
    if sources.is_empty() {
        return Err(TrainError::hint(
            TrainError::Nothing {
                what: "successful trajectory to randomize",
            },
            "train the secondaries first",
        ));
    }
    let randomize = RandomizeConfig {
        per_trajectory: config.curriculum.randomizations,
        seed: opts.seed,
        env: config.episode_rules()?,
        robot: config.robot.clone(),
        ..RandomizeConfig::default()
    };
    let bar = if opts.progress {
        indicatif::ProgressBar::new(sources.len() as u64)
    } else {
        indicatif::ProgressBar::hidden()
    };
    let stats = randomize_batch_with(&sources, &randomize, &opts.out.join(BATCH_FILE), |p| {
        bar.set_position(p.sources_done);
        bar.set_message(format!("{} kept of {} tried", p.kept, p.tried));
    })?;
    bar.finish_and_clear();
    println!(
        "trajectory batch: {} sources, {} randomized scenes kept of {} tried, {} trajectories, \
         {:.1} bytes each",
        stats.sources,
        stats.kept,
        stats.tried,
        stats.trajectories(),
        stats.bytes_per_trajectory()
    );
    Ok(stats)
}

/// Where a primary starts and what it replays, when not what its curriculum folder holds.
#[derive(Clone, Debug, Default)]
pub struct PrimaryInputs {
    /// A checkpoint whose network a fresh primary starts from, in place of
    /// `curriculum.primary_init` (a fine-tune, on expert labels say; its Adam state and step
    /// count are not taken: the run counts its own env steps from 0). A primary that resumes
    /// its own checkpoint continues from that, so the same command resumes a killed fine-tune.
    pub init: Option<PathBuf>,
    /// Trajectory batches replayed together, in this order, in place of the folder's
    /// [`BATCH_FILE`]; empty: that one.
    pub batches: Vec<PathBuf>,
    /// Expert labels ([`run_label`]; several rounds' together), replayed and cloned beside the
    /// batch, `curriculum.label_steps_per_iteration` samples per iteration. Empty: none.
    pub labels: Vec<PathBuf>,
}

/// Expert labels ([`crate::trajectory::expert_labels`]): `policy` driven through `scenarios`
/// by `label.stack`, the states it visits labelled with the expert's way (the full stack's, or
/// the planner's shortest), into `OUT/labels.wltb` (resumable), for [`run_primary_with`].
pub fn run_label(
    policy: &dyn BatchPolicy,
    scenarios: &[Scenario],
    label: &LabelConfig,
    opts: &CurriculumOptions,
) -> Result<LabelStats, TrainError> {
    std::fs::create_dir_all(&opts.out).map_err(|e| TrainError::io(&opts.out, "create", e))?;
    let bar = if opts.progress {
        indicatif::ProgressBar::new(0)
    } else {
        indicatif::ProgressBar::hidden()
    };
    bar.set_message("driving the episodes");
    let stats = label_batch(policy, scenarios, label, &opts.out.join(LABELS_FILE), |p| {
        bar.set_length(p.states_total);
        bar.set_position(p.states_done);
        bar.set_message(format!("{} labelled", p.labelled));
    })?;
    bar.finish_and_clear();
    Ok(stats)
}

/// Algorithm 2: PPO on complex scenes with replayed samples from the trajectory batch.
pub fn run_primary(
    config: &TrainConfig,
    opts: &CurriculumOptions,
) -> Result<RunSummary, TrainError> {
    run_primary_with(config, opts, &PrimaryInputs::default())
}

/// The trajectory batches of `paths`, each checked for the robot, as one.
fn load_batches(config: &TrainConfig, paths: &[PathBuf]) -> Result<TrajectoryBatch, TrainError> {
    let mut all: Option<TrajectoryBatch> = None;
    for path in paths {
        let batch = TrajectoryBatch::load(path).map_err(|e| TrainError::in_file(path, e))?;
        batch
            .header()
            .check_robot(&config.robot, &path.display().to_string())?;
        match &mut all {
            None => all = Some(batch),
            Some(all) => all
                .append(batch)
                .map_err(|e| TrainError::in_file(path, e))?,
        }
    }
    all.ok_or(TrainError::Nothing {
        what: "trajectory batch to replay",
    })
}

/// [`run_primary`] from `inputs.init` when given, replaying `inputs.batches` when given.
pub fn run_primary_with(
    config: &TrainConfig,
    opts: &CurriculumOptions,
    inputs: &PrimaryInputs,
) -> Result<RunSummary, TrainError> {
    let batch = if inputs.batches.is_empty() {
        let batch_path = opts.out.join(BATCH_FILE);
        let batch = TrajectoryBatch::load(&batch_path).map_err(|e| {
            TrainError::hint(
                e,
                "make the trajectory batch first: wheelleg train randomize",
            )
        })?;
        batch
            .header()
            .check_robot(&config.robot, &batch_path.display().to_string())?;
        batch
    } else {
        load_batches(config, &inputs.batches)?
    };
    let labels = if inputs.labels.is_empty() {
        None
    } else if config.curriculum.label_steps_per_iteration == 0 {
        return Err(TrainError::setting(
            "curriculum.label_steps_per_iteration",
            "0 with expert labels given: they would never be replayed",
        ));
    } else {
        Some(load_batches(config, &inputs.labels)?)
    };
    let init = match (&inputs.init, config.curriculum.primary_init.as_str()) {
        (Some(path), _) => Some(load_init_network(config, path)?),
        (None, "scratch") => None,
        (None, name) => match SceneKind::from_name(name) {
            Some(SceneKind::Behaviour(b)) => {
                Some(load_network(config, &secondary_dir(&opts.out, b))?)
            }
            _ => {
                return Err(TrainError::setting(
                    "curriculum.primary_init",
                    format!("{name:?} is not a behaviour"),
                ))
            }
        },
    };
    let dir = opts.out.join(PRIMARY_DIR);
    let mut stage = config.clone();
    stage.run.scene_kind = "complex".into();
    let summary = run_stage(
        &stage,
        &dir,
        opts.seed,
        "primary",
        opts.progress,
        opts.stop_at_env_steps,
        StageInputs {
            init: init.as_ref(),
            replay: Some(&batch),
            replay_options: ReplayOptions {
                steps: config.curriculum.replay_steps_per_iteration,
                imitation_coef: config.curriculum.replay_imitation_coef,
                balance: config.curriculum.replay_balance,
            },
            labels: labels.as_ref(),
            label_options: ReplayOptions {
                steps: config.curriculum.label_steps_per_iteration,
                imitation_coef: config.curriculum.label_imitation_coef,
                balance: ReplayBalance::Trajectory,
            },
            // Read from the curriculum section directly, so a resume must keep them.
            resume_keeps: &[
                "replay_steps_per_iteration",
                "primary_init",
                "replay_imitation_coef",
                "replay_balance",
                "label_steps_per_iteration",
                "label_imitation_coef",
            ],
            ..StageInputs::default()
        },
    )?;
    report_stage("primary", &summary);
    Ok(summary)
}

/// The whole pipeline: secondary policies, trajectory batch, primary policy.
pub fn run_all(config: &TrainConfig, opts: &CurriculumOptions) -> Result<RunSummary, TrainError> {
    std::fs::create_dir_all(&opts.out).map_err(|e| TrainError::io(&opts.out, "create", e))?;
    run_secondary(config, opts)?;
    run_randomize(config, opts)?;
    run_primary(config, opts)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn secondaries_train_on_their_behaviour_alone_at_the_constant_rate() {
        let path = concat!(env!("CARGO_MANIFEST_DIR"), "/../configs/shipped.toml");
        let mut config = TrainConfig::load(std::path::Path::new(path)).unwrap();
        assert!(config.run.composed_share > 0.0 && config.ppo.learning_rate_final.is_some());
        config.curriculum.secondary_stop_success_rate = 0.95;
        for (first, behaviour) in [
            (true, Behaviour::Straight),
            (false, Behaviour::LiftOver),
            (false, Behaviour::Squeeze),
        ] {
            let stage = secondary_stage(&config, behaviour, first);
            assert_eq!(stage.run.scene_kind, behaviour.name());
            assert_eq!(stage.run.composed_share, 0.0);
            assert_eq!(stage.ppo.learning_rate_final, None);
            // Squeeze's start stages need more steps to reach the task as specified, and lift's
            // secondary more to learn it well enough for the batch (configs/shipped.toml).
            let budget = match behaviour {
                Behaviour::LiftOver => 1_500_000,
                Behaviour::Squeeze => 2_500_000,
                _ => config.curriculum.secondary_env_steps,
            };
            assert_eq!(stage.run.total_env_steps, budget);
            // Each stops once learnt but the straight-line policy the others start from.
            let stop = if first { 0.0 } else { 0.95 };
            assert_eq!(stage.run.stop_success_rate, stop, "{}", behaviour.name());
            stage.validate().unwrap();
        }
    }
    #[test]
    fn a_behaviour_without_trajectories_stops_the_batch_naming_it() {
        let out =
            std::env::temp_dir().join(format!("wheelleg-no-trajectories-{}", std::process::id()));
        let config = TrainConfig::default();
        let behaviours = behaviours(&config).unwrap();
        // Files as a secondary writes them when it stored no episode.
        let empty = RandomizeConfig {
            per_trajectory: 0,
            include_original: true,
            ..RandomizeConfig::default()
        };
        for &behaviour in &behaviours {
            let dir = secondary_dir(&out, behaviour);
            std::fs::create_dir_all(&dir).unwrap();
            randomize_batch_with(&[], &empty, &dir.join(TRAJECTORIES_FILE), |_| {}).unwrap();
        }
        let e = stored_trajectories(&config, &out).unwrap_err();
        let _ = std::fs::remove_dir_all(&out);
        let first = behaviours[0].name();
        assert!(
            matches!(&e, TrainError::NoTrajectories { behaviour, .. } if *behaviour == first),
            "{e}"
        );
        let e = e.to_string();
        assert!(e.contains(&format!("secondary {first} stored no")), "{e}");
        assert!(
            e.contains(&format!("secondary_env_steps_by_behaviour.{first}")),
            "{e}"
        );
    }

    use crate::network::init_policy;
    use crate::network_f32::Architecture;
    use rand::SeedableRng;

    #[test]
    fn softening_keeps_each_heads_ranking_and_flattens_its_distribution() {
        let arch = Architecture::default_policy();
        let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(3);
        let sharp = init_policy(&arch, &mut rng);
        let mut soft = sharp.clone();
        soften_action_head(&mut soft, 10.0);
        let height_m: Vec<f32> = (0..32 * 32).map(|i| (i % 7) as f32 * 0.03).collect();
        let state = vec![0.12, 0.36, 0.8, -0.1];
        let (a, _) = sharp.forward(&height_m, &state);
        let (b, _) = soft.forward(&height_m, &state);
        for (x, y) in a.iter().zip(&b) {
            assert!((x / 10.0 - y).abs() < 1e-5, "{x} / 10 != {y}");
        }
        assert_eq!(sharp.convs, soft.convs, "only the action head changes");
    }
}
