//! Expert labels of the states a decision stack visits (DAgger, expert iteration): the policy is
//! driven through scenes by the stack, and the states it reaches are labelled with an expert's
//! way from there: the full decision stack's (look-ahead and its searches, with the same policy)
//! or the planner's shortest. Written as a trajectory batch, the labels are replayed by the
//! primary's training and cloned (`curriculum.replay_imitation_coef`), so the policy learns what
//! to do where its own stack takes it, not only where the secondaries went.
//!
//! 1. **Drive** ([`visited_states`]): every scene through the stack in lock-step
//!    (`wheelleg_stack::episodes::run_episodes`), keeping the state before each decision. A
//!    state met again in the same episode (an undone action leaves the robot where it was) is
//!    kept once. All states of a failed episode are labelled, every `every`-th of a successful
//!    one (its start first): the failures are where the policy needs the teacher.
//! 2. **Move the start**: a label's scene is its episode's scene started at the visited state,
//!    pose and legs, so the first observation replayed is the one the policy read there. A
//!    fresh episode measures its arena, give-up distance and step limit from its start, so the
//!    plan is searched in that fresh episode, under the rules its replay will have.
//! 3. **Label**: with `expert_stack` ([`label_by_stack`]), the full stack drives the policy from
//!    each state to the episode's end, batched as evaluation runs it, and a success is the label:
//!    what the companion computer's stack would have done from there, in the policy's own
//!    manner (its leg moves are the policy's, not the planner's arbitrary ones). Otherwise the
//!    planner ([`label_state`]): an exact search within `planner_expansions`, so a label is a
//!    proven shortest way; with `weighted_fallback`, a weighted search where the exact one runs
//!    out, so a label is a proven way. A state the expert finds no way from is stored as a
//!    rejected source, with the reason, and gives no trajectory.
//! 4. **Store**: the records of a batch of originals only (`per_trajectory` 0,
//!    `include_original`; [`super::randomize::randomize_source`]), so every label is replayed
//!    by the simulator before it is kept, exactly as the secondaries' stores are.
//!
//! The rollout is deterministic (the untried rule draws nothing; the rule `sample` draws from
//! ChaCha8 seeded with the scenes' seed, stream 1) and each state's plan depends only on the
//! state, so the same policy, stack, scenes and budget give the same file byte for byte,
//! whatever the thread count. Planning is the costly part and is resumable: a killed run leaves
//! `<out>.partial`; the next run drives the episodes again (cheap, and the same) and plans on
//! from the first state not yet written ([`super::batch_file`]).

use super::batch_file::{
    fnv1a, parse_header, partial_path, scan_chunks, BatchFileError, BatchHeader, BatchWriter,
    Chunk, SourceRecord, TrajectoryBatch,
};
use super::randomize::{randomize_source, RandomizeConfig};
use super::Trajectory;
use crate::error::TrainError;
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use wheelleg_robot::RobotDescription;
use wheelleg_sim::env::{Env, EnvConfig, Status};
use wheelleg_sim::generate::Behaviour;
use wheelleg_sim::planner::{plan, plan_with_fallback, PlanOutcome, PlannerConfig};
use wheelleg_sim::scenario::Scenario;
use wheelleg_sim::state::RobotState;
use wheelleg_stack::episodes::run_episodes;
use wheelleg_stack::policy::BatchPolicy;
use wheelleg_stack::StackConfig;

/// Name of the labels in a run folder (a trajectory batch file).
pub const LABELS_FILE: &str = "labels.wltb";

/// Why a rejected state has no label: the planner proved there is no way.
pub const NO_WAY: &str = "planner: no way to the target under the episode rules";
/// Why a rejected state has no label: the planner's budget ran out first (the reason goes on
/// with the budget).
pub const OUT_OF_BUDGET: &str = "planner: budget ran out";
/// Why a rejected state has no label: the expert stack did not reach the target from it (the
/// reason goes on with the episode's end).
pub const EXPERT_FAILED: &str = "expert stack: no success";

/// States the expert stack drives together in one batched rollout: fixed, so that the file does
/// not depend on how many states a chunk holds.
pub const EXPERT_BATCH_STATES: usize = 64;

/// How the labels are made.
#[derive(Clone, Debug)]
pub struct LabelConfig {
    /// The stack that drives the policy (the on-board stack: `wheelleg_stack::Preset::Robot`).
    pub stack: StackConfig,
    /// Episode rules of the rollouts, the plans and the labels' replays, on the robot's
    /// geometry.
    pub env: EnvConfig,
    /// The robot, named in the batch's header (its geometry is `env`'s).
    pub robot: RobotDescription,
    /// Seed the scenes were generated with, recorded in the header (and the seed of the
    /// `sample` rule's draws).
    pub seed: u64,
    /// Of a successful episode, every this-many-th visited state is labelled (1: all).
    pub every: usize,
    /// Expansions each plan may take; a state whose search runs out has no label.
    pub planner_expansions: usize,
    /// Where the exact search runs out, a weighted one with the same budget
    /// (`wheelleg_sim::planner::plan_with_fallback`): a proven way, not a proven shortest one.
    /// The states the stack fails from are the ones the exact search most often runs out on.
    pub weighted_fallback: bool,
    /// The expert: this stack's rollout from each state, with the policy being labelled (the
    /// full stack: `wheelleg_stack::Preset::Full`); `None`: the planner.
    pub expert_stack: Option<StackConfig>,
    /// The behaviour the labels are filed under (the batch's codes are the five secondaries';
    /// with `replay_balance = "behaviour"` the labels share that behaviour's draws).
    pub behaviour: Behaviour,
    /// Plans searched (or, with `expert_stack`, batches of [`EXPERT_BATCH_STATES`] driven) at
    /// once, one thread each.
    pub threads: usize,
    /// States planned per chunk written: the work a killed run can lose.
    pub chunk_states: usize,
}

impl Default for LabelConfig {
    fn default() -> Self {
        LabelConfig {
            stack: StackConfig::default(),
            env: EnvConfig::default(),
            robot: RobotDescription::shipped(),
            seed: 0,
            every: 5,
            planner_expansions: 5_000,
            weighted_fallback: false,
            expert_stack: None,
            // Complex scenes are clutter driven around; the leg behaviours keep their own
            // share of the draws.
            behaviour: Behaviour::Around,
            threads: 2,
            chunk_states: 256,
        }
    }
}

impl LabelConfig {
    /// Checks the settings, naming the first that cannot work.
    pub fn check(&self) -> Result<(), TrainError> {
        self.stack.check().map_err(TrainError::Stack)?;
        if self.every == 0 {
            return Err(TrainError::setting(
                "every",
                "must be at least 1 (1 labels every visited state)",
            ));
        }
        if self.planner_expansions == 0 {
            return Err(TrainError::setting(
                "planner_expansions",
                "the planner needs at least 1 expansion",
            ));
        }
        if self.threads == 0 {
            return Err(TrainError::setting("threads", "must be at least 1"));
        }
        if self.chunk_states == 0 {
            return Err(TrainError::setting("chunk_states", "must be at least 1"));
        }
        if let Some(set) = wheelleg_sim::seeds::measuring_set(self.seed) {
            return Err(TrainError::setting(
                "seed",
                format!(
                    "{} makes {set}, which measure the policy; label scenes of another seed ({} + \
                     round, say)",
                    self.seed,
                    wheelleg_sim::seeds::EXPERT_LABELS
                ),
            ));
        }
        Ok(())
    }

    /// The randomization of a batch of originals only: what stores a label as the
    /// secondaries' stores are stored.
    fn originals_only(&self) -> RandomizeConfig {
        RandomizeConfig {
            per_trajectory: 0,
            include_original: true,
            seed: self.seed,
            env: self.env,
            robot: self.robot.clone(),
            ..RandomizeConfig::default()
        }
    }

    /// The batch header for `states`: the planner's settings are folded into the fingerprint
    /// of the sources, so a resume with other settings is refused like one with other states.
    pub fn header(&self, states: &[Trajectory]) -> Result<BatchHeader, BatchFileError> {
        let mut header = self.originals_only().header(states)?;
        header.sources_fingerprint = fnv1a(
            &(self.planner_expansions as u64).to_le_bytes(),
            header.sources_fingerprint,
        );
        if self.weighted_fallback {
            header.sources_fingerprint = fnv1a(b"weighted", header.sources_fingerprint);
        }
        if let Some(stack) = &self.expert_stack {
            let expert = format!("expert stack {stack:?}");
            header.sources_fingerprint = fnv1a(expert.as_bytes(), header.sources_fingerprint);
        }
        Ok(header)
    }
}

/// What the rollouts did and which states they offer for labelling.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Visited {
    /// The states to label, each as its episode's scene started there (no actions yet), in
    /// scene order and, within a scene, in the order visited.
    pub states: Vec<Trajectory>,
    /// Episodes driven.
    pub episodes: usize,
    /// Of them, those that reached the target.
    pub successes: usize,
    /// Decisions taken in all (states visited, repeats included).
    pub decisions: u64,
}

/// Drives `policy` through every scenario with `config.stack` and returns the states to label:
/// all (distinct) states of a failed episode, every `config.every`-th of a successful one.
pub fn visited_states(
    policy: &dyn BatchPolicy,
    scenarios: &[Scenario],
    config: &LabelConfig,
) -> Result<Visited, TrainError> {
    config.check()?;
    let mut path: Vec<Vec<(u32, RobotState)>> = vec![Vec::new(); scenarios.len()];
    let mut decisions = 0u64;
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    rng.set_stream(1);
    let episodes = run_episodes(
        policy,
        scenarios,
        &config.stack,
        config.env,
        &mut rng,
        &mut |decision| {
            decisions += 1;
            let state = *decision.env.state();
            let seen = &mut path[decision.episode];
            if !seen.iter().any(|&(_, s)| s == state) {
                seen.push((decision.env.steps(), state));
            }
        },
    )
    .map_err(TrainError::Stack)?;
    let mut visited = Visited {
        episodes: episodes.len(),
        decisions,
        ..Visited::default()
    };
    for ((scenario, episode), path) in scenarios.iter().zip(&episodes).zip(path) {
        let success = episode.env.status() == Status::Success;
        visited.successes += usize::from(success);
        let step = if success { config.every } else { 1 };
        for (steps, state) in path.into_iter().step_by(step) {
            visited.states.push(Trajectory::new(
                Scenario {
                    name: format!("{}@{steps}", scenario.name),
                    start: state,
                    target: scenario.target,
                    obstacles: scenario.obstacles.clone(),
                },
                Vec::new(),
                config.behaviour,
            ));
        }
    }
    Ok(visited)
}

/// What became of one state.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Verdict {
    /// Labelled: a way of this many steps, replayed clean and stored.
    Labelled(usize),
    /// The planner proved there is no way.
    NoWay,
    /// The planner's budget ran out.
    OutOfBudget,
    /// The expert stack did not reach the target.
    ExpertFailed,
    /// Not usable otherwise (the start does not validate, the plan did not store).
    Unusable,
}

impl Verdict {
    /// The verdict a stored record stands for.
    pub fn of_record(record: &SourceRecord) -> Verdict {
        if !record.scenes.is_empty() {
            Verdict::Labelled(record.actions.len())
        } else if record.rejected == NO_WAY {
            Verdict::NoWay
        } else if record.rejected.starts_with(OUT_OF_BUDGET) {
            Verdict::OutOfBudget
        } else if record.rejected.starts_with(EXPERT_FAILED) {
            Verdict::ExpertFailed
        } else {
            Verdict::Unusable
        }
    }
}

/// Plans from `state` (a scene started at a visited state) and returns its record: the plan
/// stored as an original scene, or the reason there is none. `index` is the state's place in
/// the batch.
pub fn label_state(
    state: &Trajectory,
    index: u64,
    config: &LabelConfig,
) -> Result<SourceRecord, BatchFileError> {
    let unstorable = |e: super::batch_file::RecordError| BatchFileError::Unstorable { reason: e.0 };
    let rejected = |reason: String| -> Result<SourceRecord, BatchFileError> {
        let mut record = SourceRecord::of_trajectory(state).map_err(unstorable)?;
        record.rejected = reason;
        Ok(record)
    };
    let env = match Env::new(&state.scenario, config.env) {
        Ok(env) => env,
        Err(e) => return rejected(format!("start: {e}")),
    };
    let planner = PlannerConfig {
        max_expansions: config.planner_expansions,
        ..PlannerConfig::default()
    };
    let outcome = if config.weighted_fallback {
        plan_with_fallback(&env, &planner).outcome().clone()
    } else {
        plan(&env, &planner).outcome
    };
    match outcome {
        PlanOutcome::Solved { actions, .. } if actions.is_empty() => {
            rejected("already at the target".into())
        }
        PlanOutcome::Solved { actions, .. } => {
            let labelled = Trajectory::new(state.scenario.clone(), actions, state.behaviour);
            randomize_source(&labelled, index, &config.originals_only())
        }
        PlanOutcome::Unsolvable => rejected(NO_WAY.into()),
        PlanOutcome::BudgetExceeded => rejected(format!(
            "{OUT_OF_BUDGET} ({} expansions)",
            config.planner_expansions
        )),
    }
}

/// Progress of a labelling run.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Progress {
    /// States planned (including those already in a resumed file).
    pub states_done: u64,
    /// States to plan in all.
    pub states_total: u64,
    /// Of the states done, those labelled.
    pub labelled: u64,
}

/// What a labelling run produced.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct LabelStats {
    /// Episodes driven.
    pub episodes: usize,
    /// Of them, those that reached the target.
    pub successes: usize,
    /// Decisions the stack took in all.
    pub decisions: u64,
    /// States offered for labelling (the batch's sources).
    pub states: u64,
    /// States labelled (the batch's trajectories).
    pub labelled: u64,
    /// Steps of all labels together.
    pub label_steps: u64,
    /// States where the planner proved there is no way.
    pub no_way: u64,
    /// States where the planner's budget ran out.
    pub out_of_budget: u64,
    /// States the expert stack did not reach the target from.
    pub expert_failed: u64,
    /// States not usable otherwise.
    pub unusable: u64,
    /// States planned by this run (the rest were in the file already).
    pub planned_here: u64,
    /// The state this run started planning at (0 for a fresh one; all of them when the batch
    /// was complete).
    pub resumed_at_state: u64,
    /// Bytes of a half-written chunk cut off the partial file on resume.
    pub discarded_tail_bytes: u64,
    /// Size of the finished file.
    pub file_bytes: u64,
}

impl LabelStats {
    fn count(&mut self, record: &SourceRecord) {
        match Verdict::of_record(record) {
            Verdict::Labelled(steps) => {
                self.labelled += 1;
                self.label_steps += steps as u64;
            }
            Verdict::NoWay => self.no_way += 1,
            Verdict::OutOfBudget => self.out_of_budget += 1,
            Verdict::ExpertFailed => self.expert_failed += 1,
            Verdict::Unusable => self.unusable += 1,
        }
    }

    fn count_chunks(&mut self, chunks: &[Chunk]) {
        for record in chunks.iter().flat_map(|c| &c.sources) {
            self.count(record);
        }
    }
}

/// Drives `policy` through `scenarios` ([`visited_states`]), labels the states ([`label_state`],
/// `config.threads` at once) and writes the batch `out` (via `<out>.partial`, resumed when it
/// exists). When `out` already holds the complete batch of the same header, nothing is planned
/// and its counts are returned; one with another header is refused.
pub fn label_batch(
    policy: &dyn BatchPolicy,
    scenarios: &[Scenario],
    config: &LabelConfig,
    out: &Path,
    mut progress: impl FnMut(Progress),
) -> Result<LabelStats, TrainError> {
    if scenarios.is_empty() {
        return Err(TrainError::Nothing {
            what: "scenes to label",
        });
    }
    let visited = visited_states(policy, scenarios, config)?;
    let header = config.header(&visited.states)?;
    let mut stats = LabelStats {
        episodes: visited.episodes,
        successes: visited.successes,
        decisions: visited.decisions,
        states: visited.states.len() as u64,
        ..LabelStats::default()
    };
    if out.exists() {
        let bytes = std::fs::read(out).map_err(|e| TrainError::io(out, "read", e))?;
        let (found, start) = parse_header(&bytes).map_err(|e| TrainError::in_file(out, e))?;
        if let Some((field, in_file, requested)) = found.first_difference(&header) {
            return Err(TrainError::LabelsDiffer {
                path: out.to_path_buf(),
                field,
                in_file,
                requested,
            });
        }
        TrajectoryBatch::from_bytes(&bytes).map_err(|e| TrainError::in_file(out, e))?;
        stats.count_chunks(&scan_chunks(&bytes, &found, start).chunks);
        stats.resumed_at_state = stats.states;
        stats.file_bytes = bytes.len() as u64;
        return Ok(stats);
    }
    let in_file = |e: BatchFileError| TrainError::in_file(partial_path(out), e);
    let (mut writer, resume) = BatchWriter::resume(out, &header).map_err(in_file)?;
    stats.resumed_at_state = resume.next_source;
    stats.discarded_tail_bytes = resume.discarded_tail_bytes;
    stats.count_chunks(&resume.chunks);
    let total = visited.states.len();
    let mut first = resume.next_source as usize;
    while first < total {
        let end = (first + config.chunk_states).min(total);
        let states = &visited.states[first..end];
        let records = match &config.expert_stack {
            Some(stack) => label_by_stack(policy, stack, states, first as u64, config)?,
            None => label_in_parallel(states, first as u64, config)?,
        };
        for record in &records {
            stats.count(record);
        }
        stats.planned_here += records.len() as u64;
        writer
            .append(&Chunk {
                first_source: first as u64,
                sources: records,
            })
            .map_err(in_file)?;
        first = end;
        progress(Progress {
            states_done: first as u64,
            states_total: total as u64,
            labelled: stats.labelled,
        });
    }
    stats.file_bytes = writer.bytes();
    writer
        .finish(out)
        .map_err(|e| TrainError::in_file(out, e))?;
    Ok(stats)
}

/// Labels `states` (the first at batch index `first`) with `stack`'s rollouts of `policy` from
/// them, [`EXPERT_BATCH_STATES`] at a time, in lock-step: a success is stored as the label (its
/// undone actions left out, replayed clean as every stored trajectory is), anything else as a
/// rejected source with the episode's end. The `sample` rule's draws come from ChaCha8 seeded
/// with the scenes' seed, one stream per rollout batch.
pub fn label_by_stack(
    policy: &dyn BatchPolicy,
    stack: &StackConfig,
    states: &[Trajectory],
    first: u64,
    config: &LabelConfig,
) -> Result<Vec<SourceRecord>, TrainError> {
    let batches: Vec<&[Trajectory]> = states.chunks(EXPERT_BATCH_STATES).collect();
    let labelled = in_parallel(batches.len(), config.threads, |b| {
        let batch_first = first + (b * EXPERT_BATCH_STATES) as u64;
        label_stack_batch(policy, stack, batches[b], batch_first, config)
    })
    .map_err(|b| TrainError::Panicked {
        work: "labelling",
        first: first + (b * EXPERT_BATCH_STATES) as u64,
        last: first + (b * EXPERT_BATCH_STATES + batches[b].len()) as u64 - 1,
    })?;
    let mut records = Vec::with_capacity(states.len());
    for batch in labelled {
        records.extend(batch?);
    }
    Ok(records)
}

/// One batch of [`label_by_stack`], the first state at batch index `batch_first`.
fn label_stack_batch(
    policy: &dyn BatchPolicy,
    stack: &StackConfig,
    batch: &[Trajectory],
    batch_first: u64,
    config: &LabelConfig,
) -> Result<Vec<SourceRecord>, TrainError> {
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    rng.set_stream(2 + batch_first);
    let scenarios: Vec<Scenario> = batch.iter().map(|t| t.scenario.clone()).collect();
    let episodes = run_episodes(policy, &scenarios, stack, config.env, &mut rng, &mut |_| {})
        .map_err(TrainError::Stack)?;
    batch
        .iter()
        .zip(episodes)
        .enumerate()
        .map(|(i, (state, episode))| {
            let index = batch_first + i as u64;
            let status = episode.env.status();
            let record = if status == Status::Success && !episode.actions.is_empty() {
                let labelled =
                    Trajectory::new(state.scenario.clone(), episode.actions, state.behaviour);
                randomize_source(&labelled, index, &config.originals_only())
            } else {
                SourceRecord::of_trajectory(state)
                    .map_err(|e| BatchFileError::Unstorable { reason: e.0 })
                    .map(|mut record| {
                        record.rejected = format!("{EXPERT_FAILED} ({status:?})");
                        record
                    })
            };
            record.map_err(TrainError::from)
        })
        .collect()
}

/// Labels `states` (the first at batch index `first`) with the planner, `config.threads` at
/// once; the records come back in the states' order.
fn label_in_parallel(
    states: &[Trajectory],
    first: u64,
    config: &LabelConfig,
) -> Result<Vec<SourceRecord>, TrainError> {
    in_parallel(states.len(), config.threads, |i| {
        label_state(&states[i], first + i as u64, config)
    })
    .map_err(|i| TrainError::Panicked {
        work: "planning",
        first: first + i as u64,
        last: first + i as u64,
    })?
    .into_iter()
    .map(|record| record.map_err(TrainError::from))
    .collect()
}

/// `work(i)` for every `i` below `count`, `threads` at once, each thread taking the next `i`
/// not yet taken; the results come back in the order of `i`, so they do not depend on the
/// thread count. `Err(i)`: the work on `i` panicked (a planner bug, say): the run stops with an
/// error that names the state, and what was written before stays.
fn in_parallel<T: Send>(
    count: usize,
    threads: usize,
    work: impl Fn(usize) -> T + Sync,
) -> Result<Vec<T>, usize> {
    let next = AtomicUsize::new(0);
    let slots: Vec<Mutex<Option<T>>> = (0..count).map(|_| Mutex::new(None)).collect();
    let worker = || loop {
        let i = next.fetch_add(1, Ordering::Relaxed);
        if i >= count {
            break;
        }
        let Ok(result) = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| work(i))) else {
            break;
        };
        if let Ok(mut slot) = slots[i].lock() {
            *slot = Some(result);
        }
    };
    std::thread::scope(|scope| {
        for _ in 1..threads.min(count) {
            scope.spawn(worker);
        }
        worker();
    });
    slots
        .into_iter()
        .enumerate()
        .map(|(i, slot)| slot.into_inner().ok().flatten().ok_or(i))
        .collect()
}
