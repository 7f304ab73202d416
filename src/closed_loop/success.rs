//! Closed-loop success against pure-simulation success over a set of scenes: the closed loop
//! must reach the pure-simulation success over held-out scenes within 2 points.
//!
//! The same driver, built fresh for each run, plays every scene twice: once in the world alone
//! (`Env::step` with the driver's actions) and once through the closed loop (motors, CAN,
//! measured motion). The gap is in percentage points.

use super::{ClosedLoop, Driver, DriverError, LoopConfig, LoopError};
use wheelleg_sim::env::{Env, Status};
use wheelleg_sim::scenario::Scenario;

/// Success counts of both runs over the same scenes.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Default)]
pub struct SuccessComparison {
    /// Scenes played.
    pub scenes: usize,
    /// Successes in pure simulation.
    pub simulation_successes: usize,
    /// Successes through the closed loop.
    pub closed_loop_successes: usize,
    /// Closed-loop runs stopped by a fault (counted as failures).
    pub closed_loop_faults: usize,
}

impl SuccessComparison {
    /// Pure-simulation success rate, in percent.
    pub fn simulation_percent(&self) -> f64 {
        percent(self.simulation_successes, self.scenes)
    }

    /// Closed-loop success rate, in percent.
    pub fn closed_loop_percent(&self) -> f64 {
        percent(self.closed_loop_successes, self.scenes)
    }

    /// |closed loop - simulation|, in percentage points.
    pub fn gap_points(&self) -> f64 {
        (self.closed_loop_percent() - self.simulation_percent()).abs()
    }
}

fn percent(count: usize, of: usize) -> f64 {
    if of == 0 {
        0.0
    } else {
        100.0 * count as f64 / of as f64
    }
}

/// Plays `driver` in the world alone until the episode ends; returns the final status.
pub fn simulate(env: &mut Env, driver: &mut dyn Driver) -> Result<Status, LoopError> {
    while !env.status().is_done() {
        let action = driver.decide(env)?;
        env.step(action)?;
    }
    Ok(env.status())
}

/// Plays every scene in pure simulation and through the in-process closed loop with a driver
/// made by `make_driver` for each run (from the episode's start), and counts successes.
pub fn compare_success<D: Driver>(
    scenarios: &[Scenario],
    config: &LoopConfig,
    mut make_driver: impl FnMut(&Env) -> Result<D, DriverError>,
) -> Result<SuccessComparison, LoopError> {
    let mut comparison = SuccessComparison {
        scenes: scenarios.len(),
        ..SuccessComparison::default()
    };
    for scenario in scenarios {
        let mut env = Env::new(scenario, config.env)?;
        let mut driver = make_driver(&env)?;
        if simulate(&mut env, &mut driver)? == Status::Success {
            comparison.simulation_successes += 1;
        }

        let mut closed_loop = ClosedLoop::in_process(scenario, *config)?;
        closed_loop.start()?;
        let mut driver = make_driver(closed_loop.env())?;
        let report = closed_loop.run(&mut driver)?;
        if report.status == Status::Success {
            comparison.closed_loop_successes += 1;
        }
        if report.fault.is_some() {
            comparison.closed_loop_faults += 1;
        }
    }
    Ok(comparison)
}
