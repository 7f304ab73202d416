//! Many simulator episodes stepped in lock-step, so the policy runs once per step on all of
//! them (batched inference), with the environments spread over worker threads.
//!
//! Determinism: every environment owns its scene generator (ChaCha8, the run's seed on stream
//! = env index) and its slot in the output buffers; threads only split the slice of envs, so
//! the result does not depend on thread count or scheduling.

use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;
use wheelleg_runtime::action::{Action, DIMS};
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_sim::env::{Env, EnvConfig, Observation, Status};
use wheelleg_sim::failure_memory::FailureMemory;
use wheelleg_sim::generate::{exit_scene, generate_staged, Behaviour, SceneKind, StartYaw};
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
    env: Env,
    scenario: Scenario,
    scene_rng: ChaCha8Rng,
    episode_return: f32,
    actions: Vec<u8>,
    episodes_started: u64,
    /// Start stage the current scene was drawn at.
    stage: f32,
    /// Scenes of the task as specified (stage 1) this environment failed, offered again
    /// (Algorithm 2; off unless [`VecEnv::set_failure_memory`]).
    failures: FailureMemory,
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

/// How new scenes are drawn.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Scenes {
    /// The kind of scene.
    pub kind: SceneKind,
    /// How the start yaw is drawn.
    pub start_yaw: StartYaw,
    /// Start stage (`wheelleg_sim::generate::generate_staged`; 1 is the task as specified).
    pub stage: f32,
    /// Share of episodes on composed scenes instead of `kind` (`run.composed_share`).
    pub composed_share: f64,
    /// Share of episodes on exit scenes of `exit_behaviour`'s fence (`run.exit_share`).
    pub exit_share: f64,
    /// The fence of the exit scenes.
    pub exit_behaviour: Behaviour,
}

fn new_scene(scenes: Scenes, rng: &mut ChaCha8Rng, env: usize, episode: u64) -> Scenario {
    // Without exit or composed scenes nothing extra is drawn, so such a run sees exactly the
    // scenes it saw before the mixes existed.
    if scenes.exit_share > 0.0 && rng.random_bool(scenes.exit_share.min(1.0)) {
        let name = format!("{}-exit-e{env}-{episode}", scenes.exit_behaviour.name());
        return exit_scene(scenes.exit_behaviour, scenes.start_yaw, rng, name);
    }
    // Of the episodes left, so many that `composed_share` of all are composed.
    let composed = if scenes.exit_share > 0.0 {
        scenes.composed_share / (1.0 - scenes.exit_share)
    } else {
        scenes.composed_share
    };
    let kind = if composed > 0.0 && rng.random_bool(composed.min(1.0)) {
        SceneKind::Composed
    } else {
        scenes.kind
    };
    // At stage 1 this is `generate_with_start`, draw for draw.
    generate_staged(
        kind,
        scenes.start_yaw,
        scenes.stage,
        rng,
        format!("{}-e{env}-{episode}", kind.name()),
    )
}

impl EnvSlot {
    fn start(
        scenario: Scenario,
        config: EnvConfig,
        scene_rng: ChaCha8Rng,
        episodes_started: u64,
        stage: f32,
    ) -> Result<EnvSlot, String> {
        let env = Env::new(&scenario, config)
            .map_err(|e| format!("scenario {}: {e:?}", scenario.name))?;
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

    fn step(
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

    fn reset(&mut self, scenes: Scenes, config: EnvConfig, index: usize) {
        // Generated scenes are valid by construction; retry on the (unexpected) invalid one.
        loop {
            self.episodes_started += 1;
            // An empty memory draws nothing from the generator, so a run without failure
            // re-sampling sees exactly the scenes it did before the memory existed.
            let (scenario, stage) = match self.failures.take(&mut self.scene_rng) {
                Some(failed) => (failed, 1.0),
                None => (
                    new_scene(scenes, &mut self.scene_rng, index, self.episodes_started),
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

impl VecEnv {
    /// `num_envs` environments on fresh `kind` scenes; env `i` draws its scenes from ChaCha8
    /// seeded with `seed` on stream `i`.
    pub fn new(
        kind: SceneKind,
        num_envs: usize,
        seed: u64,
        config: EnvConfig,
        threads: usize,
    ) -> Result<VecEnv, String> {
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
    ) -> Result<VecEnv, String> {
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
    ) -> Result<VecEnv, String> {
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
    ) -> Result<VecEnv, String> {
        let slots = (0..num_envs)
            .map(|i| {
                let mut rng = ChaCha8Rng::seed_from_u64(seed);
                rng.set_stream(i as u64);
                let scenario = new_scene(scenes, &mut rng, i, 0);
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
                wheelleg_sim::scenario_file::to_json(&scenes)
            })
            .collect()
    }

    /// Restores what [`Self::failure_snapshot`] saved (after [`Self::set_failure_memory`]).
    pub fn restore_failures(&mut self, snapshot: &[String]) -> Result<(), String> {
        if snapshot.len() != self.slots.len() {
            return Err(format!(
                "checkpoint has failure memories of {} environments, config has {}",
                snapshot.len(),
                self.slots.len()
            ));
        }
        for (i, (slot, json)) in self.slots.iter_mut().zip(snapshot).enumerate() {
            let scenes =
                wheelleg_sim::scenario_file::parse(json, &wheelleg_runtime::robot::WHEELLEG)
                    .map_err(|e| format!("checkpoint env {i} failure memory: {e}"))?;
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
    pub fn set_env_stages(&mut self, stages: &[f32]) -> Result<(), String> {
        if stages.len() != self.slots.len() {
            return Err(format!(
                "checkpoint has start stages of {} environments, config has {}",
                stages.len(),
                self.slots.len()
            ));
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
                scenario_json: wheelleg_sim::scenario_file::to_json(std::slice::from_ref(
                    &s.scenario,
                )),
                actions: s.actions.clone(),
                episodes_started: s.episodes_started,
            })
            .collect()
    }

    /// Rebuilds the envs of a snapshot taken with the same `kind`, `seed` and config, replaying
    /// each unfinished episode's actions.
    pub fn restore(&mut self, seed: u64, snapshots: &[EnvSnapshot]) -> Result<(), String> {
        if snapshots.len() != self.slots.len() {
            return Err(format!(
                "checkpoint has {} environments, config has {}",
                snapshots.len(),
                self.slots.len()
            ));
        }
        for (i, (slot, snap)) in self.slots.iter_mut().zip(snapshots).enumerate() {
            let mut rng = ChaCha8Rng::seed_from_u64(seed);
            rng.set_stream(i as u64);
            rng.set_word_pos(snap.scene_rng_word_pos);
            let scenarios = wheelleg_sim::scenario_file::parse(
                &snap.scenario_json,
                &wheelleg_runtime::robot::WHEELLEG,
            )
            .map_err(|e| format!("checkpoint env {i}: {e}"))?;
            let scenario = scenarios
                .into_iter()
                .next()
                .ok_or_else(|| format!("checkpoint env {i}: no scenario"))?;
            // The stage of the restored scene is not in the snapshot (older checkpoints have
            // none); a staged run sets it afterwards with `set_env_stages`.
            let mut restored =
                EnvSlot::start(scenario, self.config, rng, snap.episodes_started, 1.0)?;
            // The memory is restored separately (`restore_failures`); keep its settings.
            restored.failures = slot.failures.clone();
            for &a in &snap.actions {
                let action = Action::from_index(a as usize)
                    .ok_or_else(|| format!("checkpoint env {i}: bad action {a}"))?;
                let outcome = restored
                    .env
                    .step(action)
                    .map_err(|_| format!("checkpoint env {i}: replay ran past the episode end"))?;
                restored.episode_return += outcome.reward.total();
                restored.actions.push(a);
            }
            *slot = restored;
        }
        Ok(())
    }
}

fn observe_slots(slots: &[EnvSlot], heights_m: &mut [f32], states: &mut [f32]) {
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

#[cfg(test)]
mod tests;
