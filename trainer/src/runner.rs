//! The training loop, top to bottom like the paper's Algorithm 1 for one scene family:
//! sample trajectories with the current policy in many environments, compute returns and
//! advantages, update by PPO; log every iteration, checkpoint at an interval.
//!
//! Run folder: `config.toml` (the config used), `metrics.jsonl` (one JSON object per
//! iteration), `checkpoint.ckpt` (latest checkpoint, atomic).

use crate::checkpoint::{Checkpoint, CheckpointExtras, NetworkRecord, StartStageState};
use crate::config::TrainConfig;
use crate::error::TrainError;
use crate::network::{init_policy, BackendKind};
use crate::network_f32::NetworkF32;
use crate::ppo::Ppo;
use crate::replay::{replay_samples, ReplayOptions};
use crate::storage::RolloutStorage;
use crate::trajectory::batch_file::{partial_path, TrajectoryBatch};
use crate::trajectory::randomize::{randomize_batch_with, RandomizeConfig};
use crate::trajectory::Trajectory;
use crate::vec_env::{EpisodeStats, Scenes, SolvedEpisode, VecEnv};
use indicatif::{ProgressBar, ProgressStyle};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::collections::VecDeque;
use std::path::{Path, PathBuf};
use std::time::Instant;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_sim::env::EnvConfig;
use wheelleg_sim::generate::{Behaviour, SceneKind};

/// Name of the latest checkpoint in a run folder.
pub const CHECKPOINT_FILE: &str = "checkpoint.ckpt";
/// Name of the stored successful trajectories in a run folder (a trajectory batch file).
pub const TRAJECTORIES_FILE: &str = "trajectories.wltb";
/// Name of the metrics log in a run folder.
pub const METRICS_FILE: &str = "metrics.jsonl";

pub mod learnt;
mod metrics;
pub mod start_stage;

pub use learnt::LearntRule;
pub use start_stage::StartStageSchedule;

use metrics::{append_metrics, truncate_metrics};
pub use metrics::{read_metrics, summarise, IterationMetrics, IterationTime};

/// Options of a run besides the config.
#[derive(Clone, Debug)]
pub struct RunOptions {
    /// Run folder.
    pub out: PathBuf,
    /// Seed of every random choice.
    pub seed: u64,
    /// Continue from the folder's checkpoint.
    pub resume: bool,
    /// Draw a progress bar.
    pub progress: bool,
    /// Stop after this many iterations in this process (tests of resume; `None`: run to the
    /// budget).
    pub max_iterations: Option<u64>,
    /// Stop, with a checkpoint, once the run has this many env steps, short of its budget (a
    /// comparison at a smaller budget; `--resume` later goes on to the config's total, on the
    /// same schedules). `None`: run to the budget.
    pub stop_at_env_steps: Option<u64>,
    /// Label stored in checkpoints.
    pub kind: String,
}

/// Where a run ended.
#[derive(Clone, Debug)]
pub struct RunSummary {
    /// Iterations completed in total.
    pub iterations: u64,
    /// Environment steps taken in total.
    pub env_steps: u64,
    /// The last iteration's metrics.
    pub last: Option<IterationMetrics>,
    /// The checkpoint file.
    pub checkpoint: PathBuf,
}

/// What the paper's method adds to a plain PPO run; the default (nothing) is the baseline.
#[derive(Clone, Copy, Default)]
pub struct StageInputs<'a> {
    /// Parameters a fresh run starts from instead of a random init (Algorithm 1: the other
    /// behaviours start from the straight-line policy; Algorithm 2: optionally the primary).
    pub init: Option<&'a NetworkF32>,
    /// Algorithm 2: every update also learns from `replay_steps` samples of this batch.
    pub replay: Option<&'a TrajectoryBatch>,
    /// How many replayed samples per iteration, drawn and weighed how.
    pub replay_options: ReplayOptions,
    /// Expert iteration: every update also learns from `label_options.steps` samples of these
    /// expert labels, drawn and weighed as `label_options` says.
    pub labels: Option<&'a TrajectoryBatch>,
    /// How many expert-labelled samples per iteration, drawn and weighed how.
    pub label_options: ReplayOptions,
    /// Algorithm 1: keep the latest `keep_trajectories` successful, collision-free episodes,
    /// labelled with this behaviour, in the run folder's [`TRAJECTORIES_FILE`].
    pub record: Option<Behaviour>,
    /// How many trajectories `record` keeps.
    pub keep_trajectories: usize,
    /// `[curriculum]` keys this stage reads directly, which a resume must therefore keep
    /// (see [`TrainConfig::changes_from_stored`]).
    pub resume_keeps: &'a [&'a str],
}

/// Trains a policy with PPO on fresh scenes of `config.run.scene_kind` (the baseline).
pub fn train(config: &TrainConfig, opts: &RunOptions) -> Result<RunSummary, TrainError> {
    train_stage(config, opts, StageInputs::default())
}

/// [`train`] with the additions of a curriculum stage.
pub fn train_stage(
    config: &TrainConfig,
    opts: &RunOptions,
    inputs: StageInputs<'_>,
) -> Result<RunSummary, TrainError> {
    config.validate()?;
    let run = &config.run;
    let kind = SceneKind::from_name(&run.scene_kind).ok_or_else(|| {
        TrainError::setting(
            "run.scene_kind",
            format!("{:?} is no kind of scene", run.scene_kind),
        )
    })?;
    wheelleg_sim::generate::SceneRobot::of(&config.simulated_robot()?)
        .has_kind(kind)
        .map_err(|why| {
            TrainError::setting(
                "run.scene_kind",
                format!(
                    "{}: robot '{}' has no such scenes: {why}",
                    run.scene_kind, config.robot.name
                ),
            )
        })?;
    let device = BackendKind::from_name(&run.backend)?.device()?;
    std::fs::create_dir_all(&opts.out).map_err(|e| TrainError::io(&opts.out, "create", e))?;
    let ckpt_path = opts.out.join(CHECKPOINT_FILE);
    let metrics_path = opts.out.join(METRICS_FILE);
    let env_config = config.episode_rules()?;
    let steps_per_env = config.steps_per_env();
    let n = run.num_envs;

    // Every random choice derives from the seed: network init, scene streams, action sampling
    // and minibatch shuffles.
    let mut sampler = ChaCha8Rng::seed_from_u64(opts.seed);
    sampler.set_stream(1);
    let mut init_rng = ChaCha8Rng::seed_from_u64(opts.seed);
    init_rng.set_stream(2);
    let env_seed = opts
        .seed
        .wrapping_mul(0x9E37_79B9_7F4A_7C15)
        .wrapping_add(3);
    let mut schedule = StartStageSchedule::of_run(run);
    let mut learnt = LearntRule::of_run(run);
    let scenes = Scenes {
        kind,
        start_yaw: config.start_yaw(),
        stage: schedule.as_ref().map_or(1.0, StartStageSchedule::stage),
        composed_share: mix_at(run, 0).0,
        exit_share: mix_at(run, 0).1,
        exit_behaviour: exit_behaviour(run)?,
    };
    let mut envs = VecEnv::with_scenes(scenes, n, env_seed, env_config, run.threads)?;
    if run.failure_resample_probability > 0.0 {
        envs.set_failure_memory(run.failure_memory_per_env, run.failure_resample_probability);
    }
    let random_init = init_policy(&config.architecture(), &mut init_rng);
    let mut ppo = Ppo::new(
        inputs.init.cloned().unwrap_or(random_init),
        config.ppo.clone(),
        device,
    )?;
    let trajectories_path = opts.out.join(TRAJECTORIES_FILE);
    let mut solved: VecDeque<Trajectory> = VecDeque::new();
    let (mut iteration, mut env_steps, mut elapsed_before) = (0u64, 0u64, 0.0f64);

    if opts.resume {
        let (c, extras) = Checkpoint::load_with_extras(&ckpt_path)?;
        // The robot first: a run on another robot differs in `run.robot` too, and the
        // message that names both robots says more.
        extras.check_robot(&config.robot, &ckpt_path.display().to_string())?;
        let changes = config
            .changes_from_stored(&c.config_toml, inputs.resume_keeps)
            .map_err(|e| TrainError::in_file(&ckpt_path, e))?;
        if !changes.is_empty() {
            return Err(TrainError::ConfigChanged {
                checkpoint: ckpt_path,
                changes,
                config: opts.out.join("config.toml"),
            });
        }
        if c.seed != opts.seed {
            return Err(TrainError::SeedChanged {
                checkpoint: ckpt_path,
                stored: c.seed,
                requested: opts.seed,
            });
        }
        ppo.net = c.network.to_network()?;
        ppo.adam = c.adam;
        sampler.set_word_pos(c.sampler_word_pos);
        envs.restore(env_seed, &c.envs)?;
        if let Some(schedule) = schedule.as_mut() {
            let state = extras.start_stage.ok_or_else(|| TrainError::NoStartStage {
                checkpoint: ckpt_path.clone(),
            })?;
            schedule.restore(state.stage, &state.window)?;
            envs.set_stage(state.stage);
            envs.set_env_stages(&state.env_stages)?;
        }
        // A run continued with re-sampling newly turned on starts with empty memories.
        if let (true, Some(failures)) = (run.failure_resample_probability > 0.0, &extras.failures) {
            envs.restore_failures(failures)?;
        }
        (iteration, env_steps, elapsed_before) = (c.iteration, c.env_steps, c.elapsed_s);
        if inputs.record.is_some() && trajectories_path.exists() {
            let stored = TrajectoryBatch::load(&trajectories_path)?;
            solved.extend((0..stored.len()).filter_map(|i| stored.trajectory(i)));
        }
        truncate_metrics(&metrics_path, iteration)?;
        if let Some(learnt) = learnt.as_mut() {
            learnt.restore(&read_metrics(&opts.out)?);
        }
        // A resume may change the budget and the other resumable keys: the folder's config
        // then says what the run now is, as the checkpoint does.
        write_config(config, &opts.out)?;
    } else {
        if ckpt_path.exists() {
            return Err(TrainError::RunExists {
                out: opts.out.clone(),
            });
        }
        write_config(config, &opts.out)?;
        let _ = std::fs::remove_file(&metrics_path);
    }

    let bar = if opts.progress {
        ProgressBar::new(run.total_env_steps)
    } else {
        ProgressBar::hidden()
    };
    // A constant template, so it parses; the default bar stands in should indicatif refuse it.
    let style = ProgressStyle::with_template(
        "{elapsed_precise} [{bar:30}] {human_pos}/{human_len} steps, ETA {eta} | {msg}",
    )
    .unwrap_or_else(|_| ProgressStyle::default_bar());
    bar.set_style(style.progress_chars("=> "));
    bar.set_position(env_steps);

    let mut storage = RolloutStorage::new(n, steps_per_env);
    let mut heights = vec![0.0f32; n * HEIGHT_MAP_CELLS];
    let mut states = vec![0.0f32; n * STATE_LEN];
    envs.observe(&mut heights, &mut states);
    let start = Instant::now();
    let mut last = None;
    let mut iterations_here = 0;
    let stop_at = opts
        .stop_at_env_steps
        .map_or(run.total_env_steps, |s| s.min(run.total_env_steps));
    // A run that records trajectories has learnt only once it holds all it keeps.
    let has_learnt = |learnt: &Option<LearntRule>, solved: &VecDeque<Trajectory>| {
        learnt.as_ref().is_some_and(LearntRule::reached)
            && (inputs.record.is_none() || solved.len() >= inputs.keep_trajectories)
    };
    while env_steps < stop_at
        && !has_learnt(&learnt, &solved)
        && opts.max_iterations.is_none_or(|m| iterations_here < m)
    {
        let iter_start = Instant::now();
        let mut time = IterationTime::default();
        let (composed_share, exit_share) = mix_at(run, env_steps);
        envs.set_composed_share(composed_share);
        envs.set_exit_share(exit_share);
        // 1. Sample trajectories with the current policy.
        storage.clear();
        let mut episodes = Vec::new();
        let stage_now = envs.stage();
        for _ in 0..steps_per_env {
            let acting = Instant::now();
            let acted = ppo.act(&heights, &states, n, &mut sampler)?;
            time.act_s += acting.elapsed().as_secs_f64();
            let (obs_h, obs_s) = (heights.clone(), states.clone());
            let stepping = Instant::now();
            let results = envs.step(&acted.choices, &mut heights, &mut states);
            time.env_s += stepping.elapsed().as_secs_f64();
            let rewards: Vec<f32> = results.iter().map(|r| r.reward).collect();
            let dones: Vec<bool> = results.iter().map(|r| r.done).collect();
            episodes.extend(results.iter().filter_map(|r| r.episode));
            if let Some(behaviour) = inputs.record {
                // Only full-task episodes: the trajectory batch stands for the task as specified,
                // and a staged start (legs already spread, inside the passage) is not one.
                for episode in results.into_iter().filter_map(|r| r.success) {
                    let SolvedEpisode {
                        scenario,
                        actions,
                        stage,
                    } = *episode;
                    if stage < 1.0 {
                        continue;
                    }
                    solved.push_back(Trajectory::new(scenario, actions, behaviour));
                    if solved.len() > inputs.keep_trajectories {
                        solved.pop_front();
                    }
                }
            }
            storage.push_step(
                &obs_h,
                &obs_s,
                &acted.choices,
                &acted.log_probs,
                &acted.values,
                &rewards,
                &dones,
            );
        }
        // 2. Returns and advantages (GAE), bootstrapped with the value of where each env stands.
        let acting = Instant::now();
        let last_values = ppo.evaluate(&heights, &states, n)?.values;
        time.act_s += acting.elapsed().as_secs_f64();
        storage.compute_returns(&last_values, config.ppo.gamma, config.ppo.gae_lambda);
        // 3. PPO update, on the on-policy samples plus (Algorithm 2) replayed ones whose
        //    advantages come from the current value function.
        ppo.config.learning_rate = config.ppo.learning_rate_at(env_steps, run.total_env_steps);
        let mut mixed = None;
        let replaying = Instant::now();
        for (batch, options) in [
            (inputs.replay, &inputs.replay_options),
            (inputs.labels, &inputs.label_options),
        ] {
            if let Some(batch) = batch {
                let samples = replay_samples(&ppo, batch, options, &mut sampler)?;
                mixed
                    .get_or_insert_with(|| storage.samples.clone())
                    .extend(&samples);
                time.replay_s = replaying.elapsed().as_secs_f64();
            }
        }
        let updating = Instant::now();
        let update = ppo.update(mixed.as_ref().unwrap_or(&storage.samples), &mut sampler)?;
        time.update_s = updating.elapsed().as_secs_f64();

        iteration += 1;
        iterations_here += 1;
        env_steps += (n * steps_per_env) as u64;
        let elapsed_s = elapsed_before + start.elapsed().as_secs_f64();
        let (mean_return, success_rate, collision_free_rate, mean_success_steps) =
            summarise(&episodes);
        // The stage advances on the episodes that started at it (some that end now were drawn
        // before the last advance).
        let stage_success = schedule.as_mut().map(|schedule| {
            let at_stage: Vec<&EpisodeStats> =
                episodes.iter().filter(|e| e.stage == stage_now).collect();
            let successes = at_stage.iter().filter(|e| e.success).count() as u32;
            if schedule.record(successes, at_stage.len() as u32) {
                envs.set_stage(schedule.stage());
            }
            successes as f32 / at_stage.len().max(1) as f32
        });
        if let Some(learnt) = learnt.as_mut() {
            learnt.record(success_rate, schedule.as_ref().map(|_| stage_now));
        }
        let m = IterationMetrics {
            iteration,
            env_steps,
            episodes: episodes.len(),
            mean_return,
            success_rate,
            collision_free_rate,
            mean_success_steps,
            update,
            steps_per_s: (n * steps_per_env) as f32 / iter_start.elapsed().as_secs_f32(),
            time,
            elapsed_s,
            start_stage: schedule.as_ref().map(|_| stage_now),
            start_stage_success_rate: stage_success,
        };
        append_metrics(&metrics_path, &m)?;
        bar.set_position(env_steps.min(run.total_env_steps));
        bar.set_message(format!(
            "it {iteration} success {:.0}% coll-free {:.0}% return {:.2} {:.0} steps/s{}",
            100.0 * success_rate,
            100.0 * collision_free_rate,
            mean_return,
            m.steps_per_s,
            schedule
                .as_ref()
                .map_or(String::new(), |s| format!(" stage {:.2}", s.stage()))
        ));
        last = Some(m);
        let finished = env_steps >= stop_at
            || has_learnt(&learnt, &solved)
            || opts.max_iterations.is_some_and(|mx| iterations_here >= mx);
        if iteration % run.checkpoint_interval as u64 == 0 || finished {
            if inputs.record.is_some() {
                save_trajectories(
                    &trajectories_path,
                    solved.make_contiguous(),
                    env_config,
                    &config.robot,
                )?;
            }
            let extras = CheckpointExtras {
                start_stage: schedule.as_ref().map(|s| StartStageState {
                    stage: s.stage(),
                    window: s.window(),
                    env_stages: envs.env_stages(),
                }),
                failures: (run.failure_resample_probability > 0.0).then(|| envs.failure_snapshot()),
                robot: CheckpointExtras::robot_record(&config.robot),
            };
            Checkpoint {
                kind: opts.kind.clone(),
                config_toml: config.to_toml(),
                seed: opts.seed,
                iteration,
                env_steps,
                network: NetworkRecord::from_network(&ppo.net),
                adam: ppo.adam.clone(),
                sampler_word_pos: sampler.get_word_pos(),
                envs: envs.snapshot(),
                elapsed_s,
            }
            .save_with(&ckpt_path, &extras)?;
        }
    }
    bar.finish();
    Ok(RunSummary {
        iterations: iteration,
        env_steps,
        last,
        checkpoint: ckpt_path,
    })
}

/// The shares of composed and exit scenes for episodes drawn after `env_steps` env steps of the
/// run: `run.composed_share` and `run.exit_share` from `run.composed_from_env_steps` on, none
/// before.
fn mix_at(run: &crate::config::RunConfig, env_steps: u64) -> (f64, f64) {
    if env_steps >= run.composed_from_env_steps {
        (run.composed_share, run.exit_share)
    } else {
        (0.0, 0.0)
    }
}

/// The fence of the run's exit scenes (`run.exit_behaviour`).
fn exit_behaviour(run: &crate::config::RunConfig) -> Result<Behaviour, TrainError> {
    Behaviour::from_name(&run.exit_behaviour)
        .filter(|b| b.has_fence())
        .ok_or_else(|| {
            TrainError::setting(
                "run.exit_behaviour",
                format!("no fence named {:?}", run.exit_behaviour),
            )
        })
}

/// Writes the run's config into its folder (atomically), as `config.toml`.
fn write_config(config: &TrainConfig, out: &Path) -> Result<(), TrainError> {
    let path = out.join("config.toml");
    wheelleg_sim::atomic_write(&path, config.to_toml().as_bytes())
        .map_err(|e| TrainError::io(&path, "write", e))
}

/// Writes the stored trajectories as a trajectory batch of originals only (no randomized
/// scenes), beside the checkpoint: to a fresh temporary file, then renamed over the old one, so a
/// crash leaves the previous set.
fn save_trajectories(
    path: &Path,
    trajectories: &[Trajectory],
    env: EnvConfig,
    robot: &wheelleg_robot::RobotDescription,
) -> Result<(), TrainError> {
    let temp = path.with_extension("new");
    let _ = std::fs::remove_file(&temp);
    let _ = std::fs::remove_file(partial_path(&temp));
    let config = RandomizeConfig {
        per_trajectory: 0,
        include_original: true,
        env,
        robot: robot.clone(),
        ..RandomizeConfig::default()
    };
    randomize_batch_with(trajectories, &config, &temp, |_| {})?;
    std::fs::rename(&temp, path).map_err(|e| TrainError::io(path, "write", e))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn composed_scenes_start_at_their_env_step() {
        let mut run = crate::config::RunConfig {
            composed_share: 0.5,
            ..Default::default()
        };
        assert_eq!(mix_at(&run, 0).0, 0.5, "from the start by default");
        run.composed_from_env_steps = 10_000_000;
        assert_eq!(mix_at(&run, 0).0, 0.0);
        assert_eq!(mix_at(&run, 9_990_000).0, 0.0);
        assert_eq!(mix_at(&run, 10_000_000).0, 0.5);
        assert_eq!(mix_at(&run, 29_000_000).0, 0.5);
    }
}
