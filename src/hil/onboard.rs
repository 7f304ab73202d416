//! The firmware's on-board stack as a driver of the host's in-process closed loop: the same
//! decision code (`controller/src/stack.rs`, compiled here), fed what the firmware is fed (the
//! observation in millimetres and the guard's fine window), so that the firmware in the loop
//! can be held to this loop's outcomes.

#[path = "../../controller/src/stack.rs"]
pub mod stack;

use stack::{ControllerDecider, Stack, ROW_ELEMENTS, WORK_BYTES};
pub use stack::{DecisionRecord, Observation};
use wheelleg_runtime::action::Action;
use wheelleg_runtime::guard::{height_mm, GridMap, HeightMapRef, WindowBounds};
use wheelleg_sim::env::{Env, Observation as SimObservation};
use wheelleg_sim::height_map::MapGrid;

use crate::closed_loop::driver::observation_mm;
use crate::closed_loop::{Driver, DriverError};

/// The cells of `bounds` in the 1 cm map `fine_m` (metres, row-major, `bounds.side` cells a
/// side) in whole millimetres, `i16` little-endian: the fine window the firmware's guard reads,
/// as the observation link carries it.
pub fn window_mm_le(fine_m: &[f32], bounds: &WindowBounds) -> Vec<u8> {
    let mut out = Vec::with_capacity(2 * bounds.cells());
    for row in bounds.rows() {
        for col in bounds.cols() {
            let m = fine_m.get(row * bounds.side + col).copied().unwrap_or(0.0);
            out.extend_from_slice(&height_mm(m).to_le_bytes());
        }
    }
    out
}

/// One decision of the on-board stack, with what it was fed.
pub struct OnboardDecision {
    /// The observation in millimetres, as the observation link carries it.
    pub observation: Observation,
    /// The guard's fine window ([`window_mm_le`]).
    pub window_mm_le: Vec<u8>,
    /// The stack's decision on them.
    pub record: DecisionRecord,
}

/// The controller's decision stack (policy, decision rule, guard on the fine window, arrival).
pub struct OnboardDriver<'w> {
    stack: Stack<'w, 'static>,
    fine: Vec<f32>,
    sim_observation: SimObservation,
    work: Vec<i8>,
    row: Vec<i16>,
    first: bool,
}

impl<'w> OnboardDriver<'w> {
    /// The stack on the weights file `weights`; each driver starts a new episode.
    pub fn new(weights: &'w [u8]) -> Result<OnboardDriver<'w>, DriverError> {
        // The firmware keeps the decision rule's memory in a static; one per driver here.
        let decider = Box::leak(Box::new(ControllerDecider::new()));
        let stack =
            Stack::new(weights, decider).map_err(|e| DriverError(format!("weights: {e:?}")))?;
        Ok(OnboardDriver {
            stack,
            fine: vec![0.0; MapGrid::GUARD_FINE.cells()],
            sim_observation: SimObservation::default(),
            work: vec![0; WORK_BYTES],
            row: vec![0; ROW_ELEMENTS],
            first: true,
        })
    }

    /// Starts a new episode: the decision rule forgets what it met.
    pub fn reset(&mut self) {
        self.stack.reset();
        self.first = false;
    }

    /// The robot the weights were trained for: what the stack's guard and lattice are for.
    pub fn robot(&self) -> wheelleg_runtime::robot::Robot {
        self.stack.robot()
    }

    /// The fine window the guard reads, within the 1 cm map.
    pub fn window(&self) -> WindowBounds {
        self.stack.window()
    }

    /// The whole 1 cm map of the last decision, in metres (`MapGrid::GUARD_FINE`).
    pub fn fine_map_m(&self) -> &[f32] {
        &self.fine
    }

    /// One decision on `env` as it is now. With `whole_map` the guard reads the whole 1 cm map
    /// in metres (the host's `--guard-map fine`) instead of the firmware's window.
    pub fn decide_on(
        &mut self,
        env: &Env,
        whole_map: bool,
    ) -> Result<OnboardDecision, DriverError> {
        env.observe(&mut self.sim_observation);
        let (height_mm, state_mm) = observation_mm(&self.sim_observation);
        let mut observation = Observation::new();
        observation
            .height_mm
            .copy_from_slice(height_mm.as_flattened());
        observation.state_mm = state_mm;
        env.observe_grid(MapGrid::GUARD_FINE, &mut self.fine);
        let bounds = self.stack.window();
        let window_mm_le = window_mm_le(&self.fine, &bounds);
        let outputs = self
            .stack
            .infer(&observation, &mut self.work, &mut self.row)
            .map_err(|e| DriverError(format!("inference: {e:?}")))?;
        let record = if whole_map {
            let grid = GridMap::new(&self.fine, bounds.side, bounds.cell_m)
                .map_err(|e| DriverError(format!("the fine map: {e}")))?;
            self.stack
                .decide_on(&observation, &outputs, HeightMapRef::Grid(grid))
        } else {
            self.stack
                .decide(&observation, &outputs, &window_mm_le)
                .map_err(|e| DriverError(format!("decision: {e:?}")))?
        };
        Ok(OnboardDecision {
            observation,
            window_mm_le,
            record,
        })
    }
}

impl Driver for OnboardDriver<'_> {
    fn describe(&self) -> String {
        "the controller's on-board stack (policy, decision rule, guard on the fine window, \
         arrival)"
            .into()
    }

    fn decide(&mut self, env: &Env) -> Result<Action, DriverError> {
        if self.first {
            self.reset();
        }
        Ok(self.decide_on(env, false)?.record.action())
    }
}
