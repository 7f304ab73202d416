//! Planner demonstrations (beyond the paper, off unless `curriculum.planner_demonstrations` is
//! set): the exact planner's plans of complex training scenes, stored as sources of the
//! trajectory batch beside the secondary policies' successes.
//!
//! Why: the primary's remaining failures are scenes whose target lies on or beside an
//! obstacle (docs/results.md, "Nearly every failure is a target beside an obstacle"). No
//! secondary behaviour ends astride a slab, so the batch never shows it; the planner solves
//! those scenes by turning across the slab and spreading to full track. Its plans go through
//! the same randomization as every other source (only replays that still succeed without a
//! collision are kept), and the primary learns from them exactly as from the secondaries'.
//!
//! Scenes: `scenes` complex scenes drawn from ChaCha8 seeded with the run seed on stream
//! [`DEMO_STREAM`] (the scene generator of `wheelleg generate` uses stream 0, so these are never
//! the held-out scenes), optionally only those whose target lies within
//! [`crate::evaluate::BESIDE_TARGET_M`] of an obstacle. Each is planned by
//! [`plan_with_fallback`] (exact search, then the weighted one with the same budget), and a
//! plan is kept only when it replays to success with no undone action.
//!
//! Planning takes seconds per cluttered scene, so it is resumable: every scene's outcome is a
//! line of `plans.jsonl` (a header line first, checked on resume), appended and synced a
//! chunk at a time; a half-written last line is cut on resume.

use super::{Origin, Trajectory};
use rand::SeedableRng;
use rand_chacha::ChaCha8Rng;
use serde::{Deserialize, Serialize};
use std::fs::{self, OpenOptions};
use std::io::Write;
use std::path::Path;
use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::Mutex;
use wheelleg_runtime::action::Action;
use wheelleg_sim::env::{Env, EnvConfig, Status};
use wheelleg_sim::generate::{generate_many, SceneKind};
use wheelleg_sim::planner::{plan_with_fallback, PlanOutcome, PlannerConfig};
use wheelleg_sim::scenario::Scenario;

/// ChaCha8 stream of the demonstration scenes.
pub const DEMO_STREAM: u64 = 0xde70;
/// Name of the plan log in the demonstrations folder.
pub const PLANS_FILE: &str = "plans.jsonl";
/// Scenes planned between two syncs of the log: the work a killed run can lose.
const CHUNK_SCENES: usize = 16;

/// What to plan.
#[derive(Clone, Copy, Debug, PartialEq, Serialize, Deserialize)]
pub struct DemoConfig {
    /// Complex scenes drawn.
    pub scenes: usize,
    /// Seed of the scenes.
    pub seed: u64,
    /// Expansion budget of each of the two searches per scene.
    pub max_expansions: usize,
    /// Plan only scenes whose target lies beside an obstacle; skip the others.
    pub target_beside_only: bool,
    /// Episode step limit the plans must fit.
    pub max_steps: u32,
}

impl DemoConfig {
    /// The episode rules plans are searched and replayed under.
    fn env(&self, base: EnvConfig) -> EnvConfig {
        EnvConfig {
            max_steps: self.max_steps,
            ..base
        }
    }
}

/// What planning one scene gave.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
enum SceneOutcome {
    /// Exact search: a proven shortest plan, kept.
    Shortest,
    /// Weighted search: a plan, not proven shortest, kept.
    Solved,
    /// Both searches ran out of budget.
    Budget,
    /// Proven unsolvable.
    Unsolvable,
    /// Nothing beside the target (with `target_beside_only`): not planned.
    Skipped,
    /// The scene starts no episode.
    Invalid,
    /// The plan did not replay cleanly.
    NoReplay,
}

/// One scene's outcome, a line of the log.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
struct PlanRecord {
    /// Scene index.
    index: usize,
    /// What planning gave.
    outcome: SceneOutcome,
    /// Joint action indices of a kept plan.
    actions: Vec<u8>,
}

/// What planning produced.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct DemoStats {
    /// Scenes with an outcome (skipped ones included).
    pub scenes: usize,
    /// Scenes skipped because nothing lies beside their target.
    pub skipped: usize,
    /// Plans kept.
    pub kept: usize,
    /// Of those, proven shortest.
    pub shortest: usize,
    /// Scenes whose searches ran out of budget.
    pub budget: usize,
    /// Scenes proven unsolvable.
    pub unsolvable: usize,
    /// Plans that did not replay cleanly, or scenes that start no episode (none expected:
    /// the generator validates its scenes and the planner replays its plans).
    pub not_replayed: usize,
    /// Scenes already planned by an earlier run.
    pub resumed: usize,
}

/// The demonstration scenes (all of them, skipped ones included), named `demo-<index>`.
pub fn demo_scenes(config: &DemoConfig) -> Vec<Scenario> {
    let mut rng = ChaCha8Rng::seed_from_u64(config.seed);
    rng.set_stream(DEMO_STREAM);
    let mut scenes = generate_many(SceneKind::Complex, &mut rng, config.scenes);
    for (i, s) in scenes.iter_mut().enumerate() {
        s.name = format!("demo-{i}");
    }
    scenes
}

/// Plans (or resumes planning) every demonstration scene into `dir/plans.jsonl` with `threads`
/// workers, and returns the kept plans as trajectories in scene order. `progress` gets (scenes
/// done, scenes in all).
pub fn plan_demonstrations(
    config: &DemoConfig,
    base_env: EnvConfig,
    dir: &Path,
    threads: usize,
    mut progress: impl FnMut(usize, usize),
) -> Result<(Vec<Trajectory>, DemoStats), String> {
    fs::create_dir_all(dir).map_err(|e| format!("cannot create {}: {e}", dir.display()))?;
    let path = dir.join(PLANS_FILE);
    let env = config.env(base_env);
    let scenes = demo_scenes(config);
    let mut records = read_log(&path, config)?;
    let mut stats = DemoStats {
        resumed: records.len(),
        ..DemoStats::default()
    };
    let mut log = OpenOptions::new()
        .append(true)
        .open(&path)
        .map_err(|e| format!("cannot open {}: {e}", path.display()))?;
    progress(records.len(), scenes.len());
    while records.len() < scenes.len() {
        let first = records.len();
        let last = (first + CHUNK_SCENES.max(threads)).min(scenes.len());
        let planned = plan_chunk(&scenes[first..last], first, config, env, threads);
        let mut text = String::new();
        for record in &planned {
            text.push_str(&serde_json::to_string(record).map_err(|e| e.to_string())?);
            text.push('\n');
        }
        log.write_all(text.as_bytes())
            .and_then(|()| log.sync_data())
            .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        records.extend(planned);
        progress(records.len(), scenes.len());
    }
    let mut kept = Vec::new();
    for (record, scene) in records.iter().zip(scenes) {
        stats.scenes += 1;
        match record.outcome {
            SceneOutcome::Skipped => stats.skipped += 1,
            SceneOutcome::Budget => stats.budget += 1,
            SceneOutcome::Unsolvable => stats.unsolvable += 1,
            SceneOutcome::NoReplay | SceneOutcome::Invalid => stats.not_replayed += 1,
            SceneOutcome::Shortest | SceneOutcome::Solved => {
                stats.kept += 1;
                stats.shortest += usize::from(record.outcome == SceneOutcome::Shortest);
                let actions = decode_actions(&record.actions, record.index, &path)?;
                kept.push(Trajectory::new(scene, actions, Origin::Planner));
            }
        }
    }
    Ok((kept, stats))
}

/// Plans `scenes` (indices from `first`) on `threads` workers, in scene order.
fn plan_chunk(
    scenes: &[Scenario],
    first: usize,
    config: &DemoConfig,
    env: EnvConfig,
    threads: usize,
) -> Vec<PlanRecord> {
    let next = AtomicUsize::new(0);
    let done = Mutex::new(Vec::with_capacity(scenes.len()));
    std::thread::scope(|scope| {
        for _ in 0..threads.max(1) {
            scope.spawn(|| loop {
                let i = next.fetch_add(1, Ordering::Relaxed);
                let Some(scene) = scenes.get(i) else { break };
                let record = plan_scene(scene, first + i, config, env);
                // A worker that panicked poisons the lock; the others still finish.
                done.lock().unwrap_or_else(|p| p.into_inner()).push(record);
            });
        }
    });
    let mut done = done.into_inner().unwrap_or_else(|p| p.into_inner());
    done.sort_by_key(|r| r.index);
    done
}

/// One scene's outcome.
fn plan_scene(scene: &Scenario, index: usize, config: &DemoConfig, env: EnvConfig) -> PlanRecord {
    let record = |outcome: SceneOutcome, actions: Vec<u8>| PlanRecord {
        index,
        outcome,
        actions,
    };
    if config.target_beside_only && crate::evaluate::target_beside(scene).is_none() {
        return record(SceneOutcome::Skipped, Vec::new());
    }
    let Ok(start) = Env::new(scene, env) else {
        return record(SceneOutcome::Invalid, Vec::new());
    };
    let planner = PlannerConfig {
        max_expansions: config.max_expansions,
        ..PlannerConfig::default()
    };
    match plan_with_fallback(&start, &planner).outcome() {
        PlanOutcome::Solved { actions, shortest } => {
            // The planner replays its plan itself; this checks the trajectory as the batch
            // will store it (every action valid, success at the last one).
            let t = Trajectory::new(scene.clone(), actions.clone(), Origin::Planner);
            let clean = t.replay(env).is_ok_and(|r| {
                r.status == Status::Success && r.invalid_actions == 0 && r.collisions == 0
            });
            if !clean {
                return record(SceneOutcome::NoReplay, Vec::new());
            }
            let codes = actions.iter().map(|a| a.index() as u8).collect();
            let outcome = if *shortest {
                SceneOutcome::Shortest
            } else {
                SceneOutcome::Solved
            };
            record(outcome, codes)
        }
        PlanOutcome::Unsolvable => record(SceneOutcome::Unsolvable, Vec::new()),
        PlanOutcome::BudgetExceeded => record(SceneOutcome::Budget, Vec::new()),
    }
}

fn decode_actions(codes: &[u8], index: usize, path: &Path) -> Result<Vec<Action>, String> {
    codes
        .iter()
        .map(|&c| {
            Action::from_index(c as usize).ok_or_else(|| {
                format!(
                    "{}: scene {index}: action index {c} is not an action",
                    path.display()
                )
            })
        })
        .collect()
}

/// The records already in the log at `path`, creating it (header line only) when absent. A
/// log written with another configuration is refused; a half-written last line is cut.
fn read_log(path: &Path, config: &DemoConfig) -> Result<Vec<PlanRecord>, String> {
    let header = serde_json::to_string(config).map_err(|e| e.to_string())?;
    if !path.exists() {
        wheelleg_sim::atomic_write(path, format!("{header}\n").as_bytes())
            .map_err(|e| format!("cannot write {}: {e}", path.display()))?;
        return Ok(Vec::new());
    }
    let text =
        fs::read_to_string(path).map_err(|e| format!("cannot read {}: {e}", path.display()))?;
    let mut lines = text.split_inclusive('\n');
    let found: DemoConfig = lines
        .next()
        .and_then(|l| serde_json::from_str(l.trim_end()).ok())
        .ok_or_else(|| {
            format!(
                "{}: the first line is not a demonstration header",
                path.display()
            )
        })?;
    if found != *config {
        return Err(format!(
            "{} was planned with {} but the configuration asks for {header}: move it away \
             or restore the configuration",
            path.display(),
            serde_json::to_string(&found).unwrap_or_default()
        ));
    }
    let mut records = Vec::new();
    let mut good_bytes = header.len() + 1;
    for line in lines {
        let parsed = line
            .strip_suffix('\n')
            .and_then(|l| serde_json::from_str::<PlanRecord>(l).ok());
        match parsed {
            Some(r) if r.index == records.len() => {
                good_bytes += line.len();
                records.push(r);
            }
            // A line cut by a kill can only be the last one; anything after it is dropped.
            _ => break,
        }
    }
    if good_bytes < text.len() {
        let file = OpenOptions::new()
            .write(true)
            .open(path)
            .map_err(|e| format!("cannot open {}: {e}", path.display()))?;
        file.set_len(good_bytes as u64)
            .and_then(|()| file.sync_data())
            .map_err(|e| format!("cannot cut {}: {e}", path.display()))?;
    }
    Ok(records)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn temp_dir(name: &str) -> PathBuf {
        let dir = std::env::temp_dir().join(format!("wheelleg-demo-{name}-{}", std::process::id()));
        let _ = fs::remove_dir_all(&dir);
        dir
    }

    fn config() -> DemoConfig {
        DemoConfig {
            scenes: 6,
            seed: 3,
            max_expansions: 300,
            target_beside_only: false,
            max_steps: 100,
        }
    }

    #[test]
    fn kept_plans_succeed_and_a_cut_log_resumes_to_the_same_plans() {
        let dir = temp_dir("resume");
        let (full, stats) =
            plan_demonstrations(&config(), EnvConfig::default(), &dir, 2, |_, _| {}).unwrap();
        assert_eq!(stats.scenes, 6);
        assert!(stats.kept > 0, "{stats:?}");
        for t in &full {
            let r = t.replay(EnvConfig::default()).unwrap();
            assert!(r.success() && r.collision_free(), "{}", t.scenario.name);
            assert_eq!(t.origin, Origin::Planner);
        }
        // Kill in the middle of a line: keep the header and two records plus half a line.
        let path = dir.join(PLANS_FILE);
        let text = fs::read_to_string(&path).unwrap();
        let cut: usize = text
            .split_inclusive('\n')
            .take(3)
            .map(str::len)
            .sum::<usize>()
            + 5;
        fs::write(&path, &text[..cut]).unwrap();
        let (again, resumed) =
            plan_demonstrations(&config(), EnvConfig::default(), &dir, 1, |_, _| {}).unwrap();
        assert_eq!(resumed.resumed, 2);
        assert_eq!(again, full);
        assert_eq!(fs::read_to_string(&path).unwrap(), text);
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn a_log_of_another_configuration_is_refused_and_kept() {
        let dir = temp_dir("mismatch");
        plan_demonstrations(&config(), EnvConfig::default(), &dir, 1, |_, _| {}).unwrap();
        let before = fs::read_to_string(dir.join(PLANS_FILE)).unwrap();
        let other = DemoConfig {
            seed: 4,
            ..config()
        };
        let err =
            plan_demonstrations(&other, EnvConfig::default(), &dir, 1, |_, _| {}).unwrap_err();
        assert!(err.contains("planned with"), "{err}");
        assert_eq!(fs::read_to_string(dir.join(PLANS_FILE)).unwrap(), before);
        let _ = fs::remove_dir_all(&dir);
    }

    #[test]
    fn target_beside_only_skips_exactly_the_scenes_with_nothing_beside_the_target() {
        let dir = temp_dir("beside");
        let c = DemoConfig {
            target_beside_only: true,
            max_expansions: 50,
            scenes: 12,
            ..config()
        };
        let (_, stats) = plan_demonstrations(&c, EnvConfig::default(), &dir, 2, |_, _| {}).unwrap();
        let nothing = demo_scenes(&c)
            .iter()
            .filter(|s| crate::evaluate::target_beside(s).is_none())
            .count();
        assert_eq!(stats.skipped, nothing);
        assert!(
            nothing > 0 && nothing < 12,
            "{nothing} of 12 with nothing beside"
        );
        let _ = fs::remove_dir_all(&dir);
    }
}
