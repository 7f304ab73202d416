//! Who decides the next action: the int8 policy from a weights file through a decision stack,
//! or the exact planner.
//!
//! Both look at the same world ([`Env`]) and answer with one lattice [`Action`] per decision,
//! so the closed loop cannot tell them apart. The policy sees exactly what it would see on the
//! robot: the height map and state in millimetres, the integer units of the runtime's model.

use std::collections::VecDeque;
use std::fmt;
use wheelleg_runtime::action::Action;
use wheelleg_runtime::arrival::Arrival;
use wheelleg_runtime::decision::{Decider, ObservationKey};
use wheelleg_runtime::guard::{CollisionGuard, HeightMapRef};
use wheelleg_runtime::leg::LegConfig;
use wheelleg_runtime::model::DefaultPolicy;
use wheelleg_runtime::observation::{HEIGHT_MAP_CELLS, HEIGHT_MAP_SIDE, STATE_LEN};
use wheelleg_sim::env::{Env, GuardMap, Observation};
use wheelleg_sim::local_plan::LastMetres;
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig};
use wheelleg_stack::lookahead::Lookahead;
use wheelleg_stack::policy::Int8Policy;
use wheelleg_stack::rule::{candidates, mark_taken, settled, GuardAt, RobotRule};
use wheelleg_stack::{DecisionRule, StackConfig};

/// A decision maker of the closed loop.
pub trait Driver {
    /// What is driving, for the user (for example "exact planner (21 steps, shortest)").
    fn describe(&self) -> String;
    /// The next action in the world as it is now.
    fn decide(&mut self, env: &Env) -> Result<Action, DriverError>;
}

/// Why a driver cannot decide.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct DriverError(pub String);

impl fmt::Display for DriverError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(&self.0)
    }
}

impl std::error::Error for DriverError {}

/// Replays the exact planner's action sequence, planned once from the episode's start.
///
/// Replaying open-loop is sound here because the closed loop keeps the world on the lattice
/// states the planner searched (see the module docs of [`crate::closed_loop`]); if the world
/// ever left them, the loop reports a tracking fault before this driver is asked again.
#[derive(Clone, Debug)]
pub struct PlannerDriver {
    actions: VecDeque<Action>,
    planned_steps: usize,
    shortest: bool,
}

impl PlannerDriver {
    /// Plans from `env`'s current state; an error when the planner finds no plan.
    pub fn new(env: &Env, config: &PlannerConfig) -> Result<PlannerDriver, DriverError> {
        match plan(env, config).outcome {
            PlanOutcome::Solved { actions, shortest } => Ok(PlannerDriver {
                planned_steps: actions.len(),
                actions: actions.into(),
                shortest,
            }),
            PlanOutcome::Unsolvable => Err(DriverError(
                "the planner proved the scene unsolvable within the episode rules".to_owned(),
            )),
            PlanOutcome::BudgetExceeded => Err(DriverError(format!(
                "the planner found no plan within {} expansions",
                config.max_expansions
            ))),
        }
    }

    /// Length of the plan.
    pub fn planned_steps(&self) -> usize {
        self.planned_steps
    }

    /// Whether the plan is proven shortest.
    pub fn shortest(&self) -> bool {
        self.shortest
    }
}

impl Driver for PlannerDriver {
    fn describe(&self) -> String {
        format!(
            "exact planner's action sequence ({} steps{})",
            self.planned_steps,
            if self.shortest { ", shortest" } else { "" }
        )
    }

    fn decide(&mut self, _env: &Env) -> Result<Action, DriverError> {
        self.actions.pop_front().ok_or_else(|| {
            DriverError("the planner's action sequence ended before the episode did".to_owned())
        })
    }
}

/// The robot's int8 policy, run by the runtime's integer inference on the world's observation,
/// through a decision stack (`wheelleg_stack`): the rule, the guard and arrival as the
/// controller firmware runs them, and the host's look-ahead and searches where the stack has
/// them.
#[derive(Clone, Debug)]
pub struct PolicyDriver<'a> {
    policy: DefaultPolicy<'a>,
    label: String,
    observation: Observation,
    /// Never repeats an action already taken at the same observation (see
    /// `wheelleg_runtime::decision`).
    decider: Decider,
    /// The layers that run.
    stack: StackConfig,
    /// The guard, where the stack checks actions.
    guard: Option<CollisionGuard>,
    /// The map the guard reads when it is not the policy's: its layout and its cells.
    guard_map: Option<GuardMap>,
    /// Weighs the rule's first candidates by rollouts of the same network on the robot's map,
    /// where the stack has the look-ahead. Host-side: a batched copy of the policy.
    lookahead: Option<(Lookahead, Int8Policy<'a>)>,
    /// The search for the last metres, where the stack has it.
    last_metres: Option<LastMetres>,
    /// The collision count when the last action handed out was a searched plan's: a rise
    /// by the next decision means the world refused it, and the rest of the plan is dropped.
    plan_step_collisions: Option<u32>,
}

impl<'a> PolicyDriver<'a> {
    /// Loads a `.wlw` weights file's bytes; `label` names the file in messages. It decides
    /// through `stack`.
    pub fn new(
        bytes: &'a [u8],
        label: &str,
        stack: StackConfig,
    ) -> Result<PolicyDriver<'a>, DriverError> {
        let unusable = |e: &dyn fmt::Display| {
            DriverError(format!("{label}: not a usable policy weights file: {e}"))
        };
        stack.check().map_err(DriverError)?;
        if stack.rule != DecisionRule::Untried {
            return Err(DriverError(format!(
                "the robot decides by the untried rule, not {:?}",
                stack.rule
            )));
        }
        let policy = DefaultPolicy::from_bytes(bytes).map_err(|e| unusable(&e))?;
        // As on the controller, the robot is the one the weights name.
        let robot = policy.model().trained_for.robot;
        let lookahead = match stack.lookahead {
            Some(config) => Some((
                Lookahead::new(config),
                Int8Policy::from_bytes(bytes).map_err(|e| unusable(&e))?,
            )),
            None => None,
        };
        Ok(PolicyDriver {
            policy,
            label: label.to_owned(),
            observation: Observation::default(),
            decider: Decider::new(),
            guard: stack.guard.map(|g| CollisionGuard::new(&robot, g.margin_m)),
            guard_map: stack.guard.and_then(|g| g.grid).map(GuardMap::new),
            lookahead,
            last_metres: stack.last_metres.map(LastMetres::new),
            plan_step_collisions: None,
            stack,
        })
    }

    /// The next action of a searched plan, if one is being followed or is due now.
    fn planned_step(&mut self, env: &Env) -> Option<Action> {
        let last_metres = self.last_metres.as_mut()?;
        if let Some(before) = self.plan_step_collisions.take() {
            if env.collisions() > before {
                last_metres.abandon();
            }
        }
        let action = last_metres.next_action(env)?;
        self.plan_step_collisions = Some(env.collisions());
        Some(action)
    }
}

impl Driver for PolicyDriver<'_> {
    fn describe(&self) -> String {
        format!(
            "int8 policy {} ({:?} kernel){}{}{}{}",
            self.label,
            self.policy.kernel(),
            self.guard.map_or(String::new(), |g| format!(
                ", collision guard (columns grown by {} m, {} m cells)",
                g.margin_m(),
                self.guard_map
                    .as_ref()
                    .map_or(wheelleg_runtime::observation::HEIGHT_MAP_CELL_M, |m| m
                        .grid()
                        .cell_m)
            )),
            if self.stack.arrival {
                ", arrival rule"
            } else {
                ""
            },
            self.lookahead
                .as_ref()
                .map_or(String::new(), |(l, _)| format!(
                    ", look-ahead ({} candidates, {}-step rollouts on the robot's map{})",
                    l.config().candidates,
                    l.config().horizon_steps,
                    match l.config().search_expansions {
                        0 => String::new(),
                        n => format!(", a search for a shorter way within {n} expansions"),
                    }
                )),
            self.stack.last_metres.map_or(String::new(), |l| format!(
                ", a search for the last metres within {} expansions",
                l.planner.max_expansions
            ))
        )
    }

    fn decide(&mut self, env: &Env) -> Result<Action, DriverError> {
        let trained = self.policy.model().trained_for;
        if *env.geometry() != trained.robot.geometry {
            return Err(DriverError(format!(
                "{} was trained for robot '{}', and the world simulates another robot's \
                 geometry: a policy drives only the robot it was trained for",
                self.label, trained.name
            )));
        }
        if let Some(action) = self.planned_step(env) {
            return Ok(action);
        }
        env.observe(&mut self.observation);
        let (height_mm, state_mm) = observation_mm(&self.observation);
        let outputs = self
            .policy
            .evaluate(height_mm.as_flattened(), &state_mm)
            .map_err(|e| DriverError(format!("{}: inference failed: {e}", self.label)))?;
        let key = ObservationKey::of_mm(height_mm.as_flattened(), &state_mm);
        let cells: &[i16; HEIGHT_MAP_CELLS] = height_mm
            .as_flattened()
            .try_into()
            .map_err(|_| DriverError("height map of the wrong size".to_owned()))?;
        let map = match (&self.guard, &mut self.guard_map) {
            (None, _) => None,
            (Some(_), None) => Some(HeightMapRef::Millimetres(cells)),
            (Some(_), Some(guard_map)) => Some(
                guard_map
                    .observe(env)
                    .map_err(|e| DriverError(format!("guard map: {e}")))?,
            ),
        };
        let success_radius_m = env.config().success_radius_m;
        let rule = RobotRule {
            guard: self.guard.as_ref().zip(map).map(|(guard, map)| GuardAt {
                guard,
                map,
                legs: LegConfig {
                    clearance_m: state_mm[0] as f32 * 1.0e-3,
                    track_m: state_mm[1] as f32 * 1.0e-3,
                },
            }),
            arrival: self.stack.arrival.then(|| {
                Arrival::from_state_mm(&state_mm, success_radius_m, &trained.robot.actions)
            }),
        };
        let logits = &outputs.action_logits;
        let Some((lookahead, policy)) = &mut self.lookahead else {
            return Ok(rule.choose(&mut self.decider, key, logits));
        };
        let found = candidates(&self.decider, lookahead.candidates_wanted(), |d| {
            rule.choose(d, key, logits)
        });
        let action = match settled(&found, rule.arrival.as_ref()) {
            Some(first) => first,
            None => {
                let first = found.first().copied().unwrap_or_default();
                lookahead.push(0, env, &self.decider, key, found);
                let weighed = lookahead
                    .weigh(
                        &*policy,
                        self.stack.arrival,
                        success_radius_m,
                        &mut |_, a| rule.allows(a),
                    )
                    .map_err(|e| DriverError(format!("{}: look-ahead: {e}", self.label)))?;
                let weighed = weighed.first();
                // No candidate arrives within the horizon: the policy is lost here, so the
                // search (when on) runs now rather than when it is next due.
                let lost = weighed.is_some_and(|w| !w.arrives);
                let searched = match &mut self.last_metres {
                    Some(search) if lost => {
                        if search.search_now(env) {
                            search.next_action(env)
                        } else {
                            None
                        }
                    }
                    _ => None,
                };
                match searched {
                    Some(action) => {
                        self.plan_step_collisions = Some(env.collisions());
                        action
                    }
                    None => weighed.map_or(first, |w| w.action),
                }
            }
        };
        mark_taken(&mut self.decider, key, action);
        Ok(action)
    }
}

/// The observation in the runtime model's input units: heights in millimetres (i16, row = robot
/// x ahead first, column = robot y left first, as the simulator renders it) and the state
/// (clearance, track, target x, target y) in millimetres. Rounded half away from zero, like the
/// trainer's `quantize::observation_mm`, so the robot sees what calibration saw; `as` saturates,
/// so an absurd height cannot wrap around.
pub fn observation_mm(
    observation: &Observation,
) -> ([[i16; HEIGHT_MAP_SIDE]; HEIGHT_MAP_SIDE], [i32; STATE_LEN]) {
    let mut height_mm = [[0i16; HEIGHT_MAP_SIDE]; HEIGHT_MAP_SIDE];
    for (row_mm, row_m) in height_mm
        .iter_mut()
        .zip(observation.height_map.chunks_exact(HEIGHT_MAP_SIDE))
    {
        for (mm, m) in row_mm.iter_mut().zip(row_m) {
            *mm = (m * 1000.0).round() as i16;
        }
    }
    let state_mm = observation.state.map(|m| (m * 1000.0).round() as i32);
    (height_mm, state_mm)
}
