//! Evaluation (paper, "Evaluation"): run the policy on fixed scenarios and report success rate,
//! collision-free success rate, mean path length and its ratio to the planner's shortest path.
//!
//! All scenarios run in lock-step so the policy is evaluated once per step on the whole batch.
//! Deterministic by default: the most probable joint action not yet taken at the same observation
//! (`wheelleg_runtime::decision::Decider`, the rule the robot runs). Plain per-head argmax, which
//! repeats a refused action until the step limit, is kept for comparison; stochastic draws come
//! from the caller's seeded RNG.

use crate::batch_policy::BatchPolicy;
use crate::lookahead::{candidates, mark_taken, settled, Lookahead, LookaheadConfig};
use crate::network_f32::NetworkF32;
use rand::Rng;
use serde::{Deserialize, Serialize};
use std::collections::HashMap;
use wheelleg_runtime::action::{Action, CHOICES, DIMS};
use wheelleg_runtime::arrival::Arrival;
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_runtime::guard::{CollisionGuard, HeightMapRef};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_runtime::robot::WHEELLEG;
use wheelleg_sim::env::{Env, EnvConfig, GuardMap, Observation, Status};
use wheelleg_sim::generate::{ComposedVariant, SceneKind};
use wheelleg_sim::height_map::MapGrid;
use wheelleg_sim::local_plan::{LastMetres, LastMetresConfig};
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig};
use wheelleg_sim::scenario::Scenario;

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

/// What the look-ahead did in one episode.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
pub struct LookaheadStats {
    /// Decisions it weighed candidates at (not those with one candidate or an arriving one).
    pub decisions: u32,
    /// Of them, those where it took another action than the rule's own.
    pub overrides: u32,
}

/// A finished episode and what the last-metres search and the look-ahead did in it.
#[derive(Clone, Debug)]
pub struct FinishedEpisode {
    /// What the look-ahead did (zeros without it).
    pub lookahead: LookaheadStats,
    /// The episode at its end.
    pub env: Env,
    /// Searches of the last metres run.
    pub local_searches: u32,
    /// Of them, those that found a plan.
    pub local_plans: u32,
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
    /// Whether the look-ahead weighed candidates (`crate::lookahead`), and if so how often it
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

/// How the policy's five heads become one action.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum DecisionRule {
    /// The most probable joint action not yet taken at the same observation (deterministic;
    /// what the robot runs).
    #[default]
    Untried,
    /// Each head's most probable choice, even if that action was just refused.
    Argmax,
    /// A draw from each head's distribution (the training rule).
    Sample,
}

/// Options of an evaluation.
#[derive(Clone, Debug)]
pub struct EvalOptions {
    /// How actions are chosen.
    pub decision: DecisionRule,
    /// Planner budget (expanded states) per scenario; 0 skips the planner.
    pub planner_expansions: usize,
    /// Episode rules.
    pub env_config: EnvConfig,
    /// Shortest step counts already known by scenario name (none: not proven within the
    /// planner's budget), read from `wheelleg plan --json` by [`read_plan_results`]. When
    /// given, the planner is not run: one planner pass over a held-out set then serves every
    /// policy evaluated on it.
    pub known_shortest: Option<HashMap<String, Option<usize>>>,
    /// Check each action against the height map before taking it
    /// (`wheelleg_runtime::guard::CollisionGuard` with this margin), as a robot running the
    /// guard does; only with [`DecisionRule::Untried`]. None: the policy alone.
    pub guard_margin_m: Option<f32>,
    /// The map the guard reads: none, the policy's own; a layout, a map of it rendered from
    /// the scene at every step (a robot that keeps a finer elevation map than the policy's
    /// input, docs/results.md "A finer map for the guard").
    pub guard_grid: Option<MapGrid>,
    /// Take the policy's most probable action that reaches the target whenever one does
    /// (`wheelleg_runtime::arrival`, at the episode's success radius); only with
    /// [`DecisionRule::Untried`].
    pub arrival: bool,
    /// Search the robot's own map for the last metres when the policy lingers near the
    /// target (`wheelleg_sim::local_plan`), and take the plan found; none: the policy alone.
    pub last_metres: Option<LastMetresConfig>,
    /// Weigh the rule's first few candidate actions by rollouts of the policy on the robot's
    /// own map, and take the one that arrives soonest (`crate::lookahead`); none: the rule's
    /// own action.
    pub lookahead: Option<LookaheadConfig>,
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
pub fn read_plan_results(json: &str) -> Result<HashMap<String, Option<usize>>, String> {
    let file: PlanFile = serde_json::from_str(json)
        .map_err(|e| format!("not the output of `wheelleg plan --json`: {e}"))?;
    let mut known = HashMap::with_capacity(file.results.len());
    for line in file.results {
        let steps = line.steps.filter(|_| line.shortest);
        if known.insert(line.name.clone(), steps).is_some() {
            return Err(format!("scenario {:?} appears twice", line.name));
        }
    }
    Ok(known)
}

impl Default for EvalOptions {
    fn default() -> Self {
        EvalOptions {
            decision: DecisionRule::Untried,
            planner_expansions: 20_000,
            env_config: EnvConfig::default(),
            known_shortest: None,
            guard_margin_m: None,
            guard_grid: None,
            arrival: false,
            last_metres: None,
            lookahead: None,
        }
    }
}

/// One decision the policy took part in: the observation it read (height map in metres,
/// row-major; state) and the action taken there, whoever chose it (the rule, the guard, the
/// arrival rule or the look-ahead; steps of a search's plan are not decisions).
#[derive(Clone, Copy, Debug)]
pub struct Decision<'a> {
    /// The height map the policy read.
    pub height_map_m: &'a [f32],
    /// The state it read.
    pub state: &'a [f32],
    /// The action taken.
    pub action: Action,
}

/// Runs every scenario to its end in lock-step (one batched policy call per step), calling
/// `on_decision` at each decision. Returns the finished episodes.
pub fn run_episodes(
    policy: &dyn BatchPolicy,
    scenarios: &[Scenario],
    options: &EvalOptions,
    rng: &mut impl Rng,
    on_decision: &mut dyn FnMut(Decision<'_>),
) -> Result<Vec<FinishedEpisode>, String> {
    let mut envs = scenarios
        .iter()
        .map(|s| Env::new(s, options.env_config).map_err(|e| format!("scenario {}: {e:?}", s.name)))
        .collect::<Result<Vec<_>, _>>()?;
    let mut obs = Observation::default();
    let mut deciders: Vec<Decider> = vec![Decider::new(); envs.len()];
    let mut keys = vec![ObservationKey(0); envs.len()];
    if options.arrival && options.decision != DecisionRule::Untried {
        return Err(format!(
            "arrival needs the untried decision rule, not {:?}",
            options.decision
        ));
    }
    let guard = match (options.guard_margin_m, options.decision) {
        (None, _) => None,
        (Some(margin_m), DecisionRule::Untried) => Some(CollisionGuard::new(WHEELLEG, margin_m)),
        (Some(_), rule) => {
            return Err(format!(
                "the collision guard needs the untried decision rule, not {rule:?}"
            ))
        }
    };
    let mut guard_map = options.guard_grid.map(GuardMap::new);
    let mut lookahead = Lookahead::new(options.lookahead.unwrap_or_default());
    let mut lookahead_stats = vec![LookaheadStats::default(); envs.len()];
    let mut last_metres: Vec<Option<LastMetres>> = envs
        .iter()
        .map(|_| options.last_metres.map(LastMetres::new))
        .collect();
    loop {
        // Episodes following a local plan step without the policy.
        for (env, last_metres) in envs.iter_mut().zip(&mut last_metres) {
            let Some(last_metres) = last_metres else {
                continue;
            };
            while !env.status().is_done() {
                let Some(action) = last_metres.next_action(env) else {
                    break;
                };
                let outcome = env
                    .step(action)
                    .map_err(|_| "stepped a finished episode".to_string())?;
                if outcome.invalid.is_some() {
                    last_metres.abandon();
                }
            }
        }
        let running: Vec<usize> = (0..envs.len())
            .filter(|&i| !envs[i].status().is_done())
            .collect();
        if running.is_empty() {
            break;
        }
        let mut heights = Vec::with_capacity(running.len() * HEIGHT_MAP_CELLS);
        let mut states = Vec::with_capacity(running.len() * STATE_LEN);
        for &i in &running {
            envs[i].observe(&mut obs);
            keys[i] = ObservationKey::of_metres(&obs.height_map, &obs.state);
            heights.extend_from_slice(&obs.height_map);
            states.extend_from_slice(&obs.state);
        }
        let out = policy.log_probs(&heights, &states, running.len())?;
        // Each running episode's action, or its candidates when the look-ahead picks.
        let mut chosen: Vec<Option<Action>> = vec![None; running.len()];
        for (k, &i) in running.iter().enumerate() {
            let action = match options.decision {
                DecisionRule::Sample => from_choices(out.sample(k, rng)),
                DecisionRule::Argmax => from_choices(out.greedy(k)),
                DecisionRule::Untried => {
                    let mut logits = [0.0f32; DIMS * CHOICES];
                    logits.copy_from_slice(
                        &out.log_probs[k * DIMS * CHOICES..(k + 1) * DIMS * CHOICES],
                    );
                    let state = &states[k * STATE_LEN..(k + 1) * STATE_LEN];
                    let arrival = options
                        .arrival
                        .then(|| Arrival::from_state_m(state, options.env_config.success_radius_m));
                    let legs = LegConfig {
                        clearance_m: state[0],
                        track_m: state[1],
                    };
                    let map = match (&guard, &mut guard_map) {
                        (None, _) => None,
                        (Some(_), None) => {
                            let cells = &heights[k * HEIGHT_MAP_CELLS..(k + 1) * HEIGHT_MAP_CELLS];
                            let cells: &[f32; HEIGHT_MAP_CELLS] = cells
                                .try_into()
                                .map_err(|_| "height map of the wrong size".to_string())?;
                            Some(HeightMapRef::Metres(cells))
                        }
                        (Some(_), Some(guard_map)) => Some(
                            guard_map
                                .observe(&envs[i])
                                .map_err(|e| format!("guard map: {e}"))?,
                        ),
                    };
                    let key = keys[i];
                    let decide = |decider: &mut Decider| match (&guard, map) {
                        (Some(guard), Some(map)) => {
                            guard
                                .choose(decider, key, &logits, map, legs, arrival.as_ref())
                                .action
                        }
                        _ => match &arrival {
                            Some(arrival) => arrival.choose(decider, key, &logits).action,
                            None => decider.choose(key, &logits),
                        },
                    };
                    match &options.lookahead {
                        None => decide(&mut deciders[i]),
                        Some(_) => {
                            let wanted = lookahead.candidates_wanted();
                            let found = candidates(&deciders[i], wanted, decide);
                            match settled(&found, arrival.as_ref()) {
                                Some(first) => {
                                    mark_taken(&mut deciders[i], key, first);
                                    first
                                }
                                None => {
                                    let allows = |action| match (&guard, map) {
                                        (Some(guard), Some(map)) => {
                                            guard.check(map, legs, action).is_ok()
                                        }
                                        _ => true,
                                    };
                                    lookahead.push(i, &envs[i], &deciders[i], key, found, &allows);
                                    continue;
                                }
                            }
                        }
                    }
                }
            };
            chosen[k] = Some(action);
        }
        for weighed in
            lookahead.weigh(policy, options.arrival, options.env_config.success_radius_m)?
        {
            // Slots are episodes, so that a way kept for one is offered to it again.
            let i = weighed.slot;
            let k = running
                .binary_search(&i)
                .map_err(|_| "the look-ahead weighed an episode not running")?;
            // No candidate arrives within the horizon: the policy is lost here, so the search
            // (when on) runs now rather than when it is next due.
            if !weighed.arrives {
                if let Some(search) = &mut last_metres[i] {
                    if search.search_now(&envs[i]) {
                        if let Some(action) = search.next_action(&envs[i]) {
                            mark_taken(&mut deciders[i], keys[i], action);
                            chosen[k] = Some(action);
                            continue;
                        }
                    }
                }
            }
            mark_taken(&mut deciders[i], keys[i], weighed.action);
            lookahead_stats[i].decisions += 1;
            lookahead_stats[i].overrides += u32::from(weighed.overridden);
            chosen[k] = Some(weighed.action);
        }
        for (k, &i) in running.iter().enumerate() {
            let action = chosen[k].ok_or("no action chosen")?;
            on_decision(Decision {
                height_map_m: &heights[k * HEIGHT_MAP_CELLS..(k + 1) * HEIGHT_MAP_CELLS],
                state: &states[k * STATE_LEN..(k + 1) * STATE_LEN],
                action,
            });
            envs[i]
                .step(action)
                .map_err(|_| "stepped a finished episode".to_string())?;
        }
    }
    Ok(envs
        .into_iter()
        .zip(last_metres)
        .zip(lookahead_stats)
        .map(|((env, last_metres), lookahead)| FinishedEpisode {
            env,
            lookahead,
            local_searches: last_metres.as_ref().map_or(0, LastMetres::searches),
            local_plans: last_metres.as_ref().map_or(0, LastMetres::plans),
        })
        .collect())
}

fn from_choices(choices: [u8; DIMS]) -> Action {
    Action::from_head_indices(choices.map(usize::from)).unwrap_or_default()
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
) -> Result<Vec<RecordedObservation>, String> {
    let mut observations = Vec::new();
    run_episodes(policy, scenarios, options, rng, &mut |decision| {
        if observations.len() < limit {
            observations.push((decision.height_map_m.to_vec(), decision.state.to_vec()));
        }
    })?;
    Ok(observations)
}

/// Runs `policy` once on every scenario and measures it.
pub fn evaluate(
    policy: &dyn BatchPolicy,
    scenarios: &[Scenario],
    options: &EvalOptions,
    rng: &mut impl Rng,
) -> Result<EvalReport, String> {
    let episodes = run_episodes(policy, scenarios, options, rng, &mut |_| {})?;
    let planner = PlannerConfig {
        max_expansions: options.planner_expansions,
        ..PlannerConfig::default()
    };
    let mut results = Vec::with_capacity(scenarios.len());
    for (s, episode) in scenarios.iter().zip(&episodes) {
        let env = &episode.env;
        let success = env.status() == Status::Success;
        let planner_steps = if let Some(known) = &options.known_shortest {
            *known
                .get(&s.name)
                .ok_or_else(|| format!("the planner results name no scenario {:?}", s.name))?
        } else if success && options.planner_expansions > 0 {
            let fresh = Env::new(s, options.env_config)
                .map_err(|e| format!("scenario {}: {e:?}", s.name))?;
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
        decision: options.decision,
        guard_margin_m: options.guard_margin_m,
        guard_cell_m: options.guard_margin_m.map(|_| {
            options
                .guard_grid
                .map_or(wheelleg_runtime::observation::HEIGHT_MAP_CELL_M, |g| {
                    g.cell_m
                })
        }),
        arrival: options.arrival,
        last_metres: options.last_metres.map(|_| LastMetresReport {
            episodes_searched: results.iter().filter(|r| r.local_searches > 0).count(),
            searches: results.iter().map(|r| r.local_searches).sum(),
            plans: results.iter().map(|r| r.local_plans).sum(),
        }),
        lookahead: options.lookahead.map(|config| LookaheadReport {
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

/// Loads a policy from a checkpoint file.
pub fn load_policy(path: &std::path::Path) -> Result<NetworkF32, String> {
    crate::checkpoint::load_policy(path)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::batch_policy::Fixated;
    use nalgebra::Point2;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;
    use wheelleg_sim::obstacle::{Obstacle, ObstacleKind, ObstacleYaw};
    use wheelleg_sim::state::RobotState;

    /// [`Fixated`] on `scenario` alone, without the planner.
    fn fixated_on(scenario: &Scenario, options: EvalOptions) -> Result<EvalReport, String> {
        let options = EvalOptions {
            planner_expansions: 0,
            ..options
        };
        let mut rng = ChaCha8Rng::seed_from_u64(0);
        evaluate(&Fixated, std::slice::from_ref(scenario), &options, &mut rng)
    }

    #[test]
    fn arrival_takes_the_one_step_the_policy_would_not() {
        // The target 6 cm to the robot's right: one step right arrives; the policy only ever
        // wants forward, then left.
        let scenario = Scenario {
            name: "target-beside".into(),
            start: RobotState::new(Point2::new(0.0, 0.125), 0),
            target: Point2::new(0.0, 0.065),
            obstacles: vec![],
        };
        let run = |arrival| {
            fixated_on(
                &scenario,
                EvalOptions {
                    arrival,
                    ..EvalOptions::default()
                },
            )
            .unwrap()
        };
        let alone = run(false);
        assert!(!alone.arrival);
        assert_ne!(alone.scenarios[0].status, "Success");
        let arriving = run(true);
        assert!(arriving.arrival);
        assert_eq!(arriving.scenarios[0].status, "Success");
        assert_eq!(arriving.scenarios[0].steps, 1);
        assert!(arriving.scenarios[0].final_distance_m <= 0.05);
        assert_eq!(
            arriving.by_target_beside,
            [TargetBeside {
                beside: "nothing".into(),
                scenarios: 1,
                successes: 1,
                collision_free: 1,
            }]
        );
        // Not with a rule that does not remember what it took.
        let argmax = EvalOptions {
            decision: DecisionRule::Argmax,
            arrival: true,
            ..EvalOptions::default()
        };
        assert!(fixated_on(&scenario, argmax).is_err());
    }

    #[test]
    fn the_default_rule_does_not_repeat_a_refused_action_and_argmax_does() {
        // A block straight ahead: "forward" is refused once the robot reaches it.
        let scenario = Scenario {
            name: "block-ahead".into(),
            start: RobotState::new(Point2::new(0.0, 0.125), 0),
            target: Point2::new(0.9, 0.125),
            obstacles: vec![Obstacle::new(
                ObstacleKind::Block,
                0.625,
                0.125,
                ObstacleYaw::Deg0,
            )],
        };
        let run = |decision| {
            fixated_on(
                &scenario,
                EvalOptions {
                    decision,
                    ..EvalOptions::default()
                },
            )
            .unwrap()
            .scenarios
            .remove(0)
        };
        let argmax = run(DecisionRule::Argmax);
        assert_eq!(argmax.status, "StepLimit");
        // The block's far face is 0.175 m short of the target.
        assert_eq!(argmax.target_beside.as_deref(), Some("block"));
        assert!(argmax.collisions > 80, "argmax pushes on: {argmax:?}");
        let untried = run(DecisionRule::Untried);
        // After each refusal it takes the next most probable action (forward and left, then
        // left), which slides it along the block's face until forward is free again; argmax
        // pushes into the block every step.
        assert!(untried.collisions > 0, "it did meet the block: {untried:?}");
        assert!(
            untried.collisions * 4 < argmax.collisions,
            "untried {untried:?}, argmax {argmax:?}"
        );
    }

    #[test]
    fn the_look_ahead_takes_a_later_choice_only_where_it_arrives_sooner() {
        let lookahead = |candidates| EvalOptions {
            lookahead: Some(LookaheadConfig {
                candidates,
                stuck_candidates: candidates,
                ..LookaheadConfig::default()
            }),
            ..EvalOptions::default()
        };
        // Ahead and to the left: the policy only ever drives forward and passes it by; its
        // second choice, forward and left, leads there diagonally.
        let ahead_left = Scenario {
            name: "ahead-left".into(),
            start: RobotState::new(Point2::new(0.0, 0.125), 0),
            target: Point2::new(0.5, 0.625),
            obstacles: vec![],
        };
        let alone = fixated_on(&ahead_left, EvalOptions::default()).unwrap();
        assert_ne!(alone.scenarios[0].status, "Success");
        assert!(alone.lookahead.is_none());
        let looked = fixated_on(&ahead_left, lookahead(2)).unwrap();
        let episode = &looked.scenarios[0];
        assert_eq!(episode.status, "Success", "{episode:?}");
        // 0.71 m at 0.0707 m a diagonal step, within the 0.05 m success radius.
        assert!(episode.steps <= 10, "{episode:?}");
        assert!(episode.lookahead.overrides > 0, "{episode:?}");
        let report = looked.lookahead.unwrap();
        assert_eq!(report.candidates, 2);
        assert_eq!(report.overrides, u64::from(episode.lookahead.overrides));
        // Straight ahead the policy's own choice is already the shortest: never overridden.
        let ahead = Scenario {
            name: "ahead".into(),
            target: Point2::new(0.5, 0.125),
            ..ahead_left
        };
        let alone = fixated_on(&ahead, EvalOptions::default()).unwrap();
        let looked = fixated_on(&ahead, lookahead(4)).unwrap();
        assert_eq!(looked.scenarios[0].status, "Success");
        assert_eq!(looked.scenarios[0].steps, alone.scenarios[0].steps);
        assert!(looked.scenarios[0].lookahead.decisions > 0);
        assert_eq!(looked.scenarios[0].lookahead.overrides, 0);
    }

    #[test]
    fn the_search_finds_the_shortest_way_where_every_rollout_is_longer() {
        // Far ahead on open ground: the policy drives straight, one 5 cm step at a time; the
        // shortest way turns so that the longer diagonal steps carry it.
        let ahead = Scenario {
            name: "far-ahead".into(),
            start: RobotState::new(Point2::new(0.0, 0.125), 0),
            target: Point2::new(0.9, 0.125),
            obstacles: vec![],
        };
        let searching = |search_expansions| EvalOptions {
            lookahead: Some(LookaheadConfig {
                candidates: 4,
                stuck_candidates: 4,
                search_expansions,
                ..LookaheadConfig::default()
            }),
            ..EvalOptions::default()
        };
        let run = |options| fixated_on(&ahead, options).unwrap().scenarios.remove(0);
        let rollouts = run(searching(0));
        let searched = run(searching(2_000));
        assert_eq!(rollouts.status, "Success", "{rollouts:?}");
        assert_eq!(searched.status, "Success", "{searched:?}");
        let env = Env::new(&ahead, EnvConfig::default()).unwrap();
        let PlanOutcome::Solved { actions, .. } = plan(&env, &PlannerConfig::default()).outcome
        else {
            panic!("open ground is solvable");
        };
        let shortest = actions.len();
        assert!(rollouts.steps > shortest as u32, "{rollouts:?}");
        assert_eq!(searched.steps, shortest as u32, "{searched:?}");
        assert!(searched.lookahead.overrides > 0);
    }
}
