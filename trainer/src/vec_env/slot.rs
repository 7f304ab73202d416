//! One environment of the batch: its episode, its scene generator, and what a finished
//! episode hands back.

use super::scenes::{new_scene, Scenes};
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_sim::env::{Env, EnvConfig, Observation, Status};
use wheelleg_sim::failure_memory::FailureMemory;
use wheelleg_sim::scenario::Scenario;

/// How a finished episode went.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct EpisodeStats {
    /// Undiscounted sum of rewards.
    pub return_sum: f32,
    /// Steps taken.
    pub steps: u32,
    /// Reached the target.
    pub success: bool,
    /// Collisions (undone actions that would have hit an obstacle).
    pub collisions: u32,
    /// Start stage its scene was drawn at (1: the task as specified).
    pub stage: f32,
}

/// One environment: its episode, the scene generator and the episode's actions so far (a
/// checkpoint restores an unfinished episode by replaying them; the simulator is exact).
#[derive(Clone, Debug)]
pub struct EnvSlot {
    pub(super) env: Env,
    pub(super) scenario: Scenario,
    pub(super) scene_rng: ChaCha8Rng,
    pub(super) episode_return: f32,
    pub(super) actions: Vec<u8>,
    pub(super) episodes_started: u64,
    /// Start stage the current scene was drawn at.
    pub(super) stage: f32,
    /// Scenes of the task as specified (stage 1) this environment failed, offered again
    /// (Algorithm 2; off unless [`VecEnv::set_failure_memory`]).
    pub(super) failures: FailureMemory,
}

/// What one environment's step returned.
#[derive(Clone, Debug, PartialEq)]
pub struct StepResult {
    /// The reward.
    pub reward: f32,
    /// Whether the episode ended (the env has already started the next one).
    pub done: bool,
    /// The finished episode, when `done`.
    pub episode: Option<EpisodeStats>,
    /// The scene and actions of a finished episode that reached the target without a
    /// collision (Algorithm 1 stores the latest of these).
    pub success: Option<Box<SolvedEpisode>>,
}

/// A scene and the actions that solved it without a collision.
#[derive(Clone, Debug, PartialEq)]
pub struct SolvedEpisode {
    /// The scene.
    pub scenario: Scenario,
    /// The actions, in order.
    pub actions: Vec<Action>,
    /// Start stage the scene was drawn at (1: the task as specified).
    pub stage: f32,
}

impl EnvSlot {
    pub(super) fn start(
        scenario: Scenario,
        config: EnvConfig,
        scene_rng: ChaCha8Rng,
        episodes_started: u64,
        stage: f32,
    ) -> Result<EnvSlot, super::VecEnvError> {
        let env = Env::new(&scenario, config).map_err(|e| super::VecEnvError::Scene {
            scenario: scenario.name.clone(),
            problem: format!("{e:?}"),
        })?;
        Ok(EnvSlot {
            env,
            scenario,
            scene_rng,
            episode_return: 0.0,
            actions: Vec::new(),
            episodes_started,
            stage,
            failures: FailureMemory::new(0, 0.0),
        })
    }

    pub(super) fn step(
        &mut self,
        choices: &[u8],
        scenes: Scenes,
        config: EnvConfig,
        index: usize,
    ) -> StepResult {
        let indices = std::array::from_fn(|h| choices[h] as usize);
        // Choices come from the policy's 3-way heads, so they are always in range.
        let action = Action::from_head_indices(indices).unwrap_or_default();
        let Ok(outcome) = self.env.step(action) else {
            // Cannot happen: finished episodes are replaced at once below.
            return StepResult {
                reward: 0.0,
                done: true,
                episode: None,
                success: None,
            };
        };
        let reward = outcome.reward.total();
        self.episode_return += reward;
        self.actions.push(action.index() as u8);
        if !outcome.status.is_done() {
            return StepResult {
                reward,
                done: false,
                episode: None,
                success: None,
            };
        }
        let episode = EpisodeStats {
            return_sum: self.episode_return,
            steps: self.env.steps(),
            success: outcome.status == Status::Success,
            collisions: self.env.collisions(),
            stage: self.stage,
        };
        // Only scenes of the task as specified come back: a staged start replayed at another
        // stage would be counted at the wrong stage, and its success stored as a stage-1
        // trajectory (the shortcut `SolvedEpisode::stage` keeps out of the batch).
        if !episode.success && self.stage >= 1.0 && self.failures.is_on() {
            self.failures.record_failure(self.scenario.clone());
        }
        let success = (episode.success && episode.collisions == 0).then(|| {
            Box::new(SolvedEpisode {
                scenario: self.scenario.clone(),
                actions: self
                    .actions
                    .iter()
                    .filter_map(|&a| Action::from_index(a as usize))
                    .collect(),
                stage: self.stage,
            })
        });
        self.reset(scenes, config, index);
        StepResult {
            reward,
            done: true,
            episode: Some(episode),
            success,
        }
    }

    pub(super) fn reset(&mut self, scenes: Scenes, config: EnvConfig, index: usize) {
        // Generated scenes are valid by construction; retry on the (unexpected) invalid one.
        loop {
            self.episodes_started += 1;
            // An empty memory draws nothing from the generator, so a run without failure
            // re-sampling sees exactly the scenes it did before the memory existed.
            let (scenario, stage) = match self.failures.take(&mut self.scene_rng) {
                Some(failed) => (failed, 1.0),
                None => (
                    new_scene(
                        &config.robot,
                        scenes,
                        &mut self.scene_rng,
                        index,
                        self.episodes_started,
                    ),
                    scenes.stage,
                ),
            };
            if let Ok(env) = Env::new(&scenario, config) {
                self.env = env;
                self.stage = stage;
                self.scenario = scenario;
                self.episode_return = 0.0;
                self.actions.clear();
                return;
            }
        }
    }
}

pub(super) fn observe_slots(slots: &[EnvSlot], heights_m: &mut [f32], states: &mut [f32]) {
    let mut obs = Observation::default();
    for ((slot, h), s) in slots
        .iter()
        .zip(heights_m.chunks_mut(HEIGHT_MAP_CELLS))
        .zip(states.chunks_mut(STATE_LEN))
    {
        slot.env.observe(&mut obs);
        h.copy_from_slice(&obs.height_map);
        s.copy_from_slice(&obs.state);
    }
}
