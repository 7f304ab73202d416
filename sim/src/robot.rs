//! The robot as the simulator steps it: its geometry and its action lattice, checked for what
//! the scene generators and the planner build on.
//!
//! The runtime drives any lattice a description gives. The simulator asks three things more:
//!
//! - **The yaw step divides the quarter turn** into whole steps (5 degrees: 18), so that the
//!   robot can line up with the axis-aligned fences and passages from any start, and states
//!   store whole steps that wrap exactly at a full turn. At least 1.5 degrees, so that a turn's
//!   steps fit the trajectory batch's byte.
//! - **The move step divides the scene grid's cell** (0.25 m) into whole steps (0.05 m: 5),
//!   so that every obstacle cell's centre lies on the start lattice and a passage centred on a
//!   cell is entered exactly on its centre line. At least 1 cm.
//! - **The leg ranges hold at most 16 clearance and 32 track steps**, the planner's leg sets.

use crate::obstacle::GRID_CELL_M;
use crate::planner::{LEG_COLS, LEG_ROWS};
use wheelleg_robot::RobotDescription;
use wheelleg_runtime::action::ActionLattice;
use wheelleg_runtime::robot::{RobotGeometry, WHEELLEG};

/// The smallest yaw step the simulator steps on, degrees.
const MIN_YAW_STEP_DEG: f32 = 1.5;
/// The smallest move step the simulator steps on, metres.
const MIN_MOVE_STEP_M: f32 = 0.01;

/// A robot's geometry and the action lattice it steps on, checked for simulation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SimulatedRobot {
    geometry: RobotGeometry,
    lattice: ActionLattice,
}

impl SimulatedRobot {
    /// The robot this project ships, on the paper's lattice.
    pub const SHIPPED: SimulatedRobot = SimulatedRobot {
        geometry: WHEELLEG,
        lattice: ActionLattice::PAPER,
    };

    /// `geometry` stepping on `lattice`; the error names the lattice key the simulator cannot
    /// step on and why.
    pub fn new(geometry: RobotGeometry, lattice: ActionLattice) -> Result<SimulatedRobot, String> {
        check_lattice(&lattice)?;
        // The planner's leg sets hold this many steps of each range (a bitset row per
        // clearance step, a bit per track step).
        for (key, range_m, step_m, most) in [
            (
                "actions.clearance_step_m",
                geometry.clearance_range_m,
                lattice.clearance_step_m,
                LEG_ROWS,
            ),
            (
                "actions.track_step_m",
                geometry.track_range_m,
                lattice.track_step_m,
                LEG_COLS,
            ),
        ] {
            let span_m = range_m[1] - range_m[0];
            let steps = (span_m / step_m + 1.0e-3).floor() as usize + 1;
            if steps > most {
                return Err(format!(
                    "{key} = {step_m}: the range {range_m:?} m holds {steps} steps, and the \
                     planner holds at most {most}; use a step of at least {:.4} m",
                    span_m / (most - 1) as f32
                ));
            }
        }
        Ok(SimulatedRobot { geometry, lattice })
    }

    /// The robot a description describes; the error names the robot and the key.
    pub fn of(description: &RobotDescription) -> Result<SimulatedRobot, String> {
        SimulatedRobot::new(description.robot.geometry, description.robot.actions)
            .map_err(|e| format!("robot '{}': {e}", description.name))
    }

    /// Body, legs, wheels and pose ranges.
    pub fn geometry(&self) -> &RobotGeometry {
        &self.geometry
    }

    /// How far one step of each action dimension moves.
    pub fn lattice(&self) -> &ActionLattice {
        &self.lattice
    }

    /// Whole yaw steps in a full turn (72 on the paper's lattice).
    pub fn yaw_steps_per_turn(&self) -> i32 {
        yaw_steps_per_turn(&self.lattice)
    }
}

/// Whole yaw steps in a full turn on `lattice` (72 on the paper's), for a lattice that
/// [`SimulatedRobot::new`] accepts.
pub fn yaw_steps_per_turn(lattice: &ActionLattice) -> i32 {
    (360.0 / lattice.yaw_step_deg).round() as i32
}

/// How many times `step` goes into `whole`, when that is a whole number to 1 part in 10^4.
fn whole_steps(whole: f32, step: f32) -> Option<i32> {
    let count = (whole / step).round();
    ((count * step - whole).abs() <= 1.0e-4 * whole).then_some(count as i32)
}

fn check_lattice(lattice: &ActionLattice) -> Result<(), String> {
    let yaw = lattice.yaw_step_deg;
    if !(MIN_YAW_STEP_DEG..=90.0).contains(&yaw) || whole_steps(90.0, yaw).is_none() {
        return Err(format!(
            "actions.yaw_step_deg = {yaw}: the simulator steps on yaws that divide 90 degrees \
             into whole steps of at least {MIN_YAW_STEP_DEG} degrees (5, 7.5, 10, 15, ...), so \
             that the robot lines up with axis-aligned passages"
        ));
    }
    let step = lattice.move_step_m;
    if !(MIN_MOVE_STEP_M..=GRID_CELL_M).contains(&step) || whole_steps(GRID_CELL_M, step).is_none()
    {
        return Err(format!(
            "actions.move_step_m = {step}: the simulator steps on moves that divide the scene \
             grid's {GRID_CELL_M} m cell into whole steps of at least {MIN_MOVE_STEP_M} m \
             (0.05, 0.0625, 0.125, ...), so that passages centred on a cell are entered on centre"
        ));
    }
    for (key, step) in [
        ("actions.clearance_step_m", lattice.clearance_step_m),
        ("actions.track_step_m", lattice.track_step_m),
    ] {
        if !(step.is_finite() && step > 0.0) {
            return Err(format!(
                "{key} = {step}: must be a positive number of metres"
            ));
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn with(change: impl FnOnce(&mut ActionLattice)) -> Result<SimulatedRobot, String> {
        let mut lattice = ActionLattice::PAPER;
        change(&mut lattice);
        SimulatedRobot::new(WHEELLEG, lattice)
    }

    #[test]
    fn the_papers_lattice_has_72_yaw_steps_per_turn() {
        assert_eq!(SimulatedRobot::SHIPPED.yaw_steps_per_turn(), 72);
        assert_eq!(with(|_| {}), Ok(SimulatedRobot::SHIPPED));
    }

    #[test]
    fn lattices_the_scenes_cannot_line_up_with_are_refused_naming_the_key() {
        for (change, key) in [
            (7.0, "actions.yaw_step_deg"),
            (1.0, "actions.yaw_step_deg"),
            (-5.0, "actions.yaw_step_deg"),
            (f32::NAN, "actions.yaw_step_deg"),
        ] {
            let error = with(|l| l.yaw_step_deg = change).unwrap_err();
            assert!(error.starts_with(key), "{error}");
        }
        for step in [0.04, 0.005, 0.5, f32::INFINITY] {
            let error = with(|l| l.move_step_m = step).unwrap_err();
            assert!(error.starts_with("actions.move_step_m"), "{error}");
        }
        let error = with(|l| l.track_step_m = 0.0).unwrap_err();
        assert!(error.starts_with("actions.track_step_m"), "{error}");
        // 0.20 m of clearance in 0.01 m steps is 21 rows, more than the planner's 16.
        let error = with(|l| l.clearance_step_m = 0.01).unwrap_err();
        assert!(
            error.starts_with("actions.clearance_step_m") && error.contains("21 steps"),
            "{error}"
        );
        for (yaw, move_m) in [(7.5, 0.0625), (15.0, 0.125), (2.0, 0.025)] {
            let robot = with(|l| {
                l.yaw_step_deg = yaw;
                l.move_step_m = move_m;
            })
            .expect("divides the quarter turn and the cell");
            assert_eq!(robot.yaw_steps_per_turn() as f32 * yaw, 360.0);
        }
    }
}
