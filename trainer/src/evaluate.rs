//! Evaluation (paper, "Evaluation"): run the policy on fixed scenarios and report success rate,
//! collision-free success rate, mean path length and its ratio to the planner's shortest path.
//!
//! The episodes run through a decision stack (`wheelleg_stack`: the rule, the guard, arrival,
//! the look-ahead and the searches), all scenarios in lock-step so that the policy is evaluated
//! once per step on the whole batch; stochastic draws come from the caller's seeded RNG.

use crate::error::TrainError;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use wheelleg_sim::env::{Env, EnvConfig, Status};
use wheelleg_sim::generate::{ComposedVariant, SceneKind};
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig};
use wheelleg_sim::scenario::Scenario;
use wheelleg_stack::episodes::{run_episodes, LookaheadStats};
use wheelleg_stack::policy::BatchPolicy;
use wheelleg_stack::{DecisionRule, StackConfig};

/// One scenario's result.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct ScenarioResult {
    /// Scenario name.
    pub name: String,
    /// Reached the target.
    pub success: bool,
    /// Reached it without any collision.
    pub collision_free: bool,
    /// Steps taken.
    pub steps: u32,
    /// Collisions.
    pub collisions: u32,
    /// How the episode ended.
    pub status: String,
    /// The planner's shortest step count, when it found one within its budget.
    pub planner_steps: Option<usize>,
    /// Distance from the body centre to the target when the episode ended: how near a
    /// failed episode came.
    pub final_distance_m: f32,
    /// The kind of obstacle nearest the target, if one is within [`BESIDE_TARGET_M`]:
    /// whether the robot must end its way beside, over or astride something.
    pub target_beside: Option<String>,
    /// Searches of the last metres run (0 without them).
    pub local_searches: u32,
    /// Of them, those that found a plan.
    pub local_plans: u32,
    /// What the look-ahead did (zeros without it).
    pub lookahead: LookaheadStats,
}

/// How near an obstacle's footprint must come to the target for the target to count as beside
/// it: 0.25 m, about the robot's half length, so the robot standing at the target is within
/// reach of it.
pub const BESIDE_TARGET_M: f32 = 0.25;

/// Results of the scenarios whose target is beside one kind of obstacle (or beside none).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct TargetBeside {
    /// `bar`, `slab`, `block`, or `nothing`.
    pub beside: String,
    /// Scenarios.
    pub scenarios: usize,
    /// Of them reached.
    pub successes: usize,
    /// Of them reached without collision.
    pub collision_free: usize,
}

/// Results of one group of scenarios (a scene family, a composed variant).
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct GroupResult {
    /// The group's name.
    pub name: String,
    /// Scenarios.
    pub scenarios: usize,
    /// Of them reached.
    pub successes: usize,
    /// Of them reached without collision.
    pub collision_free: usize,
}

/// A scenario's family: its name up to the first `-`, as the generators name their scenes
/// (`complex-3`, `composed-7-spread+lift-beyond`, `squeeze-12`); a name without one is its own
/// family.
pub fn scene_family(name: &str) -> &str {
    name.split_once('-').map_or(name, |(family, _)| family)
}

/// `results` split by `key`, groups in the order they first appear; scenarios without a key
/// are left out.
fn split_by(
    results: &[ScenarioResult],
    key: impl Fn(&ScenarioResult) -> Option<String>,
) -> Vec<GroupResult> {
    let mut groups: Vec<GroupResult> = Vec::new();
    for r in results {
        let Some(name) = key(r) else { continue };
        let at = match groups.iter().position(|g| g.name == name) {
            Some(at) => at,
            None => {
                groups.push(GroupResult {
                    name,
                    scenarios: 0,
                    successes: 0,
                    collision_free: 0,
                });
                groups.len() - 1
            }
        };
        let g = &mut groups[at];
        g.scenarios += 1;
        g.successes += usize::from(r.success);
        g.collision_free += usize::from(r.collision_free);
    }
    groups
}

/// The kind of the obstacle nearest `scenario`'s target, if within [`BESIDE_TARGET_M`].
pub fn target_beside(scenario: &Scenario) -> Option<&'static str> {
    scenario
        .obstacles
        .iter()
        .map(|o| (o.ground_box().ground_distance_m(scenario.target), o.kind))
        .filter(|(distance_m, _)| *distance_m <= BESIDE_TARGET_M)
        .min_by(|a, b| a.0.total_cmp(&b.0))
        .map(|(_, kind)| kind.name())
}

/// The whole evaluation.
#[derive(Clone, Debug, PartialEq, Serialize)]
pub struct EvalReport {
    /// How actions were chosen.
    pub decision: DecisionRule,
    /// Margin of the look-ahead collision guard, when one checked the actions
    /// (`wheelleg_runtime::guard`); none: the policy alone.
    pub guard_margin_m: Option<f32>,
    /// Cell side of the map the guard read, when one checked the actions: the policy's
    /// 0.05 m, or a finer map's.
    pub guard_cell_m: Option<f32>,
    /// Whether an action that reaches the target was taken first whenever one did
    /// (`wheelleg_runtime::arrival`).
    pub arrival: bool,
    /// Whether the last metres were searched on the robot's map
    /// (`wheelleg_sim::local_plan`), and if so how often and with what luck.
    pub last_metres: Option<LastMetresReport>,
    /// Whether the look-ahead weighed candidates (`wheelleg_stack::lookahead`), and if so how often it
    /// took another action than the rule's.
    pub lookahead: Option<LookaheadReport>,
    /// Fraction of scenarios reached.
    pub success_rate: f32,
    /// Fraction reached without collision.
    pub collision_free_rate: f32,
    /// Mean steps of the successful episodes (none without successes).
    pub mean_steps: Option<f32>,
    /// Sum of policy steps over sum of planner steps, over scenarios both solved.
    pub steps_vs_shortest: Option<f32>,
    /// Median over the same scenarios of each one's steps over its planner steps: the typical
    /// detour, which a few long ones do not move (the sum ratio above weighs them fully).
    pub median_steps_vs_shortest: Option<f32>,
    /// Successful scenarios left out of the ratio because the planner ran out of budget.
    pub planner_budget_exceeded: usize,
    /// The results split by what stands beside the target (nothing first, then bar, slab,
    /// block): where the failures are.
    pub by_target_beside: Vec<TargetBeside>,
    /// The results split by scene family ([`scene_family`]), in the order they first appear.
    pub by_family: Vec<GroupResult>,
    /// The composed scenes' results split by variant (fences and ending,
    /// `wheelleg_sim::generate::ComposedVariant`), sorted by name; empty without composed
    /// scenes.
    pub by_composed_variant: Vec<GroupResult>,
    /// Per scenario.
    pub scenarios: Vec<ScenarioResult>,
}

/// What the look-ahead did over an evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LookaheadReport {
    /// Candidates weighed at each decision.
    pub candidates: usize,
    /// Candidates weighed where none of the first arrives.
    pub stuck_candidates: usize,
    /// Steps a rollout may take.
    pub horizon_steps: u32,
    /// Expansions of the search for a shorter way (0: no search).
    pub search_expansions: usize,
    /// Decisions at which candidates were weighed.
    pub decisions: u64,
    /// Of them, those where another action than the rule's own was taken.
    pub overrides: u64,
}

/// What the last-metres search did over an evaluation.
#[derive(Clone, Copy, Debug, PartialEq, Serialize)]
pub struct LastMetresReport {
    /// Episodes in which it ran.
    pub episodes_searched: usize,
    /// Searches run.
    pub searches: u32,
    /// Of them, those that found a plan.
    pub plans: u32,
}

/// Options of an evaluation.
#[derive(Clone, Debug)]
pub struct EvalOptions {
    /// The layers between the policy's logits and the action sent.
    pub stack: StackConfig,
    /// Planner budget (expanded states) per scenario; 0 skips the planner.
    pub planner_expansions: usize,
    /// Episode rules.
    pub env_config: EnvConfig,
    /// Shortest step counts already known by scenario name (none: not proven within the
    /// planner's budget), read from `wheelleg plan --json` by [`read_plan_results`]. When
    /// given, the planner is not run: one planner pass over a held-out set then serves every
    /// policy evaluated on it.
    pub known_shortest: Option<HashMap<String, Option<usize>>>,
}

#[derive(Deserialize)]
struct PlanFile {
    results: Vec<PlanLine>,
}

#[derive(Deserialize)]
struct PlanLine {
    name: String,
    steps: Option<usize>,
    shortest: bool,
}

/// Parses the JSON of `wheelleg plan --json` into shortest step counts by scenario name; a
/// result the planner did not prove shortest (weighted fallback, budget) counts as unknown.
pub fn read_plan_results(json: &str) -> Result<HashMap<String, Option<usize>>, TrainError> {
    let file: PlanFile = serde_json::from_str(json).map_err(TrainError::NotPlanResults)?;
    let mut known = HashMap::with_capacity(file.results.len());
    for line in file.results {
        let steps = line.steps.filter(|_| line.shortest);
        if known.insert(line.name.clone(), steps).is_some() {
            return Err(TrainError::ScenarioTwice { name: line.name });
        }
    }
    Ok(known)
}

impl Default for EvalOptions {
    /// The `robot` stack, a planner pass of 20,000 expansions per scenario.
    fn default() -> Self {
        EvalOptions {
            stack: StackConfig::default(),
            planner_expansions: 20_000,
            env_config: EnvConfig::default(),
            known_shortest: None,
        }
    }
}

/// One observation as plain vectors: height map (metres, row-major) and state.
pub type RecordedObservation = (Vec<f32>, Vec<f32>);

/// Observations a policy meets when it drives through `scenarios` (every step of every
/// episode, at most `limit`): the calibration and agreement data of quantization.
pub fn collect_observations(
    policy: &dyn BatchPolicy,
    scenarios: &[Scenario],
    options: &EvalOptions,
    rng: &mut impl Rng,
    limit: usize,
) -> Result<Vec<RecordedObservation>, TrainError> {
    let mut observations = Vec::new();
    let stack = &options.stack;
    run_episodes(
        policy,
        scenarios,
        stack,
        options.env_config,
        rng,
        &mut |decision| {
            if observations.len() < limit {
                observations.push((decision.height_map_m.to_vec(), decision.state.to_vec()));
            }
        },
    )
    .map_err(TrainError::Stack)?;
    Ok(observations)
}

/// Runs `policy` once on every scenario and measures it.
pub fn evaluate(
    policy: &dyn BatchPolicy,
    scenarios: &[Scenario],
    options: &EvalOptions,
    rng: &mut impl Rng,
) -> Result<EvalReport, TrainError> {
    let stack = &options.stack;
    let episodes = run_episodes(
        policy,
        scenarios,
        stack,
        options.env_config,
        rng,
        &mut |_| {},
    )
    .map_err(TrainError::Stack)?;
    let planner = PlannerConfig {
        max_expansions: options.planner_expansions,
        ..PlannerConfig::default()
    };
    let mut results = Vec::with_capacity(scenarios.len());
    for (s, episode) in scenarios.iter().zip(&episodes) {
        let env = &episode.env;
        let success = env.status() == Status::Success;
        let planner_steps = if let Some(known) = &options.known_shortest {
            *known.get(&s.name).ok_or_else(|| TrainError::NoPlanResult {
                name: s.name.clone(),
            })?
        } else if success && options.planner_expansions > 0 {
            let fresh = Env::new(s, options.env_config)?;
            match plan(&fresh, &planner).outcome {
                PlanOutcome::Solved { actions, .. } => Some(actions.len()),
                _ => None,
            }
        } else {
            None
        };
        results.push(ScenarioResult {
            name: s.name.clone(),
            success,
            collision_free: success && env.collisions() == 0,
            steps: env.steps(),
            collisions: env.collisions(),
            status: format!("{:?}", env.status()),
            planner_steps,
            final_distance_m: env.distance_to_target_m(),
            target_beside: target_beside(s).map(str::to_owned),
            local_searches: episode.local_searches,
            local_plans: episode.local_plans,
            lookahead: episode.lookahead,
        });
    }
    let n = results.len().max(1) as f32;
    let successes: Vec<&ScenarioResult> = results.iter().filter(|r| r.success).collect();
    let mean_steps = (!successes.is_empty())
        .then(|| successes.iter().map(|r| r.steps as f32).sum::<f32>() / successes.len() as f32);
    let both: Vec<&&ScenarioResult> = successes
        .iter()
        .filter(|r| r.planner_steps.is_some())
        .collect();
    let steps_vs_shortest = (!both.is_empty()).then(|| {
        both.iter().map(|r| r.steps as f32).sum::<f32>()
            / both
                .iter()
                .map(|r| r.planner_steps.unwrap_or(1) as f32)
                .sum::<f32>()
    });
    let mut ratios: Vec<f32> = both
        .iter()
        .filter_map(|r| Some(r.steps as f32 / r.planner_steps? as f32))
        .collect();
    ratios.sort_unstable_by(f32::total_cmp);
    let median_steps_vs_shortest = match ratios.len() {
        0 => None,
        len if len % 2 == 1 => Some(ratios[len / 2]),
        len => Some(0.5 * (ratios[len / 2 - 1] + ratios[len / 2])),
    };
    let by_target_beside = ["nothing", "bar", "slab", "block"]
        .into_iter()
        .map(|beside| {
            let of: Vec<&ScenarioResult> = results
                .iter()
                .filter(|r| r.target_beside.as_deref().unwrap_or("nothing") == beside)
                .collect();
            TargetBeside {
                beside: beside.to_owned(),
                scenarios: of.len(),
                successes: of.iter().filter(|r| r.success).count(),
                collision_free: of.iter().filter(|r| r.collision_free).count(),
            }
        })
        .filter(|b| b.scenarios > 0)
        .collect();
    let by_family = split_by(&results, |r| Some(scene_family(&r.name).to_owned()));
    let mut by_composed_variant = split_by(&results, |r| {
        (scene_family(&r.name) == SceneKind::Composed.name())
            .then(|| ComposedVariant::of_name(&r.name).map(|v| v.name()))
            .flatten()
    });
    by_composed_variant.sort_by(|a, b| a.name.cmp(&b.name));
    Ok(EvalReport {
        decision: stack.rule,
        guard_margin_m: stack.guard.map(|g| g.margin_m),
        guard_cell_m: stack.guard.map(|g| {
            g.grid
                .map_or(wheelleg_runtime::observation::HEIGHT_MAP_CELL_M, |g| {
                    g.cell_m
                })
        }),
        arrival: stack.arrival,
        last_metres: stack.last_metres.map(|_| LastMetresReport {
            episodes_searched: results.iter().filter(|r| r.local_searches > 0).count(),
            searches: results.iter().map(|r| r.local_searches).sum(),
            plans: results.iter().map(|r| r.local_plans).sum(),
        }),
        lookahead: stack.lookahead.map(|config| LookaheadReport {
            candidates: config.candidates,
            search_expansions: config.search_expansions,
            stuck_candidates: config.stuck_candidates,
            horizon_steps: config.horizon_steps,
            decisions: results
                .iter()
                .map(|r| u64::from(r.lookahead.decisions))
                .sum(),
            overrides: results
                .iter()
                .map(|r| u64::from(r.lookahead.overrides))
                .sum(),
        }),
        success_rate: successes.len() as f32 / n,
        collision_free_rate: results.iter().filter(|r| r.collision_free).count() as f32 / n,
        mean_steps,
        steps_vs_shortest,
        median_steps_vs_shortest,
        planner_budget_exceeded: if options.planner_expansions > 0
            || options.known_shortest.is_some()
        {
            successes.len() - both.len()
        } else {
            0
        },
        by_target_beside,
        by_family,
        by_composed_variant,
        scenarios: results,
    })
}

#[cfg(test)]
mod tests;
