//! A batch of scenarios driven to their end through a stack, in lock-step: one batched policy
//! call per step for all running episodes (and one per rollout step for the look-ahead).

use crate::config::{DecisionRule, StackConfig};
use crate::lookahead::Lookahead;
use crate::policy::{greedy_heads, sample_heads, BatchPolicy, LOG_PROBS};
use crate::rule::{candidates, mark_taken, settled, GuardAt, RobotRule};
use rand::Rng;
use serde::Serialize;
use wheelleg_runtime::action::{Action, DIMS};
use wheelleg_runtime::arrival::Arrival;
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_runtime::guard::{CollisionGuard, HeightMapRef};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, STATE_LEN};
use wheelleg_runtime::robot::Robot;
use wheelleg_sim::env::{Env, EnvConfig, GuardMap, Observation};
use wheelleg_sim::local_plan::LastMetres;
use wheelleg_sim::scenario::Scenario;

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
    /// Every action stepped, in order, whoever chose it (a search's plan steps included, and
    /// actions the world undid): the episode replays from its scenario with them.
    pub actions: Vec<Action>,
}

/// One decision the policy took part in: the episode and where it stood, the observation the
/// policy read (height map in metres, row-major; state) and the action taken there, whoever
/// chose it (the rule, the guard, the arrival rule or the look-ahead; steps of a search's plan
/// are not decisions).
#[derive(Clone, Copy, Debug)]
pub struct Decision<'a> {
    /// Index of the episode's scenario in the batch.
    pub episode: usize,
    /// The episode as it stood when the action was chosen (before it is taken).
    pub env: &'a Env,
    /// The height map the policy read.
    pub height_map_m: &'a [f32],
    /// The state it read.
    pub state: &'a [f32],
    /// The action taken.
    pub action: Action,
}

/// Runs every scenario to its end under `env_config` through `stack`, in lock-step, calling
/// `on_decision` at each decision; draws of [`DecisionRule::Sample`] come from `rng`. Returns
/// the finished episodes in the scenarios' order.
pub fn run_episodes(
    policy: &dyn BatchPolicy,
    scenarios: &[Scenario],
    stack: &StackConfig,
    env_config: EnvConfig,
    rng: &mut impl Rng,
    on_decision: &mut dyn FnMut(Decision<'_>),
) -> Result<Vec<FinishedEpisode>, String> {
    stack.check()?;
    let mut envs = scenarios
        .iter()
        .map(|s| Env::new(s, env_config).map_err(|e| format!("scenario {}: {e:?}", s.name)))
        .collect::<Result<Vec<_>, _>>()?;
    let mut obs = Observation::default();
    let mut deciders: Vec<Decider> = vec![Decider::new(); envs.len()];
    let mut keys = vec![ObservationKey(0); envs.len()];
    // The guard checks the robot simulated: its geometry and lattice from the episode rules
    // (the CAN wiring plays no part in it).
    let robot = Robot {
        geometry: *env_config.robot.geometry(),
        actions: *env_config.robot.lattice(),
        ..Robot::WHEELLEG
    };
    let guard = stack
        .guard
        .map(|layer| CollisionGuard::new(&robot, layer.margin_m));
    let mut guard_map = stack.guard.and_then(|layer| layer.grid).map(GuardMap::new);
    let mut lookahead = Lookahead::new(stack.lookahead.unwrap_or_default());
    let mut lookahead_stats = vec![LookaheadStats::default(); envs.len()];
    let mut last_metres: Vec<Option<LastMetres>> = envs
        .iter()
        .map(|_| stack.last_metres.map(LastMetres::new))
        .collect();
    let mut actions: Vec<Vec<Action>> = vec![Vec::new(); envs.len()];
    let success_radius_m = env_config.success_radius_m;
    loop {
        // Episodes following a local plan step without the policy.
        for ((env, last_metres), taken) in envs.iter_mut().zip(&mut last_metres).zip(&mut actions) {
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
                taken.push(action);
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
        let log_probs = policy.log_probs(&heights, &states, running.len())?;
        if log_probs.len() < running.len() * LOG_PROBS {
            return Err("the policy returned too few log-probabilities".to_string());
        }
        // Each running episode's action, or none where the look-ahead picks.
        let mut chosen: Vec<Option<Action>> = vec![None; running.len()];
        for (k, &i) in running.iter().enumerate() {
            let own = &log_probs[k * LOG_PROBS..(k + 1) * LOG_PROBS];
            let action = match stack.rule {
                DecisionRule::Sample => from_choices(sample_heads(own, rng)),
                DecisionRule::Argmax => from_choices(greedy_heads(own)),
                DecisionRule::Untried => {
                    let logits: &[f32; LOG_PROBS] = own
                        .try_into()
                        .map_err(|_| "log-probabilities of the wrong size".to_string())?;
                    let state = &states[k * STATE_LEN..(k + 1) * STATE_LEN];
                    let cells = &heights[k * HEIGHT_MAP_CELLS..(k + 1) * HEIGHT_MAP_CELLS];
                    let rule = RobotRule {
                        guard: guard_at(
                            guard.as_ref(),
                            guard_map.as_mut(),
                            &envs[i],
                            cells,
                            state,
                        )?,
                        arrival: stack.arrival.then(|| {
                            Arrival::from_state_m(state, success_radius_m, &robot.actions)
                        }),
                    };
                    let key = keys[i];
                    if stack.lookahead.is_none() {
                        rule.choose(&mut deciders[i], key, logits)
                    } else {
                        let wanted = lookahead.candidates_wanted();
                        let found =
                            candidates(&deciders[i], wanted, |d| rule.choose(d, key, logits));
                        match settled(&found, rule.arrival.as_ref()) {
                            Some(first) => {
                                mark_taken(&mut deciders[i], key, first);
                                first
                            }
                            None => {
                                lookahead.push(i, &envs[i], &deciders[i], key, found);
                                continue;
                            }
                        }
                    }
                }
            };
            chosen[k] = Some(action);
        }
        // The guard of a pushed decision, asked again at weighing: the episodes have not moved
        // since, and the guard map is one buffer rendered per episode.
        let mut guard_error = None;
        let mut allows = |i: usize, action: Action| {
            let Ok(k) = running.binary_search(&i) else {
                return false;
            };
            let cells = &heights[k * HEIGHT_MAP_CELLS..(k + 1) * HEIGHT_MAP_CELLS];
            let state = &states[k * STATE_LEN..(k + 1) * STATE_LEN];
            match guard_at(guard.as_ref(), guard_map.as_mut(), &envs[i], cells, state) {
                Ok(at) => RobotRule {
                    guard: at,
                    arrival: None,
                }
                .allows(action),
                Err(e) => {
                    guard_error = Some(e);
                    false
                }
            }
        };
        let weighed = lookahead.weigh(policy, stack.arrival, success_radius_m, &mut allows)?;
        if let Some(e) = guard_error {
            return Err(e);
        }
        for weighed in weighed {
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
                episode: i,
                env: &envs[i],
                height_map_m: &heights[k * HEIGHT_MAP_CELLS..(k + 1) * HEIGHT_MAP_CELLS],
                state: &states[k * STATE_LEN..(k + 1) * STATE_LEN],
                action,
            });
            envs[i]
                .step(action)
                .map_err(|_| "stepped a finished episode".to_string())?;
            actions[i].push(action);
        }
    }
    Ok(envs
        .into_iter()
        .zip(last_metres)
        .zip(lookahead_stats)
        .zip(actions)
        .map(
            |(((env, last_metres), lookahead), actions)| FinishedEpisode {
                env,
                lookahead,
                local_searches: last_metres.as_ref().map_or(0, LastMetres::searches),
                local_plans: last_metres.as_ref().map_or(0, LastMetres::plans),
                actions,
            },
        )
        .collect())
}

/// The guard at episode `env`'s observation (its `cells` and `state`, in metres), reading
/// `guard_map` where one is rendered and the observation's own height map otherwise; none
/// without a guard.
fn guard_at<'a>(
    guard: Option<&'a CollisionGuard>,
    guard_map: Option<&'a mut GuardMap>,
    env: &Env,
    cells: &'a [f32],
    state: &[f32],
) -> Result<Option<GuardAt<'a>>, String> {
    let Some(guard) = guard else {
        return Ok(None);
    };
    let map = match guard_map {
        None => {
            let cells: &[f32; HEIGHT_MAP_CELLS] = cells
                .try_into()
                .map_err(|_| "height map of the wrong size".to_string())?;
            HeightMapRef::Metres(cells)
        }
        Some(guard_map) => guard_map
            .observe(env)
            .map_err(|e| format!("guard map: {e}"))?,
    };
    let legs = LegConfig {
        clearance_m: state.first().copied().unwrap_or_default(),
        track_m: state.get(1).copied().unwrap_or_default(),
    };
    Ok(Some(GuardAt { guard, map, legs }))
}

fn from_choices(choices: [u8; DIMS]) -> Action {
    Action::from_head_indices(choices.map(usize::from)).unwrap_or_default()
}
