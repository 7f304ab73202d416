//! The behaviour scenes' fences: each kind's passage geometry, a scene with one fence across
//! the arena, the leg pose that passes it, and the start-stage scenes that begin in front of
//! the passage, lined up.

use super::{cell_index, layout};
use super::{Behaviour, SceneRobot, StartYaw};
use crate::obstacle::{cell_centre_m, Obstacle, ObstacleKind, ObstacleYaw, GRID_CELL_M};
use crate::scenario::Scenario;
use crate::state::RobotState;
use nalgebra::Point2;
use rand::Rng;

/// `scenario` (as drawn, valid) with its start moved to `stage`; `None` when no valid start
/// was found near the staged one.
pub(super) fn staged_scene(
    robot: &SceneRobot,
    scenario: &Scenario,
    behaviour: Behaviour,
    passage: Passage,
    stage: f32,
) -> Option<Scenario> {
    let stage = if stage.is_finite() {
        stage.clamp(0.0, 1.0)
    } else {
        1.0
    };
    let drawn = scenario.start;
    let back = (2.0 * stage).min(1.0);
    let relax = (2.0 * stage - 1.0).max(0.0);
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    // Signed yaw of the drawn start from the nearer of the two headings along x, in steps.
    let per_turn = drawn.yaw_steps_per_turn();
    let half = per_turn / 2;
    let wrapped = (drawn.yaw_steps + half).rem_euclid(per_turn) - half;
    let base = if wrapped.abs() <= half / 2 { 0 } else { half };
    let deviation = (drawn.yaw_steps - base + half).rem_euclid(per_turn) - half;
    let (clearance_steps, track_steps) = robot.passing_legs(behaviour);
    let mut start = RobotState {
        position: Point2::new(
            robot.on_start_lattice(robot.start_lattice_index(lerp(
                passage.entry_x_m,
                drawn.position.x,
                back,
            ))),
            robot.on_start_lattice(robot.start_lattice_index(lerp(
                passage.line_y_m,
                drawn.position.y,
                relax,
            ))),
        ),
        yaw_steps: (base + (deviation as f32 * relax).round() as i32).rem_euclid(per_turn),
        clearance_steps: (clearance_steps as f32 * (1.0 - relax)).round() as i32,
        track_steps: (track_steps as f32 * (1.0 - relax)).round() as i32,
        lattice: drawn.lattice,
    };
    for _ in 0..20 {
        let candidate = Scenario {
            start,
            ..scenario.clone()
        };
        if candidate.validate(robot.robot()).is_ok()
            && (candidate.target - start.position).norm() > 0.2
        {
            return Some(candidate);
        }
        start.position.x = robot.on_start_lattice(robot.start_lattice_index(start.position.x) - 1);
    }
    None
}

/// Rows of a behaviour's fence (docs/simulator.md: why three for the slab, two for squeeze).
pub(super) const fn fence_rows(behaviour: Behaviour) -> i32 {
    match behaviour {
        Behaviour::SpreadOver => 3,
        Behaviour::Squeeze => 2,
        _ => 1,
    }
}

/// Cells of a fence: (y cell offset from the opening, kind) pairs.
pub(super) fn fence_cells(behaviour: Behaviour) -> Vec<(i32, ObstacleKind)> {
    let span = -6..=6;
    match behaviour {
        Behaviour::LiftOver => span.map(|m| (m, ObstacleKind::Bar)).collect(),
        Behaviour::SpreadOver => span
            .filter_map(|m: i32| match m.rem_euclid(4) {
                0 => Some((m, ObstacleKind::Slab)),
                2 => Some((m, ObstacleKind::Block)),
                _ => None,
            })
            .collect(),
        Behaviour::Squeeze => span
            .filter(|&m| m != 0)
            .map(|m| (m, ObstacleKind::Block))
            .collect(),
        Behaviour::Straight | Behaviour::Around => Vec::new(),
    }
}

/// Where a behaviour scene's passage is: the line a robot in the passing pose drives along.
#[derive(Clone, Copy, Debug)]
pub(super) struct Passage {
    /// x of the fence's first row (the around block's centre), on the robot lattice.
    pub(super) entry_x_m: f32,
    /// y of the line through the passage (the opening's centre; beside the around block), on the
    /// robot lattice.
    pub(super) line_y_m: f32,
}

pub(super) fn behaviour_scene(
    robot: &SceneRobot,
    behaviour: Behaviour,
    rng: &mut impl Rng,
    name: String,
    start_yaw: StartYaw,
) -> (Scenario, Passage) {
    // The fence (or block) stands in the first cell at least the robot's fence lead ahead of the
    // start, so the robot starts clear of it at any yaw; the target is at least `beyond` past
    // its centre.
    let beyond_m = match behaviour {
        Behaviour::Around => 0.45,
        _ => 0.25,
    };
    let lead_m = robot.fence_lead_m();
    let lay = layout(robot, rng, lead_m + beyond_m, start_yaw);
    let fence_x = cell_centre_m(cell_index(lay.start.position.x + lead_m) + 1);
    let fence_x = if fence_x - GRID_CELL_M >= lay.start.position.x + lead_m {
        fence_x - GRID_CELL_M
    } else {
        fence_x
    };
    let mut target = lay.target;
    if target.x < fence_x + beyond_m {
        target.x =
            robot.on_start_lattice(robot.start_lattice_index(
                fence_x + beyond_m + 0.5 * robot.robot().lattice().move_step_m,
            ));
    }
    let path_cell = cell_index(lay.start.position.y);
    let mut line_y_m = lay.start.position.y;
    let obstacles = match behaviour {
        Behaviour::Straight => Vec::new(),
        Behaviour::Around => {
            // Beside the block, on the side away from the second block (or, for one block, on
            // the start's side), the default pose 0.10 m clear of the block's face
            // ([`SceneRobot`]: 0.40 m from the block's centre for the shipped robot).
            let centre_m = cell_centre_m(path_cell);
            let mut free_side = if lay.start.position.y >= centre_m {
                1.0
            } else {
                -1.0
            };
            let mut blocks = vec![Obstacle::new(
                ObstacleKind::Block,
                fence_x,
                cell_centre_m(path_cell),
                ObstacleYaw::Deg0,
            )];
            if rng.random_bool(0.5) {
                let side = if rng.random_bool(0.5) { 1 } else { -1 };
                free_side = -side as f32;
                blocks.push(Obstacle::new(
                    ObstacleKind::Block,
                    fence_x,
                    cell_centre_m(path_cell + side),
                    ObstacleYaw::Deg0,
                ));
            }
            line_y_m = robot.on_start_lattice(
                robot.start_lattice_index(centre_m + free_side * robot.around_offset_m()),
            );
            blocks
        }
        Behaviour::LiftOver | Behaviour::SpreadOver | Behaviour::Squeeze => {
            let opening = path_cell + rng.random_range(-1..=1);
            line_y_m = cell_centre_m(opening);
            (0..fence_rows(behaviour))
                .flat_map(|row| {
                    fence_cells(behaviour).into_iter().map(move |(m, kind)| {
                        let x = fence_x + row as f32 * GRID_CELL_M;
                        Obstacle::new(kind, x, cell_centre_m(opening + m), ObstacleYaw::Deg0)
                    })
                })
                .collect()
        }
    };
    (
        Scenario {
            name,
            start: lay.start,
            target,
            obstacles,
        },
        Passage {
            entry_x_m: fence_x,
            line_y_m,
        },
    )
}
