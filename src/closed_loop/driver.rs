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
use wheelleg_runtime::observation::{HEIGHT_MAP_SIDE, STATE_LEN};
use wheelleg_sim::env::{Env, GuardMap, Observation};
use wheelleg_sim::height_map::MapGrid;
use wheelleg_sim::planner::{plan, PlanOutcome, PlannerConfig};

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
        })
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
            "int8 policy {} ({:?} kernel){}{}",
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
                .map_or(String::new(), |r| format!(", arrival within {r} m"))
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
        let Some(guard) = &self.guard else {
            return Ok(match arrival {
                Some(arrival) => {
                    arrival
                        .choose(&mut self.decider, key, &outputs.action_logits)
                        .action
                }
                None => self.decider.choose(key, &outputs.action_logits),
            });
        };
        let cells = height_mm
            .as_flattened()
            .try_into()
            .map_err(|_| DriverError("height map of the wrong size".to_owned()))?;
        let legs = LegConfig {
            clearance_m: state_mm[0] as f32 * 1.0e-3,
            track_m: state_mm[1] as f32 * 1.0e-3,
        };
        let map = match &mut self.guard_map {
            None => HeightMapRef::Millimetres(cells),
            Some(guard_map) => guard_map
                .observe(env)
                .map_err(|e| DriverError(format!("guard map: {e}")))?,
        };
        let checked = guard.choose(
            &mut self.decider,
            key,
            &outputs.action_logits,
            map,
            legs,
            arrival.as_ref(),
        );
        Ok(checked.action)
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
