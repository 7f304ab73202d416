//! Every hyperparameter of a training run, read from a TOML file.
//!
//! Defaults follow the paper where it gives a value (batch of 10,000 environment steps for the
//! baseline, the reward of the simulator) and common PPO practice elsewhere. Unknown keys are
//! refused so a typo never silently falls back to a default.

use crate::replay::ReplayBalance;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// PPO's hyperparameters (the reusable core: the curriculum uses the same ones).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct PpoConfig {
    /// Adam learning rate (at `anneal_start_env_steps` and before, when annealed).
    pub learning_rate: f64,
    /// The learning rate reached at `run.total_env_steps`, linearly from `learning_rate` at
    /// `anneal_start_env_steps` (CleanRL's `anneal_lr`, over a chosen span so that a
    /// continued run anneals over its own steps). `None`, the default: constant. A finished run
    /// may be continued with it changed (`--resume`).
    pub learning_rate_final: Option<f64>,
    /// Where the anneal to `learning_rate_final` starts, in env steps.
    pub anneal_start_env_steps: u64,
    /// Adam epsilon.
    pub adam_epsilon: f64,
    /// Discount factor gamma.
    pub gamma: f32,
    /// GAE lambda. 1.0 gives the paper's A = R - V (Monte-Carlo return minus value); the
    /// default 0.95 trades a little bias for much less variance.
    pub gae_lambda: f32,
    /// Clip range epsilon of the probability ratio (Eq. 1).
    pub clip_epsilon: f32,
    /// Weight of the surrogate, lambda_1 of Eq. 2.
    pub policy_coef: f32,
    /// Weight of the value loss, lambda_2 of Eq. 2.
    pub value_coef: f32,
    /// Weight of the entropy bonus.
    pub entropy_coef: f32,
    /// Passes over each batch.
    pub epochs: usize,
    /// Samples per gradient step.
    pub minibatch_size: usize,
    /// Global gradient norm limit (0 disables clipping).
    pub max_grad_norm: f32,
    /// Normalise advantages per minibatch to zero mean, unit variance.
    pub normalize_advantages: bool,
    /// Stop the epochs early once the approximate KL(old || new) of a minibatch exceeds this
    /// (0 disables).
    pub target_kl: f32,
    /// Who computes the conv layers, in updates and in `Ppo::evaluate`/`act` (rollouts):
    /// `native` (the specialised im2col + GEMM kernel of `conv_kernel`, the default: measured
    /// faster, docs/decisions.md) or `burn` (burn's conv2d, inside the autodiff graph in
    /// updates). Both give the same results within f32 rounding.
    pub conv_kernel: String,
}

impl Default for PpoConfig {
    fn default() -> Self {
        PpoConfig {
            learning_rate: 3e-4,
            learning_rate_final: None,
            anneal_start_env_steps: 0,
            adam_epsilon: 1e-5,
            gamma: 0.99,
            gae_lambda: 0.95,
            clip_epsilon: 0.2,
            policy_coef: 1.0,
            value_coef: 0.5,
            entropy_coef: 0.01,
            epochs: 4,
            minibatch_size: 256,
            max_grad_norm: 0.5,
            normalize_advantages: true,
            target_kl: 0.03,
            conv_kernel: "native".into(),
        }
    }
}

/// Network sizes (the architecture is stored with every checkpoint, never assumed).
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct NetworkConfig {
    /// Output channels of each stride-2 3x3 conv layer.
    pub conv_channels: Vec<usize>,
    /// Widths of the hidden dense layers.
    pub hidden: Vec<usize>,
}

impl Default for NetworkConfig {
    fn default() -> Self {
        NetworkConfig {
            conv_channels: vec![16, 32, 32],
            hidden: vec![128],
        }
    }
}

/// `run` keys a resumed run may change: its budget, the re-sampling of failed scenes and the
/// share of composed scenes (which only change which scenes come next).
const RESUMABLE_CHANGES: [&str; 4] = [
    "total_env_steps",
    "composed_share",
    "failure_resample_probability",
    "failure_memory_per_env",
];

/// `ppo` keys a resumed run may change: the learning rate's anneal (which only changes the
/// steps to come).
const RESUMABLE_PPO_CHANGES: [&str; 2] = ["learning_rate_final", "anneal_start_env_steps"];

/// The run: budget, scenes, parallelism, logging.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct RunConfig {
    /// Scene kind trained on (`straight`, `around`, `lift`, `spread`, `squeeze`, `complex`).
    pub scene_kind: String,
    /// Environment steps per PPO iteration (the paper's batch: 10,000 for the baseline).
    pub steps_per_iteration: usize,
    /// Environments stepped in lock-step (one batched inference per step).
    pub num_envs: usize,
    /// Total environment steps of the run.
    pub total_env_steps: u64,
    /// Step limit of an episode.
    pub max_episode_steps: u32,
    /// Reward of an undone action (collision, impossible pose, out of bounds). The paper's is
    /// -0.1, the same as one step of time: a collision then costs next to nothing, and policies
    /// learn to feel their way along obstacles (docs/results.md, "Keeping the behaviours").
    pub invalid_reward: f32,
    /// Checkpoint every this many iterations (the last iteration always checkpoints).
    pub checkpoint_interval: usize,
    /// Worker threads stepping environments (std threads, each owns a fixed slice of envs).
    pub threads: usize,
    /// Deep-learning backend: `flex` (default) or `cuda` (with the cargo feature `cuda`).
    pub backend: String,
    /// Start yaw of the training scenes: within this many degrees of the world x axis
    /// (facing the target or away from it); 90 or more: any yaw, the task as specified.
    pub start_yaw_within_deg: f32,
    /// Start-stage curriculum (a reverse curriculum over start states,
    /// `wheelleg_sim::generate::generate_staged`): the stage the run's scenes start at, from 0
    /// (inside the passage, in the behaviour's leg pose) to 1 (the task as specified). 1, the
    /// default, turns it off.
    pub start_stage: f32,
    /// How much the stage grows each time the training success rate passes
    /// `start_stage_success_rate` (capped at 1).
    pub start_stage_step: f32,
    /// Success rate of the episodes started at the current stage, over the last
    /// `start_stage_window` iterations, that advances the stage.
    pub start_stage_success_rate: f32,
    /// Iterations the success rate is measured over (the window restarts after each advance).
    pub start_stage_window: usize,
    /// Algorithm 2's memory of failed configurations: each environment remembers the scenes
    /// it failed (up to `failure_memory_per_env`) and starts its next episode on one of them
    /// with this probability, instead of a fresh scene. 0, the default, turns it off. A
    /// finished run may be continued with it changed (`--resume`).
    pub failure_resample_probability: f64,
    /// Failed scenes each environment remembers (the oldest is forgotten first).
    pub failure_memory_per_env: usize,
    /// Share of episodes drawn as composed scenes (one or two fences amid clutter,
    /// `wheelleg_sim::generate::SceneKind::Composed`) instead of `scene_kind`. 0, the default,
    /// draws `scene_kind` alone. A finished run may be continued with it changed (`--resume`).
    pub composed_share: f64,
}

impl Default for RunConfig {
    fn default() -> Self {
        RunConfig {
            scene_kind: "complex".into(),
            steps_per_iteration: 10_000,
            num_envs: 50,
            total_env_steps: 5_000_000,
            max_episode_steps: 100,
            invalid_reward: -0.1,
            checkpoint_interval: 5,
            threads: 2,
            backend: "flex".into(),
            start_yaw_within_deg: 180.0,
            start_stage: 1.0,
            start_stage_step: 0.1,
            start_stage_success_rate: 0.5,
            start_stage_window: 3,
            failure_resample_probability: 0.0,
            failure_memory_per_env: 8,
            composed_share: 0.0,
        }
    }
}

/// The paper's method around PPO (Algorithms 1 and 2): secondary policies, the
/// domain-randomized trajectory batch, and the primary policy's mixed batches. Used by
/// `wheelleg train secondary|randomize|primary|all`; the baseline ignores it.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct CurriculumConfig {
    /// Behaviours trained as secondary policies, straight first (the others start from it).
    pub behaviours: Vec<String>,
    /// Environment steps per PPO iteration of a secondary policy (the paper: 3,000).
    pub secondary_steps_per_iteration: usize,
    /// Environment steps of each secondary policy.
    pub secondary_env_steps: u64,
    /// Environment steps of the named secondaries, instead of `secondary_env_steps` (a
    /// behaviour that learns slower gets more without retraining the others; extending it on
    /// `--resume` continues that secondary alone). Default none.
    pub secondary_env_steps_by_behaviour: BTreeMap<String, u64>,
    /// Latest successful, collision-free trajectories kept per secondary policy.
    pub keep_trajectories: usize,
    /// Randomized scenes tried per stored trajectory (the paper: 1,000).
    pub randomizations: usize,
    /// Replayed steps added to each primary iteration's on-policy batch (the paper: 2,000).
    pub replay_steps_per_iteration: usize,
    /// Weight of a behaviour-cloning term on the replayed samples (0: the paper's
    /// Algorithm 2). See `crate::replay` for why the surrogate alone lets rare behaviours fade.
    pub replay_imitation_coef: f32,
    /// How replayed trajectories are drawn: `trajectory` (uniformly, the paper) or
    /// `behaviour` (each behaviour an equal share).
    pub replay_balance: ReplayBalance,
    /// Where the primary policy starts: `scratch` or a behaviour's secondary policy.
    pub primary_init: String,
    /// Softmax temperature applied to the straight-line policy's action head when another
    /// secondary policy starts from it (1 = copied as is, the paper). A converged straight
    /// policy is nearly deterministic and, in a scene where driving straight collides, it
    /// never samples the way around: curriculum-s0 found 0% success for `around` after
    /// 300k steps at 1. Dividing the head by a temperature keeps what the features learned
    /// and gives the sampling back its spread.
    pub secondary_init_temperature: f32,
    /// Entropy coefficient of the secondary policies that start from the straight-line
    /// policy (the straight one uses `ppo.entropy_coef`), for the same reason.
    pub secondary_entropy_coef: f32,
    /// `run.start_yaw_within_deg` of the secondary policies that start from the straight-line
    /// one (see `wheelleg_sim::generate::StartYaw::AlongX` for why): 180 keeps any yaw.
    pub secondary_start_yaw_within_deg: f32,
    /// Behaviours whose secondary policy trains with the start-stage curriculum (see
    /// `run.start_stage`): spread and squeeze need a leg pose far from the default before the
    /// first reward, which sampling from the straight-line policy never found. Default none.
    pub start_stage_behaviours: Vec<String>,
    /// `run.start_stage` of those secondaries: where their curriculum starts.
    pub start_stage_initial: f32,
    /// `run.start_stage_step` of those secondaries.
    pub start_stage_step: f32,
    /// `run.start_stage_success_rate` of those secondaries.
    pub start_stage_success_rate: f32,
    /// `run.start_stage_window` of those secondaries.
    pub start_stage_window: usize,
}

impl Default for CurriculumConfig {
    fn default() -> Self {
        CurriculumConfig {
            behaviours: ["straight", "around", "lift", "spread", "squeeze"]
                .map(String::from)
                .to_vec(),
            secondary_steps_per_iteration: 3_000,
            secondary_env_steps: 300_000,
            secondary_env_steps_by_behaviour: BTreeMap::new(),
            keep_trajectories: 1_000,
            randomizations: 1_000,
            replay_steps_per_iteration: 2_000,
            replay_imitation_coef: 0.0,
            replay_balance: ReplayBalance::Trajectory,
            primary_init: "scratch".into(),
            secondary_init_temperature: 1.0,
            secondary_entropy_coef: 0.003,
            secondary_start_yaw_within_deg: 180.0,
            start_stage_behaviours: Vec::new(),
            start_stage_initial: 0.0,
            start_stage_step: 0.1,
            start_stage_success_rate: 0.5,
            start_stage_window: 3,
        }
    }
}

/// A whole training configuration file.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize, Default)]
#[serde(deny_unknown_fields, default)]
pub struct TrainConfig {
    /// The run.
    pub run: RunConfig,
    /// PPO.
    pub ppo: PpoConfig,
    /// The network.
    pub network: NetworkConfig,
    /// The curriculum (secondary policies, randomization, primary policy).
    pub curriculum: CurriculumConfig,
}

/// How many `extends` a config may chain: more is a cycle or a mistake.
const MAX_EXTENDS: usize = 8;

/// Keys of experiments that measured no gain and left the code (docs/results.md, "Experiments
/// that measured no gain"), with the value that kept each off (`None`: a parameter of the
/// experiment, meaningless without it). Configs and checkpoints written while they existed
/// still load: a retired key holding its off value is dropped, one that would switch the
/// experiment on is an error naming it.
const RETIRED_KEYS: [(&str, &str, Option<RetiredOff>); 4] = [
    (
        "curriculum",
        "planner_demonstrations",
        Some(RetiredOff::Integer(0)),
    ),
    ("curriculum", "planner_demo_expansions", None),
    ("curriculum", "planner_demo_target_beside_only", None),
    (
        "curriculum",
        "replay_planner_share",
        Some(RetiredOff::Float(0.0)),
    ),
];

/// The value that kept a retired experiment off.
#[derive(Clone, Copy)]
enum RetiredOff {
    Integer(i64),
    Float(f64),
}

/// Drops the retired keys from a config's table, or names one that would switch a removed
/// experiment on.
fn drop_retired(table: &mut toml::Table) -> Result<(), String> {
    for (section, key, off) in RETIRED_KEYS {
        let Some(toml::Value::Table(keys)) = table.get_mut(section) else {
            continue;
        };
        let Some(value) = keys.remove(key) else {
            continue;
        };
        let is_off = match (off, &value) {
            (None, _) => true,
            (Some(RetiredOff::Integer(off)), toml::Value::Integer(v)) => *v == off,
            (Some(RetiredOff::Float(off)), toml::Value::Float(v)) => *v == off,
            (Some(RetiredOff::Float(off)), toml::Value::Integer(v)) => *v as f64 == off,
            _ => false,
        };
        if !is_off {
            return Err(format!(
                "{section}.{key} = {value}: that experiment measured no gain and was removed \
                 (docs/results.md, \"Experiments that measured no gain\"); drop the key"
            ));
        }
    }
    Ok(())
}

/// Parses a config's TOML text into its table, retired keys dropped.
fn parse_table(text: &str) -> Result<toml::Table, String> {
    let mut table: toml::Table = text.parse().map_err(|e: toml::de::Error| e.to_string())?;
    drop_retired(&mut table)?;
    Ok(table)
}

/// A config file's keys with its `extends` chain merged beneath them.
fn load_table(path: &Path, depth: usize) -> Result<toml::Table, String> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| format!("cannot read config {}: {e}", path.display()))?;
    let mut table = parse_table(&text).map_err(|e| format!("config {}: {e}", path.display()))?;
    let base = match table.remove("extends") {
        None => return Ok(table),
        Some(toml::Value::String(base)) => base,
        Some(other) => {
            return Err(format!(
                "config {}: extends must name a config file, not {other}",
                path.display()
            ))
        }
    };
    if depth >= MAX_EXTENDS {
        return Err(format!(
            "config {}: more than {MAX_EXTENDS} configs extend one another (a cycle?)",
            path.display()
        ));
    }
    let base_path = path.parent().unwrap_or(Path::new(".")).join(&base);
    let mut merged = load_table(&base_path, depth + 1)
        .map_err(|e| format!("config {} extends {base}: {e}", path.display()))?;
    merge_over(&mut merged, table);
    Ok(merged)
}

/// `over`'s keys replace `base`'s; tables merge key by key.
fn merge_over(base: &mut toml::Table, over: toml::Table) {
    for (key, value) in over {
        match (base.get_mut(&key), value) {
            (Some(toml::Value::Table(below)), toml::Value::Table(above)) => {
                merge_over(below, above)
            }
            (_, value) => {
                base.insert(key, value);
            }
        }
    }
}

impl PpoConfig {
    /// The learning rate of the update after `env_steps` env steps of a run of
    /// `total_env_steps`.
    pub fn learning_rate_at(&self, env_steps: u64, total_env_steps: u64) -> f64 {
        let Some(last) = self.learning_rate_final else {
            return self.learning_rate;
        };
        let start = self.anneal_start_env_steps;
        if env_steps <= start || total_env_steps <= start {
            return self.learning_rate;
        }
        let done = ((env_steps - start) as f64 / (total_env_steps - start) as f64).min(1.0);
        self.learning_rate + (last - self.learning_rate) * done
    }
}

impl TrainConfig {
    /// Parses TOML text and validates it.
    pub fn from_toml(text: &str) -> Result<TrainConfig, String> {
        let config: TrainConfig = toml::Value::Table(parse_table(text)?)
            .try_into()
            .map_err(|e: toml::de::Error| e.to_string())?;
        config.validate()?;
        Ok(config)
    }

    /// Reads and validates a config file. A file may start from another: `extends =
    /// "base.toml"` (a path relative to the file's folder) takes every key of the base, and
    /// the file's own keys replace the base's one by one, so a variant names only what it
    /// changes.
    pub fn load(path: &Path) -> Result<TrainConfig, String> {
        let table = load_table(path, 0)?;
        let config: TrainConfig = toml::Value::Table(table)
            .try_into()
            .map_err(|e| format!("config {}: {e}", path.display()))?;
        config
            .validate()
            .map_err(|e| format!("config {}: {e}", path.display()))?;
        Ok(config)
    }

    /// The config as TOML (stored in every checkpoint to detect mismatched resumes).
    pub fn to_toml(&self) -> String {
        toml::to_string(self).unwrap_or_default()
    }

    /// What a resume from a checkpoint written with `stored` (its config text) would change:
    /// one `"section.key: then -> now"` line per differing key, empty when the run may resume.
    /// Compared parsed, so that a checkpoint written before a key existed still matches when
    /// the key holds its default.
    ///
    /// Compared: `[run]` (except `run.total_env_steps`: extending a finished run is what
    /// resuming is for, and the failure re-sampling keys), `[ppo]`, `[network]`, and of `[curriculum]` only `curriculum_keys`.
    /// The rest of the curriculum describes the pipeline around a stage, and `wheelleg train
    /// all` copies what a stage uses of it into that stage's `run` and `ppo`, so tuning a later
    /// stage does not lock out the finished earlier ones; a stage that reads curriculum keys
    /// directly (the primary's replay) names them.
    pub fn changes_from_stored(
        &self,
        stored: &str,
        curriculum_keys: &[&str],
    ) -> Result<Vec<String>, String> {
        let then: TrainConfig = parse_table(stored)
            .and_then(|t| {
                toml::Value::Table(t)
                    .try_into()
                    .map_err(|e: toml::de::Error| e.to_string())
            })
            .map_err(|e| format!("stored config does not parse: {e}"))?;
        let as_table = |c: &TrainConfig| {
            toml::Table::try_from(c).map_err(|e| format!("config does not serialize: {e}"))
        };
        let (then, now) = (as_table(&then)?, as_table(self)?);
        let mut keys: Vec<(&str, String)> = Vec::new();
        for section in ["run", "ppo", "network"] {
            let both = [&then, &now];
            let names = both
                .iter()
                .filter_map(|t| t.get(section).and_then(toml::Value::as_table))
                .flat_map(|t| t.keys().cloned())
                .filter(|k| !(section == "run" && RESUMABLE_CHANGES.contains(&k.as_str())))
                .filter(|k| !(section == "ppo" && RESUMABLE_PPO_CHANGES.contains(&k.as_str())));
            keys.extend(names.map(|k| (section, k)));
        }
        keys.extend(
            curriculum_keys
                .iter()
                .map(|k| ("curriculum", k.to_string())),
        );
        keys.sort();
        keys.dedup();
        let value = |t: &toml::Table, section: &str, key: &str| {
            t.get(section)
                .and_then(toml::Value::as_table)
                .and_then(|s| s.get(key))
                .map_or_else(|| "(none)".to_string(), toml::Value::to_string)
        };
        Ok(keys
            .into_iter()
            .filter_map(|(section, key)| {
                let (a, b) = (value(&then, section, &key), value(&now, section, &key));
                (a != b).then(|| format!("{section}.{key}: {a} -> {b}"))
            })
            .collect())
    }

    /// Checks ranges, naming the offending key.
    pub fn validate(&self) -> Result<(), String> {
        let r = &self.run;
        let p = &self.ppo;
        let check = |ok: bool, what: &str| if ok { Ok(()) } else { Err(what.to_string()) };
        check(
            wheelleg_sim::generate::SceneKind::from_name(&r.scene_kind).is_some(),
            "run.scene_kind must be one of straight, around, lift, spread, squeeze, complex, composed",
        )?;
        check(
            (0.0..=1.0).contains(&r.composed_share),
            "run.composed_share must be between 0 and 1",
        )?;
        check(r.num_envs >= 1, "run.num_envs must be at least 1")?;
        check(
            r.steps_per_iteration >= r.num_envs,
            "run.steps_per_iteration must be at least run.num_envs",
        )?;
        check(
            r.max_episode_steps >= 1,
            "run.max_episode_steps must be at least 1",
        )?;
        check(
            r.invalid_reward.is_finite() && r.invalid_reward <= 0.0,
            "run.invalid_reward must be a number <= 0 (the paper: -0.1)",
        )?;
        check(
            r.checkpoint_interval >= 1,
            "run.checkpoint_interval must be at least 1",
        )?;
        check(r.threads >= 1, "run.threads must be at least 1")?;
        check(
            r.start_yaw_within_deg.is_finite() && r.start_yaw_within_deg >= 0.0,
            "run.start_yaw_within_deg must be a non-negative number of degrees",
        )?;
        check(
            r.start_stage.is_finite() && (0.0..=1.0).contains(&r.start_stage),
            "run.start_stage must be in [0, 1] (1: off)",
        )?;
        check(
            r.start_stage_step.is_finite() && r.start_stage_step > 0.0,
            "run.start_stage_step must be a positive number",
        )?;
        check(
            (0.0..=1.0).contains(&r.start_stage_success_rate),
            "run.start_stage_success_rate must be in [0, 1]",
        )?;
        check(
            r.start_stage_window >= 1,
            "run.start_stage_window must be at least 1",
        )?;
        check(
            (0.0..=1.0).contains(&r.failure_resample_probability),
            "run.failure_resample_probability must be in [0, 1] (0: off)",
        )?;
        crate::network::BackendKind::from_name(&r.backend).map(|_| ())?;
        crate::conv_kernel::ConvKernel::from_name(&p.conv_kernel)
            .map_err(|e| format!("ppo.conv_kernel: {e}"))?;
        check(p.learning_rate > 0.0, "ppo.learning_rate must be positive")?;
        check(
            p.learning_rate_final.is_none_or(|lr| lr >= 0.0),
            "ppo.learning_rate_final must be >= 0",
        )?;
        check(
            p.learning_rate_final.is_none() || p.anneal_start_env_steps < r.total_env_steps,
            "ppo.anneal_start_env_steps must be below run.total_env_steps",
        )?;
        check(
            (0.0..=1.0).contains(&p.gamma),
            "ppo.gamma must be in [0, 1]",
        )?;
        check(
            (0.0..=1.0).contains(&p.gae_lambda),
            "ppo.gae_lambda must be in [0, 1]",
        )?;
        check(p.clip_epsilon > 0.0, "ppo.clip_epsilon must be positive")?;
        check(p.epochs >= 1, "ppo.epochs must be at least 1")?;
        check(
            p.minibatch_size >= 2,
            "ppo.minibatch_size must be at least 2",
        )?;
        check(p.max_grad_norm >= 0.0, "ppo.max_grad_norm must be >= 0")?;
        check(p.target_kl >= 0.0, "ppo.target_kl must be >= 0")?;
        check(
            !self.network.conv_channels.is_empty()
                && self.network.conv_channels.iter().all(|&c| c > 0),
            "network.conv_channels must be non-empty positive widths",
        )?;
        check(
            self.network.hidden.iter().all(|&h| h > 0),
            "network.hidden widths must be positive",
        )?;
        let c = &self.curriculum;
        check(
            c.behaviours.first().map(String::as_str) == Some("straight")
                && c.behaviours.iter().all(|b| {
                    wheelleg_sim::generate::SceneKind::from_name(b)
                        .is_some_and(|k| k != wheelleg_sim::generate::SceneKind::Complex)
                }),
            "curriculum.behaviours must start with straight and name behaviours (straight, \
             around, lift, spread, squeeze)",
        )?;
        check(
            c.secondary_steps_per_iteration >= r.num_envs,
            "curriculum.secondary_steps_per_iteration must be at least run.num_envs",
        )?;
        check(
            c.primary_init == "scratch" || c.behaviours.contains(&c.primary_init),
            "curriculum.primary_init must be scratch or one of curriculum.behaviours",
        )?;
        check(
            c.secondary_init_temperature.is_finite() && c.secondary_init_temperature > 0.0,
            "curriculum.secondary_init_temperature must be a positive number",
        )?;
        check(
            c.replay_imitation_coef.is_finite() && c.replay_imitation_coef >= 0.0,
            "curriculum.replay_imitation_coef must be a non-negative number",
        )?;
        check(
            c.secondary_entropy_coef.is_finite() && c.secondary_entropy_coef >= 0.0,
            "curriculum.secondary_entropy_coef must be a non-negative number",
        )?;
        check(
            c.secondary_start_yaw_within_deg.is_finite() && c.secondary_start_yaw_within_deg >= 0.0,
            "curriculum.secondary_start_yaw_within_deg must be a non-negative number of degrees",
        )?;
        check(
            c.secondary_env_steps_by_behaviour
                .keys()
                .all(|b| c.behaviours.contains(b)),
            "curriculum.secondary_env_steps_by_behaviour must name behaviours of \
             curriculum.behaviours",
        )?;
        check(
            c.start_stage_behaviours
                .iter()
                .all(|b| b != "straight" && c.behaviours.contains(b)),
            "curriculum.start_stage_behaviours must name behaviours of curriculum.behaviours \
             other than straight",
        )?;
        check(
            c.start_stage_initial.is_finite() && (0.0..=1.0).contains(&c.start_stage_initial),
            "curriculum.start_stage_initial must be in [0, 1]",
        )?;
        check(
            c.start_stage_step.is_finite() && c.start_stage_step > 0.0,
            "curriculum.start_stage_step must be a positive number",
        )?;
        check(
            (0.0..=1.0).contains(&c.start_stage_success_rate),
            "curriculum.start_stage_success_rate must be in [0, 1]",
        )?;
        check(
            c.start_stage_window >= 1,
            "curriculum.start_stage_window must be at least 1",
        )?;
        Ok(())
    }

    /// How the training scenes' start yaw is drawn.
    pub fn start_yaw(&self) -> wheelleg_sim::generate::StartYaw {
        wheelleg_sim::generate::StartYaw::within_deg(self.run.start_yaw_within_deg)
    }

    /// Environment steps each env takes per iteration.
    pub fn steps_per_env(&self) -> usize {
        self.run.steps_per_iteration / self.run.num_envs
    }

    /// The architecture these sizes describe.
    pub fn architecture(&self) -> crate::network_f32::Architecture {
        let mut arch = crate::network_f32::Architecture::default_policy();
        let mut in_channels = 1;
        arch.convs = self
            .network
            .conv_channels
            .iter()
            .map(|&out| {
                let spec = crate::network_f32::ConvSpec {
                    in_channels,
                    out_channels: out,
                    kernel: 3,
                    stride: 2,
                    padding: 1,
                };
                in_channels = out;
                spec
            })
            .collect();
        arch.hidden = self.network.hidden.clone();
        arch.value_head = true;
        arch
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn defaults_follow_the_paper_and_round_trip() {
        let c = TrainConfig::default();
        assert_eq!(c.run.steps_per_iteration, 10_000);
        assert_eq!(
            c.architecture(),
            crate::network_f32::Architecture::default_policy()
        );
        assert_eq!(TrainConfig::from_toml(&c.to_toml()).unwrap(), c);
    }

    #[test]
    fn every_shipped_config_and_every_committed_runs_stored_config_loads() {
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("..");
        let mut loaded = 0;
        for entry in std::fs::read_dir(root.join("configs")).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                TrainConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
                loaded += 1;
            }
        }
        assert!(loaded >= 5, "{loaded} configs");
        // What `--resume` reads back from each committed run (written while retired keys
        // existed, so they hold them).
        let mut stored = 0;
        for run in std::fs::read_dir(root.join("runs")).unwrap() {
            let run = run.unwrap().path();
            for path in [run.join("config.toml"), run.join("primary/config.toml")] {
                if let Ok(text) = std::fs::read_to_string(&path) {
                    TrainConfig::from_toml(&text)
                        .unwrap_or_else(|e| panic!("{}: {e}", path.display()));
                    stored += 1;
                }
            }
        }
        assert!(stored >= 3, "{stored} stored configs");
    }

    #[test]
    fn retired_keys_at_their_off_values_load_and_resume_and_switched_on_are_named() {
        let c = TrainConfig::default();
        let retired = "planner_demonstrations = 0\nplanner_demo_expansions = 2000\n\
                       planner_demo_target_beside_only = false\nreplay_planner_share = 0.0\n";
        let stored = c
            .to_toml()
            .replace("[curriculum]\n", &format!("[curriculum]\n{retired}"));
        assert!(stored.contains("planner_demonstrations"), "{stored}");
        assert_eq!(TrainConfig::from_toml(&stored).unwrap(), c);
        assert_eq!(
            c.changes_from_stored(&stored, &["replay_balance"]).unwrap(),
            Vec::<String>::new()
        );
        for on in ["planner_demonstrations = 800", "replay_planner_share = 0.5"] {
            let e = TrainConfig::from_toml(&format!("[curriculum]\n{on}\n")).unwrap_err();
            let key = on.split(' ').next().unwrap();
            assert!(
                e.contains(&format!("curriculum.{key}")) && e.contains("removed"),
                "{e}"
            );
            let e = c
                .changes_from_stored(&format!("[curriculum]\n{on}\n"), &[])
                .unwrap_err();
            assert!(e.contains(key), "{e}");
        }
    }

    #[test]
    fn a_config_extends_its_base_key_by_key_and_a_cycle_is_named() {
        let dir = std::env::temp_dir().join(format!("wheelleg-extends-{}", std::process::id()));
        std::fs::create_dir_all(dir.join("sub")).unwrap();
        let write = |name: &str, text: &str| std::fs::write(dir.join(name), text).unwrap();
        write(
            "base.toml",
            "[run]\ntotal_env_steps = 7000000\nnum_envs = 10\nsteps_per_iteration = 1000\n\
             [ppo]\ngamma = 0.9\n",
        );
        write(
            "sub/variant.toml",
            "extends = \"../base.toml\"\n[run]\ntotal_env_steps = 9000000\n",
        );
        let c = TrainConfig::load(&dir.join("sub/variant.toml")).unwrap();
        assert_eq!(c.run.total_env_steps, 9_000_000, "the variant's own key");
        assert_eq!(c.run.num_envs, 10, "the base's key beside it");
        assert_eq!(c.ppo.gamma, 0.9, "the base's other table");
        assert_eq!(
            c.ppo.epochs,
            PpoConfig::default().epochs,
            "the defaults below both"
        );

        write("a.toml", "extends = \"b.toml\"\n");
        write("b.toml", "extends = \"a.toml\"\n");
        let e = TrainConfig::load(&dir.join("a.toml")).unwrap_err();
        assert!(e.contains("extend one another"), "{e}");
        write("c.toml", "extends = \"missing.toml\"\n");
        let e = TrainConfig::load(&dir.join("c.toml")).unwrap_err();
        assert!(
            e.contains("extends missing.toml") && e.contains("cannot read"),
            "{e}"
        );
        write("d.toml", "extends = \"base.toml\"\n[run]\nnum_env = 3\n");
        let e = TrainConfig::load(&dir.join("d.toml")).unwrap_err();
        assert!(e.contains("num_env"), "a typo in a variant is named: {e}");
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn the_learning_rate_anneals_linearly_over_its_span_and_may_change_on_resume() {
        let mut c = TrainConfig::from_toml(
            "[run]\ntotal_env_steps = 30000000\n[ppo]\nlearning_rate = 0.001\n",
        )
        .unwrap();
        assert_eq!(
            c.ppo.learning_rate_at(25_000_000, 30_000_000),
            0.001,
            "constant"
        );
        let stored = c.to_toml();
        c.ppo.learning_rate_final = Some(0.0001);
        c.ppo.anneal_start_env_steps = 20_000_000;
        c.validate().unwrap();
        let at = |steps| c.ppo.learning_rate_at(steps, 30_000_000);
        assert_eq!(at(10_000_000), 0.001, "before the span");
        assert_eq!(at(20_000_000), 0.001, "at its start");
        assert!(
            (at(25_000_000) - 0.00055).abs() < 1e-12,
            "{}",
            at(25_000_000)
        );
        assert!((at(30_000_000) - 0.0001).abs() < 1e-12, "at the end");
        assert!((at(40_000_000) - 0.0001).abs() < 1e-12, "past the end");
        assert!(c.changes_from_stored(&stored, &[]).unwrap().is_empty());
        c.ppo.anneal_start_env_steps = 30_000_000;
        let e = c.validate().unwrap_err();
        assert!(e.contains("ppo.anneal_start_env_steps"), "{e}");
    }

    #[test]
    fn every_committed_config_loads() {
        let dir = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/../configs"));
        let mut loaded = 0;
        for entry in std::fs::read_dir(dir).unwrap() {
            let path = entry.unwrap().path();
            if path.extension().is_some_and(|e| e == "toml") {
                TrainConfig::load(&path).unwrap_or_else(|e| panic!("{e}"));
                loaded += 1;
            }
        }
        assert!(loaded >= 5, "{loaded} configs in {}", dir.display());
    }

    #[test]
    fn typos_and_bad_values_are_named() {
        let e = TrainConfig::from_toml("[ppo]\nlearning_rat = 1.0\n").unwrap_err();
        assert!(e.contains("learning_rat"), "{e}");
        let e = TrainConfig::from_toml("[run]\nscene_kind = \"maze\"\n").unwrap_err();
        assert!(e.contains("run.scene_kind"), "{e}");
        let e =
            TrainConfig::from_toml("[curriculum]\nsecondary_init_temperature = 0.0\n").unwrap_err();
        assert!(e.contains("curriculum.secondary_init_temperature"), "{e}");
        let e = TrainConfig::from_toml("[run]\nstart_stage = 1.5\n").unwrap_err();
        assert!(e.contains("run.start_stage"), "{e}");
        let e = TrainConfig::from_toml("[curriculum]\nstart_stage_behaviours = [\"straight\"]\n")
            .unwrap_err();
        assert!(e.contains("curriculum.start_stage_behaviours"), "{e}");
        let budgets = "[curriculum.secondary_env_steps_by_behaviour]\n";
        let c = TrainConfig::from_toml(&format!("{budgets}lift = 5000\n")).unwrap();
        assert_eq!(c.curriculum.secondary_env_steps_by_behaviour["lift"], 5000);
        let e = TrainConfig::from_toml(&format!("{budgets}hover = 5000\n")).unwrap_err();
        assert!(e.contains("secondary_env_steps_by_behaviour"), "{e}");
        let e = TrainConfig::from_toml("[run]\ninvalid_reward = 0.5\n").unwrap_err();
        assert!(e.contains("run.invalid_reward"), "{e}");
        let e = TrainConfig::from_toml("[curriculum]\nreplay_imitation_coef = -1.0\n").unwrap_err();
        assert!(e.contains("curriculum.replay_imitation_coef"), "{e}");
        let e = TrainConfig::from_toml("[curriculum]\nreplay_balance = \"kind\"\n").unwrap_err();
        assert!(e.contains("replay_balance"), "{e}");
        let e = TrainConfig::from_toml("[ppo]\nconv_kernel = \"cudnn\"\n").unwrap_err();
        assert!(e.contains("ppo.conv_kernel") && e.contains("native"), "{e}");
        let burn = TrainConfig::from_toml("[ppo]\nconv_kernel = \"burn\"\n").unwrap();
        assert_eq!(burn.ppo.conv_kernel, "burn");
    }

    #[test]
    fn a_resume_may_extend_the_budget_or_retune_the_curriculum_but_not_ppo() {
        let stored = TrainConfig::default().to_toml();
        let changes =
            |c: &TrainConfig, keys: &[&str]| c.changes_from_stored(&stored, keys).unwrap();
        let mut longer = TrainConfig::default();
        longer.run.total_env_steps *= 2;
        assert!(changes(&longer, &[]).is_empty());
        longer.run.failure_resample_probability = 0.3;
        longer.run.failure_memory_per_env = 4;
        assert!(changes(&longer, &[]).is_empty());
        let mut retuned = TrainConfig::default();
        retuned.curriculum.secondary_init_temperature = 10.0;
        assert!(changes(&retuned, &[]).is_empty());
        retuned.curriculum.replay_imitation_coef = 0.5;
        assert!(changes(&retuned, &["secondary_env_steps"]).is_empty());
        assert_eq!(
            changes(&retuned, &["replay_imitation_coef"]),
            ["curriculum.replay_imitation_coef: 0.0 -> 0.5"],
            "a stage that reads a curriculum key keeps it"
        );
        let mut other = TrainConfig::default();
        other.ppo.entropy_coef *= 2.0;
        other.run.num_envs += 1;
        let found = changes(&other, &[]);
        assert_eq!(found.len(), 2, "{found:?}");
        assert!(found[0].starts_with("ppo.entropy_coef: "), "{found:?}");
        assert!(found[1].starts_with("run.num_envs: "), "{found:?}");
        // A config stored before the start-stage keys existed means the curriculum off.
        let old = stored
            .lines()
            .filter(|l| !l.starts_with("start_stage"))
            .collect::<Vec<_>>()
            .join("\n");
        assert!(old.len() < stored.len());
        assert!(TrainConfig::default()
            .changes_from_stored(&old, &[])
            .unwrap()
            .is_empty());
        let mut staged = TrainConfig::default();
        staged.run.start_stage = 0.0;
        assert!(!staged.changes_from_stored(&old, &[]).unwrap().is_empty());
        assert!(TrainConfig::default()
            .changes_from_stored("[run\n", &[])
            .unwrap_err()
            .contains("does not parse"));
    }
}
