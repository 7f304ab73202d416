//! Exit scenes: a fence whose target stands just past it, beside the opening.
//!
//! In a behaviour scene the target is drawn on the start's line, so where the opening is one cell
//! off that line and the target near the fence, the target stands behind a block of the fence:
//! the robot, 0.5 m long, cannot stand there lined up with the passage (its rear would be in the
//! block), only turned alongside the fence. The policy passes the gap and dithers there
//! (docs/results.md, "Composed scenes"). An exit scene is a behaviour scene with that target
//! drawn on purpose: 0.20 to 0.30 m past the centre of the fence's last row, 0.15 to 0.35 m to
//! either side of the opening's centre line, where the robot can stand
//! ([`super::target_is_free`]).

use super::{behaviour_scene, fence_rows, target_is_free};
use super::{Behaviour, SceneRobot, StartYaw};
use crate::obstacle::GRID_CELL_M;
use crate::scenario::Scenario;
use nalgebra::Point2;
use rand::Rng;

/// Distance of the target past the centre of the fence's last row, in robot-lattice steps.
const PAST_LAST_ROW_STEPS: std::ops::RangeInclusive<i32> = 4..=6;
/// Distance of the target beside the opening's centre line, in robot-lattice steps.
const BESIDE_OPENING_STEPS: std::ops::RangeInclusive<i32> = 3..=7;

/// A scene of `behaviour`'s fence (lift, spread or squeeze; any other behaviour is drawn as its
/// plain scene) with the target just past the fence, beside the opening. Every draw flows from
/// `rng`; the result validates and its target is free.
pub fn exit_scene(
    robot: &SceneRobot,
    behaviour: Behaviour,
    start_yaw: StartYaw,
    rng: &mut impl Rng,
    name: String,
) -> Scenario {
    loop {
        let (mut scenario, passage) =
            behaviour_scene(robot, behaviour, rng, name.clone(), start_yaw);
        if behaviour.has_fence() {
            let last_row_x_m = passage.entry_x_m + (fence_rows(behaviour) - 1) as f32 * GRID_CELL_M;
            let step_m = robot.robot().lattice().move_step_m;
            let past = rng.random_range(PAST_LAST_ROW_STEPS) as f32 * step_m;
            let side = if rng.random_bool(0.5) { 1.0 } else { -1.0 };
            let beside = side * rng.random_range(BESIDE_OPENING_STEPS) as f32 * step_m;
            scenario.target = Point2::new(
                robot.on_start_lattice(robot.start_lattice_index(last_row_x_m + past)),
                robot.on_start_lattice(robot.start_lattice_index(passage.line_y_m + beside)),
            );
        }
        if scenario.validate(robot.robot()).is_ok() && target_is_free(robot, &scenario) {
            return scenario;
        }
    }
}

#[cfg(test)]
#[allow(clippy::unwrap_used)]
mod tests {
    use super::*;
    use rand::SeedableRng;
    use rand_chacha::ChaCha8Rng;

    #[test]
    fn the_target_stands_just_past_the_fence_beside_the_opening() {
        let mut rng = ChaCha8Rng::seed_from_u64(5);
        for i in 0..50 {
            let s = exit_scene(
                SceneRobot::shipped(),
                Behaviour::Squeeze,
                StartYaw::Any,
                &mut rng,
                format!("x-{i}"),
            );
            // The fence's last row: the largest obstacle x.
            let last_row_x_m = s
                .obstacles
                .iter()
                .map(|o| o.centre.x)
                .fold(f32::MIN, f32::max);
            let past_m = s.target.x - last_row_x_m;
            assert!((0.19..=0.31).contains(&past_m), "{past_m}");
            // The opening: the one cell of the last row without a block, near the start.
            let opening_y_m = (-8..=8)
                .map(crate::obstacle::cell_centre_m)
                .find(|&y| {
                    (y - s.start.position.y).abs() < 0.4
                        && !s
                            .obstacles
                            .iter()
                            .any(|o| o.centre.x == last_row_x_m && (o.centre.y - y).abs() < 0.01)
                })
                .unwrap();
            let beside_m = (s.target.y - opening_y_m).abs();
            assert!((0.14..=0.36).contains(&beside_m), "{beside_m}");
        }
    }
}
