//! Who decides the next action: the int8 policy from a weights file, or the exact planner.
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
use wheelleg_sim::height_map::MapGrid;
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig};
use wheelleg_trainer::lookahead::{candidates, mark_taken, settled, Lookahead, LookaheadConfig};
use wheelleg_trainer::quantize::EvalPolicy;

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

/// The robot's int8 policy, run by the runtime's integer inference on the world's observation.
#[derive(Clone, Debug)]
pub struct PolicyDriver<'a> {
    policy: DefaultPolicy<'a>,
    label: String,
    observation: Observation,
    /// Never repeats an action already taken at the same observation (see
    /// `wheelleg_runtime::decision`).
    decider: Decider,
    /// Checks each action against the height map first, when set.
    guard: Option<CollisionGuard>,
    /// The map the guard reads when it is not the policy's: its layout and its cells.
    guard_map: Option<GuardMap>,
    /// Takes an action that reaches the target within this radius when one does, when set.
    arrival_radius_m: Option<f32>,
    /// Weighs the rule's first candidates by rollouts of the same network on the robot's map
    /// (`wheelleg_trainer::lookahead`), when set. Host-side: a batched copy of the policy.
    lookahead: Option<(Lookahead, EvalPolicy<'a>)>,
    bytes: &'a [u8],
}

impl<'a> PolicyDriver<'a> {
    /// Loads a `.wlw` weights file's bytes; `label` names the file in messages.
    pub fn from_bytes(bytes: &'a [u8], label: &str) -> Result<PolicyDriver<'a>, DriverError> {
        let policy = DefaultPolicy::from_bytes(bytes)
            .map_err(|e| DriverError(format!("{label}: not a usable policy weights file: {e}")))?;
        Ok(PolicyDriver {
            policy,
            label: label.to_owned(),
            observation: Observation::default(),
            decider: Decider::new(),
            guard: None,
            guard_map: None,
            arrival_radius_m: None,
            lookahead: None,
            bytes,
        })
    }

    /// Weighs the rule's first `config.candidates` actions at every decision by rollouts of
    /// the same network in the scene as the robot's map shows it, and takes the one that
    /// arrives soonest (`wheelleg_trainer::lookahead`; docs/results.md, "Rollouts on the
    /// robot's map").
    pub fn with_lookahead(
        mut self,
        config: LookaheadConfig,
    ) -> Result<PolicyDriver<'a>, DriverError> {
        let policy = EvalPolicy::from_bytes(self.bytes).map_err(|e| {
            DriverError(format!(
                "{}: not a usable policy weights file: {e}",
                self.label
            ))
        })?;
        self.lookahead = Some((Lookahead::new(config), policy));
        Ok(self)
    }

    /// Checks every action with `guard` before taking it (`wheelleg_runtime::guard`): the
    /// policy's most probable action that the guard passes is taken.
    pub fn with_guard(mut self, guard: CollisionGuard) -> PolicyDriver<'a> {
        self.guard = Some(guard);
        self
    }

    /// Lets the guard read a map of layout `grid` (for example the 1 cm
    /// `MapGrid::GUARD_FINE`, as a robot's elevation mapping keeps) instead of the policy's
    /// 5 cm map; the policy still sees its own.
    pub fn with_guard_map(mut self, grid: MapGrid) -> PolicyDriver<'a> {
        self.guard_map = Some(GuardMap::new(grid));
        self
    }

    /// Takes the policy's most probable action that ends within `radius_m` of the target
    /// whenever one does (`wheelleg_runtime::arrival`; after the guard, if one is set).
    pub fn with_arrival(mut self, radius_m: f32) -> PolicyDriver<'a> {
        self.arrival_radius_m = Some(radius_m);
        self
    }
}

impl Driver for PolicyDriver<'_> {
    fn describe(&self) -> String {
        format!(
            "int8 policy {} ({:?} kernel){}{}{}",
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
            self.arrival_radius_m
                .map_or(String::new(), |r| format!(", arrival within {r} m")),
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
                ))
        )
    }

    fn decide(&mut self, env: &Env) -> Result<Action, DriverError> {
        env.observe(&mut self.observation);
        let (height_mm, state_mm) = observation_mm(&self.observation);
        let outputs = self
            .policy
            .evaluate(height_mm.as_flattened(), &state_mm)
            .map_err(|e| DriverError(format!("{}: inference failed: {e}", self.label)))?;
        let key = ObservationKey::of_mm(height_mm.as_flattened(), &state_mm);
        let arrival = self
            .arrival_radius_m
            .map(|radius_m| Arrival::from_state_mm(&state_mm, radius_m));
        let legs = LegConfig {
            clearance_m: state_mm[0] as f32 * 1.0e-3,
            track_m: state_mm[1] as f32 * 1.0e-3,
        };
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
        let logits = &outputs.action_logits;
        let guard = self.guard;
        let decide = |decider: &mut Decider| match (&guard, map) {
            (Some(guard), Some(map)) => {
                guard
                    .choose(decider, key, logits, map, legs, arrival.as_ref())
                    .action
            }
            _ => match &arrival {
                Some(arrival) => arrival.choose(decider, key, logits).action,
                None => decider.choose(key, logits),
            },
        };
        let Some((lookahead, policy)) = &mut self.lookahead else {
            return Ok(decide(&mut self.decider));
        };
        let found = candidates(&self.decider, lookahead.candidates_wanted(), decide);
        let action = match settled(&found, arrival.as_ref()) {
            Some(first) => first,
            None => {
                let first = found.first().copied().unwrap_or_default();
                let allows = |action| match (&guard, map) {
                    (Some(guard), Some(map)) => guard.check(map, legs, action).is_ok(),
                    _ => true,
                };
                lookahead.push(0, env, &self.decider, key, found, &allows);
                let success_radius_m = env.config().success_radius_m;
                lookahead
                    .weigh(&*policy, arrival.is_some(), success_radius_m)
                    .map_err(|e| DriverError(format!("{}: look-ahead: {e}", self.label)))?
                    .first()
                    .map_or(first, |w| w.action)
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
