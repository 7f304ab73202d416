//! Many simulator episodes stepped in lock-step, so the policy runs once per step on all of
//! them (batched inference), with the environments spread over worker threads.
//!
//! Determinism: every environment owns its scene generator (ChaCha8, the run's seed on stream
//! = env index) and its slot in the output buffers; threads only split the slice of envs, so
//! the result does not depend on thread count or scheduling.

use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::action::{Action, DIMS};
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_sim::env::EnvConfig;
use wheelleg_sim::failure_memory::FailureMemory;
use wheelleg_sim::generate::{Behaviour, SceneKind, StartYaw};
use wheelleg_sim::scenario::Scenario;

mod scenes;
mod slot;

use scenes::new_scene;
pub use scenes::Scenes;
use slot::{observe_slots, EnvSlot};
pub use slot::{EpisodeStats, SolvedEpisode, StepResult};

/// Where an environment stands, for checkpoints.
#[derive(Clone, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct EnvSnapshot {
    /// The scene generator's position (ChaCha word position).
    pub scene_rng_word_pos: u128,
    /// The current scenario as scenario-file JSON.
    pub scenario_json: String,
    /// Actions of the unfinished episode (action indices).
    pub actions: Vec<u8>,
    /// Episodes started so far (names new scenes).
    pub episodes_started: u64,
}

/// Lock-step environments on fresh scenes of one kind (or a mix with composed scenes).
pub struct VecEnv {
    slots: Vec<EnvSlot>,
    /// How the scenes from now on are drawn (the start stage changes during a run).
    scenes: Scenes,
    config: EnvConfig,
    threads: usize,
}

/// Why environments cannot be made or restored from a checkpoint.
#[derive(Clone, Debug, PartialEq)]
pub enum VecEnvError {
    /// A scene does not start an episode (the robot inside an obstacle, say).
    Scene {
        /// The scene's name.
        scenario: String,
        /// What is wrong with it.
        problem: String,
    },
    /// The checkpoint holds `what` for another number of environments than the config's.
    Count {
        /// What is restored (environments, failure memories, start stages).
        what: &'static str,
        /// In the checkpoint.
        stored: usize,
        /// In the config.
        configured: usize,
    },
    /// An environment's snapshot does not restore.
    Snapshot {
        /// The environment.
        env: usize,
        /// What is wrong with its snapshot.
        problem: String,
    },
}

impl std::fmt::Display for VecEnvError {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        match self {
            VecEnvError::Scene { scenario, problem } => write!(f, "scenario {scenario}: {problem}"),
            VecEnvError::Count {
                what,
                stored,
                configured,
            } => write!(
                f,
                "checkpoint has {what} of {stored} environments, config has {configured}"
            ),
            VecEnvError::Snapshot { env, problem } => write!(f, "checkpoint env {env}: {problem}"),
        }
    }
}

impl std::error::Error for VecEnvError {}

impl VecEnv {
    /// `num_envs` environments on fresh `kind` scenes; env `i` draws its scenes from ChaCha8
    /// seeded with `seed` on stream `i`.
    pub fn new(
        kind: SceneKind,
        num_envs: usize,
        seed: u64,
        config: EnvConfig,
        threads: usize,
    ) -> Result<VecEnv, VecEnvError> {
        VecEnv::with_start_yaw(kind, StartYaw::Any, num_envs, seed, config, threads)
    }

    /// [`VecEnv::new`] with the scenes' start yaw drawn as `start_yaw`.
    pub fn with_start_yaw(
        kind: SceneKind,
        start_yaw: StartYaw,
        num_envs: usize,
        seed: u64,
        config: EnvConfig,
        threads: usize,
    ) -> Result<VecEnv, VecEnvError> {
        VecEnv::with_stage(kind, start_yaw, 1.0, num_envs, seed, config, threads)
    }

    /// [`VecEnv::with_start_yaw`] with the scenes drawn at start stage `stage`
    /// (`wheelleg_sim::generate::generate_staged`; 1 is the task as specified).
    pub fn with_stage(
        kind: SceneKind,
        start_yaw: StartYaw,
        stage: f32,
        num_envs: usize,
        seed: u64,
        config: EnvConfig,
        threads: usize,
    ) -> Result<VecEnv, VecEnvError> {
        let scenes = Scenes {
            kind,
            start_yaw,
            stage,
            composed_share: 0.0,
            exit_share: 0.0,
            exit_behaviour: Behaviour::Squeeze,
        };
        VecEnv::with_scenes(scenes, num_envs, seed, config, threads)
    }

    /// `num_envs` environments on scenes drawn as `scenes`; env `i` draws its scenes from
    /// ChaCha8 seeded with `seed` on stream `i`.
    pub fn with_scenes(
        scenes: Scenes,
        num_envs: usize,
        seed: u64,
        config: EnvConfig,
        threads: usize,
    ) -> Result<VecEnv, VecEnvError> {
        let slots = (0..num_envs)
            .map(|i| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(i as u64);
                let scenario = new_scene(&config.robot, scenes, &mut rng, i, 0);
                EnvSlot::start(scenario, config, rng, 0, scenes.stage)
            })
            .collect::<Result<Vec<_>, _>>()?;
        Ok(VecEnv {
            slots,
            scenes,
            config,
            threads: threads.max(1),
        })
    }

    /// Turns on Algorithm 2's re-sampling of failed scenes: each environment remembers up to
    /// `per_env` scenes it failed and starts an episode on one of them with `probability`
    /// (`wheelleg_sim::failure_memory`). What is already remembered is kept, up to `per_env`.
    pub fn set_failure_memory(&mut self, per_env: usize, probability: f64) {
        for slot in &mut self.slots {
            let kept: Vec<Scenario> = slot.failures.scenes().cloned().collect();
            slot.failures = FailureMemory::new(per_env, probability);
            slot.failures.restore(kept);
        }
    }

    /// Each environment's remembered failed scenes as one scenario-file JSON (checkpoints).
    pub fn failure_snapshot(&self) -> Vec<String> {
        self.slots
            .iter()
            .map(|s| {
                let scenes: Vec<Scenario> = s.failures.scenes().cloned().collect();
                wheelleg_sim::scenario_file::to_json(&scenes, &self.config.robot)
            })
            .collect()
    }

    /// Restores what [`Self::failure_snapshot`] saved (after [`Self::set_failure_memory`]).
    pub fn restore_failures(&mut self, snapshot: &[String]) -> Result<(), VecEnvError> {
        if snapshot.len() != self.slots.len() {
            return Err(VecEnvError::Count {
                what: "failure memories",
                stored: snapshot.len(),
                configured: self.slots.len(),
            });
        }
        for (i, (slot, json)) in self.slots.iter_mut().zip(snapshot).enumerate() {
            let scenes =
                wheelleg_sim::scenario_file::parse(json, &self.config.robot).map_err(|e| {
                    VecEnvError::Snapshot {
                        env: i,
                        problem: format!("failure memory: {e}"),
                    }
                })?;
            slot.failures.restore(scenes);
        }
        Ok(())
    }

    /// Start stage of the scenes drawn from now on.
    pub fn stage(&self) -> f32 {
        self.scenes.stage
    }

    /// Draws the following scenes at start stage `stage`; running episodes keep theirs.
    pub fn set_stage(&mut self, stage: f32) {
        self.scenes.stage = stage;
    }

    /// Sets the share of composed scenes of the episodes that start from now on.
    pub fn set_composed_share(&mut self, share: f64) {
        self.scenes.composed_share = share;
    }

    /// Sets the share of exit scenes of the episodes that start from now on.
    pub fn set_exit_share(&mut self, share: f64) {
        self.scenes.exit_share = share;
    }

    /// The start stage each env's current scene was drawn at (for checkpoints).
    pub fn env_stages(&self) -> Vec<f32> {
        self.slots.iter().map(|s| s.stage).collect()
    }

    /// Sets the stage each env's current scene was drawn at (restoring a checkpoint).
    pub fn set_env_stages(&mut self, stages: &[f32]) -> Result<(), VecEnvError> {
        if stages.len() != self.slots.len() {
            return Err(VecEnvError::Count {
                what: "start stages",
                stored: stages.len(),
                configured: self.slots.len(),
            });
        }
        for (slot, &stage) in self.slots.iter_mut().zip(stages) {
            slot.stage = stage;
        }
        Ok(())
    }

    /// Number of environments.
    pub fn len(&self) -> usize {
        self.slots.len()
    }

    /// Whether there are none.
    pub fn is_empty(&self) -> bool {
        self.slots.is_empty()
    }

    /// Writes every env's observation: `len * HEIGHT_MAP_CELLS` heights, `len * STATE_LEN` states.
    pub fn observe(&self, heights_m: &mut [f32], states: &mut [f32]) {
        let chunk = self.slots.len().div_ceil(self.threads);
        std::thread::scope(|scope| {
            for ((slots, h), s) in self
                .slots
                .chunks(chunk)
                .zip(heights_m.chunks_mut(chunk * HEIGHT_MAP_CELLS))
                .zip(states.chunks_mut(chunk * STATE_LEN))
            {
                scope.spawn(move || observe_slots(slots, h, s));
            }
        });
    }

    /// Steps every env with its `DIMS` choices (`len * DIMS`), restarting finished episodes on
    /// fresh scenes, then writes the new observations.
    pub fn step(
        &mut self,
        choices: &[u8],
        heights_m: &mut [f32],
        states: &mut [f32],
    ) -> Vec<StepResult> {
        let chunk = self.slots.len().div_ceil(self.threads);
        let scenes = self.scenes;
        let config = self.config;
        let mut results = vec![
            StepResult {
                reward: 0.0,
                done: false,
                episode: None,
                success: None,
            };
            self.slots.len()
        ];
        std::thread::scope(|scope| {
            for (k, (((slots, r), h), s)) in self
                .slots
                .chunks_mut(chunk)
                .zip(results.chunks_mut(chunk))
                .zip(heights_m.chunks_mut(chunk * HEIGHT_MAP_CELLS))
                .zip(states.chunks_mut(chunk * STATE_LEN))
                .enumerate()
            {
                let choices = &choices[k * chunk * DIMS..];
                scope.spawn(move || {
                    for (j, (slot, r)) in slots.iter_mut().zip(r.iter_mut()).enumerate() {
                        *r = slot.step(
                            &choices[j * DIMS..(j + 1) * DIMS],
                            scenes,
                            config,
                            k * chunk + j,
                        );
                    }
                    observe_slots(slots, h, s);
                });
            }
        });
        results
    }

    /// Snapshots of every env (for checkpoints).
    pub fn snapshot(&self) -> Vec<EnvSnapshot> {
        self.slots
            .iter()
            .map(|s| EnvSnapshot {
                scene_rng_word_pos: s.scene_rng.get_word_pos(),
                scenario_json: wheelleg_sim::scenario_file::to_json(
                    std::slice::from_ref(&s.scenario),
                    &self.config.robot,
                ),
                actions: s.actions.clone(),
                episodes_started: s.episodes_started,
            })
            .collect()
    }

    /// Rebuilds the envs of a snapshot taken with the same `kind`, `seed` and config, replaying
    /// each unfinished episode's actions.
    pub fn restore(&mut self, seed: u64, snapshots: &[EnvSnapshot]) -> Result<(), VecEnvError> {
        if snapshots.len() != self.slots.len() {
            return Err(VecEnvError::Count {
                what: "snapshots",
                stored: snapshots.len(),
                configured: self.slots.len(),
            });
        }
        for (i, (slot, snap)) in self.slots.iter_mut().zip(snapshots).enumerate() {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(i as u64);
            rng.set_word_pos(snap.scene_rng_word_pos);
            let scenarios =
                wheelleg_sim::scenario_file::parse(&snap.scenario_json, &self.config.robot)
                    .map_err(|e| VecEnvError::Snapshot {
                        env: i,
                        problem: e.to_string(),
                    })?;
            let scenario = scenarios
                .into_iter()
                .next()
                .ok_or_else(|| VecEnvError::Snapshot {
                    env: i,
                    problem: "no scenario".into(),
                })?;
            // The stage of the restored scene is not in the snapshot (older checkpoints have
            // none); a staged run sets it afterwards with `set_env_stages`.
            let mut restored =
                EnvSlot::start(scenario, self.config, rng, snap.episodes_started, 1.0)?;
            // The memory is restored separately (`restore_failures`); keep its settings.
            restored.failures = slot.failures.clone();
            for &a in &snap.actions {
                let action =
                    Action::from_index(a as usize).ok_or_else(|| VecEnvError::Snapshot {
                        env: i,
                        problem: format!("bad action {a}"),
                    })?;
                let outcome = restored
                    .env
                    .step(action)
                    .map_err(|_| VecEnvError::Snapshot {
                        env: i,
                        problem: "replay ran past the episode end".into(),
                    })?;
                restored.episode_return += outcome.reward.total();
                restored.actions.push(a);
            }
            *slot = restored;
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests;
