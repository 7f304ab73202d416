//! Every hyperparameter of a training run, read from a TOML file.
//!
//! Defaults follow the paper where it gives a value (batch of 10,000 environment steps for the
//! baseline, the reward of the simulator) and common PPO practice elsewhere. Unknown keys are
//! refused so a typo never silently falls back to a default.

use crate::replay::ReplayBalance;
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;
use wheelleg_sim::robot::SimulatedRobot;

mod file;
pub use file::ConfigError;
#[cfg(test)]
mod tests;
mod validate;

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
    /// Share of episodes drawn as exit scenes of `exit_behaviour`'s fence (the target just past
    /// the fence, beside the opening: `wheelleg_sim::generate::exit_scene`) instead of
    /// `scene_kind` or composed scenes. 0, the default, draws none. A finished run may be
    /// continued with it changed (`--resume`).
    pub exit_share: f64,
    /// The fence of the exit scenes: lift, spread or squeeze.
    pub exit_behaviour: String,
    /// Env steps of the run before `composed_share` and `exit_share` apply (0, the default:
    /// from the start).
    /// One run then does what a run on `scene_kind` continued with the mix does: the shipped
    /// primary's first 10 M env steps on complex scenes alone (configs/shipped.toml).
    pub composed_from_env_steps: u64,
    /// Ends the run before `total_env_steps` once its training success rate reached this in
    /// each of the last `stop_window` iterations, all on the task as specified (start stage 1):
    /// a run that has learnt its scenes stops spending time on them. 0, the default, runs to
    /// the budget. A finished run may be continued with it changed (`--resume`).
    pub stop_success_rate: f32,
    /// Iterations `stop_success_rate` is measured over.
    pub stop_window: usize,
    /// The robot trained for: a description (robots/NAME.toml), relative to this config file's
    /// folder; empty, the default, is the shipped robot. `wheelleg train --robot FILE` replaces
    /// it. Checkpoints, trajectory batches and weights files carry the robot, and a run or a
    /// stage refuses files of another.
    pub robot: String,
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
            exit_share: 0.0,
            exit_behaviour: "squeeze".into(),
            composed_from_env_steps: 0,
            stop_success_rate: 0.0,
            stop_window: 10,
            robot: String::new(),
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
    /// `ppo.epochs` of the secondary policies (none, the default: the primary's): the
    /// secondaries' small batches and the primary's large ones need not take as many passes.
    pub secondary_epochs: Option<usize>,
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
    /// Expert-labelled steps (`train label`, given to `train primary --labels`) added to each
    /// primary iteration beside the replayed ones, drawn uniformly over the labels: expert
    /// iteration (DAgger). Without labels, nothing.
    pub label_steps_per_iteration: usize,
    /// Weight of the behaviour-cloning term on the expert-labelled samples.
    pub label_imitation_coef: f32,
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
    /// `run.stop_success_rate` of the secondaries that start from the straight-line one
    /// (which always runs to its budget: the others learn from a converged start): each stops
    /// once it has learnt its scenes and holds its `keep_trajectories`, its budget then only a
    /// cap. 0, the default: each runs to its budget.
    pub secondary_stop_success_rate: f32,
    /// `run.stop_window` of those secondaries.
    pub secondary_stop_window: usize,
}

impl Default for CurriculumConfig {
    fn default() -> Self {
        CurriculumConfig {
            behaviours: ["straight", "around", "lift", "spread", "squeeze"]
                .map(String::from)
                .to_vec(),
            secondary_steps_per_iteration: 3_000,
            secondary_epochs: None,
            secondary_env_steps: 300_000,
            secondary_env_steps_by_behaviour: BTreeMap::new(),
            keep_trajectories: 1_000,
            randomizations: 1_000,
            replay_steps_per_iteration: 2_000,
            replay_imitation_coef: 0.0,
            replay_balance: ReplayBalance::Trajectory,
            label_steps_per_iteration: 2_000,
            label_imitation_coef: 0.5,
            primary_init: "scratch".into(),
            secondary_init_temperature: 1.0,
            secondary_entropy_coef: 0.003,
            secondary_start_yaw_within_deg: 180.0,
            start_stage_behaviours: Vec::new(),
            start_stage_initial: 0.0,
            start_stage_step: 0.1,
            start_stage_success_rate: 0.5,
            start_stage_window: 3,
            secondary_stop_success_rate: 0.0,
            secondary_stop_window: 10,
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
    /// The robot `run.robot` names, read and checked when the config is loaded.
    #[serde(skip)]
    pub robot: wheelleg_robot::RobotDescription,
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
    /// The run's robot as the simulator steps it; an error names the lattice key the simulator
    /// cannot step on ([`SimulatedRobot::of`]; a loaded config has been checked).
    pub fn simulated_robot(&self) -> Result<SimulatedRobot, ConfigError> {
        SimulatedRobot::of(&self.robot).map_err(ConfigError::Robot)
    }

    /// The episode rules of the run's environments: its step limit and invalid reward, on its
    /// robot.
    pub fn episode_rules(&self) -> Result<wheelleg_sim::env::EnvConfig, ConfigError> {
        Ok(wheelleg_sim::env::EnvConfig {
            max_steps: self.run.max_episode_steps,
            invalid_reward: self.run.invalid_reward,
            robot: self.simulated_robot()?,
            ..wheelleg_sim::env::EnvConfig::default()
        })
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
