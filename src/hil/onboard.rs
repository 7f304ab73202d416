//! The firmware's on-board stack as a driver of the host's in-process closed loop: the same
//! decision code (`controller/src/stack.rs`, compiled here), fed what the firmware is fed (the
//! observation in millimetres and the guard's fine window), so that the firmware in the loop
//! can be held to this loop's outcomes.

#[path = "../../controller/src/stack.rs"]
#[allow(dead_code)]
mod stack;

use stack::{ControllerDecider, Observation, Stack, ROW_ELEMENTS, WORK_BYTES};
use wheelleg_runtime::action::Action;
use wheelleg_sim::env::{Env, Observation as SimObservation};
use wheelleg_sim::height_map::MapGrid;

use crate::closed_loop::driver::observation_mm;
use crate::closed_loop::{Driver, DriverError};

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
}

impl Driver for OnboardDriver<'_> {
    fn describe(&self) -> String {
        "the controller's on-board stack (policy, decision rule, guard on the fine window, \
         arrival)"
            .into()
    }

    fn decide(&mut self, env: &Env) -> Result<Action, DriverError> {
        if std::mem::take(&mut self.first) {
            self.stack.reset();
        }
        env.observe(&mut self.sim_observation);
        let (height_mm, state_mm) = observation_mm(&self.sim_observation);
        let mut observation = Observation::new();
        observation
            .height_mm
            .copy_from_slice(height_mm.as_flattened());
        observation.state_mm = state_mm;
        env.observe_grid(MapGrid::GUARD_FINE, &mut self.fine);
        let bounds = self.stack.window();
        let mut window_mm_le = Vec::with_capacity(2 * bounds.cells());
        for row in bounds.rows() {
            for col in bounds.cols() {
                let m = self.fine[row * bounds.side + col];
                window_mm_le.extend_from_slice(&((m * 1000.0).round() as i16).to_le_bytes());
            }
        }
        let outputs = self
            .stack
            .infer(&observation, &mut self.work, &mut self.row)
            .map_err(|e| DriverError(format!("inference: {e:?}")))?;
        let record = self
            .stack
            .decide(&observation, &outputs, &window_mm_le)
            .map_err(|e| DriverError(format!("decision: {e:?}")))?;
        Ok(record.action())
    }
}
