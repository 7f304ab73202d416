//! Stored successful episodes and the paper's domain-randomized trajectory batch (paper:
//! "Domain Randomization"; Algorithm 2's "batch of traj.").
//!
//! A [`Trajectory`] is a scene plus the actions that solved it. The simulator is deterministic,
//! so replaying the actions from the scene in a fresh [`Env`] reproduces the episode exactly;
//! observations, rewards and returns are therefore not stored but re-rendered when the trainer
//! samples ([`Trajectory::replay_observations`]). That is what lets millions of trajectories fit
//! in memory and on disk.
//!
//! - [`sweep`]: the essential area of a trajectory: everything the robot's parts swept, plus a
//!   margin.
//! - [`randomize`]: new scenes around the essential area, replayed and kept only when the
//!   actions still succeed without a collision; [`randomize::randomize_batch`] writes the batch.
//! - [`batch_file`]: the batch file (magic, version, CRC-32 per chunk, resumable) and the
//!   in-memory [`batch_file::TrajectoryBatch`] the trainer samples from.
//! - [`relevance`]: the paper's relevance test: remove each obstacle, roll the greedy policy,
//!   measure how far its trajectory moves, and draw it.
//! - [`expert_labels`]: the states a decision stack visits, each labelled with the planner's
//!   shortest way from there (DAgger), written as a batch the primary replays and clones.
//!
//! The design and the measured figures are in docs/curriculum.md.

pub mod batch_file;
pub mod expert_labels;
pub mod randomize;
pub mod relevance;
pub mod sweep;

use core::fmt;
use wheelleg_runtime::action::Action;
use wheelleg_sim::env::{Env, EnvConfig, InvalidAction, Observation, Status, StepOutcome};
use wheelleg_sim::generate::Behaviour;
use wheelleg_sim::scenario::{Scenario, ScenarioError};
use wheelleg_sim::state::RobotState;

/// A stored episode: replaying `actions` from `scenario` in a fresh [`Env`] reproduces it.
#[derive(Clone, Debug, PartialEq)]
pub struct Trajectory {
    /// The scene (start pose, target, obstacles).
    pub scenario: Scenario,
    /// The actions, in order.
    pub actions: Vec<Action>,
    /// The behaviour whose secondary policy produced it; randomized copies keep their
    /// source's.
    pub behaviour: Behaviour,
}

/// A behaviour's code in trajectory files: its index in [`Behaviour::ALL`].
pub fn behaviour_code(behaviour: Behaviour) -> u8 {
    Behaviour::ALL
        .iter()
        .position(|&b| b == behaviour)
        .unwrap_or_default() as u8
}

/// The behaviour of file code `code`; `None` for an unknown code (5 and 6 were the planner
/// demonstrations and the astride behaviour, experiments that measured no gain).
pub fn behaviour_of_code(code: u8) -> Option<Behaviour> {
    Behaviour::ALL.get(code as usize).copied()
}

/// Why a trajectory could not be replayed at all (as opposed to replaying and failing, which
/// [`Replay`] reports).
#[derive(Clone, Debug, PartialEq)]
pub enum ReplayError {
    /// The scenario does not validate (non-finite numbers, robot starting inside an obstacle).
    Scenario(ScenarioError),
    /// The episode ended (success, too far, step limit) before every action was used: the
    /// actions do not belong to this scene and rules.
    ActionsAfterEnd {
        /// Index of the first action that found the episode over.
        step: usize,
        /// How the episode had ended.
        status: Status,
    },
}

impl fmt::Display for ReplayError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            ReplayError::Scenario(e) => write!(f, "{e}"),
            ReplayError::ActionsAfterEnd { step, status } => write!(
                f,
                "the episode ended ({status:?}) before action {step}: the actions do not fit \
                 this scene"
            ),
        }
    }
}

impl std::error::Error for ReplayError {}

impl From<ScenarioError> for ReplayError {
    fn from(e: ScenarioError) -> Self {
        ReplayError::Scenario(e)
    }
}

/// What a replay did.
#[derive(Clone, Debug, PartialEq)]
pub struct Replay {
    /// How the episode stands after the last action (`Running` if the actions ran out first).
    pub status: Status,
    /// Steps taken (= actions replayed).
    pub steps: u32,
    /// Actions undone because they would have hit an obstacle.
    pub collisions: u32,
    /// Actions undone for any reason (collision, impossible leg pose, out of bounds).
    pub invalid_actions: u32,
    /// Reward of every step.
    pub rewards: Vec<f32>,
    /// The robot's state before the first step and after every step (`steps + 1` states).
    pub path: Vec<RobotState>,
}

impl Replay {
    /// Reached the target.
    pub fn success(&self) -> bool {
        self.status == Status::Success
    }

    /// No action was undone by a collision.
    pub fn collision_free(&self) -> bool {
        self.collisions == 0
    }

    /// Sum of the rewards (undiscounted return of the whole episode).
    pub fn total_reward(&self) -> f32 {
        self.rewards.iter().sum()
    }

    /// Discounted return from every step: `R_t = r_t + gamma R_{t+1}` (0 after the last step,
    /// which is right for a successful, hence terminal, episode).
    pub fn returns(&self, gamma: f32) -> Vec<f32> {
        let mut out = vec![0.0; self.rewards.len()];
        let mut running = 0.0;
        for (slot, &r) in out.iter_mut().zip(&self.rewards).rev() {
            running = r + gamma * running;
            *slot = running;
        }
        out
    }
}

/// One step of a replay as the trainer samples it: what the policy saw, what it did, what it
/// got.
#[derive(Clone, Debug, PartialEq)]
pub struct ReplayStep {
    /// The observation the action was taken on.
    pub observation: Observation,
    /// The action.
    pub action: Action,
    /// The step's reward.
    pub reward: f32,
    /// Whether the episode ended with this step.
    pub done: bool,
    /// Why the action was undone, if it was.
    pub invalid: Option<InvalidAction>,
}

impl Trajectory {
    /// A trajectory of `actions` in `scenario`.
    pub fn new(scenario: Scenario, actions: Vec<Action>, behaviour: Behaviour) -> Self {
        Trajectory {
            scenario,
            actions,
            behaviour,
        }
    }

    /// Steps through the actions in a fresh episode, calling `visit` with the observation each
    /// action is taken on (`None` when `observe` is false, to skip the height map's cost), the
    /// action, and what the step did. The workhorse of every replay below.
    pub fn for_each_step(
        &self,
        config: EnvConfig,
        observe: bool,
        mut visit: impl FnMut(&Env, Option<&Observation>, Action, &StepOutcome),
    ) -> Result<Env, ReplayError> {
        let mut env = Env::new(&self.scenario, config)?;
        let mut observation = Observation::default();
        for (i, &action) in self.actions.iter().enumerate() {
            if observe {
                env.observe(&mut observation);
            }
            let outcome = env.step(action).map_err(|_| ReplayError::ActionsAfterEnd {
                step: i,
                status: env.status(),
            })?;
            visit(&env, observe.then_some(&observation), action, &outcome);
        }
        Ok(env)
    }

    /// Replays the actions and reports the outcome, rewards and the path.
    pub fn replay(&self, config: EnvConfig) -> Result<Replay, ReplayError> {
        let mut rewards = Vec::with_capacity(self.actions.len());
        let mut path = Vec::with_capacity(self.actions.len() + 1);
        path.push(self.scenario.start);
        let mut invalid_actions = 0;
        let env = self.for_each_step(config, false, |env, _, _, outcome| {
            rewards.push(outcome.reward.total());
            path.push(*env.state());
            invalid_actions += u32::from(outcome.invalid.is_some());
        })?;
        Ok(Replay {
            status: env.status(),
            steps: env.steps(),
            collisions: env.collisions(),
            invalid_actions,
            rewards,
            path,
        })
    }

    /// Replays the actions re-rendering every observation: the samples the trainer rebuilds
    /// from a stored trajectory. About 4 KiB per step (the height map).
    pub fn replay_observations(&self, config: EnvConfig) -> Result<Vec<ReplayStep>, ReplayError> {
        let mut steps = Vec::with_capacity(self.actions.len());
        self.for_each_step(config, true, |_, observation, action, outcome| {
            steps.push(ReplayStep {
                observation: observation.cloned().unwrap_or_default(),
                action,
                reward: outcome.reward.total(),
                done: outcome.status.is_done(),
                invalid: outcome.invalid,
            });
        })?;
        Ok(steps)
    }

    /// The same episode without its undone actions (collisions, impossible poses, leaving the
    /// arena). An undone action leaves the state as it was, so dropping it keeps the path and
    /// the outcome (only fewer steps count against the step limit); what remains replays with
    /// every action valid, which randomization needs: an obstacle the original run bumped into
    /// could otherwise be moved away and let that action through, changing the path.
    pub fn without_undone_actions(&self, config: EnvConfig) -> Result<Trajectory, ReplayError> {
        let mut kept = Vec::with_capacity(self.actions.len());
        self.for_each_step(config, false, |_, _, action, outcome| {
            if outcome.invalid.is_none() {
                kept.push(action);
            }
        })?;
        Ok(Trajectory {
            scenario: self.scenario.clone(),
            actions: kept,
            behaviour: self.behaviour,
        })
    }
}
